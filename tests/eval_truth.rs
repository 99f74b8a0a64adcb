//! The evaluation's truth (`alfd::eval::truth`) against closed forms: a street
//! between two blocks seen from nadir, where the strip neither neighbouring
//! capture sees, each floor point's visibility interval and the parallax span
//! between the captures have exact values; and the depth-map fast path
//! against the exact test on every pixel of a shipped scene.

use alfd::eval::recon::{Geometry, View};
use alfd::eval::truth::{captures_within, Halves, Truth, BOTH, NEITHER, ONE};
use alfd::render::{render_depth, survey_camera};
use alfd::scene::Scene;
use std::path::Path;

/// Blocks 20 m tall at x ≤ 0 and x ≥ 2 (a 2 m street across the track, the
/// whole width of every row), camera at 40 m, nadir.
const STREET: &str = r#"
name = "street"
[survey]
altitude_m = 40.0
speed_mps = 5.0
pitch_deg = 0.0
hfov_deg = 69.0
width = 200
height = 150
start_x_m = -4.0
end_x_m = 6.0
view_step_m = 0.04
[ground]
texture = { colour = [0.5, 0.5, 0.5] }
[[box]]
min_m = [-60.0, -200.0, 0.0]
max_m = [0.0, 200.0, 20.0]
texture = { colour = [0.5, 0.5, 0.5] }
[[box]]
min_m = [2.0, -200.0, 0.0]
max_m = [62.0, 200.0, 20.0]
texture = { colour = [0.5, 0.5, 0.5] }
"#;

fn view(scene: &Scene, x_m: f64) -> View {
    let s = &scene.survey;
    let cam = survey_camera(scene, x_m, s.width, s.height);
    View {
        x_m,
        lum: vec![0.0; s.width * s.height],
        depth_m: render_depth(scene, &cam),
    }
}

fn geometry(scene: &Scene) -> Geometry {
    Geometry::of_survey(scene, scene.survey.width, scene.survey.height)
}

#[test]
fn the_street_floor_between_two_captures_is_seen_by_neither_with_its_closed_form_width() {
    let scene = Scene::parse(STREET, "street.toml").unwrap();
    let g = geometry(&scene);
    let truth = Truth::new(&scene, g);
    // Mid view above the street's centre, captures 6 m apart. A floor point
    // x_g is visible from cameras in [x_g + (0 − x_g)·r, x_g + (2 − x_g)·r],
    // r = H/h = 2: an interval of g·r = 4 m. The capture at −2 misses every
    // floor point with x_g < 2, the one at 4 every point with x_g > 0: the
    // whole floor, 2 m at 40 m depth, is seen by neither: 2·f/40 px per row.
    let (mid, a, b) = (view(&scene, 1.0), view(&scene, -2.0), view(&scene, 4.0));
    let c = truth.classify(&mid, &a, &b, false);
    let expected_px = 2.0 * g.focal_px / 40.0;
    for r in 0..g.height {
        let row = &c.class[r * g.width..(r + 1) * g.width];
        let neither = row.iter().filter(|&&k| k == NEITHER).count();
        assert!(
            (neither as f64 - expected_px).abs() <= 1.0,
            "row {r}: {neither} px seen by neither, closed form {expected_px:.2}"
        );
        // Each wall of the street (3.64 px wide in the mid view) is seen by
        // exactly one capture: the one on its side of the street. (Near the
        // image's ends roofs are in one capture's frustum only: f·3/20 px
        // each side, so only the middle 40 columns are counted.)
        let mid_cols = (g.cx_px as usize - 20)..(g.cx_px as usize + 20);
        let one = row[mid_cols].iter().filter(|&&k| k == ONE).count();
        let walls_px = 2.0 * (g.focal_px / 20.0 - g.focal_px / 40.0);
        assert!(
            (one as f64 - walls_px).abs() <= 2.0,
            "row {r}: {one} px seen by one capture, walls {walls_px:.2}"
        );
    }
    // Everything else in view (the roofs) is seen by both: one depth, so the
    // disparity range between the captures is zero.
    assert!(c.counts[BOTH as usize] > 0);
    let span = c.parallax_span_px.unwrap();
    assert!(span.abs() < 0.05, "roofs only, one depth: span {span}");
    let unseen = c.unseen_fraction();
    let expected = expected_px / g.width as f64;
    assert!(
        (unseen - expected).abs() <= 1.0 / g.width as f64,
        "unseen fraction {unseen}, closed form {expected}"
    );
}

