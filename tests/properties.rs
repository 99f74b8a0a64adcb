//! Property tests of the estimator over random maps, pitches, fields of view,
//! focal lengths and invalid fractions. Cases per property: `ALFD_PROPTEST_CASES`
//! (default 100000, which CI runs); `ALFD_PROPTEST_CASES=1000000` is the long run.

use alfd::core::params::ScoreParams;
use alfd::core::{
    Bound, DepthData, DepthImage, Estimate, Estimator, EstimatorParams, Intrinsics, Model, Profile,
};
use proptest::prelude::*;

fn cases() -> u32 {
    std::env::var("ALFD_PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000)
}

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: cases(),
        max_shrink_iters: 2000,
        ..ProptestConfig::default()
    }
}

/// Depth in metres, log-uniform over 1 mm to 1e6 m, or a special value.
fn depth() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => (-3.0f64..6.0).prop_map(|e| 10f64.powf(e) as f32),
        1 => Just(f32::INFINITY),
        1 => prop_oneof![Just(f32::NAN), Just(0.0f32), Just(-1.0f32), Just(f32::NEG_INFINITY)],
    ]
}

#[derive(Debug, Clone)]
struct Case {
    w: usize,
    h: usize,
    depth: Vec<f32>,
    intr: Intrinsics,
    pitch_rad: f64,
}

fn intrinsics(w: usize, h: usize) -> impl Strategy<Value = Intrinsics> {
    prop_oneof![
        (1.0f64..=170.0).prop_map(move |fov| Intrinsics::from_hfov_deg(w, h, fov, None).unwrap()),
        (1.0f64..5.0)
            .prop_map(move |e| Intrinsics::from_focal_px(w, h, 10f64.powf(e), None).unwrap()),
    ]
}

/// A random map: a few depth levels in random blocks, random invalid pixels.
fn random_case() -> impl Strategy<Value = Case> {
    (1usize..=48, 1usize..=24)
        .prop_flat_map(|(w, h)| {
            (
                Just(w),
                Just(h),
                proptest::collection::vec(depth(), 1..6),
                proptest::collection::vec(0usize..6, w * h),
                0.0f64..1.0,
                proptest::collection::vec(0.0f64..1.0, w * h),
                intrinsics(w, h),
                prop_oneof![9 => -85.0f64..85.0, 1 => -400.0f64..400.0],
            )
        })
        .prop_map(
            |(w, h, levels, pick, invalid_frac, coin, intr, pitch_deg)| {
                let depth = pick
                    .iter()
                    .zip(&coin)
                    .map(|(&k, &c)| {
                        if c < invalid_frac {
                            f32::NAN
                        } else {
                            levels[k % levels.len()]
                        }
                    })
                    .collect();
                Case {
                    w,
                    h,
                    depth,
                    intr,
                    pitch_rad: pitch_deg.to_radians(),
                }
            },
        )
}

fn run(c: &Case, params: &EstimatorParams) -> Estimate {
    let img = DepthImage::new(c.w, c.h, DepthData::Metres(c.depth.clone())).unwrap();
    Estimator::new(params.clone())
        .estimate_at(&img, &c.intr, c.pitch_rad, 1)
        .unwrap()
}

fn all_params() -> EstimatorParams {
    EstimatorParams {
        with_sspa: true,
        score: Some(ScoreParams {
            candidates_rad: (-4..=4).map(|k| (k as f64 * 20.0).to_radians()).collect(),
            step_px: 1,
            min_coverage: 0.3,
        }),
        ..EstimatorParams::with_model(Model::Occlusion)
    }
}

