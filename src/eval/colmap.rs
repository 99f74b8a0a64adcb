//! `alfd eval --colmap` (DESIGN §3, a second judge): each method's captures at
//! equal counts written as a capture directory (grey PNGs of the rendered
//! views, nerfstudio `transforms.json` in the scene's frame) with samples of
//! the scene's occluded surfaces, then judged by `scripts/colmap_judge.py`
//! (pycolmap: registration, reprojection error, camera centres against the
//! truth, completeness of the occluded surfaces).

use super::recon::{Geometry, View};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Scenes judged by `--colmap` unless `--scene` names others: the
/// occlusion-heavy ones, where completeness on hidden surfaces means most
/// (COLMAP on every method of all eight scenes would take tens of minutes).
pub const DEFAULT_SCENES: [&str; 3] = ["canyon", "courtyard", "orchard"];

/// Tolerance of completeness: a triangulated point within this of a sample.
pub const TOLERANCE_M: f64 = 0.5;

/// Surface samples that the truth marks as occluded: visible from less than
/// half of the flown line (the length of their visibility runs inside it).
pub fn occluded_points(
    points_m: &[[f64; 3]],
    intervals: &[super::truth::Runs],
    line: (f64, f64),
) -> Vec<[f64; 3]> {
    let half = 0.5 * (line.1 - line.0);
    points_m
        .iter()
        .zip(intervals)
        .filter(|(_, iv)| {
            let inside: f64 = iv
                .iter()
                .map(|&(a, b)| (b.min(line.1) - a.max(line.0)).max(0.0))
                .sum();
            inside < half
        })
        .map(|(p, _)| *p)
        .collect()
}

/// Camera-to-world of a survey view at `x_m`: nerfstudio's convention, the
/// camera in OpenGL axes (x right along the image's columns, y up, z back),
/// the world the scene's (x along track, y left, z up: right-handed, read as
/// local east-north-up).
pub fn camera_to_world(g: &Geometry, position_m: [f64; 3]) -> [[f64; 4]; 4] {
    let (s, c) = g.pitch_rad.sin_cos();
    // Columns: image x (along track), image up (−rows = +y world), back (−axis).
    let x = [c, 0.0, s];
    let y = [0.0, 1.0, 0.0];
    let z = [-s, 0.0, c];
    [
        [x[0], y[0], z[0], position_m[0]],
        [x[1], y[1], z[1], position_m[1]],
        [x[2], y[2], z[2], position_m[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Writes the capture directory of one method: `NNNN.png`, `transforms.json`,
/// `occluded_points.json`.
pub fn export(
    dir: &Path,
    g: &Geometry,
    line_y_z_m: (f64, f64),
    views: &[View],
    captures: &[usize],
    occluded: &[[f64; 3]],
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut frames = Vec::new();
    for (n, &k) in captures.iter().enumerate() {
        let name = format!("{n:04}.png");
        let rgb: Vec<u8> = views[k]
            .lum
            .iter()
            .flat_map(|&l| {
                // Display gamma, so SIFT sees the contrast a camera would give.
                let v = (l.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8;
                [v, v, v]
            })
            .collect();
        crate::render::write_png(&dir.join(&name), g.width, g.height, &rgb)?;
        let m = camera_to_world(g, [views[k].x_m, line_y_z_m.0, line_y_z_m.1]);
        frames.push(json!({"file_path": name, "transform_matrix": m}));
    }
    let t = json!({
        "camera_model": "OPENCV",
        "fl_x": g.focal_px, "fl_y": g.focal_px,
        "cx": g.cx_px, "cy": g.cy_px,
        "w": g.width, "h": g.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": frames,
    });
    std::fs::write(
        dir.join("transforms.json"),
        serde_json::to_string_pretty(&t).expect("json"),
    )?;
    std::fs::write(
        dir.join("occluded_points.json"),
        serde_json::to_string(&json!({ "points_m": occluded })).expect("json"),
    )
}

/// Runs the judge on an exported directory; its JSON, or why it could not run.
pub fn judge(script: &Path, dir: &Path) -> Result<Value, String> {
    let out: PathBuf = dir.join("judge.json");
    let st = Command::new("python3")
        .arg(script)
        .arg(dir)
        .arg("--occluded-points")
        .arg(dir.join("occluded_points.json"))
        .arg("--tolerance-m")
        .arg(TOLERANCE_M.to_string())
        .arg("--json")
        .arg(&out)
        .arg("--work")
        .arg(dir.join("colmap"))
        .output()
        .map_err(|e| format!("python3 {}: {e}", script.display()))?;
    if !st.status.success() {
        return Err(format!(
            "{} exited with {}: {}",
            script.display(),
            st.status,
            String::from_utf8_lossy(&st.stderr).trim()
        ));
    }
    let text = std::fs::read_to_string(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("{}: {e}", out.display()))
}
