//! What the along-the-line examples share: a scene's survey line as the
//! daemon's depth camera sees it, frame after frame.

use alfd::core::{DepthData, DepthImage, Intrinsics};
use alfd::render::{render_depth, survey_camera, Frame, SensorModel};
use alfd::scene::Scene;
use std::hint::black_box;
use std::time::{Duration, Instant};

/// The daemon's frame rate.
pub const FPS: f64 = 30.0;

/// The evaluation's sensor (2 mm, 131 m) where it reaches the scene, else
/// `alfd sim`'s 1 cm a Z16 unit.
pub fn sensor(scene: &Scene) -> SensorModel {
    let s = &scene.survey;
    let far_m = s.altitude_m / s.pitch_rad.cos().max(0.2) * 2.0;
    if far_m <= 131.0 {
        alfd::eval::eval_sensor()
    } else {
        SensorModel {
            scale_m: 0.01,
            max_range_m: 600.0,
            ..SensorModel::default()
        }
    }
}

/// The camera positions along the line at `FPS` and the scene's speed.
pub fn positions_m(scene: &Scene) -> impl Iterator<Item = f64> {
    let s = &scene.survey;
    let step_m = s.speed_mps / FPS;
    let n = ((s.end_x_m - s.start_x_m) / step_m).floor() as usize + 1;
    let start = s.start_x_m;
    (0..n).map(move |k| start + k as f64 * step_m)
}

/// The `w × h` Z16 depth frame at `x_m` along the line, and its intrinsics.
pub fn z16_at(
    scene: &Scene,
    x_m: f64,
    (w, h): (usize, usize),
    sensor: &SensorModel,
) -> anyhow::Result<(DepthImage, Intrinsics)> {
    let cam = survey_camera(scene, x_m, w, h);
    let intr = Intrinsics::from_focal_px(
        w,
        h,
        cam.intrinsics.focal_px(),
        Some(cam.intrinsics.principal_px()),
    )?;
    let frame = Frame {
        width: w,
        height: h,
        rgb: Vec::new(),
        depth_m: render_depth(scene, &cam),
    };
    Ok((frame.z16(sensor), intr))
}

/// Reading the frame once (the sum of its u16 values): the unit of cost.
pub fn read_time(img: &DepthImage) -> Duration {
    let DepthData::Z16 { data, .. } = img.data() else {
        unreachable!("z16_at makes Z16 frames")
    };
    let t = Instant::now();
    black_box(black_box(data).iter().map(|&z| z as u64).sum::<u64>());
    t.elapsed()
}

/// The scene files named on the command line, else `alfd sim`'s `district`
/// and the evaluation's eight (`alfd::eval::SCENES`, in its table order).
pub fn scene_paths() -> Vec<std::path::PathBuf> {
    let named: Vec<std::path::PathBuf> = std::env::args()
        .skip(1)
        .map(std::path::PathBuf::from)
        .collect();
    if !named.is_empty() {
        return named;
    }
    std::iter::once("district")
        .chain(alfd::eval::SCENES)
        .map(|s| std::path::PathBuf::from(format!("scenes/{s}.toml")))
        .collect()
}
