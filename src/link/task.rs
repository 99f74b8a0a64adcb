//! The link task: connect (capped backoff between attempts), then one loop selecting on received
//! messages, commands, the heartbeat and TIMESYNC ticks, and shutdown. A reader task per
//! connection does the reads, each wrapped in a timeout; every send goes through `send_checked`,
//! the one place the allow-list is enforced. With signing configured, rust-mavlink signs every
//! frame sent and drops, silently, every frame received that fails the check. Frames are read
//! raw and decoded here, so the tap (`telemetry.tlog`) gets each one's bytes as received.

use super::clock::mono_ns;
use super::config::LinkConfig;
use super::state::{Reaction, Tracker};
use super::wire::{MemoryWire, Wire};
use super::{Command, LinkEvent, LinkHandle, LinkHealth, SendError, VehicleState};
use crate::core::allowlist;
use crate::core::backoff::reconnect_delay_ms;
use mavlink::dialects::ardupilotmega::*;
use mavlink::error::MessageReadError;
use mavlink::{
    AsyncMavConnection, MAVLinkMessageRaw, MavHeader, MavlinkVersion, Message, SigningConfig,
};
use std::future::Future;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio::time::{sleep_until, timeout, Instant};

type Conn = Arc<Wire>;

const OPEN_TIMEOUT: Duration = Duration::from_secs(2);
/// A lost connection is logged at most this often.
const CLOSED_SAID_EVERY: Duration = Duration::from_secs(10);
const WRITE_TIMEOUT: Duration = Duration::from_secs(1);
const PUBLISH_EVERY: Duration = Duration::from_millis(50);
const UNSYNCED_TIMESYNC_EVERY: Duration = Duration::from_millis(100);
const RATE_RETRIES: u32 = 10;
/// HOME_POSITION / GPS_GLOBAL_ORIGIN requests: every heartbeat tick (1 s) this many times, then
/// every 10th tick (an EKF may take minutes to get its origin).
const ORIGIN_FAST_TRIES: u32 = 30;

/// Why the link could not connect, as the operator was last told: a link that does not
/// come up (a wrong serial device, a port nobody serves) is reported once per reason, not
/// once per retry, until it connects.
#[derive(Debug, Default)]
struct Told(Option<String>);

impl Told {
    /// Whether `why` is news (and remembers it).
    fn news(&mut self, why: &str) -> bool {
        if self.0.as_deref() == Some(why) {
            return false;
        }
        self.0 = Some(why.to_string());
        true
    }
}

/// Failures that stop the link (everything else is retried).
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("mavlink.address `{address}`: {reason}")]
    Address { address: String, reason: String },
}

enum Rx {
    /// A CRC-valid frame (signature checked when signing): its bytes as received, and the
    /// message when this build can decode it.
    Frame {
        header: MavHeader,
        msg: Option<Box<MavMessage>>,
        bytes: Vec<u8>,
        mono_ns: u64,
    },
    Closed,
}

/// One received frame, byte for byte as it came (MAVLink 1 stays 1, signatures kept; frames
/// whose payload does not decode too), for `telemetry.tlog`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TapFrame {
    pub mono_ns: u64,
    pub bytes: Vec<u8>,
}

/// The link task, before it runs.
pub struct Link {
    cfg: LinkConfig,
    tracker: Tracker,
    state_tx: watch::Sender<Option<VehicleState>>,
    health_tx: watch::Sender<LinkHealth>,
    commands: mpsc::Receiver<Command>,
    events: mpsc::Sender<LinkEvent>,
    rate_tries: u32,
    tap: Option<mpsc::Sender<TapFrame>>,
    tap_dropped: u64,
    origin_tries: u32,
    /// In-memory streams to connect through instead of `cfg.address` ([`Link::set_memory_wire`]).
    memory: Option<mpsc::Receiver<tokio::io::DuplexStream>>,
}