fn finite_nonneg(x: f64) -> bool {
    x.is_finite() && x >= 0.0
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn every_output_is_finite_and_non_negative(c in random_case()) {
        let p = all_params();
        let e = run(&c, &p);
        prop_assert!((0.0..=1.0).contains(&e.valid_fraction));
        let s = e.spacing;
        for x in [s.mmds_m, s.sspa_m, s.occlusion_m, s.coverage_m, s.permissible_m, s.chosen_m].into_iter().flatten() {
            prop_assert!(x.is_finite() && x > 0.0, "{:?}", s);
        }
        if e.is_ok() {
            let chosen = s.chosen_m.unwrap();
            prop_assert!(chosen >= p.spacing_min_m && chosen <= p.spacing_max_m);
            prop_assert!(e.active_bound.is_some());
        } else {
            prop_assert!(s.chosen_m.is_none());
        }
        if let Some(i) = e.inv_depth {
            prop_assert!(finite_nonneg(i.min_per_m) && finite_nonneg(i.max_per_m) && i.min_per_m <= i.max_per_m);
        }
        if let Some(o) = e.occlusion {
            prop_assert!(finite_nonneg(o.density_per_m) && finite_nonneg(o.contrast_per_m));
            prop_assert!((0.0..=1.0).contains(&o.degree));
        }
        if let Some(pl) = e.plane {
            prop_assert!(finite_nonneg(pl.delta_w_per_m) && pl.extent_m.is_finite() && pl.extent_m > 0.0);
        }
        for sc in &e.pitch_scores {
            prop_assert!(sc.pitch_rad.is_finite() && (0.0..=1.0).contains(&sc.degree));
        }
    }

    /// The quality model (issue 13): every spacing finite and positive, and
    /// the chosen one keeps every target by the frame's own prediction (unless
    /// the config's floor lifted it above them).
    #[test]
    fn quality_model_keeps_every_target_it_predicts(
        c in random_case(),
        mapping in any::<bool>(),
    ) {
        let profile = if mapping { Profile::Mapping } else { Profile::Lightfield };
        let p = EstimatorParams {
            score: None,
            quality: profile.targets(),
            ..EstimatorParams::with_model(Model::Quality)
        };
        let e = run(&c, &p);
        let s = e.spacing;
        for x in [s.parallax_m, s.forward_overlap_m, s.unseen_m, s.views_m, s.coverage_m, s.chosen_m].into_iter().flatten() {
            prop_assert!(x.is_finite() && x > 0.0, "{:?}", s);
        }
        if !e.is_ok() {
            prop_assert!(e.quality.is_none() && s.chosen_m.is_none());
            return Ok(());
        }
        let chosen = s.chosen_m.unwrap();
        let q = e.quality.expect("the quality model says its targets");
        prop_assert_eq!(q.targets, p.quality);
        if let Some(px) = q.parallax_px { prop_assert!(finite_nonneg(px)); }
        if let Some(o) = q.forward_overlap { prop_assert!((0.0..=1.0).contains(&o)); }
        if let Some(u) = q.unseen_fraction { prop_assert!((0.0..=1.0).contains(&u)); }
        if e.active_bound == Some(Bound::ConfigMin) {
            return Ok(());
        }
        for x in [s.parallax_m, s.forward_overlap_m, s.unseen_m, s.views_m, s.coverage_m].into_iter().flatten() {
            prop_assert!(chosen <= x, "chosen {chosen} above a target's {x}: {:?}", s);
        }
        let t = q.targets;
        if let (Some(px), Some(target)) = (q.parallax_px, t.parallax_px) {
            prop_assert!(px <= target * (1.0 + 1e-9), "parallax {px} px");
        }
        if let (Some(o), Some(target), Some(_)) = (q.forward_overlap, t.forward_overlap, s.forward_overlap_m) {
            prop_assert!(o >= target - 1e-9, "overlap {o}");
        }
        if let Some(u) = q.unseen_fraction {
            prop_assert!(u <= t.unseen_fraction_max, "unseen {u}");
        }
        if let (Some(k), Some(_)) = (q.views_per_point, s.views_m) {
            prop_assert!(k >= t.views_per_point_min, "{k} views");
        }
    }

    #[test]
    fn occlusion_aware_spacing_never_exceeds_mmds(c in random_case()) {
        let p = EstimatorParams { score: None, ..EstimatorParams::with_model(Model::Occlusion) };
        let occ = run(&c, &p);
        let mm = run(&c, &EstimatorParams { model: Model::Mmds, ..p.clone() });
        if let (Some(o), Some(m)) = (occ.spacing.occlusion_m, occ.spacing.mmds_m) {
            prop_assert!(o <= m);
        }
        match (occ.spacing.chosen_m, mm.spacing.chosen_m) {
            (Some(o), Some(m)) => prop_assert!(o <= m, "occlusion {o} > mmds {m}"),
            (None, None) => {}
            other => prop_assert!(false, "one model answered and not the other: {:?}", other),
        }
    }
}

