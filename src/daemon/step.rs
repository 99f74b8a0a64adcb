//! One depth frame through the daemon: the estimate at the pose of the frame's
//! instant, the trigger's decision, and the capture record when it fires. Pure:
//! frames, poses and clocks are arguments, so the flight, `alfd sim` and the
//! tests run the same decision code.

use crate::capture::{
    image_file_name, Attitude, CameraIntrinsics, CaptureMode, CaptureRecord, ClosedLoopRecord,
    ImageFormat, Occlusion, Position, QualityRecord, Spacing,
};
use crate::core::attitude::{camera_to_body, flight_axis};
use crate::core::closedloop::{ClosedLoop, ClosedLoopTargets, DepthSnapshot, Measure, View};
use crate::core::geo::LocalFrame;
use crate::core::pose::Pose;
use crate::core::trigger::{Capture, Decision, Opportunity, Trigger, TriggerParams};
use crate::core::{DepthImage, Estimate, Estimator, EstimatorParams, Intrinsics, TrackAxis};
use glam::{DMat3, EulerRot};

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

pub struct Pipeline {
    estimator: Estimator,
    trigger: Trigger,
    params: StepParams,
    local: LocalFrame,
    odometer_m: f64,
    last_ne_m: Option<[f64; 2]>,
    seq: u64,
    /// `Some` when `[trigger] closed_loop` is on.
    closed_loop: Option<ClosedLoop>,
    /// The configured scan axis, used while the vehicle hovers.
    fixed_axis: TrackAxis,
}

impl Pipeline {
    pub fn new(
        estimator: EstimatorParams,
        trigger: TriggerParams,
        params: StepParams,
        local: LocalFrame,
    ) -> Self {
        Pipeline {
            fixed_axis: estimator.track_axis,
            estimator: Estimator::new(estimator),
            trigger: Trigger::new(trigger),
            params,
            local,
            odometer_m: 0.0,
            last_ne_m: None,
            seq: 0,
            closed_loop: trigger.closed_loop.then(ClosedLoop::default),
        }
    }

    pub fn odometer_m(&self) -> f64 {
        self.odometer_m
    }

    /// Continue numbering after the captures already in a flight's manifest.
    pub fn set_last_seq(&mut self, seq: u64) {
        self.seq = seq;
    }

    pub fn params(&self) -> &StepParams {
        &self.params
    }

    pub fn local(&self) -> &LocalFrame {
        &self.local
    }

    /// The autopilot's origin moved: positions are expressed around the new
    /// home from now on. The shift is not distance flown (the odometer
    /// restarts its differences at the next frame), and the closed loop's
    /// capture, in the old frame, is forgotten.
    pub fn set_local(&mut self, local: LocalFrame) {
        self.local = local;
        self.last_ne_m = None;
        if let Some(cl) = &mut self.closed_loop {
            *cl = ClosedLoop::default();
        }
    }

    pub fn model(&self) -> &'static str {
        self.estimator.params().model.as_str()
    }

    pub fn on_frame(&mut self, f: FrameInput) -> StepOutcome {
        let pose = match f.pose {
            Ok(p) if p.pos_ned_m.is_finite() && p.q.is_finite() => p,
            Ok(_) => {
                return StepOutcome::Suspended {
                    reason: "pose with non-finite values".into(),
                }
            }
            Err(reason) => return StepOutcome::Suspended { reason },
        };
        // Distance flown, horizontally, frame to frame: the trigger's odometer.
        let ne = [pose.pos_ned_m.x, pose.pos_ned_m.y];
        if let Some(last) = self.last_ne_m {
            self.odometer_m += (ne[0] - last[0]).hypot(ne[1] - last[1]);
        }
        self.last_ne_m = Some(ne);
        // Scan along the image axis nearest the direction of flight, with the
        // camera's tilt along it (a belly camera tilts forward as the nose goes up).
        let cam_to_ned =
            DMat3::from_quat(pose.q) * camera_to_body(self.params.camera_mount_pitch_rad);
        let (axis, camera_pitch) = flight_axis(&cam_to_ned, pose.vel_ned_mps, self.fixed_axis);
        self.estimator.set_track_axis(axis);
        let estimate = match f.depth {
            None => Estimate::without_depth(camera_pitch),
            Some(depth) => match self.estimator.estimate(depth, f.intrinsics, camera_pitch) {
                Ok((e, _)) => e,
                Err(e) => {
                    return StepOutcome::Suspended {
                        reason: format!("depth frame does not match the intrinsics: {e}"),
                    }
                }
            },
        };
        let speed = pose.vel_ned_mps.x.hypot(pose.vel_ned_mps.y);
        let next_step_m = speed * self.params.frame_period_s;
        // The closed loop: this frame against the last capture, in full 6-DoF.
        let view = match (&self.closed_loop, f.depth) {
            (Some(_), Some(depth)) if estimate.is_ok() => Some(View {
                depth: DepthSnapshot::kept(depth, f.intrinsics),
                cam_to_ned,
                pos_ned_m: pose.pos_ned_m,
            }),
            _ => None,
        };
        let q = self.estimator.params().quality;
        let targets = ClosedLoopTargets {
            parallax_px: q.parallax_px,
            unseen_fraction_max: q.unseen_fraction_max,
        };
        let measure = match (&mut self.closed_loop, &view) {
            (Some(cl), Some(v)) => cl.on_frame(v.clone(), self.odometer_m, next_step_m, &targets),
            _ => None,
        };
        let closed_m = measure.and_then(|m| m.spacing_m);
        let spacing_m = match (estimate.spacing.chosen_m, closed_m) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        let decision = self.trigger.update(&Opportunity {
            time_s: f.mono_ns as f64 * 1e-9,
            odometer_m: self.odometer_m,
            next_step_m,
            spacing_m,
            pose_fresh: true,
        });
        let capture = match decision {
            Decision::Capture(c) => c,
            Decision::Wait => {
                return StepOutcome::Wait {
                    estimate: Box::new(estimate),
                }
            }
            Decision::Suspended => {
                return StepOutcome::Suspended {
                    reason: "trigger suspended".into(),
                }
            }
        };
        self.seq += 1;
        if let (Some(cl), Some(v)) = (&mut self.closed_loop, view) {
            cl.on_capture(v, self.odometer_m);
        }
        let record = capture_record(&RecordInputs {
            seq: self.seq,
            mono_ns: f.mono_ns,
            pose: &pose,
            boot_us: f.boot_us,
            unix_us: f.unix_us,
            local: &self.local,
            estimate: Some(&estimate),
            closed_loop: measure.as_ref(),
            capture: &capture,
            model: self.estimator.params().model.as_str(),
            mode: self.params.capture_mode,
            image_format: self.params.image_format,
            intrinsics: Some(f.intrinsics),
            mount_pitch_rad: self.params.camera_mount_pitch_rad,
        });
        StepOutcome::Capture {
            estimate: Box::new(estimate),
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
            assert!(r.intrinsics.is_some() && r.model == "quality");
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
