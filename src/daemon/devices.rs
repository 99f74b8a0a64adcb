//! Opening the devices a config names, for `alfd run`: V4L2 (feature `v4l2`),
//! a recording (once as recorded, or live: paced, re-stamped, looping), or the
//! synthetic cameras following the telemetry pose (feature `sim`; a synthetic
//! camera at the simulator's truth only exists inside `alfd sim`).

use super::run::{Devices, Frames};
use crate::config::{Config, Source, SourceConfig};
use crate::link::LinkHandle;
use crate::source::recorded::Recording;
use crate::source::select::DeviceSelector;
use crate::source::{DepthSource, FrameSource};
use std::path::Path;
use std::sync::{Arc, OnceLock};
use synthetic::Synthetic;
#[cfg(feature = "sim")]
pub use synthetic::{scene_camera_pose, telemetry_pose};

/// Where the telemetry pose comes from once the link exists.
pub type LinkSlot = Arc<OnceLock<LinkHandle>>;

/// A camera's pinhole intrinsics from its section (`width`, `height`, `hfov_deg`,
/// `principal_px`): what it renders with, and what the manifest says of its images.
pub(crate) fn intrinsics(s: &SourceConfig) -> Result<crate::core::Intrinsics, String> {
    crate::core::Intrinsics::from_hfov_deg(s.width, s.height, s.hfov_deg, s.principal_px)
        .map_err(|e| format!("intrinsics: {e}"))
}

/// Opens what `config` names. Errors name the section and what is wrong.
pub fn open(config: &Config, slot: LinkSlot) -> Result<Devices, String> {
    if let Some(note) = config.unsupported_by_build() {
        return Err(note);
    }
    let synthetic = Synthetic::open(config, slot)?;
    let d = &config.depth;
    let depth: Option<Box<dyn DepthSource>> = match &d.source {
        Source::None => None,
        Source::Recorded { dir, replay_live } => {
            Some(recorded_depth(dir, *replay_live).map_err(|e| format!("depth.dir: {e}"))?)
        }
        Source::Synthetic => Some(synthetic.depth(d)?),
        Source::V4l2 { device, .. } => open_v4l2_depth(d, device)?,
    };
    let c = &config.camera;
    let frames = match &c.source {
        Source::None => None,
        Source::Recorded { dir, replay_live } => Some(Frames::Stream(
            recorded_color(dir, *replay_live).map_err(|e| format!("camera.dir: {e}"))?,
        )),
        Source::Synthetic => Some(synthetic.color(c, d)?),
        Source::V4l2 { device, mjpeg } => open_v4l2_color(c, device, *mjpeg)?,
    };
    Ok(Devices {
        depth,
        frames,
        tick_hz: d.fps,
    })
}

/// A recorded depth camera: once with the recorded times, or `live`.
fn recorded_depth(dir: &Path, live: bool) -> Result<Box<dyn DepthSource>, String> {
    let rec = Recording::open(dir).map_err(|e| e.to_string())?;
    Ok(if live {
        Box::new(rec.live().map_err(|e| e.to_string())?)
    } else {
        Box::new(rec)
    })
}

/// A recorded colour camera: once with the recorded times, or `live`.
fn recorded_color(dir: &Path, live: bool) -> Result<Box<dyn FrameSource>, String> {
    let rec = Recording::open(dir).map_err(|e| e.to_string())?;
    Ok(if live {
        Box::new(rec.live().map_err(|e| e.to_string())?)
    } else {
        Box::new(rec)
    })
}

