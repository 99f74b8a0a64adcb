//! The link's bookkeeping, with no I/O: digests each incoming message (at its receive instant)
//! into the TIMESYNC filter, the glitch gate, the pose buffer, the published vehicle state and
//! the health counters, and says what to send back. The local frame is anchored only on a valid
//! origin (the autopilot's EKF origin or home, else a position with a 3-D fix, never lat = lon =
//! 0), and poses are given for captures only while the vehicle is airborne.

use super::config::LinkConfig;
use super::{LinkEvent, LinkHealth, VehicleState};
use crate::core::allowlist::Trust;
use crate::core::geo::{Geodetic, LocalFrame};
use crate::core::glitch::{GlitchConfig, GlitchGate, Verdict};
use crate::core::localpos::{LocalConfig, LocalOutcome, LocalTrack, NedSample};
use crate::core::pose::{
    AttitudeSample, Pose, PoseBuffer, PoseBufferConfig, PoseError, PositionSample, PushError,
};
use crate::core::timesync::{SampleOutcome, TimeCheck, TimeSync, TimeSyncConfig};
use glam::{DQuat, DVec3};
use mavlink::dialects::ardupilotmega::*;
use mavlink::MavHeader;
use std::collections::{HashMap, VecDeque};

/// Why the link cannot give a pose at an instant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PoseQueryError {
    #[error("no time synchronisation with the autopilot yet")]
    NotSynced,
    #[error(transparent)]
    Pose(#[from] PoseError),
    /// `[mavlink] require_airborne`: no capture on the ground.
    #[error("not airborne: {0}")]
    NotAirborne(Airborne),
}

/// Where the local frame's anchor came from, in rising order of authority: a source replaces
/// the anchor only if it is at least as authoritative.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum AnchorSource {
    /// The first position with a 3-D fix, at the ground its relative altitude is measured
    /// from (an autopilot that sends neither message below).
    Position,
    /// HOME_POSITION.
    Home,
    /// GPS_GLOBAL_ORIGIN: the EKF origin, around which the autopilot's own local frame is;
    /// it stays put when home is reset at arming.
    Origin,
    /// `[mavlink] home_lat_deg` / `home_lon_deg`: fixed by the operator.
    Config,
}

impl AnchorSource {
    pub fn as_str(self) -> &'static str {
        match self {
            AnchorSource::Position => "first 3-D fix",
            AnchorSource::Home => "HOME_POSITION",
            AnchorSource::Origin => "GPS_GLOBAL_ORIGIN",
            AnchorSource::Config => "config",
        }
    }
}

/// Whether the vehicle is airborne, and if not, why (the text a STATUSTEXT carries).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Airborne {
    Yes,
    /// EXTENDED_SYS_STATE's landed state (MAV_LANDED_STATE) is not IN_AIR.
    Landed(u8),
    /// No landed state from the autopilot, and HEARTBEAT says disarmed.
    Disarmed,
    /// Armed, no landed state, and lower above home than `min_rel_alt_m` (both in cm).
    Low {
        rel_alt_cm: i32,
        min_cm: i32,
    },
}

impl Airborne {
    pub fn is_airborne(self) -> bool {
        self == Airborne::Yes
    }

    /// From what the autopilot said: its landed state where it sends one (anything but
    /// UNDEFINED decides), otherwise armed and at least `min_rel_alt_m` above home.
    pub fn judge(
        landed: Option<MavLandedState>,
        armed: bool,
        rel_alt_m: f64,
        min_rel_alt_m: f64,
    ) -> Airborne {
        match landed {
            Some(MavLandedState::MAV_LANDED_STATE_IN_AIR) => Airborne::Yes,
            Some(l) if l != MavLandedState::MAV_LANDED_STATE_UNDEFINED => Airborne::Landed(l as u8),
            _ if !armed => Airborne::Disarmed,
            // A NaN height is not airborne either.
            _ if rel_alt_m.is_nan() || rel_alt_m < min_rel_alt_m => Airborne::Low {
                rel_alt_cm: (rel_alt_m * 100.0).round() as i32,
                min_cm: (min_rel_alt_m * 100.0).round() as i32,
            },
            _ => Airborne::Yes,
        }
    }
}

impl std::fmt::Display for Airborne {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Airborne::Yes => write!(f, "airborne"),
            Airborne::Landed(1) => write!(f, "on the ground (landed state)"),
            Airborne::Landed(3) => write!(f, "taking off (landed state)"),
            Airborne::Landed(4) => write!(f, "landing (landed state)"),
            Airborne::Landed(l) => write!(f, "landed state {l}"),
            Airborne::Disarmed => write!(f, "disarmed"),
            Airborne::Low { rel_alt_cm, min_cm } => write!(
                f,
                "{:.1} m above home, below min_rel_alt_m {:.1} m",
                rel_alt_cm as f64 / 100.0,
                min_cm as f64 / 100.0
            ),
        }
    }
}

/// What digesting a message asks the task to do.
#[derive(Debug, PartialEq)]
pub enum Reaction {
    Reply(Box<MavMessage>),
    Event(LinkEvent),
    /// (Re)request the telemetry rates.
    RequestRates,
    StateChanged,
}

/// The link's state machine, with time passed in: the link task owns one and feeds it every
/// message it reads. Public so that tests and the fuzz targets drive it without a transport.
pub struct Tracker {
    cfg: LinkConfig,
    pub sync: TimeSync,
    poses: PoseBuffer,
    gate: GlitchGate,
    /// LOCAL_POSITION_NED carried into `frame` (finer than GLOBAL_POSITION_INT's 1e-7°).
    local: LocalTrack,
    frame: Option<LocalFrame>,
    /// Where `frame` came from (set together).
    anchor: Option<AnchorSource>,
    /// GPS_RAW_INT's fix type, once the autopilot sends it.
    gps_fix: Option<u8>,
    armed: bool,
    /// EXTENDED_SYS_STATE's landed state, once the autopilot sends it.
    landed: Option<MavLandedState>,
    rel_alt_m: f64,
    /// The autopilot refused MAV_CMD_REQUEST_MESSAGE (UNSUPPORTED or DENIED): not asked again.
    origin_refused: bool,
    pub health: LinkHealth,
    pub state: Option<VehicleState>,
    /// The autopilot we follow: (system id, component id).
    pub autopilot: Option<(u8, u8)>,
    seqs: HashMap<(u32, u8), u8>,
    /// TIMESYNC requests in flight (their ts1 = our send instant).
    outstanding: VecDeque<u64>,
    /// The autopilot's UNIX time less its boot time (µs), from its latest SYSTEM_TIME that
    /// knew UTC: maps a CAMERA_FEEDBACK's GPS time stamp onto the boot clock.
    unix_minus_boot_us: Option<i64>,
    /// SET_MESSAGE_INTERVAL requests not yet acknowledged, oldest first.
    pub pending_rates: VecDeque<u32>,
}

impl Tracker {
    pub fn new(cfg: LinkConfig) -> Self {
        let poses = PoseBuffer::new(PoseBufferConfig {
            horizon_ns: cfg.pose_horizon.as_nanos() as u64,
            keep_ns: cfg.pose_keep.as_nanos() as u64,
            max_samples: 4096,
        });
        let gate = GlitchGate::new(GlitchConfig {
            tolerance_m: cfg.glitch_tolerance_m,
            reanchor_after_ns: cfg.glitch_reanchor.as_nanos() as u64,
            ..GlitchConfig::default()
        });
        let local = LocalTrack::new(LocalConfig {
            check_tolerance_m: cfg.glitch_tolerance_m,
            ..LocalConfig::default()
        });
        Tracker {
            local,
            frame: cfg.home.map(LocalFrame::new),
            anchor: cfg.home.map(|_| AnchorSource::Config),
            gps_fix: None,
            armed: false,
            landed: None,
            rel_alt_m: 0.0,
            origin_refused: false,
            sync: TimeSync::new(TimeSyncConfig::default()),
            poses,
            gate,
            health: LinkHealth::default(),
            state: None,
            autopilot: None,
            seqs: HashMap::new(),
            outstanding: VecDeque::new(),
            unix_minus_boot_us: None,
            pending_rates: VecDeque::new(),
            cfg,
        }
    }

