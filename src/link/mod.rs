//! alfd's MAVLink link: one task owns the connection to the flight controller. It announces a
//! camera component, requests telemetry rates, keeps time in sync and a pose buffer, reconnects
//! with capped backoff, and sends only what the allow-list permits. Others talk to it through a
//! `LinkHandle`: `watch` channels for the latest state and health, commands with replies.

pub mod clock;
pub mod config;
mod state;
mod task;
mod wire;

pub use clock::{mono_ns, simulate_on_this_thread, simulated, unix_us_at, SimulatedTime};
pub use config::{LinkConfig, LinkConfigError, RawLinkConfig};
pub use state::{Airborne, AnchorSource, PoseQueryError, Reaction, Tracker};
pub use task::{new, Link, LinkError, TapFrame};

use crate::core::allowlist::Trust;
use crate::core::geo::Geodetic;
use crate::core::pose::Pose;
use mavlink::dialects::ardupilotmega::MavMessage;
use tokio::sync::{mpsc, oneshot, watch};

/// The latest vehicle state, from the newest accepted position and attitude.
#[derive(Clone, Debug, PartialEq)]
pub struct VehicleState {
    pub time_boot_ms: u32,
    /// The sample's instant on the companion's monotonic clock, once time is in sync.
    pub mono_ns: Option<u64>,
    pub position: Geodetic,
    /// Local NED around `home`.
    pub pos_ned_m: [f64; 3],
    pub vel_ned_mps: [f64; 3],
    /// The local frame's anchor: the autopilot's EKF origin or home, else the first position
    /// with a 3-D fix (`origin_source` says which). It moves only when the autopilot's does.
    pub home: Geodetic,
    pub origin_source: AnchorSource,
    /// Height above the autopilot's home (GLOBAL_POSITION_INT.relative_alt), m.
    pub rel_alt_m: f64,
    /// Whether captures may be taken, and if not, why ([`Airborne`]).
    pub airborne: Airborne,
    /// Body to NED (w, x, y, z).
    pub q: [f64; 4],
    pub rpy_deg: [f64; 3],
    pub gps_fix: u8,
    pub armed: bool,
}

/// How the link is doing: counters only grow; flags say what holds now.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LinkHealth {
    pub connected: bool,
    /// Successful connections (the first one included).
    pub connects: u32,
    /// Connection attempts that failed, and the last backoff waited (ms).
    pub connect_failures: u32,
    pub last_backoff_ms: u64,
    pub messages_rx: u64,
    pub parse_errors: u64,
    /// Frames missing by sequence number (dropped or failing CRC).
    pub seq_gaps: u64,
    /// Messages from systems not in `accept_system_ids`, other than commands addressed to us.
    pub foreign_ignored: u64,
    /// COMMAND_LONGs addressed to us from systems not in `accept_system_ids`.
    pub foreign_commands: u64,
    pub autopilot_heartbeats: u64,
    pub last_rx_mono_ns: u64,
    pub last_position_rx_mono_ns: u64,
    pub positions_accepted: u64,
    /// Of those, positions from LOCAL_POSITION_NED carried into the link's frame (finer than
    /// GLOBAL_POSITION_INT's 1e-7°; the global stream serves when none comes).
    pub local_positions: u64,
    /// LOCAL_POSITION_NED samples dropped for disagreeing with the accepted global track.
    pub local_disagreements: u64,
    /// Times the offset to the autopilot's local frame restarted after a jump.
    pub local_offset_restarts: u64,
    pub rejected_time: u64,
    pub rejected_position: u64,
    /// Positions not newer than the newest kept (never expected on an ordered link).
    pub out_of_order: u64,
    pub rejected_attitude: u64,
    pub synced: bool,
    pub synced_at_mono_ns: u64,
    pub offset_ns: i64,
    pub drift_ppm: f64,
    pub rtt_min_ns: u64,
    pub timesync_resets: u32,
    pub timesync_outliers: u64,
    pub timesync_discarded: u64,
    /// TIMESYNC replies not from the autopilot the link follows, or addressed to someone else:
    /// not used (a ground station may answer the requests the autopilot forwards).
    pub timesync_foreign: u64,
    pub reboots: u32,
    pub glitch_active: bool,
    pub glitches: u64,
    pub glitch_rejected: u64,
    pub reanchors: u32,
    /// Times the local frame was anchored on the autopilot's origin or home, or re-anchored
    /// when it moved (never on a glitch).
    pub origin_anchors: u32,
    /// Positions not used for want of a valid origin (no 3-D fix, or lat = lon = 0).
    pub positions_without_origin: u64,
    /// MAV_CMD_REQUEST_MESSAGE sent for HOME_POSITION and GPS_GLOBAL_ORIGIN.
    pub origin_requests: u32,
    /// CAMERA_FEEDBACK messages from the autopilot (ArduPilot's per-photo report).
    pub camera_feedbacks: u64,
    pub rates_acked: bool,
    pub sent: u64,
    pub refused: u64,
    /// Events dropped because the coordinator's queue was full (newest dropped).
    pub events_dropped: u64,
}

