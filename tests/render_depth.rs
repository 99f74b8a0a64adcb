//! The renderer's depth against analytic ray–box and ray–ellipsoid hits, and
//! against the independent box world of `alfd::synth`; determinism, Z16 output
//! and supersampling; the binned, table-textured renderer against the
//! reference one (every primitive, exact sines) on every shipped scene.

use alfd::core::{DepthData, Intrinsics};
use alfd::render::{
    ray_box, ray_ellipsoid, render, render_depth, render_reference, survey_camera, Camera,
    RenderOptions, SensorModel,
};
use alfd::scene::Scene;
use alfd::synth::{Aabb, BoxWorld, CameraPose};

fn scene(extra: &str, pitch_deg: f64) -> Scene {
    let text = format!(
        r#"name = "t"
[survey]
altitude_m = 40.0
speed_mps = 5.0
pitch_deg = {pitch_deg}
hfov_deg = 69.0
width = 64
height = 48
start_x_m = -5.0
end_x_m = 5.0
view_step_m = 0.1
[ground]
texture = {{ colour = [0.4, 0.5, 0.3], contrast = 0.4, cutoff_per_m = 2.0, seed = 1 }}
{extra}
"#
    );
    Scene::parse(&text, "t.toml").unwrap()
}

fn camera(x: f64, z: f64, pitch_deg: f64, w: usize, h: usize) -> Camera {
    Camera {
        position_m: [x, 0.0, z],
        roll_rad: 0.0,
        pitch_rad: pitch_deg.to_radians(),
        yaw_rad: 0.0,
        intrinsics: Intrinsics::from_hfov_deg(w, h, 69.0, None).unwrap(),
    }
}

#[test]
fn ray_box_hits_match_hand_computation() {
    // Straight down onto a 20 m roof from 40 m: t = 20, entered through z.
    let hit = ray_box(
        [-5.0, -5.0, 0.0],
        [5.0, 5.0, 20.0],
        [0.0, 0.0, 40.0],
        [0.0, 0.0, -1.0],
    );
    assert_eq!(hit, Some((20.0, 2)));
    // Horizontal ray at z = 10 towards a wall at x = 30: t = 30, axis x.
    let hit = ray_box(
        [30.0, -5.0, 0.0],
        [40.0, 5.0, 20.0],
        [0.0, 0.0, 10.0],
        [1.0, 0.0, 0.0],
    );
    assert_eq!(hit, Some((30.0, 0)));
    // Passing above the box.
    assert!(ray_box(
        [30.0, -5.0, 0.0],
        [40.0, 5.0, 20.0],
        [0.0, 0.0, 25.0],
        [1.0, 0.0, 0.0]
    )
    .is_none());
    // Slanted: from (0,0,40) along (0.3,0,-1) the roof plane z=20 is met at x=6 (outside
    // a box reaching x=5); the wall x=5 at t=16.67, z=23.3, above the roof: miss.
    assert!(ray_box(
        [-5.0, -5.0, 0.0],
        [5.0, 5.0, 20.0],
        [0.0, 0.0, 40.0],
        [0.3, 0.0, -1.0]
    )
    .is_none());
    // Behind the origin: no hit.
    assert!(ray_box(
        [-5.0, -5.0, 0.0],
        [5.0, 5.0, 20.0],
        [0.0, 0.0, 40.0],
        [0.0, 0.0, 1.0]
    )
    .is_none());
}

/// The slab test as first written: axis by axis, stopping at the first empty
/// overlap.
fn ray_box_stepwise(
    min: [f64; 3],
    max: [f64; 3],
    o: [f64; 3],
    d: [f64; 3],
) -> Option<(f64, usize)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    let mut axis = 0;
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < min[k] || o[k] > max[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        if a > t0 {
            t0 = a;
            axis = k;
        }
        t1 = t1.min(b);
        if t0 > t1 {
            return None;
        }
    }
    (t0 > 0.0).then_some((t0, axis))
}

