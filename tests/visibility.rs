//! The visibility term (`alfd::core::visibility`) against closed forms, against
//! ray casting on 2-D profiles, and its properties. Scenes are rendered by the
//! analytic box-world renderer (`alfd::synth`); the checks' own geometry (eq. 5,
//! segments against boxes) is written here and shares nothing with the sweep.
//! Cases per property: `ALFD_PROPTEST_CASES` (default 100000) divided by the
//! cost of the check, as in `tests/properties.rs`.

use alfd::core::inverse::{fill_grid, DepthRange, InvGrid};
use alfd::core::visibility::{
    line_intervals, visibility, visibility_interleaved, visibility_of_image, visibility_on, End,
    Interleave, Interval, LineRun, LineScratch, SweepWorkers, TrackRays, Visibility,
    VisibilityParams, INTERLEAVE_REFRESH_REL,
};
use alfd::core::{
    DepthData, DepthImage, Estimate, Estimator, EstimatorParams, Intrinsics, TrackAxis,
};
use alfd::synth::{Aabb, BoxWorld, CameraPose};
use alfd::workers::ThreadWorkers;
use proptest::prelude::*;

fn cases(divisor: u32) -> u32 {
    let n: u32 = std::env::var("ALFD_PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    (n / divisor).max(16)
}

fn config(divisor: u32) -> ProptestConfig {
    ProptestConfig {
        cases: cases(divisor),
        max_shrink_iters: 2000,
        ..ProptestConfig::default()
    }
}

/// A box long across track (a 2-D profile's rectangle): `x0..x1`, `0..top`.
fn slab(x0: f64, x1: f64, top: f64) -> Aabb {
    Aabb::building(x0, x1, -1e5, 1e5, top)
}

fn render(
    world: &BoxWorld,
    height_m: f64,
    pitch_rad: f64,
    intr: &Intrinsics,
) -> (DepthImage, Vec<f32>) {
    let pose = CameraPose {
        position_m: [0.0, 0.0, height_m],
        pitch_rad,
    };
    let depth = world.render_depth(&pose, intr);
    let img = DepthImage::new(
        intr.width(),
        intr.height(),
        DepthData::Metres(depth.clone()),
    )
    .unwrap();
    (img, depth)
}

fn grid(img: &DepthImage, step: usize) -> InvGrid {
    let mut g = InvGrid::default();
    fill_grid(img, TrackAxis::Rows, step, &DepthRange::default(), &mut g);
    g
}

/// Every interval of line `a` of `g`.
fn intervals(
    g: &InvGrid,
    intr: &Intrinsics,
    pitch_rad: f64,
    a: usize,
    margin: f64,
) -> Vec<Option<Interval>> {
    let rays = TrackRays::new(&intr.track(TrackAxis::Rows), &g.along_idx, pitch_rad);
    let mut out = Vec::new();
    line_intervals(
        g.line(a),
        &rays,
        margin,
        &mut LineScratch::default(),
        &mut out,
    );
    out
}

// ---------------------------------------------------------------- closed forms

/// A street of width `gap` across track between two blocks of height `block`,
/// its centre `centre` metres ahead of a nadir camera at `height` (DESIGN §1).
fn street(block: f64, gap: f64, centre: f64, height: f64, intr: &Intrinsics) -> DepthImage {
    let world = BoxWorld {
        ground_z_m: Some(0.0),
        boxes: vec![
            slab(centre - gap / 2.0 - 1e3, centre - gap / 2.0, block),
            slab(centre + gap / 2.0, centre + gap / 2.0 + 1e3, block),
        ],
    };
    render(&world, height, 0.0, intr).0
}

const H: f64 = 48.0;
const BLOCK: f64 = 30.0;
const GAP: f64 = 5.0;

fn street_intr() -> Intrinsics {
    Intrinsics::from_hfov_deg(640, 4, 90.0, None).unwrap()
}

fn exact() -> VisibilityParams {
    VisibilityParams {
        occluder_margin_rel: 0.0,
        ..VisibilityParams::default()
    }
}

/// Every floor point of the street is visible from `g·H/h` of track, so the
/// views-per-point spacing is `g·H/(h·k)`; sampling can only lengthen an
/// interval, by less than the travel that moves the occluding corner one pixel.
#[test]
fn street_floor_interval_is_gap_times_height_ratio() {
    let intr = street_intr();
    let img = street(BLOCK, GAP, 0.0, H, &intr);
    let g = grid(&img, 1);
    let l_true = GAP * H / BLOCK;
    let mut floor = 0;
    for a in 0..g.lines {
        for (j, iv) in intervals(&g, &intr, 0.0, a, 0.0).iter().enumerate() {
            let iv = iv.expect("every pixel sees a surface");
            if (1.0 / g.line(a)[j] as f64 - H).abs() < 1e-3 {
                floor += 1;
                assert!(iv.from == End::Occluder && iv.to == End::Occluder);
                let l = iv.length_m();
                assert!(
                    l >= l_true * (1.0 - 1e-6) && l <= l_true * 1.03,
                    "floor sample {j}: interval {l} m against {l_true} m"
                );
            }
        }
    }
    // The floor spans f·g/H pixels per line.
    assert!(floor >= 4 * 33, "{floor} floor samples");
    for k in [1u32, 2, 3] {
        let v = visibility_of_image(
            &img,
            &intr,
            TrackAxis::Rows,
            1,
            0.0,
            &VisibilityParams {
                views_per_point_min: k,
                ..exact()
            },
        );
        let s = v.spacing_views_m.unwrap();
        let want = l_true / k as f64;
        assert!(
            s >= want * (1.0 - 1e-6) && s <= want * 1.03,
            "k={k}: {s} against {want}"
        );
        assert_eq!(v.spacing_views_occluded_m, v.spacing_views_m);
        assert!(v.has_occluders() && v.occluded_lines == 4);
    }
}

/// `visibility_refresh` on a flight: a frame whose own lines' shortest
/// interval shortened sweeps every line only where the views spacing that
/// predicts (every class shortened alike, and what the last frames hold) comes
/// within the margin, widened by the spread of the last frames' shortest
/// intervals, of what the frame's other terms allow (`others_m`). Every line of
/// the street is alike, so the term is the narrow street's whether or not.
#[test]
fn a_shorter_interval_sweeps_every_line_only_where_the_views_spacing_can_decide() {
    let intr = street_intr();
    let geom = intr.track(TrackAxis::Rows);
    let p = exact();
    let wide = grid(&street(BLOCK, GAP, 0.0, H, &intr), 1);
    let narrow = grid(&street(BLOCK, 0.8 * GAP, 0.0, H, &intr), 1);
    let (vw, vn) = (
        visibility(&wide, &geom, 0.0, &p),
        visibility(&narrow, &geom, 0.0, &p),
    );
    let (l_wide, l_narrow) = (vw.interval_min_m.unwrap(), vn.interval_min_m.unwrap());
    let rel = INTERLEAVE_REFRESH_REL;
    assert!(l_narrow < l_wide * (1.0 - rel), "{l_narrow} {l_wide}");
    // Fewer floor samples: the share of occluded ones does not grow.
    assert!(
        vn.occluded_samples * vw.samples <= vw.occluded_samples * vn.samples,
        "{vn:?} {vw:?}"
    );
    // Two frames of the wide street (both classes of lines), then the narrow
    // one's first class.
    let flight = |others_m: Option<f64>| {
        let mut state = Interleave::refreshing(rel);
        for _ in 0..2 {
            visibility_interleaved(&wide, &geom, 0.0, &p, None, 2, others_m, &mut state);
            assert_eq!(state.refreshed_frames(), 0);
        }
        let v = visibility_interleaved(&narrow, &geom, 0.0, &p, None, 2, others_m, &mut state);
        assert_eq!(v.interval_min_m, Some(l_narrow));
        assert_eq!(v.spacing_views_m, vn.spacing_views_m);
        state.swept_every_line()
    };
    let views_m = vn.spacing_views_m.unwrap();
    // The last frames' shortest intervals differ by `l_wide / l_narrow`.
    let (margin, spread) = (1.0 + rel, l_wide / l_narrow);
    assert!(flight(None), "other terms not known: every line");
    assert!(
        flight(Some(views_m)),
        "the views spacing at the others' bound"
    );
    assert!(
        flight(Some(views_m / (margin * spread) * 1.01)),
        "within the margin and the spread"
    );
    assert!(
        !flight(Some(views_m / (margin * spread) * 0.99)),
        "beyond them: the turn alone"
    );
    assert!(
        flight(Some(views_m / margin * 0.99)),
        "the spread widens the margin"
    );
}

/// `visibility_refresh` compares the class a frame sweeps with that class's
/// sweep on its own turn, `stride` frames before, not with a sweep of every
/// line since: a scene that shortens by 3 % a frame (the same street, every
/// length scaled) sweeps every line on the turn after a refresh too, where its
/// class is 12.7 % shorter than on its own turn but only 3 % shorter than the
/// refresh left it.
#[test]
fn a_refresh_compares_each_class_with_its_own_turn() {
    let intr = street_intr();
    let geom = intr.track(TrackAxis::Rows);
    let p = exact();
    let scaled = |f: f64| grid(&street(BLOCK * f, GAP * f, 0.0, H * f, &intr), 1);
    let (a, b, c) = (scaled(1.0), scaled(0.9), scaled(0.9 * 0.97));
    let l = |g: &InvGrid| visibility(g, &geom, 0.0, &p).interval_min_m.unwrap();
    assert!(l(&b) < l(&a) * 0.95 && l(&c) > l(&b) * 0.95 && l(&c) < l(&a) * 0.95);
    let mut state = Interleave::refreshing(INTERLEAVE_REFRESH_REL);
    let mut every_line = Vec::new();
    for g in [&a, &a, &b, &c, &c] {
        visibility_interleaved(g, &geom, 0.0, &p, None, 2, None, &mut state);
        every_line.push(state.swept_every_line());
    }
    // The first frame; the refresh on `b`; `c`'s second class against `a`;
    // then `c`'s first class against `b`'s own turn, 3 %: the turn alone.
    assert_eq!(every_line, [true, false, true, true, false]);
}

/// A watching flight (`Interleave::watching`) also sweeps, on every frame, the
/// `stride` lines either side of the line that holds the shortest interval: a
/// street narrower on one line only, beside that line and in a class the frame
/// does not sweep, is in the frame's views bound at once; the same street
/// farther than `stride` lines away waits for its class's turn, as it does
/// without watching.
#[test]
fn a_watching_flight_sweeps_the_lines_beside_the_shortest_interval_every_frame() {
    let (w, h) = (640usize, 12usize);
    let intr = Intrinsics::from_hfov_deg(w, h, 90.0, None).unwrap();
    let geom = intr.track(TrackAxis::Rows);
    let p = exact();
    let gap = |g: f64| {
        let world = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![
                slab(-g / 2.0 - 1e3, -g / 2.0, BLOCK),
                slab(g / 2.0, g / 2.0 + 1e3, BLOCK),
            ],
        };
        render(&world, H, 0.0, &intr).1
    };
    let (wide, hot, narrow) = (gap(GAP), gap(GAP * 0.9), gap(GAP * 0.8));
    // Every line the wide street's, line 5 the hot one's, and `dip` (if any)
    // the narrow one's.
    let image = |dip: Option<usize>| {
        let mut d = wide.clone();
        d[5 * w..6 * w].copy_from_slice(&hot[5 * w..6 * w]);
        if let Some(a) = dip {
            d[a * w..(a + 1) * w].copy_from_slice(&narrow[a * w..(a + 1) * w]);
        }
        DepthImage::new(w, h, DepthData::Metres(d)).unwrap()
    };
    let frame = |dip: Option<usize>| grid(&image(dip), 1);
    let l = |g: &InvGrid| visibility(g, &geom, 0.0, &p).interval_min_m.unwrap();
    let (before, near, far) = (frame(None), frame(Some(6)), frame(Some(11)));
    assert!(
        l(&near) < l(&before) * 0.95 && l(&far) == l(&near),
        "the dip is the shortest"
    );
    let stride = 4;
    // The second frame sweeps class 0 (lines 0, 4, 8): neither dip's line.
    let second = |state: Interleave, g: &InvGrid| {
        let mut state = state;
        visibility_interleaved(&before, &geom, 0.0, &p, None, stride, None, &mut state);
        let v = visibility_interleaved(g, &geom, 0.0, &p, None, stride, None, &mut state);
        assert!(!state.swept_every_line());
        v.interval_min_m.unwrap()
    };
    // Line 6 is within 4 of line 5.
    assert_eq!(second(Interleave::default().watching(), &near), l(&near));
    assert_eq!(second(Interleave::default(), &near), l(&before));
    // Line 11 is not: its class's turn comes.
    assert_eq!(second(Interleave::default().watching(), &far), l(&before));
    // The refresh sees the frame's own class unchanged, and watches too.
    let refreshing = Interleave::refreshing(INTERLEAVE_REFRESH_REL).watching();
    assert_eq!(second(refreshing, &near), l(&near));
    // The estimator's flight (its defaults: one line in 4, refreshing) watches.
    let params = EstimatorParams {
        score: None,
        ..EstimatorParams::default()
    };
    assert_eq!(params.visibility_interleave, stride);
    let shortest = |e: &Estimate| e.visibility.expect("swept").interval_min_m;
    let every_pixel = Estimator::new(params.clone())
        .estimate_at(&image(Some(6)), &intr, 0.0, 1)
        .unwrap();
    let mut flight = Estimator::new(params);
    flight.estimate(&image(None), &intr, 0.0).unwrap();
    let (second, _) = flight.estimate(&image(Some(6)), &intr, 0.0).unwrap();
    assert_eq!(second.visibility.unwrap().interleave, stride);
    assert_eq!(shortest(&second), shortest(&every_pixel));
    assert_eq!(second.spacing.views_m, every_pixel.spacing.views_m);
}

