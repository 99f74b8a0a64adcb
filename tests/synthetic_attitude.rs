//! The synthetic camera renders the vehicle's whole attitude (issue 14): a red and a blue
//! marker on a plain ground land, within a pixel, where projecting them through the pose the
//! exports write (`transforms.json`'s camera-to-world for the logged roll, pitch, yaw and mount
//! pitch) says, for yawed, rolled and sideways-flying vehicles.

use alfd::capture::export::camera_to_world_gl;
use alfd::capture::record::Attitude;
use alfd::core::Intrinsics;
use alfd::daemon::devices::scene_camera_pose;
use alfd::scene::Scene;
use alfd::source::synthetic::SyntheticColor;
use alfd::source::FrameAt;
use glam::{DVec3, DVec4};
use std::sync::Arc;

/// A plain grey ground with two flat markers, red (2 × 2 m) and blue (2 × 1 m), off the
/// survey line on different sides, so a turn or a mirror of the image moves them apart.
const SCENE: &str = r#"
name = "markers"
[survey]
altitude_m = 40.0
speed_mps = 5.0
hfov_deg = 69.0
width = 64
height = 48
start_x_m = -20.0
end_x_m = 20.0
y_m = 0.0
view_step_m = 1.0
[ground]
texture = { colour = [0.3, 0.3, 0.3], contrast = 0.0, seed = 1 }
[[box]]
min_m = [5.0, 3.0, 0.0]
max_m = [7.0, 5.0, 0.05]
texture = { colour = [0.9, 0.1, 0.1], contrast = 0.0, seed = 2 }
[[box]]
min_m = [-6.0, -9.0, 0.0]
max_m = [-4.0, -8.0, 0.05]
texture = { colour = [0.1, 0.1, 0.9], contrast = 0.0, seed = 3 }
"#;

/// Top-face centres of the markers (scene frame: x north, y west, z up).
const RED_M: [f64; 3] = [6.0, 4.0, 0.05];
const BLUE_M: [f64; 3] = [-5.0, -8.5, 0.05];

const W: usize = 640;
const H: usize = 480;

fn scene() -> Arc<Scene> {
    Arc::new(Scene::parse(SCENE, "markers").expect("the marker scene parses"))
}

fn intrinsics() -> Intrinsics {
    Intrinsics::from_hfov_deg(W, H, 69.0, None).unwrap()
}

/// A logged pose: the vehicle's local NED position and attitude, and the mount's pitch.
#[derive(Debug, Clone, Copy)]
struct Logged {
    ned_m: [f64; 3],
    roll_deg: f64,
    pitch_deg: f64,
    yaw_deg: f64,
    mount_deg: f64,
}

/// The synthetic colour camera's picture at `pose` (RGB bytes), as `alfd sim` takes it.
fn picture(scene: &Arc<Scene>, pose: Logged) -> Vec<u8> {
    let sc = scene.clone();
    let mut camera = SyntheticColor::new(scene.clone(), intrinsics(), 3, move |_t: u64| {
        Some(scene_camera_pose(
            &sc,
            pose.mount_deg.to_radians(),
            pose.ned_m,
            [pose.roll_deg, pose.pitch_deg, pose.yaw_deg].map(f64::to_radians),
        ))
    });
    let frame = camera.frame_at(0).expect("a pose, so a frame");
    assert_eq!((frame.data.width, frame.data.height), (W, H));
    frame.data.rgb
}

/// Where the scene point `p` appears (continuous pixel coordinates, pixel centres at
/// +0.5) by the exports' camera-to-world: ENU metres around the same origin as the NED.
fn projected(scene: &Scene, pose: Logged, p: [f64; 3]) -> (f64, f64) {
    let s = &scene.survey;
    let enu = |n: f64, e: f64, u: f64| DVec3::new(e, n, u);
    let cam = enu(pose.ned_m[0], pose.ned_m[1], -pose.ned_m[2]);
    let point = enu(p[0] - s.start_x_m, s.y_m - p[1], p[2]);
    let att = Attitude {
        roll_deg: pose.roll_deg,
        pitch_deg: pose.pitch_deg,
        yaw_deg: pose.yaw_deg,
        camera_pitch_deg: pose.mount_deg,
    };
    let gl = camera_to_world_gl(&att, cam).inverse() * DVec4::from((point, 1.0));
    // OpenGL camera axes (x right, y up, z back) to OpenCV's (x right, y down, z forward).
    let (x, y, z) = (gl.x, -gl.y, -gl.z);
    assert!(z > 1.0, "the point is in front of the camera: {z}");
    let intr = intrinsics();
    let (cx, cy) = intr.principal_px();
    (cx + intr.focal_px() * x / z, cy + intr.focal_px() * y / z)
}