#[test]
fn the_branch_free_slab_test_gives_the_stepwise_bits() {
    // Rays from inside, outside and on the faces, along and across the axes
    // (zero components), grazing edges, and at boxes of zero extent.
    let mut s = 3u64;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut hits = 0;
    for case in 0..200_000 {
        let pick = |u: f64, choices: &[f64]| choices[(u * choices.len() as f64) as usize];
        let mut min = [0.0; 3];
        let mut max = [0.0; 3];
        let (mut o, mut d) = ([0.0; 3], [0.0; 3]);
        for k in 0..3 {
            min[k] = pick(next(), &[-5.0, -1.0, 0.0, 2.5]) + next() * (case % 2) as f64;
            max[k] = min[k] + pick(next(), &[0.0, 1.0, 10.0]);
            o[k] = pick(
                next(),
                &[-20.0, min[k], max[k], 0.5 * (min[k] + max[k]), 20.0],
            ) + (next() - 0.5) * 30.0 * f64::from(u8::from(case % 3 == 0));
            // Mostly aimed at a point in or near the box.
            let aim = min[k] + (next() * 1.4 - 0.2) * (max[k] - min[k]) - o[k];
            d[k] = pick(next(), &[0.0, 1e-300, next() - 0.5, aim, aim, aim, aim]);
        }
        let (want, got) = (ray_box_stepwise(min, max, o, d), ray_box(min, max, o, d));
        assert_eq!(
            got.map(|(t, a)| (t.to_bits(), a)),
            want.map(|(t, a)| (t.to_bits(), a)),
            "box {min:?}..{max:?} from {o:?} along {d:?}"
        );
        hits += want.is_some() as usize;
    }
    // Both outcomes are exercised.
    assert!(hits > 20_000 && hits < 180_000, "{hits} hits");
}

#[test]
fn ray_ellipsoid_hits_match_hand_computation() {
    // Sphere of radius 2 at (0,0,10), ray straight down from 40: t = 28.
    let t = ray_ellipsoid(
        [0.0, 0.0, 10.0],
        [2.0, 2.0, 2.0],
        [0.0, 0.0, 40.0],
        [0.0, 0.0, -1.0],
    );
    assert!((t.unwrap() - 28.0).abs() < 1e-12);
    // Ellipsoid with z semi-axis 4: top at 14, t = 26.
    let t = ray_ellipsoid(
        [0.0, 0.0, 10.0],
        [2.0, 2.0, 4.0],
        [0.0, 0.0, 40.0],
        [0.0, 0.0, -1.0],
    );
    assert!((t.unwrap() - 26.0).abs() < 1e-12);
    // Offset ray x = 1 on a sphere r = 2: z = 10 + sqrt(3), t = 30 - sqrt(3).
    let t = ray_ellipsoid(
        [0.0, 0.0, 10.0],
        [2.0, 2.0, 2.0],
        [1.0, 0.0, 40.0],
        [0.0, 0.0, -1.0],
    );
    assert!((t.unwrap() - (30.0 - 3f64.sqrt())).abs() < 1e-12);
    // Grazing outside: x = 2.01 misses.
    assert!(ray_ellipsoid(
        [0.0, 0.0, 10.0],
        [2.0, 2.0, 2.0],
        [2.01, 0.0, 40.0],
        [0.0, 0.0, -1.0]
    )
    .is_none());
    // Scaled direction (depth-normalised rays): parameter scales inversely.
    let t = ray_ellipsoid(
        [0.0, 0.0, 10.0],
        [2.0, 2.0, 2.0],
        [0.0, 0.0, 40.0],
        [0.0, 0.0, -2.0],
    );
    assert!((t.unwrap() - 14.0).abs() < 1e-12);
}

#[test]
fn rendered_depth_matches_the_synth_box_world() {
    for pitch_deg in [0.0, 20.0, 35.0] {
        let sc = scene(
            r#"[[box]]
min_m = [-8.0, -6.0, 0.0]
max_m = [8.0, 6.0, 20.0]
texture = { colour = [0.7, 0.7, 0.7] }
[[box]]
min_m = [12.0, -10.0, 0.0]
max_m = [20.0, 4.0, 30.0]
texture = { colour = [0.7, 0.6, 0.5] }"#,
            pitch_deg,
        );
        let world = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![
                Aabb::building(-8.0, 8.0, -6.0, 6.0, 20.0),
                Aabb::building(12.0, 20.0, -10.0, 4.0, 30.0),
            ],
        };
        let cam = camera(-3.0, 45.0, pitch_deg, 96, 72);
        let frame = render(&sc, &cam, &RenderOptions { supersample: 1 });
        let pose = CameraPose {
            position_m: cam.position_m,
            pitch_rad: cam.pitch_rad,
        };
        let truth = world.render_depth(&pose, &cam.intrinsics);
        let ground = BoxWorld {
            ground_z_m: Some(0.0),
            boxes: vec![],
        }
        .render_depth(&pose, &cam.intrinsics);
        let mut boxes_seen = 0;
        for (k, (a, b)) in frame.depth_m.iter().zip(&truth).enumerate() {
            if a.is_infinite() || b.is_infinite() {
                assert_eq!(
                    a.is_infinite(),
                    b.is_infinite(),
                    "pixel {k} pitch {pitch_deg}"
                );
                continue;
            }
            assert!((a - b).abs() <= 1e-4 * b.abs(), "pixel {k}: {a} vs {b}");
            if *b < ground[k] - 0.5 {
                boxes_seen += 1;
            }
        }
        assert!(boxes_seen > 100, "the boxes are in view: {boxes_seen}");
    }
}