/// The unseen fraction is 0 up to `g·H/h`; beyond it the floor strip neither
/// capture sees is `(b − g·H/h)/(H/h − 1)` metres wide, `f·width/H` pixels of
/// the mid view, whatever the phase while the strip stays on the floor.
#[test]
fn street_unseen_fraction_follows_the_closed_form() {
    let intr = street_intr();
    let img = street(BLOCK, GAP, 0.0, H, &intr);
    let v = visibility_of_image(&img, &intr, TrackAxis::Rows, 1, 0.0, &exact());
    let (r, f, w) = (H / BLOCK, intr.focal_px(), 640.0);
    let l = GAP * r;
    assert_eq!(v.samples, 640 * 4);
    for b in [0.5, 4.0, 7.9, l * (1.0 - 1e-6)] {
        assert_eq!(v.unseen_at(b), 0.0, "b = {b}");
    }
    let px = 1.0 / w;
    for b in [8.5, 9.0, 10.0, 10.5] {
        let want = f * (b - l) / (r - 1.0) / H / w;
        let got = v.unseen_at(b);
        // Sampling lengthens intervals (narrower strip) by up to ~3 px here.
        assert!(
            got <= want + 1.5 * px && got >= want - 4.0 * px,
            "b = {b}: {got} against {want}"
        );
    }
    for u in [0.005, 0.01, 0.02] {
        let v = visibility_of_image(
            &img,
            &intr,
            TrackAxis::Rows,
            1,
            0.0,
            &VisibilityParams {
                unseen_fraction_max: u,
                ..exact()
            },
        );
        let want = l + (r - 1.0) * u * w * H / f;
        let got = v.spacing_unseen_m.unwrap();
        assert!(
            got >= want - (r - 1.0) * 1.5 * H / f && got <= want * 1.05,
            "u = {u}: {got} m against {want} m"
        );
        // The spacing is the largest meeting the target.
        assert!(v.unseen_at(got) <= u);
        assert!(v.unseen_at(got * (1.0 + 1e-6) + 1e-9) > u);
    }
}

