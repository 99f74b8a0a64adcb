//! One depth frame through the daemon: the core's decision (`core::step`) and, when it
//! captures, the manifest line, with the position and attitude in the flight's frame.
//! Pure: frames, poses and clocks are arguments, so the flight, `alfd sim` and the tests
//! run the same code.

use crate::capture::{
    image_file_name, Attitude, CameraIntrinsics, CaptureMode, CaptureRecord, ClosedLoopRecord,
    ImageFormat, Occlusion, Position, QualityRecord, Spacing,
};
use crate::core::closedloop::Measure;
use crate::core::geo::LocalFrame;
use crate::core::pose::Pose;
use crate::core::step::{self as decision, Decided};
use crate::core::trigger::{Capture, TriggerParams};
use crate::core::visibility::SweepWorkers;
use crate::core::{DepthImage, Estimate, EstimatorParams, Intrinsics};
use glam::EulerRot;
use std::sync::Arc;

/// What the pipeline needs besides the estimator and trigger settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepParams {
    /// Camera tilt about the vehicle's right axis: 0 = nadir, positive = forward.
    pub camera_mount_pitch_rad: f64,
    /// Time between depth frames, seconds (the next opportunity).
    pub frame_period_s: f64,
    pub capture_mode: CaptureMode,
    /// Set when alfd saves the frames itself (`CaptureMode::Frame`).
    pub image_format: Option<ImageFormat>,
    /// The saved frames' intrinsics: the colour camera's, which the manifest and
    /// `transforms.json` carry (the depth camera's may differ: a D435's depth sees 87°,
    /// its colour 69°).
    pub image_intrinsics: Option<Intrinsics>,
}

/// One depth frame (or an opportunity without one: the depth camera stalled)
/// and what is known at its instant.
pub struct FrameInput<'a> {
    pub mono_ns: u64,
    /// `None`: no depth frame came in time; the fallback spacing decides.
    pub depth: Option<&'a DepthImage>,
    pub intrinsics: &'a Intrinsics,
    /// The pose interpolated to `mono_ns`, or why there is none (stale, not synced).
    pub pose: Result<Pose, String>,
    /// The autopilot's boot clock at `mono_ns`, if time is in sync.
    pub boot_us: Option<u64>,
    pub unix_us: Option<u64>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum StepOutcome {
    /// No fresh pose: nothing may be captured (say so once, by STATUSTEXT).
    Suspended {
        reason: String,
    },
    Wait {
        estimate: Box<Estimate>,
    },
    Capture {
        estimate: Box<Estimate>,
        record: Box<CaptureRecord>,
    },
}

/// The core's decision, and the flight's frame and capture settings for its records.
pub struct Pipeline {
    decision: decision::Pipeline,
    params: StepParams,
    local: LocalFrame,
}

impl Pipeline {
    pub fn new(
        estimator: EstimatorParams,
        trigger: TriggerParams,
        params: StepParams,
        local: LocalFrame,
    ) -> Self {
        let core_params = decision::StepParams {
            camera_mount_pitch_rad: params.camera_mount_pitch_rad,
            frame_period_s: params.frame_period_s,
        };
        Pipeline {
            decision: decision::Pipeline::new(estimator, trigger, core_params),
            params,
            local,
        }
    }

    pub fn odometer_m(&self) -> f64 {
        self.decision.odometer_m()
    }

    /// Lends the estimator's visibility sweep threads (`[estimator] threads`).
    pub fn set_sweep_workers(&mut self, workers: Arc<dyn SweepWorkers>) {
        self.decision.set_sweep_workers(workers);
    }

    /// Continue numbering after the captures already in a flight's manifest.
    pub fn set_last_seq(&mut self, seq: u64) {
        self.decision.set_last_seq(seq);
    }

    /// The last capture whose position the trigger still takes from an extrapolated pose:
    /// its number and its frame's instant.
    pub fn unlocated_capture(&self) -> Option<(u64, u64)> {
        self.decision.unlocated_capture()
    }

    /// Capture `seq`'s position from an interpolated pose (`decision::Pipeline::capture_located`).
    pub fn capture_located(&mut self, seq: u64, pos_ned_m: glam::DVec3) {
        self.decision.capture_located(seq, pos_ned_m);
    }

    pub fn params(&self) -> &StepParams {
        &self.params
    }

