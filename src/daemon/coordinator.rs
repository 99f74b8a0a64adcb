//! The daemon's decisions between the estimator, the link and the writer, as a pure state
//! machine: events and the time in, [`Action`]s out. It numbers the manifest (every capture,
//! whoever decided it, gets the next `seq`), schedules the captures ground stations command,
//! keeps the autopilot-trigger bookkeeping and the camera's capture activity, and says what
//! happens by STATUSTEXT. The loop in `run.rs` performs the actions.

use std::collections::{BTreeMap, VecDeque};

use super::camera::{
    camera_q_ned, CameraInfo, CameraProtocol, CaptureActivity, CaptureCommand, Captured,
    StorageState,
};
use super::step::{capture_record, relocate, RecordInputs};
use crate::capture::{image_file_name, CaptureMode, CaptureRecord, ImageFormat};
use crate::config::{CameraCommand, Config};
use crate::core::distset::{
    Counting, DistanceSetter, DistanceSetterParams, SinceLastPicture, ARDUPILOT_CAMERA_UPDATE_S,
    PX4_TRIGGER_POLL_S,
};
use crate::core::estimate::Terms;
use crate::core::geo::LocalFrame;
use crate::core::pose::Pose;
use crate::core::trigger::{self, Capture, Trigger};
use crate::core::{Estimate, Intrinsics};
use crate::link::LinkEvent;
use mavlink::dialects::ardupilotmega::*;

/// Messages and errors kept in the report; beyond, only counted.
pub const REPORT_KEEP: usize = 1000;
/// Captures waiting for their pose (a command burst, an autopilot trigger storm); beyond,
/// a capture is reported failed at once rather than queued without bound.
pub const LOCATING_MAX: usize = 256;
/// NAMED_VALUE_FLOAT of the fastest ground speed the rate limit allows at the spacing (m/s).
pub const NAME_VMAX: &str = "ALF_VMAX";
/// The quality model's predictions at the spacing in force, once a second:
/// parallax (px), forward overlap (0–1), unseen fraction (0–1), views per
/// point, and the bound that set the spacing as `Bound::code`.
pub const NAME_PARALLAX: &str = "ALF_PAR";
pub const NAME_OVERLAP: &str = "ALF_FOV";
pub const NAME_UNSEEN: &str = "ALF_UNS";
pub const NAME_VIEWS: &str = "ALF_VPP";
pub const NAME_BOUND: &str = "ALF_BND";
const SECOND_NS: u64 = 1_000_000_000;
/// At most one "too fast" STATUSTEXT in this long.
const TOO_FAST_EVERY_NS: u64 = 10_000_000_000;
/// At most this often a STATUSTEXT says a picture's report matched no capture.
const UNMATCHED_EVERY_NS: u64 = 10_000_000_000;
/// At most this often a STATUSTEXT says which terms the estimate used.
const TERMS_EVERY_NS: u64 = 10_000_000_000;
/// At most this often a STATUSTEXT says the spacing floor holds captures over the permissible.
const FLOOR_EVERY_NS: u64 = 10_000_000_000;
/// `camera_command`: how long after its decision a capture waits for the autopilot to say it
/// took the picture (CAMERA_TRIGGER, CAMERA_FEEDBACK) before it is logged where it was decided.
pub const PICTURE_WAIT_NS: u64 = 1_000_000_000;
/// After this many captures in a row the autopilot did not report, captures stop waiting (its
/// camera reports nothing); its next report makes them wait again.
pub const UNREPORTED_IN_ROW_MAX: u32 = 3;
/// A report this long before a capture's decision can still be its picture (time sync's error).
const PICTURE_EARLY_NS: u64 = 5_000_000;
/// How many of the latest decision-to-picture delays give the usual one.
const PICTURE_DELAYS_KEPT: usize = 8;

/// What the daemon's clocks say now.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Now {
    pub mono_ns: u64,
    /// The autopilot's boot clock, 0 while time is not in sync.
    pub boot_ms: u32,
}

/// A suspension whose reason changes is said again at most this often.
const SUSPENSION_REPEAT_NS: u64 = 10_000_000_000;

/// The estimator's latest word (a latest-value: intermediate ones may be skipped).
#[derive(Clone, Debug, PartialEq)]
pub enum EstimatorView {
    Suspended {
        reason: String,
    },
    Estimate {
        mono_ns: u64,
        estimate: Box<Estimate>,
    },
}

/// Where a capture the coordinator took itself was (from the link, by the loop).
pub struct Located {
    pub pose: Pose,
    pub boot_us: Option<u64>,
    pub unix_us: Option<u64>,
    pub local: LocalFrame,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    Send(Box<MavMessage>),
    /// Find the pose at `mono_ns`, then call [`Coordinator::on_located`] with `id`.
    Locate {
        id: u64,
        mono_ns: u64,
    },
    /// Log this capture (image, manifest line); the writer answers with
    /// [`Coordinator::on_capture_written`].
    Write(Box<CaptureRecord>),
}

/// Which report of the autopilot's picture (`PictureReports`).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Report {
    /// The IMAGE_START_CAPTURE ArduPilot's MAVLinkCamV2 backend sends the camera.
    Command,
    /// Its CAMERA_FEEDBACK.
    Feedback,
}

/// How many of one kind of report are kept to match the other kind against.
const REPORTS_KEPT: usize = 8;

/// ArduPilot reports a picture of its MAVLinkCamV2 backend twice: the IMAGE_START_CAPTURE it
/// sends the camera (param4, the image index) and a CAMERA_FEEDBACK (`img_idx`, the same
/// index), the command first on its own link but in either order here. Its servo and relay
/// backends send the feedback alone. A picture is logged at its first report; a report whose
/// index is among the last few of the other kind is its echo. An autopilot that sends
/// CAMERA_TRIGGER (PX4) is heard by those; its feedbacks, if any, are not counted again.
#[derive(Debug, Default)]
struct PictureReports {
    commands: VecDeque<u16>,
    feedbacks: VecDeque<u16>,
    /// A CAMERA_TRIGGER came since the autopilot booted.
    trigger_seen: bool,
}

impl PictureReports {
    /// Whether this report is its picture's first.
    fn first(&mut self, report: Report, index: u16) -> bool {
        if report == Report::Feedback && self.trigger_seen {
            return false;
        }
        let (mine, other) = match report {
            Report::Command => (&mut self.commands, &mut self.feedbacks),
            Report::Feedback => (&mut self.feedbacks, &mut self.commands),
        };
        if let Some(k) = other.iter().position(|&i| i == index) {
            other.remove(k);
            return false;
        }
        if mine.len() == REPORTS_KEPT {
            mine.pop_front();
        }
        mine.push_back(index);
        true
    }
}

/// Who asked for a capture the coordinator takes itself.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Asked {
    /// A ground station's command.
    Command { from: (u8, u8) },
    /// The autopilot's distance trigger: CAMERA_TRIGGER, or its IMAGE_START_CAPTURE
    /// (ArduPilot's MAVLinkCamV2 backend sends one per trigger); with the tightest
    /// spacing of the frames in the interval it closes (`None`: none heard of).
    Autopilot {
        from: Option<(u8, u8)>,
        tightest_m: Option<f64>,
    },
}

/// A capture waiting for its pose.
struct Waiting {
    what: Awaits,
    mono_ns: u64,
    answer: Answer,
    /// The [`Action::Locate`] whose answer this capture takes (a picture reported later is
    /// located again, and the earlier answer is then stale).
    locate_id: u64,
    picture: Picture,
}

/// A `camera_command` capture and the autopilot's report of its picture.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Picture {
    /// Not waited for.
    NotAwaited,
    /// Waiting for the autopilot's report until this instant.
    Awaited { until_ns: u64 },
    /// Reported taken at this instant, where the capture is located.
    Reported { mono_ns: u64 },
}

enum Answer {
    Pending,
    Located(Box<Result<Located, String>>),
    /// A decided capture whose pose was already interpolated, in line behind others.
    NotNeeded,
}

enum Awaits {
    /// A capture the coordinator takes itself: its record is made from the pose.
    Asked(Asked),
    /// The estimator's decided capture, whose pose reached past the newest telemetry:
    /// written with the pose interpolated once the sample after it is in, or as decided.
    Decided(Box<CaptureRecord>),
}

/// An interval capture a ground station started.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Interval {
    from: (u8, u8),
    interval_ns: u64,
    /// Images still to take; `None` until stopped.
    remaining: Option<u32>,
    next_ns: u64,
}

/// Counters the run's report takes over at the end.
#[derive(Debug, Default, Clone)]
pub struct CoordinatorReport {
    /// Where each answered capture's time went (filled by the outbox, which holds the clock).
    pub latency: super::latency::LatencyLog,
    pub captures_decided: u64,
    pub command_captures: u64,
    pub camera_commands: u64,
    pub camera_command_failures: u64,
    /// `camera_command` captures whose command the autopilot refused: logged where decided
    /// at its answer, without waiting for a picture.
    pub pictures_refused: u64,
    pub autopilot_triggers: u64,
    /// Of those, the pictures known by the autopilot's CAMERA_FEEDBACK alone (ArduPilot's
    /// servo and relay cameras), and of these the ones placed at the feedback's arrival
    /// (its GPS time stamp could not be mapped: no SYSTEM_TIME with UTC yet).
    pub autopilot_feedbacks: u64,
    pub feedbacks_timed_on_arrival: u64,
    /// `camera_command`: captures placed at the instant the autopilot reported their picture,
    /// captures that waited for a report in vain (logged where decided), and reports no
    /// waiting capture took.
    pub pictures_reported: u64,
    pub pictures_unreported: u64,
    pub reports_unmatched: u64,
    /// Captures written without their image, or not written (with the reason).
    pub captures_failed: u64,
    pub statustexts: Vec<String>,
    pub statustexts_dropped: u64,
}