/// Decimation keeps the street's figures (the occluder is sampled coarser:
/// intervals lengthen by at most the travel of a coarser pixel).
#[test]
fn street_figures_hold_under_decimation() {
    let intr = Intrinsics::from_hfov_deg(640, 48, 90.0, None).unwrap();
    let img = street(BLOCK, GAP, 1.3, H, &intr);
    let p = VisibilityParams {
        unseen_fraction_max: 0.01,
        ..VisibilityParams::default()
    };
    let full = visibility_of_image(&img, &intr, TrackAxis::Rows, 1, 0.0, &p);
    for step in [2usize, 4] {
        let v = visibility_of_image(&img, &intr, TrackAxis::Rows, step, 0.0, &p);
        let rel = |a: Option<f64>, b: Option<f64>| (a.unwrap() / b.unwrap() - 1.0).abs();
        assert!(rel(v.spacing_views_m, full.spacing_views_m) < 0.02 * step as f64);
        assert!(rel(v.spacing_unseen_m, full.spacing_unseen_m) < 0.03 * step as f64);
        assert!((v.unseen_at(10.0) - full.unseen_at(10.0)).abs() < 3.0 * step as f64 / 640.0);
        assert_eq!(v.lines, 48 / step as u64);
    }
}

/// A street along track hides nothing in the flight plane: the lines cross no
/// occluder, the term is left out, and the views are the footprint's.
#[test]
fn open_ground_and_a_street_along_track_bind_nothing() {
    let intr = Intrinsics::from_hfov_deg(320, 240, 70.0, None).unwrap();
    let along = BoxWorld {
        ground_z_m: Some(0.0),
        boxes: vec![
            Aabb::building(-1e3, 1e3, 3.0, 1e3, 25.0),
            Aabb::building(-1e3, 1e3, -1e3, -3.0, 25.0),
        ],
    };
    let (img, _) = render(&along, 40.0, 0.0, &intr);
    let v = visibility_of_image(&img, &intr, TrackAxis::Rows, 1, 0.0, &exact());
    assert_eq!(v.occluded_samples, 0);
    assert!(!v.has_occluders() && v.spacing_unseen_m.is_none());
    assert!(v.spacing_views_occluded_m.is_none());
    // The roofs' footprint along track, 15 m below the camera, over k = 2.
    let foot = 15.0 * 320.0 / intr.focal_px();
    let s = v.spacing_views_m.unwrap();
    assert!(
        (s / (foot / 2.0) - 1.0).abs() < 1e-3,
        "{s} against {}",
        foot / 2.0
    );
    assert_eq!(v.unseen_at(1e9), 0.0);
}

// ------------------------------------------------------ ray casting, 2-D profiles

/// How far off a surface, relative to its distance, a sample may be placed and
/// still count as lying on it. The depth is rounded to `f32` and inverted in
/// `f32`, each within 2^-24 of its value, so a sample is within 1.2e-7 of its
/// distance of the surface it was rendered on; this is 8 times that. The scale
/// is the point's own distance, not the altitude: a corner 8.4 µm above a
/// point on a wall 3 m below the camera hides it, while 1e-6 of a 10 m
/// altitude would have taken the corner for the point's own roof.
const ON_SURFACE_REL: f64 = 1e-6;

/// A 2-D scene: a camera at height `height` over ground with slabs.
#[derive(Debug, Clone)]
struct Profile {
    height: f64,
    slabs: Vec<(f64, f64, f64)>,
    pitch_rad: f64,
    intr: Intrinsics,
    step: usize,
}

fn profile() -> impl Strategy<Value = Profile> {
    (
        10.0f64..120.0,
        proptest::collection::vec((-2.0f64..2.0, 0.02f64..1.0, 1u32..9), 0..7),
        -30.0f64..30.0,
        20.0f64..100.0,
        16usize..200,
        1usize..4,
    )
        .prop_map(|(height, raw, pitch_deg, fov, w, step)| {
            // Keep every ray 10° below the horizon; heights in tenths of the
            // altitude, so occluders stand clear of what they hide.
            let fov = fov.min(2.0 * (80.0 - pitch_deg.abs()));
            let slabs = raw
                .iter()
                .map(|&(x, wd, k)| {
                    (
                        x * height,
                        x * height + wd * height,
                        k as f64 * height / 10.0,
                    )
                })
                .collect();
            Profile {
                height,
                slabs,
                pitch_rad: pitch_deg.to_radians(),
                intr: Intrinsics::from_hfov_deg(w, 1, fov, None).unwrap(),
                step,
            }
        })
}