/// Build the link: the task to run, the handle for the rest of the daemon, and its events.
pub fn new(cfg: LinkConfig) -> (Link, LinkHandle, mpsc::Receiver<LinkEvent>) {
    let (state_tx, state) = watch::channel(None);
    let (health_tx, health) = watch::channel(LinkHealth::default());
    // Commands from the rest of the daemon: when full, a sender waits (each is a request
    // that expects its answer; the coordinator never has more than a few in flight).
    let (cmd_tx, commands) = mpsc::channel(64);
    // Events for the coordinator: when full, the newest is dropped and counted
    // (`LinkHealth::events_dropped`); the link never waits on its consumer.
    let (events, events_rx) = mpsc::channel(256);
    let link = Link {
        tracker: Tracker::new(cfg.clone()),
        cfg,
        state_tx,
        health_tx,
        commands,
        events,
        rate_tries: 0,
        tap: None,
        tap_dropped: 0,
        origin_tries: 0,
        memory: None,
    };
    (
        link,
        LinkHandle {
            state,
            health,
            commands: cmd_tx,
        },
        events_rx,
    )
}

/// A raw frame's header, bytes, and message if it decodes. rust-mavlink's decoder only passes
/// frames whose id the dialect knows (it needs the id's CRC_EXTRA to check the CRC), so an id
/// outside ardupilotmega never gets here; a known id whose payload fails to decode does.
fn split_raw(raw: &MAVLinkMessageRaw) -> (MavHeader, Option<MavMessage>, Vec<u8>) {
    let header = MavHeader {
        system_id: raw.system_id(),
        component_id: raw.component_id(),
        sequence: raw.sequence(),
    };
    let bytes = match raw {
        MAVLinkMessageRaw::V1(f) => f.raw_bytes().to_vec(),
        MAVLinkMessageRaw::V2(f) => f.raw_bytes().to_vec(),
    };
    let msg = MavMessage::parse(raw.version(), raw.message_id(), raw.payload()).ok();
    (header, msg, bytes)
}

/// The device of a `serial:PATH:BAUD` address.
fn serial_path(address: &str) -> Option<std::path::PathBuf> {
    let rest = address.strip_prefix("serial:")?;
    let (path, _baud) = rest.rsplit_once(':')?;
    Some(path.into())
}

async fn read_loop(
    conn: Conn,
    tx: mpsc::Sender<Rx>,
    read_timeout: Duration,
    serial: Option<std::path::PathBuf>,
) {
    loop {
        let rx = match timeout(read_timeout, conn.recv_raw()).await {
            // rust-mavlink's raw read retries every serial error but end-of-file, so an
            // unplugged device (EIO) never ends it: a read that times out on a device that is
            // gone closes the connection (else silence_reconnect_ms would, later).
            Err(_) if serial.as_ref().is_some_and(|p| !p.exists()) => Rx::Closed,
            Err(_) => continue,
            Ok(Ok(raw)) => {
                let (header, msg, bytes) = split_raw(&raw);
                Rx::Frame {
                    header,
                    msg: msg.map(Box::new),
                    bytes,
                    mono_ns: mono_ns(),
                }
            }
            // Raw reads do not decode, so a parse error cannot come from them; anything
            // else is the transport.
            Ok(Err(MessageReadError::Parse(_))) => continue,
            Ok(Err(MessageReadError::Io(_))) => Rx::Closed,
        };
        let closed = matches!(rx, Rx::Closed);
        if tx.send(rx).await.is_err() || closed {
            return;
        }
    }
}

impl Link {
    /// Copy every received message to `tap` (never blocking the link: a full
    /// tap drops frames and counts them in `LinkHealth::events_dropped`).
    pub fn set_tap(&mut self, tap: mpsc::Sender<TapFrame>) {
        self.tap = Some(tap);
    }

    /// Connect through firmware-sim's in-memory streams (one per opening of its link)
    /// instead of `mavlink.address`: `alfd sim` on simulated time ([`super::wire`]).
    pub fn set_memory_wire(&mut self, streams: mpsc::Receiver<tokio::io::DuplexStream>) {
        self.memory = Some(streams);
    }

