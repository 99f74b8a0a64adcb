//! Unit tests at each formula's extremes. Expected values are derived by hand
//! in the comments; f32 storage of inverse depth limits agreement to ~1e-7.

// Tests change one parameter of the defaults at a time, on purpose.
#![allow(clippy::field_reassign_with_default)]

use super::depth::*;
use super::estimate::*;
use super::inverse::*;
use super::params::*;
use super::spacing::*;

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(1e-300)
}

fn metres(w: usize, h: usize, d: Vec<f32>) -> DepthImage {
    DepthImage::new(w, h, DepthData::Metres(d)).unwrap()
}

/// `h` rows of `w` pixels, each row alternating stripes of depth `d1` and `d2`
/// every `stripe` pixels (one stripe only if `stripe >= w`).
fn stripes(w: usize, h: usize, stripe: usize, d1: f32, d2: f32) -> DepthImage {
    let row: Vec<f32> = (0..w)
        .map(|i| if (i / stripe) % 2 == 0 { d1 } else { d2 })
        .collect();
    metres(w, h, row.repeat(h))
}

fn no_score() -> EstimatorParams {
    EstimatorParams {
        score: None,
        ..EstimatorParams::with_model(Model::Occlusion)
    }
}

fn run(img: &DepthImage, intr: &Intrinsics, pitch: f64, p: &EstimatorParams) -> Estimate {
    Estimator::new(p.clone())
        .estimate_at(img, intr, pitch, 1)
        .unwrap()
}

// ---- spacing formulas ----

#[test]
fn mmds_two_level_design_example() {
    // f = 465 px, nadir, ground 40 m and roofs 20 m: Δw = 1/20 − 1/40 = 0.025 1/m,
    // b = 2·1 / (465·1·0.025·1) = 2/11.625 = 0.172043 m (DESIGN: "about 0.17 m").
    let b = mmds_m(disparity_gain_px(465.0, 0.0), 0.025, 1.0, 1.0).unwrap();
    assert!(close(b, 2.0 / 11.625, 1e-15), "{b}");
    // Pitch 60°: cos = 0.5 doubles it.
    let b60 = mmds_m(
        disparity_gain_px(465.0, 60f64.to_radians()),
        0.025,
        1.0,
        1.0,
    )
    .unwrap();
    assert!(close(b60, 4.0 / 11.625, 1e-12));
    // Half the texture bandwidth or twice the disparity tolerance: twice the spacing.
    assert!(close(
        mmds_m(465.0, 0.025, 0.5, 1.0).unwrap(),
        2.0 * b,
        1e-15
    ));
    assert!(close(
        mmds_m(465.0, 0.025, 1.0, 2.0).unwrap(),
        2.0 * b,
        1e-15
    ));
}

#[test]
fn mmds_extremes_are_unbounded_not_infinite() {
    // Flat scene: Δw = 0 → 2/0, nothing bounds it.
    assert_eq!(mmds_m(465.0, 0.0, 1.0, 1.0), None);
    // Δw = 1e-12 with f = 10: 2/(1e-11) = 2e11 > the 1e9 m cap → unbounded.
    assert_eq!(mmds_m(10.0, 1e-12, 1.0, 1.0), None);
    // Just under the cap: Δw = 2.5e-9, f = 1 → 8e8 m, kept.
    assert!(close(mmds_m(1.0, 2.5e-9, 1.0, 1.0).unwrap(), 8e8, 1e-12));
    assert_eq!(mmds_m(f64::NAN, 0.1, 1.0, 1.0), None);
    assert_eq!(mmds_m(465.0, -0.1, 1.0, 1.0), None);
    // Huge focal and Δw: 2/(1e5·1000) = 2e-8 m, tiny but positive and finite.
    assert!(close(mmds_m(1e5, 1000.0, 1.0, 1.0).unwrap(), 2e-8, 1e-12));
}

#[test]
fn sspa_plane_and_extent_terms() {
    // No slant and an infinite plane: nothing bounds it.
    assert_eq!(sspa_m(465.0, 0.0, f64::INFINITY, 1.0, 1.0), None);
    // No slant, L = 10 m: 2/(4/10) = 5 m, the sinc main lobe alone.
    assert!(close(
        sspa_m(465.0, 0.0, 10.0, 1.0, 1.0).unwrap(),
        5.0,
        1e-15
    ));
    // Slant only: same as MMDS with Δw_plane.
    assert!(close(
        sspa_m(465.0, 0.025, f64::INFINITY, 1.0, 1.0).unwrap(),
        mmds_m(465.0, 0.025, 1.0, 1.0).unwrap(),
        1e-15
    ));
    // Both: 2/(465·0.025 + 0.4) = 2/12.025.
    assert!(close(
        sspa_m(465.0, 0.025, 10.0, 1.0, 1.0).unwrap(),
        2.0 / 12.025,
        1e-15
    ));
}

#[test]
fn occlusion_density_term_and_degree() {
    // ρ = β·f·cos φ·D/(2·v_m) = 465·0.025/640 = 0.018164 per m;
    // O_max/ρ = 0.01/0.018164 = 0.55054 m; O(b) at that spacing = O_max.
    let rho = occlusion_density_per_m(1.0, 465.0, 0.025, 320.0);
    assert!(close(rho, 465.0 * 0.025 / 640.0, 1e-15));
    let b = occlusion_term_m(0.01, rho).unwrap();
    assert!(close(b, 0.01 * 640.0 / (465.0 * 0.025), 1e-15));
    assert!(close(occlusion_degree(rho, b), 0.01, 1e-12));
    // No boundary: density 0, no term.
    assert_eq!(occlusion_density_per_m(1.0, 465.0, 0.0, 320.0), 0.0);
    assert_eq!(occlusion_term_m(0.01, 0.0), None);
    // Degree is a fraction of rays: 0 ≤ O ≤ 1, even for absurd baselines.
    assert_eq!(occlusion_degree(rho, 1e12), 1.0);
    assert_eq!(occlusion_degree(0.0, 1e12), 0.0);
    assert_eq!(occlusion_degree(f64::INFINITY, 0.0), 1.0);
    // O_max = 1 (everything may be occluded): b = 1/ρ.
    assert!(close(occlusion_term_m(1.0, rho).unwrap(), 1.0 / rho, 1e-15));
}