impl Profile {
    fn world(&self) -> BoxWorld {
        BoxWorld {
            ground_z_m: Some(0.0),
            boxes: self.slabs.iter().map(|&(a, b, t)| slab(a, b, t)).collect(),
        }
    }

    /// Sample `j`'s point `(x ahead, h below the camera)` from the same `f32`
    /// inverse depth the core reads.
    fn point(&self, g: &InvGrid, j: usize) -> Option<(f64, f64)> {
        let w = g.w[j];
        if w.is_nan() || w <= 0.0 {
            return None;
        }
        let d = 1.0 / w as f64;
        let (cx, _) = self.intr.principal_px();
        let t = (g.along_idx[j] as f64 + 0.5 - cx) / self.intr.focal_px();
        let (s, c) = self.pitch_rad.sin_cos();
        Some((d * (s + t * c), d * (c - t * s)))
    }

    /// Eq. 5: whether the camera at `c` has `(x, h)` inside its image along track.
    fn in_view(&self, c: f64, (x, h): (f64, f64)) -> bool {
        let (s, co) = self.pitch_rad.sin_cos();
        let depth = s * (x - c) + co * h;
        if depth <= 0.0 {
            return false;
        }
        let v = self.intr.focal_px() * (co * (x - c) - s * h) / depth;
        let col = v + self.intr.principal_px().0 - 0.5;
        (-0.5..=self.intr.width() as f64 - 0.5).contains(&col)
    }