/// Things the rest of the daemon may want to act on.
#[derive(Clone, Debug, PartialEq)]
pub enum LinkEvent {
    Synced,
    /// The autopilot's first HEARTBEAT: its firmware, which decides how it counts a
    /// distance trigger (`core::distset::Counting`).
    AutopilotFound {
        firmware: mavlink::dialects::ardupilotmega::MavAutopilot,
    },
    AutopilotRebooted,
    GpsGlitch {
        jump_m: f64,
    },
    GpsReanchored {
        jump_m: f64,
    },
    /// The local frame was anchored (`moved_m`: `None`) or moved with the autopilot's origin;
    /// poses already kept were re-expressed in the new frame, so nothing was suspended.
    OriginSet {
        source: AnchorSource,
        home: Geodetic,
        moved_m: Option<f64>,
    },
    /// ArduPilot's CAMERA_FEEDBACK: a photo its camera backend took (`time_usec` is GPS time,
    /// UNIX epoch µs, not boot time; `img_idx` counts from 1).
    CameraFeedback {
        img_idx: u16,
        gps_time_usec: u64,
        /// The picture's instant on this machine's monotonic clock, from its GPS time stamp
        /// through the autopilot's SYSTEM_TIME and TIMESYNC; `None` when they cannot say.
        mono_ns: Option<u64>,
        /// When the feedback was received (monotonic): a link latency after the picture.
        received_mono_ns: u64,
        lat_deg: f64,
        lon_deg: f64,
        alt_msl_m: f32,
        alt_rel_m: f32,
    },
    /// The autopilot's own camera trigger fired.
    CameraTrigger {
        seq: u32,
        time_boot_us: u64,
        /// The same instant on this machine's monotonic clock, when time is in sync.
        mono_ns: Option<u64>,
    },
    /// The autopilot answered one of our camera commands.
    CommandAck {
        command: u32,
        /// MAV_RESULT (0 = accepted).
        result: u8,
    },
    /// A COMMAND_LONG addressed to us, from any system: `trust` says whether its sender is in
    /// `accept_system_ids` (a foreign one may only read, `core::allowlist::may_obey`).
    Command {
        system_id: u8,
        component_id: u8,
        command: u32,
        params: [f32; 7],
        trust: Trust,
    },
}

/// Why a message was not sent.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SendError {
    #[error("not on the send allow-list: {0:?}")]
    NotAllowed(crate::core::allowlist::Refusal),
    #[error("message id {0} cannot be sent over MAVLink 1")]
    NotInV1(u32),
    #[error("not connected")]
    NotConnected,
    #[error("write failed: {0}")]
    Write(String),
    #[error("the link task has stopped")]
    Stopped,
}

pub(crate) enum Command {
    Send(Box<MavMessage>, oneshot::Sender<Result<(), SendError>>),
    PoseAt(u64, oneshot::Sender<Result<Pose, PoseQueryError>>),
    BootNsAt(u64, oneshot::Sender<Option<u64>>),
}

/// What the rest of the daemon holds to use the link. Cheap to clone.
#[derive(Clone)]
pub struct LinkHandle {
    state: watch::Receiver<Option<VehicleState>>,
    health: watch::Receiver<LinkHealth>,
    commands: mpsc::Sender<Command>,
}

impl LinkHandle {
    pub fn state(&self) -> watch::Receiver<Option<VehicleState>> {
        self.state.clone()
    }

    pub fn health(&self) -> watch::Receiver<LinkHealth> {
        self.health.clone()
    }

    /// Send a message (checked against the allow-list first, then the protocol version).
    pub async fn send(&self, msg: MavMessage) -> Result<(), SendError> {
        let (tx, rx) = oneshot::channel();
        self.commands
            .send(Command::Send(Box::new(msg), tx))
            .await
            .map_err(|_| SendError::Stopped)?;
        rx.await.map_err(|_| SendError::Stopped)?
    }

    /// The pose at an instant of this machine's CLOCK_MONOTONIC (e.g. a frame's timestamp).
    pub async fn pose_at_mono_ns(&self, mono_ns: u64) -> Result<Pose, PoseQueryError> {
        let (tx, rx) = oneshot::channel();
        if self
            .commands
            .send(Command::PoseAt(mono_ns, tx))
            .await
            .is_err()
        {
            return Err(PoseQueryError::NotSynced);
        }
        rx.await.unwrap_or(Err(PoseQueryError::NotSynced))
    }

    /// [`Self::pose_at_mono_ns`] from a thread that blocks (a synthetic source's, which
    /// renders at the telemetry's pose): it parks the thread until the link answers. Not
    /// on simulated time, where every loop is a task of the one runtime thread and the
    /// link could never answer (`alfd sim` refuses that combination).
    pub fn pose_at_mono_ns_blocking(&self, mono_ns: u64) -> Result<Pose, PoseQueryError> {
        park_on(self.pose_at_mono_ns(mono_ns))
    }

    /// The autopilot's boot time (ns) at a monotonic instant, by the current TIMESYNC estimate.
    pub async fn boot_ns_at_mono_ns(&self, mono_ns: u64) -> Option<u64> {
        let (tx, rx) = oneshot::channel();
        self.commands
            .send(Command::BootNsAt(mono_ns, tx))
            .await
            .ok()?;
        rx.await.ok().flatten()
    }
}

/// Polls `fut` to its end on this thread, parking it between wake-ups. tokio's `block_on`
/// refuses to run inside another (a source is called from its loop's future); the link's
/// channels need no runtime to be waited on.
fn park_on<F: std::future::Future>(fut: F) -> F::Output {
    struct Unpark(std::thread::Thread);
    impl std::task::Wake for Unpark {
        fn wake(self: std::sync::Arc<Self>) {
            self.0.unpark();
        }
    }
    let waker = std::task::Waker::from(std::sync::Arc::new(Unpark(std::thread::current())));
    let mut cx = std::task::Context::from_waker(&waker);
    let mut fut = std::pin::pin!(fut);
    loop {
        if let std::task::Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
            return v;
        }
        std::thread::park();
    }
}