    /// A TIMESYNC request to send now (`now_ns` doubles as its ts1).
    pub fn timesync_request(&mut self, now_ns: u64) -> MavMessage {
        // Requests the autopilot never answered are forgotten oldest first: an answer
        // older than sixteen requests would be too stale to fit the offset with.
        if self.outstanding.len() >= 16 {
            self.outstanding.pop_front();
        }
        self.outstanding.push_back(now_ns);
        let (target_system, target_component) = self.autopilot.unwrap_or((0, 0));
        MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: now_ns as i64,
            target_system,
            target_component,
        })
    }

    /// The pose at a local monotonic instant, for a capture: none before a valid origin (no
    /// position is kept until then) and, with `require_airborne`, none on the ground. The
    /// airborne state is the latest known, not the one at `mono_ns` (it changes seldom).
    pub fn pose_at(&self, mono_ns: u64) -> Result<Pose, PoseQueryError> {
        let boot_ns = self
            .sync
            .local_to_remote(mono_ns)
            .ok_or(PoseQueryError::NotSynced)?;
        let pose = self.poses.at(boot_ns)?;
        match self.airborne() {
            a if self.cfg.require_airborne && !a.is_airborne() => {
                Err(PoseQueryError::NotAirborne(a))
            }
            _ => Ok(pose),
        }
    }

    /// Whether the vehicle is airborne now, by what the autopilot last said.
    pub fn airborne(&self) -> Airborne {
        Airborne::judge(
            self.landed,
            self.armed,
            self.rel_alt_m,
            self.cfg.min_rel_alt_m,
        )
    }

    /// Where the local frame is anchored (`None`: not yet, no pose is kept).
    pub fn anchor(&self) -> Option<(AnchorSource, Geodetic)> {
        Some((self.anchor?, self.frame?.home()))
    }

    /// Whether HOME_POSITION and GPS_GLOBAL_ORIGIN are still worth requesting: neither has
    /// come (nor a configured home), and the autopilot has not refused the request.
    pub fn wants_origin(&self) -> bool {
        !self.origin_refused && self.anchor.is_none_or(|a| a < AnchorSource::Home)
    }

    /// MAV_CMD_REQUEST_MESSAGE for HOME_POSITION and GPS_GLOBAL_ORIGIN, addressed to the
    /// autopilot (ArduPilot answers only once it has them, so the task repeats these).
    pub fn origin_requests(&mut self) -> [MavMessage; 2] {
        self.health.origin_requests += 2;
        let (target_system, target_component) = self.autopilot.unwrap_or((0, 0));
        // The origin first: answered in order, it anchors the frame before home could.
        [49.0, 242.0].map(|id| {
            MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
                param1: id,
                target_system,
                target_component,
                ..Default::default()
            })
        })
    }

    /// Publish a changed airborne state.
    fn refresh_airborne(&mut self, out: &mut Vec<Reaction>) {
        let a = self.airborne();
        if let Some(s) = self.state.as_mut() {
            s.armed = self.armed;
            if s.airborne != a {
                s.airborne = a;
                out.push(Reaction::StateChanged);
            }
        }
    }

    /// Anchor the local frame on `home` from `source`, or move it there if the anchor in force
    /// is not more authoritative. Kept positions are re-expressed in the new frame and the
    /// glitch gate restarts from the next one, so a moved origin suspends nothing.
    fn anchor_at(&mut self, source: AnchorSource, home: Geodetic, out: &mut Vec<Reaction>) {
        if self.anchor.is_some_and(|a| a > source) {
            return;
        }
        let new = LocalFrame::new(home);
        let moved_m = match self.frame {
            None => None,
            Some(old) => {
                let d = DVec3::from_array(old.to_ned(home)).length();
                // Resent unchanged (ArduPilot resends home at arming): only the source is news.
                if d < 0.01 {
                    self.anchor = Some(source);
                    if let Some(s) = self.state.as_mut() {
                        s.origin_source = source;
                    }
                    return;
                }
                self.poses.map_positions(|p| {
                    DVec3::from_array(new.to_ned(old.to_geodetic(p.to_array())))
                });
                self.gate.reset();
                Some(d)
            }
        };
        self.frame = Some(new);
        self.anchor = Some(source);
        // The offset to the autopilot's local frame was in the old frame.
        self.local.reset();
        self.health.origin_anchors += 1;
        if let Some(s) = self.state.as_mut() {
            s.pos_ned_m = new.to_ned(s.position);
            s.home = home;
            s.origin_source = source;
            out.push(Reaction::StateChanged);
        }
        out.push(Reaction::Event(LinkEvent::OriginSet {
            source,
            home,
            moved_m,
        }));
    }

    fn time_ok(&mut self, boot_ms: u32, rx_ns: u64, out: &mut Vec<Reaction>) -> bool {
        match self
            .sync
            .check_remote_time(boot_ms as u64 * 1_000_000, rx_ns)
        {
            TimeCheck::Plausible => true,
            TimeCheck::Implausible => {
                self.health.rejected_time += 1;
                false
            }
            TimeCheck::Rebooted => {
                self.on_reboot(out);
                true
            }
        }
    }

    /// The local instant of a picture CAMERA_FEEDBACK stamps `gps_time_us` (UNIX µs), through
    /// the autopilot's latest SYSTEM_TIME and TIMESYNC; `None` when either is unknown, the stamp
    /// is 0 (no GPS time), or the instant is not in the two seconds before it was heard of
    /// (a stamp that disagrees with its own arrival is not believed). Up to 5 ms after its
    /// arrival is the mapping's own error (SYSTEM_TIME's millisecond, the clock fit): the
    /// arrival is taken then.
    fn feedback_instant(&self, gps_time_us: u64, rx_ns: u64) -> Option<u64> {
        let offset_us = self.unix_minus_boot_us?;
        let boot_us = i64::try_from(gps_time_us).ok()?.checked_sub(offset_us)?;
        if gps_time_us == 0 || boot_us <= 0 {
            return None;
        }
        let mono = self
            .sync
            .remote_to_local((boot_us as u64).checked_mul(1000)?)?;
        let mono = (mono <= rx_ns + 5_000_000).then_some(mono.min(rx_ns))?;
        (rx_ns - mono <= 2_000_000_000).then_some(mono)
    }

    fn on_reboot(&mut self, out: &mut Vec<Reaction>) {
        self.poses.clear();
        self.gate.reset();
        self.local.reset();
        self.outstanding.clear();
        self.unix_minus_boot_us = None;
        self.health.reboots += 1;
        self.health.synced = false;
        out.push(Reaction::Event(LinkEvent::AutopilotRebooted));
        out.push(Reaction::RequestRates);
    }

    /// Digest one message received at `rx_ns`.
    pub fn on_message(&mut self, h: &MavHeader, msg: &MavMessage, rx_ns: u64) -> Vec<Reaction> {
        let mut out = Vec::new();
        let sysid = h.system_id;
        if !self
            .cfg
            .accept_system_ids
            .iter()
            .any(|id| u32::from(*id) == sysid)
        {
            // Any system may ask the camera for its state (a ground station the operator did
            // not list); the camera protocol refuses its other commands with DENIED.
            match self.command_for_us(h, msg, Trust::Foreign) {
                Some(ev) => {
                    self.health.foreign_commands += 1;
                    out.push(Reaction::Event(ev));
                }
                None => self.health.foreign_ignored += 1,
            }
            return out;
        }
        self.health.messages_rx += 1;
        self.health.last_rx_mono_ns = rx_ns;
        if let Some(last) = self.seqs.insert((sysid, h.component_id), h.sequence) {
            self.health.seq_gaps += u64::from(h.sequence.wrapping_sub(last).wrapping_sub(1));
        }
        if let Some(ev) = self.command_for_us(h, msg, Trust::Accepted) {
            out.push(Reaction::Event(ev));
            return out;
        }
        let from_autopilot = self.is_autopilot(sysid, h.component_id);
        match msg {
            MavMessage::HEARTBEAT(hb) if from_autopilot => {
                if self.autopilot.is_none() {
                    self.autopilot = Some((sysid as u8, h.component_id));
                    out.push(Reaction::RequestRates);
                    out.push(Reaction::Event(LinkEvent::AutopilotFound {
                        firmware: hb.autopilot,
                    }));
                }
                self.health.autopilot_heartbeats += 1;
                self.armed = hb
                    .base_mode
                    .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                self.refresh_airborne(&mut out);
            }
            MavMessage::EXTENDED_SYS_STATE(e) if from_autopilot => {
                self.landed = Some(e.landed_state);
                self.refresh_airborne(&mut out);
            }
            MavMessage::HOME_POSITION(h) if from_autopilot => {
                if let Some(g) = valid_geodetic(h.latitude, h.longitude, h.altitude) {
                    self.anchor_at(AnchorSource::Home, g, &mut out);
                }
            }
            MavMessage::GPS_GLOBAL_ORIGIN(o) if from_autopilot => {
                if let Some(g) = valid_geodetic(o.latitude, o.longitude, o.altitude) {
                    self.anchor_at(AnchorSource::Origin, g, &mut out);
                }
            }
            MavMessage::CAMERA_FEEDBACK(c) if from_autopilot => {
                self.health.camera_feedbacks += 1;
                out.push(Reaction::Event(LinkEvent::CameraFeedback {
                    img_idx: c.img_idx,
                    gps_time_usec: c.time_usec,
                    mono_ns: self.feedback_instant(c.time_usec, rx_ns),
                    received_mono_ns: rx_ns,
                    lat_deg: c.lat as f64 * 1e-7,
                    lon_deg: c.lng as f64 * 1e-7,
                    alt_msl_m: c.alt_msl,
                    alt_rel_m: c.alt_rel,
                }));
            }
            MavMessage::TIMESYNC(t) if t.tc1 == 0 => {
                out.push(Reaction::Reply(Box::new(MavMessage::TIMESYNC(
                    TIMESYNC_DATA {
                        tc1: rx_ns as i64,
                        ts1: t.ts1,
                        target_system: sysid as u8,
                        target_component: h.component_id,
                    },
                ))));
            }
            MavMessage::TIMESYNC(t) => {
                // Only the autopilot's own answer, addressed to us (target fields 0 when the
                // sender leaves the extension out): ArduPilot forwards our requests to its
                // ground stations, and one that answers them must not move our clock.
                if !from_autopilot || !self.for_us(t.target_system, t.target_component) {
                    self.health.timesync_foreign += 1;
                    return out;
                }
                let ts1 = t.ts1 as u64;
                let Some(i) = self.outstanding.iter().position(|s| *s == ts1) else {
                    return out;
                };
                self.outstanding.remove(i);
                let was_synced = self.sync.is_synced();
                let resets = self.sync.resets();
                match self.sync.on_exchange(ts1, t.tc1.max(0) as u64, rx_ns) {
                    SampleOutcome::Outlier => self.health.timesync_outliers += 1,
                    SampleOutcome::Discarded => self.health.timesync_discarded += 1,
                    SampleOutcome::Accepted | SampleOutcome::Reset => {}
                }
                if self.sync.resets() > resets && self.health.synced {
                    self.on_reboot(&mut out);
                }
                self.health.synced = self.sync.is_synced();
                if let Some(f) = self.sync.fit() {
                    self.health.offset_ns = f.offset_ns as i64;
                    self.health.drift_ppm = f.drift * 1e6;
                    self.health.rtt_min_ns = f.rtt_min_ns;
                }
                self.health.timesync_resets = self.sync.resets();
                if !was_synced && self.health.synced {
                    self.health.synced_at_mono_ns = rx_ns;
                    out.push(Reaction::Event(LinkEvent::Synced));
                }
            }
            MavMessage::SYSTEM_TIME(t) if from_autopilot => {
                let plausible = self.time_ok(t.time_boot_ms, rx_ns, &mut out);
                if plausible && t.time_unix_usec > 0 {
                    // time_boot_ms is truncated to the millisecond: its instant is half a
                    // millisecond later on average.
                    let boot_us = i64::from(t.time_boot_ms) * 1000 + 500;
                    self.unix_minus_boot_us =
                        i64::try_from(t.time_unix_usec).ok().map(|u| u - boot_us);
                }
            }
            MavMessage::GLOBAL_POSITION_INT(p) if from_autopilot => {
                self.on_position(p, rx_ns, &mut out)
            }
            MavMessage::LOCAL_POSITION_NED(p) if from_autopilot => {
                self.on_local_position(p, rx_ns, &mut out)
            }
            MavMessage::ATTITUDE_QUATERNION(a) if from_autopilot => {
                if !self.time_ok(a.time_boot_ms, rx_ns, &mut out) {
                    return out;
                }
                let q = DQuat::from_xyzw(a.q2 as f64, a.q3 as f64, a.q4 as f64, a.q1 as f64);
                let rates = DVec3::new(a.rollspeed as f64, a.pitchspeed as f64, a.yawspeed as f64);
                self.on_attitude(a.time_boot_ms, q, rates, &mut out);
            }
            MavMessage::ATTITUDE(a) if from_autopilot => {
                if !self.time_ok(a.time_boot_ms, rx_ns, &mut out) {
                    return out;
                }
                let q = DQuat::from_euler(
                    glam::EulerRot::ZYX,
                    a.yaw as f64,
                    a.pitch as f64,
                    a.roll as f64,
                );
                let rates = DVec3::new(a.rollspeed as f64, a.pitchspeed as f64, a.yawspeed as f64);
                self.on_attitude(a.time_boot_ms, q, rates, &mut out);
            }
            MavMessage::GPS_RAW_INT(g) if from_autopilot => {
                self.gps_fix = Some(g.fix_type as u8);
                if let Some(s) = self.state.as_mut() {
                    s.gps_fix = g.fix_type as u8;
                }
            }
            // Acks come in the order of the requests. LOCAL_POSITION_NED is optional:
            // refused, it is not asked again. Only answers to the link's own requests count:
            // a ground station's are answered on links alfd may hear.
            MavMessage::COMMAND_ACK(a)
                if from_autopilot
                    && self.for_us(a.target_system, a.target_component)
                    && a.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL
                    && (a.result == MavResult::MAV_RESULT_ACCEPTED
                        || self.pending_rates.front() == Some(&32)) =>
            {
                self.pending_rates.pop_front();
                self.health.rates_acked = self.pending_rates.is_empty();
            }
            // The link's only REQUEST_MESSAGE to the autopilot is for the origin.
            MavMessage::COMMAND_ACK(a)
                if from_autopilot
                    && self.for_us(a.target_system, a.target_component)
                    && a.command == MavCmd::MAV_CMD_REQUEST_MESSAGE
                    && matches!(
                        a.result,
                        MavResult::MAV_RESULT_UNSUPPORTED | MavResult::MAV_RESULT_DENIED
                    ) =>
            {
                self.origin_refused = true;
            }
            MavMessage::CAMERA_TRIGGER(c) if from_autopilot => {
                out.push(Reaction::Event(LinkEvent::CameraTrigger {
                    seq: c.seq,
                    time_boot_us: c.time_usec,
                    mono_ns: self.sync.remote_to_local(c.time_usec.saturating_mul(1000)),
                }));
            }
            // Only answers to alfd's own commands (target fields 0 when the autopilot leaves
            // the extension out): a ground station's photo command is answered too, on a
            // link alfd may hear, and must not be taken for one of alfd's captures.
            MavMessage::COMMAND_ACK(a)
                if from_autopilot
                    && matches!(
                        a.command,
                        MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST
                            | MavCmd::MAV_CMD_IMAGE_START_CAPTURE
                            | MavCmd::MAV_CMD_DO_DIGICAM_CONTROL
                    )
                    && self.for_us(a.target_system, a.target_component) =>
            {
                out.push(Reaction::Event(LinkEvent::CommandAck {
                    command: a.command as u32,
                    result: a.result as u8,
                }));
            }
            _ => {}
        }
        out
    }

    /// The autopilot the link follows: `autopilot_component_id` on the system whose HEARTBEAT
    /// from that component came first (before any, on any accepted system). Once it is known,
    /// nothing from another system, a ground station's included, counts as the autopilot's.
    fn is_autopilot(&self, sysid: u32, component_id: u8) -> bool {
        component_id == self.cfg.autopilot_component_id
            && self.autopilot.is_none_or(|(s, _)| u32::from(s) == sysid)
    }

    /// Whether a message's target fields name alfd, all of its system's components, or nobody
    /// (0: a sender that leaves the MAVLink 2 extension out).
    fn for_us(&self, target_system: u8, target_component: u8) -> bool {
        (target_system == 0 || target_system == self.cfg.system_id)
            && (target_component == 0 || target_component == self.cfg.component_id)
    }

    /// A COMMAND_LONG addressed to our component (or to all of our system's, or broadcast), as
    /// an event. Broadcast matters: ArduPilot's MAVLinkCamV2 backend sent IMAGE_START_CAPTURE
    /// with target 0/0 on the camera's link before it filled in the target (docs/link.md).
    fn command_for_us(&self, h: &MavHeader, msg: &MavMessage, trust: Trust) -> Option<LinkEvent> {
        let MavMessage::COMMAND_LONG(c) = msg else {
            return None;
        };
        self.for_us(c.target_system, c.target_component)
            .then_some(LinkEvent::Command {
                system_id: h.system_id as u8,
                component_id: h.component_id,
                command: c.command as u32,
                params: [
                    c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
                ],
                trust,
            })
    }

    fn on_attitude(&mut self, boot_ms: u32, q: DQuat, rates: DVec3, out: &mut Vec<Reaction>) {
        let s = AttitudeSample {
            time_ns: boot_ms as u64 * 1_000_000,
            q,
            rates_rps: rates,
        };
        if self.poses.push_attitude(s).is_err() {
            self.health.rejected_attitude += 1;
            return;
        }
        if let Some(st) = self.state.as_mut() {
            let q = s.q.normalize();
            st.q = [q.w, q.x, q.y, q.z];
            let (yaw, pitch, roll) = q.to_euler(glam::EulerRot::ZYX);
            st.rpy_deg = [roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()];
            out.push(Reaction::StateChanged);
        }
    }

    fn on_position(&mut self, p: &GLOBAL_POSITION_INT_DATA, rx_ns: u64, out: &mut Vec<Reaction>) {
        if !self.time_ok(p.time_boot_ms, rx_ns, out) {
            return;
        }
        let g = Geodetic {
            lat_deg: p.lat as f64 * 1e-7,
            lon_deg: p.lon as f64 * 1e-7,
            alt_m: p.alt as f64 * 1e-3,
        };
        if !(-90.0..=90.0).contains(&g.lat_deg) || !(-180.0..=180.0).contains(&g.lon_deg) {
            self.health.rejected_position += 1;
            return;
        }
        // ArduPilot sends lat = lon = 0 until its EKF has an origin: no position at all.
        if p.lat == 0 && p.lon == 0 {
            self.health.positions_without_origin += 1;
            return;
        }
        self.rel_alt_m = p.relative_alt as f64 * 1e-3;
        if self.frame.is_none() {
            // Neither origin nor home yet: the first position with a 3-D fix (where
            // GPS_RAW_INT says), at the ground relative altitude is measured from (alfd may
            // start in the air). HOME_POSITION or GPS_GLOBAL_ORIGIN re-anchor it when they come.
            if self
                .gps_fix
                .is_some_and(|f| f < GpsFixType::GPS_FIX_TYPE_3D_FIX as u8)
            {
                self.health.positions_without_origin += 1;
                return;
            }
            let home = Geodetic {
                alt_m: g.alt_m - self.rel_alt_m,
                ..g
            };
            self.anchor_at(AnchorSource::Position, home, out);
        }
        let Some(frame) = self.frame else {
            return;
        };
        let pos = DVec3::from_array(frame.to_ned(g));
        let vel = DVec3::new(p.vx as f64, p.vy as f64, p.vz as f64) * 0.01;
        let time_ns = p.time_boot_ms as u64 * 1_000_000;
        let verdict = self.gate.check(time_ns, pos, vel);
        match verdict {
            Verdict::Accept => {}
            Verdict::Glitch { jump_m } => {
                self.health.glitch_rejected += 1;
                if !self.health.glitch_active {
                    self.health.glitch_active = true;
                    self.health.glitches += 1;
                    out.push(Reaction::Event(LinkEvent::GpsGlitch { jump_m }));
                }
                return;
            }
            Verdict::Reanchored { jump_m } => {
                self.health.reanchors += 1;
                out.push(Reaction::Event(LinkEvent::GpsReanchored { jump_m }));
            }
        }
        self.health.glitch_active = false;
        if matches!(verdict, Verdict::Reanchored { .. }) {
            self.local.reset();
        }
        self.local.on_global(NedSample {
            time_ns,
            pos_m: pos,
            vel_mps: vel,
        });
        // While the local stream serves, this sample only keeps its offset and the height.
        if self.local.active(time_ns) {
            if let Some(s) = self.state.as_mut() {
                s.rel_alt_m = self.rel_alt_m;
            }
            return;
        }
        let sample = PositionSample {
            time_ns,
            pos_ned_m: pos,
            vel_ned_mps: vel,
        };
        self.accept_position(sample, g, p.time_boot_ms, rx_ns, out);
    }

    /// LOCAL_POSITION_NED: once paired with GLOBAL_POSITION_INT, the position in the link's frame.
    fn on_local_position(
        &mut self,
        p: &LOCAL_POSITION_NED_DATA,
        rx_ns: u64,
        out: &mut Vec<Reaction>,
    ) {
        if !self.time_ok(p.time_boot_ms, rx_ns, out) {
            return;
        }
        // The global stream decides glitches, and there is no frame before an origin.
        let Some(frame) = self.frame.filter(|_| !self.health.glitch_active) else {
            return;
        };
        let sample = NedSample {
            time_ns: p.time_boot_ms as u64 * 1_000_000,
            pos_m: DVec3::new(p.x as f64, p.y as f64, p.z as f64),
            vel_mps: DVec3::new(p.vx as f64, p.vy as f64, p.vz as f64),
        };
        let s = match self.local.on_local(sample) {
            LocalOutcome::Position(s) => s,
            LocalOutcome::Unpaired => return,
            LocalOutcome::Disagrees { .. } => {
                self.health.local_disagreements += 1;
                return;
            }
            LocalOutcome::Invalid => {
                self.health.rejected_position += 1;
                return;
            }
        };
        self.health.local_offset_restarts = self.local.restarts;
        // Where the stream switches from global to local samples, one may not be newer.
        if self
            .poses
            .newest_position()
            .is_some_and(|n| n.time_ns >= s.time_ns)
        {
            return;
        }
        let g = frame.to_geodetic(s.pos_m.to_array());
        self.health.local_positions += 1;
        let sample = PositionSample {
            time_ns: s.time_ns,
            pos_ned_m: s.pos_m,
            vel_ned_mps: s.vel_mps,
        };
        self.accept_position(sample, g, p.time_boot_ms, rx_ns, out);
    }

    /// Keeps a position and publishes it as the vehicle's state.
    fn accept_position(
        &mut self,
        sample: PositionSample,
        g: Geodetic,
        time_boot_ms: u32,
        rx_ns: u64,
        out: &mut Vec<Reaction>,
    ) {
        let Some(frame) = self.frame else {
            return;
        };
        let (time_ns, pos, vel) = (sample.time_ns, sample.pos_ned_m, sample.vel_ned_mps);
        match self.poses.push_position(sample) {
            Ok(()) => {}
            Err(PushError::OutOfOrder) => {
                self.health.out_of_order += 1;
                return;
            }
            Err(PushError::Invalid) => {
                self.health.rejected_position += 1;
                return;
            }
        }
        self.health.positions_accepted += 1;
        self.health.last_position_rx_mono_ns = rx_ns;
        let mono_ns = self.sync.remote_to_local(time_ns);
        let prev = self.state.take();
        self.state = Some(VehicleState {
            time_boot_ms,
            mono_ns,
            position: g,
            pos_ned_m: pos.to_array(),
            vel_ned_mps: vel.to_array(),
            home: frame.home(),
            origin_source: self.anchor.unwrap_or(AnchorSource::Position),
            rel_alt_m: self.rel_alt_m,
            airborne: self.airborne(),
            q: prev.as_ref().map_or([1.0, 0.0, 0.0, 0.0], |s| s.q),
            rpy_deg: prev.as_ref().map_or([0.0; 3], |s| s.rpy_deg),
            gps_fix: self.gps_fix.unwrap_or(0),
            armed: self.armed,
        });
        out.push(Reaction::StateChanged);
    }
}