    /// Whether the segment from `p` to the camera at `c` passes through a slab
    /// (walked against the rectangles; `p` is nudged towards the current camera
    /// by [`ON_SURFACE_REL`] of its distance, off the surface it lies on).
    fn blocked_by_scene(&self, c: f64, p: (f64, f64)) -> bool {
        let p = (p.0 * (1.0 - ON_SURFACE_REL), p.1 * (1.0 - ON_SURFACE_REL));
        // World: z up; the camera at height `self.height`.
        let (px, pz) = (p.0, self.height - p.1);
        let (dx, dz) = (c - px, self.height - pz);
        self.slabs.iter().any(|&(x0, x1, top)| {
            let (mut t0, mut t1) = (0.0f64, 1.0f64);
            for (o, d, lo, hi) in [(px, dx, x0, x1), (pz, dz, 0.0, top)] {
                if d.abs() < 1e-300 {
                    if o <= lo || o >= hi {
                        return false;
                    }
                    continue;
                }
                let (a, b) = ((lo - o) / d, (hi - o) / d);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
            t1 - t0 > 1e-12
        })
    }

    /// Whether the segment from `p` to the camera at `c` passes behind a sample
    /// of the frame (farther from the current camera than the sample, along its
    /// ray): the depth-mesh scene the sweep assumes, checked ray by ray.
    fn blocked_by_mesh(&self, c: f64, p: (f64, f64), pts: &[(f64, f64)]) -> bool {
        let e = (c - p.0, -p.1);
        pts.iter().any(|&q| {
            // p + λ·e = μ·q
            let det = -e.0 * q.1 + e.1 * q.0;
            if det.abs() < 1e-300 {
                return false;
            }
            let lambda = (p.0 * q.1 - p.1 * q.0) / det;
            let mu = (-e.0 * p.1 + e.1 * p.0) / det;
            lambda > 1e-9 && lambda < 1.0 && mu > 1.0 + 1e-9
        })
    }

    /// The truth's end of `p`'s occlusion interval in direction `dir` (±1):
    /// the tightest slab corner (a height field's horizon lies on a corner),
    /// with the corner.
    fn occlusion_end(&self, dir: f64, p: (f64, f64)) -> (f64, Option<(f64, f64)>) {
        let mut best = (dir * f64::INFINITY, None);
        for &(x0, x1, top) in &self.slabs {
            for xq in [x0, x1] {
                let q = (xq, self.height - top);
                // Above `p` nudged as in `blocked_by_scene` (clear of the roof
                // `p` may lie on, not of the wall's top corner just above a
                // point on a wall) and on the side the cameras move to.
                if q.1 < p.1 * (1.0 - ON_SURFACE_REL) && dir * (q.0 * p.1 - p.0 * q.1) > 0.0 {
                    let c = (q.0 * p.1 - p.0 * q.1) / (p.1 - q.1);
                    if dir * c < dir * best.0 {
                        best = (c, Some(q));
                    }
                }
            }
        }
        best
    }
}

fn render_profile(p: &Profile) -> (DepthImage, InvGrid) {
    let (img, _) = render(&p.world(), p.height, p.pitch_rad, &p.intr);
    let g = grid(&img, p.step);
    (img, g)
}

proptest! {
    #![proptest_config(config(400))]

    /// The sweep is exact for the depth mesh it assumes: at every camera
    /// position of a fine grid, a sample's interval contains the position iff
    /// the camera has the sample in view and the segment to it passes behind no
    /// sample of the frame (tested ray by ray, O(n) per segment).
    #[test]
    fn sweep_equals_brute_force_on_the_depth_mesh(p in profile()) {
        let (_, g) = render_profile(&p);
        let ivs = intervals(&g, &p.intr, p.pitch_rad, 0, 0.0);
        let pts: Vec<(f64, f64)> = (0..g.per_line).filter_map(|j| p.point(&g, j)).collect();
        for (j, iv) in ivs.iter().enumerate() {
            let Some(pt) = p.point(&g, j) else {
                prop_assert!(iv.is_none());
                continue;
            };
            let iv = iv.unwrap();
            prop_assert!(iv.from_m <= 0.0 && iv.to_m >= 0.0);
            let span = 4.0 * p.height;
            for k in 0..=60 {
                let c = -span + 2.0 * span * k as f64 / 60.0;
                let near = |e: f64| (c - e).abs() <= 1e-6 * (e.abs() + p.height);
                if near(iv.from_m) || near(iv.to_m) {
                    continue;
                }
                let brute = p.in_view(c, pt) && !p.blocked_by_mesh(c, pt, &pts);
                prop_assert_eq!(iv.contains(c), brute, "sample {} at c = {}: {:?}", j, c, iv);
            }
        }
    }

    /// Against the scene itself: a sample's interval contains the truth's
    /// (sampled occluders lie on the true surface, so it is never shorter), and
    /// exceeds it by no more than the sample beside the true occluding corner
    /// allows. The truth's corner is checked by walking the segment against the
    /// slabs on either side of it; frustum ends by eq. 5.
    #[test]
    fn intervals_agree_with_ray_casting_within_a_pixel(p in profile()) {
        let (_, g) = render_profile(&p);
        let ivs = intervals(&g, &p.intr, p.pitch_rad, 0, 0.0);
        let cols: Vec<f64> = g.along_idx.iter().map(|&i| i as f64).collect();
        let (s, co) = p.pitch_rad.sin_cos();
        let (f, cx) = (p.intr.focal_px(), p.intr.principal_px().0);
        for (j, iv) in ivs.iter().enumerate() {
            let Some(pt) = p.point(&g, j) else { continue };
            let iv = iv.unwrap();
            for dir in [1.0f64, -1.0] {
                let (end, kind) = if dir > 0.0 { (iv.to_m, iv.to) } else { (iv.from_m, iv.from) };
                let (occ, corner) = p.occlusion_end(dir, pt);
                // The `f32` depth places `p` within 1.2e-7 of its distance and
                // the walk nudges it by `ON_SURFACE_REL`; the tangent over a
                // corner `Δh` above `p` moves by `h/Δh` times that.
                let gain = corner.map_or(1.0, |q| pt.1 / (pt.1 - q.1));
                let tol = 1e-5 * (occ.abs().min(1e9) + p.height) * gain;
                if corner.is_some() {
                    // The walk confirms the analytic horizon.
                    prop_assert!(!p.blocked_by_scene(occ - dir * tol, pt) || occ.abs() < 2.0 * tol,
                        "sample {}: hidden before the corner's {}", j, occ);
                    prop_assert!(p.blocked_by_scene(occ + dir * tol, pt),
                        "sample {}: visible beyond the corner's {}", j, occ);
                }
                // Never tighter than the truth: a frustum end is the truth's or
                // beyond it, an occluder's lies at or beyond the true corner's.
                prop_assert!(dir * end + tol >= 0.0);
                if kind == End::Occluder {
                    prop_assert!(dir * end >= dir * occ - tol, "sample {}: {} tighter than {}", j, end, occ);
                }
                // The frustum end by eq. 5.
                if kind == End::Frustum && end.is_finite() {
                    let e = 1e-7 * (end.abs() + p.height);
                    prop_assert!(p.in_view(end - dir * e, pt) && !p.in_view(end + dir * e, pt),
                        "sample {}: frustum end {}", j, end);
                }
                // At most the tangent over a sample beside the true corner.
                if let Some(q) = corner {
                    let depth = s * q.0 + co * q.1;
                    if depth <= 0.0 {
                        continue;
                    }
                    let col = f * (co * q.0 - s * q.1) / depth + cx - 0.5;
                    if col < cols[0] || col > cols[cols.len() - 1] {
                        continue; // outside the frame: it cannot occlude
                    }
                    let a = cols.partition_point(|&c| c <= col).saturating_sub(1);
                    let bound = [a, (a + 1).min(cols.len() - 1)]
                        .iter()
                        .filter_map(|&k| p.point(&g, k))
                        .filter(|nb| nb.1 < pt.1 && dir * (nb.0 * pt.1 - pt.0 * nb.1) > 0.0)
                        .map(|nb| dir * (nb.0 * pt.1 - pt.0 * nb.1) / (pt.1 - nb.1))
                        .fold(f64::INFINITY, f64::min);
                    prop_assert!(dir * end <= bound + 1e-9 * (bound.abs() + p.height),
                        "sample {}: end {} beyond the corner's neighbours' {}", j, end, dir * bound);
                }
            }
        }
    }

    /// A taller slab never lengthens an interval: every sample that keeps its
    /// depth keeps an interval inside the lower scene's.
    #[test]
    fn a_taller_occluder_never_lengthens_an_interval(p in profile(), which in 0usize..7, raise in 0.05f64..0.5) {
        prop_assume!(!p.slabs.is_empty());
        let mut taller = p.clone();
        let k = which % p.slabs.len();
        taller.slabs[k].2 = (taller.slabs[k].2 + raise * p.height).min(0.95 * p.height);
        let (_, g1) = render_profile(&p);
        let (_, g2) = render_profile(&taller);
        let margin = VisibilityParams::default().occluder_margin_rel;
        let i1 = intervals(&g1, &p.intr, p.pitch_rad, 0, margin);
        let i2 = intervals(&g2, &p.intr, p.pitch_rad, 0, margin);
        for j in 0..g1.per_line {
            if g1.w[j] != g2.w[j] {
                continue;
            }
            if let (Some(a), Some(b)) = (i1[j], i2[j]) {
                let tol = 1e-9 * (a.length_m().min(1e12) + p.height);
                prop_assert!(b.from_m >= a.from_m - tol && b.to_m <= a.to_m + tol,
                    "sample {}: {:?} not inside {:?}", j, b, a);
            }
        }
    }

    /// Raising a street's blocks (the camera over the street) never raises the
    /// unseen spacing nor the views spacing.
    #[test]
    fn taller_blocks_never_raise_the_spacing(
        height in 20.0f64..100.0,
        gap in 2.0f64..20.0,
        at in -0.45f64..0.45,
        lo in 0.1f64..0.6,
        up in 0.02f64..0.3,
        u in 0.0f64..0.05,
        step in 1usize..3,
    ) {
        let intr = Intrinsics::from_hfov_deg(160, 2, 80.0, None).unwrap();
        let p = VisibilityParams { unseen_fraction_max: u, ..VisibilityParams::default() };
        let run = |block: f64| {
            let img = street(block, gap, at * gap, height, &intr);
            visibility_of_image(&img, &intr, TrackAxis::Rows, step, 0.0, &p)
        };
        let (a, b) = (run(lo * height), run((lo + up) * height));
        let inf = |x: Option<f64>| x.unwrap_or(f64::INFINITY);
        prop_assert!(inf(b.spacing_unseen_m) <= inf(a.spacing_unseen_m) * (1.0 + 1e-9),
            "{:?} > {:?}", b.spacing_unseen_m, a.spacing_unseen_m);
        prop_assert!(inf(b.spacing_views_m) <= inf(a.spacing_views_m) * (1.0 + 1e-9));
    }
}

// ------------------------------------------------------------------ properties

fn depth() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => (-3.0f64..6.0).prop_map(|e| 10f64.powf(e) as f32),
        1 => Just(f32::INFINITY),
        1 => prop_oneof![Just(f32::NAN), Just(0.0f32), Just(-1.0f32), Just(f32::NEG_INFINITY)],
    ]
}

fn intrinsics(w: usize, h: usize) -> impl Strategy<Value = Intrinsics> {
    prop_oneof![
        (1.0f64..=170.0).prop_map(move |fov| Intrinsics::from_hfov_deg(w, h, fov, None).unwrap()),
        (-3.0f64..6.0)
            .prop_map(move |e| Intrinsics::from_focal_px(w, h, 10f64.powf(e), None).unwrap()),
    ]
}

