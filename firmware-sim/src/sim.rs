//! The engine: one task owns the vehicle (trajectory, boot clock, stream schedule, camera
//! trigger, active faults); the transport task owns the wire. The handle injects faults and
//! reads the truth; events come out on a broadcast channel. With a ground station configured,
//! the engine is also the router between the two links, like PX4's MAVLink forwarding.

use crate::clock::{instant_at, mono_ns, BootClock};
use crate::config::{Autopilot, CameraBackend, FaultKind, SimConfig};
use crate::faults::{delay, mangle, Noise, Rng};
use crate::geo::ned_to_geodetic;
use crate::trajectory::{quat_from_rpy, Trajectory};
use crate::transport::{self, GcsLink, Inbound, LinkCtl, LinkIo, Outgoing};
use crate::trigger::{check_period_ns, DistanceTrigger};
use crate::truth::{Line, Truth};
use crate::{Fault, SimEvent};
use mavlink::dialects::ardupilotmega::*;
use mavlink::{MavHeader, MavlinkVersion, Message};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::task::JoinHandle;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("opening the link: {0}")]
    Link(#[from] std::io::Error),
    #[error("ground-station link {address}: {source}")]
    Gcs {
        address: String,
        source: std::io::Error,
    },
    #[error("truth file {path}: {source}")]
    Truth {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("the simulator has stopped")]
    Stopped,
}

/// Counters of what the simulator sent and what the wire did to it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SimStats {
    pub frames_sent: u64,
    pub frames_dropped: u64,
    pub frames_corrupted: u64,
    pub bytes_corrupted: u64,
    /// Frames lost because the transport task was behind (should stay 0).
    pub frames_overflowed: u64,
    /// Messages decoded from the main transport.
    pub received: u64,
    /// The simulator's own frames sent to the ground station.
    pub gcs_sent: u64,
    /// Frames heard on the main transport and passed to the ground station.
    pub forwarded_to_gcs: u64,
    /// Frames from the ground station put on the main transport (before the wire's faults).
    pub forwarded_from_gcs: u64,
    /// TIMESYNC replies of the configured `gcs_timesync` station put on the main transport.
    pub gcs_timesync_replies: u64,
}

struct Shared {
    traj: Trajectory,
    origin: [f64; 3],
    start_mono_ns: u64,
    boot: Mutex<Vec<BootClock>>,
    stats: Mutex<SimStats>,
}

impl Shared {
    fn truth(&self, mono: u64) -> Truth {
        let t = mono.saturating_sub(self.start_mono_ns) as f64 * 1e-9;
        let s = self.traj.state(t);
        let boots = self.boot.lock().expect("boot lock");
        let boot = boots
            .iter()
            .rev()
            .find(|b| b.boot_mono_ns <= mono)
            .or(boots.first())
            .copied();
        let time_boot_ms = boot.map_or(0.0, |b| b.boot_ns(mono) as f64 * 1e-6);
        let g = ned_to_geodetic(self.origin, s.pos_ned_m);
        Truth {
            mono_ns: mono,
            time_boot_ms,
            lat_deg: g[0],
            lon_deg: g[1],
            alt_m: g[2],
            pos_ned_m: s.pos_ned_m,
            vel_ned_mps: s.vel_ned_mps,
            rpy_deg: s.rpy_rad.map(f64::to_degrees),
            q: quat_from_rpy(s.rpy_rad),
        }
    }
}

enum Control {
    Inject(Fault, oneshot::Sender<u64>),
    Stop,
}

/// The running simulator.
pub struct SimHandle {
    address: String,
    link_path: Option<PathBuf>,
    memory_wire: std::sync::Mutex<Option<mpsc::Receiver<tokio::io::DuplexStream>>>,
    control: mpsc::Sender<Control>,
    events: broadcast::Sender<SimEvent>,
    shared: Arc<Shared>,
    task: JoinHandle<()>,
}

impl SimHandle {
    /// The rust-mavlink address alfd should open (`serial:PATH:921600` for a pty, where PATH is
    /// a symlink the simulator keeps pointing at the current pty).
    pub fn address(&self) -> &str {
        &self.address
    }

    /// The pty's stable symlink, if the transport is a pty.
    pub fn link_path(&self) -> Option<&Path> {
        self.link_path.as_deref()
    }

    /// With [`crate::Transport::Memory`]: the link's ends, one per (re)opening, for the
    /// one who takes them (the first call); `None` for another transport or a second call.
    pub fn take_memory_wire(&self) -> Option<mpsc::Receiver<tokio::io::DuplexStream>> {
        self.memory_wire
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take()
    }

    pub fn subscribe(&self) -> broadcast::Receiver<SimEvent> {
        self.events.subscribe()
    }

    /// Apply a fault now; resolves with the monotonic instant it took effect.
    pub async fn inject(&self, fault: Fault) -> Result<u64, SimError> {
        let (tx, rx) = oneshot::channel();
        self.control
            .send(Control::Inject(fault, tx))
            .await
            .map_err(|_| SimError::Stopped)?;
        rx.await.map_err(|_| SimError::Stopped)
    }

    /// The true pose at a monotonic instant.
    pub fn truth_at_mono_ns(&self, mono_ns: u64) -> Truth {
        self.shared.truth(mono_ns)
    }

    /// The survey origin (lat deg, lon deg, alt m) that local NED truth is relative to.
    pub fn origin(&self) -> [f64; 3] {
        self.shared.origin
    }

    pub fn stats(&self) -> SimStats {
        *self.shared.stats.lock().expect("stats lock")
    }

    /// Stop and wait for the engine to finish (the truth file is flushed).
    pub async fn shutdown(self) {
        let _ = self.control.send(Control::Stop).await;
        let _ = self.task.await;
    }
}