#[test]
fn rendered_depth_of_an_ellipsoid_matches_the_analytic_hit() {
    let sc = scene(
        r#"[[ellipsoid]]
centre_m = [0.0, 0.0, 10.0]
radii_m = [6.0, 5.0, 4.0]
texture = { colour = [0.2, 0.4, 0.1] }"#,
        0.0,
    );
    let cam = camera(0.0, 40.0, 0.0, 64, 48);
    let frame = render(&sc, &cam, &RenderOptions { supersample: 1 });
    let f = cam.intrinsics.focal_px();
    let mut on_crown = 0;
    for r in 0..48 {
        for i in 0..64 {
            let x = (i as f64 + 0.5 - 32.0) / f;
            let y = (r as f64 + 0.5 - 24.0) / f;
            // Ray (x, -y, -1) from (0, 0, 40): solve the ellipsoid by hand.
            let (dx, dy, dz) = (x / 6.0, -y / 5.0, -1.0 / 4.0);
            let (ox, oy, oz) = (0.0, 0.0, 30.0 / 4.0);
            let a = dx * dx + dy * dy + dz * dz;
            let b = 2.0 * (ox * dx + oy * dy + oz * dz);
            let c = ox * ox + oy * oy + oz * oz - 1.0;
            let disc = b * b - 4.0 * a * c;
            let expected = if disc >= 0.0 {
                on_crown += 1;
                (-b - disc.sqrt()) / (2.0 * a)
            } else {
                40.0
            };
            let got = frame.depth_m[r * 64 + i] as f64;
            assert!(
                (got - expected).abs() < 1e-4 * expected,
                "({i},{r}): {got} vs {expected}"
            );
        }
    }
    assert!(on_crown > 50, "{on_crown}");
}

#[test]
fn rendering_is_deterministic_and_supersampling_smooths() {
    let sc = scene("", 20.0);
    let cam = camera(0.0, 40.0, 20.0, 48, 36);
    let a = render(&sc, &cam, &RenderOptions { supersample: 3 });
    let b = render(&sc, &cam, &RenderOptions { supersample: 3 });
    assert_eq!(a, b);
    let one = render(&sc, &cam, &RenderOptions { supersample: 1 });
    // Same depth (pixel centres); colours differ by the box filter only.
    assert_eq!(a.depth_m, one.depth_m);
    let var = |f: &alfd::render::Frame| {
        let l = f.luminance();
        let m = l.iter().sum::<f32>() / l.len() as f32;
        l.iter().map(|v| (v - m) * (v - m)).sum::<f32>() / l.len() as f32
    };
    assert!(
        var(&a) < var(&one),
        "averaging lowers the variance of a busy texture"
    );
    assert!(a
        .rgb
        .iter()
        .all(|p| p.iter().all(|c| (0.0..=1.0).contains(c))));
}

#[test]
fn z16_output_marks_sky_and_applies_noise_and_dropout() {
    let sc = scene("", 60.0);
    let cam = camera(0.0, 40.0, 60.0, 64, 48);
    let frame = render(&sc, &cam, &RenderOptions { supersample: 1 });
    assert!(
        frame.depth_m.iter().any(|d| d.is_infinite()),
        "sky in view at 60 deg"
    );
    let clean = frame.z16(&SensorModel {
        max_range_m: f64::INFINITY,
        scale_m: 0.01,
        ..SensorModel::default()
    });
    let DepthData::Z16 { data, scale_m } = clean.data() else {
        panic!()
    };
    assert_eq!(*scale_m, 0.01);
    for (z, d) in data.iter().zip(&frame.depth_m) {
        if d.is_finite() && (*d as f64 / 0.01).round() < 65535.0 {
            assert!((*z as f32 * 0.01 - d).abs() <= 0.0051, "{z} {d}");
        } else {
            assert_eq!(*z, 0);
        }
    }
    let noisy = frame.z16(&SensorModel {
        scale_m: 0.01,
        noise_per_m: 1e-3,
        dropout: 0.1,
        max_range_m: 500.0,
        seed: 3,
    });
    let again = frame.z16(&SensorModel {
        scale_m: 0.01,
        noise_per_m: 1e-3,
        dropout: 0.1,
        max_range_m: 500.0,
        seed: 3,
    });
    assert_eq!(noisy, again, "seeded noise is deterministic");
    let DepthData::Z16 { data: nz, .. } = noisy.data() else {
        panic!()
    };
    let zeros = nz.iter().filter(|z| **z == 0).count();
    let sky = data.iter().filter(|z| **z == 0).count();
    assert!(zeros > sky + 64 * 48 / 20, "dropout adds no-return pixels");
    assert!(
        nz.iter()
            .zip(data)
            .any(|(a, b)| *a != 0 && *b != 0 && a != b),
        "noise moves depths"
    );
}