#[test]
fn the_parallax_span_between_captures_is_the_closed_form_disparity_range() {
    // Captures 1 m apart on either side of x = 1: both see parts of the
    // floor (depth 40 m) and of the roofs (20 m): disparities f·1/40 and
    // f·1/20, so the span is f/40.
    let scene = Scene::parse(STREET, "street.toml").unwrap();
    let g = geometry(&scene);
    let truth = Truth::new(&scene, g);
    let (mid, a, b) = (view(&scene, 1.0), view(&scene, 0.5), view(&scene, 1.5));
    let c = truth.classify(&mid, &a, &b, false);
    let span = c.parallax_span_px.unwrap();
    let expected = g.focal_px / 40.0;
    assert!(
        (span - expected).abs() < 0.05,
        "span {span}, closed form {expected}"
    );
}

#[test]
fn a_floor_point_is_visible_over_the_closed_form_interval_of_camera_positions() {
    let scene = Scene::parse(STREET, "street.toml").unwrap();
    let truth = Truth::new(&scene, geometry(&scene));
    for x_g in [0.2, 1.0, 1.7] {
        // [x_g − 2·x_g, x_g + 2·(2 − x_g)] = [−x_g, 4 − x_g].
        let iv = truth.visibility([x_g, 0.0, 0.0], 1.0, 0.25, 200.0);
        assert_eq!(iv.len(), 1, "one run of visibility: {iv:?}");
        let (from, to) = iv[0];
        assert!(
            (from + x_g).abs() < 0.01 && (to - (4.0 - x_g)).abs() < 0.01,
            "floor point {x_g}: visible from {from:.3} to {to:.3}, closed form {:.3} to {:.3}",
            -x_g,
            4.0 - x_g
        );
    }
}

#[test]
fn a_point_behind_a_tree_crown_has_two_runs_of_visibility_with_closed_form_ends() {
    // A crown of radius 2 m at (10, 0, 20) between the camera line (40 m) and
    // the ground point P = (20, 0, 0). The ray from P to the camera at
    // (x, 0, 40) passes the crown's centre at distance 20·|x| / √((x − 20)² +
    // 1600): below 2 m, hidden, iff 99x² + 40x − 2000 < 0, i.e. for x in
    // ((−40 − √793600)/198, (−40 + √793600)/198) = (−4.701, 4.297).
    let text = r#"
name = "crown"
[survey]
altitude_m = 40.0
speed_mps = 5.0
hfov_deg = 120.0
width = 200
height = 150
start_x_m = -10.0
end_x_m = 10.0
view_step_m = 0.04
[ground]
texture = { colour = [0.5, 0.5, 0.5] }
[[ellipsoid]]
centre_m = [10.0, 0.0, 20.0]
radii_m = [2.0, 2.0, 2.0]
texture = { colour = [0.2, 0.4, 0.2] }
"#;
    let scene = Scene::parse(text, "crown.toml").unwrap();
    let truth = Truth::new(&scene, geometry(&scene));
    let iv = truth.visibility([20.0, 0.0, 0.0], 20.0, 0.25, 200.0);
    let root = 793_600f64.sqrt();
    let (lo, hi) = ((-40.0 - root) / 198.0, (-40.0 + root) / 198.0);
    assert_eq!(iv.len(), 2, "two runs of visibility: {iv:?}");
    assert!(
        (iv[0].1 - lo).abs() < 0.01 && (iv[1].0 - hi).abs() < 0.01,
        "hidden from {:.3} to {:.3}, closed form {lo:.3} to {hi:.3}",
        iv[0].1,
        iv[1].0
    );
    // Each run ends where P leaves the frustum along track (120°: at
    // x = 20 ± 40·tan 60°), and the counting follows the runs.
    let edge = 40.0 * 60f64.to_radians().tan();
    assert!((iv[0].0 - (20.0 - edge)).abs() < 0.01, "{iv:?}");
    assert!((iv[1].1 - (20.0 + edge)).abs() < 0.01, "{iv:?}");
    assert_eq!(captures_within(&[-5.0, 0.0, 4.0, 5.0], &iv), 2);
}