/// Start the simulator on the current tokio runtime.
pub async fn start(config: SimConfig) -> Result<SimHandle, SimError> {
    let (events, _) = broadcast::channel(4096);
    let mut io = transport::start(config.transport.clone(), events.clone()).await?;
    let gcs = match &config.gcs {
        Some(a) => Some(GcsLink::open(a).await.map_err(|source| SimError::Gcs {
            address: a.clone(),
            source,
        })?),
        None => None,
    };
    let truth = match &config.truth_path {
        Some(p) => Some(std::io::BufWriter::new(std::fs::File::create(p).map_err(
            |source| SimError::Truth {
                path: p.clone(),
                source,
            },
        )?)),
        None => None,
    };
    let now = mono_ns();
    let boot = BootClock {
        boot_mono_ns: now,
        drift: config.clock_drift_ppm * 1e-6,
    };
    let s = &config.survey;
    let shared = Arc::new(Shared {
        traj: Trajectory::new(s, config.faults.seed).with_prelude(
            config.vehicle.ground.as_secs_f64(),
            config.vehicle.climb_mps,
        ),
        origin: [s.origin_lat_deg, s.origin_lon_deg, s.origin_alt_m],
        start_mono_ns: now,
        boot: Mutex::new(vec![boot]),
        stats: Mutex::new(SimStats::default()),
    });
    let (control, control_rx) = mpsc::channel(16);
    let address = io.address.clone();
    let link_path = io.link_path.clone();
    let memory_wire = std::sync::Mutex::new(io.memory_peers.take());
    let mut engine = Engine::new(config, shared.clone(), events.clone(), boot, truth);
    let links = Links { main: io, gcs };
    let task = tokio::spawn(async move { engine.run(links, control_rx).await });
    Ok(SimHandle {
        address,
        link_path,
        memory_wire,
        control,
        events,
        shared,
        task,
    })
}

/// The main transport and the optional ground-station port.
struct Links {
    main: LinkIo,
    gcs: Option<GcsLink>,
}

/// Where a frame came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Main,
    Gcs,
}

/// Where the simulator's own frame goes: replies go back where the request came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum To {
    Both,
    Only(Side),
}

/// The streamed messages, by MAVLink id.
const STREAM_IDS: [u32; 9] = [0, 1, 30, 31, 33, 32, 24, 2, 245];
/// MAV_COMP_ID_CAMERA: where ArduPilot's MAVLinkCamV2 (instance 0) looks for its camera.
const CAMERA_COMPONENT: u8 = 100;

struct Engine {
    cfg: SimConfig,
    shared: Arc<Shared>,
    events: broadcast::Sender<SimEvent>,
    boot: BootClock,
    rng: Rng,
    noise: Noise,
    /// Sequence numbers per link (main, ground station), so neither sees gaps.
    seq: [u8; 2],
    /// The sequence of the `gcs_timesync` station's frames.
    gcs_timesync_seq: u8,
    last_delivery: tokio::time::Instant,
    /// Per stream: period (ms, 0 = off) and next due boot ms.
    streams: [(u64, u64); 9],
    silent_until: u64,
    quiet_until: u64,
    glitch: Option<([f64; 3], u64)>,
    /// The distance trigger, and when it fires next (monotonic ns).
    trigger: DistanceTrigger,
    trigger_at: Option<f64>,
    capture_seq: u32,
    /// Milestones already announced: origin set, armed, in the air.
    origin_sent: bool,
    armed_sent: bool,
    in_air_sent: bool,
    /// MAVLinkCamV2: the camera found (system, component), its CAMERA_INFORMATION flags once
    /// read, and when to ask for them next.
    camera: Option<(u8, u8)>,
    camera_flags: Option<CameraCapFlags>,
    caminfo_next_ns: u64,
    pending: Vec<(u64, Fault)>,
    /// Pictures capture commands asked for, due at these instants (`camera_delay` after them).
    command_pictures: std::collections::VecDeque<u64>,
    /// Capture commands refused so far (`camera_refuse_first`).
    commands_refused: u32,
    truth: Option<std::io::BufWriter<std::fs::File>>,
}

fn period_ms(hz: f64) -> u64 {
    if hz <= 0.0 {
        0
    } else {
        ((1000.0 / hz).round() as u64).max(1)
    }
}

impl Engine {
    fn new(
        cfg: SimConfig,
        shared: Arc<Shared>,
        events: broadcast::Sender<SimEvent>,
        boot: BootClock,
        truth: Option<std::io::BufWriter<std::fs::File>>,
    ) -> Self {
        let start = shared.start_mono_ns;
        let pending = cfg
            .faults
            .events
            .iter()
            .map(|e| {
                let f = match e.kind {
                    FaultKind::LinkLoss => Fault::LinkLoss {
                        duration: e.duration,
                    },
                    FaultKind::Reboot => Fault::Reboot {
                        silence: e.duration,
                    },
                    FaultKind::GpsGlitch => Fault::GpsGlitch {
                        offset_m: e.offset_m,
                        duration: e.duration,
                    },
                    FaultKind::Silence => Fault::Silence {
                        duration: e.duration,
                    },
                };
                (start + e.at.as_nanos() as u64, f)
            })
            .collect();
        let noise = Noise {
            corrupt_byte_rate: cfg.faults.corrupt_byte_rate,
            drop_rate: cfg.faults.drop_rate,
            latency: cfg.faults.latency,
            jitter: cfg.faults.jitter,
        };
        let mut e = Engine {
            rng: Rng::new(cfg.faults.seed),
            noise,
            seq: [0; 2],
            gcs_timesync_seq: 0,
            last_delivery: tokio::time::Instant::now(),
            streams: [(0, 0); 9],
            silent_until: 0,
            quiet_until: 0,
            glitch: None,
            trigger: DistanceTrigger::new(cfg.autopilot),
            trigger_at: None,
            capture_seq: 0,
            origin_sent: false,
            armed_sent: false,
            in_air_sent: false,
            camera: None,
            camera_flags: None,
            caminfo_next_ns: 0,
            pending,
            command_pictures: Default::default(),
            commands_refused: 0,
            truth,
            cfg,
            shared,
            events,
            boot,
        };
        e.reset_streams();
        e
    }