/// A position from degE7 and mm, unless it is lat = lon = 0 (nothing known) or out of range.
fn valid_geodetic(lat_e7: i32, lon_e7: i32, alt_mm: i32) -> Option<Geodetic> {
    let g = Geodetic {
        lat_deg: lat_e7 as f64 * 1e-7,
        lon_deg: lon_e7 as f64 * 1e-7,
        alt_m: alt_mm as f64 * 1e-3,
    };
    let known = (lat_e7, lon_e7) != (0, 0);
    (known && (-90.0..=90.0).contains(&g.lat_deg) && (-180.0..=180.0).contains(&g.lon_deg))
        .then_some(g)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn command(from: u32) -> (MavHeader, MavMessage) {
        let h = MavHeader {
            system_id: from,
            component_id: 190,
            sequence: 0,
        };
        let m = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            command: MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            target_system: 1,
            target_component: 100,
            ..Default::default()
        });
        (h, m)
    }

    #[test]
    fn commands_from_any_system_say_whether_it_is_accepted() {
        let mut t = Tracker::new(LinkConfig::for_address("udpin:127.0.0.1:0"));
        let (h, m) = command(1);
        let got = t.on_message(&h, &m, 1_000);
        assert!(matches!(
            got.as_slice(),
            [Reaction::Event(LinkEvent::Command {
                system_id: 1,
                command: 2000,
                trust: Trust::Accepted,
                ..
            })]
        ));
        // Not in accept_system_ids ([1]): still passed on, so the camera can answer a
        // request or refuse the command with DENIED, never silence.
        let (h, m) = command(245);
        let got = t.on_message(&h, &m, 2_000);
        assert!(matches!(
            got.as_slice(),
            [Reaction::Event(LinkEvent::Command {
                system_id: 245,
                component_id: 190,
                command: 2000,
                trust: Trust::Foreign,
                ..
            })]
        ));
        assert_eq!(t.health.foreign_commands, 1);
        assert_eq!(t.health.foreign_ignored, 0);
        assert_eq!(t.health.messages_rx, 1);
        // Anything else from it is ignored, as is a command for another component.
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA::default());
        assert!(t.on_message(&h, &hb, 3_000).is_empty());
        let MavMessage::COMMAND_LONG(mut c) = m else {
            unreachable!()
        };
        c.target_component = 1;
        let other = MavMessage::COMMAND_LONG(c);
        assert!(t.on_message(&h, &other, 4_000).is_empty());
        assert_eq!(t.health.foreign_ignored, 2);
        assert_eq!(t.health.foreign_commands, 1);
    }

    fn header(system_id: u32, component_id: u8) -> MavHeader {
        MavHeader {
            system_id,
            component_id,
            sequence: 0,
        }
    }

    fn timesync_reply(ts1: u64, tc1: i64, target: (u8, u8)) -> MavMessage {
        MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1,
            ts1: ts1 as i64,
            target_system: target.0,
            target_component: target.1,
        })
    }

    #[test]
    fn timesync_answers_only_from_the_autopilot() {
        let mut cfg = LinkConfig::for_address("udpin:127.0.0.1:0");
        cfg.accept_system_ids = vec![1, 255];
        let mut t = Tracker::new(cfg);
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA::default());
        t.on_message(&header(1, 1), &hb, 1_000);
        assert_eq!(t.autopilot, Some((1, 1)));
        // The autopilot's boot clock reads local time minus 0.5 s; every reply takes 1 ms.
        let boot = |local_ns: u64| (local_ns - 500_000_000) as i64;
        for i in 0..5u64 {
            let sent = 1_000_000_000 + i * 100_000_000;
            let MavMessage::TIMESYNC(req) = t.timesync_request(sent) else {
                unreachable!()
            };
            assert_eq!((req.target_system, req.target_component), (1, 1));
            // Forwarded to ground stations, which answer first and with their own clocks:
            // QGC (255, 190), one on the autopilot's component id, and the autopilot
            // answering someone else. None of them may be taken for the exchange.
            for (h, target) in [
                (header(255, 190), (1, 100)),
                (header(255, 1), (1, 100)),
                (header(2, 1), (1, 100)),
                (header(1, 1), (255, 190)),
                (header(1, 1), (1, 1)),
            ] {
                let wrong = timesync_reply(sent, boot(sent) + 7_000_000_000, target);
                assert!(t.on_message(&h, &wrong, sent + 800_000).is_empty());
            }
            // The autopilot's own (target as sent by older firmware: 0).
            let right = timesync_reply(sent, boot(sent + 500_000), (0, 0));
            t.on_message(&header(1, 1), &right, sent + 1_000_000);
        }
        assert_eq!(t.health.timesync_foreign, 4 * 5);
        // System 2 is not accepted at all.
        assert_eq!(t.health.foreign_ignored, 5);
        assert!(t.health.synced);
        assert_eq!(t.health.offset_ns, 500_000_000);
        assert_eq!(t.health.rtt_min_ns, 1_000_000);
        assert_eq!(t.sync.local_to_remote(2_000_000_000), Some(1_500_000_000));
        // A ground station's HEARTBEAT on component 1 does not become the autopilot.
        t.on_message(&header(255, 1), &hb, 3_000_000_000);
        assert_eq!(t.autopilot, Some((1, 1)));
        assert_eq!(t.health.autopilot_heartbeats, 1);
    }

    /// The first HEARTBEAT names the autopilot's firmware (how it counts a distance
    /// trigger); later ones do not again.
    #[test]
    fn the_first_heartbeat_says_which_autopilot() {
        let mut t = Tracker::new(LinkConfig::for_address("udpin:127.0.0.1:0"));
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            ..Default::default()
        });
        let found = |r: &Vec<Reaction>| {
            r.iter()
                .filter_map(|r| match r {
                    Reaction::Event(LinkEvent::AutopilotFound { firmware }) => Some(*firmware),
                    _ => None,
                })
                .collect::<Vec<_>>()
        };
        let first = t.on_message(&header(1, 1), &hb, 1_000);
        assert_eq!(
            found(&first),
            vec![MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA]
        );
        let second = t.on_message(&header(1, 1), &hb, 2_000);
        assert!(found(&second).is_empty(), "{second:?}");
    }

    #[test]
    fn timesync_requests_from_the_autopilot_are_answered() {
        let mut t = Tracker::new(LinkConfig::for_address("udpin:127.0.0.1:0"));
        let h = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        let m = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 77,
            target_system: 0,
            target_component: 0,
        });
        let got = t.on_message(&h, &m, 5_000);
        let [Reaction::Reply(r)] = got.as_slice() else {
            panic!("{got:?}")
        };
        assert!(matches!(
            **r,
            MavMessage::TIMESYNC(TIMESYNC_DATA {
                tc1: 5_000,
                ts1: 77,
                ..
            })
        ));
    }
}