#[test]
fn coverage_bound_from_nearest_depth() {
    // overlap 0.6, W = 640 (v_m 320), f = 465, nearest 20 m:
    // b = 0.4·640/(465·0.05) = 256/23.25 = 11.011 m = 0.4 × footprint (27.5 m).
    let b = coverage_m(0.6, 320.0, 465.0, 0.05).unwrap();
    assert!(close(b, 256.0 / 23.25, 1e-15));
    // Sky only (w_max = 0): coverage does not bound.
    assert_eq!(coverage_m(0.6, 320.0, 465.0, 0.0), None);
}

// ---- order statistics ----

#[test]
fn radix_selection_equals_sorting() {
    let mut sel = Selector::default();
    let mut s = 12345u64;
    for n in [1usize, 2, 3, 17, 1000, 4096] {
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = (s >> 33) as u32;
            v.push(match u % 10 {
                0 => INVALID,
                1 => SKY,
                // Spread over many binades, 1e-6 to 1e3, like 1 mm to 1e6 m depth.
                _ => 10f32.powf((u % 9000) as f32 / 1000.0 - 6.0),
            });
        }
        for include_sky in [false, true] {
            let mut good: Vec<f32> = v
                .iter()
                .copied()
                .filter(|&w| w > 0.0 || (include_sky && w == 0.0))
                .collect();
            good.sort_by(f32::total_cmp);
            if good.is_empty() {
                assert_eq!(sel.select2(&v, include_sky, [0, 0]), None);
                continue;
            }
            let [lo, hi] = percentile_ranks(good.len() as u64, 0.005, 0.995);
            let got = sel.select2(&v, include_sky, [lo, hi]).unwrap();
            assert_eq!(got, [good[lo as usize], good[hi as usize]], "n={n}");
            let last = good.len() as u64 - 1;
            assert_eq!(
                sel.select2(&v, include_sky, [0, last]).unwrap(),
                [good[0], good[last as usize]]
            );
        }
    }
}

#[test]
fn percentile_ranks_round_outwards() {
    // n = 1000: 0.005·999 = 4.995 → 4; 0.995·999 = 994.005 → 995.
    assert_eq!(percentile_ranks(1000, 0.005, 0.995), [4, 995]);
    assert_eq!(percentile_ranks(1, 0.005, 0.995), [0, 0]);
    assert_eq!(percentile_ranks(2, 0.0, 1.0), [0, 1]);
}

// ---- whole estimates ----

#[test]
fn two_level_scene_gives_design_mmds_and_occlusion_spacings() {
    // 640 px, hfov 69° → f = 320/tan(34.5°); rows half roof (20 m), half ground (40 m).
    let intr = Intrinsics::from_hfov_deg(640, 8, 69.0, None).unwrap();
    let f = intr.focal_px();
    let img = stripes(640, 8, 320, 20.0, 40.0);
    for pitch_deg in [0.0f64, 15.0, -30.0, 60.0] {
        let phi = pitch_deg.to_radians();
        let mut p = no_score();
        // One edge per row: O_max/ρ = O_max·2v_m/(f cos φ D) = 0.001·640/(f cos φ·0.025),
        // against MMDS 2/(f cos φ·0.025): the occlusion term binds (0.64 < 2).
        p.occlusion_max = 0.001;
        let e = run(&img, &intr, phi, &p);
        let dw = (1.0f32 / 20.0) as f64 - (1.0f32 / 40.0) as f64;
        let mmds = 2.0 / (f * phi.cos() * dw);
        let occ = 0.001 * 640.0 / (f * phi.cos() * dw);
        assert!(close(e.spacing.mmds_m.unwrap(), mmds, 1e-12), "{pitch_deg}");
        assert!(
            close(e.spacing.occlusion_m.unwrap(), occ, 1e-12),
            "{pitch_deg}"
        );
        assert_eq!(e.active_bound, Some(Bound::Occlusion));
        assert_eq!(e.spacing.chosen_m, e.spacing.occlusion_m);
        let o = e.occlusion.unwrap();
        assert_eq!((o.boundaries, o.lines), (8, 8));
        assert!(close(o.degree, 0.001, 1e-12));
        assert_eq!(e.terms.names(), vec!["mmds", "occlusion", "coverage"]);
    }
}

#[test]
fn many_edges_bind_at_the_default_occlusion_max() {
    // 32 stripes of 20 px: 31 edges per row of contrast 0.025. Default O_max 0.01:
    // occ = 0.01·640/(f·31·0.025) = 0.2065·(2/(f·0.025))·... i.e. MMDS × 3.2/31.
    // occ ≈ 0.0178 m, below the default 0.05 m floor: lower the floor to see the bound.
    let intr = Intrinsics::from_hfov_deg(640, 4, 69.0, None).unwrap();
    let mut p = no_score();
    p.spacing_min_m = 0.001;
    let e = run(&stripes(640, 4, 20, 20.0, 40.0), &intr, 0.0, &p);
    let ratio = e.spacing.occlusion_m.unwrap() / e.spacing.mmds_m.unwrap();
    assert!(close(ratio, 3.2 / 31.0, 1e-6), "{ratio}");
    assert_eq!(e.active_bound, Some(Bound::Occlusion));
}