#[test]
fn the_depth_map_fast_path_agrees_with_the_exact_test_on_shipped_scenes() {
    // `building` at the evaluation's 200×150, and `canyon` at `--quick`'s
    // 66×50, where walls seen almost edge-on are slivers thinner than a pixel
    // (a fast path that trusted "all four neighbours are nearer" called them
    // seen by neither).
    let mut differ = 0usize;
    let mut total = 0usize;
    for (name, w, h, cases) in [
        (
            "building",
            200,
            150,
            [(-12.0, 1.0), (-4.0, 2.0), (0.0, 4.0)],
        ),
        ("canyon", 66, 50, [(-13.0, 0.36), (-3.0, 1.0), (6.0, 4.0)]),
    ] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
        let mut scene = Scene::load(&path).unwrap();
        scene.survey.width = w;
        scene.survey.height = h;
        let g = geometry(&scene);
        let truth = Truth::new(&scene, g);
        for (xm, b) in cases {
            let (mid, a, c) = (
                view(&scene, xm),
                view(&scene, xm - b / 3.0),
                view(&scene, xm + 2.0 * b / 3.0),
            );
            let fast = truth.classify(&mid, &a, &c, false);
            let exact = truth.classify(&mid, &a, &c, true);
            differ += fast
                .class
                .iter()
                .zip(&exact.class)
                .filter(|(x, y)| x != y)
                .count();
            total += fast.class.len();
            assert!(fast.exact_tests < exact.exact_tests);
        }
    }
    let frac = differ as f64 / total as f64;
    eprintln!("fast path against exact: {differ} of {total} pixels differ ({frac:.2e})");
    assert!(frac < 1e-4, "{differ} of {total} pixels differ");
}

/// A truth keeping the halves of its classifications ([`Halves`]) classifies as one that
/// keeps none, class for class and to the bit of the parallax span, whichever half it made
/// and whichever it took: views of `tree` (crowns seen through, pixels the maps leave to the
/// exact test) against pairs of captures that share one neighbour or both, in an order that
/// takes some halves back.
#[test]
fn kept_halves_classify_as_halves_made_afresh() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/tree.toml");
    let mut scene = Scene::load(&path).unwrap();
    scene.survey.width = 100;
    scene.survey.height = 75;
    let g = geometry(&scene);
    let fresh = Truth::new(&scene, g);
    let halves = Halves::default();
    let kept = Truth::new(&scene, g).with_halves(&halves);
    let views: Vec<View> = (0..7)
        .map(|k| view(&scene, -6.0 + 1.5 * k as f64))
        .collect();
    // (view, capture, capture): the second and later ones share halves with earlier ones.
    let cases = [
        (2, 0, 4),
        (2, 0, 5),
        (2, 1, 4),
        (3, 0, 4),
        (2, 0, 4),
        (3, 1, 6),
        (2, 1, 5),
    ];
    let mut exact_kept = 0;
    let mut exact_fresh = 0;
    for (v, a, b) in cases {
        let want = fresh.classify(&views[v], &views[a], &views[b], false);
        let got = kept.classify(&views[v], &views[a], &views[b], false);
        assert_eq!(got.class, want.class, "view {v} between {a} and {b}");
        assert_eq!(got.counts, want.counts);
        assert_eq!(
            got.parallax_span_px.map(f64::to_bits),
            want.parallax_span_px.map(f64::to_bits)
        );
        exact_kept += got.exact_tests;
        exact_fresh += want.exact_tests;
    }
    // The halves taken back were not tested again; the scene needs exact tests at all.
    assert!(exact_fresh > 0);
    assert!(exact_kept < exact_fresh, "{exact_kept} of {exact_fresh}");
}