#[cfg(feature = "v4l2")]
fn open_v4l2_depth(
    d: &SourceConfig,
    device: &DeviceSelector,
) -> Result<Option<Box<dyn DepthSource>>, String> {
    let intr = intrinsics(d).map_err(|e| format!("depth: {e}"))?;
    let src = crate::source::v4l2::V4l2Depth::open(device.clone(), intr, d.scale_m, d.fps as u32)
        .map_err(|e| format!("depth: {e}"))?;
    Ok(Some(Box::new(src)))
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2_depth(
    _: &SourceConfig,
    _: &DeviceSelector,
) -> Result<Option<Box<dyn DepthSource>>, String> {
    Err("depth.source = \"v4l2\" needs a build with `--features v4l2`".into())
}

#[cfg(feature = "v4l2")]
fn open_v4l2_color(
    c: &SourceConfig,
    device: &DeviceSelector,
    mjpeg: bool,
) -> Result<Option<Frames>, String> {
    let src = crate::source::v4l2::V4l2Color::open(
        device.clone(),
        mjpeg,
        c.width,
        c.height,
        c.fps as u32,
    )
    .map_err(|e| format!("camera: {e}"))?;
    Ok(Some(Frames::Stream(Box::new(src))))
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2_color(
    _: &SourceConfig,
    _: &DeviceSelector,
    _: bool,
) -> Result<Option<Frames>, String> {
    Err("camera.source = \"v4l2\" needs a build with `--features v4l2`".into())
}

/// The synthetic cameras of `alfd run`, rendering the config's scene at the
/// telemetry pose.
#[cfg(feature = "sim")]
mod synthetic {
    use super::{intrinsics, Frames, LinkSlot};
    use crate::config::{Config, SimPose, SourceConfig, SourceKind};
    use crate::render::SensorModel;
    use crate::scene::Scene;
    use crate::source::synthetic::{CameraPose, MonotonicClock, SyntheticColor, SyntheticDepth};
    use crate::source::DepthSource;
    use std::sync::Arc;

    /// The synthetic camera at a local NED position and the vehicle's roll, pitch,
    /// yaw (`rpy_rad`): the scene's survey line starts at its `start_x_m` and heads
    /// north along +x; west is +y; up is +z.
    pub fn scene_camera_pose(
        scene: &Scene,
        mount_pitch_rad: f64,
        ned: [f64; 3],
        rpy_rad: [f64; 3],
    ) -> CameraPose {
        let position_m = [
            scene.survey.start_x_m + ned[0],
            scene.survey.y_m - ned[1],
            -ned[2],
        ];
        CameraPose::on_vehicle(position_m, rpy_rad, mount_pitch_rad)
    }

    /// The synthetic camera's pose from the telemetry ([`scene_camera_pose`]), or
    /// `None` while there is none.
    pub fn telemetry_pose(
        scene: Arc<Scene>,
        mount_pitch_rad: f64,
        slot: LinkSlot,
    ) -> impl FnMut(u64) -> Option<CameraPose> + Send {
        move |t: u64| {
            let link = slot.get()?;
            let p = link.pose_at_mono_ns_blocking(t).ok()?;
            let (yaw, pitch, roll) = p.q.to_euler(glam::EulerRot::ZYX);
            Some(scene_camera_pose(
                &scene,
                mount_pitch_rad,
                p.pos_ned_m.to_array(),
                [roll, pitch, yaw],
            ))
        }
    }

    fn uses(c: &Config, kind: SourceKind) -> bool {
        c.camera.kind() == kind || c.depth.kind() == kind
    }

    /// The scene the synthetic sources render, loaded once for both.
    pub struct Synthetic {
        scene: Option<Arc<Scene>>,
        slot: LinkSlot,
    }

    impl Synthetic {
        pub fn open(config: &Config, slot: LinkSlot) -> Result<Self, String> {
            let scene = match &config.sim_scene {
                Some(p) if uses(config, SourceKind::Synthetic) => {
                    if config.sim_pose == SimPose::Truth {
                        return Err(
                            "sim.pose = \"truth\" needs the simulator's truth, which only `alfd sim` has: use \"telemetry\" with `alfd run`"
                                .into(),
                        );
                    }
                    Some(Arc::new(Scene::load(p).map_err(|e| e.to_string())?))
                }
                _ => None,
            };
            Ok(Synthetic { scene, slot })
        }

        pub fn depth(&self, d: &SourceConfig) -> Result<Box<dyn DepthSource>, String> {
            let scene = self
                .scene
                .clone()
                .ok_or("sim.scene: needed by a synthetic depth source")?;
            let intr = intrinsics(d).map_err(|e| format!("depth: {e}"))?;
            let sensor = SensorModel {
                scale_m: d.scale_m,
                noise_per_m: d.noise_per_m,
                dropout: d.dropout,
                max_range_m: d.max_range_m,
                seed: 1,
            };
            Ok(Box::new(SyntheticDepth::new(
                scene.clone(),
                intr,
                sensor,
                d.fps,
                telemetry_pose(scene, d.mount_pitch_rad, self.slot.clone()),
                MonotonicClock,
            )))
        }

        pub fn color(&self, c: &SourceConfig, d: &SourceConfig) -> Result<Frames, String> {
            let scene = self
                .scene
                .clone()
                .ok_or("sim.scene: needed by a synthetic camera")?;
            // Its own field of view, as the manifest records it.
            let intr = intrinsics(c).map_err(|e| format!("camera: {e}"))?;
            Ok(Frames::AtInstant(Box::new(SyntheticColor::new(
                scene.clone(),
                intr,
                1,
                telemetry_pose(scene, d.mount_pitch_rad, self.slot.clone()),
            ))))
        }
    }
}

/// The lean build has no renderer: `Config::unsupported_by_build` refuses a
/// synthetic source before these are reached.
#[cfg(not(feature = "sim"))]
mod synthetic {
    use super::{Frames, LinkSlot};
    use crate::config::{Config, SourceConfig};
    use crate::source::DepthSource;

    const LACKS: &str = "a synthetic source needs a build with the default features (`sim`)";

    pub struct Synthetic;

    impl Synthetic {
        pub fn open(_: &Config, _: LinkSlot) -> Result<Self, String> {
            Ok(Synthetic)
        }

        pub fn depth(&self, _: &SourceConfig) -> Result<Box<dyn DepthSource>, String> {
            Err(LACKS.into())
        }

        pub fn color(&self, _: &SourceConfig, _: &SourceConfig) -> Result<Frames, String> {
            Err(LACKS.into())
        }
    }
}