#[test]
fn one_edge_does_not_bind_at_the_default() {
    // DESIGN: with O_max = 0.01 the bound binds only beyond 0.005·W full-contrast
    // edges per row (3.2 at 640 px); one edge leaves MMDS in charge.
    let intr = Intrinsics::from_hfov_deg(640, 4, 69.0, None).unwrap();
    let e = run(&stripes(640, 4, 320, 20.0, 40.0), &intr, 0.0, &no_score());
    assert_eq!(e.active_bound, Some(Bound::Mmds));
    assert_eq!(e.spacing.occlusion_m, e.spacing.mmds_m);
    assert!(e.terms.occlusion);
}

#[test]
fn scene_without_boundaries_is_exactly_mmds_and_has_no_occlusion_term() {
    // A smooth ramp in depth: neighbouring pixels differ by < 3 %, no boundary.
    let intr = Intrinsics::from_hfov_deg(200, 10, 60.0, None).unwrap();
    let row: Vec<f32> = (0..200).map(|i| 30.0 + 0.05 * i as f32).collect();
    let img = metres(200, 10, row.repeat(10));
    let e = run(
        &img,
        &intr,
        0.2,
        &EstimatorParams::with_model(Model::Occlusion),
    );
    let mut mm = EstimatorParams::with_model(Model::Occlusion);
    mm.model = Model::Mmds;
    let m = run(&img, &intr, 0.2, &mm);
    assert_eq!(e.occlusion.unwrap().boundaries, 0);
    assert!(!e.terms.occlusion && !e.terms.score);
    assert_eq!(e.spacing.occlusion_m, None);
    assert_eq!(
        e.spacing.chosen_m.unwrap().to_bits(),
        m.spacing.chosen_m.unwrap().to_bits()
    );
    assert_eq!(e.active_bound, m.active_bound);
    assert_eq!(e.best_pitch, None);
}

#[test]
fn pitch_extremes_are_typed_outcomes() {
    let intr = Intrinsics::from_hfov_deg(64, 4, 69.0, None).unwrap();
    let img = stripes(64, 4, 16, 20.0, 40.0);
    let p = EstimatorParams::with_model(Model::Occlusion);
    for deg in [80.0001f64, 89.999, 90.0, -90.0, 135.0, 1e9] {
        let e = run(&img, &intr, deg.to_radians(), &p);
        assert_eq!(
            e.no_estimate,
            Some(NoEstimate::PitchNearHorizontal),
            "{deg}"
        );
        assert_eq!(e.spacing.chosen_m, None);
    }
    for bad in [f64::NAN, f64::INFINITY] {
        assert_eq!(
            run(&img, &intr, bad, &p).no_estimate,
            Some(NoEstimate::InvalidPitch)
        );
    }
    // At the limit (80°) an answer, finite and positive: cos 80° = 0.17 widens it.
    let e = run(&img, &intr, 80f64.to_radians(), &p);
    let c = e.spacing.chosen_m.unwrap();
    assert!(c.is_finite() && c > 0.0);
}

#[test]
fn all_sky_falls_to_the_config_maximum() {
    let intr = Intrinsics::from_hfov_deg(32, 8, 90.0, None).unwrap();
    let e = run(
        &metres(32, 8, vec![f32::INFINITY; 256]),
        &intr,
        0.0,
        &EstimatorParams::with_model(Model::Occlusion),
    );
    assert!(e.is_ok());
    assert_eq!(e.inv_depth, None);
    assert_eq!(e.active_bound, Some(Bound::ConfigMax));
    assert_eq!(e.spacing.chosen_m, Some(100.0));
    assert_eq!(e.spacing.permissible_m, None);
    // With sky as scene: w = 0 everywhere, Δw = 0 and w_max = 0: still unbounded.
    let mut p = EstimatorParams::with_model(Model::Occlusion);
    p.sky_is_scene = true;
    let e = run(&metres(32, 8, vec![f32::INFINITY; 256]), &intr, 0.0, &p);
    assert_eq!(e.active_bound, Some(Bound::ConfigMax));
}

#[test]
fn flat_scene_is_bounded_by_coverage() {
    // Nadir over flat ground at 40 m: Δw = 0, MMDS unbounded; coverage
    // 0.4·W/(f/40) = 0.4·2·40·tan(45°) = 32 m at hfov 90°.
    let intr = Intrinsics::from_hfov_deg(100, 10, 90.0, None).unwrap();
    let e = run(
        &metres(100, 10, vec![40.0; 1000]),
        &intr,
        0.0,
        &EstimatorParams::with_model(Model::Occlusion),
    );
    assert_eq!(e.spacing.mmds_m, None);
    assert!(close(e.spacing.coverage_m.unwrap(), 32.0, 1e-6));
    assert_eq!(e.active_bound, Some(Bound::Coverage));
}

