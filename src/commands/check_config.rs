//! `alfd check-config`: validates a config file, and says what this build lacks.

use super::{bad, emit};
use alfd::capture::CaptureMode;
use alfd::config::{Config, SimPose, Source, SourceConfig, SourceKind};
use alfd::core::{Decimation, Model};
use alfd::report::targets_text;
use anyhow::Result;
use std::fmt::Write;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The TOML config file.
    file: PathBuf,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let file = a.file;
    let cfg = Config::load(&file).map_err(|e| bad(e.to_string()))?;
    // The lean build has no scene parser; its note below names the synthetic source.
    #[cfg(feature = "sim")]
    if let Some(scene) = &cfg.sim_scene {
        alfd::scene::Scene::load(scene)
            .map_err(|e| bad(format!("{}: sim.scene: {e}", file.display())))?;
    }
    emit(&format!("{}: ok\n{}", file.display(), summary(&cfg)))?;
    if let Some(note) = cfg.unsupported_by_build() {
        emit(&format!("note: {note}\n"))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// What the daemon would do with the config, a line a section, defaults
/// included: what an operator checks before a flight.
fn summary(c: &Config) -> String {
    let mut s = String::new();
    if let Some(l) = &c.link {
        let _ = writeln!(
            s,
            "link           {} as system {} component {}; position {} Hz, attitude {} Hz",
            l.address, l.system_id, l.component_id, l.position_hz, l.attitude_hz
        );
    }
    let source = |name: &str, d: &SourceConfig, depth: bool| {
        let what = match &d.source {
            Source::None => return format!("{name:<15}none\n"),
            Source::Synthetic => "synthetic".to_owned(),
            Source::V4l2 { device, mjpeg } => {
                // A path is taken as it is; otherwise every field given must match.
                let by = match &device.path {
                    Some(p) => p.display().to_string(),
                    None => {
                        let mut by = Vec::new();
                        if let Some(v) = &device.serial {
                            by.push(format!("serial {v}"));
                        }
                        if let Some(v) = &device.bus {
                            by.push(format!("bus {v}"));
                        }
                        if let Some(v) = &device.card {
                            by.push(format!("card \"{v}\""));
                        }
                        if by.is_empty() {
                            "the first device that streams it".to_owned()
                        } else {
                            format!("the device of {}", by.join(", "))
                        }
                    }
                };
                let format = match (depth, mjpeg) {
                    (true, _) => "Z16",
                    (false, true) => "MJPEG",
                    (false, false) => "YUYV",
                };
                format!("V4L2 {by} ({format})")
            }
            Source::Recorded { dir, replay_live } => format!(
                "recorded {}{}",
                dir.display(),
                if *replay_live { ", replayed live" } else { "" }
            ),
        };
        let mut line = format!(
            "{name:<15}{what}, {}x{} at {} fps, {} deg wide",
            d.width, d.height, d.fps, d.hfov_deg
        );
        if depth {
            line += &format!(
                ", {} m per unit, mounted {} deg forward",
                d.scale_m,
                d.mount_pitch_rad.to_degrees()
            );
        }
        line + "\n"
    };
    if c.link.is_some() || c.depth.kind() != SourceKind::None {
        s += &source("depth", &c.depth, true);
        s += &source("camera", &c.camera, false);
    }
    if let Some(scene) = &c.sim_scene {
        let pose = match c.sim_pose {
            SimPose::Truth => "the simulator's true pose",
            SimPose::Telemetry => "the pose alfd believes",
        };
        let _ = writeln!(
            s,
            "sim            scene {}, rendered at {pose}",
            scene.display()
        );
    }
    let p = &c.estimator;
    let _ = writeln!(s, "model          {}", p.model.as_str());
    if p.model == Model::Quality {
        let q = &p.quality;
        let _ = writeln!(
            s,
            "targets        {} profile: {}",
            q.profile.as_str(),
            targets_text(
                q.parallax_px,
                q.forward_overlap,
                q.unseen_fraction_max,
                q.views_per_point_min
            )
        );
    }
    let _ = writeln!(
        s,
        "decimation     {}",
        match &p.decimation {
            Decimation::Fixed(n) => format!("{n}"),
            Decimation::Auto { budget, .. } =>
                format!("auto (within {} % of full resolution)", 100.0 * budget),
        }
    );
    if c.link.is_some() {
        let t = &c.trigger;
        let _ = writeln!(
            s,
            "trigger        at most {} captures a second; {} m without an estimate; closed loop {}",
            t.rate_max_hz,
            t.fallback_spacing_m,
            if t.closed_loop { "on" } else { "off" }
        );
        let mode = match c.capture.mode {
            CaptureMode::Frame => "frames saved by alfd",
            CaptureMode::CameraCommand => "an external camera commanded, each capture logged at the autopilot's report of its picture (its pictures on its card: alfd export --images)",
            CaptureMode::AutopilotDistance => "the autopilot's distance trigger (its camera's pictures on its card: alfd export --images)",
            CaptureMode::Command => "on command",
        };
        let _ = writeln!(s, "capture        {mode}, into {}", c.capture.dir.display());
    }
    s
}
