//! The closed loop (`core::closedloop`) against closed forms and against the
//! evaluation's ground truth (`eval::truth`, exact ray tests) on the scenes of
//! `scenes/`: parallax span between two captures and unseen fraction of the
//! view between them. Issue 13's target for the geometry is a median relative
//! error ≤ 10 % and a worst ≤ 30 % on the held-out scenes.

use alfd::core::closedloop::{
    pair, unseen_fraction, ClosedLoop, ClosedLoopTargets, DepthSnapshot, View,
};
use alfd::core::{DepthData, DepthImage};
use alfd::eval::recon::{Geometry, View as TruthView};
use alfd::eval::truth::Truth;
use alfd::eval::{CALIBRATION_FIT, SCENES};
use alfd::render::{render_depth, survey_camera};
use alfd::scene::Scene;
use glam::{DMat3, DVec3};
use std::path::Path;

fn scene(name: &str) -> Scene {
    Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml")))
        .expect("a shipped scene")
}

/// How the closed loop samples a frame: every `n`-th pixel, or as the daemon
/// and the evaluation keep it ([`DepthSnapshot::kept`], about 4800 samples).
#[derive(Debug, Clone, Copy)]
enum Sampling {
    Step(usize),
    Kept,
}

/// The survey camera at `x_m`: the closed loop's view and the truth's.
fn views(s: &Scene, x_m: f64, w: usize, h: usize, sampling: Sampling) -> (View, TruthView) {
    let cam = survey_camera(s, x_m, w, h);
    let depth = render_depth(s, &cam);
    let img = DepthImage::new(w, h, DepthData::Metres(depth.clone())).unwrap();
    // World (x forward, y left, z up) → NED; the camera pitches about east.
    let v = View {
        depth: match sampling {
            Sampling::Step(n) => DepthSnapshot::new(&img, &cam.intrinsics, n),
            Sampling::Kept => DepthSnapshot::kept(&img, &cam.intrinsics),
        },
        cam_to_ned: DMat3::from_rotation_y(s.survey.pitch_rad),
        pos_ned_m: DVec3::new(x_m, -s.survey.y_m, -s.survey.altitude_m),
    };
    (
        v,
        TruthView {
            x_m,
            lum: Vec::new(),
            depth_m: depth,
        },
    )
}

fn geometry(s: &Scene, w: usize, h: usize) -> Geometry {
    Geometry::of_survey(s, w, h)
}

/// Flat ground seen straight down: every point has the same disparity, so the
/// span is 0 whatever the baseline; nothing is hidden; the overlap is
/// `1 − b·f/(H·W)`.
#[test]
fn flat_ground_has_no_parallax_span_and_hides_nothing() {
    // The open scene seen straight down.
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/open.toml"))
            .unwrap()
            .replace("pitch_deg = 20.0", "pitch_deg = 0.0");
    let s = Scene::parse(&text, "open-nadir").unwrap();
    assert_eq!(s.survey.pitch_rad, 0.0);
    let (w, h) = (160, 120);
    let x0 = s.survey.start_x_m + 5.0;
    let (a, _) = views(&s, x0, w, h, Sampling::Step(1));
    let f = survey_camera(&s, x0, w, h).intrinsics.focal_px();
    for b in [0.5, 2.0, 8.0] {
        let (v, _) = views(&s, x0 + b, w, h, Sampling::Step(1));
        let p = pair(&a, &v);
        let span = p.parallax_span_px.expect("the ground is seen by both");
        assert!(span < 0.05, "b = {b}: span {span} px on flat ground");
        assert_eq!(p.hidden_fraction, 0.0, "b = {b}");
        let ground_m = s.survey.altitude_m - s.ground.as_ref().unwrap().z_m;
        let overlap = 1.0 - b * f / (ground_m * w as f64);
        assert!(
            (p.in_view_fraction - overlap).abs() < 2.0 / w as f64,
            "b = {b}: in view {} against {overlap}",
            p.in_view_fraction
        );
        let (m, _) = views(&s, x0 + 0.5 * b, w, h, Sampling::Step(1));
        assert_eq!(unseen_fraction(&m, &a, &v), 0.0, "b = {b}");
    }
}

