//! Captures chosen by the daemon's trigger, and the equal-capture scaling.

use alfd::eval::plan::{captures, largest_passing_scale, scale_to_count, SCALE_PRECISION};

#[test]
fn constant_spacing_captures_every_k_views_and_the_last() {
    // Views 0.1 m apart, spacing 0.5 m: every 5th view, and the end of the line.
    let s = vec![Some(0.5); 53];
    let c = captures(&s, 0.1, 5.0, 1.0);
    assert_eq!(c, vec![0, 5, 10, 15, 20, 25, 30, 35, 40, 45, 50, 52]);
    // Scaled by 2: every 10th.
    let c = captures(&s, 0.1, 5.0, 2.0);
    assert_eq!(c, vec![0, 10, 20, 30, 40, 50, 52]);
}

#[test]
fn a_drop_in_spacing_is_followed_online() {
    // 1 m, then 0.3 m from view 40 on.
    let s: Vec<Option<f64>> = (0..101)
        .map(|k| Some(if k < 40 { 1.0 } else { 0.3 }))
        .collect();
    let c = captures(&s, 0.1, 5.0, 1.0);
    assert_eq!(&c[..5], &[0, 10, 20, 30, 40]);
    assert!(c[5..].windows(2).all(|w| w[1] - w[0] <= 3), "{c:?}");
}

#[test]
fn equal_capture_scaling_matches_the_target_count() {
    let s: Vec<Option<f64>> = (0..400)
        .map(|k| Some(0.4 + 0.3 * ((k as f64) * 0.05).sin().abs()))
        .collect();
    for target in [5usize, 12, 30, 57, 100] {
        let (scale, caps) = scale_to_count(&s, 0.05, 5.0, target);
        assert_eq!(caps.len(), target, "target {target}: scale {scale}");
        assert_eq!(caps, captures(&s, 0.05, 5.0, scale));
        assert_eq!(*caps.last().unwrap(), 399);
    }
    // Fewer captures need a larger scale.
    let (a, _) = scale_to_count(&s, 0.05, 5.0, 20);
    let (b, _) = scale_to_count(&s, 0.05, 5.0, 40);
    assert!(a > b);
}

#[test]
fn unreachable_counts_give_the_closest() {
    // 11 views: at most 11 captures.
    let s = vec![Some(1.0); 11];
    let (_, caps) = scale_to_count(&s, 0.1, 5.0, 50);
    assert_eq!(caps.len(), 11);
}

#[test]
fn the_largest_passing_scale_is_found_from_either_side() {
    for threshold in [0.013, 0.7, 1.0, 3.9, 250.0] {
        let mut calls = 0;
        for start in [1e-3, 0.5, 1.0, 40.0] {
            let s = largest_passing_scale(start, |c| {
                calls += 1;
                c <= threshold
            })
            .expect("a scale passes");
            assert!(s <= threshold, "{s} above {threshold} (start {start})");
            assert!(
                s * SCALE_PRECISION > threshold,
                "{s} more than the precision under {threshold} (start {start})"
            );
        }
        assert!(calls < 4 * 40, "{calls} calls for four searches");
    }
}

#[test]
fn the_largest_passing_scale_never_returns_a_failing_scale() {
    // Not monotone: a window of failure inside the passing range, as a plan's
    // phase can make. The answer passes, whatever the search lands on.
    let ok = |c: f64| c <= 2.0 && !(0.9..1.1).contains(&c);
    for start in [0.05, 0.95, 1.0, 1.5, 3.0] {
        let s = largest_passing_scale(start, ok).expect("a scale passes");
        assert!(ok(s), "{s} fails (start {start})");
    }
    assert_eq!(largest_passing_scale(1.0, |_| false), None);
    assert_eq!(largest_passing_scale(1.0, |_| true), Some(1e4));
}