    /// The configured period (ms, 0 = off) of each stream.
    fn configured_periods(&self) -> [u64; 9] {
        let r = &self.cfg.streams;
        [
            r.heartbeat,
            r.sys_status,
            r.attitude,
            r.attitude_quaternion,
            r.global_position_int,
            r.local_position_ned,
            r.gps_raw_int,
            r.system_time,
            r.extended_sys_state,
        ]
        .map(period_ms)
    }

    /// The monotonic instant `after` the start.
    fn at(&self, after: std::time::Duration) -> u64 {
        self.shared.start_mono_ns + after.as_nanos() as u64
    }

    fn origin_known(&self, mono: u64) -> bool {
        mono >= self.at(self.cfg.vehicle.origin_delay)
    }

    /// GPS_RAW_INT has a 3-D fix from half the origin delay on: the GPS is fine before the EKF
    /// has its origin (ArduPilot's window of lat = lon = 0 positions with a fix).
    fn fix_known(&self, mono: u64) -> bool {
        mono >= self.at(self.cfg.vehicle.origin_delay / 2)
    }

    fn armed(&self, mono: u64) -> bool {
        mono >= self.at(self.cfg.vehicle.arm_at())
    }

    /// When the take-off climb ends: landed state IN_AIR from then on.
    fn in_air_at(&self) -> u64 {
        self.shared.start_mono_ns + (self.shared.traj.takeoff_done_s() * 1e9) as u64
    }

    fn landed_state(&self, mono: u64) -> MavLandedState {
        if mono >= self.in_air_at() {
            MavLandedState::MAV_LANDED_STATE_IN_AIR
        } else if mono >= self.at(self.cfg.vehicle.ground) {
            MavLandedState::MAV_LANDED_STATE_TAKEOFF
        } else {
            MavLandedState::MAV_LANDED_STATE_ON_GROUND
        }
    }

    /// HOME_POSITION (where the vehicle is, on the ground) or GPS_GLOBAL_ORIGIN (the survey
    /// origin), as ArduPilot fills them: altitude AMSL in mm, local x/y/z and q left zero.
    fn origin_message(&self, id: u32, mono: u64) -> Option<MavMessage> {
        let o = self.shared.origin;
        let now_us = self.boot.boot_ns(mono) / 1000;
        match id {
            242 => {
                let tr = self.shared.truth(mono);
                Some(MavMessage::HOME_POSITION(HOME_POSITION_DATA {
                    latitude: (tr.lat_deg * 1e7).round() as i32,
                    longitude: (tr.lon_deg * 1e7).round() as i32,
                    altitude: (o[2] * 1e3).round() as i32,
                    q: [1.0, 0.0, 0.0, 0.0],
                    time_usec: now_us,
                    ..Default::default()
                }))
            }
            49 => Some(MavMessage::GPS_GLOBAL_ORIGIN(GPS_GLOBAL_ORIGIN_DATA {
                latitude: (o[0] * 1e7).round() as i32,
                longitude: (o[1] * 1e7).round() as i32,
                altitude: (o[2] * 1e3).round() as i32,
                time_usec: now_us,
            })),
            _ => None,
        }
    }