pub struct Coordinator {
    config: Config,
    camera: CameraProtocol,
    setter: DistanceSetter,
    /// The frames since the autopilot's last picture (its distance counts from there).
    since_picture: SinceLastPicture,
    /// The autopilot's pictures by their two reports (`PictureReports`).
    picture_reports: PictureReports,
    /// The vehicle's ground speed, as last known (set with each estimate and tick).
    ground_speed_mps: Option<f64>,
    trigger: Trigger,
    intrinsics: Option<Intrinsics>,
    /// Whether alfd has a colour camera whose frames it saves.
    saves_frames: bool,
    suspended: Option<String>,
    /// When a suspension was last said (a new reason at most every 10 s).
    suspension_said_ns: u64,
    fallback: bool,
    terms: Option<Terms>,
    terms_said_ns: u64,
    /// Whether `sampling.spacing_min_m` holds the spacing above the permissible one
    /// (the targets broken), and when that was last said.
    floored: bool,
    floor_said_ns: Option<u64>,
    skipped_said: u64,
    last_estimate: Option<Box<Estimate>>,
    last_trigger_ne: Option<[f64; 2]>,
    last_capture_ne: Option<[f64; 2]>,
    seq: u64,
    next_id: u64,
    /// Captures waiting for their pose, in the order they were taken (ids rise): each is
    /// numbered and written once it and every capture before it has its answer, so the
    /// manifest stays in capture order.
    locating: BTreeMap<u64, Waiting>,
    interval: Option<Interval>,
    /// Captures handed to the writer and not yet answered (the camera is busy).
    writing: usize,
    last_second_ns: Option<u64>,
    too_fast_said_ns: Option<u64>,
    unmatched_said_ns: Option<u64>,
    /// `camera_command`: captures in a row whose picture the autopilot did not report, and
    /// the latest delays from a decision to its picture.
    unreported_in_row: u32,
    picture_delays_ns: VecDeque<u64>,
    /// `camera_command`: the captures whose command the autopilot has not answered yet, in
    /// the order sent (their key in `locating`, their decision's instant). Acks come in the
    /// order of the commands.
    unacked: VecDeque<(u64, u64)>,
    pub report: CoordinatorReport,
}

impl Coordinator {
    /// `last_seq`: the flight's manifest so far (numbering continues after it);
    /// `intrinsics`: of the saved frames, when alfd saves them.
    pub fn new(config: &Config, last_seq: u64, intrinsics: Option<Intrinsics>) -> Self {
        Coordinator {
            camera: CameraProtocol::new(CameraInfo::for_alfd(
                config.camera.width as u16,
                config.camera.height as u16,
            )),
            setter: DistanceSetter::new(DistanceSetterParams::default()),
            since_picture: SinceLastPicture::default(),
            picture_reports: PictureReports::default(),
            ground_speed_mps: None,
            trigger: Trigger::new(config.trigger),
            saves_frames: config.capture.mode == CaptureMode::Frame && intrinsics.is_some(),
            intrinsics,
            config: config.clone(),
            suspended: None,
            suspension_said_ns: 0,
            fallback: false,
            terms: None,
            terms_said_ns: 0,
            floored: false,
            floor_said_ns: None,
            skipped_said: 0,
            last_estimate: None,
            last_trigger_ne: None,
            last_capture_ne: None,
            seq: last_seq,
            next_id: 0,
            locating: BTreeMap::new(),
            interval: None,
            writing: 0,
            last_second_ns: None,
            too_fast_said_ns: None,
            unmatched_said_ns: None,
            unreported_in_row: 0,
            picture_delays_ns: VecDeque::new(),
            unacked: VecDeque::new(),
            report: CoordinatorReport::default(),
        }
    }

    pub fn camera(&self) -> &CameraProtocol {
        &self.camera
    }

    /// Captures waiting for their pose ([`Action::Locate`] not yet answered).
    pub fn locating(&self) -> usize {
        self.locating.len()
    }

    pub fn setter(&self) -> &DistanceSetter {
        &self.setter
    }

    /// The first words: what alfd will do.
    pub fn ready(&mut self) -> Vec<Action> {
        let c = &self.config;
        let terms = match c.estimator.model {
            crate::core::Model::Fixed => "fixed".to_string(),
            crate::core::Model::Quality => {
                // The targets in force, in one 50-byte chunk where they fit.
                let q = c.estimator.quality;
                let mut t = q.profile.as_str().to_string();
                if let Some(px) = q.parallax_px {
                    t += &format!(" {px}px");
                }
                if let Some(o) = q.forward_overlap {
                    t += &format!(" {:.0}%", 100.0 * o);
                }
                format!("{t} u{} k{}", q.unseen_fraction_max, q.views_per_point_min)
            }
            m => format!("{} model", m.as_str()),
        };
        let how = match c.capture.mode {
            CaptureMode::Frame => "frames",
            CaptureMode::CameraCommand => "by camera command",
            CaptureMode::AutopilotDistance => "by autopilot distance",
            CaptureMode::Command => "on command",
        };
        let text = format!("alfd ready: {terms}, capture {how}");
        let mut out = Vec::new();
        self.status(&mut out, MavSeverity::MAV_SEVERITY_INFO, &text);
        out
    }

    /// When [`Coordinator::on_tick`] has something to do next (an interval capture, a
    /// capture's wait for its picture's report ending).
    pub fn next_due_ns(&self) -> Option<u64> {
        let waits = self.locating.values().filter_map(|w| match w.picture {
            Picture::Awaited { until_ns } => Some(until_ns),
            _ => None,
        });
        self.interval
            .map(|i| i.next_ns)
            .into_iter()
            .chain(waits)
            .min()
    }

    /// The vehicle's ground speed now (kept until the next one known).
    pub fn set_ground_speed(&mut self, ground_speed_mps: Option<f64>) {
        if ground_speed_mps.is_some() {
            self.ground_speed_mps = ground_speed_mps;
        }
    }

    pub fn on_estimate(&mut self, view: EstimatorView, now: Now) -> Vec<Action> {
        let mut out = Vec::new();
        match view {
            EstimatorView::Suspended { reason } => {
                if self.suspended.as_deref() != Some(reason.as_str()) {
                    if self.suspended.is_none() {
                        let text = format!("alfd: triggers suspended: {reason}");
                        self.status(&mut out, MavSeverity::MAV_SEVERITY_WARNING, &text);
                        self.suspension_said_ns = now.mono_ns;
                    } else if now.mono_ns >= self.suspension_said_ns + SUSPENSION_REPEAT_NS {
                        // A new reason (no position yet, then on the ground) is
                        // what the operator must act on; at most one per 10 s.
                        let text = format!("alfd: still suspended: {reason}");
                        self.status(&mut out, MavSeverity::MAV_SEVERITY_WARNING, &text);
                        self.suspension_said_ns = now.mono_ns;
                    }
                    self.suspended = Some(reason);
                }
            }
            EstimatorView::Estimate { mono_ns, estimate } => {
                if self.suspended.take().is_some() {
                    self.status(
                        &mut out,
                        MavSeverity::MAV_SEVERITY_NOTICE,
                        "alfd: triggers resumed",
                    );
                }
                let _ = now;
                self.estimate(&mut out, estimate, mono_ns);
            }
        }
        out
    }

    fn spacing_of(&self, e: &Estimate) -> f64 {
        e.spacing
            .chosen_m
            .unwrap_or(self.config.trigger.fallback_spacing_m)
    }

    fn estimate(&mut self, out: &mut Vec<Action>, e: Box<Estimate>, mono: u64) {
        let spacing = self.spacing_of(&e);
        let fallback = e.spacing.chosen_m.is_none();
        if fallback != self.fallback {
            self.fallback = fallback;
            let text = match (&e.no_estimate, fallback) {
                (Some(why), true) => format!(
                    "alfd: no estimate ({}), fallback spacing {:.1} m",
                    crate::report::no_estimate_reason(*why, &e, &self.config.estimator),
                    self.config.trigger.fallback_spacing_m
                ),
                (_, true) => "alfd: no estimate, fallback spacing".to_string(),
                (_, false) => "alfd: estimating again".to_string(),
            };
            self.status(out, MavSeverity::MAV_SEVERITY_NOTICE, &text);
        }
        // Which terms the estimate used: said when they change (a scene without occlusion
        // boundaries drops the occlusion term), not more than every 10 s.
        if e.is_ok() && self.terms != Some(e.terms) && mono >= self.terms_said_ns + TERMS_EVERY_NS {
            self.terms = Some(e.terms);
            self.terms_said_ns = mono;
            let bound = e.active_bound.map_or("config limit", |b| b.as_str());
            let text = format!("alfd: terms {}; bound {bound}", e.terms.names().join(", "));
            self.status(out, MavSeverity::MAV_SEVERITY_INFO, &text);
        }
        // Captures held above the permissible spacing by the floor break the
        // targets the operator set: said when it starts, at most every 10 s.
        let floored = e.floor_over_permissible();
        if let Some((chosen, permissible)) = floored.filter(|_| !self.floored) {
            if due_every(&mut self.floor_said_ns, mono, FLOOR_EVERY_NS) {
                let text = format!(
                    "alfd: sampling.spacing_min_m {chosen:.2} m is over the permissible {permissible:.3} m: targets not met"
                );
                self.status(out, MavSeverity::MAV_SEVERITY_WARNING, &text);
            }
        }
        self.floored = floored.is_some();
        if self.config.capture.mode == CaptureMode::AutopilotDistance {
            // Counted from the last picture, the distance spans every frame
            // since: it must meet the tightest of their spacings, not only
            // this frame's (a spacing growing past open ground would
            // otherwise stretch the interval begun before it).
            self.since_picture.on_spacing(mono, spacing);
            let counting = self.setter.counting();
            let wanted = match counting {
                Counting::FromCommand => spacing,
                Counting::FromLastPicture => self.since_picture.tightest_m().unwrap_or(spacing),
            };
            // Less the way flown while the autopilot has yet to check (at the
            // link's latest ground speed; none before the first velocity).
            let wish = self
                .setter
                .wish_m(wanted, self.ground_speed_mps.unwrap_or(0.0));
            if let Some(d) = self.setter.update(mono as f64 * 1e-9, wish) {
                // Trigger once now where the autopilot counts the new distance
                // from the command (docs/daemon.md, what each autopilot does).
                let once = if self.setter.trigger_now() { 1.0 } else { 0.0 };
                out.push(send(command(
                    self.target_system(),
                    1,
                    MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST,
                    [d as f32, 0.0, once, 0.0, 0.0, 0.0, 0.0],
                )));
            }
        }
        self.last_estimate = Some(e);
    }

    fn target_system(&self) -> u8 {
        self.config.link.as_ref().map_or(1, |l| l.system_id)
    }