fn params() -> impl Strategy<Value = VisibilityParams> {
    (
        prop_oneof![4 => 0.0f64..0.1, 1 => Just(0.0), 1 => Just(1.0), 1 => Just(f64::NAN), 1 => Just(-1.0)],
        0u32..6,
        0usize..24,
        prop_oneof![3 => 0.0f64..0.05, 1 => Just(f64::NAN), 1 => Just(f64::INFINITY)],
    )
        .prop_map(|(u, k, phases, margin)| VisibilityParams {
            unseen_fraction_max: u,
            views_per_point_min: k,
            phases,
            occluder_margin_rel: margin,
            views_band: 1.0,
        })
}

#[derive(Debug, Clone)]
struct Case {
    img: DepthImage,
    intr: Intrinsics,
    pitch_rad: f64,
    step: usize,
    axis: TrackAxis,
}

fn random_case() -> impl Strategy<Value = Case> {
    (1usize..=40, 1usize..=12)
        .prop_flat_map(|(w, h)| {
            (
                Just(w),
                Just(h),
                proptest::collection::vec(depth(), 1..6),
                proptest::collection::vec(0usize..6, w * h),
                intrinsics(w, h),
                prop_oneof![6 => -85.0f64..85.0, 1 => Just(89.9), 1 => Just(-89.9), 2 => -400.0f64..400.0],
                1usize..5,
                prop_oneof![Just(TrackAxis::Rows), Just(TrackAxis::Columns)],
            )
        })
        .prop_map(|(w, h, levels, pick, intr, pitch_deg, step, axis)| {
            let depth = pick.iter().map(|&k| levels[k % levels.len()]).collect();
            Case {
                img: DepthImage::new(w, h, DepthData::Metres(depth)).unwrap(),
                intr,
                pitch_rad: pitch_deg.to_radians(),
                step,
                axis,
            }
        })
}

fn check_outputs(v: &Visibility) -> Result<(), TestCaseError> {
    for x in [
        v.interval_min_m,
        v.occluded_interval_min_m,
        v.spacing_unseen_m,
        v.spacing_views_m,
        v.spacing_views_occluded_m,
    ]
    .into_iter()
    .flatten()
    {
        prop_assert!(x.is_finite() && x >= 0.0, "{:?}", v);
    }
    prop_assert!(v.occluded_samples <= v.samples && v.occluded_lines <= v.lines);
    if v.occluded_samples == 0 {
        prop_assert!(v.spacing_unseen_m.is_none() && v.spacing_views_occluded_m.is_none());
    }
    let mut last = 0.0;
    for b in [
        f64::NAN,
        -1.0,
        0.0,
        1e-300,
        1e-3,
        0.1,
        1.0,
        10.0,
        1e3,
        1e6,
        1e300,
        f64::INFINITY,
    ] {
        let u = v.unseen_at(b);
        prop_assert!((0.0..=1.0).contains(&u), "unseen_at({}) = {}", b, u);
        if b.is_finite() || b == f64::INFINITY {
            prop_assert!(
                u >= last,
                "unseen fraction falls at {}: {} < {}",
                b,
                u,
                last
            );
            last = u;
        }
    }
    if let Some(s) = v.spacing_unseen_m {
        prop_assert!(v.unseen_at(s) <= v.unseen_fraction_max);
        prop_assert!(v.unseen_at(s * (1.0 + 1e-6) + 1e-12) > v.unseen_fraction_max);
    }
    Ok(())
}

/// Every output of two terms equal, to the bit (the unseen fraction at spacings
/// around each of the second's).
fn same_term(a: &Visibility, b: &Visibility) -> Result<(), TestCaseError> {
    prop_assert_eq!(
        (a.lines, a.samples, a.occluded_samples, a.occluded_lines),
        (b.lines, b.samples, b.occluded_samples, b.occluded_lines)
    );
    prop_assert_eq!(
        (
            a.interval_min_m,
            a.occluded_interval_min_m,
            a.spacing_views_m,
            a.spacing_views_occluded_m
        ),
        (
            b.interval_min_m,
            b.occluded_interval_min_m,
            b.spacing_views_m,
            b.spacing_views_occluded_m
        )
    );
    prop_assert_eq!(a.spacing_unseen_m, b.spacing_unseen_m);
    for x in [
        b.interval_min_m,
        b.occluded_interval_min_m,
        b.spacing_unseen_m,
        Some(1.0),
    ]
    .into_iter()
    .flatten()
    {
        for s in [x * 0.5, x, x * 2.0] {
            prop_assert_eq!(a.unseen_at(s), b.unseen_at(s), "at {}", s);
        }
    }
    Ok(())
}

/// Workers that sweep every other run, each twice, and leave the rest: what
/// the core must make whole whoever it lends the runs to.
#[derive(Debug)]
struct Careless(usize);

impl SweepWorkers for Careless {
    fn threads(&self) -> usize {
        self.0
    }

    fn each(&self, runs: &mut [LineRun], job: &(dyn Fn(&mut LineRun) + Sync)) {
        for r in runs.iter_mut().step_by(2) {
            job(r);
            job(r);
        }
    }
}

