//! One depth frame through the trigger's decision: the flight axis and camera tilt from
//! the frame's pose, the estimate, the closed loop against the last capture, the distance
//! flown, and whether to capture. Frames, poses and instants are arguments, so the
//! flight, `alfd sim` and the tests run the same decision. What a decided capture is then
//! written as (the manifest line) is the daemon's.

use crate::attitude::{camera_to_body, flight_axis};
use crate::closedloop::{ClosedLoop, ClosedLoopTargets, DepthSnapshot, Measure, View};
use crate::pose::Pose;
use crate::trigger::{Capture, Decision, Opportunity, Trigger, TriggerParams};
use crate::visibility::SweepWorkers;
use crate::{DepthImage, Estimate, Estimator, EstimatorParams, Intrinsics, TrackAxis};
use glam::{DMat3, DVec3};

/// What the decision needs besides the estimator and trigger settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepParams {
    /// Camera tilt about the vehicle's right axis: 0 = nadir, positive = forward.
    pub camera_mount_pitch_rad: f64,
    /// Time between depth frames, seconds (the next opportunity).
    pub frame_period_s: f64,
}

/// One depth frame (or an opportunity without one: the depth camera stalled) and the
/// pose at its instant.
pub struct FrameInput<'a> {
    pub mono_ns: u64,
    /// `None`: no depth frame came in time; the fallback spacing decides.
    pub depth: Option<&'a DepthImage>,
    pub intrinsics: &'a Intrinsics,
    /// The pose interpolated to `mono_ns`, or why there is none (stale, not synced).
    pub pose: Result<Pose, String>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum StepOutcome {
    /// No usable pose: nothing may be captured.
    Suspended {
        reason: String,
    },
    Wait {
        estimate: Box<Estimate>,
    },
    Capture(Box<Decided>),
}

/// A capture the trigger decided, and everything that decided it.
#[derive(Debug, Clone, PartialEq)]
pub struct Decided {
    /// Numbered from 1, after [`Pipeline::set_last_seq`].
    pub seq: u64,
    pub pose: Pose,
    pub estimate: Estimate,
    pub capture: Capture,
    /// The closed loop's measurement at this frame, when it is on and measured.
    pub closed_loop: Option<Measure>,
}