    /// A capture the estimator's trigger decided (its `seq` is replaced by the manifest's).
    pub fn on_decided(&mut self, record: CaptureRecord) -> Vec<Action> {
        let mut out = Vec::new();
        self.report.captures_decided += 1;
        match self.config.capture.mode {
            CaptureMode::Frame | CaptureMode::Command => {}
            CaptureMode::CameraCommand => {
                // Its manifest number: after the captures still waiting for their pose.
                let seq = self.seq + 1 + self.locating.len() as u64;
                let sys = self.target_system();
                let msg = match self.config.capture.command {
                    CameraCommand::ImageStartCapture => command(
                        sys,
                        0,
                        MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
                        [0.0, 0.0, 1.0, seq as f32, 0.0, 0.0, 0.0],
                    ),
                    CameraCommand::DigicamControl => command(
                        sys,
                        0,
                        MavCmd::MAV_CMD_DO_DIGICAM_CONTROL,
                        [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
                    ),
                };
                self.report.camera_commands += 1;
                out.push(send(msg));
            }
            // The autopilot takes the pictures; its triggers are logged.
            CaptureMode::AutopilotDistance => return out,
        }
        let mono_ns = record.mono_ns;
        // An external camera's picture comes after the command: where the autopilot says it
        // took it (its CAMERA_TRIGGER or CAMERA_FEEDBACK), the capture is placed.
        let picture = if self.config.capture.mode == CaptureMode::CameraCommand
            && self.unreported_in_row < UNREPORTED_IN_ROW_MAX
        {
            Picture::Awaited {
                until_ns: mono_ns + PICTURE_WAIT_NS,
            }
        } else {
            Picture::NotAwaited
        };
        let extrapolated = record.pose_age_ms > 0.0;
        let what = Awaits::Decided(Box::new(record));
        let awaited = matches!(picture, Picture::Awaited { .. });
        if extrapolated && self.locating.len() < LOCATING_MAX {
            self.wait_for_pose(&mut out, what, mono_ns, picture);
        } else {
            // In line after any capture still waiting for its pose; written at once when
            // there is none. (With LOCATING_MAX waiting, one more decided capture goes past
            // the bound rather than being lost; the estimator decides at most one per frame.)
            self.next_id += 1;
            let waiting = Waiting {
                what,
                mono_ns,
                answer: Answer::NotNeeded,
                locate_id: self.next_id,
                picture,
            };
            self.locating.insert(self.next_id, waiting);
            self.write_in_order(&mut out);
        }
        if awaited {
            // Its command's answer is due; a capture whose answer never came (a lost ack)
            // is not kept past the wait for its picture.
            if self.unacked.len() == LOCATING_MAX {
                self.unacked.pop_front();
            }
            self.unacked.push_back((self.next_id, mono_ns));
        }
        out
    }

    /// The next manifest number, and the image name that goes with it.
    fn number(&mut self, record: &mut CaptureRecord) {
        self.seq += 1;
        record.seq = self.seq;
        if record.image.is_some() {
            record.image = Some(image_file_name(self.seq, self.image_format()));
        }
    }

    fn image_format(&self) -> ImageFormat {
        self.config.capture.image_format
    }

    fn write(&mut self, out: &mut Vec<Action>, record: CaptureRecord) {
        self.last_capture_ne = Some([record.position.north_m, record.position.east_m]);
        self.writing += 1;
        self.sync_activity();
        out.push(Action::Write(Box::new(record)));
    }

    pub fn on_link_event(&mut self, ev: LinkEvent, now: Now) -> Vec<Action> {
        let mut out = Vec::new();
        match ev {
            LinkEvent::Command {
                system_id,
                component_id,
                command,
                params,
                trust,
            } => {
                for m in self.camera.on_command(
                    command,
                    params,
                    system_id,
                    component_id,
                    trust,
                    now.boot_ms,
                ) {
                    out.push(send(m));
                }
                for c in self.camera.take_capture_commands() {
                    self.on_command(&mut out, c, now);
                }
            }
            LinkEvent::CommandAck { command, result } => {
                let accepted = result == MavResult::MAV_RESULT_ACCEPTED as u8;
                if command == MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST as u32 {
                    self.setter.on_ack(accepted);
                } else if result != MavResult::MAV_RESULT_IN_PROGRESS as u8 {
                    // IN_PROGRESS is not an answer yet: the final ack follows.
                    self.on_camera_ack(&mut out, accepted, now.mono_ns);
                    if !accepted {
                        self.report.camera_command_failures += 1;
                        let text = format!("alfd: camera command {command} refused ({result})");
                        self.status(&mut out, MavSeverity::MAV_SEVERITY_WARNING, &text);
                    }
                }
            }
            LinkEvent::CameraTrigger {
                mono_ns: Some(t), ..
            } if self.config.capture.mode == CaptureMode::AutopilotDistance => {
                self.picture_reports.trigger_seen = true;
                self.autopilot_picture(&mut out, None, t);
            }
            LinkEvent::CameraTrigger {
                mono_ns: Some(t), ..
            } if self.config.capture.mode == CaptureMode::CameraCommand => {
                self.picture_reports.trigger_seen = true;
                self.picture_reported(&mut out, t);
            }
            LinkEvent::CameraFeedback {
                img_idx,
                mono_ns,
                received_mono_ns,
                ..
            } if self.config.capture.mode == CaptureMode::CameraCommand
                && self.picture_reports.first(Report::Feedback, img_idx) =>
            {
                self.picture_reported(&mut out, mono_ns.unwrap_or(received_mono_ns));
            }
            LinkEvent::CameraTrigger { mono_ns: None, .. }
                if self.config.capture.mode == CaptureMode::AutopilotDistance =>
            {
                self.picture_reports.trigger_seen = true;
                self.status(
                    &mut out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    "alfd: autopilot trigger before time sync: not logged",
                );
            }
            LinkEvent::CameraFeedback {
                img_idx,
                mono_ns,
                received_mono_ns,
                ..
            } if self.config.capture.mode == CaptureMode::AutopilotDistance
                && self.picture_reports.first(Report::Feedback, img_idx) =>
            {
                // ArduPilot's servo or relay camera: the feedback is all that says a
                // picture was taken. Its GPS time stamp places it; without one that maps,
                // its arrival does (a link latency late, as MAVLinkCamV2's command is).
                self.report.autopilot_feedbacks += 1;
                if mono_ns.is_none() {
                    self.report.feedbacks_timed_on_arrival += 1;
                }
                let from = self.autopilot_id();
                self.autopilot_picture(&mut out, from, mono_ns.unwrap_or(received_mono_ns));
            }
            LinkEvent::AutopilotFound { firmware } => {
                // Only ArduPilot is known to count from its last picture; PX4
                // and firmware-sim's generic autopilot count from the command.
                // Each checks its distance on its own clock (docs/daemon.md);
                // an autopilot not known is taken to fire at the point.
                let (counting, check_period_s) = match firmware {
                    MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA => {
                        (Counting::FromLastPicture, ARDUPILOT_CAMERA_UPDATE_S)
                    }
                    MavAutopilot::MAV_AUTOPILOT_PX4 => (Counting::FromCommand, PX4_TRIGGER_POLL_S),
                    _ => (Counting::FromCommand, 0.0),
                };
                self.setter.set_counting(counting);
                self.setter.set_check_period_s(check_period_s);
            }
            LinkEvent::AutopilotRebooted => {
                // Its trigger distance was set, not saved: send it again. Its image
                // index starts again too.
                self.setter.forget();
                self.picture_reports = PictureReports::default();
                self.status(
                    &mut out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    "alfd: autopilot rebooted, resynchronising time",
                )
            }
            LinkEvent::GpsGlitch { jump_m } => {
                let text = format!("alfd: GPS glitch ({jump_m:.1} m jump), position held");
                self.status(&mut out, MavSeverity::MAV_SEVERITY_WARNING, &text);
            }
            _ => {}
        }
        out
    }

    /// A capture command the camera protocol accepted: taken now (the next frame), or
    /// scheduled at its interval.
    fn on_command(&mut self, out: &mut Vec<Action>, c: CaptureCommand, now: Now) {
        match c {
            CaptureCommand::Start {
                from,
                interval_s,
                count,
                command,
                sequence,
            } => {
                let autopilot = self.config.capture.mode == CaptureMode::AutopilotDistance
                    && command == MavCmd::MAV_CMD_IMAGE_START_CAPTURE
                    && self.is_autopilot(from);
                if autopilot {
                    // ArduPilot's MAVLinkCamV2: its distance trigger's picture, unless its
                    // CAMERA_FEEDBACK came first.
                    let index = sequence.map(|s| s as u16);
                    if index.is_none_or(|i| self.picture_reports.first(Report::Command, i)) {
                        self.autopilot_picture(out, Some(from), now.mono_ns);
                    }
                    return;
                }
                self.report.command_captures += 1;
                self.locate(out, Asked::Command { from }, now.mono_ns);
                self.interval = (count != 1).then(|| Interval {
                    from,
                    interval_ns: (f64::from(interval_s) * 1e9) as u64,
                    remaining: (count > 1).then(|| count - 1),
                    next_ns: now.mono_ns + (f64::from(interval_s) * 1e9) as u64,
                });
            }
            CaptureCommand::Stop { .. } => self.interval = None,
        }
        self.sync_activity();
    }

    /// The autopilot's (system, component), as configured.
    fn autopilot_id(&self) -> Option<(u8, u8)> {
        let l = self.config.link.as_ref()?;
        Some((*l.accept_system_ids.first()?, l.autopilot_component_id))
    }

    fn is_autopilot(&self, from: (u8, u8)) -> bool {
        self.config.link.as_ref().is_some_and(|l| {
            l.accept_system_ids.first() == Some(&from.0) && l.autopilot_component_id == from.1
        }) || from.1 == 1
    }

    /// The autopilot's distance trigger took a picture at `mono_ns` (`from`: the
    /// component that said so, `None`: CAMERA_TRIGGER): it closes the interval
    /// since the last one, whose tightest spacing the record carries.
    fn autopilot_picture(&mut self, out: &mut Vec<Action>, from: Option<(u8, u8)>, mono_ns: u64) {
        let tightest_m = self.since_picture.on_picture(mono_ns);
        self.locate(out, Asked::Autopilot { from, tightest_m }, mono_ns);
    }

    fn locate(&mut self, out: &mut Vec<Action>, asked: Asked, mono_ns: u64) {
        if self.locating.len() >= LOCATING_MAX {
            self.report.captures_failed += 1;
            let text = "alfd: capture refused, too many waiting for a pose";
            self.status(out, MavSeverity::MAV_SEVERITY_ERROR, text);
            return;
        }
        self.wait_for_pose(out, Awaits::Asked(asked), mono_ns, Picture::NotAwaited);
    }

    /// The autopilot says it took a picture at `mono_ns` (`camera_command`): a capture
    /// decided before it that waits for its picture is located there. The first report
    /// goes to the oldest such capture (the picture may come after later decisions: an
    /// autopilot's and a camera's delay can exceed the time between captures); from then
    /// on each goes to the capture whose decision lies the usual delay before it (the
    /// median of the last few), so a command the camera missed leaves that one capture
    /// unreported instead of placing every later one at its successor's picture.
    fn picture_reported(&mut self, out: &mut Vec<Action>, mono_ns: u64) {
        self.unreported_in_row = 0;
        let usual_ns = median_u64(&self.picture_delays_ns);
        let waiting = self
            .locating
            .iter()
            .filter(|(_, w)| {
                matches!(w.picture, Picture::Awaited { .. })
                    && w.mono_ns <= mono_ns + PICTURE_EARLY_NS
            })
            .min_by_key(|(_, w)| match usual_ns {
                Some(d) => (w.mono_ns + d).abs_diff(mono_ns),
                None => w.mono_ns,
            })
            .map(|(k, w)| (*k, w.mono_ns));
        let Some((key, decided_ns)) = waiting else {
            self.report.reports_unmatched += 1;
            // A picture alfd did not command (the autopilot's own distance or time trigger
            // left on, a ground station's photo), or one reported after its capture stopped
            // waiting: the operator hears of it in flight, at most every 10 s.
            if due_every(&mut self.unmatched_said_ns, mono_ns, UNMATCHED_EVERY_NS) {
                let text = "alfd: picture report matched no capture";
                self.status(out, MavSeverity::MAV_SEVERITY_WARNING, text);
            }
            return;
        };
        if self.picture_delays_ns.len() == PICTURE_DELAYS_KEPT {
            self.picture_delays_ns.pop_front();
        }
        self.picture_delays_ns
            .push_back(mono_ns.saturating_sub(decided_ns));
        self.next_id += 1;
        let id = self.next_id;
        if let Some(w) = self.locating.get_mut(&key) {
            w.picture = Picture::Reported { mono_ns };
            w.answer = Answer::Pending;
            w.locate_id = id;
        }
        out.push(Action::Locate { id, mono_ns });
    }

    /// The autopilot answered the oldest camera command not answered yet. Refused, its
    /// picture will not come: the capture is logged where it was decided now, and no report
    /// is matched to it (the first report would otherwise go to it, the oldest waiting, and
    /// every capture after it would take its successor's picture).
    fn on_camera_ack(&mut self, out: &mut Vec<Action>, accepted: bool, now_ns: u64) {
        // Commands older than the wait for a picture had their ack lost.
        while self
            .unacked
            .front()
            .is_some_and(|&(_, decided_ns)| decided_ns + PICTURE_WAIT_NS < now_ns)
        {
            self.unacked.pop_front();
        }
        let Some((key, _)) = self.unacked.pop_front() else {
            return;
        };
        if accepted {
            return;
        }
        if let Some(w) = self.locating.get_mut(&key) {
            if matches!(w.picture, Picture::Awaited { .. }) {
                w.picture = Picture::NotAwaited;
                self.report.pictures_refused += 1;
                self.write_in_order(out);
            }
        }
    }

    /// The captures whose wait for their picture's report is over (`until`: those due by
    /// then; `None`: all, at the daemon's stop) are logged where they were decided.
    fn stop_awaiting(&mut self, out: &mut Vec<Action>, until: Option<u64>) {
        let mut ended = 0;
        for w in self.locating.values_mut() {
            if let Picture::Awaited { until_ns } = w.picture {
                if until.is_none_or(|t| until_ns <= t) {
                    w.picture = Picture::NotAwaited;
                    ended += 1;
                }
            }
        }
        if ended == 0 {
            return;
        }
        self.report.pictures_unreported += ended;
        let was = self.unreported_in_row;
        self.unreported_in_row = was.saturating_add(ended as u32);
        if was < UNREPORTED_IN_ROW_MAX && self.unreported_in_row >= UNREPORTED_IN_ROW_MAX {
            let text = "alfd: no picture reports: logged where decided";
            self.status(out, MavSeverity::MAV_SEVERITY_WARNING, text);
        }
        self.write_in_order(out);
    }

    /// Captures waiting for their picture's report.
    pub fn awaiting_pictures(&self) -> usize {
        self.locating
            .values()
            .filter(|w| matches!(w.picture, Picture::Awaited { .. }))
            .count()
    }

    /// At the daemon's stop: no capture waits for its picture's report any longer.
    pub fn stop_awaiting_pictures(&mut self) -> Vec<Action> {
        let mut out = Vec::new();
        self.stop_awaiting(&mut out, None);
        out
    }

    fn wait_for_pose(
        &mut self,
        out: &mut Vec<Action>,
        what: Awaits,
        mono_ns: u64,
        picture: Picture,
    ) {
        self.next_id += 1;
        let waiting = Waiting {
            what,
            mono_ns,
            answer: Answer::Pending,
            locate_id: self.next_id,
            picture,
        };
        self.locating.insert(self.next_id, waiting);
        self.sync_activity();
        out.push(Action::Locate {
            id: self.next_id,
            mono_ns,
        });
    }

    /// The pose of a capture asked by [`Action::Locate`]: its record goes to the writer, or
    /// (no pose) the ground station hears of the failure.
    pub fn on_located(&mut self, id: u64, located: Result<Located, String>) -> Vec<Action> {
        let mut out = Vec::new();
        // Only the capture's latest Locate counts (a reported picture asked again).
        let Some(w) = self.locating.values_mut().find(|w| w.locate_id == id) else {
            return out;
        };
        w.answer = Answer::Located(Box::new(located));
        self.write_in_order(&mut out);
        out
    }

    /// Numbers and writes the captures at the head of the line that have their answer.
    fn write_in_order(&mut self, out: &mut Vec<Action>) {
        while let Some(e) = self.locating.first_entry() {
            if matches!(e.get().answer, Answer::Pending)
                || matches!(e.get().picture, Picture::Awaited { .. })
            {
                break;
            }
            let w = e.remove();
            match (w.what, w.answer) {
                (Awaits::Asked(asked), answer) => {
                    let located = match answer {
                        Answer::Located(l) => *l,
                        // Not made: an asked capture always waits for its pose.
                        _ => Err("no pose was asked for".into()),
                    };
                    self.asked_located(out, asked, w.mono_ns, located)
                }
                (Awaits::Decided(mut record), answer) => {
                    let located = match &answer {
                        Answer::Located(l) => l.as_ref().as_ref().ok(),
                        _ => None,
                    };
                    if let Some(l) = located {
                        relocate(
                            &mut record,
                            &l.pose,
                            l.boot_us,
                            &l.local,
                            self.config.depth.mount_pitch_rad,
                        );
                        if let Picture::Reported { mono_ns } = w.picture {
                            // The picture's instant and place, not the decision's.
                            self.report.pictures_reported += 1;
                            record.picture_after_ms =
                                Some(mono_ns as f64 * 1e-6 - record.mono_ns as f64 * 1e-6);
                            record.mono_ns = mono_ns;
                            record.time_unix_us = l.unix_us;
                            record.distance_since_last_m =
                                distance_m(self.last_capture_ne, &l.pose);
                        }
                    } else if matches!(w.picture, Picture::Reported { .. }) {
                        // Reported, but no pose there: where it was decided, unplaced.
                        self.report.pictures_unreported += 1;
                    }
                    // No later pose: the capture keeps the one it was decided with (its
                    // pose_age_ms says how far that reached); it is never dropped.
                    self.number(&mut record);
                    self.write(out, *record);
                }
            }
        }
        self.sync_activity();
    }

    fn asked_located(
        &mut self,
        out: &mut Vec<Action>,
        asked: Asked,
        mono_ns: u64,
        located: Result<Located, String>,
    ) {
        let l = match located {
            Ok(l) => l,
            Err(e) => {
                let what = match asked {
                    Asked::Autopilot { .. } => "autopilot trigger",
                    Asked::Command { .. } => "commanded capture",
                };
                self.report.captures_failed += 1;
                let text = format!("alfd: {what} without a pose ({e}): not logged");
                // Said by STATUSTEXT, not by a failed CAMERA_IMAGE_CAPTURED: its index would
                // be a manifest number no line carries (no pose is ever made up).
                self.status(out, MavSeverity::MAV_SEVERITY_WARNING, &text);
                return;
            }
        };
        let ne = [l.pose.pos_ned_m.x, l.pose.pos_ned_m.y];
        let (capture, mode, requested_by, image_format) = match asked {
            Asked::Autopilot { from, tightest_m } => {
                self.report.autopilot_triggers += 1;
                let distance = distance_m(self.last_trigger_ne, &l.pose);
                self.last_trigger_ne = Some(ne);
                // The frames of the interval this picture closes, split at its own
                // instant (a frame estimated after the picture, before it was heard
                // of, is the next interval's).
                let tightest = tightest_m.unwrap_or(self.config.trigger.fallback_spacing_m);
                let spacing = self.setter.in_force_m().unwrap_or(tightest).min(tightest);
                let capture = Capture {
                    distance_since_last_m: distance,
                    spacing_m: spacing,
                    undersampled: trigger::undersampled(distance, tightest),
                    rate_limited: false,
                    fallback: self.fallback,
                };
                let by = from.map(|(s, c)| [s, c]);
                (capture, CaptureMode::AutopilotDistance, by, None)
            }
            Asked::Command { from } => {
                let spacing = self
                    .last_estimate
                    .as_deref()
                    .map_or(self.config.trigger.fallback_spacing_m, |e| {
                        self.spacing_of(e)
                    });
                let capture = Capture {
                    distance_since_last_m: distance_m(self.last_capture_ne, &l.pose),
                    spacing_m: spacing,
                    // Not the trigger's decision: the spacing is reported, not judged.
                    undersampled: false,
                    rate_limited: false,
                    fallback: self.fallback,
                };
                let fmt = self.saves_frames.then_some(self.image_format());
                (capture, CaptureMode::Command, Some([from.0, from.1]), fmt)
            }
        };
        let mut record = capture_record(&RecordInputs {
            seq: 0,
            mono_ns,
            pose: &l.pose,
            boot_us: l.boot_us,
            unix_us: l.unix_us,
            local: &l.local,
            estimate: self.last_estimate.as_deref(),
            closed_loop: None,
            capture: &capture,
            model: self.config.estimator.model.as_str(),
            mode,
            image_format,
            intrinsics: self.intrinsics.as_ref(),
            mount_pitch_rad: self.config.depth.mount_pitch_rad,
        });
        record.requested_by = requested_by;
        self.number(&mut record);
        self.write(out, record);
    }

    /// The writer's answer for a capture: CAMERA_IMAGE_CAPTURED, a failure when the record
    /// names no image though one was wanted (`missing` says why) or was not written.
    pub fn on_capture_written(
        &mut self,
        record: &CaptureRecord,
        result: Result<(), String>,
        image_missing: Option<&str>,
    ) -> Vec<Action> {
        let mut out = Vec::new();
        self.writing = self.writing.saturating_sub(1);
        let success = result.is_ok() && image_missing.is_none();
        if !success {
            self.report.captures_failed += 1;
        }
        out.push(send(self.camera.image_captured(&captured(record, success))));
        if let Err(e) = result {
            self.status(
                &mut out,
                MavSeverity::MAV_SEVERITY_ERROR,
                &format!("alfd: {e}"),
            );
        }
        self.sync_activity();
        out
    }

    /// Once a second and at [`Coordinator::next_due_ns`]: the interval captures due, the
    /// named values, the storage, and whether the estimator kept up.
    pub fn on_tick(
        &mut self,
        now: Now,
        storage: StorageState,
        frames_skipped_busy: u64,
        ground_speed_mps: Option<f64>,
    ) -> Vec<Action> {
        let mut out = Vec::new();
        self.set_ground_speed(ground_speed_mps);
        self.stop_awaiting(&mut out, Some(now.mono_ns));
        while let Some(mut i) = self.interval.filter(|i| i.next_ns <= now.mono_ns) {
            self.report.command_captures += 1;
            self.locate(&mut out, Asked::Command { from: i.from }, now.mono_ns);
            i.next_ns += i.interval_ns.max(1);
            i.remaining = i.remaining.map(|r| r - 1);
            // A late tick catches up with one capture, not a burst.
            i.next_ns = i.next_ns.max(now.mono_ns + 1);
            self.interval = (i.remaining != Some(0)).then_some(i);
        }
        self.sync_activity();
        // Once a second; a tick of the loop's 1 s timer that comes a little early against
        // the previous one (handled late) still counts.
        if self
            .last_second_ns
            .is_some_and(|t| now.mono_ns < t + SECOND_NS * 9 / 10)
        {
            return out;
        }
        self.last_second_ns = Some(now.mono_ns);
        self.camera.set_storage(storage);
        let (spacing, occ) = match &self.last_estimate {
            Some(e) => (Some(self.spacing_of(e)), e.occlusion.map(|o| o.degree)),
            None => (None, None),
        };
        for m in CameraProtocol::named_values(spacing, occ, now.boot_ms) {
            out.push(send(m));
        }
        // The quality model: each target's predicted value at the spacing in
        // force, and which bound set it (`Bound::code`).
        if let (Some(e), Some(s)) = (&self.last_estimate, spacing) {
            if let Some(q) = e.predict_at(s) {
                let values = [
                    (NAME_PARALLAX, q.parallax_px),
                    (NAME_OVERLAP, q.forward_overlap),
                    (NAME_UNSEEN, q.unseen_fraction),
                    (NAME_VIEWS, q.views_per_point.map(f64::from)),
                    (NAME_BOUND, e.active_bound.map(|b| b.code() as f64)),
                ];
                for (name, v) in values {
                    if let Some(m) =
                        v.and_then(|v| CameraProtocol::named_value(name, v, now.boot_ms))
                    {
                        out.push(send(m));
                    }
                }
            }
        }
        if let Some(s) = spacing {
            let mut vmax = self.trigger.speed_advice_mps(s);
            if self.config.capture.mode == CaptureMode::AutopilotDistance {
                // The autopilot's own checks: beyond this speed one is more than
                // the spacing (PX4 every 50 ms: 0.3 m is 5.8 m/s).
                vmax = vmax.min(self.setter.speed_max_mps(s));
            }
            if let Some(m) = CameraProtocol::named_value(NAME_VMAX, vmax, now.boot_ms) {
                out.push(send(m));
            }
            let fast = ground_speed_mps.filter(|v| *v > vmax * (1.0 + 1e-6));
            if let Some(v) = fast
                .filter(|_| due_every(&mut self.too_fast_said_ns, now.mono_ns, TOO_FAST_EVERY_NS))
            {
                // One STATUSTEXT chunk (50 bytes): ground stations show it whole.
                let text = format!("alfd: too fast: {v:.1} m/s, max {vmax:.1} m/s at {s:.1} m");
                self.status(&mut out, MavSeverity::MAV_SEVERITY_WARNING, &text);
            }
        }
        // The estimator runs on as many frames as its budget allows: say when it could not
        // keep up.
        if frames_skipped_busy > self.skipped_said {
            let text = format!(
                "alfd: estimator behind, {} depth frames skipped",
                frames_skipped_busy - self.skipped_said
            );
            self.skipped_said = frames_skipped_busy;
            self.status(&mut out, MavSeverity::MAV_SEVERITY_NOTICE, &text);
        }
        out
    }

    /// CAMERA_CAPTURE_STATUS from what is under way: capturing while a capture waits for its
    /// pose or its write, or an interval capture runs.
    fn sync_activity(&mut self) {
        self.camera.set_activity(CaptureActivity {
            active: self.writing > 0 || !self.locating.is_empty() || self.interval.is_some(),
            image_interval_s: self.interval.map(|i| (i.interval_ns as f64 * 1e-9) as f32),
        });
    }

    fn status(&mut self, out: &mut Vec<Action>, severity: MavSeverity, text: &str) {
        tracing::info!("{text}");
        // A long flight must not grow memory with its messages: the first ones are kept
        // for the report, the rest counted.
        if self.report.statustexts.len() < REPORT_KEEP {
            self.report.statustexts.push(text.to_string());
        } else {
            self.report.statustexts_dropped += 1;
        }
        out.extend(
            CameraProtocol::statustext(severity, text)
                .into_iter()
                .map(send),
        );
    }
}

/// Whether a message said at most every `every_ns` may be said at `now_ns` (never said yet, or
/// that long ago); if so, it counts as said now.
fn due_every(said_ns: &mut Option<u64>, now_ns: u64, every_ns: u64) -> bool {
    let due = said_ns.is_none_or(|t| now_ns >= t + every_ns);
    if due {
        *said_ns = Some(now_ns);
    }
    due
}

/// The horizontal way from `from` (north, east) to the pose, metres; `None` without `from`.
fn distance_m(from: Option<[f64; 2]>, to: &Pose) -> Option<f64> {
    from.map(|p| (to.pos_ned_m.x - p[0]).hypot(to.pos_ned_m.y - p[1]))
}

/// The middle value (the upper of the two middle ones), `None` for none.
fn median_u64(values: &VecDeque<u64>) -> Option<u64> {
    let mut v: Vec<u64> = values.iter().copied().collect();
    v.sort_unstable();
    v.get(v.len() / 2).copied()
}

fn send(m: MavMessage) -> Action {
    Action::Send(Box::new(m))
}

fn command(target_system: u8, target_component: u8, cmd: MavCmd, p: [f32; 7]) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        target_system,
        target_component,
        command: cmd,
        confirmation: 0,
        param1: p[0],
        param2: p[1],
        param3: p[2],
        param4: p[3],
        param5: p[4],
        param6: p[5],
        param7: p[6],
    })
}