/// Maps with no edge: a random walk in log depth with steps under 1 %, below the
/// 3 % relative threshold, so no pair of neighbours is a boundary.
fn smooth_case() -> impl Strategy<Value = Case> {
    (1usize..=48, 1usize..=24)
        .prop_flat_map(|(w, h)| {
            (
                Just(w),
                Just(h),
                (-2.0f64..5.0),
                proptest::collection::vec(-0.0099f64..0.0099, w * h),
                intrinsics(w, h),
                -80.0f64..80.0,
            )
        })
        .prop_map(|(w, h, log_d0, steps, intr, pitch_deg)| {
            let mut depth = Vec::with_capacity(w * h);
            for r in 0..h {
                let mut d = 10f64.powf(log_d0) * (1.0 + steps[r * w]);
                for i in 0..w {
                    d *= 1.0 + steps[r * w + i];
                    depth.push(d as f32);
                }
            }
            Case {
                w,
                h,
                depth,
                intr,
                pitch_rad: pitch_deg.to_radians(),
            }
        })
}

/// A background scene and a rectangular occluder in front of all of it,
/// covering at most half the map, at a sequence of ever nearer depths.
fn occluder_case() -> impl Strategy<Value = (Case, (usize, usize, usize, usize), Vec<f32>)> {
    (2usize..=48, 1usize..=24)
        .prop_flat_map(|(w, h)| {
            (
                Just(w),
                Just(h),
                proptest::collection::vec(1.0f64..3.0, w * h),
                intrinsics(w, h),
                -80.0f64..80.0,
                (0..w, 0..h, 1..=w, 1..=h),
                proptest::collection::vec(0.01f64..0.99, 1..8),
            )
        })
        .prop_map(
            |(w, h, bg_log, intr, pitch_deg, (x0, y0, rw, rh), mut fracs)| {
                let depth: Vec<f32> = bg_log.iter().map(|&e| 10f64.powf(e) as f32).collect();
                let nearest = depth.iter().cloned().fold(f32::INFINITY, f32::min);
                let rw = rw.min(w - x0);
                let rh = rh.min(h - y0).min(((w * h) / 2 / rw).max(1));
                // Decreasing depths, all in front of the nearest background point.
                fracs.sort_by(|a, b| b.total_cmp(a));
                let seq = fracs.iter().map(|f| nearest * *f as f32).collect();
                (
                    Case {
                        w,
                        h,
                        depth,
                        intr,
                        pitch_rad: pitch_deg.to_radians(),
                    },
                    (x0, y0, rw, rh),
                    seq,
                )
            },
        )
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn scene_without_boundaries_gives_exactly_mmds(c in smooth_case()) {
        let p = EstimatorParams { score: None, ..EstimatorParams::with_model(Model::Occlusion) };
        let occ = run(&c, &p);
        let mm = run(&c, &EstimatorParams { model: Model::Mmds, ..p.clone() });
        prop_assert_eq!(occ.occlusion.map(|o| o.boundaries), Some(0));
        prop_assert!(!occ.terms.occlusion);
        prop_assert_eq!(occ.spacing.chosen_m.map(f64::to_bits), mm.spacing.chosen_m.map(f64::to_bits));
        prop_assert_eq!(occ.active_bound, mm.active_bound);
    }

    #[test]
    fn spacing_shrinks_as_occluder_contrast_grows((c, rect, seq) in occluder_case()) {
        let p = EstimatorParams { score: None, ..EstimatorParams::with_model(Model::Occlusion) };
        let (x0, y0, rw, rh) = rect;
        let mut last: Option<(f64, f64)> = None;
        for &df in &seq {
            let mut cc = c.clone();
            for y in y0..y0 + rh {
                for x in x0..x0 + rw {
                    cc.depth[y * c.w + x] = df;
                }
            }
            let e = run(&cc, &p);
            let perm = e.spacing.permissible_m.unwrap_or(f64::INFINITY);
            let occ = e.spacing.occlusion_m.unwrap_or(f64::INFINITY);
            if let Some((lp, lo)) = last {
                prop_assert!(perm <= lp, "permissible grew from {lp} to {perm} at occluder depth {df}");
                prop_assert!(occ <= lo, "occlusion term grew from {lo} to {occ} at occluder depth {df}");
            }
            last = Some((perm, occ));
        }
    }
}