proptest! {
    #![proptest_config(config(20))]

    /// Lines swept on several threads give the bits of one thread: counts,
    /// shortest intervals and the occluded samples in line order (the unseen
    /// spacing reads them). So do workers that skip runs or repeat them.
    #[test]
    fn any_thread_count_gives_the_same_bits(
        c in random_case(),
        p in params(),
        threads in 2usize..7,
        band in prop_oneof![Just(1.0), 0.0f64..1.0],
    ) {
        let p = VisibilityParams { views_band: band, ..p };
        let mut g = InvGrid::default();
        fill_grid(&c.img, c.axis, c.step, &DepthRange::default(), &mut g);
        let geom = c.intr.track(c.axis);
        let one = visibility(&g, &geom, c.pitch_rad, &p);
        let many = visibility_on(&g, &geom, c.pitch_rad, &p, Some(&ThreadWorkers::new(threads)));
        // `Visibility`'s `==` on its floats: none is NaN (the test below).
        prop_assert_eq!(&one, &many);
        let careless = visibility_on(&g, &geom, c.pitch_rad, &p, Some(&Careless(threads)));
        prop_assert_eq!(&one, &careless);
    }

    /// A sweep spread over frames takes each line from the newest frame that
    /// swept it: after frame A, each frame of B replaces one residue class of
    /// lines, and the term is the sweep of the grid spliced so, to the bit
    /// (every output; the occluded samples come in another order, which no
    /// output depends on), except that the views bound holds A's shortest
    /// intervals: every frame here is within the `2 × stride` frames it
    /// holds. `stride` frames of B give B's own term, A's intervals held.
    /// Watching the lines beside the shortest interval changes the views
    /// bound alone: to one no longer than the turn's, and no shorter than
    /// A's or B's own.
    #[test]
    fn an_interleaved_sweep_is_the_sweep_of_each_lines_newest_frame(
        (c, other) in random_case().prop_flat_map(|c| {
            let n = c.img.width() * c.img.height();
            (Just(c), proptest::collection::vec(depth(), n))
        }),
        p in params(),
        stride in 2usize..6,
        threads in prop_oneof![Just(1usize), 2usize..4],
    ) {
        let b_img = DepthImage::new(c.img.width(), c.img.height(), DepthData::Metres(other)).unwrap();
        let (mut ga, mut gb) = (InvGrid::default(), InvGrid::default());
        fill_grid(&c.img, c.axis, c.step, &DepthRange::default(), &mut ga);
        fill_grid(&b_img, c.axis, c.step, &DepthRange::default(), &mut gb);
        let geom = c.intr.track(c.axis);
        let pool = ThreadWorkers::new(threads);
        let workers: Option<&dyn SweepWorkers> = (threads > 1).then_some(&pool as _);
        let mut state = Interleave::default();
        let first = visibility_interleaved(&ga, &geom, c.pitch_rad, &p, workers, stride, None, &mut state);
        let va = visibility(&ga, &geom, c.pitch_rad, &p);
        same_term(&first, &va)?;
        // Watching the lines beside the shortest interval changes the views
        // bound alone, and only to an interval one of the frames has.
        let mut watched = Interleave::default().watching();
        same_term(&visibility_interleaved(&ga, &geom, c.pitch_rad, &p, workers, stride, None, &mut watched), &va)?;
        let vb = visibility(&gb, &geom, c.pitch_rad, &p);
        // The stride in force: at most one class per line.
        let s = stride.min(ga.lines.max(1));
        let per = ga.per_line;
        // A term whose views bound also holds A's shortest intervals (stride 1
        // holds nothing).
        let k = va.views_per_point_min as f64;
        let shorter = |x: Option<f64>, y: Option<f64>| match (x, y) {
            (Some(x), Some(y)) => Some(x.min(y)),
            (x, y) => x.or(y),
        };
        let held = |mut v: Visibility| {
            if s == 1 {
                return v;
            }
            let all = shorter(v.interval_min_m, va.interval_min_m);
            let occ = shorter(v.occluded_interval_min_m, va.occluded_interval_min_m);
            v.interval_min_m = all;
            v.occluded_interval_min_m = occ;
            v.spacing_views_m = all.map(|l| l / k);
            v.spacing_views_occluded_m = occ.map(|l| l / k);
            v
        };
        let mut spliced = ga.clone();
        // Refreshing: the same, but a frame whose lines tightened since their
        // own last turn is B's own sweep; the same frame over and over never is.
        let mut fresh = Interleave::refreshing(INTERLEAVE_REFRESH_REL);
        for _ in 0..=s {
            let v = visibility_interleaved(&ga, &geom, c.pitch_rad, &p, workers, stride, None, &mut fresh);
            same_term(&v, &visibility(&ga, &geom, c.pitch_rad, &p))?;
        }
        prop_assert_eq!(fresh.refreshed_frames(), 0);
        let mut refreshed = false;
        for j in 0..s {
            let v = visibility_interleaved(&gb, &geom, c.pitch_rad, &p, workers, stride, None, &mut state);
            let mut w = visibility_interleaved(&gb, &geom, c.pitch_rad, &p, workers, stride, None, &mut watched);
            for (lw, lv, la, lb) in [
                (w.interval_min_m, v.interval_min_m, va.interval_min_m, vb.interval_min_m),
                (
                    w.occluded_interval_min_m,
                    v.occluded_interval_min_m,
                    va.occluded_interval_min_m,
                    vb.occluded_interval_min_m,
                ),
            ] {
                // Shorter than without the watch, or the same; where the
                // turn alone found none, the watched lines of B may have one.
                if let Some(lv) = lv {
                    prop_assert!(lw.is_some_and(|lw| lw <= lv), "watched {:?} against {}", lw, lv);
                }
                if let Some(lw) = lw {
                    let floor = shorter(la, lb).expect("a frame has it");
                    prop_assert!(lw >= floor, "watched {} below every frame's {}", lw, floor);
                }
            }
            (w.interval_min_m, w.spacing_views_m) = (v.interval_min_m, v.spacing_views_m);
            (w.occluded_interval_min_m, w.spacing_views_occluded_m) =
                (v.occluded_interval_min_m, v.spacing_views_occluded_m);
            same_term(&w, &v)?;
            for a in (0..ga.lines).filter(|a| a % s == j) {
                spliced.w[a * per..(a + 1) * per].copy_from_slice(gb.line(a));
            }
            same_term(&v, &held(visibility(&spliced, &geom, c.pitch_rad, &p)))?;
            let before = fresh.refreshed_frames();
            let r = visibility_interleaved(&gb, &geom, c.pitch_rad, &p, workers, stride, None, &mut fresh);
            refreshed |= fresh.refreshed_frames() > before;
            // (One line: stride 1, every frame sweeps it.)
            prop_assert_eq!(fresh.swept_every_line(), s == 1 || fresh.refreshed_frames() > before);
            same_term(&r, &held(visibility(if refreshed { &gb } else { &spliced }, &geom, c.pitch_rad, &p)))?;
        }
        same_term(&visibility(&spliced, &geom, c.pitch_rad, &p), &visibility(&gb, &geom, c.pitch_rad, &p))?;
        // Stride 1 is the frame's own sweep, and forgets the others.
        let one = visibility_interleaved(&ga, &geom, c.pitch_rad, &p, workers, 1, None, &mut state);
        prop_assert_eq!(&one, &visibility(&ga, &geom, c.pitch_rad, &p));
    }

    /// Finite, non-negative, in range and monotone on random maps, focal
    /// lengths, pitches (beyond ±90° too), decimations and track axes.
    #[test]
    fn every_output_is_finite_and_non_negative(c in random_case(), p in params()) {
        let v = visibility_of_image(&c.img, &c.intr, c.axis, c.step, c.pitch_rad, &p);
        check_outputs(&v)?;
        // Every interval holds the current camera.
        let mut g = InvGrid::default();
        fill_grid(&c.img, c.axis, c.step, &DepthRange::default(), &mut g);
        let rays = TrackRays::new(&c.intr.track(c.axis), &g.along_idx, c.pitch_rad);
        let mut out = Vec::new();
        let mut scratch = LineScratch::default();
        for a in 0..g.lines {
            line_intervals(g.line(a), &rays, p.occluder_margin_rel, &mut scratch, &mut out);
            for iv in out.iter().flatten() {
                prop_assert!(iv.from_m <= 0.0 && iv.to_m >= 0.0 && !iv.length_m().is_nan(), "{:?}", iv);
            }
        }
    }

    /// Flat ground at any pitch and field of view, in metres or as Z16 with
    /// its millimetre steps: nothing occludes, so nothing binds.
    #[test]
    fn flat_ground_has_no_occluder(
        height in 2.0f64..200.0,
        pitch_deg in -60.0f64..60.0,
        fov in 20.0f64..120.0,
        z16 in any::<bool>(),
    ) {
        let intr = Intrinsics::from_hfov_deg(96, 8, fov, None).unwrap();
        let world = BoxWorld { ground_z_m: Some(0.0), boxes: vec![] };
        let (img, depth) = render(&world, height, pitch_deg.to_radians(), &intr);
        let img = if z16 {
            DepthImage::new(96, 8, DepthData::Z16 { data: alfd::synth::to_z16(&depth, 1e-3), scale_m: 1e-3 }).unwrap()
        } else {
            img
        };
        let v = visibility_of_image(&img, &intr, TrackAxis::Rows, 1, pitch_deg.to_radians(), &VisibilityParams::default());
        check_outputs(&v)?;
        prop_assert_eq!(v.occluded_samples, 0, "{:?}", v);
        prop_assert!(v.spacing_unseen_m.is_none());
    }
}