    /// The next connection: rust-mavlink's for the address, or the next in-memory stream;
    /// else why not.
    async fn connect(&mut self) -> Result<Wire, String> {
        let version = if self.cfg.mavlink_version == 1 {
            MavlinkVersion::V1
        } else {
            MavlinkVersion::V2
        };
        let no_answer = || format!("no connection within {} s", OPEN_TIMEOUT.as_secs());
        if let Some(streams) = self.memory.as_mut() {
            let s = timeout(OPEN_TIMEOUT, streams.recv())
                .await
                .map_err(|_| no_answer())?
                .ok_or("the simulator's wire is closed")?;
            return Ok(Wire::Memory(MemoryWire::new(s, version)));
        }
        let address = &self.cfg.address;
        let mut conn = timeout(OPEN_TIMEOUT, mavlink::connect_async::<MavMessage>(address))
            .await
            .map_err(|_| no_answer())?
            .map_err(|e| e.to_string())?;
        conn.set_allow_recv_any_version(true);
        conn.set_protocol_version(version);
        if let Some(s) = &self.cfg.signing {
            // Fresh per connection: replay state (last timestamp per stream) starts
            // over at each reconnection; see docs/link.md.
            conn.setup_signing(Some(SigningConfig::new(
                s.key,
                s.link_id,
                true,
                s.accept_unsigned,
            )));
        }
        Ok(Wire::Mav(conn))
    }

    /// Run until `shutdown` resolves.
    pub async fn run(mut self, shutdown: impl Future<Output = ()>) -> Result<(), LinkError> {
        let address_error = |reason: String| LinkError::Address {
            address: self.cfg.address.clone(),
            reason,
        };
        if self.memory.is_some() {
            if self.cfg.signing.is_some() {
                return Err(address_error(
                    "the simulator's in-memory wire does not sign; leave [mavlink.signing] out"
                        .into(),
                ));
            }
        } else if let Err(e) = mavlink::ConnectionAddress::parse_address(&self.cfg.address) {
            return Err(address_error(e.to_string()));
        }
        tokio::pin!(shutdown);
        let mut attempt = 0u32;
        let mut told = Told::default();
        let (mut closed_said, mut closes): (Option<Instant>, u64) = (None, 0);
        loop {
            let connected = tokio::select! {
                biased;
                _ = &mut shutdown => return Ok(()),
                c = self.connect() => c,
            };
            match connected {
                Ok(conn) => {
                    if attempt > 0 {
                        tracing::info!(
                            "MAVLink link on {} connected after {attempt} failed attempts",
                            self.cfg.address
                        );
                    }
                    attempt = 0;
                    told = Told::default();
                    self.tracker.health.connects += 1;
                    self.tracker.health.connected = true;
                    if self.serve_connection(Arc::new(conn), &mut shutdown).await {
                        return Ok(());
                    }
                    // A link that flaps (a peer that accepts and hangs up) is said
                    // at most every CLOSED_SAID_EVERY, with the closes in between.
                    closes += 1;
                    let now = Instant::now();
                    if closed_said.is_none_or(|t| now >= t + CLOSED_SAID_EVERY) {
                        let times = match closes {
                            1 => String::new(),
                            n => format!(" {n} times since the last warning"),
                        };
                        tracing::warn!(
                            "MAVLink link on {} closed{times}; reconnecting",
                            self.cfg.address
                        );
                        (closed_said, closes) = (Some(now), 0);
                    }
                    self.tracker.health.connected = false;
                    self.publish_health();
                }
                Err(why) => {
                    if told.news(&why) {
                        tracing::warn!(
                            "MAVLink link on {}: cannot connect: {why}; retrying every {} ms at most",
                            self.cfg.address,
                            self.cfg.reconnect_max.as_millis()
                        );
                    }
                    self.tracker.health.connect_failures += 1;
                    let initial = self.cfg.reconnect_initial.as_millis() as u64;
                    let max = self.cfg.reconnect_max.as_millis() as u64;
                    let wait = reconnect_delay_ms(attempt, initial, max);
                    attempt = attempt.saturating_add(1);
                    self.tracker.health.last_backoff_ms = wait;
                    self.publish_health();
                    if self
                        .idle_until(Instant::now() + Duration::from_millis(wait), &mut shutdown)
                        .await
                    {
                        return Ok(());
                    }
                }
            }
        }
    }

    /// Serve commands (without a connection) until `deadline`; true if shut down.
    async fn idle_until<F: Future<Output = ()>>(
        &mut self,
        deadline: Instant,
        shutdown: &mut std::pin::Pin<&mut F>,
    ) -> bool {
        loop {
            tokio::select! {
                biased;
                _ = sleep_until(deadline) => return false,
                _ = shutdown.as_mut() => return true,
                Some(c) = self.commands.recv() => self.serve(c, None).await,
            }
        }
    }