/// The loop asks for a capture before the parallax target is exceeded, from
/// the span it measured (linear in the baseline).
#[test]
fn the_loop_stops_at_the_parallax_target() {
    let s = scene("roof");
    let (w, h) = (160, 120);
    let x0 = s.survey.start_x_m + 10.0;
    let targets = ClosedLoopTargets {
        parallax_px: Some(2.0),
        unseen_fraction_max: 0.002,
    };
    let mut cl = ClosedLoop::default();
    let (a, _) = views(&s, x0, w, h, Sampling::Step(2));
    let step_m = 0.1;
    assert!(
        cl.on_frame(a.clone(), 0.0, step_m, &targets).is_none(),
        "no capture yet"
    );
    cl.on_capture(a.clone(), 0.0);
    let mut stop = None;
    for k in 1..200 {
        let d = k as f64 * step_m;
        let (v, _) = views(&s, x0 + d, w, h, Sampling::Step(2));
        let m = cl.on_frame(v.clone(), d, step_m, &targets).unwrap();
        assert!((m.distance_m - d).abs() < 1e-12);
        if m.spacing_m.is_some_and(|sp| d + step_m > sp) {
            stop = Some((d, m));
            break;
        }
    }
    let (d, m) = stop.expect("the parallax target is reached within 20 m");
    let px = m.parallax_px.unwrap();
    // One frame before: the span now is at most the target, the next frame's above it.
    assert!(px <= 2.0 + 1e-9, "stopped at {d} m with {px} px already");
    assert!(
        px * (d + step_m) / d > 2.0,
        "stopped early at {d} m ({px} px)"
    );
}

/// The unseen-fraction target of the light-field profile.
const TARGET: f64 = 0.002;

struct Errors {
    parallax: Vec<f64>,
    /// `(truth, closed loop)` unseen fractions.
    unseen: Vec<(f64, f64)>,
}