/// The extremes of the brief: nothing panics, nothing is NaN.
#[test]
fn extremes_give_finite_outputs() {
    let (w, h) = (32usize, 6usize);
    let street_like: Vec<f32> = (0..w * h)
        .map(|k| if (k % w) / 8 % 2 == 0 { 1.0 } else { 3.0 })
        .collect();
    let maps: Vec<Vec<f32>> = vec![
        street_like.iter().map(|&d| d * 1e-3).collect(),
        street_like.iter().map(|&d| d * 1e6).collect(),
        street_like.clone(),
        vec![f32::INFINITY; w * h],
        vec![f32::NAN; w * h],
        vec![0.0; w * h],
    ];
    for focal in [1e-3, 1.0, 30.0, 1e6] {
        let intr = Intrinsics::from_focal_px(w, h, focal, None).unwrap();
        for pitch_deg in [-89.9, -45.0, 0.0, 45.0, 89.9, 90.0, 180.0] {
            for m in &maps {
                let img = DepthImage::new(w, h, DepthData::Metres(m.clone())).unwrap();
                for step in [1, 2, 4] {
                    let v = visibility_of_image(
                        &img,
                        &intr,
                        TrackAxis::Rows,
                        step,
                        f64::to_radians(pitch_deg),
                        &VisibilityParams::default(),
                    );
                    check_outputs(&v).unwrap();
                }
            }
        }
    }
    let intr = Intrinsics::from_focal_px(w, h, 30.0, None).unwrap();
    let img = DepthImage::new(w, h, DepthData::Metres(vec![f32::INFINITY; w * h])).unwrap();
    let v = visibility_of_image(
        &img,
        &intr,
        TrackAxis::Rows,
        1,
        0.0,
        &VisibilityParams::default(),
    );
    assert_eq!((v.samples, v.lines), (0, 0));
    assert!(v.spacing_views_m.is_none() && v.unseen_at(1.0) == 0.0);
    let img = DepthImage::new(w, h, DepthData::Metres(street_like)).unwrap();
    let v = visibility_of_image(
        &img,
        &intr,
        TrackAxis::Rows,
        1,
        f64::NAN,
        &VisibilityParams::default(),
    );
    assert_eq!(v.samples, 0);
}

// ------------------------------------------------------------------------ cost

/// Microseconds per 640×480 frame of a city block at decimation 1, 2, 4,
/// against reading the frame once (the inverse-depth pass every term shares).
/// Printed, not asserted: `cargo test --release --test visibility cost -- --ignored --nocapture`.
#[test]
#[ignore = "a measurement for the report, not a check"]
fn cost_per_frame() {
    use std::time::Instant;
    let intr = Intrinsics::from_hfov_deg(640, 480, 69.0, None).unwrap();
    let mut boxes = Vec::new();
    for i in -6..6 {
        for k in -6..6 {
            let (x, y) = (i as f64 * 14.0, k as f64 * 14.0);
            boxes.push(Aabb::building(
                x,
                x + 9.0,
                y,
                y + 9.0,
                6.0 + ((i * 7 + k * 3) % 5) as f64 * 6.0,
            ));
        }
    }
    let world = BoxWorld {
        ground_z_m: Some(0.0),
        boxes,
    };
    let (img, _) = render(&world, 48.0, 0.2, &intr);
    let z16 = match img.data() {
        DepthData::Metres(d) => alfd::synth::to_z16(d, 1e-3),
        _ => unreachable!(),
    };
    let img = DepthImage::new(
        640,
        480,
        DepthData::Z16 {
            data: z16,
            scale_m: 1e-3,
        },
    )
    .unwrap();
    let geom = intr.track(TrackAxis::Rows);
    let p = VisibilityParams::default();
    let reps = 40;
    // The fastest of the repetitions: the machine may be shared, and the
    // fastest run is the one least disturbed.
    let fastest = |f: &mut dyn FnMut()| {
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e6
            })
            .fold(f64::INFINITY, f64::min)
    };
    for step in [1usize, 2, 4] {
        let mut g = InvGrid::default();
        let read =
            fastest(&mut || fill_grid(&img, TrackAxis::Rows, step, &DepthRange::default(), &mut g));
        let mut v = visibility(&g, &geom, 0.2, &p);
        let sweep = fastest(&mut || v = visibility(&g, &geom, 0.2, &p));
        // The sweep alone: a target of 1 needs no order statistics.
        let only = VisibilityParams {
            unseen_fraction_max: 1.0,
            ..p
        };
        let sweep_only = fastest(&mut || {
            std::hint::black_box(visibility(&g, &geom, 0.2, &only));
        });
        let two = ThreadWorkers::new(2);
        let sweep_two = fastest(&mut || {
            std::hint::black_box(visibility_on(&g, &geom, 0.2, &p, Some(&two)));
        });
        println!("step {step}: visibility on two threads {sweep_two:.0} µs");
        let mut u = 0.0;
        let query = fastest(&mut || u = v.unseen_at(v.spacing_unseen_m.unwrap_or(5.0)));
        println!(
            "step {step}: read {read:.0} µs, visibility {sweep:.0} µs ({:.1}× read; sweep alone {sweep_only:.0} µs), unseen_at {query:.0} µs; samples {}, occluded {}, spacing_unseen {:?} m, spacing_views {:?} m, unseen {u:.4}",
            sweep / read,
            v.samples,
            v.occluded_samples,
            v.spacing_unseen_m,
            v.spacing_views_m,
        );
    }
}