#[test]
fn single_pixel_and_invalid_frames() {
    let intr = Intrinsics::from_hfov_deg(1, 1, 60.0, None).unwrap();
    let e = run(
        &metres(1, 1, vec![10.0]),
        &intr,
        0.0,
        &EstimatorParams::with_model(Model::Occlusion),
    );
    assert!(e.is_ok());
    assert_eq!(e.occlusion.unwrap().boundaries, 0);
    // f = 0.5/tan 30° = 0.866 px: coverage 0.4·1/(0.866·0.1) = 4.62 m.
    assert!(close(
        e.spacing.coverage_m.unwrap(),
        0.4 / (0.5 / 30f64.to_radians().tan() * 0.1),
        1e-6
    ));
    for bad in [f32::NAN, 0.0, -3.0, f32::NEG_INFINITY] {
        let e = run(
            &metres(1, 1, vec![bad]),
            &intr,
            0.0,
            &EstimatorParams::with_model(Model::Occlusion),
        );
        assert_eq!(e.no_estimate, Some(NoEstimate::TooFewValidPixels), "{bad}");
        assert_eq!(e.valid_samples, 0);
    }
    // 85 % invalid with a 20 % floor: no estimate, and the fraction is reported.
    let mut d = vec![f32::NAN; 100];
    d[..15].fill(12.0);
    let intr = Intrinsics::from_hfov_deg(100, 1, 60.0, None).unwrap();
    let e = run(
        &metres(100, 1, d),
        &intr,
        0.0,
        &EstimatorParams::with_model(Model::Occlusion),
    );
    assert_eq!(e.no_estimate, Some(NoEstimate::TooFewValidPixels));
    assert!(close(e.valid_fraction, 0.15, 1e-12));
}

#[test]
fn extreme_fov_focal_and_depth_stay_finite() {
    for (w, fov) in [(640usize, 1.0f64), (640, 170.0), (1, 1.0), (1, 170.0)] {
        let intr = Intrinsics::from_hfov_deg(w, 2, fov, None).unwrap();
        for (d1, d2) in [
            (0.001f32, 0.002f32),
            (1e6, 5e5),
            (0.001, 1e6),
            (1.0, f32::INFINITY),
        ] {
            let img = stripes(w, 2, (w / 2).max(1), d1, d2);
            let e = run(
                &img,
                &intr,
                0.3,
                &EstimatorParams::with_model(Model::Occlusion),
            );
            let c = e.spacing.chosen_m.unwrap();
            assert!(c.is_finite() && c > 0.0, "fov {fov} d {d1}/{d2}: {c}");
            for x in [
                e.spacing.mmds_m,
                e.spacing.occlusion_m,
                e.spacing.coverage_m,
            ]
            .into_iter()
            .flatten()
            {
                assert!(x.is_finite() && x > 0.0);
            }
        }
    }
    for f in [10.0, 1e5] {
        let intr = Intrinsics::from_focal_px(64, 2, f, None).unwrap();
        let e = run(
            &stripes(64, 2, 8, 5.0, 9.0),
            &intr,
            0.0,
            &EstimatorParams::with_model(Model::Occlusion),
        );
        assert!(e.spacing.chosen_m.unwrap().is_finite());
    }
}

#[test]
fn fov_outside_range_is_rejected() {
    for bad in [0.0, 0.99, 170.01, f64::NAN, -10.0] {
        assert!(matches!(
            Intrinsics::from_hfov_deg(64, 48, bad, None),
            Err(IntrinsicsError::FovOutOfRange(_))
        ));
    }
    assert!(Intrinsics::from_focal_px(64, 48, 0.0, None).is_err());
}

#[test]
fn z16_and_metres_agree() {
    // Millimetre depths are exact in both encodings; scale 0.001 m.
    let intr = Intrinsics::from_hfov_deg(64, 4, 69.0, None).unwrap();
    let mm: Vec<u16> = (0..256)
        .map(|i| if (i / 8) % 2 == 0 { 20_000 } else { 40_000 })
        .collect();
    let z = DepthImage::new(
        64,
        4,
        DepthData::Z16 {
            data: mm.clone(),
            scale_m: 0.001,
        },
    )
    .unwrap();
    let m = metres(64, 4, mm.iter().map(|&v| v as f32 * 0.001).collect());
    let p = no_score();
    let (ez, em) = (run(&z, &intr, 0.1, &p), run(&m, &intr, 0.1, &p));
    assert!(close(
        ez.spacing.chosen_m.unwrap(),
        em.spacing.chosen_m.unwrap(),
        1e-6
    ));
    assert_eq!(
        ez.occlusion.unwrap().boundaries,
        em.occlusion.unwrap().boundaries
    );
    // 0 and u16::MAX are no return and saturation: invalid.
    let z = DepthImage::new(
        2,
        1,
        DepthData::Z16 {
            data: vec![0, u16::MAX],
            scale_m: 0.001,
        },
    )
    .unwrap();
    let intr = Intrinsics::from_hfov_deg(2, 1, 69.0, None).unwrap();
    assert_eq!(run(&z, &intr, 0.0, &p).valid_samples, 0);
}

#[test]
fn columns_along_track_equal_rows_transposed() {
    let (w, h) = (48usize, 32usize);
    let img = stripes(w, h, 6, 15.0, 35.0);
    let DepthData::Metres(d) = img.data() else {
        unreachable!()
    };
    let t: Vec<f32> = (0..w * h).map(|k| d[(k % h) * w + k / h]).collect();
    let timg = metres(h, w, t);
    let intr = Intrinsics::from_focal_px(w, h, 40.0, None).unwrap();
    let tintr = Intrinsics::from_focal_px(h, w, 40.0, None).unwrap();
    let mut p = no_score();
    p.track_axis = TrackAxis::Columns;
    let a = run(&img, &intr, 0.2, &no_score());
    let b = run(&timg, &tintr, 0.2, &p);
    assert_eq!(a.spacing, b.spacing);
    assert_eq!(a.occlusion, b.occlusion);
}

#[test]
fn invalid_shadow_beside_an_edge_is_bridged_up_to_max_gap() {
    // Stereo leaves a masked band beside occluders: 5 px gap is bridged (≤ 8),
    // a 20 px gap is not.
    let intr = Intrinsics::from_hfov_deg(100, 1, 60.0, None).unwrap();
    for (gap, expect) in [(5usize, 1u64), (20, 0)] {
        let mut row = vec![20.0f32; 50];
        row.extend(vec![f32::NAN; gap]);
        row.extend(vec![40.0f32; 50 - gap]);
        let e = run(&metres(100, 1, row), &intr, 0.0, &no_score());
        assert_eq!(e.occlusion.unwrap().boundaries, expect, "gap {gap}");
    }
}