    pub fn local(&self) -> &LocalFrame {
        &self.local
    }

    /// The autopilot's origin moved: positions are expressed around the new
    /// home from now on, and the decision forgets what was in the old frame.
    pub fn set_local(&mut self, local: LocalFrame) {
        self.local = local;
        self.decision.origin_moved();
    }

    pub fn model(&self) -> &'static str {
        self.decision.model()
    }

    pub fn on_frame(&mut self, f: FrameInput) -> StepOutcome {
        let outcome = self.decision.on_frame(decision::FrameInput {
            mono_ns: f.mono_ns,
            depth: f.depth,
            intrinsics: f.intrinsics,
            pose: f.pose,
        });
        let d: Decided = match outcome {
            decision::StepOutcome::Suspended { reason } => {
                return StepOutcome::Suspended { reason }
            }
            decision::StepOutcome::Wait { estimate } => return StepOutcome::Wait { estimate },
            decision::StepOutcome::Capture(d) => *d,
        };
        let record = capture_record(&RecordInputs {
            seq: d.seq,
            mono_ns: f.mono_ns,
            pose: &d.pose,
            boot_us: f.boot_us,
            unix_us: f.unix_us,
            local: &self.local,
            estimate: Some(&d.estimate),
            closed_loop: d.closed_loop.as_ref(),
            capture: &d.capture,
            model: self.decision.model(),
            mode: self.params.capture_mode,
            image_format: self.params.image_format,
            intrinsics: self.params.image_intrinsics.as_ref(),
            mount_pitch_rad: self.params.camera_mount_pitch_rad,
        });
        StepOutcome::Capture {
            estimate: Box::new(d.estimate),
            record: Box::new(record),
        }
    }
}

/// What a capture record is made of.
pub struct RecordInputs<'a> {
    pub seq: u64,
    pub mono_ns: u64,
    pub pose: &'a Pose,
    pub boot_us: Option<u64>,
    pub unix_us: Option<u64>,
    pub local: &'a LocalFrame,
    /// The estimate in force (`None`: the fallback spacing decided).
    pub estimate: Option<&'a Estimate>,
    /// The closed loop's measurement at this frame, if on.
    pub closed_loop: Option<&'a Measure>,
    pub capture: &'a Capture,
    pub model: &'a str,
    pub mode: CaptureMode,
    /// Set when alfd saves the frame itself.
    pub image_format: Option<ImageFormat>,
    pub intrinsics: Option<&'a Intrinsics>,
    pub mount_pitch_rad: f64,
}

/// A manifest line's position and attitude from a pose.
fn placed(pose: &Pose, local: &LocalFrame, mount_pitch_rad: f64) -> (Position, Attitude) {
    let (yaw, pitch, roll) = pose.q.to_euler(EulerRot::ZYX);
    let geo = local.to_geodetic(pose.pos_ned_m.to_array());
    let position = Position {
        lat_deg: geo.lat_deg,
        lon_deg: geo.lon_deg,
        alt_m: geo.alt_m,
        rel_alt_m: geo.alt_m - local.home().alt_m,
        east_m: pose.pos_ned_m.y,
        north_m: pose.pos_ned_m.x,
        up_m: -pose.pos_ned_m.z,
    };
    let attitude = Attitude {
        roll_deg: roll.to_degrees(),
        pitch_deg: pitch.to_degrees(),
        yaw_deg: yaw.to_degrees().rem_euclid(360.0),
        camera_pitch_deg: mount_pitch_rad.to_degrees(),
    };
    (position, attitude)
}

/// Puts a decided capture where a later look at the pose buffer says it was: the pose the
/// trigger decided on may reach past the newest telemetry sample (extrapolated with the
/// rates, which overshoot when a turn eases off); once the sample after the capture's
/// instant is in, the pose is interpolated. Only the pose and the autopilot's clock change;
/// what decided the capture (spacing, distance, estimate) stays as it was decided.
pub fn relocate(
    record: &mut CaptureRecord,
    pose: &Pose,
    boot_us: Option<u64>,
    local: &LocalFrame,
    mount_pitch_rad: f64,
) {
    let (position, attitude) = placed(pose, local, mount_pitch_rad);
    record.position = position;
    record.attitude = attitude;
    record.pose_age_ms = pose.extrapolated_ns as f64 * 1e-6;
    if let Some(b) = boot_us {
        record.time_boot_us = b;
    }
}