/// `Truth::occluded` tries a primitive's exact test only where its bounds meet
/// the segment's. Every surface point a view sees, from cameras along the line
/// either side (points on walls and crowns seen edge-on included), against
/// the same exact tests on every primitive: not one answer may differ.
#[test]
fn the_occlusion_test_bounded_by_the_segment_agrees_with_every_primitive_tested() {
    use alfd::render::{ray_box, ray_ellipsoid};
    let plain = |scene: &Scene, c: [f64; 3], p: [f64; 3]| {
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-9);
        let before = 1.0 - 1e-5 - 0.01 / len;
        scene
            .boxes
            .iter()
            .any(|b| ray_box(b.min_m, b.max_m, c, d).is_some_and(|(t, _)| t < before))
            || scene
                .ellipsoids
                .iter()
                .any(|e| ray_ellipsoid(e.centre_m, e.radii_m, c, d).is_some_and(|t| t < before))
    };
    let (mut tested, mut hidden) = (0usize, 0usize);
    for name in ["orchard", "district", "tree", "canyon"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
        let mut scene = Scene::load(&path).unwrap();
        scene.survey.width = 80;
        scene.survey.height = 60;
        let g = geometry(&scene);
        let truth = Truth::new(&scene, g);
        let s = &scene.survey;
        let x0 = 0.5 * (s.start_x_m + s.end_x_m);
        let v = view(&scene, x0);
        for r in 0..g.height {
            for i in 0..g.width {
                let d = v.depth_m[r * g.width + i] as f64;
                if !(d.is_finite() && d > 0.0) {
                    continue;
                }
                let p = truth.point(x0, i, r, d);
                for dx in [-30.0, -7.5, -1.0, 0.0, 2.5, 12.0] {
                    let c = [x0 + dx, s.y_m, s.altitude_m];
                    let want = plain(&scene, c, p);
                    assert_eq!(
                        truth.occluded(c, p),
                        want,
                        "{name} pixel ({i}, {r}) from {dx} m"
                    );
                    tested += 1;
                    hidden += want as usize;
                }
            }
        }
    }
    // Both answers occur often enough for the comparison to mean something.
    assert!(
        hidden > tested / 50 && hidden < tested / 2,
        "{hidden} of {tested}"
    );
}

/// The estimator under evaluation reads each view's depth through `eval_sensor()`, the truth
/// reads the exact depth: a surface past the sensor's range is one the truth counts and the
/// estimator cannot see (it reads as sky). `edifice`'s far ground, 115-140 m along the axis
/// of its 30-degree camera, was clipped at the default 65 m, and both loops under-predicted
/// its parallax by a third. Every surface of every shipped scene's survey, at both ends of
/// the line, must be within range and representable in Z16.
#[test]
fn the_evaluation_sensor_sees_every_surface_of_every_survey() {
    let sensor = alfd::eval::eval_sensor();
    assert!(
        sensor.max_range_m <= 65_535.0 * sensor.scale_m,
        "range {} m past Z16's {} m",
        sensor.max_range_m,
        65_535.0 * sensor.scale_m
    );
    for name in alfd::eval::SCENES {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
        let scene = Scene::load(&path).unwrap();
        let s = &scene.survey;
        for x_m in [s.start_x_m, s.end_x_m] {
            let cam = survey_camera(&scene, x_m, s.width, s.height);
            let far_m = render_depth(&scene, &cam)
                .into_iter()
                .filter(|d| d.is_finite())
                .fold(0.0_f32, f32::max) as f64;
            assert!(
                far_m <= sensor.max_range_m,
                "{name} at x = {x_m} m: a surface {far_m:.1} m away, the sensor stops at {} m",
                sensor.max_range_m
            );
        }
    }
}