#[test]
fn config_limits_clamp_and_say_so() {
    let intr = Intrinsics::from_hfov_deg(640, 2, 69.0, None).unwrap();
    let img = stripes(640, 2, 20, 20.0, 40.0);
    let mut p = no_score();
    p.spacing_min_m = 1.0; // the occlusion-aware spacing here is ~0.018 m
    let e = run(&img, &intr, 0.0, &p);
    assert_eq!(e.active_bound, Some(Bound::ConfigMin));
    assert_eq!(e.spacing.chosen_m, Some(1.0));
    assert!(e.spacing.permissible_m.unwrap() < 1.0);
    p.spacing_min_m = 0.001;
    p.spacing_max_m = 0.002;
    assert_eq!(
        run(&img, &intr, 0.0, &p).active_bound,
        Some(Bound::ConfigMax)
    );
    p.model = Model::Fixed;
    p.spacing_max_m = 100.0;
    let e = run(&img, &intr, 0.0, &p);
    assert_eq!(
        (e.active_bound, e.spacing.chosen_m),
        (Some(Bound::Fixed), Some(5.0))
    );
    assert!(!e.terms.occlusion);
}

#[test]
fn sspa_of_a_slanted_plane_recovers_its_range_and_ignores_occluders() {
    // A plane tilted along track: w = 0.03 + 0.01·x (x normalised), 200 px, f = 100:
    // x spans ±1 → w from 0.02 to 0.04, Δw_plane = 0.02.
    let (w, h, f) = (200usize, 20usize, 100.0);
    let intr = Intrinsics::from_focal_px(w, h, f, None).unwrap();
    let mut d = Vec::new();
    for _ in 0..h {
        for i in 0..w {
            let x = (i as f64 + 0.5 - 100.0) / f;
            d.push((1.0 / (0.03 + 0.01 * x)) as f32);
        }
    }
    // 5 % of pixels on a near occluder (w = 0.2): the trimmed fit ignores them.
    for k in (0..d.len()).step_by(20) {
        d[k] = 5.0;
    }
    let mut p = no_score();
    p.model = Model::Sspa;
    let e = run(&metres(w, h, d), &intr, 0.0, &p);
    let pl = e.plane.unwrap();
    assert!(
        close(pl.a, 0.01, 1e-4) && pl.b.abs() < 1e-6 && close(pl.c, 0.03, 1e-4),
        "{pl:?}"
    );
    assert!(close(pl.delta_w_per_m, 0.02, 1e-3));
    // Extent: from x = -1 at depth 50 (x·d = -50 m) to x = +1 at depth 25 (+25 m): 75 m
    // (inlier pixel centres reach x = ±0.995, so a little less).
    assert!(pl.extent_m > 73.0 && pl.extent_m <= 75.0, "{}", pl.extent_m);
    let want = 2.0 / (f * pl.delta_w_per_m + 4.0 / pl.extent_m);
    assert!(close(e.spacing.sspa_m.unwrap(), want, 1e-12));
    assert_eq!(e.active_bound, Some(Bound::Sspa));
    assert!(e.terms.sspa && !e.terms.occlusion);
}

#[test]
fn score_at_the_current_pitch_reproduces_the_direct_degree() {
    // Re-projection into the same pitch is the identity: the score's degree for
    // the candidate equal to the current pitch is the estimate's own degree.
    let intr = Intrinsics::from_hfov_deg(320, 16, 69.0, None).unwrap();
    let img = stripes(320, 16, 10, 20.0, 40.0);
    let mut p = EstimatorParams::with_model(Model::Occlusion);
    let phi = 10f64.to_radians();
    p.score = Some(ScoreParams {
        candidates_rad: vec![-phi, 0.0, phi],
        step_px: 1,
        min_coverage: 0.5,
    });
    let e = run(&img, &intr, phi, &p);
    let own = e.pitch_scores.iter().find(|s| s.pitch_rad == phi).unwrap();
    assert!(
        close(own.degree, e.occlusion.unwrap().degree, 1e-9),
        "{own:?} vs {:?}",
        e.occlusion
    );
    assert!(e.best_pitch.is_some() && e.terms.score);
}

#[test]
fn auto_decimation_picks_the_coarsest_level_within_budget() {
    let intr = Intrinsics::from_hfov_deg(320, 240, 69.0, None).unwrap();
    // Stripes every 40 px, and a frame of fine detail (every 3 px), where coarse
    // levels miss the far stripes: calibration must stop at a finer level there.
    let mut chosen = Vec::new();
    for img in [
        stripes(320, 240, 40, 20.0, 40.0),
        stripes(320, 240, 3, 20.0, 40.0),
    ] {
        let mut est = Estimator::new(no_score());
        let reference = est.estimate_at(&img, &intr, 0.0, 1).unwrap();
        // By brute force: every level's error, the coarsest within budget.
        let within = DECIMATION_LEVELS
            .iter()
            .copied()
            .filter(|&l| {
                let e = est.estimate_at(&img, &intr, 0.0, l).unwrap();
                relative_error(e.spacing.permissible_m, reference.spacing.permissible_m) <= 0.05
            })
            .max()
            .unwrap();
        let (e, c) = est
            .calibrate(&img, &intr, 0.0, 0.05, &DECIMATION_LEVELS)
            .unwrap();
        assert_eq!(c.level, within);
        assert_eq!(e.decimation, c.level);
        assert_eq!(c.errors[0], (1, 0.0));
        // Tried coarsest first, stopping at the first within budget.
        let tried: Vec<usize> = c.errors[1..].iter().map(|&(l, _)| l).collect();
        let expected: Vec<usize> = DECIMATION_LEVELS
            .iter()
            .rev()
            .copied()
            .filter(|&l| l > 1 && l >= within)
            .collect();
        assert_eq!(tried, expected);
        assert!(c.errors[1..c.errors.len() - 1]
            .iter()
            .all(|&(_, err)| err > 0.05));
        chosen.push(c.level);
    }
    assert!(chosen[1] < 16, "the fine frame stopped finer: {chosen:?}");
}

