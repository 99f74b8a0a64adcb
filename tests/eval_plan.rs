//! Captures chosen by the daemon's trigger, and the equal-capture scaling.

use alfd::core::closedloop::{ClosedLoopTargets, DepthSnapshot, View};
use alfd::core::{DepthData, DepthImage, Intrinsics};
use alfd::eval::plan::{
    captures, closed_loop_captures, largest_passing_scale, scale_to_count, SCALE_PRECISION,
};
use glam::{DMat3, DVec3};

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

/// A nadir view at `x_m` over a roof 10 m below the camera (north −2…2 m,
/// every east) and ground 20 m below; image x is north, `f` = 32 px, 64 × 48.
fn roof_view(x_m: f64) -> View {
    let (w, h, f) = (64, 48, 32.0);
    let d: Vec<f32> = (0..w * h)
        .map(|k| {
            let t = ((k % w) as f64 + 0.5 - 32.0) / f;
            if (-2.0..=2.0).contains(&(x_m + 10.0 * t)) {
                10.0
            } else {
                20.0
            }
        })
        .collect();
    let intr = Intrinsics::from_focal_px(w, h, f, None).unwrap();
    View {
        depth: DepthSnapshot::new(
            &DepthImage::new(w, h, DepthData::Metres(d)).unwrap(),
            &intr,
            1,
        ),
        cam_to_ned: DMat3::IDENTITY,
        pos_ned_m: DVec3::new(x_m, 0.0, 0.0),
    }
}

#[test]
fn the_closed_loop_captures_where_the_measured_parallax_reaches_its_target() {
    // Roof and ground, 10 and 20 m: a baseline `b` spans 32·b·(1/10 − 1/20)
    // = 1.6·b px, so 2 px is reached at 1.25 m. The open loop allows 5 m.
    let step_m = 0.1;
    let views: Vec<View> = (0..81)
        .map(|k| roof_view(-4.0 + k as f64 * step_m))
        .collect();
    let open = vec![Some(5.0); views.len()];
    let targets = ClosedLoopTargets {
        parallax_px: Some(2.0),
        unseen_fraction_max: 0.002,
    };
    let flight = closed_loop_captures(&open, &views, step_m, 5.0, &targets);
    let c = &flight.captures;
    assert_eq!(c[0], 0);
    assert_eq!(*c.last().unwrap(), 80, "the line's end");
    // Every interval but the last (cut by the line's end) stops at the
    // last view before 1.25 m.
    for w in c[..c.len() - 1].windows(2) {
        assert_eq!(w[1] - w[0], 12, "{c:?}");
    }
    assert_eq!(flight.by_bound, vec![("parallax", c.len() - 2)]);
    // Without the closed loop: every 5 m (50 views).
    assert_eq!(captures(&open, step_m, 5.0, 1.0), vec![0, 50, 80]);
}