#[cfg(test)]
mod origin_tests {
    use super::*;

    const MS: u64 = 1_000_000;
    /// The autopilot's boot clock reads local time minus this.
    const OFFSET_NS: u64 = 500 * MS;
    const AP: (u32, u8) = (1, 1);
    const HOME: (f64, f64, f64) = (47.397_742, 8.545_594, 488.0);

    fn h() -> MavHeader {
        MavHeader {
            system_id: AP.0,
            component_id: AP.1,
            sequence: 0,
        }
    }

    /// A tracker in time sync with an autopilot that has sent one HEARTBEAT (`armed`).
    fn synced(armed: bool) -> Tracker {
        let mut t = Tracker::new(LinkConfig::for_address("udpin:127.0.0.1:0"));
        t.on_message(&h(), &heartbeat(armed), 1_000);
        for i in 0..5u64 {
            let sent = 1_000 * MS + i * 100 * MS;
            t.timesync_request(sent);
            let reply = MavMessage::TIMESYNC(TIMESYNC_DATA {
                tc1: (sent + MS / 2 - OFFSET_NS) as i64,
                ts1: sent as i64,
                target_system: 0,
                target_component: 0,
            });
            t.on_message(&h(), &reply, sent + MS);
        }
        assert!(t.health.synced);
        t
    }