#[test]
fn auto_decimation_calibrates_once_a_second_not_on_every_frame() {
    let intr = Intrinsics::from_hfov_deg(320, 240, 69.0, None).unwrap();
    let img = stripes(320, 240, 40, 20.0, 40.0);
    let mut est = Estimator::new(EstimatorParams {
        decimation: Decimation::auto(),
        ..no_score()
    });
    let (first, choice) = est.estimate(&img, &intr, 0.0).unwrap();
    let level = choice.expect("the first frame calibrates").level;
    assert_eq!(first.decimation, level);
    // The next frames reuse the level (one estimate each), then it is calibrated again.
    for k in 0..AUTO_RECALIBRATE_FRAMES {
        let (e, c) = est.estimate(&img, &intr, 0.0).unwrap();
        assert!(c.is_none(), "frame {k} calibrated again");
        assert_eq!(e.decimation, level);
        assert_eq!(e.spacing.permissible_m, first.spacing.permissible_m);
    }
    assert!(est.estimate(&img, &intr, 0.0).unwrap().1.is_some());
    // A new frame size is calibrated at once.
    let intr2 = Intrinsics::from_hfov_deg(160, 120, 69.0, None).unwrap();
    let small = stripes(160, 120, 20, 20.0, 40.0);
    assert!(est.estimate(&small, &intr2, 0.0).unwrap().1.is_some());
    assert!(est.estimate(&small, &intr2, 0.0).unwrap().1.is_none());
}

#[test]
fn auto_decimation_recalibrates_after_its_configured_frames() {
    let intr = Intrinsics::from_hfov_deg(320, 240, 69.0, None).unwrap();
    let img = stripes(320, 240, 40, 20.0, 40.0);
    let mut est = Estimator::new(EstimatorParams {
        decimation: Decimation::Auto {
            budget: 0.05,
            levels: DECIMATION_LEVELS.to_vec(),
            recalibrate_frames: 3,
        },
        ..no_score()
    });
    let calibrated: Vec<bool> = (0..9)
        .map(|_| est.estimate(&img, &intr, 0.0).unwrap().1.is_some())
        .collect();
    assert_eq!(
        calibrated,
        [true, false, false, false, true, false, false, false, true]
    );
}

#[test]
fn size_mismatch_is_a_calling_error() {
    let intr = Intrinsics::from_hfov_deg(10, 10, 60.0, None).unwrap();
    let img = metres(5, 2, vec![1.0; 10]);
    assert!(Estimator::new(no_score())
        .estimate_at(&img, &intr, 0.0, 1)
        .is_err());
}

#[test]
fn default_params_validate_and_bad_ones_name_their_field() {
    assert_eq!(
        EstimatorParams::with_model(Model::Occlusion).validate(),
        Ok(())
    );
    let mut p = EstimatorParams::with_model(Model::Occlusion);
    p.occlusion_max = 0.0;
    assert_eq!(p.validate().unwrap_err().field, "sampling.occlusion_max");
    let mut p = EstimatorParams::with_model(Model::Occlusion);
    p.spacing_max_m = 0.01;
    assert_eq!(p.validate().unwrap_err().field, "sampling.spacing_max_m");
    let mut p = EstimatorParams::with_model(Model::Occlusion);
    p.pitch_max_rad = 1.6;
    assert_eq!(p.validate().unwrap_err().field, "estimator.pitch_max_deg");
}

#[test]
fn the_fixed_model_needs_no_valid_depth() {
    // A rig without a depth camera: every pixel invalid, the fixed spacing holds.
    let intr = Intrinsics::from_hfov_deg(4, 3, 69.0, None).unwrap();
    let img = metres(4, 3, vec![f32::NAN; 12]);
    let mut p = no_score();
    p.model = Model::Fixed;
    p.fixed_spacing_m = 2.5;
    let e = run(&img, &intr, 0.0, &p);
    assert!(e.no_estimate.is_none(), "{:?}", e.no_estimate);
    assert_eq!(e.spacing.chosen_m, Some(2.5));
    // Any other model says why it has nothing.
    p.model = Model::Mmds;
    let e = run(&img, &intr, 0.0, &p);
    assert_eq!(e.no_estimate, Some(NoEstimate::TooFewValidPixels));
    assert_eq!(e.spacing.chosen_m, None);
    let none = Estimate::without_depth(f64::NAN);
    assert_eq!(none.no_estimate, Some(NoEstimate::NoDepthFrame));
    assert!(none.spacing.chosen_m.is_none() && none.pitch_rad == 0.0);
}

// ---- ground beyond the range (no return below the horizon) ----

fn z16(w: usize, h: usize, data: Vec<u16>, scale_m: f64) -> DepthImage {
    DepthImage::new(w, h, DepthData::Z16 { data, scale_m }).unwrap()
}

