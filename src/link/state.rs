//! The link's bookkeeping, with no I/O: digests each incoming message (at its receive instant)
//! into the TIMESYNC filter, the glitch gate, the pose buffer, the published vehicle state and
//! the health counters, and says what to send back.

use super::config::LinkConfig;
use super::{LinkEvent, LinkHealth, VehicleState};
use crate::core::allowlist::Trust;
use crate::core::geo::{Geodetic, LocalFrame};
use crate::core::glitch::{GlitchConfig, GlitchGate, Verdict};
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
    frame: Option<LocalFrame>,
    pub health: LinkHealth,
    pub state: Option<VehicleState>,
    /// The autopilot we follow: (system id, component id).
    pub autopilot: Option<(u8, u8)>,
    seqs: HashMap<(u32, u8), u8>,
    /// TIMESYNC requests in flight (their ts1 = our send instant).
    outstanding: VecDeque<u64>,
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
        Tracker {
            frame: cfg.home.map(LocalFrame::new),
            sync: TimeSync::new(TimeSyncConfig::default()),
            poses,
            gate,
            health: LinkHealth::default(),
            state: None,
            autopilot: None,
            seqs: HashMap::new(),
            outstanding: VecDeque::new(),
            pending_rates: VecDeque::new(),
            cfg,
        }
    }

    /// A TIMESYNC request to send now (`now_ns` doubles as its ts1).
    pub fn timesync_request(&mut self, now_ns: u64) -> MavMessage {
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

    /// The pose at a local monotonic instant.
    pub fn pose_at(&self, mono_ns: u64) -> Result<Pose, PoseQueryError> {
        let boot_ns = self
            .sync
            .local_to_remote(mono_ns)
            .ok_or(PoseQueryError::NotSynced)?;
        Ok(self.poses.at(boot_ns)?)
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

    fn on_reboot(&mut self, out: &mut Vec<Reaction>) {
        self.poses.clear();
        self.gate.reset();
        self.outstanding.clear();
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
                }
                self.health.autopilot_heartbeats += 1;
                let armed = hb
                    .base_mode
                    .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                if let Some(s) = self.state.as_mut() {
                    s.armed = armed;
                }
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
                let for_us = (t.target_system == 0 || t.target_system == self.cfg.system_id)
                    && (t.target_component == 0 || t.target_component == self.cfg.component_id);
                if !from_autopilot || !for_us {
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
                self.time_ok(t.time_boot_ms, rx_ns, &mut out);
            }
            MavMessage::GLOBAL_POSITION_INT(p) if from_autopilot => {
                self.on_position(p, rx_ns, &mut out)
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
                if let Some(s) = self.state.as_mut() {
                    s.gps_fix = g.fix_type as u8;
                }
            }
            MavMessage::COMMAND_ACK(a)
                if from_autopilot
                    && a.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL
                    && a.result == MavResult::MAV_RESULT_ACCEPTED =>
            {
                self.pending_rates.pop_front();
                self.health.rates_acked = self.pending_rates.is_empty();
            }
            MavMessage::CAMERA_TRIGGER(c) if from_autopilot => {
                out.push(Reaction::Event(LinkEvent::CameraTrigger {
                    seq: c.seq,
                    time_boot_us: c.time_usec,
                    mono_ns: self.sync.remote_to_local(c.time_usec.saturating_mul(1000)),
                }));
            }
            MavMessage::COMMAND_ACK(a)
                if from_autopilot
                    && matches!(
                        a.command,
                        MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST
                            | MavCmd::MAV_CMD_IMAGE_START_CAPTURE
                            | MavCmd::MAV_CMD_DO_DIGICAM_CONTROL
                    ) =>
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

    /// A COMMAND_LONG addressed to our component (or to all of our system's), as an event.
    fn command_for_us(&self, h: &MavHeader, msg: &MavMessage, trust: Trust) -> Option<LinkEvent> {
        let MavMessage::COMMAND_LONG(c) = msg else {
            return None;
        };
        let ours = c.target_system == self.cfg.system_id
            && (c.target_component == self.cfg.component_id || c.target_component == 0);
        ours.then_some(LinkEvent::Command {
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
        // Home: where the first fix was, at the ground the autopilot measures
        // relative altitude from (alfd may start in the air).
        let frame = *self.frame.get_or_insert_with(|| {
            LocalFrame::new(Geodetic {
                alt_m: g.alt_m - p.relative_alt as f64 * 1e-3,
                ..g
            })
        });
        let pos = DVec3::from_array(frame.to_ned(g));
        let vel = DVec3::new(p.vx as f64, p.vy as f64, p.vz as f64) * 0.01;
        let time_ns = p.time_boot_ms as u64 * 1_000_000;
        match self.gate.check(time_ns, pos, vel) {
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
        let sample = PositionSample {
            time_ns,
            pos_ned_m: pos,
            vel_ned_mps: vel,
        };
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
            time_boot_ms: p.time_boot_ms,
            mono_ns,
            position: g,
            pos_ned_m: pos.to_array(),
            vel_ned_mps: vel.to_array(),
            home: frame.home(),
            q: prev.as_ref().map_or([1.0, 0.0, 0.0, 0.0], |s| s.q),
            rpy_deg: prev.as_ref().map_or([0.0; 3], |s| s.rpy_deg),
            gps_fix: prev.as_ref().map_or(0, |s| s.gps_fix),
            armed: prev.as_ref().is_some_and(|s| s.armed),
        });
        out.push(Reaction::StateChanged);
    }
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