/// CAMERA_IMAGE_CAPTURED's view of a record: image index `seq - 1`, contiguous over the
/// flight directory, failures included.
fn captured(r: &CaptureRecord, success: bool) -> Captured {
    let a = &r.attitude;
    let q = camera_q_ned(
        a.roll_deg.to_radians(),
        a.pitch_deg.to_radians(),
        a.yaw_deg.to_radians(),
        a.camera_pitch_deg.to_radians(),
    )
    .unwrap_or([f32::NAN, 0.0, 0.0, 0.0]);
    Captured {
        time_boot_ms: (r.time_boot_us / 1000) as u32,
        time_unix_us: r.time_unix_us,
        lat_deg: r.position.lat_deg,
        lon_deg: r.position.lon_deg,
        alt_m: r.position.alt_m,
        rel_alt_m: r.position.rel_alt_m,
        q_camera_ned: q,
        image_index: (r.seq as i32) - 1,
        file_name: r.image.clone(),
        success,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::allowlist::Trust;
    use crate::core::estimate::{Bound, NoEstimate};
    use crate::core::geo::Geodetic;
    use glam::{DQuat, DVec3};

    const GCS: (u8, u8) = (245, 190);
    const S: u64 = 1_000_000_000;

    fn config(mode: &str) -> Config {
        Config::from_text(&config_text(mode), "test.toml").expect("a valid config")
    }

    fn config_text(mode: &str) -> String {
        format!(
            "[mavlink]\naddress = \"udpin:127.0.0.1:1\"\nsystem_id = 1\ncomponent_id = 100\n\
             accept_system_ids = [1, 245]\n[sim]\nscene = \"scenes/district.toml\"\n\
             [camera]\nsource = \"synthetic\"\nwidth = 64\nheight = 48\nfps = 30.0\n\
             [sampling]\nmodel = \"fixed\"\n[trigger]\nrate_max_hz = 4.0\nfallback_spacing_m = 1.0\n\
             [capture]\ndir = \"/tmp/none\"\nmode = \"{mode}\"\nimage_format = \"png\"\n"
        )
    }

    fn coordinator(mode: &str, last_seq: u64) -> Coordinator {
        let i = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
        Coordinator::new(&config(mode), last_seq, Some(i))
    }

    fn now(t_ns: u64) -> Now {
        Now {
            mono_ns: t_ns,
            boot_ms: (t_ns / 1_000_000) as u32,
        }
    }

    fn command(c: MavCmd, params: [f32; 7], from: (u8, u8), trust: Trust) -> LinkEvent {
        LinkEvent::Command {
            system_id: from.0,
            component_id: from.1,
            command: c as u32,
            params,
            trust,
        }
    }

    /// A ground station's DO_DIGICAM_CONTROL with "shoot" set.
    fn digicam_shot() -> LinkEvent {
        let shoot = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        command(
            MavCmd::MAV_CMD_DO_DIGICAM_CONTROL,
            shoot,
            GCS,
            Trust::Accepted,
        )
    }

    fn located(north_m: f64) -> Result<Located, String> {
        Ok(Located {
            pose: Pose {
                time_ns: 0,
                pos_ned_m: DVec3::new(north_m, 0.0, -40.0),
                vel_ned_mps: DVec3::new(5.0, 0.0, 0.0),
                q: DQuat::IDENTITY,
                extrapolated_ns: 0,
            },
            boot_us: Some(1_000),
            unix_us: None,
            local: LocalFrame::new(Geodetic {
                lat_deg: 47.0,
                lon_deg: 8.0,
                alt_m: 500.0,
            }),
        })
    }

    fn acks(a: &[Action]) -> Vec<MavResult> {
        a.iter()
            .filter_map(|a| match a {
                Action::Send(m) => match m.as_ref() {
                    MavMessage::COMMAND_ACK(k) => Some(k.result),
                    _ => None,
                },
                _ => None,
            })
            .collect()
    }

    fn locates(a: &[Action]) -> Vec<(u64, u64)> {
        a.iter()
            .filter_map(|a| match a {
                Action::Locate { id, mono_ns } => Some((*id, *mono_ns)),
                _ => None,
            })
            .collect()
    }

    fn writes(a: &[Action]) -> Vec<CaptureRecord> {
        a.iter()
            .filter_map(|a| match a {
                Action::Write(r) => Some((**r).clone()),
                _ => None,
            })
            .collect()
    }

    fn captured(a: &[Action]) -> Vec<CAMERA_IMAGE_CAPTURED_DATA> {
        a.iter()
            .filter_map(|a| match a {
                Action::Send(m) => match m.as_ref() {
                    MavMessage::CAMERA_IMAGE_CAPTURED(c) => Some(c.clone()),
                    _ => None,
                },
                _ => None,
            })
            .collect()
    }

    fn status(co: &Coordinator) -> CAMERA_CAPTURE_STATUS_DATA {
        match co.camera().capture_status(0) {
            MavMessage::CAMERA_CAPTURE_STATUS(s) => s,
            other => panic!("{other:?}"),
        }
    }

    fn texts(a: &[Action]) -> Vec<String> {
        a.iter()
            .filter_map(|a| match a {
                Action::Send(m) => match m.as_ref() {
                    MavMessage::STATUSTEXT(t) => Some(t.text.to_str().unwrap().to_owned()),
                    _ => None,
                },
                _ => None,
            })
            .collect()
    }

    fn named(a: &[Action], name: &str) -> Vec<f32> {
        a.iter()
            .filter_map(|a| match a {
                Action::Send(m) => match m.as_ref() {
                    MavMessage::NAMED_VALUE_FLOAT(n) if n.name.to_str().unwrap() == name => {
                        Some(n.value)
                    }
                    _ => None,
                },
                _ => None,
            })
            .collect()
    }

    #[test]
    fn take_photo_is_a_logged_capture_answered_with_its_image() {
        let mut co = coordinator("frame", 4);
        let single = [0.0, 0.0, 1.0, 1.0, f32::NAN, f32::NAN, f32::NAN];
        let cmd = command(
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            single,
            GCS,
            Trust::Accepted,
        );
        let a = co.on_link_event(cmd, now(10 * S));
        assert_eq!(acks(&a), [MavResult::MAV_RESULT_ACCEPTED]);
        let l = locates(&a);
        assert_eq!(l.len(), 1);
        assert_eq!(l[0].1, 10 * S, "taken at the command's instant");
        assert_eq!(status(&co).image_status, 1, "capturing while it waits");
        let w = writes(&co.on_located(l[0].0, located(3.0)));
        assert_eq!(w.len(), 1);
        let r = &w[0];
        assert_eq!(r.seq, 5, "numbering continues the flight's manifest");
        assert_eq!(r.capture_mode, CaptureMode::Command);
        assert_eq!(r.requested_by, Some([GCS.0, GCS.1]));
        assert_eq!(r.image.as_deref(), Some("IMG_000005.png"));
        assert_eq!(r.mono_ns, 10 * S);
        assert!((r.position.north_m - 3.0).abs() < 1e-9);
        let c = captured(&co.on_capture_written(r, Ok(()), None));
        assert_eq!(c.len(), 1);
        assert_eq!(
            (c[0].image_index, c[0].capture_result),
            (4, MavBool::MAV_BOOL_TRUE)
        );
        let st = status(&co);
        assert_eq!((st.image_status, st.image_count), (0, 5));
        // The same sequence number again (its ACK lost): accepted, not taken twice.
        let cmd = command(
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            single,
            GCS,
            Trust::Accepted,
        );
        let a = co.on_link_event(cmd, now(11 * S));
        assert_eq!(acks(&a), [MavResult::MAV_RESULT_ACCEPTED]);
        assert!(locates(&a).is_empty());
        assert_eq!(co.report.command_captures, 1);
    }

    #[test]
    fn a_foreign_take_photo_is_denied_and_nothing_is_taken() {
        let mut co = coordinator("frame", 0);
        let single = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0];
        let cmd = command(
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            single,
            (77, 1),
            Trust::Foreign,
        );
        let a = co.on_link_event(cmd, now(S));
        assert_eq!(acks(&a), [MavResult::MAV_RESULT_DENIED]);
        assert!(locates(&a).is_empty());
    }

    #[test]
    fn an_interval_capture_runs_its_count_and_status_says_so() {
        let mut co = coordinator("frame", 0);
        let three = [0.0, 0.5, 3.0, 0.0, 0.0, 0.0, 0.0];
        let cmd = command(
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            three,
            GCS,
            Trust::Accepted,
        );
        let mut taken = locates(&co.on_link_event(cmd, now(S)));
        assert_eq!(co.next_due_ns(), Some(S + S / 2));
        let st = status(&co);
        assert_eq!((st.image_status, st.image_interval), (3, 0.5));
        let storage = StorageState::from_free_bytes(1 << 30);
        for t in [S + S / 4, S + S / 2, 2 * S, 2 * S + S / 2, 3 * S] {
            taken.extend(locates(&co.on_tick(now(t), storage, 0, None)));
        }
        let at: Vec<u64> = taken.iter().map(|l| l.1).collect();
        assert_eq!(at, [S, S + S / 2, 2 * S]);
        assert_eq!(co.next_due_ns(), None);
        // Until stopped, then stopped.
        let endless = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let cmd = command(
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            endless,
            GCS,
            Trust::Accepted,
        );
        assert_eq!(locates(&co.on_link_event(cmd, now(10 * S))).len(), 1);
        assert_eq!(locates(&co.on_tick(now(11 * S), storage, 0, None)).len(), 1);
        let stop = command(
            MavCmd::MAV_CMD_IMAGE_STOP_CAPTURE,
            [0.0; 7],
            GCS,
            Trust::Accepted,
        );
        let a = co.on_link_event(stop, now(11 * S + 1));
        assert_eq!(acks(&a), [MavResult::MAV_RESULT_ACCEPTED]);
        assert!(locates(&co.on_tick(now(20 * S), storage, 0, None)).is_empty());
        assert_eq!(co.report.command_captures, 5);
    }

    #[test]
    fn the_autopilots_image_start_capture_is_its_distance_trigger() {
        let mut co = coordinator("autopilot_distance", 0);
        // ArduPilot's MAVLinkCamV2: one IMAGE_START_CAPTURE per distance trigger.
        let one = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
        let mut records = Vec::new();
        for (k, north_m) in [0.0, 2.5, 5.0].into_iter().enumerate() {
            let cmd = command(
                MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
                one,
                (1, 1),
                Trust::Accepted,
            );
            let a = co.on_link_event(cmd, now((k as u64 + 1) * S));
            assert_eq!(acks(&a), [MavResult::MAV_RESULT_ACCEPTED]);
            let l = locates(&a);
            records.extend(writes(&co.on_located(l[0].0, located(north_m))));
        }
        assert_eq!(records.len(), 3);
        for (k, r) in records.iter().enumerate() {
            assert_eq!(r.seq, k as u64 + 1);
            assert_eq!(r.capture_mode, CaptureMode::AutopilotDistance);
            assert_eq!(r.requested_by, Some([1, 1]));
            assert_eq!(r.image, None, "the autopilot's camera took it");
        }
        assert_eq!(records[2].distance_since_last_m, Some(2.5));
        // No estimate: the fallback spacing (1 m) held, and 2.5 m outgrew it.
        assert!(!records[0].undersampled && records[2].undersampled);
        assert_eq!(records[2].spacing.chosen_m, 1.0);
        assert_eq!(co.report.autopilot_triggers, 3);
        assert_eq!(co.report.command_captures, 0);
        // A ground station's capture in the same mode is a command capture.
        let cmd = command(
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            one,
            GCS,
            Trust::Accepted,
        );
        let l = locates(&co.on_link_event(cmd, now(9 * S)));
        let r = writes(&co.on_located(l[0].0, located(9.0)));
        assert_eq!(r[0].capture_mode, CaptureMode::Command);
    }

    fn feedback(img_idx: u16, mono_ns: Option<u64>, received_mono_ns: u64) -> LinkEvent {
        LinkEvent::CameraFeedback {
            img_idx,
            gps_time_usec: 1_780_000_000_000_000,
            mono_ns,
            received_mono_ns,
            lat_deg: 47.0,
            lon_deg: 8.0,
            alt_msl_m: 500.0,
            alt_rel_m: 40.0,
        }
    }

    /// ArduPilot's servo or relay camera says each picture by CAMERA_FEEDBACK alone: each is
    /// an autopilot capture at the feedback's mapped instant, or at its arrival when that
    /// cannot be had. Its MAVLinkCamV2 backend says each twice (IMAGE_START_CAPTURE and
    /// CAMERA_FEEDBACK, same index, either order): logged once. After CAMERA_TRIGGER, an
    /// autopilot's feedbacks are not pictures of their own.
    #[test]
    fn the_autopilots_camera_feedback_is_a_picture_once() {
        let mut co = coordinator("autopilot_distance", 0);
        // Servo: feedbacks alone.
        let a = co.on_link_event(feedback(1, Some(S - 5_000_000), S), now(S));
        assert_eq!(locates(&a), [(1, S - 5_000_000)]);
        let a = co.on_link_event(feedback(2, None, 2 * S), now(2 * S));
        assert_eq!(locates(&a), [(2, 2 * S)], "at its arrival");
        assert_eq!(co.report.autopilot_feedbacks, 2);
        assert_eq!(co.report.feedbacks_timed_on_arrival, 1);
        // MAVLinkCamV2: the command, then its feedback (an echo).
        let cmd = |index: f32| {
            command(
                MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
                [0.0, 0.0, 1.0, index, 0.0, 0.0, 0.0],
                (1, 1),
                Trust::Accepted,
            )
        };
        assert_eq!(locates(&co.on_link_event(cmd(3.0), now(3 * S))).len(), 1);
        let echo = co.on_link_event(feedback(3, Some(3 * S), 3 * S + 1), now(3 * S + 1));
        assert!(locates(&echo).is_empty());
        // The feedback first, then its command: the command is acknowledged, not logged.
        let f = co.on_link_event(feedback(4, Some(4 * S), 4 * S), now(4 * S));
        assert_eq!(locates(&f).len(), 1);
        let c = co.on_link_event(cmd(4.0), now(4 * S + 1));
        assert_eq!(acks(&c), [MavResult::MAV_RESULT_ACCEPTED]);
        assert!(locates(&c).is_empty());
        // An index seen once is not an echo for ever: the next feedback 3 is a picture.
        assert_eq!(
            locates(&co.on_link_event(feedback(3, None, 5 * S), now(5 * S))).len(),
            1
        );
        assert_eq!(co.report.autopilot_feedbacks, 4);
        // Not in the other modes.
        let mut frame = coordinator("frame", 0);
        assert!(locates(&frame.on_link_event(feedback(9, None, S), now(S))).is_empty());
        // An autopilot that sends CAMERA_TRIGGER is heard by those.
        let trigger = LinkEvent::CameraTrigger {
            seq: 1,
            time_boot_us: 6_000_000,
            mono_ns: Some(6 * S),
        };
        assert_eq!(locates(&co.on_link_event(trigger, now(6 * S))).len(), 1);
        let f = co.on_link_event(feedback(10, Some(6 * S), 6 * S + 1), now(6 * S + 1));
        assert!(locates(&f).is_empty());
        // After a reboot, the feedbacks are its pictures again.
        co.on_link_event(LinkEvent::AutopilotRebooted, now(7 * S));
        assert_eq!(
            locates(&co.on_link_event(feedback(1, None, 8 * S), now(8 * S))).len(),
            1
        );
    }

    /// `camera_command`: each capture waits for the autopilot's word that it took the picture
    /// and is logged at that instant and place. The first report goes to the oldest capture
    /// waiting (the picture may come after the next decision); later ones by the usual delay,
    /// so a command the camera missed leaves that capture where it was decided (after
    /// `PICTURE_WAIT_NS`) and does not place the next one at its successor's picture. After
    /// three unreported in a row captures stop waiting, until a report comes again; the
    /// daemon's stop writes what still waits.
    /// A `camera_command` capture decided at `t`, its pose interpolated already.
    fn camera_decision(co: &mut Coordinator, t: u64) -> Vec<Action> {
        let mut r = crate::capture::record::tests::sample(1);
        (r.mono_ns, r.pose_age_ms, r.image) = (t, 0.0, None);
        r.capture_mode = CaptureMode::CameraCommand;
        co.on_decided(r)
    }

    /// PX4's report of a picture taken at `t`.
    fn camera_trigger(t: u64) -> LinkEvent {
        LinkEvent::CameraTrigger {
            seq: 0,
            time_boot_us: t / 1000,
            mono_ns: Some(t),
        }
    }

    #[test]
    fn a_camera_commands_capture_is_placed_where_the_autopilot_reports_its_picture() {
        const MS: u64 = 1_000_000;
        let mut co = coordinator("camera_command", 0);
        let storage = StorageState::from_free_bytes(1 << 30);
        let (decide, trigger) = (camera_decision, camera_trigger);
        // Two decisions 30 ms apart, each picture 50 ms after its decision: the command goes
        // out, nothing is written before the picture is reported.
        let a = decide(&mut co, S);
        assert_eq!(a.len(), 1, "the command alone: {a:?}");
        assert!(decide(&mut co, S + 30 * MS)
            .iter()
            .all(|a| !matches!(a, Action::Write(_))));
        assert_eq!(co.next_due_ns(), Some(S + PICTURE_WAIT_NS));
        let a = co.on_link_event(trigger(S + 50 * MS), now(S + 60 * MS));
        assert_eq!(locates(&a), [(3, S + 50 * MS)], "the oldest waiting");
        let w = writes(&co.on_located(3, located(10.0)));
        assert_eq!(w.len(), 1);
        assert_eq!((w[0].seq, w[0].mono_ns), (1, S + 50 * MS));
        assert_eq!(w[0].picture_after_ms, Some(50.0));
        assert_eq!(w[0].time_boot_us, 1_000, "the picture's clock");
        let a = co.on_link_event(trigger(S + 80 * MS), now(S + 90 * MS));
        assert_eq!(locates(&a), [(4, S + 80 * MS)]);
        let w = writes(&co.on_located(4, located(10.5)));
        assert_eq!((w[0].seq, w[0].picture_after_ms), (2, Some(50.0)));
        assert_eq!(
            w[0].distance_since_last_m,
            Some(0.5),
            "between the pictures"
        );
        // The camera misses the command of 2 s; the report at 2.08 s is 2.03 s's picture.
        decide(&mut co, 2 * S);
        decide(&mut co, 2 * S + 30 * MS);
        let a = co.on_link_event(trigger(2 * S + 80 * MS), now(2 * S + 90 * MS));
        let [(id, at)] = locates(&a)[..] else {
            panic!("{a:?}")
        };
        assert_eq!(at, 2 * S + 80 * MS);
        assert!(
            writes(&co.on_located(id, located(20.0))).is_empty(),
            "in order"
        );
        // Its wait ends at 3 s: it is written where it was decided, then the next.
        let w = writes(&co.on_tick(now(3 * S), storage, 0, None));
        assert_eq!(w.len(), 2);
        assert_eq!(
            (w[0].seq, w[0].mono_ns, w[0].picture_after_ms),
            (3, 2 * S, None)
        );
        assert_eq!((w[1].seq, w[1].mono_ns), (4, 2 * S + 80 * MS));
        assert_eq!(
            (co.report.pictures_reported, co.report.pictures_unreported),
            (3, 1)
        );
        // An autopilot that reports nothing: two more captures wait in vain (three in a row
        // since the last report, with the missed one), then none waits.
        let mut said = Vec::new();
        for k in 0..2 {
            let t = (4 + 2 * k) * S;
            assert!(writes(&decide(&mut co, t)).is_empty());
            let a = co.on_tick(now(t + PICTURE_WAIT_NS), storage, 0, None);
            assert_eq!(writes(&a).len(), 1);
            said.extend(texts(&a));
        }
        assert_eq!(said, ["alfd: no picture reports: logged where decided"]);
        assert_eq!(writes(&decide(&mut co, 10 * S)).len(), 1, "written at once");
        assert_eq!(co.next_due_ns(), None);
        // A report again (of no capture waiting): the next capture waits. The operator hears
        // of a report that matched no capture, once in 10 s.
        let a = co.on_link_event(trigger(11 * S), now(11 * S));
        assert!(locates(&a).is_empty());
        assert_eq!(texts(&a), ["alfd: picture report matched no capture"]);
        assert!(texts(&co.on_link_event(trigger(11 * S + S / 2), now(11 * S))).is_empty());
        assert_eq!(co.report.reports_unmatched, 2);
        assert!(writes(&decide(&mut co, 12 * S)).is_empty());
        // The stop: no report will be read, the capture is written as decided.
        let w = writes(&co.stop_awaiting_pictures());
        assert_eq!(
            (w.len(), w[0].mono_ns, w[0].picture_after_ms),
            (1, 12 * S, None)
        );
        assert_eq!(co.locating(), 0);
        // Not in frame mode: a decided capture is written at once.
        let mut frame = coordinator("frame", 0);
        let mut r = crate::capture::record::tests::sample(1);
        r.pose_age_ms = 0.0;
        assert_eq!(writes(&frame.on_decided(r)).len(), 1);
    }

    #[test]
    fn a_refused_camera_commands_capture_takes_no_report() {
        const MS: u64 = 1_000_000;
        let mut co = coordinator("camera_command", 0);
        let (decide, trigger) = (camera_decision, camera_trigger);
        let ack = |r: MavResult| LinkEvent::CommandAck {
            command: MavCmd::MAV_CMD_IMAGE_START_CAPTURE as u32,
            result: r as u8,
        };
        for k in 0..3 {
            decide(&mut co, S + k * 30 * MS);
        }
        // The camera is not ready for the first command: the autopilot says so, and that
        // capture is logged where it was decided, at once.
        let a = co.on_link_event(
            ack(MavResult::MAV_RESULT_TEMPORARILY_REJECTED),
            now(S + 10 * MS),
        );
        let w = writes(&a);
        assert_eq!(w.len(), 1, "{a:?}");
        assert_eq!(
            (w[0].seq, w[0].mono_ns, w[0].picture_after_ms),
            (1, S, None)
        );
        assert_eq!(texts(&a), ["alfd: camera command 2000 refused (1)"]);
        // Not an answer yet: nothing happens.
        let a = co.on_link_event(ack(MavResult::MAV_RESULT_IN_PROGRESS), now(S + 35 * MS));
        assert!(a.is_empty(), "{a:?}");
        for t in [40, 70] {
            co.on_link_event(ack(MavResult::MAV_RESULT_ACCEPTED), now(S + t * MS));
        }
        // The second and third commands' pictures, 50 ms after each decision, are theirs: the
        // first report does not go to the refused capture.
        for (seq, t) in [(2, 80), (3, 110)] {
            let a = co.on_link_event(trigger(S + t * MS), now(S + (t + 5) * MS));
            let [(id, at)] = locates(&a)[..] else {
                panic!("{a:?}")
            };
            assert_eq!(at, S + t * MS);
            let w = writes(&co.on_located(id, located(seq as f64)));
            assert_eq!((w[0].seq, w[0].picture_after_ms), (seq, Some(50.0)));
        }
        let r = &co.report;
        assert_eq!(
            (
                r.pictures_refused,
                r.camera_command_failures,
                r.pictures_reported
            ),
            (1, 1, 2)
        );
        assert_eq!((r.pictures_unreported, r.reports_unmatched), (0, 0));
        // A capture whose ack was lost is no longer expected to be answered once its wait
        // is over: the next refusal is the next command's.
        decide(&mut co, 3 * S);
        decide(&mut co, 4 * S + 500 * MS);
        let w = writes(&co.on_tick(
            now(4 * S + 10 * MS),
            StorageState::from_free_bytes(1 << 30),
            0,
            None,
        ));
        assert_eq!((w.len(), w[0].mono_ns), (1, 3 * S), "waited in vain");
        let a = co.on_link_event(ack(MavResult::MAV_RESULT_DENIED), now(4 * S + 520 * MS));
        let w = writes(&a);
        assert_eq!((w.len(), w[0].mono_ns), (1, 4 * S + 500 * MS));
        assert_eq!(co.locating(), 0);
    }

    #[test]
    fn decisions_are_renumbered_after_command_captures() {
        let mut co = coordinator("frame", 0);
        let cmd = digicam_shot();
        let l = locates(&co.on_link_event(cmd, now(S)));
        assert_eq!(writes(&co.on_located(l[0].0, located(0.0)))[0].seq, 1);
        // The estimator numbered its own capture 1 too: the manifest's number wins.
        let mut decided = crate::capture::record::tests::sample(1);
        decided.image = Some(image_file_name(1, ImageFormat::Png));
        decided.pose_age_ms = 0.0; // interpolated already: written at once
        let w = writes(&co.on_decided(decided));
        assert_eq!(
            (w[0].seq, w[0].image.as_deref()),
            (2, Some("IMG_000002.png"))
        );
    }

    /// A decided capture whose pose the link extrapolated: waits for its pose.
    fn extrapolated_decision(seq: u64) -> CaptureRecord {
        let mut r = crate::capture::record::tests::sample(seq);
        r.pose_age_ms = 98.8;
        r
    }

    #[test]
    fn an_extrapolated_decision_is_written_at_the_pose_interpolated_later() {
        let mut co = coordinator("frame", 0);
        let decided = extrapolated_decision(1);
        let a = co.on_decided(decided.clone());
        assert!(writes(&a).is_empty(), "not written before its pose is in");
        assert_eq!(locates(&a), vec![(1, decided.mono_ns)]);
        assert_eq!(co.locating(), 1);
        let mut l = located(7.0).unwrap();
        l.pose.q = DQuat::from_rotation_z(0.5);
        let w = writes(&co.on_located(1, Ok(l)));
        assert_eq!(w.len(), 1);
        let r = &w[0];
        assert_eq!((r.seq, r.mono_ns, r.pose_age_ms), (1, decided.mono_ns, 0.0));
        assert_eq!((r.position.north_m, r.position.up_m), (7.0, 40.0));
        assert!((r.attitude.yaw_deg - 0.5_f64.to_degrees()).abs() < 1e-9);
        assert_eq!(r.time_boot_us, 1_000);
        // What decided it stays as decided.
        assert_eq!(r.spacing, decided.spacing);
        assert_eq!(r.distance_since_last_m, decided.distance_since_last_m);
        assert_eq!(r.time_unix_us, decided.time_unix_us);
        assert_eq!(co.locating(), 0);
    }

    #[test]
    fn a_decision_with_no_later_pose_is_written_with_its_own() {
        let mut co = coordinator("frame", 0);
        let decided = extrapolated_decision(1);
        let a = co.on_decided(decided.clone());
        let w = writes(&co.on_located(locates(&a)[0].0, Err("stale".into())));
        assert_eq!(
            w.len(),
            1,
            "a capture is never dropped for want of a better pose"
        );
        assert_eq!(w[0].position, decided.position);
        assert_eq!(w[0].pose_age_ms, 98.8);
    }

    #[test]
    fn captures_are_written_in_the_order_taken_whichever_pose_comes_first() {
        let mut co = coordinator("frame", 0);
        let first = locates(&co.on_decided(extrapolated_decision(1)));
        let cmd = digicam_shot();
        let second = locates(&co.on_link_event(cmd, now(6 * S)));
        // An interpolated decision behind them waits in line too.
        let mut third = crate::capture::record::tests::sample(3);
        third.pose_age_ms = 0.0;
        assert!(writes(&co.on_decided(third)).is_empty());
        assert!(writes(&co.on_located(second[0].0, located(9.0))).is_empty());
        let w = writes(&co.on_located(first[0].0, located(8.0)));
        let got: Vec<_> = w
            .iter()
            .map(|r| (r.seq, r.capture_mode, r.position.north_m))
            .collect();
        assert_eq!(
            got,
            vec![
                (1, CaptureMode::Frame, 8.0),
                (2, CaptureMode::Command, 9.0),
                (3, CaptureMode::Frame, 3.0 * 1.1),
            ]
        );
        assert_eq!(co.locating(), 0);
    }

    #[test]
    fn a_capture_without_its_image_is_a_failed_capture() {
        let mut co = coordinator("frame", 0);
        let cmd = digicam_shot();
        let l = locates(&co.on_link_event(cmd, now(S)));
        let mut r = writes(&co.on_located(l[0].0, located(0.0))).remove(0);
        r.image = None;
        let c = captured(&co.on_capture_written(&r, Ok(()), Some("no colour frame")));
        assert_eq!(
            (c[0].image_index, c[0].capture_result),
            (0, MavBool::MAV_BOOL_FALSE)
        );
        let c = captured(&co.on_capture_written(&r, Err("disk full".into()), None));
        assert_eq!(c[0].capture_result, MavBool::MAV_BOOL_FALSE);
        assert_eq!(co.report.captures_failed, 2);
    }

    #[test]
    fn speed_advice_every_second_and_too_fast_at_most_every_ten() {
        let mut co = coordinator("frame", 0);
        let storage = StorageState::from_free_bytes(1 << 30);
        // No estimate yet: no advice.
        assert!(named(&co.on_tick(now(S), storage, 0, Some(9.0)), NAME_VMAX).is_empty());
        let mut e = Estimate::without_depth(0.0);
        e.spacing.chosen_m = Some(2.0);
        co.on_estimate(
            EstimatorView::Estimate {
                mono_ns: 2 * S,
                estimate: Box::new(e),
            },
            now(2 * S),
        );
        let mut said = 0;
        for k in 0..25u64 {
            let a = co.on_tick(now(3 * S + k * S), storage, 0, Some(9.0));
            // 2 m at 4 captures/s: 8 m/s.
            assert_eq!(named(&a, NAME_VMAX), [8.0], "{k}");
            said += texts(&a).iter().filter(|t| t.contains("too fast")).count();
        }
        assert_eq!(said, 3, "at 3, 13 and 23 s");
        // Slower than the advice: nothing said.
        let a = co.on_tick(now(40 * S), storage, 0, Some(7.9));
        assert!(texts(&a).iter().all(|t| !t.contains("too fast")));
        // A tick within the second adds nothing.
        assert!(co
            .on_tick(now(40 * S + S / 2), storage, 0, Some(9.0))
            .is_empty());
    }

    #[test]
    fn a_frame_beyond_the_depth_range_says_so_when_it_falls_back() {
        let mut co = coordinator("frame", 0);
        // Every sample beyond the range: a RealSense's 1 mm Z16 flown above 65.5 m.
        let mut e = Estimate::without_depth(0.0);
        e.no_estimate = Some(NoEstimate::TooFewValidPixels);
        (e.samples, e.far_below_samples, e.valid_fraction) = (1200, 1200, 0.0);
        co.on_estimate(
            EstimatorView::Estimate {
                mono_ns: S,
                estimate: Box::new(e),
            },
            now(S),
        );
        let said = co.report.statustexts.last().cloned().unwrap_or_default();
        assert!(said.contains("0 % of the depth valid"), "{said}");
        assert!(
            said.contains("100 % beyond the depth camera's range"),
            "{said}"
        );
        assert!(said.contains("fallback spacing"), "{said}");
    }

    /// A spacing held above the permissible one by `sampling.spacing_min_m` breaks the
    /// targets: said as a warning when it starts, not on every frame, and again
    /// after it ends and starts again at least 10 s later.
    #[test]
    fn a_spacing_floor_over_the_permissible_is_warned_of() {
        let mut co = coordinator("frame", 0);
        let floored = |t: u64, co: &mut Coordinator, held: bool| {
            let mut e = Estimate::without_depth(0.0);
            e.no_estimate = None;
            e.spacing.permissible_m = Some(0.0035);
            e.spacing.chosen_m = Some(if held { 0.05 } else { 0.0035 });
            e.active_bound = Some(if held {
                Bound::ConfigMin
            } else {
                Bound::Parallax
            });
            co.on_estimate(
                EstimatorView::Estimate {
                    mono_ns: t,
                    estimate: Box::new(e),
                },
                now(t),
            );
        };
        let warnings = |co: &Coordinator| {
            co.report
                .statustexts
                .iter()
                .filter(|t| t.contains("targets not met"))
                .cloned()
                .collect::<Vec<_>>()
        };
        for k in 1..=5 {
            floored(k * S / 10, &mut co, true);
        }
        let said = warnings(&co);
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(
            said[0].contains("sampling.spacing_min_m 0.05 m is over the permissible 0.004 m"),
            "{said:?}"
        );
        // Ended and back within 10 s: not said again; after 10 s it is.
        floored(S, &mut co, false);
        floored(2 * S, &mut co, true);
        assert_eq!(warnings(&co).len(), 1);
        floored(3 * S, &mut co, false);
        floored(12 * S, &mut co, true);
        assert_eq!(warnings(&co).len(), 2);
    }

    /// The DO_SET_CAM_TRIGG_DISTs among `a`: (distance, param3).
    fn distances(a: &[Action]) -> Vec<(f32, f32)> {
        a.iter()
            .filter_map(|a| match a {
                Action::Send(m) => match m.as_ref() {
                    MavMessage::COMMAND_LONG(c)
                        if c.command == MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST =>
                    {
                        Some((c.param1, c.param3))
                    }
                    _ => None,
                },
                _ => None,
            })
            .collect()
    }

    /// Feeds one estimate of `spacing_m` at `t_ns`.
    fn estimate_at(co: &mut Coordinator, t_ns: u64, spacing_m: f64) -> Vec<Action> {
        let mut e = Estimate::without_depth(0.0);
        e.spacing.chosen_m = Some(spacing_m);
        co.on_estimate(
            EstimatorView::Estimate {
                mono_ns: t_ns,
                estimate: Box::new(e),
            },
            now(t_ns),
        )
    }

    fn distance_ack(co: &mut Coordinator, t_ns: u64) {
        co.on_link_event(
            LinkEvent::CommandAck {
                command: MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST as u32,
                result: MavResult::MAV_RESULT_ACCEPTED as u8,
            },
            now(t_ns),
        );
    }

    /// ArduPilot counts a new distance from its last picture, so only the first
    /// command triggers once; an autopilot counting from the command gets a
    /// picture with every one. After a reboot the distance goes again at once.
    #[test]
    fn the_distance_command_triggers_once_only_where_the_autopilot_needs_it() {
        for (firmware, pictures) in [
            (MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, [1.0, 0.0, 1.0]),
            (MavAutopilot::MAV_AUTOPILOT_PX4, [1.0, 1.0, 1.0]),
        ] {
            let mut co = coordinator("autopilot_distance", 0);
            co.on_link_event(LinkEvent::AutopilotFound { firmware }, now(S));
            let first = distances(&estimate_at(&mut co, 2 * S, 5.0));
            distance_ack(&mut co, 2 * S + 1);
            let shorter = distances(&estimate_at(&mut co, 3 * S, 4.0));
            distance_ack(&mut co, 3 * S + 1);
            assert!(distances(&estimate_at(&mut co, 4 * S, 4.0)).is_empty());
            co.on_link_event(LinkEvent::AutopilotRebooted, now(5 * S));
            let again = distances(&estimate_at(&mut co, 5 * S + 1, 4.0));
            let got: Vec<f32> = [&first, &shorter, &again]
                .iter()
                .map(|d| {
                    assert_eq!(d.len(), 1, "{firmware:?}: {d:?}");
                    d[0].1
                })
                .collect();
            assert_eq!(got, pictures, "{firmware:?}");
            assert!((again[0].0 - 4.0 * 0.97).abs() < 1e-5, "{again:?}");
        }
    }

    /// PX4 checks its distance every 50 ms: alfd asks for the spacing less the
    /// way flown in one poll, and advises a speed at which a poll stays within
    /// the spacing (0.3 m: 5.8 m/s). An autopilot not known fires at the point.
    #[test]
    fn a_polling_autopilot_is_asked_its_lateness_less_and_advised_its_speed() {
        let text =
            config_text("autopilot_distance").replace("rate_max_hz = 4.0", "rate_max_hz = 30.0");
        let storage = StorageState::from_free_bytes(1 << 30);
        for (firmware, distance_m, vmax) in [
            (
                MavAutopilot::MAV_AUTOPILOT_PX4,
                (0.3 - 4.0 * 0.05) * 0.97,
                5.8,
            ),
            (MavAutopilot::MAV_AUTOPILOT_GENERIC, 0.3 * 0.97, 9.0),
        ] {
            let i = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
            let mut co = Coordinator::new(&Config::from_text(&text, "t.toml").unwrap(), 0, Some(i));
            co.on_link_event(LinkEvent::AutopilotFound { firmware }, now(S));
            co.on_tick(now(S), storage, 0, Some(4.0));
            let d = distances(&estimate_at(&mut co, 2 * S, 0.3));
            assert_eq!(d.len(), 1, "{firmware:?}");
            assert!(
                (d[0].0 as f64 - distance_m).abs() < 1e-6,
                "{firmware:?}: {d:?}"
            );
            let a = co.on_tick(now(3 * S), storage, 0, Some(7.0));
            let said = named(&a, NAME_VMAX);
            assert_eq!(said.len(), 1);
            assert!(
                (said[0] as f64 - vmax).abs() < 1e-5,
                "{firmware:?}: {said:?}"
            );
            let fast = texts(&a).iter().any(|t| t.contains("too fast"));
            assert_eq!(fast, vmax < 7.0, "{firmware:?}");
        }
    }
}