#[test]
fn ground_beyond_the_range_below_the_horizon_is_far_not_sky() {
    // Nadir over a 20 m roof on the upper half; the lower half is ground 600 m
    // away, beyond the sensor: Z16 0. Ignored, as before, the frame holds one
    // depth, a span of 0 and no parallax bound at all (the spacing then comes
    // from the other targets: silently too long). Now the far end is at
    // infinity: span 1/20 per m, the parallax bound `px/(f/20)`.
    let (w, h) = (64usize, 48usize);
    let intr = Intrinsics::from_hfov_deg(w, h, 69.0, None).unwrap();
    let f = intr.focal_px();
    let p = EstimatorParams::with_model(Model::Quality);
    let px = p.quality.parallax_px.unwrap();
    let frame = |far: u16| {
        let data: Vec<u16> = (0..w * h)
            .map(|k| if k / w < h / 2 { 2000 } else { far })
            .collect();
        z16(w, h, data, 0.01)
    };
    let e = run(&frame(0), &intr, 0.0, &p);
    assert!(e.is_ok(), "{:?}", e.no_estimate);
    assert_eq!(e.far_below_samples, w * h / 2);
    assert!(e.terms.beyond_range);
    assert!(e.terms.names().contains(&"beyond_range"));
    assert_eq!(e.inv_depth.unwrap().min_per_m, 0.0);
    let b = e
        .spacing
        .parallax_m
        .expect("the far end bounds the parallax");
    assert!(
        close(b, px / (f / 20.0), 1e-5),
        "{b} vs {}",
        px / (f / 20.0)
    );
    // The truth, had the sensor reached it (600 m, inside 655 m of Z16 range):
    // a span of 1/20 − 1/600, so the spacing assumed is short of it by 1/30,
    // never longer.
    let t = run(&frame(60000), &intr, 0.0, &p);
    assert_eq!((t.far_below_samples, t.terms.beyond_range), (0, false));
    let bt = t.spacing.parallax_m.unwrap();
    assert!(
        b <= bt && b >= bt * (1.0 - 1.0 / 30.0 - 1e-6),
        "{b} vs {bt}"
    );
    // A metric frame past the configured range says the same.
    let mut pr = p.clone();
    pr.depth_range.max_m = 65.0;
    let m = metres(
        w,
        h,
        (0..w * h)
            .map(|k| if k / w < h / 2 { 20.0 } else { 600.0 })
            .collect(),
    );
    let em = run(&m, &intr, 0.0, &pr);
    assert_eq!(em.far_below_samples, w * h / 2);
    assert!(close(em.spacing.parallax_m.unwrap(), b, 1e-6));
}

#[test]
fn no_return_above_the_horizon_is_sky() {
    // Pitched 70° forward with 90° along track: rays past t = cot 70° = 0.36
    // look above the horizon. No return there is sky (or a tower out of
    // range): it stays out of the depth range, as a metric frame's +inf does.
    let (w, h) = (80usize, 20usize);
    let intr = Intrinsics::from_hfov_deg(w, h, 90.0, None).unwrap();
    let f = intr.focal_px();
    let pitch = 70f64.to_radians();
    let above = |i: usize| (i as f64 + 0.5 - w as f64 / 2.0) / f > 0.5;
    let depth = |i: usize| 30.0 + i as f32 * 0.25;
    let z: Vec<u16> = (0..w * h)
        .map(|k| {
            let i = k % w;
            if above(i) {
                0
            } else {
                (depth(i) * 100.0).round() as u16
            }
        })
        .collect();
    let m: Vec<f32> = (0..w * h)
        .map(|k| {
            let i = k % w;
            if above(i) {
                f32::INFINITY
            } else {
                (depth(i) * 100.0).round() / 100.0
            }
        })
        .collect();
    let p = EstimatorParams::with_model(Model::Quality);
    let ez = run(&z16(w, h, z, 0.01), &intr, pitch, &p);
    let em = run(&metres(w, h, m), &intr, pitch, &p);
    assert!(ez.is_ok() && em.is_ok());
    assert_eq!((ez.far_below_samples, ez.terms.beyond_range), (0, false));
    assert!(!ez.terms.names().contains(&"beyond_range"));
    let (a, b) = (
        ez.spacing.parallax_m.unwrap(),
        em.spacing.parallax_m.unwrap(),
    );
    assert!(close(a, b, 1e-5), "{a} vs {b}");
}

#[test]
fn no_return_within_the_percentile_tail_leaves_the_range_alone() {
    // Stripes at 20 m and 40 m with 2 pixels in 1000 without a return: fewer
    // than the 0.5 % tail the robust range drops, so the range is the
    // stripes' and the far end stays finite; the samples are still counted.
    let (w, h) = (100usize, 10usize);
    let intr = Intrinsics::from_hfov_deg(w, h, 69.0, None).unwrap();
    let p = EstimatorParams::with_model(Model::Quality);
    let clean: Vec<u16> = (0..w * h)
        .map(|k| if (k % w / 10) % 2 == 0 { 2000 } else { 4000 })
        .collect();
    let mut holes = clean.clone();
    holes[17] = 0;
    holes[555] = 0;
    let a = run(&z16(w, h, clean, 0.01), &intr, 0.0, &p);
    let b = run(&z16(w, h, holes, 0.01), &intr, 0.0, &p);
    assert_eq!((b.far_below_samples, b.terms.beyond_range), (2, false));
    assert_eq!(a.inv_depth, b.inv_depth);
    assert_eq!(a.spacing.parallax_m, b.spacing.parallax_m);
    assert!(b.spacing.parallax_m.is_some());
}