    fn heartbeat(armed: bool) -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            base_mode: if armed {
                MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED
            } else {
                MavModeFlag::empty()
            },
            ..Default::default()
        })
    }

    fn fix(fix_type: GpsFixType) -> MavMessage {
        MavMessage::GPS_RAW_INT(GPS_RAW_INT_DATA {
            fix_type,
            ..Default::default()
        })
    }

    /// GLOBAL_POSITION_INT at boot time `boot_ms`, `north_m`/`east_m` from HOME, `rel_alt_m`
    /// above it, flying north at 10 m/s; lat = lon = 0 when `zero`.
    fn position(boot_ms: u32, north_m: f64, east_m: f64, rel_alt_m: f64, zero: bool) -> MavMessage {
        let g = LocalFrame::new(Geodetic {
            lat_deg: HOME.0,
            lon_deg: HOME.1,
            alt_m: HOME.2,
        })
        .to_geodetic([north_m, east_m, -rel_alt_m]);
        let (lat, lon) = if zero {
            (0, 0)
        } else {
            (
                (g.lat_deg * 1e7).round() as i32,
                (g.lon_deg * 1e7).round() as i32,
            )
        };
        MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
            time_boot_ms: boot_ms,
            lat,
            lon,
            alt: (g.alt_m * 1e3).round() as i32,
            relative_alt: (rel_alt_m * 1e3).round() as i32,
            vx: 1000,
            ..Default::default()
        })
    }

    fn attitude(boot_ms: u32) -> MavMessage {
        MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
            time_boot_ms: boot_ms,
            q1: 1.0,
            ..Default::default()
        })
    }

    /// The local instant a boot-time sample was taken at.
    fn local(boot_ms: u32) -> u64 {
        boot_ms as u64 * MS + OFFSET_NS
    }

    fn feed(t: &mut Tracker, m: &MavMessage, boot_ms: u32) -> Vec<Reaction> {
        t.on_message(&h(), m, local(boot_ms) + MS)
    }

    fn origin_msg(north_m: f64, east_m: f64) -> MavMessage {
        let g = LocalFrame::new(Geodetic {
            lat_deg: HOME.0,
            lon_deg: HOME.1,
            alt_m: HOME.2,
        })
        .to_geodetic([north_m, east_m, 0.0]);
        MavMessage::GPS_GLOBAL_ORIGIN(GPS_GLOBAL_ORIGIN_DATA {
            latitude: (g.lat_deg * 1e7).round() as i32,
            longitude: (g.lon_deg * 1e7).round() as i32,
            altitude: (g.alt_m * 1e3).round() as i32,
            time_usec: 0,
        })
    }

    #[test]
    fn zero_positions_never_anchor_and_the_origin_anchors_at_once() {
        let mut t = synced(true);
        // ArduPilot before its EKF origin: no fix, then a fix while positions still read 0, 0.
        feed(&mut t, &fix(GpsFixType::GPS_FIX_TYPE_NO_FIX), 2_000);
        for k in 0..20u32 {
            if k == 10 {
                feed(
                    &mut t,
                    &fix(GpsFixType::GPS_FIX_TYPE_3D_FIX),
                    2_000 + k * 100,
                );
            }
            feed(
                &mut t,
                &position(2_000 + k * 100, 0.0, 0.0, 0.0, true),
                2_000 + k * 100,
            );
            feed(&mut t, &attitude(2_000 + k * 100), 2_000 + k * 100);
        }
        assert_eq!(t.health.positions_without_origin, 20);
        assert_eq!(t.health.positions_accepted, 0);
        assert!(t.state.is_none(), "no vehicle state before an origin");
        assert!(t.anchor().is_none());
        assert!(matches!(
            t.pose_at(local(3_900)),
            Err(PoseQueryError::Pose(_))
        ));
        assert!(t.wants_origin());
        // The origin: the frame is anchored there, announced once.
        let got = feed(&mut t, &origin_msg(0.0, 0.0), 4_000);
        assert!(
            got.iter().any(|r| matches!(
                r,
                Reaction::Event(LinkEvent::OriginSet {
                    source: AnchorSource::Origin,
                    moved_m: None,
                    ..
                })
            )),
            "{got:?}"
        );
        assert!(!t.wants_origin());
        // The first real position, 100 m north and 60 m up: the pose is there at once.
        for k in 0..3u32 {
            let b = 4_100 + k * 100;
            feed(&mut t, &position(b, 100.0 + k as f64, 0.0, 60.0, false), b);
            feed(&mut t, &attitude(b), b);
        }
        let s = t.state.as_ref().unwrap();
        assert!((s.home.lat_deg - HOME.0).abs() < 1e-7 && (s.home.lon_deg - HOME.1).abs() < 1e-7);
        assert_eq!(s.origin_source, AnchorSource::Origin);
        assert!((s.pos_ned_m[0] - 102.0).abs() < 0.05, "{:?}", s.pos_ned_m);
        assert!((s.pos_ned_m[2] + 60.0).abs() < 0.05, "{:?}", s.pos_ned_m);
        let p = t
            .pose_at(local(4_250))
            .expect("a pose right after the origin");
        assert!((p.pos_ned_m.x - 101.5).abs() < 0.05, "{:?}", p.pos_ned_m);
        assert_eq!(t.health.glitches, 0);
        assert_eq!(t.health.origin_anchors, 1);
    }

    #[test]
    fn a_position_without_a_3d_fix_does_not_anchor() {
        let mut t = synced(true);
        feed(&mut t, &fix(GpsFixType::GPS_FIX_TYPE_2D_FIX), 2_000);
        feed(&mut t, &position(2_100, 5.0, 0.0, 0.0, false), 2_100);
        assert!(t.anchor().is_none());
        // An autopilot that does not answer REQUEST_MESSAGE is not asked again.
        assert!(t.wants_origin());
        // A ground station's request refused is not the link's.
        let refused_to_gcs = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
            result: MavResult::MAV_RESULT_UNSUPPORTED,
            target_system: 255,
            target_component: 190,
            ..Default::default()
        });
        feed(&mut t, &refused_to_gcs, 2_110);
        assert!(t.wants_origin());
        let refused = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
            result: MavResult::MAV_RESULT_UNSUPPORTED,
            ..Default::default()
        });
        feed(&mut t, &refused, 2_120);
        assert!(!t.wants_origin());
        feed(&mut t, &fix(GpsFixType::GPS_FIX_TYPE_3D_FIX), 2_150);
        feed(&mut t, &position(2_200, 5.0, 0.0, 0.0, false), 2_200);
        let (source, home) = t.anchor().unwrap();
        assert_eq!(source, AnchorSource::Position);
        // At the first fixed position, on the ground relative altitude is measured from.
        let d = LocalFrame::new(Geodetic {
            lat_deg: HOME.0,
            lon_deg: HOME.1,
            alt_m: HOME.2,
        })
        .to_ned(home);
        assert!((d[0] - 5.0).abs() < 0.02 && d[1].abs() < 0.02 && d[2].abs() < 0.01);
    }

    #[test]
    fn a_moved_origin_reanchors_without_a_suspension() {
        let mut t = synced(true);
        feed(&mut t, &fix(GpsFixType::GPS_FIX_TYPE_3D_FIX), 2_000);
        // Anchored on the first position (at HOME, 0 m up), then flying north at 10 m/s.
        for k in 0..10u32 {
            let b = 2_000 + k * 100;
            feed(&mut t, &position(b, k as f64, 0.0, 30.0, false), b);
            feed(&mut t, &attitude(b), b);
        }
        assert_eq!(t.anchor().unwrap().0, AnchorSource::Position);
        // The autopilot's origin is 40 m east of where alfd anchored.
        let got = feed(&mut t, &origin_msg(0.0, 40.0), 2_950);
        let moved = got.iter().find_map(|r| match r {
            Reaction::Event(LinkEvent::OriginSet { moved_m, .. }) => *moved_m,
            _ => None,
        });
        assert!((moved.expect("an OriginSet event") - 40.0).abs() < 0.05);
        // The poses already kept are in the new frame: no gap, no glitch, no suspension.
        let p = t.pose_at(local(2_850)).expect("a pose at once");
        assert!((p.pos_ned_m.x - 8.5).abs() < 0.05, "{:?}", p.pos_ned_m);
        assert!((p.pos_ned_m.y + 40.0).abs() < 0.05, "{:?}", p.pos_ned_m);
        for k in 10..15u32 {
            let b = 2_000 + k * 100;
            feed(&mut t, &position(b, k as f64, 0.0, 30.0, false), b);
            feed(&mut t, &attitude(b), b);
        }
        assert_eq!(t.health.glitches, 0, "the re-anchor is no GPS glitch");
        assert_eq!(t.health.positions_accepted, 15);
        let p = t.pose_at(local(3_350)).unwrap();
        assert!((p.pos_ned_m.x - 13.5).abs() < 0.05 && (p.pos_ned_m.y + 40.0).abs() < 0.05);
        // Home resent where the origin already is: nothing moves. A less authoritative
        // HOME_POSITION elsewhere does not move the EKF origin's frame either.
        let home = |east: f64| {
            let MavMessage::GPS_GLOBAL_ORIGIN(o) = origin_msg(0.0, east) else {
                unreachable!()
            };
            MavMessage::HOME_POSITION(HOME_POSITION_DATA {
                latitude: o.latitude,
                longitude: o.longitude,
                altitude: o.altitude,
                ..Default::default()
            })
        };
        assert!(feed(&mut t, &home(40.0), 3_400).is_empty());
        assert!(feed(&mut t, &home(45.0), 3_450).is_empty());
        assert_eq!(t.health.origin_anchors, 2);
        assert_eq!(t.anchor().unwrap().0, AnchorSource::Origin);
    }

    #[test]
    fn airborne_by_landed_state_else_armed_and_height() {
        use MavLandedState::*;
        let j = Airborne::judge;
        assert_eq!(
            j(Some(MAV_LANDED_STATE_IN_AIR), false, 0.0, 2.0),
            Airborne::Yes
        );
        assert_eq!(
            j(Some(MAV_LANDED_STATE_ON_GROUND), true, 50.0, 2.0),
            Airborne::Landed(1)
        );
        assert_eq!(
            j(Some(MAV_LANDED_STATE_TAKEOFF), true, 50.0, 2.0),
            Airborne::Landed(3)
        );
        assert_eq!(j(None, false, 50.0, 2.0), Airborne::Disarmed);
        assert_eq!(
            j(None, true, 1.5, 2.0),
            Airborne::Low {
                rel_alt_cm: 150,
                min_cm: 200
            }
        );
        assert_eq!(j(None, true, 2.0, 2.0), Airborne::Yes);
        assert_eq!(
            j(Some(MAV_LANDED_STATE_UNDEFINED), true, 2.0, 2.0),
            Airborne::Yes
        );
        assert!(!j(None, true, f64::NAN, 0.0).is_airborne());
        assert_eq!(
            Airborne::Low {
                rel_alt_cm: 150,
                min_cm: 200
            }
            .to_string(),
            "1.5 m above home, below min_rel_alt_m 2.0 m"
        );
    }

    #[test]
    fn no_pose_for_a_capture_until_airborne() {
        let mut t = synced(false);
        feed(&mut t, &fix(GpsFixType::GPS_FIX_TYPE_3D_FIX), 2_000);
        let ground = |t: &mut Tracker, from: u32| {
            for k in 0..3u32 {
                let b = from + k * 100;
                feed(t, &position(b, 0.0, 0.0, 0.0, false), b);
                feed(t, &attitude(b), b);
            }
        };
        ground(&mut t, 2_000);
        let err = t.pose_at(local(2_150)).unwrap_err();
        assert_eq!(err, PoseQueryError::NotAirborne(Airborne::Disarmed));
        assert_eq!(err.to_string(), "not airborne: disarmed");
        // Armed, still on the ground by its landed state.
        feed(&mut t, &heartbeat(true), 2_300);
        let landed = |s| {
            MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
                landed_state: s,
                ..Default::default()
            })
        };
        feed(
            &mut t,
            &landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND),
            2_300,
        );
        ground(&mut t, 2_300);
        assert_eq!(
            t.pose_at(local(2_450)).unwrap_err().to_string(),
            "not airborne: on the ground (landed state)"
        );
        assert_eq!(t.state.as_ref().unwrap().airborne, Airborne::Landed(1));
        let got = feed(
            &mut t,
            &landed(MavLandedState::MAV_LANDED_STATE_IN_AIR),
            2_600,
        );
        assert!(got.contains(&Reaction::StateChanged));
        ground(&mut t, 2_600);
        assert!(t.pose_at(local(2_750)).is_ok());
        // Without the requirement, the ground is no reason.
        let mut cfg = LinkConfig::for_address("udpin:127.0.0.1:0");
        cfg.require_airborne = false;
        t.cfg = cfg;
        feed(&mut t, &heartbeat(false), 2_900);
        feed(
            &mut t,
            &landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND),
            2_900,
        );
        assert!(t.pose_at(local(2_750)).is_ok());
    }

    #[test]
    fn camera_feedback_is_counted_and_passed_on() {
        let mut t = synced(true);
        let m = MavMessage::CAMERA_FEEDBACK(CAMERA_FEEDBACK_DATA {
            time_usec: 1_700_000_000_000_000,
            img_idx: 7,
            lat: 473_977_420,
            lng: 85_455_940,
            alt_msl: 528.0,
            alt_rel: 40.0,
            ..Default::default()
        });
        let got = feed(&mut t, &m, 2_000);
        assert_eq!(t.health.camera_feedbacks, 1);
        assert!(matches!(
            got.as_slice(),
            [Reaction::Event(LinkEvent::CameraFeedback {
                img_idx: 7,
                gps_time_usec: 1_700_000_000_000_000,
                mono_ns: None,
                ..
            })]
        ));
    }

    /// The autopilot's answer to a camera command is passed on when it is addressed to alfd
    /// (or to nobody: the extension left out), not when it answers a ground station.
    #[test]
    fn only_answers_to_alfds_camera_commands_are_passed_on() {
        let mut t = synced(true);
        let (sys, comp) = (t.cfg.system_id, t.cfg.component_id);
        for ((target_system, target_component), ours) in [
            ((0, 0), true),
            ((sys, comp), true),
            ((255, 190), false),
            ((sys, 1), false),
        ] {
            let ack = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
                result: MavResult::MAV_RESULT_DENIED,
                target_system,
                target_component,
                ..Default::default()
            });
            let got = feed(&mut t, &ack, 2_000);
            let passed = matches!(
                got.as_slice(),
                [Reaction::Event(LinkEvent::CommandAck { .. })]
            );
            assert_eq!(
                passed, ours,
                "to ({target_system}, {target_component}): {got:?}"
            );
        }
    }

    /// A feedback's GPS time stamp is mapped through SYSTEM_TIME and TIMESYNC onto this
    /// machine's clock; a stamp nothing maps, or one that disagrees with its own arrival, is
    /// not believed (the coordinator then takes the arrival).
    #[test]
    fn camera_feedback_is_placed_by_its_gps_time() {
        const UNIX_AT_BOOT_US: u64 = 1_780_000_000_000_000;
        let instant = |t: &mut Tracker, stamp_us: u64, heard_ms: u32| {
            let m = MavMessage::CAMERA_FEEDBACK(CAMERA_FEEDBACK_DATA {
                time_usec: stamp_us,
                img_idx: 3,
                ..Default::default()
            });
            match feed(t, &m, heard_ms).as_slice() {
                [Reaction::Event(LinkEvent::CameraFeedback {
                    mono_ns,
                    received_mono_ns,
                    ..
                })] => {
                    assert_eq!(*received_mono_ns, local(heard_ms) + MS);
                    *mono_ns
                }
                other => panic!("{other:?}"),
            }
        };
        let mut t = synced(true);
        // No SYSTEM_TIME yet: nothing maps GPS time.
        assert_eq!(instant(&mut t, UNIX_AT_BOOT_US + 1_950_250, 2_000), None);
        let time = MavMessage::SYSTEM_TIME(SYSTEM_TIME_DATA {
            time_unix_usec: UNIX_AT_BOOT_US + 1_900_000,
            time_boot_ms: 1_900,
        });
        feed(&mut t, &time, 1_900);
        // The picture 50 ms before it was heard of, to within the millisecond.
        let picture_ns = 1_950_250 * 1000 + OFFSET_NS;
        let got = instant(&mut t, UNIX_AT_BOOT_US + 1_950_250, 2_000).expect("mapped");
        assert!(got.abs_diff(picture_ns) <= MS, "{got} vs {picture_ns}");
        // A zero stamp (no GPS time), one 100 ms after its arrival, one 5 s before: not
        // believed. Within the mapping's error after it: its arrival.
        assert_eq!(instant(&mut t, 0, 2_000), None);
        assert_eq!(instant(&mut t, UNIX_AT_BOOT_US + 2_100_000, 2_000), None);
        assert_eq!(
            instant(&mut t, UNIX_AT_BOOT_US + 2_002_000, 2_000),
            Some(local(2_000) + MS)
        );
        assert_eq!(instant(&mut t, UNIX_AT_BOOT_US + 1_000, 5_000), None);
        // A SYSTEM_TIME without UTC (time_unix_usec 0) keeps the last one that had it.
        let no_utc = MavMessage::SYSTEM_TIME(SYSTEM_TIME_DATA {
            time_unix_usec: 0,
            time_boot_ms: 2_100,
        });
        feed(&mut t, &no_utc, 2_100);
        let later_ns = 2_150_000 * 1000 + OFFSET_NS;
        let got = instant(&mut t, UNIX_AT_BOOT_US + 2_150_000, 2_200).expect("mapped");
        assert!(got.abs_diff(later_ns) <= MS, "{got} vs {later_ns}");
    }

    #[test]
    fn a_broadcast_command_is_for_us() {
        // Older ArduPilot: IMAGE_START_CAPTURE from MAVLinkCamV2 with target 0/0.
        let mut t = synced(true);
        let m = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            command: MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            param3: 1.0,
            param4: 1.0,
            ..Default::default()
        });
        let got = feed(&mut t, &m, 2_000);
        assert!(matches!(
            got.as_slice(),
            [Reaction::Event(LinkEvent::Command {
                command: 2000,
                trust: Trust::Accepted,
                ..
            })]
        ));
    }

    /// LOCAL_POSITION_NED at boot time `boot_ms` in a frame `shift_m` north of HOME, 10 m/s north.
    fn local_position(boot_ms: u32, north_m: f64, shift_m: f64) -> MavMessage {
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: boot_ms,
            x: (north_m - shift_m) as f32,
            y: 0.0,
            z: -50.0,
            vx: 10.0,
            ..Default::default()
        })
    }

    /// The positions kept at `boot_ms`, against the truth (10 m/s north from HOME).
    fn worst_error_m(t: &Tracker, from_ms: u32, to_ms: u32) -> f64 {
        (from_ms..to_ms)
            .step_by(7)
            .map(|ms| {
                let p = t.pose_at(local(ms)).expect("a pose").pos_ned_m;
                (p.x - 10.0 * ms as f64 * 1e-3).abs()
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn local_positions_replace_the_quantised_global_ones_and_a_glitch_stops_both() {
        let (mut global_only, mut both) = (synced(true), synced(true));
        for t in [&mut global_only, &mut both] {
            feed(t, &fix(GpsFixType::GPS_FIX_TYPE_3D_FIX), 1_990);
            feed(t, &origin_msg(0.0, 0.0), 1_995);
        }
        // 10 Hz each, the local sample 1 ms after the global one, in a frame 12.3 m north.
        for k in 0..100u32 {
            let ms = 2_000 + 100 * k;
            let north = 10.0 * ms as f64 * 1e-3;
            for t in [&mut global_only, &mut both] {
                feed(t, &position(ms, north, 0.0, 50.0, false), ms);
                feed(t, &attitude(ms), ms);
            }
            let north_l = 10.0 * (ms + 1) as f64 * 1e-3;
            feed(&mut both, &local_position(ms + 1, north_l, 12.3), ms + 1);
        }
        assert_eq!(global_only.health.local_positions, 0);
        assert!(both.health.local_positions >= 98, "{:?}", both.health);
        assert_eq!(both.health.out_of_order, 0);
        assert_eq!(both.health.local_disagreements, 0);
        // GLOBAL_POSITION_INT's 1e-7° is 1.1 cm north: half of it shows between samples; the
        // local stream (f32 near 80 m: 8 µm) with the offset's mean leaves under a millimetre.
        let (coarse, fine) = (
            worst_error_m(&global_only, 8_000, 11_900),
            worst_error_m(&both, 8_000, 11_900),
        );
        assert!(coarse > 0.004, "global only: {coarse} m");
        assert!(fine < 0.001, "with the local stream: {fine} m");
        let state = both.state.clone().expect("a state");
        assert!((state.pos_ned_m[0] - 10.0 * 11_901.0 * 1e-3).abs() < 0.001);
        assert!((state.rel_alt_m - 50.0).abs() < 1e-9);
        // A 30 m glitch in both streams: the gate rejects the global samples, and the local
        // ones are not kept either.
        let kept = both.health.local_positions;
        for k in 0..5u32 {
            let ms = 12_000 + 100 * k;
            let north = 10.0 * ms as f64 * 1e-3 + 30.0;
            feed(&mut both, &position(ms, north, 0.0, 50.0, false), ms);
            feed(
                &mut both,
                &local_position(ms + 1, north + 0.01, 12.3),
                ms + 1,
            );
        }
        assert!(both.health.glitch_active);
        assert_eq!(both.health.local_positions, kept);
    }

    #[test]
    fn a_refused_local_position_rate_leaves_the_rates_acknowledged() {
        let mut t = synced(true);
        t.pending_rates = [33, 32, 31].into();
        let ack = |result| {
            MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                result,
                ..Default::default()
            })
        };
        feed(&mut t, &ack(MavResult::MAV_RESULT_ACCEPTED), 2_000);
        feed(&mut t, &ack(MavResult::MAV_RESULT_UNSUPPORTED), 2_001);
        assert_eq!(t.pending_rates, VecDeque::from([31]));
        assert!(!t.health.rates_acked);
        // Another refusal is not taken for an answer.
        feed(&mut t, &ack(MavResult::MAV_RESULT_DENIED), 2_002);
        assert!(!t.health.rates_acked);
        feed(&mut t, &ack(MavResult::MAV_RESULT_ACCEPTED), 2_003);
        assert!(t.health.rates_acked);
    }
}