    /// One connection's life; true if shut down, false if the connection was lost.
    async fn serve_connection<F: Future<Output = ()>>(
        &mut self,
        conn: Conn,
        shutdown: &mut std::pin::Pin<&mut F>,
    ) -> bool {
        // Decoded frames from the connection's reader: when full, the reader waits, and the
        // transport's own buffer (the serial driver's, the socket's) absorbs the burst.
        let (rx_tx, mut rx) = mpsc::channel(256);
        let reader = tokio::spawn(read_loop(
            conn.clone(),
            rx_tx,
            self.cfg.read_timeout,
            serial_path(&self.cfg.address),
        ));
        let _abort = AbortOnDrop(reader);
        self.publish_health();
        self.heartbeat(&conn).await;
        if self.tracker.autopilot.is_some() {
            self.request_rates(&conn).await;
        }
        let connected_at = mono_ns();
        let mut heartbeat = tokio::time::interval(Duration::from_secs(1));
        heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut publish = tokio::time::interval(PUBLISH_EVERY);
        let mut next_sync = Instant::now();
        loop {
            tokio::select! {
                biased;
                _ = shutdown.as_mut() => {
                    self.publish_health();
                    return true;
                }
                r = rx.recv() => match r {
                    Some(Rx::Frame { header, msg, bytes, mono_ns }) => {
                        self.tap_frame(bytes, mono_ns);
                        match msg {
                            Some(m) => self.on_message(&conn, &header, &m, mono_ns).await,
                            None => self.tracker.health.parse_errors += 1,
                        }
                    }
                    Some(Rx::Closed) | None => return false,
                },
                Some(c) = self.commands.recv() => self.serve(c, Some(&conn)).await,
                _ = heartbeat.tick() => {
                    self.heartbeat(&conn).await;
                    self.request_origin(&conn).await;
                    if !self.tracker.pending_rates.is_empty() && self.rate_tries < RATE_RETRIES {
                        self.rate_tries += 1;
                        self.send_rate_requests(&conn).await;
                    }
                }
                _ = sleep_until(next_sync) => {
                    let msg = self.tracker.timesync_request(mono_ns());
                    let _ = self.send_checked(Some(&conn), &msg).await;
                    let every = if self.tracker.sync.is_synced() {
                        Duration::from_secs_f64(1.0 / self.cfg.timesync_hz)
                    } else {
                        UNSYNCED_TIMESYNC_EVERY
                    };
                    next_sync = Instant::now() + every;
                }
                _ = publish.tick() => {
                    self.publish_health();
                    let last = self.tracker.health.last_rx_mono_ns.max(connected_at);
                    if mono_ns().saturating_sub(last) > self.cfg.silence_reconnect.as_nanos() as u64 {
                        return false;
                    }
                }
            }
        }
    }

    /// Copy a received frame to the tap, never waiting (a full tap drops and counts it).
    fn tap_frame(&mut self, bytes: Vec<u8>, mono_ns: u64) {
        if let Some(tap) = &self.tap {
            if tap.try_send(TapFrame { mono_ns, bytes }).is_err() {
                self.tap_dropped += 1;
                self.tracker.health.events_dropped += 1;
            }
        }
    }

    /// Ask the autopilot for its home and EKF origin until one of them has anchored the local
    /// frame: ArduPilot answers MAV_CMD_REQUEST_MESSAGE for them only once it has them.
    async fn request_origin(&mut self, conn: &Conn) {
        if self.tracker.autopilot.is_none() || !self.tracker.wants_origin() {
            return;
        }
        self.origin_tries = self.origin_tries.saturating_add(1);
        if self.origin_tries > ORIGIN_FAST_TRIES && self.origin_tries % 10 != 0 {
            return;
        }
        for msg in self.tracker.origin_requests() {
            let _ = self.send_checked(Some(conn), &msg).await;
        }
    }