/// The estimator hands the refresh the frame's other bounds: the same frames
/// (a scene, then closer by a tenth: every interval a tenth shorter, the same
/// share occluded) sweep every line where the views spacing can decide the
/// spacing (a loose parallax target) and keep the turn where the parallax
/// bound is far below it.
#[test]
fn a_flights_refresh_weighs_the_views_spacing_against_the_frames_other_bounds() {
    let intr = Intrinsics::from_hfov_deg(160, 120, 69.0, None).unwrap();
    let far = stripes(160, 120, 40, 20.0, 40.0);
    let near = stripes(160, 120, 40, 18.0, 36.0);
    let flight = |parallax_px: f64| {
        let mut params = EstimatorParams {
            visibility_interleave: 2,
            score: None,
            ..EstimatorParams::default()
        };
        params.quality.parallax_px = Some(parallax_px);
        params.validate().unwrap();
        let mut est = Estimator::new(params);
        for _ in 0..2 {
            est.estimate(&far, &intr, 0.0).unwrap();
        }
        let e = est.estimate(&near, &intr, 0.0).unwrap().0;
        let v = e.visibility.expect("the quality model sweeps");
        (e, v.interleave)
    };
    let others = |e: &Estimate| {
        let s = &e.spacing;
        [s.parallax_m, s.forward_overlap_m, s.coverage_m]
            .into_iter()
            .flatten()
            .reduce(f64::min)
            .unwrap()
    };
    let (tight, kept) = flight(2.0);
    let views = tight.spacing.views_m.unwrap();
    // Far above the others, and beyond the margin and the spread (1/0.9).
    assert!(views > others(&tight) * 1.05 / 0.9 * 2.0, "{tight:?}");
    assert_eq!(kept, 2, "the parallax bound decides: the turn alone");
    let (loose, refreshed) = flight(1e4);
    assert!(loose.spacing.views_m.unwrap() < others(&loose), "{loose:?}");
    assert_eq!(refreshed, 1, "the views spacing decides: every line");
}

#[test]
fn a_flights_sweep_spread_over_frames_takes_each_line_from_its_newest_frame_and_holds_the_shortest_interval_two_turns(
) {
    let intr = Intrinsics::from_hfov_deg(160, 120, 69.0, None).unwrap();
    // Stripes across track (every line alike): a narrow one has the shorter
    // shortest interval.
    let (wide, narrow) = (
        stripes(160, 120, 40, 20.0, 40.0),
        stripes(160, 120, 8, 20.0, 40.0),
    );
    let params = EstimatorParams {
        visibility_interleave: 2,
        score: None,
        ..EstimatorParams::default()
    };
    params.validate().unwrap();
    let alone = |img: &DepthImage| {
        Estimator::new(params.clone())
            .estimate_at(img, &intr, 0.0, 1)
            .unwrap()
    };
    let vis = |e: &Estimate| e.visibility.expect("the quality model sweeps");
    let (w, n) = (alone(&wide), alone(&narrow));
    let (w_min, n_min) = (
        vis(&w).interval_min_m.unwrap(),
        vis(&n).interval_min_m.unwrap(),
    );
    assert!(n_min < w_min, "{n_min} {w_min}");
    let mut est = Estimator::new(params.clone());
    // The first frame sweeps every line.
    let first = est.estimate(&narrow, &intr, 0.0).unwrap().0;
    assert_eq!(first, n);
    assert_eq!(vis(&first).interleave, 1);
    // The daemon sets the axis on every frame: the same axis keeps the turn.
    est.set_track_axis(TrackAxis::Rows);
    // A frame estimated alone in between leaves the flight's sweep alone.
    assert_eq!(est.estimate_at(&wide, &intr, 0.0, 1).unwrap(), w);
    // Half the lines of the wide frame, half still the narrow one's.
    let second = est.estimate(&wide, &intr, 0.0).unwrap().0;
    assert_eq!(vis(&second).interleave, 2);
    assert_eq!(vis(&second).interval_min_m, Some(n_min));
    assert_eq!(vis(&second).samples, vis(&w).samples);
    // Every line is the wide frame's now, but the shortest interval the first
    // frame found holds for 2 × 2 frames: the views spacing stays the narrow
    // one's, the unseen fraction (the occluded samples) is the wide one's.
    for held in 2..4 {
        let e = est.estimate(&wide, &intr, 0.0).unwrap().0;
        assert_eq!(vis(&e).interval_min_m, Some(n_min), "frame {held}");
        assert_eq!(e.spacing.views_m, n.spacing.views_m, "frame {held}");
        assert_eq!(vis(&e).occluded_samples, vis(&w).occluded_samples);
        assert_eq!(e.spacing.unseen_m, w.spacing.unseen_m);
    }
    let third = est.estimate(&wide, &intr, 0.0).unwrap().0;
    assert_eq!(vis(&third).interval_min_m, Some(w_min));
    assert_eq!(third.spacing, w.spacing);
    // Narrow again: the lines swept came out tighter than on their last sweep
    // (wide), so the kept ones are stale too and every line is swept.
    let fourth = est.estimate(&narrow, &intr, 0.0).unwrap().0;
    assert_eq!(vis(&fourth).interleave, 1);
    assert_eq!(fourth, n);
    // Without the refresh, half the lines are still the wide frame's.
    let mut kept = Estimator::new(EstimatorParams {
        visibility_refresh: false,
        ..params.clone()
    });
    for img in [&narrow, &wide, &wide] {
        kept.estimate(img, &intr, 0.0).unwrap();
    }
    let stale = kept.estimate(&narrow, &intr, 0.0).unwrap().0;
    assert_eq!(vis(&stale).interleave, 2);
    assert_ne!(vis(&stale).occluded_samples, vis(&n).occluded_samples);
    // Loosening never sweeps every line: wide after narrow keeps the turn.
    let fifth = est.estimate(&wide, &intr, 0.0).unwrap().0;
    assert_eq!(vis(&fifth).interleave, 2);
    // Another axis starts again from every line.
    est.set_track_axis(TrackAxis::Columns);
    let turned = est.estimate(&narrow, &intr, 0.0).unwrap().0;
    assert_eq!(vis(&turned).interleave, 1);
}