/// Centroid of the pixels where channel `c` stands out of the other two, weighted by how
/// much (edge pixels count by their coverage), and the weight.
fn centroid(rgb: &[u8], c: usize) -> ((f64, f64), f64) {
    let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (k, px) in rgb.chunks_exact(3).enumerate() {
        let others = (0..3).filter(|&j| j != c).map(|j| px[j]).max().unwrap();
        let w = px[c].saturating_sub(others) as f64;
        sw += w;
        sx += w * ((k % W) as f64 + 0.5);
        sy += w * ((k / W) as f64 + 0.5);
    }
    ((sx / sw, sy / sw), sw)
}

/// Both markers, seen at `pose`, within a pixel of their projections; returns where.
fn markers_where_logged(scene: &Arc<Scene>, pose: Logged) -> [(f64, f64); 2] {
    let rgb = picture(scene, pose);
    let mut at = [(0.0, 0.0); 2];
    for (k, (name, c, p)) in [("red", 0, RED_M), ("blue", 2, BLUE_M)]
        .into_iter()
        .enumerate()
    {
        let want = projected(scene, pose, p);
        // A marker near the border would be cut and its centroid pulled inwards.
        assert!(
            want.0 > 40.0 && want.0 < W as f64 - 40.0 && want.1 > 40.0 && want.1 < H as f64 - 40.0,
            "{name} marker projects well inside the image at {pose:?}: {want:?}"
        );
        let (got, weight) = centroid(&rgb, c);
        // 2 m² at ~50 m is ~170 px of full colour difference (~200 each).
        assert!(
            weight > 5_000.0,
            "{name} marker seen at {pose:?}: weight {weight}"
        );
        let off = (got.0 - want.0).hypot(got.1 - want.1);
        assert!(
            off < 1.0,
            "{name} marker at {got:?}, its logged pose projects it to {want:?} ({off:.2} px off) at {pose:?}"
        );
        println!("{name} marker {off:.3} px from its projection at {pose:?}");
        at[k] = got;
    }
    at
}

fn level(ned_m: [f64; 3], yaw_deg: f64) -> Logged {
    Logged {
        ned_m,
        roll_deg: 0.0,
        pitch_deg: 0.0,
        yaw_deg,
        mount_deg: 0.0,
    }
}

/// Over the line's start, 40 m up (the markers are 20–30 m north of it).
const OVER_M: [f64; 3] = [20.0, 0.0, -40.0];

#[test]
fn a_level_camera_yawed_90_degrees_sees_the_markers_where_its_logged_pose_says() {
    let sc = scene();
    // The red marker is 6 m north and 4 m west of the camera. Heading north the image's
    // columns run north and its rows east: red is right of the centre and up. Heading east
    // the columns run east and the rows south: red is left of the centre and up.
    let north = markers_where_logged(&sc, level(OVER_M, 0.0));
    let east = markers_where_logged(&sc, level(OVER_M, 90.0));
    let (cx, cy) = intrinsics().principal_px();
    assert!(
        north[0].0 > cx && north[0].1 < cy,
        "heading north: {north:?}"
    );
    assert!(east[0].0 < cx && east[0].1 < cy, "heading east: {east:?}");
}

#[test]
fn a_rolled_camera_sees_the_markers_where_its_logged_pose_says() {
    let sc = scene();
    // Rolled right the camera looks west: from 40 m, 14.6 m west of the vehicle. Each roll's
    // vehicle stands off to the other side so that the markers (between 4 m west and 8.5 m
    // east of the line) stay well inside the picture.
    for (roll_deg, east_m) in [(20.0, 16.8), (-20.0, -12.3)] {
        markers_where_logged(
            &sc,
            Logged {
                roll_deg,
                ..level([20.0, east_m, -40.0], 0.0)
            },
        );
    }
    // Roll, pitch, yaw and a tilted mount at once (the mount turns after the roll): the
    // vehicle heads south-east, 27 m north-north-west of the markers, which it looks at.
    markers_where_logged(
        &sc,
        Logged {
            ned_m: [47.0, -6.0, -45.0],
            roll_deg: -15.0,
            pitch_deg: 8.0,
            yaw_deg: 135.0,
            mount_deg: 20.0,
        },
    );
}

#[test]
fn flying_sideways_the_markers_move_along_the_image_rows() {
    // Along the line (north) with the nose to the east, as a crabbing or sideways-flying
    // vehicle does: the image's columns point east, so the ground moves down the rows.
    let sc = scene();
    let step_m = 4.0;
    let f = intrinsics().focal_px();
    let mut last: Option<[(f64, f64); 2]> = None;
    for k in 0..5 {
        let ned = [12.0 + step_m * k as f64, 0.0, -40.0];
        let at = markers_where_logged(&sc, level(ned, 90.0));
        if let Some(prev) = last {
            for (p, q) in prev.iter().zip(&at) {
                // Flat markers 39.95 m below: f·step/depth pixels per step, down the rows.
                let want = f * step_m / 39.95;
                assert!((q.0 - p.0).abs() < 1.0, "{prev:?} → {at:?}");
                assert!(
                    (q.1 - p.1 - want).abs() < 1.0,
                    "{prev:?} → {at:?}, want +{want:.1} rows"
                );
            }
        }
        last = Some(at);
    }
}