    async fn on_message(&mut self, conn: &Conn, h: &MavHeader, m: &MavMessage, rx_ns: u64) {
        let mut publish = false;
        for r in self.tracker.on_message(h, m, rx_ns) {
            match r {
                Reaction::Reply(msg) => {
                    let _ = self.send_checked(Some(conn), &msg).await;
                }
                Reaction::Event(e) => {
                    publish = true;
                    if self.events.try_send(e).is_err() {
                        self.tracker.health.events_dropped += 1;
                    }
                }
                Reaction::RequestRates => {
                    self.request_rates(conn).await;
                    self.origin_tries = 0;
                    self.request_origin(conn).await;
                }
                Reaction::StateChanged => {
                    self.state_tx.send_replace(self.tracker.state.clone());
                }
            }
        }
        if publish {
            self.publish_health();
        }
    }

    async fn serve(&mut self, c: Command, conn: Option<&Conn>) {
        match c {
            Command::Send(msg, reply) => {
                let r = self.send_checked(conn, &msg).await;
                let _ = reply.send(r);
            }
            Command::PoseAt(t, reply) => {
                let _ = reply.send(self.tracker.pose_at(t));
            }
            Command::BootNsAt(t, reply) => {
                let _ = reply.send(self.tracker.sync.local_to_remote(t));
            }
        }
    }

    fn publish_health(&self) {
        let h = &self.tracker.health;
        self.health_tx.send_if_modified(|cur| {
            if cur != h {
                *cur = h.clone();
                true
            } else {
                false
            }
        });
    }

    async fn heartbeat(&mut self, conn: &Conn) {
        let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_CAMERA,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        });
        let _ = self.send_checked(Some(conn), &hb).await;
    }

    async fn request_rates(&mut self, conn: &Conn) {
        // LOCAL_POSITION_NED at the position rate: the finer position where the autopilot
        // has it (an autopilot that refuses it leaves the global stream to serve).
        self.tracker.pending_rates = [33, 32, 31].into();
        self.tracker.health.rates_acked = false;
        self.rate_tries = 0;
        self.send_rate_requests(conn).await;
    }

    async fn send_rate_requests(&mut self, conn: &Conn) {
        let (target_system, target_component) = self.tracker.autopilot.unwrap_or((0, 0));
        let pending: Vec<u32> = self.tracker.pending_rates.iter().copied().collect();
        for id in pending {
            let hz = if id == 33 || id == 32 {
                self.cfg.position_hz
            } else {
                self.cfg.attitude_hz
            };
            let msg = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                param1: id as f32,
                param2: (1e6 / hz) as f32,
                target_system,
                target_component,
                ..Default::default()
            });
            let _ = self.send_checked(Some(conn), &msg).await;
        }
    }

    /// The only way out: allow-list, then protocol version, then the wire.
    async fn send_checked(
        &mut self,
        conn: Option<&Conn>,
        msg: &MavMessage,
    ) -> Result<(), SendError> {
        let id = msg.message_id();
        let command = match msg {
            MavMessage::COMMAND_LONG(c) => Some(c.command as u32),
            _ => None,
        };
        if let Err(r) = allowlist::may_send(id, command) {
            self.tracker.health.refused += 1;
            return Err(SendError::NotAllowed(r));
        }
        if self.cfg.mavlink_version == 1 && id > 255 {
            return Err(SendError::NotInV1(id));
        }
        let conn = conn.ok_or(SendError::NotConnected)?;
        let header = MavHeader {
            system_id: self.cfg.system_id.into(),
            component_id: self.cfg.component_id,
            sequence: 0,
        };
        match timeout(WRITE_TIMEOUT, conn.send(&header, msg)).await {
            Ok(Ok(_)) => {
                self.tracker.health.sent += 1;
                Ok(())
            }
            Ok(Err(e)) => Err(SendError::Write(e.to_string())),
            Err(_) => Err(SendError::Write("timed out".into())),
        }
    }
}

struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reason_is_told_once_until_it_changes_or_the_link_connects() {
        let mut told = Told::default();
        assert!(told.news("No such file or directory"));
        assert!(!told.news("No such file or directory"));
        assert!(told.news("Permission denied"));
        assert!(!told.news("Permission denied"));
        assert!(told.news("No such file or directory"));
        // After a connection the next failure is news again.
        told = Told::default();
        assert!(told.news("No such file or directory"));
    }
}