/// One manifest line from the pose, the estimate and the trigger's capture.
pub fn capture_record(r: &RecordInputs) -> CaptureRecord {
    let pose = r.pose;
    let (position, attitude) = placed(pose, r.local, r.mount_pitch_rad);
    CaptureRecord {
        seq: r.seq,
        image: r.image_format.map(|fmt| image_file_name(r.seq, fmt)),
        time_boot_us: r.boot_us.unwrap_or(0),
        time_unix_us: r.unix_us,
        mono_ns: r.mono_ns,
        position,
        attitude,
        spacing: Spacing {
            permissible_m: r.estimate.and_then(|e| e.spacing.permissible_m),
            chosen_m: r.capture.spacing_m,
            active_bound: match (r.closed_loop, r.estimate.and_then(|e| e.spacing.chosen_m)) {
                // The closed loop was tighter than the open loop's spacing.
                (
                    Some(Measure {
                        spacing_m: Some(c),
                        bound: Some(b),
                        ..
                    }),
                    open,
                ) if open.is_none_or(|o| *c < o) => format!("closed_loop_{b}"),
                _ => r
                    .estimate
                    .and_then(|e| e.active_bound)
                    .map_or_else(|| "fallback".to_string(), |b| b.as_str().to_string()),
            },
        },
        distance_since_last_m: r.capture.distance_since_last_m,
        occlusion: r.estimate.and_then(|e| e.occlusion).map(|o| Occlusion {
            density_per_m: o.density_per_m,
            degree: o.degree,
        }),
        terms: r.estimate.map_or_else(Vec::new, |e| {
            e.terms.names().iter().map(|t| t.to_string()).collect()
        }),
        quality: r
            .estimate
            .and_then(|e| QualityRecord::from_estimate(e, r.capture.spacing_m)),
        closed_loop: r.closed_loop.map(|m| ClosedLoopRecord {
            distance_m: m.distance_m,
            parallax_px: m.parallax_px,
            unseen_fraction: m.unseen_fraction,
            in_view_fraction: m.in_view_fraction,
            spacing_m: m.spacing_m,
            bound: m.bound.map(str::to_string),
        }),
        model: r.model.to_string(),
        capture_mode: r.mode,
        undersampled: r.capture.undersampled,
        rate_limited: r.capture.rate_limited,
        fallback: r.capture.fallback,
        pose_age_ms: pose.extrapolated_ns as f64 * 1e-6,
        intrinsics: match (r.image_format, r.intrinsics) {
            (Some(_), Some(i)) => {
                let (cx, cy) = i.principal_px();
                Some(CameraIntrinsics {
                    width: i.width() as u32,
                    height: i.height() as u32,
                    focal_px: i.focal_px(),
                    cx_px: cx,
                    cy_px: cy,
                })
            }
            _ => None,
        },
        requested_by: None,
        image_missing: None,
        picture_after_ms: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::geo::Geodetic;
    use crate::core::DepthData;
    use crate::synth::{reference_scenes, CameraPose};
    use glam::{DQuat, DVec3};

    fn pipeline() -> Pipeline {
        let est = EstimatorParams {
            score: None,
            ..EstimatorParams::default()
        };
        let trig = TriggerParams {
            rate_max_hz: 1000.0,
            ..TriggerParams::default()
        };
        let params = StepParams {
            camera_mount_pitch_rad: 0.0,
            frame_period_s: 1.0 / 30.0,
            capture_mode: CaptureMode::Frame,
            image_format: Some(ImageFormat::Jpeg { quality: 90 }),
            // A colour camera other than the 64×48, 69° depth camera.
            image_intrinsics: Some(Intrinsics::from_hfov_deg(1280, 960, 60.0, None).unwrap()),
        };
        let home = Geodetic {
            lat_deg: 47.0,
            lon_deg: 8.0,
            alt_m: 400.0,
        };
        Pipeline::new(est, trig, params, LocalFrame::new(home))
    }

    /// Flies north over the roof scene at 10 m/s, 30 fps, 40 m up, heading north
    /// (x of the scene = north).
    fn fly(p: &mut Pipeline, frames: usize, stale: impl Fn(usize) -> bool) -> Vec<StepOutcome> {
        let (_, world, _) = reference_scenes()
            .into_iter()
            .find(|s| s.0 == "roof")
            .unwrap();
        let intr = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
        (0..frames)
            .map(|k| {
                let x = -12.0 + 10.0 * k as f64 / 30.0;
                let depth = world.render_depth(
                    &CameraPose {
                        position_m: [x, 0.0, 40.0],
                        pitch_rad: 0.0,
                    },
                    &intr,
                );
                let img = DepthImage::new(64, 48, DepthData::Metres(depth)).unwrap();
                let pose = if stale(k) {
                    Err("stale".to_string())
                } else {
                    Ok(Pose {
                        time_ns: k as u64 * 33_333_333,
                        pos_ned_m: DVec3::new(x, 0.0, -40.0),
                        vel_ned_mps: DVec3::new(10.0, 0.0, 0.0),
                        q: DQuat::IDENTITY,
                        extrapolated_ns: 0,
                    })
                };
                p.on_frame(FrameInput {
                    mono_ns: k as u64 * 33_333_333,
                    depth: Some(&img),
                    intrinsics: &intr,
                    pose,
                    boot_us: Some(k as u64 * 33_333),
                    unix_us: None,
                })
            })
            .collect()
    }

    fn records(out: &[StepOutcome]) -> Vec<&CaptureRecord> {
        out.iter()
            .filter_map(|o| match o {
                StepOutcome::Capture { record, .. } => Some(record.as_ref()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn captures_follow_the_permissible_spacing_and_records_are_complete() {
        let mut p = pipeline();
        let out = fly(&mut p, 72, |_| false);
        let recs = records(&out);
        assert!(recs.len() >= 3, "{}", recs.len());
        for (k, r) in recs.iter().enumerate() {
            assert_eq!(r.seq, k as u64 + 1);
            assert_eq!(
                r.image.as_deref(),
                Some(image_file_name(r.seq, ImageFormat::Jpeg { quality: 90 }).as_str())
            );
            // An interval beyond the tightest spacing in force happens only where
            // the spacing dropped between two frames (0.33 m apart here), and it
            // is then flagged, never hidden.
            if let Some(d) = r.distance_since_last_m {
                let over = d > r.spacing.chosen_m * (1.0 + 1e-9);
                assert_eq!(over, r.undersampled, "{d} vs {}", r.spacing.chosen_m);
            }
            // Heading north at 47°N: latitude grows with north_m, altitude = home + 40 m.
            assert!(
                (r.position.alt_m - 440.0).abs() < 0.01,
                "{}",
                r.position.alt_m
            );
            assert!((r.position.rel_alt_m - 40.0).abs() < 0.01);
            assert_eq!(r.position.up_m, 40.0);
            // The saved image's intrinsics are the colour camera's, not the depth camera's.
            let ci = r
                .intrinsics
                .as_ref()
                .expect("frame mode records intrinsics");
            assert_eq!((ci.width, ci.height), (1280, 960));
            assert!((ci.focal_px - 640.0 / 30f64.to_radians().tan()).abs() < 1e-9);
            assert_eq!(r.model, "quality");
            let q = r.quality.as_ref().expect("the quality model's decision");
            assert_eq!(q.targets.profile, "lightfield");
            assert!(q.predicted.parallax_px.is_some_and(|px| px <= 2.0 + 1e-9));
        }
        assert!(recs
            .windows(2)
            .all(|w| w[1].position.lat_deg > w[0].position.lat_deg));
        let late = recs.iter().filter(|r| r.undersampled).count();
        assert!(
            late * 4 <= recs.len(),
            "{late} of {} intervals late",
            recs.len()
        );
        // 23.3 m flown at 30 fps: the odometer is the distance flown.
        assert!((p.odometer_m() - 10.0 * 71.0 / 30.0).abs() < 1e-9);
    }

    #[test]
    fn a_stale_pose_suspends_and_nothing_is_captured_with_it() {
        let mut p = pipeline();
        let out = fly(&mut p, 60, |k| (10..40).contains(&k));
        for (k, o) in out.iter().enumerate() {
            if (10..40).contains(&k) {
                assert!(
                    matches!(o, StepOutcome::Suspended { .. }),
                    "frame {k}: {o:?}"
                );
            }
        }
        // After the outage the first capture says how far it had to come, and
        // that the interval ran over: under-sampled, never hidden.
        let after: Vec<&CaptureRecord> = records(&out[40..]);
        assert!(after[0].undersampled, "{:?}", after[0]);
    }
}