fn shipped(name: &str) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
    Scene::load(&path).unwrap()
}

/// Depth bits equal, colour within what the sine table allows (3e-8 on the
/// pattern, plus f32 rounding of the sums); returns the largest luminance
/// difference.
fn same_as_reference(sc: &Scene, cam: &Camera, ss: usize, what: &str) -> f32 {
    let opts = RenderOptions { supersample: ss };
    let fast = render(sc, cam, &opts);
    let slow = render_reference(sc, cam, &opts);
    let bits = |v: &[f32]| v.iter().map(|d| d.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(&fast.depth_m) == bits(&slow.depth_m),
        "{what}: depth differs from the reference at {:?}",
        fast.depth_m
            .iter()
            .zip(&slow.depth_m)
            .position(|(a, b)| a.to_bits() != b.to_bits())
    );
    assert_eq!(
        bits(&render_depth(sc, cam)),
        bits(&slow.depth_m),
        "{what}: render_depth"
    );
    let mut worst = 0f32;
    for (k, (a, b)) in fast.rgb.iter().zip(&slow.rgb).enumerate() {
        for c in 0..3 {
            assert!(
                (a[c] - b[c]).abs() <= 1e-6,
                "{what}: pixel {k}: {a:?} vs {b:?}"
            );
        }
        worst = worst.max((alfd::render::luma(*a) - alfd::render::luma(*b)).abs());
    }
    worst
}

#[test]
fn the_fast_renderer_matches_the_reference_on_every_shipped_scene() {
    for name in ["roof", "building", "tree", "edifice", "open", "district"] {
        let sc = shipped(name);
        let s = &sc.survey;
        let mut worst = 0f32;
        for x in [s.start_x_m, 0.5 * (s.start_x_m + s.end_x_m), s.end_x_m] {
            let cam = survey_camera(&sc, x, 160, 120);
            for ss in [1, 2, 3] {
                worst = worst.max(same_as_reference(
                    &sc,
                    &cam,
                    ss,
                    &format!("{name} x={x} ss={ss}"),
                ));
            }
        }
        eprintln!("{name}: largest luminance difference to the exact sines {worst:e}");
    }
}

#[test]
fn the_fast_renderer_matches_the_reference_from_awkward_viewpoints() {
    let sc = shipped("district");
    let intr = Intrinsics::from_hfov_deg(120, 90, 69.0, None).unwrap();
    let cams = [
        // Inside the tower, looking down: no wall is entered.
        ([0.0, 0.0, 20.0], 0.0),
        // Beside the tower at roof height, tilted far forward: walls edge-on,
        // boxes behind the camera and across its plane.
        ([-9.0, 0.0, 45.0], 80f64.to_radians()),
        ([-20.0, 3.0, 5.0], 75f64.to_radians()),
        // Among the tree crowns, tilted back.
        ([-58.0, 0.0, 12.0], -60f64.to_radians()),
        // Exactly on a wall's plane.
        ([8.0, 0.0, 30.0], 40f64.to_radians()),
        // Far above, everything small.
        ([0.0, 0.0, 2000.0], 0.0),
    ];
    for (k, (position_m, pitch_rad)) in cams.into_iter().enumerate() {
        let cam = Camera {
            position_m,
            roll_rad: 0.0,
            pitch_rad,
            yaw_rad: 0.0,
            intrinsics: intr,
        };
        for ss in [1, 3] {
            same_as_reference(&sc, &cam, ss, &format!("camera {k} ss={ss}"));
        }
    }
}
