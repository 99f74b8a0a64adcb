//! `alfd sim`'s external camera. In `camera_command` and `autopilot_distance`
//! flights the pictures are the camera's, not alfd's: firmware-sim's camera takes
//! one at each trigger, and here each is rendered at the vehicle's true pose of
//! its instant and written as a camera without GPS writes its card
//! (`DSC00001.JPG`, …; EXIF DateTimeOriginal and SubSecTimeOriginal from the
//! camera's own clock, set an hour and 0.35 s ahead of UTC). `alfd sim` then pairs
//! the card with the manifest as `alfd export --images` does after a flight, so
//! the bench runs that path too.

use super::devices::scene_camera_pose;
use crate::capture::exif::{encode_jpeg, exif_app1_without_gps, ExifGps};
use crate::core::Intrinsics;
use crate::render::{render, RenderOptions};
use crate::scene::Scene;
use firmware_sim::Truth;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The card's folder in the flight directory.
pub const CARD_DIR: &str = "camera-card";

/// The card camera's clock against UTC: set to Central European Time, and fast
/// by 0.35 s, as a camera's clock set by hand is.
pub const CAMERA_CLOCK_AHEAD_US: u64 = 3_600_350_000;

/// Renders and writes one picture per `(mono_ns, truth)` into `flight_dir/camera-card`,
/// named in order from `DSC00001.JPG`. `unix_us_at` maps an instant to UTC; it is
/// called on the caller's thread (a simulated clock is the thread's).
pub fn write_card(
    flight_dir: &Path,
    scene: &Scene,
    intrinsics: Intrinsics,
    mount_pitch_rad: f64,
    pictures: &[(u64, Truth)],
    unix_us_at: impl Fn(u64) -> Option<u64>,
) -> Result<PathBuf, String> {
    let dir = flight_dir.join(CARD_DIR);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let (w, h) = (intrinsics.width() as u32, intrinsics.height() as u32);
    let at: Vec<(Option<u64>, &Truth)> = pictures
        .iter()
        .map(|(mono_ns, tr)| (unix_us_at(*mono_ns), tr))
        .collect();
    let jpegs: Vec<Vec<u8>> = at
        .par_iter()
        .map(|(unix_us, tr)| {
            let pose = scene_camera_pose(
                scene,
                mount_pitch_rad,
                tr.pos_ned_m,
                tr.rpy_deg.map(f64::to_radians),
            );
            let frame = render(
                scene,
                &pose.camera(intrinsics),
                &RenderOptions { supersample: 1 },
            );
            let exif = ExifGps {
                lat_deg: 0.0,
                lon_deg: 0.0,
                alt_m: 0.0,
                time_unix_us: unix_us.map(|us| us + CAMERA_CLOCK_AHEAD_US),
                make: "firmware-sim".into(),
                model: "external camera".into(),
            };
            let app1 = exif_app1_without_gps(&exif, w, h);
            encode_jpeg(&frame.rgb8(), w, h, 90, Some(app1)).map_err(|e| e.to_string())
        })
        .collect::<Result<_, _>>()?;
    for (k, jpeg) in jpegs.iter().enumerate() {
        let path = dir.join(format!("DSC{:05}.JPG", k + 1));
        std::fs::write(&path, jpeg).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(dir)
}