/// The spacing the trigger flies with the closed loop on: the tighter of the
/// open loop's and the closed loop's, whichever of them there is.
pub fn tighter(open_m: Option<f64>, closed_m: Option<f64>) -> Option<f64> {
    match (open_m, closed_m) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

pub struct Pipeline {
    estimator: Estimator,
    trigger: Trigger,
    params: StepParams,
    odometer_m: f64,
    last_ne_m: Option<[f64; 2]>,
    seq: u64,
    /// `Some` when `[trigger] closed_loop` is on.
    closed_loop: Option<ClosedLoop>,
    /// The configured scan axis, used while the vehicle hovers.
    fixed_axis: TrackAxis,
    /// The last capture's number, its frame's instant (the caller's clock) and the
    /// extrapolated pose its odometer reading came from, until its position is located
    /// ([`Pipeline::capture_located`]).
    unlocated: Option<(u64, u64, Pose)>,
}

impl Pipeline {
    pub fn new(estimator: EstimatorParams, trigger: TriggerParams, params: StepParams) -> Self {
        Pipeline {
            fixed_axis: estimator.track_axis,
            estimator: Estimator::new(estimator),
            trigger: Trigger::new(trigger),
            params,
            odometer_m: 0.0,
            last_ne_m: None,
            seq: 0,
            closed_loop: trigger.closed_loop.then(ClosedLoop::default),
            unlocated: None,
        }
    }

    /// The last capture's number and its frame's instant (`FrameInput::mono_ns`), while its
    /// position is still the extrapolated one the trigger measured from.
    pub fn unlocated_capture(&self) -> Option<(u64, u64)> {
        self.unlocated.map(|(seq, mono_ns, _)| (seq, mono_ns))
    }

    /// Capture `seq`'s position once the autopilot's later samples place it (interpolated, not
    /// extrapolated): the trigger measures the interval from there. The pose a frame is decided
    /// with runs up to one telemetry period past the newest sample, so its error (a few
    /// millimetres where the acceleration changes) would otherwise enter the next interval.
    pub fn capture_located(&mut self, seq: u64, pos_ned_m: DVec3) {
        let Some((s, _, decided)) = self.unlocated else {
            return;
        };
        if s != seq {
            return;
        }
        self.unlocated = None;
        let v = decided.vel_ned_mps;
        let speed = v.x.hypot(v.y);
        if !(speed > 1e-3 && pos_ned_m.is_finite()) {
            return;
        }
        let d = pos_ned_m - decided.pos_ned_m;
        let along_m = (d.x * v.x + d.y * v.y) / speed;
        // More than a metre is not a refinement (a moved origin, a re-anchored track).
        if along_m.abs() <= 1.0 {
            self.trigger.shift_reference(along_m);
        }
    }

    /// Lends the estimator's visibility sweep threads ([`Estimator::set_sweep_workers`]).
    pub fn set_sweep_workers(&mut self, workers: std::sync::Arc<dyn SweepWorkers>) {
        self.estimator.set_sweep_workers(workers);
    }

    /// Horizontal distance flown, frame to frame, since the start.
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

    pub fn model(&self) -> &'static str {
        self.estimator.params().model.as_str()
    }

    /// The autopilot's origin moved: the shift is not distance flown (the odometer
    /// restarts its differences at the next frame), and the closed loop's capture, in
    /// the old frame, is forgotten.
    pub fn origin_moved(&mut self) {
        self.last_ne_m = None;
        self.unlocated = None;
        if let Some(cl) = &mut self.closed_loop {
            *cl = ClosedLoop::default();
        }
    }

    pub fn on_frame(&mut self, f: FrameInput) -> StepOutcome {
        let pose = match f.pose {
            Ok(p) if p.pos_ned_m.is_finite() && p.q.is_finite() && p.vel_ned_mps.is_finite() => p,
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
        let spacing_m = tighter(estimate.spacing.chosen_m, closed_m);
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
        // An interpolated pose is as good as it gets already.
        self.unlocated = (pose.extrapolated_ns > 0).then_some((self.seq, f.mono_ns, pose));
        if let (Some(cl), Some(v)) = (&mut self.closed_loop, view) {
            cl.on_capture(v, self.odometer_m);
        }
        StepOutcome::Capture(Box::new(Decided {
            seq: self.seq,
            pose,
            estimate,
            capture,
            closed_loop: measure,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DepthData;
    use glam::{DQuat, DVec3};

    const PERIOD_NS: u64 = 33_333_333;

    fn pipeline(closed_loop: bool) -> Pipeline {
        let trigger = TriggerParams {
            rate_max_hz: 1000.0,
            closed_loop,
            ..TriggerParams::default()
        };
        let params = StepParams {
            camera_mount_pitch_rad: 0.0,
            frame_period_s: 1.0 / 30.0,
        };
        Pipeline::new(EstimatorParams::default(), trigger, params)
    }

    fn pose(k: u64, x_m: f64) -> Pose {
        Pose {
            time_ns: k * PERIOD_NS,
            pos_ned_m: DVec3::new(x_m, 0.0, -40.0),
            vel_ned_mps: DVec3::new(10.0, 0.0, 0.0),
            q: DQuat::IDENTITY,
            extrapolated_ns: 0,
        }
    }

    /// Level ground 40 m below a nadir camera, flown north at 10 m/s and 30 fps; `pose_of`
    /// gives each frame's pose (or why there is none).
    fn fly(
        p: &mut Pipeline,
        frames: u64,
        pose_of: impl Fn(u64) -> Result<Pose, String>,
    ) -> Vec<StepOutcome> {
        let intr = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
        let ground = DepthImage::new(64, 48, DepthData::Metres(vec![40.0; 64 * 48])).unwrap();
        (0..frames)
            .map(|k| {
                p.on_frame(FrameInput {
                    mono_ns: k * PERIOD_NS,
                    depth: Some(&ground),
                    intrinsics: &intr,
                    pose: pose_of(k),
                })
            })
            .collect()
    }

    fn decided(out: &[StepOutcome]) -> Vec<&Decided> {
        out.iter()
            .filter_map(|o| match o {
                StepOutcome::Capture(d) => Some(d.as_ref()),
                _ => None,
            })
            .collect()
    }

    /// Over level ground (no depth range, so no parallax between depths: the views per
    /// point decide): captures numbered on, each interval within the estimate's spacing
    /// and less than one frame's step short of it (as few captures as keep it), the
    /// odometer the distance flown.
    #[test]
    fn captures_over_level_ground_keep_the_estimates_spacing() {
        let mut p = pipeline(false);
        p.set_last_seq(41);
        let out = fly(&mut p, 300, |k| Ok(pose(k, 10.0 * k as f64 / 30.0)));
        let caps = decided(&out);
        assert!(caps.len() >= 4, "{} captures in 99.7 m", caps.len());
        for (i, d) in caps.iter().enumerate() {
            assert_eq!(d.seq, 42 + i as u64);
            let spacing = d
                .estimate
                .spacing
                .chosen_m
                .expect("an estimate over ground");
            assert!(d.capture.spacing_m <= spacing + 1e-9);
            if let Some(flown) = d.capture.distance_since_last_m {
                assert!(flown <= spacing + 1e-9, "{flown} m flown for {spacing} m");
                assert!(
                    flown > spacing - 10.0 / 30.0,
                    "{flown} m flown for {spacing} m"
                );
                assert!(!d.capture.undersampled);
            }
            assert!(d.closed_loop.is_none(), "the closed loop is off");
        }
        assert!((p.odometer_m() - 10.0 * 299.0 / 30.0).abs() < 1e-9);
    }

    /// No pose, or one with a non-finite value, suspends with the reason and moves
    /// nothing: not the odometer, not the numbering.
    #[test]
    fn a_missing_or_non_finite_pose_suspends_and_counts_nothing() {
        let mut p = pipeline(true);
        let bad = |k: u64| match k % 3 {
            0 => Err("stale".to_string()),
            1 => Ok(Pose {
                pos_ned_m: DVec3::new(f64::NAN, 0.0, -40.0),
                ..pose(k, 0.0)
            }),
            _ => Ok(Pose {
                vel_ned_mps: DVec3::new(f64::INFINITY, 0.0, 0.0),
                ..pose(k, 0.0)
            }),
        };
        for (k, o) in fly(&mut p, 9, bad).iter().enumerate() {
            let StepOutcome::Suspended { reason } = o else {
                panic!("frame {k}: {o:?}");
            };
            let want = if k % 3 == 0 {
                "stale"
            } else {
                "pose with non-finite values"
            };
            assert_eq!(reason, want);
        }
        assert_eq!(p.odometer_m(), 0.0);
        let out = fly(&mut p, 2, |k| Ok(pose(k, k as f64)));
        assert_eq!(decided(&out)[0].seq, 1, "{out:?}");
    }

    /// A moved origin is not distance flown: the odometer resumes from the next frame.
    #[test]
    fn a_moved_origin_is_not_distance_flown() {
        let mut p = pipeline(true);
        fly(&mut p, 4, |k| Ok(pose(k, k as f64)));
        assert_eq!(p.odometer_m(), 3.0);
        p.origin_moved();
        fly(&mut p, 3, |k| Ok(pose(k, 1000.0 + k as f64)));
        assert_eq!(p.odometer_m(), 5.0);
    }

    /// A capture decided on an extrapolated pose is measured from where it was once the later
    /// samples place it: 4 cm further along, the next capture comes 4 cm later; only the last
    /// capture's location counts, once, and an interpolated pose needs none.
    #[test]
    fn the_next_interval_is_measured_from_the_located_capture() {
        let extrapolated = |k: u64| {
            Ok(Pose {
                extrapolated_ns: 50_000_000,
                ..pose(k, 10.0 * k as f64 / 30.0)
            })
        };
        let (mut plain, mut located) = (pipeline(false), pipeline(false));
        let first = |p: &mut Pipeline| {
            let out = fly(p, 1, extrapolated);
            assert_eq!(decided(&out).len(), 1);
            p.unlocated_capture()
                .expect("decided on an extrapolated pose")
        };
        let (seq, at_ns) = first(&mut plain);
        assert_eq!((seq, at_ns), (1, 0));
        first(&mut located);
        located.capture_located(7, DVec3::new(0.04, 0.0, -40.0));
        assert!(
            located.unlocated_capture().is_some(),
            "not the last capture"
        );
        located.capture_located(1, DVec3::new(0.04, 0.0, -40.0));
        assert!(located.unlocated_capture().is_none());
        // A second location of the same capture changes nothing.
        located.capture_located(1, DVec3::new(0.5, 0.0, -40.0));
        let next = |p: &mut Pipeline| {
            let out: Vec<StepOutcome> = (1..300u64)
                .map(|k| {
                    let intr = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
                    let ground =
                        DepthImage::new(64, 48, DepthData::Metres(vec![40.0; 64 * 48])).unwrap();
                    p.on_frame(FrameInput {
                        mono_ns: k * PERIOD_NS,
                        depth: Some(&ground),
                        intrinsics: &intr,
                        pose: extrapolated(k),
                    })
                })
                .collect();
            let d = decided(&out);
            (
                d[0].capture.distance_since_last_m.unwrap(),
                d[0].capture.spacing_m,
            )
        };
        let (flown_plain, spacing) = next(&mut plain);
        let (flown_located, _) = next(&mut located);
        // The odometer reads 4 cm less for the same frames: a frame's step is 33 cm, so the
        // capture lands on the same frame or the next, and the interval it reports is what
        // was flown from the located capture.
        assert!(flown_plain <= spacing + 1e-9 && flown_located <= spacing + 1e-9);
        let frames_plain = ((flown_plain) * 3.0).round();
        let frames_located = ((flown_located + 0.04) * 3.0).round();
        assert!(
            frames_located >= frames_plain,
            "{flown_plain} {flown_located}"
        );
        assert!(
            ((flown_located + 0.04) * 3.0 - frames_located).abs() < 1e-9,
            "{flown_located} m from the located capture is not a whole number of frames less 4 cm"
        );
        // An interpolated pose is never located again.
        let mut p = pipeline(false);
        fly(&mut p, 1, |k| Ok(pose(k, 0.0)));
        assert!(p.unlocated_capture().is_none());
    }
}