    /// The vehicle's milestones: origin set (GPS_GLOBAL_ORIGIN and HOME_POSITION to all),
    /// armed (home reset where it stands, as ArduCopter does), in the air.
    fn milestones(&mut self, io: &Links, now: u64) {
        if !self.origin_sent && self.origin_known(now) {
            self.origin_sent = true;
            // Not before the first stream tick: a delay of zero means "known from the start",
            // announced only when asked for.
            if !self.cfg.vehicle.origin_delay.is_zero() {
                for id in [49, 242] {
                    if let Some(m) = self.origin_message(id, now) {
                        self.send(io, &m, now, To::Both);
                    }
                }
            }
            let _ = self.events.send(SimEvent::OriginSet { mono_ns: now });
        }
        if !self.armed_sent && self.armed(now) {
            self.armed_sent = true;
            if !self.cfg.vehicle.ground.is_zero() {
                if let Some(m) = self.origin_message(242, now) {
                    self.send(io, &m, now, To::Both);
                }
            }
            let _ = self.events.send(SimEvent::Armed { mono_ns: now });
        }
        if !self.in_air_sent && now >= self.in_air_at() {
            self.in_air_sent = true;
            let _ = self.events.send(SimEvent::InAir { mono_ns: now });
        }
        if let (Some((sys, comp)), None) = (self.camera, self.camera_flags) {
            if now >= self.caminfo_next_ns {
                // MAVLinkCamV2::find_camera: CAMERA_INFORMATION asked for every second.
                self.caminfo_next_ns = now + 1_000_000_000;
                let req = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                    command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
                    param1: 259.0,
                    target_system: sys,
                    target_component: comp,
                    ..Default::default()
                });
                self.send(io, &req, now, To::Only(Side::Main));
            }
        }
    }

    fn reset_streams(&mut self) {
        for (k, p) in self.configured_periods().into_iter().enumerate() {
            self.streams[k] = (p, 1 + k as u64);
        }
    }

    fn next_wake(&self) -> u64 {
        let mut t = u64::MAX;
        for (p, due) in self.streams {
            if p > 0 {
                t = t.min(self.boot.mono_of_boot_ns(due * 1_000_000));
            }
        }
        if let Some(at) = self.trigger_at {
            t = t.min(at as u64);
        }
        if !self.origin_sent {
            t = t.min(self.at(self.cfg.vehicle.origin_delay));
        }
        if !self.armed_sent {
            t = t.min(self.at(self.cfg.vehicle.arm_at()));
        }
        if !self.in_air_sent {
            t = t.min(self.in_air_at());
        }
        for (at, _) in &self.pending {
            t = t.min(*at);
        }
        if let Some(at) = self.command_pictures.front() {
            t = t.min(*at);
        }
        for end in [
            self.silent_until,
            self.quiet_until,
            self.glitch.map_or(0, |g| g.1),
        ] {
            if end > 0 {
                t = t.min(end);
            }
        }
        t
    }

    async fn run(&mut self, mut io: Links, mut control: mpsc::Receiver<Control>) {
        loop {
            let wake = instant_at(self.next_wake());
            let from_gcs = async {
                match io.gcs.as_mut() {
                    Some(g) => g.inbound.recv().await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                biased;
                _ = tokio::time::sleep_until(wake) => self.tick(&io, mono_ns()).await,
                m = io.main.inbound.recv() => match m {
                    Some(m) => self.on_inbound(&io, Side::Main, m),
                    None => break,
                },
                Some(m) = from_gcs => self.on_inbound(&io, Side::Gcs, m),
                c = control.recv() => match c {
                    Some(Control::Inject(f, done)) => {
                        let t = self.apply(&io, f).await;
                        let _ = done.send(t);
                    }
                    Some(Control::Stop) | None => break,
                },
            }
        }
        if let Some(w) = self.truth.as_mut() {
            let _ = w.flush();
        }
        io.main.task.abort();
    }

    async fn tick(&mut self, io: &Links, now: u64) {
        let due: Vec<(u64, Fault)> = self
            .pending
            .iter()
            .filter(|(at, _)| *at <= now)
            .cloned()
            .collect();
        self.pending.retain(|(at, _)| *at > now);
        for (_, f) in due {
            self.apply(io, f).await;
        }
        if self.silent_until > 0 && now >= self.silent_until {
            self.silent_until = 0;
            let _ = self.events.send(SimEvent::SilenceEnd { mono_ns: now });
        }
        if self.quiet_until > 0 && now >= self.quiet_until {
            self.quiet_until = 0;
        }
        if let Some((_, end)) = self.glitch {
            if now >= end {
                self.glitch = None;
                let _ = self.events.send(SimEvent::GlitchEnd { mono_ns: now });
            }
        }
        self.milestones(io, now);
        while let Some(at) = self
            .command_pictures
            .front()
            .copied()
            .filter(|at| *at <= now)
        {
            self.command_pictures.pop_front();
            self.take_command_picture(io, at);
        }
        if let Some(at) = self.trigger_at {
            if at as u64 <= now {
                let at = at as u64;
                if self.capture(io, at, "trigger") || self.cfg.autopilot != Autopilot::ArduPilot {
                    self.trigger.fired(self.path_at(at));
                    self.schedule_trigger(at);
                } else {
                    // ArduPilot keeps trying at its camera's 50 Hz update.
                    let period = check_period_ns(Autopilot::ArduPilot).unwrap_or_default();
                    self.trigger_at = Some((at + period) as f64);
                }
            }
        }
        let boot_now_ms = self.boot.boot_ns(now) / 1_000_000;
        for (k, id) in STREAM_IDS.into_iter().enumerate() {
            let (p, due) = self.streams[k];
            if p == 0 || due > boot_now_ms {
                continue;
            }
            // Far behind (a stall): skip ahead rather than burst.
            let due = if boot_now_ms - due > 1000 {
                boot_now_ms
            } else {
                due
            };
            self.streams[k].1 = due + p;
            self.emit_stream(io, id, due, now);
        }
    }

    fn telemetry_allowed(&self, msg_id: u32, now: u64) -> bool {
        if now < self.quiet_until {
            return false;
        }
        msg_id == 0 || now >= self.silent_until || self.silent_until == 0
    }

    /// Emit stream message `id` sampled at boot time `boot_ms`.
    fn emit_stream(&mut self, io: &Links, id: u32, boot_ms: u64, now: u64) {
        if !self.telemetry_allowed(id, now) {
            return;
        }
        let mono = self.boot.mono_of_boot_ns(boot_ms * 1_000_000);
        let tr = self.shared.truth(mono);
        let mut ned = tr.pos_ned_m;
        if let Some((off, _)) = self.glitch {
            for k in 0..3 {
                ned[k] += off[k];
            }
        }
        let g = ned_to_geodetic(self.shared.origin, ned);
        // ArduPilot before its EKF origin: the location it sends is all zeros; the GPS itself
        // has no fix for a while either.
        let origin_known = self.origin_known(mono);
        let fix_known = self.fix_known(mono);
        let t32 = boot_ms as u32;
        let v = tr.vel_ned_mps;
        let rpy = tr.rpy_deg.map(f64::to_radians);
        let st = self
            .shared
            .traj
            .state(mono.saturating_sub(self.shared.start_mono_ns) as f64 * 1e-9);
        let msg = match id {
            0 => MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                custom_mode: 0,
                mavtype: MavType::MAV_TYPE_QUADROTOR,
                autopilot: match self.cfg.autopilot {
                    Autopilot::Generic => MavAutopilot::MAV_AUTOPILOT_GENERIC,
                    Autopilot::Px4 => MavAutopilot::MAV_AUTOPILOT_PX4,
                    Autopilot::ArduPilot => MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                },
                base_mode: if self.armed(mono) {
                    MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED
                } else {
                    MavModeFlag::empty()
                } | MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                system_status: MavState::MAV_STATE_ACTIVE,
                mavlink_version: 3,
            }),
            1 => MavMessage::SYS_STATUS(SYS_STATUS_DATA {
                voltage_battery: 15_800,
                current_battery: 1_200,
                battery_remaining: 80,
                load: 300,
                ..Default::default()
            }),
            30 => MavMessage::ATTITUDE(ATTITUDE_DATA {
                time_boot_ms: t32,
                roll: rpy[0] as f32,
                pitch: rpy[1] as f32,
                yaw: rpy[2] as f32,
                rollspeed: st.rates_rps[0] as f32,
                pitchspeed: st.rates_rps[1] as f32,
                yawspeed: st.rates_rps[2] as f32,
            }),
            31 => MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
                time_boot_ms: t32,
                q1: tr.q[0] as f32,
                q2: tr.q[1] as f32,
                q3: tr.q[2] as f32,
                q4: tr.q[3] as f32,
                rollspeed: st.rates_rps[0] as f32,
                pitchspeed: st.rates_rps[1] as f32,
                yawspeed: st.rates_rps[2] as f32,
                repr_offset_q: [0.0; 4],
            }),
            33 if !origin_known => MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
                time_boot_ms: t32,
                hdg: u16::MAX,
                ..Default::default()
            }),
            // No local frame without an origin.
            32 if !origin_known => return,
            24 if !fix_known => MavMessage::GPS_RAW_INT(GPS_RAW_INT_DATA {
                time_usec: boot_ms * 1000,
                eph: u16::MAX,
                epv: u16::MAX,
                vel: u16::MAX,
                cog: u16::MAX,
                fix_type: GpsFixType::GPS_FIX_TYPE_NO_FIX,
                satellites_visible: 3,
                ..Default::default()
            }),
            245 => MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
                vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
                landed_state: self.landed_state(mono),
            }),
            33 => MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
                time_boot_ms: t32,
                lat: (g[0] * 1e7).round() as i32,
                lon: (g[1] * 1e7).round() as i32,
                alt: (g[2] * 1e3).round() as i32,
                relative_alt: ((g[2] - self.shared.origin[2]) * 1e3).round() as i32,
                vx: (v[0] * 100.0).round() as i16,
                vy: (v[1] * 100.0).round() as i16,
                vz: (v[2] * 100.0).round() as i16,
                hdg: (tr.rpy_deg[2].rem_euclid(360.0) * 100.0).round() as u16 % 36_000,
            }),
            32 => MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
                time_boot_ms: t32,
                x: ned[0] as f32,
                y: ned[1] as f32,
                z: ned[2] as f32,
                vx: v[0] as f32,
                vy: v[1] as f32,
                vz: v[2] as f32,
            }),
            24 => MavMessage::GPS_RAW_INT(GPS_RAW_INT_DATA {
                time_usec: boot_ms * 1000,
                lat: (g[0] * 1e7).round() as i32,
                lon: (g[1] * 1e7).round() as i32,
                alt: (g[2] * 1e3).round() as i32,
                eph: 70,
                epv: 110,
                vel: (v[0].hypot(v[1]) * 100.0).round() as u16,
                cog: ((v[1].atan2(v[0]).to_degrees().rem_euclid(360.0)) * 100.0) as u16 % 36_000,
                fix_type: GpsFixType::GPS_FIX_TYPE_3D_FIX,
                satellites_visible: 16,
                ..Default::default()
            }),
            2 => MavMessage::SYSTEM_TIME(SYSTEM_TIME_DATA {
                time_unix_usec: crate::clock::unix_us(),
                time_boot_ms: t32,
            }),
            _ => return,
        };
        if id == 33 && self.cfg.truth_every_step {
            self.write_truth("step", None, tr);
        }
        self.send(io, &msg, now, To::Both);
    }

    /// Encode one of the simulator's own messages with the next sequence number of `side`.
    fn encode(&mut self, msg: &MavMessage, side: Side) -> Option<Vec<u8>> {
        let version = if self.cfg.mavlink_version == 1 {
            MavlinkVersion::V1
        } else {
            MavlinkVersion::V2
        };
        if version == MavlinkVersion::V1 && msg.message_id() > 255 {
            return None;
        }
        let seq = &mut self.seq[side as usize];
        let header = MavHeader {
            system_id: self.cfg.system_id.into(),
            component_id: self.cfg.component_id,
            sequence: *seq,
        };
        *seq = seq.wrapping_add(1);
        let mut bytes = Vec::with_capacity(64);
        mavlink::write_versioned_msg(&mut bytes, version, header, msg).ok()?;
        Some(bytes)
    }

    fn send(&mut self, io: &Links, msg: &MavMessage, now: u64, to: To) {
        if to != To::Only(Side::Gcs) {
            if let Some(bytes) = self.encode(msg, Side::Main) {
                if self.wire(io, bytes, now) {
                    self.shared.stats.lock().expect("stats lock").frames_sent += 1;
                }
            }
        }
        if to != To::Only(Side::Main) && io.gcs.is_some() {
            if let Some(bytes) = self.encode(msg, Side::Gcs) {
                self.to_gcs(io, &bytes, |s| &mut s.gcs_sent);
            }
        }
    }

    /// Send a frame to the ground station as is (no faults on that side), counting it in `counter`.
    fn to_gcs(&self, io: &Links, bytes: &[u8], counter: fn(&mut SimStats) -> &mut u64) {
        if io.gcs.as_ref().is_some_and(|g| g.send(bytes)) {
            *counter(&mut self.shared.stats.lock().expect("stats lock")) += 1;
        }
    }

    /// Put a frame on the main transport through the wire's noise; false if the wire dropped it
    /// or the transport task was behind.
    fn wire(&mut self, io: &Links, mut bytes: Vec<u8>, now: u64) -> bool {
        let mut stats = self.shared.stats.lock().expect("stats lock");
        match mangle(&mut self.rng, &self.noise, &mut bytes) {
            None => {
                stats.frames_dropped += 1;
                return false;
            }
            Some(n) if n > 0 => {
                stats.frames_corrupted += 1;
                stats.bytes_corrupted += n as u64;
            }
            Some(_) => {}
        }
        let at = (instant_at(now) + delay(&mut self.rng, &self.noise)).max(self.last_delivery);
        self.last_delivery = at;
        let queued = io.main.out.try_send(Outgoing { at, bytes }).is_ok();
        if !queued {
            stats.frames_overflowed += 1;
        }
        queued
    }

    fn write_truth(&mut self, event: &str, seq: Option<u32>, truth: Truth) {
        if let Some(w) = self.truth.as_mut() {
            let line =
                serde_json::to_string(&Line { event, seq, truth }).expect("truth serialises");
            let _ = writeln!(w, "{line}");
            if event != "step" {
                let _ = w.flush();
            }
        }
    }

    /// The path flown at `mono` (m).
    fn path_at(&self, mono: u64) -> f64 {
        let t = mono.saturating_sub(self.shared.start_mono_ns) as f64 * 1e-9;
        self.shared.traj.state(t).path_m
    }

    /// When the distance trigger fires next, from `now`: at once if its point is behind.
    /// ArduPilot and PX4 check the distance on their own clock (`check_period_ns`: 20 and 50 ms),
    /// so they fire at the first check at or after the point, up to one period late.
    fn schedule_trigger(&mut self, now: u64) {
        // An infinite distance (a float a ground station may send) is on and never reached;
        // −∞ is PX4's shot at once for a new distance.
        let period = check_period_ns(self.cfg.autopilot);
        self.trigger_at = self
            .trigger
            .next_m()
            .filter(|n| *n < f64::INFINITY)
            .map(|next| {
                let at = if next <= self.path_at(now) {
                    now as f64
                } else {
                    let t = now.saturating_sub(self.shared.start_mono_ns) as f64 * 1e-9;
                    self.shared.start_mono_ns as f64 + self.shared.traj.time_at_path(t, next) * 1e9
                };
                match period {
                    None => at,
                    Some(period) => {
                        let boot = self.boot.boot_ns(at.ceil() as u64);
                        let check = boot.div_ceil(period) * period;
                        self.boot.mono_of_boot_ns(check).max(at.ceil() as u64) as f64
                    }
                }
            });
    }

    /// A capture command arrived: its picture now, or `camera_delay` later.
    fn command_picture(&mut self, io: &Links, now: u64) {
        if self.cfg.camera_delay.is_zero() {
            self.take_command_picture(io, now);
        } else {
            let at = now + self.cfg.camera_delay.as_nanos() as u64;
            self.command_pictures.push_back(at);
        }
    }

    /// A picture a capture command asked for (ArduPilot counts its distance from it).
    fn take_command_picture(&mut self, io: &Links, at: u64) {
        if self.capture(io, at, "capture") && self.trigger.is_on() {
            self.trigger.other_picture(self.path_at(at));
            self.schedule_trigger(at);
        }
    }

    /// Takes a picture; false when none was taken (MAVLinkCamV2 without its camera).
    fn capture(&mut self, io: &Links, mono: u64, why: &str) -> bool {
        match self.cfg.camera {
            CameraBackend::MavlinkCamV2 => return self.capture_mavlink_cam(io, mono, why),
            CameraBackend::Servo => {
                // ArduPilot's servo or relay backend: the pulse always goes out, and the
                // picture is known to the world by its CAMERA_FEEDBACK alone.
                let index = self.capture_seq + 1;
                self.capture_seq = index;
                self.fed_back(io, index, mono, mono_ns(), why);
                return true;
            }
            CameraBackend::Trigger => {}
        }
        self.capture_seq += 1;
        let seq = self.capture_seq;
        let boot_us = self.boot.boot_ns(mono) / 1000;
        let msg = MavMessage::CAMERA_TRIGGER(CAMERA_TRIGGER_DATA {
            time_usec: boot_us,
            seq,
        });
        self.send(io, &msg, mono_ns(), To::Both);
        let truth = self.shared.truth(mono);
        self.write_truth(why, Some(seq), truth);
        let _ = self.events.send(SimEvent::Capture {
            mono_ns: mono,
            seq,
            truth,
        });
        true
    }

    /// A picture through ArduPilot's MAVLinkCamV2 backend: nothing until the camera is found and
    /// its CAMERA_INFORMATION says it captures images (`trigger_pic` fails, no photo counted);
    /// then IMAGE_START_CAPTURE (one image, sequence number = the next image index) to the
    /// camera, and CAMERA_FEEDBACK to everyone, stamped with GPS time (UNIX µs).
    fn capture_mavlink_cam(&mut self, io: &Links, mono: u64, why: &str) -> bool {
        let (Some((sys, comp)), Some(flags)) = (self.camera, self.camera_flags) else {
            return false;
        };
        if !flags.contains(CameraCapFlags::CAMERA_CAP_FLAGS_CAPTURE_IMAGE) {
            return false;
        }
        let now = mono_ns();
        let index = self.capture_seq + 1;
        let cmd = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            command: MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            param3: 1.0,
            param4: index as f32,
            target_system: sys,
            target_component: comp,
            ..Default::default()
        });
        self.send(io, &cmd, now, To::Only(Side::Main));
        self.capture_seq = index;
        self.fed_back(io, index, mono, now, why);
        true
    }

    /// Picture `index`, taken at `mono`, said by ArduPilot's CAMERA_FEEDBACK (sent at `now`),
    /// written to the truth and told to the simulator's subscribers.
    fn fed_back(&mut self, io: &Links, index: u32, mono: u64, now: u64, why: &str) {
        let tr = self.shared.truth(mono);
        let feedback = self.feedback(index, mono, now, &tr);
        self.send(io, &feedback, now, To::Both);
        self.write_truth(why, Some(index), tr);
        let _ = self.events.send(SimEvent::Capture {
            mono_ns: mono,
            seq: index,
            truth: tr,
        });
    }

    /// ArduPilot's CAMERA_FEEDBACK for picture `index` taken at `mono` (sent at `now`): stamped
    /// with GPS time (UNIX µs), the vehicle's place and attitude then, to every ground station.
    fn feedback(&self, index: u32, mono: u64, now: u64, tr: &Truth) -> MavMessage {
        let unix_us = crate::clock::unix_us().saturating_sub(now.saturating_sub(mono) / 1000);
        MavMessage::CAMERA_FEEDBACK(CAMERA_FEEDBACK_DATA {
            time_usec: unix_us,
            lat: (tr.lat_deg * 1e7).round() as i32,
            lng: (tr.lon_deg * 1e7).round() as i32,
            alt_msl: tr.alt_m as f32,
            alt_rel: (tr.alt_m - self.shared.origin[2]) as f32,
            roll: tr.rpy_deg[0] as f32,
            pitch: tr.rpy_deg[1] as f32,
            yaw: tr.rpy_deg[2] as f32,
            foc_len: 0.0,
            img_idx: index as u16,
            target_system: 0,
            cam_idx: 0,
            flags: CameraFeedbackFlags::CAMERA_FEEDBACK_PHOTO,
            completed_captures: 0,
        })
    }

    /// MAVLinkCamV2's discovery, from what the camera sends on the main link: a HEARTBEAT of
    /// type CAMERA from component 100, looked for from 10 s after boot until 60 s if armed by
    /// then; then its CAMERA_INFORMATION.
    fn watch_camera(&mut self, header: &MavHeader, msg: &MavMessage, now: u64) {
        if self.cfg.camera != CameraBackend::MavlinkCamV2 || header.component_id != CAMERA_COMPONENT
        {
            return;
        }
        let sys = header.system_id as u8;
        match msg {
            MavMessage::HEARTBEAT(hb)
                if self.camera.is_none() && hb.mavtype == MavType::MAV_TYPE_CAMERA =>
            {
                let boot_ms = self.boot.boot_ns(now) / 1_000_000;
                if boot_ms >= 10_000 && !(boot_ms > 60_000 && self.armed(now)) {
                    self.camera = Some((sys, CAMERA_COMPONENT));
                }
            }
            MavMessage::CAMERA_INFORMATION(info)
                if self.camera == Some((sys, CAMERA_COMPONENT)) =>
            {
                self.camera_flags = Some(info.flags);
            }
            _ => {}
        }
    }

    async fn apply(&mut self, io: &Links, f: Fault) -> u64 {
        let now = mono_ns();
        match f {
            Fault::LinkLoss { duration } => {
                let (tx, rx) = oneshot::channel();
                if io
                    .main
                    .ctl
                    .send(LinkCtl::Down { duration, done: tx })
                    .await
                    .is_ok()
                {
                    return rx.await.unwrap_or(now);
                }
            }
            Fault::Reboot { silence } => {
                self.boot = BootClock {
                    boot_mono_ns: now,
                    ..self.boot
                };
                self.shared.boot.lock().expect("boot lock").push(self.boot);
                self.reset_streams();
                self.trigger.off();
                self.trigger_at = None;
                self.quiet_until = if silence.is_zero() {
                    0
                } else {
                    now + silence.as_nanos() as u64
                };
                let _ = self.events.send(SimEvent::Rebooted { mono_ns: now });
            }
            Fault::GpsGlitch { offset_m, duration } => {
                self.glitch = Some((offset_m, now + duration.as_nanos() as u64));
                let _ = self.events.send(SimEvent::GlitchStart { mono_ns: now });
            }
            Fault::Silence { duration } => {
                self.silent_until = now + duration.as_nanos() as u64;
                let _ = self.events.send(SimEvent::SilenceStart { mono_ns: now });
            }
            Fault::Noise(n) => self.noise = n,
        }
        now
    }

    /// Addressed to this autopilot: no target, a broadcast, or our own ids.
    fn for_me(&self, msg: &MavMessage) -> bool {
        let sys = msg.target_system_id().unwrap_or(0);
        let comp = msg.target_component_id().unwrap_or(0);
        (sys == 0 || sys == self.cfg.system_id) && (comp == 0 || comp == self.cfg.component_id)
    }

    /// Route a frame, then answer it if it is for us. Everything heard on the main transport
    /// goes to the ground station unchanged; what the station sends goes to the main transport
    /// (through the wire's faults) unless it is for this autopilot alone. A booting autopilot
    /// (`quiet_until`) neither routes nor answers.
    fn on_inbound(&mut self, io: &Links, from: Side, m: Inbound) {
        let Inbound {
            mono_ns: now,
            header,
            msg,
            raw,
        } = m;
        if let (Side::Main, Some(msg)) = (from, &msg) {
            let command = match msg {
                MavMessage::COMMAND_LONG(c) => Some(c.command as u32),
                MavMessage::COMMAND_INT(c) => Some(c.command as u32),
                _ => None,
            };
            self.shared.stats.lock().expect("stats lock").received += 1;
            let _ = self.events.send(SimEvent::Received {
                mono_ns: now,
                system_id: header.system_id as u8,
                component_id: header.component_id,
                msg_id: msg.message_id(),
                command,
            });
        }
        if now < self.quiet_until {
            return;
        }
        if let (Side::Main, Some(m)) = (from, &msg) {
            self.watch_camera(&header, m, now);
        }
        if let (Side::Main, Some(MavMessage::TIMESYNC(t))) = (from, &msg) {
            if t.tc1 == 0 {
                self.gcs_answers_timesync(io, t.ts1, &header);
            }
        }
        match from {
            Side::Main => self.to_gcs(io, &raw, |s| &mut s.forwarded_to_gcs),
            Side::Gcs => {
                let only_me = msg.as_ref().is_some_and(|m| {
                    m.target_system_id() == Some(self.cfg.system_id)
                        && m.target_component_id() == Some(self.cfg.component_id)
                });
                if !only_me && self.wire(io, raw, now) {
                    self.shared
                        .stats
                        .lock()
                        .expect("stats lock")
                        .forwarded_from_gcs += 1;
                }
            }
        }
        let Some(msg) = msg.filter(|m| self.for_me(m)) else {
            return;
        };
        let back = To::Only(from);
        match msg {
            MavMessage::TIMESYNC(t) if t.tc1 == 0 => {
                let reply = MavMessage::TIMESYNC(TIMESYNC_DATA {
                    tc1: self.boot.boot_ns(mono_ns()) as i64,
                    ts1: t.ts1,
                    target_system: header.system_id as u8,
                    target_component: header.component_id,
                });
                self.send(io, &reply, mono_ns(), back);
            }
            MavMessage::COMMAND_LONG(c) => {
                let result = self.command(io, &c, now);
                let ack = MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                    command: c.command,
                    result,
                    target_system: header.system_id as u8,
                    target_component: header.component_id,
                    ..Default::default()
                });
                self.send(io, &ack, mono_ns(), back);
                if c.command == MavCmd::MAV_CMD_REQUEST_MESSAGE
                    && result == MavResult::MAV_RESULT_ACCEPTED
                {
                    let id = c.param1 as u32;
                    match self.origin_message(id, now) {
                        // Accepted, but sent only once there is one (GCS_Common's
                        // send_home_position / send_gps_global_origin return silently).
                        Some(m) if self.origin_known(now) => self.send(io, &m, mono_ns(), back),
                        Some(_) => {}
                        None => {
                            let boot_ms = self.boot.boot_ns(now) / 1_000_000;
                            self.emit_stream(io, id, boot_ms, now);
                        }
                    }
                }
            }
            _ => {}
        }
    }

    /// The `gcs_timesync` station's answer to a TIMESYNC request heard on the main transport
    /// (whatever its target: ground stations answer every request they get), stamped by the
    /// station's clock and sent ahead of the autopilot's own reply, so a requester that takes
    /// the first answer matching its ts1 takes the wrong one.
    fn gcs_answers_timesync(&mut self, io: &Links, ts1: i64, from: &MavHeader) {
        let Some(g) = self.cfg.gcs_timesync else {
            return;
        };
        let now = mono_ns();
        let reply = MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: (self.boot.boot_ns(now) as i64).saturating_add(g.offset_ns),
            ts1,
            target_system: from.system_id as u8,
            target_component: from.component_id,
        });
        let header = MavHeader {
            system_id: g.system_id.into(),
            component_id: g.component_id,
            sequence: self.gcs_timesync_seq,
        };
        self.gcs_timesync_seq = self.gcs_timesync_seq.wrapping_add(1);
        let version = if self.cfg.mavlink_version == 1 {
            MavlinkVersion::V1
        } else {
            MavlinkVersion::V2
        };
        let mut bytes = Vec::with_capacity(32);
        if mavlink::write_versioned_msg(&mut bytes, version, header, &reply).is_ok()
            && self.wire(io, bytes, now)
        {
            self.shared
                .stats
                .lock()
                .expect("stats lock")
                .gcs_timesync_replies += 1;
        }
    }

    fn command(&mut self, io: &Links, c: &COMMAND_LONG_DATA, now: u64) -> MavResult {
        let stream = |id: f32| STREAM_IDS.iter().position(|s| *s as f32 == id);
        match c.command {
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => {
                let Some(k) = stream(c.param1) else {
                    return MavResult::MAV_RESULT_UNSUPPORTED;
                };
                let boot_ms = self.boot.boot_ns(now) / 1_000_000;
                let p = if c.param2 < 0.0 {
                    0
                } else if c.param2 == 0.0 {
                    self.configured_periods()[k]
                } else {
                    ((c.param2 / 1000.0).round() as u64).max(1)
                };
                self.streams[k] = (p, boot_ms + 1);
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_REQUEST_MESSAGE => match stream(c.param1) {
                Some(_) => MavResult::MAV_RESULT_ACCEPTED,
                // HOME_POSITION and GPS_GLOBAL_ORIGIN: ArduPilot's answers; the generic profile
                // keeps what firmware-sim always did (unsupported).
                None if matches!(c.param1 as u32, 242 | 49)
                    && self.cfg.autopilot == Autopilot::ArduPilot =>
                {
                    MavResult::MAV_RESULT_ACCEPTED
                }
                None => MavResult::MAV_RESULT_UNSUPPORTED,
            },
            MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST => {
                let here = self.path_at(now);
                self.trigger.set(c.param1 as f64, here);
                if self.trigger.is_on()
                    && c.param3 == 1.0
                    && self.trigger.command_shoots_once()
                    && self.capture(io, now, "trigger")
                {
                    self.trigger.other_picture(here);
                }
                self.schedule_trigger(now);
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_DO_DIGICAM_CONTROL | MavCmd::MAV_CMD_IMAGE_START_CAPTURE
                if self.commands_refused < self.cfg.camera_refuse_first =>
            {
                self.commands_refused += 1;
                MavResult::MAV_RESULT_TEMPORARILY_REJECTED
            }
            MavCmd::MAV_CMD_DO_DIGICAM_CONTROL => {
                if c.param5 == 1.0 {
                    self.command_picture(io, now);
                }
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE => {
                self.command_picture(io, now);
                MavResult::MAV_RESULT_ACCEPTED
            }
            _ => MavResult::MAV_RESULT_UNSUPPORTED,
        }
    }
}