/// A Z16 frame (1 cm units, 1–600 m) in random blocks, a random share of its pixels without
/// a return (0), and a pitch: 9 in 10 at nadir, where the comparison below is exact.
fn no_return_case() -> impl Strategy<Value = (usize, usize, Vec<u16>, Intrinsics, f64)> {
    (1usize..=48, 1usize..=24)
        .prop_flat_map(|(w, h)| {
            (
                Just(w),
                Just(h),
                proptest::collection::vec(100u16..=60_000, 1..5),
                proptest::collection::vec(0usize..5, w * h),
                0.0f64..0.8,
                proptest::collection::vec(0.0f64..1.0, w * h),
                intrinsics(w, h),
                prop_oneof![9 => Just(0.0f64), 1 => -80.0f64..80.0],
            )
        })
        .prop_map(|(w, h, levels, pick, far_frac, coin, intr, pitch_deg)| {
            let z = pick
                .iter()
                .zip(&coin)
                .map(|(&k, &c)| {
                    if c < far_frac {
                        0
                    } else {
                        levels[k % levels.len()]
                    }
                })
                .collect();
            (w, h, z, intr, pitch_deg.to_radians())
        })
}

proptest! {
    #![proptest_config(config())]

    /// Ground beyond the range (issue 13's blind spot): no-return pixels below the horizon
    /// are counted exactly, never make a number non-finite, and put the depth range's far
    /// end at infinity only when they outnumber the low percentile's tail. At nadir, the
    /// spacing over every pixel they give is never longer than if those pixels had returned
    /// a depth beyond every other one (650 m): treating them as far can only shorten it,
    /// never leave the span understated. The spacing flown, over the pixels both captures
    /// keep in frame, is never shorter than the one over every pixel.
    #[test]
    fn no_return_below_the_horizon_never_lengthens_the_spacing(
        (w, h, z, intr, pitch) in no_return_case()
    ) {
        let p = EstimatorParams { score: None, ..EstimatorParams::with_model(Model::Quality) };
        let frame = |data: Vec<u16>| {
            DepthImage::new(w, h, DepthData::Z16 { data, scale_m: 0.01 }).unwrap()
        };
        let e = Estimator::new(p.clone()).estimate_at(&frame(z.clone()), &intr, pitch, 1).unwrap();
        let zeros = z.iter().filter(|&&v| v == 0).count();
        prop_assert!(e.far_below_samples <= zeros);
        if pitch == 0.0 {
            prop_assert_eq!(e.far_below_samples, zeros);
        }
        prop_assert_eq!(e.terms.names().contains(&"beyond_range"), e.terms.beyond_range);
        let s = e.spacing;
        for x in [s.parallax_m, s.views_m, s.coverage_m, s.mmds_m, s.permissible_m, s.chosen_m].into_iter().flatten() {
            prop_assert!(x.is_finite() && x > 0.0, "{:?}", s);
        }
        if let Some(i) = e.inv_depth {
            prop_assert!(finite_nonneg(i.min_per_m) && i.min_per_m <= i.max_per_m);
            if e.terms.beyond_range {
                prop_assert_eq!(i.min_per_m, 0.0);
            }
        }
        if pitch == 0.0 && e.is_ok() {
            let returned: Vec<u16> = z.iter().map(|&v| if v == 0 { 65_000 } else { v }).collect();
            let r = Estimator::new(p.clone()).estimate_at(&frame(returned), &intr, pitch, 1).unwrap();
            // The spacing over every pixel: the parallax target over the depth
            // range, before any pixel a step would take out of frame is left
            // out. The spacing flown is that set's (the truth's pixel set),
            // where a no-return pixel (infinitely far, it never moves) and a
            // 650 m one (it leaves the frame on a long enough step) are no
            // longer the same pixel, so the comparison is made here.
            let px = p.quality.parallax_px.unwrap();
            let all = |e: &alfd::core::Estimate| {
                e.inv_depth.map_or(f64::INFINITY, |i| px / (intr.focal_px() * (i.max_per_m - i.min_per_m)))
            };
            let (far, near) = (all(&e), all(&r));
            prop_assert!(far <= near * (1.0 + 1e-12), "{far} m with no return, {near} m with 650 m");
            for (e, all) in [(&e, far), (&r, near)] {
                let flown = e.spacing.parallax_m.unwrap_or(f64::INFINITY);
                prop_assert!(flown >= all * (1.0 - 1e-12), "{flown} m in frame, {all} m over every pixel");
            }
        }
    }
}