/// Closed loop against the truth on one scene, at `1/shrink` of the survey's
/// resolution: baselines up to the distance at which the truth's parallax
/// reaches 8 px, at three places along the line.
fn against_truth(name: &str, shrink: usize, sampling: Sampling) -> Errors {
    let s = scene(name);
    let (w, h) = (s.survey.width / shrink, s.survey.height / shrink);
    let truth = Truth::new(&s, geometry(&s, w, h));
    let mut e = Errors {
        parallax: Vec::new(),
        unseen: Vec::new(),
    };
    let len = s.survey.end_x_m - s.survey.start_x_m;
    for frac in [0.2, 0.5, 0.8] {
        let x0 = s.survey.start_x_m + frac * len;
        let (a, ta) = views(&s, x0, w, h, sampling);
        for b in [0.25, 0.5, 1.0, 2.0, 4.0, 8.0] {
            if x0 + b > s.survey.end_x_m {
                continue;
            }
            let (v, tv) = views(&s, x0 + b, w, h, sampling);
            let (m, tm) = views(&s, x0 + 0.5 * b, w, h, sampling);
            let c = truth.classify(&tm, &ta, &tv, false);
            let p = pair(&a, &v);
            if let (Some(t), Some(got)) = (c.parallax_span_px, p.parallax_span_px) {
                if t > 0.5 {
                    e.parallax.push((got - t).abs() / t);
                }
            }
            let tu = c.unseen_fraction();
            let got = unseen_fraction(&m, &a, &v);
            e.unseen.push((tu, got));
            // Below half the target by the truth, the loop must not ask for a
            // capture: no spurious triggers from depth edges.
            if tu < 0.5 * TARGET {
                assert!(
                    got <= TARGET,
                    "{name} ({sampling:?}) x {x0} b {b}: {got} unseen where the truth has {tu}"
                );
            }
        }
    }
    e
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Parallax: the target (median relative error ≤ 10 %, worst ≤ 30 %
/// on the held-out scenes) is asserted. Unseen fraction: within 8 m no scene
/// reaches the target by the truth, so the test asserts the decision (no
/// spurious capture, above) and prints the values; relative errors on the
/// few pixels involved are reported in the issue note, not asserted.
#[test]
fn closed_loop_geometry_against_the_truth() {
    let mut held_out_p = Vec::new();
    for name in SCENES {
        let e = against_truth(name, 2, Sampling::Step(1));
        let mut p = e.parallax.clone();
        let worst = p.iter().cloned().fold(0.0, f64::max);
        let unseen: Vec<String> = e
            .unseen
            .iter()
            .filter(|(t, g)| *t > 0.0 || *g > 0.0)
            .map(|(t, g)| format!("{t:.5}/{g:.5}"))
            .collect();
        eprintln!(
            "{name:<10} {:<8} parallax median {:.3} worst {worst:.3} (n {}); unseen truth/loop where either > 0: {}",
            if CALIBRATION_FIT.contains(&name) { "held-in" } else { "held-out" },
            median(&mut p),
            p.len(),
            unseen.join(" ")
        );
        if !CALIBRATION_FIT.contains(&name) {
            held_out_p.extend(e.parallax);
        }
    }
    let worst_p = held_out_p.iter().cloned().fold(0.0, f64::max);
    let med_p = median(&mut held_out_p);
    eprintln!("held-out parallax: median {med_p:.3}, worst {worst_p:.3}");
    assert!(
        med_p <= 0.10 && worst_p <= 0.30,
        "parallax: median {med_p}, worst {worst_p}"
    );
}

/// As the daemon and `alfd eval` run it: the survey's full resolution, each
/// frame kept at about 4800 samples (every third pixel at 200 × 150), along
/// the whole line every 0.2 m at baselines of 0.4 and 1.2 m (`canyon`'s and
/// `tree`'s target spacings). Below half the unseen target by the truth, no
/// scene may ask for a capture. Until a kept sample's block also kept its
/// farthest depth, `building` did at x = 3.0 m (0.78 % unseen, truth 0.003 %)
/// and `canyon` from x = −9.4 m on (1.5 %, truth 0, as in `alfd eval`): the
/// west block's wall seen edge-on behind the slab, whose depth changes by
/// more than the seen tolerance between a sample and the pixel beside it.
#[test]
fn kept_depth_raises_no_false_alarm() {
    const GRID_M: f64 = 0.2;
    for name in SCENES {
        let s = scene(name);
        let (w, h) = (s.survey.width, s.survey.height);
        let truth = Truth::new(&s, geometry(&s, w, h));
        let n = ((s.survey.end_x_m - s.survey.start_x_m) / GRID_M).floor() as usize + 1;
        let mut cache: Vec<Option<(View, TruthView)>> = (0..n).map(|_| None).collect();
        let mut view = |i: usize| -> (View, TruthView) {
            cache[i]
                .get_or_insert_with(|| {
                    views(
                        &s,
                        s.survey.start_x_m + i as f64 * GRID_M,
                        w,
                        h,
                        Sampling::Kept,
                    )
                })
                .clone()
        };
        let (mut pairs, mut worst, mut missed) = (0, 0.0f64, 0);
        for k in [2, 6] {
            for i in 0..n.saturating_sub(k) {
                let ((a, ta), (v, tv), (m, tm)) = (view(i), view(i + k), view(i + k / 2));
                let tu = truth.classify(&tm, &ta, &tv, false).unseen_fraction();
                let got = unseen_fraction(&m, &a, &v);
                pairs += 1;
                worst = worst.max(got);
                missed += (tu > TARGET && got <= TARGET) as usize;
                if tu < 0.5 * TARGET {
                    assert!(
                        got <= TARGET,
                        "{name} x {:.1} b {:.1}: {got} unseen where the truth has {tu}",
                        s.survey.start_x_m + i as f64 * GRID_M,
                        k as f64 * GRID_M
                    );
                }
            }
        }
        eprintln!("{name:<10} kept: {pairs} intervals, worst unseen by the loop {worst:.5}, {missed} over the target by the truth and not by the loop");
    }
}