/// A closed-loop view: a random map as the estimator's cases, kept every
/// `step` pixels, under any attitude (roll, pitch and yaw over the whole
/// circle, ±90° pitch exactly among them) at a position a few metres from the
/// origin or exactly on it (two views in one place).
fn closed_loop_view() -> impl Strategy<Value = alfd::core::closedloop::View> {
    let angle = prop_oneof![
        6 => -std::f64::consts::PI..std::f64::consts::PI,
        1 => Just(std::f64::consts::FRAC_PI_2),
        1 => Just(-std::f64::consts::FRAC_PI_2),
        1 => Just(0.0),
    ];
    let coord = prop_oneof![3 => -5.0f64..5.0, 1 => Just(0.0)];
    (
        random_case(),
        1usize..=3,
        (angle.clone(), angle.clone(), angle),
        (coord.clone(), coord.clone(), coord),
    )
        .prop_map(|(c, step, (roll, pitch, yaw), (x, y, z))| {
            let img = DepthImage::new(c.w, c.h, DepthData::Metres(c.depth)).unwrap();
            alfd::core::closedloop::View {
                depth: alfd::core::closedloop::DepthSnapshot::new(&img, &c.intr, step),
                cam_to_ned: glam::DMat3::from_euler(glam::EulerRot::ZYX, yaw, pitch, roll),
                pos_ned_m: glam::DVec3::new(x, y, z),
            }
        })
}

fn unit(x: f64) -> bool {
    (0.0..=1.0).contains(&x)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases() / 4, ..config() })]

    /// The closed loop on any maps (sky, invalid and negative depths, 1 mm to
    /// 1000 km), any attitudes (±90° pitch, upside down), any focal length the
    /// estimator takes, views in one place or apart, odometer steps of zero,
    /// huge or not a number: every measure is a fraction in [0, 1] or a
    /// finite non-negative number, a spacing only with the bound that set it,
    /// never NaN.
    #[test]
    fn the_closed_loop_never_gives_nan(
        a in closed_loop_view(),
        m in closed_loop_view(),
        b in closed_loop_view(),
        d_m in prop_oneof![3 => 0.0f64..50.0, 1 => Just(0.0), 1 => Just(1e12)],
        step_m in prop_oneof![3 => 0.0f64..5.0, 1 => Just(f64::NAN), 1 => Just(f64::INFINITY)],
        parallax_px in prop_oneof![3 => (0.01f64..100.0).prop_map(Some), 1 => Just(None)],
        unseen_max in prop_oneof![0.0f64..1.0, Just(0.0), Just(1.0)],
    ) {
        use alfd::core::closedloop::{pair, unseen_fraction, ClosedLoop, ClosedLoopTargets};
        let p = pair(&a, &b);
        prop_assert!(p.parallax_span_px.is_none_or(finite_nonneg), "{p:?}");
        prop_assert!(unit(p.in_view_fraction) && unit(p.hidden_fraction), "{p:?}");
        prop_assert!(p.samples as usize <= b.depth.depth_m.len());
        let u = unseen_fraction(&m, &a, &b);
        prop_assert!(unit(u), "{u}");

        let targets = ClosedLoopTargets { parallax_px, unseen_fraction_max: unseen_max };
        let mut cl = ClosedLoop::default();
        prop_assert!(cl.on_frame(a.clone(), 0.0, step_m, &targets).is_none());
        cl.on_capture(a, 0.0);
        for (view, odo) in [(m, 0.5 * d_m), (b, d_m)] {
            let r = cl.on_frame(view, odo, step_m, &targets).expect("a capture to measure against");
            prop_assert!(finite_nonneg(r.distance_m), "{r:?}");
            prop_assert!(r.parallax_px.is_none_or(finite_nonneg), "{r:?}");
            prop_assert!(unit(r.unseen_fraction) && unit(r.in_view_fraction), "{r:?}");
            prop_assert!(r.spacing_m.is_none_or(finite_nonneg), "{r:?}");
            prop_assert_eq!(r.spacing_m.is_some(), r.bound.is_some());
            // Past the unseen target the loop asks for a capture now.
            if r.unseen_fraction > unseen_max {
                prop_assert!(r.spacing_m.is_some_and(|s| s <= r.distance_m), "{r:?}");
            }
        }
    }
}
