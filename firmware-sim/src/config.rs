//! The simulator's TOML config: parsed into raw structs (unknown keys refused), then checked into
//! a `SimConfig` whose errors name the field.

use serde::Deserialize;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{0}")]
    Parse(String),
    #[error("{field}: {problem}")]
    Invalid {
        field: &'static str,
        problem: String,
    },
    #[error("{path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
}

fn bad(field: &'static str, problem: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        field,
        problem: problem.into(),
    }
}

/// Where the simulated autopilot listens.
#[derive(Clone, Debug, PartialEq)]
pub enum Transport {
    /// A pseudo-terminal it creates; its slave path is kept behind the stable symlink `link`
    /// (a fresh temporary path when `None`).
    Pty { link: Option<PathBuf> },
    /// A real serial device.
    Serial { path: PathBuf, baud: u32 },
    /// UDP on `bind` (port 0: the system picks); replies go to the last peer heard.
    Udp { bind: String },
    /// TCP listening on `bind` (port 0: the system picks), one client at a time.
    Tcp { bind: String },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pattern {
    Line,
    Lawnmower,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Survey {
    pub pattern: Pattern,
    pub origin_lat_deg: f64,
    pub origin_lon_deg: f64,
    pub origin_alt_m: f64,
    pub altitude_m: f64,
    pub heading_deg: f64,
    pub length_m: f64,
    pub lane_spacing_m: f64,
    pub lanes: u32,
    pub speed_mps: f64,
    pub accel_mps2: f64,
    /// Amplitude of the smooth wind-like wander of the position (m) and attitude (deg).
    pub wind_m: f64,
    pub wind_deg: f64,
}

/// Stream rates in Hz (0 = off).
#[derive(Clone, Debug, PartialEq)]
pub struct Streams {
    pub heartbeat: f64,
    pub sys_status: f64,
    pub attitude: f64,
    pub attitude_quaternion: f64,
    pub global_position_int: f64,
    pub local_position_ned: f64,
    pub gps_raw_int: f64,
    pub system_time: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    LinkLoss,
    Reboot,
    GpsGlitch,
    Silence,
}

#[derive(Clone, Debug, PartialEq)]
pub struct FaultEvent {
    pub at: Duration,
    pub kind: FaultKind,
    pub duration: Duration,
    pub offset_m: [f64; 3],
}

#[derive(Clone, Debug, PartialEq)]
pub struct Faults {
    pub seed: u64,
    pub corrupt_byte_rate: f64,
    pub drop_rate: f64,
    /// One-way, on what the simulator sends (a two-way sync cannot see asymmetric delay).
    pub latency: Duration,
    pub jitter: Duration,
    pub events: Vec<FaultEvent>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    pub transport: Transport,
    pub mavlink_version: u8,
    pub system_id: u8,
    pub component_id: u8,
    /// A ground station to forward to, `udpout:HOST:PORT` (the station listens): it gets the
    /// simulator's own messages and everything heard on the main transport, and what it sends
    /// is forwarded to the main transport. No faults on this side.
    pub gcs: Option<String>,
    pub survey: Survey,
    pub streams: Streams,
    /// How much faster the autopilot's boot clock runs than this machine's monotonic clock.
    pub clock_drift_ppm: f64,
    pub truth_path: Option<PathBuf>,
    pub truth_every_step: bool,
    pub faults: Faults,
    /// A ground station behind the autopilot that answers TIMESYNC requests heard on the main
    /// transport, as ArduPilot's ground stations do with the requests it forwards to them.
    pub gcs_timesync: Option<GcsTimesync>,
}

/// A ground station answering TIMESYNC requests with its own clock: each request heard on the
/// main transport gets its reply first, then the autopilot's. Its clock reads the autopilot's
/// boot clock plus `offset_ns`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GcsTimesync {
    pub system_id: u8,
    pub component_id: u8,
    pub offset_ns: i64,
}

impl GcsTimesync {
    /// A ground station with the usual ids (system 255, component 190), its clock `offset_ms`
    /// off the autopilot's.
    pub fn qgc(offset_ms: f64) -> Result<Self, String> {
        if !(offset_ms.is_finite() && offset_ms.abs() <= 1e9) {
            return Err(format!(
                "must be a number of ms within ±1e9, got {offset_ms}"
            ));
        }
        Ok(GcsTimesync {
            system_id: 255,
            component_id: 190,
            offset_ns: (offset_ms * 1e6).round() as i64,
        })
    }
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct Raw {
    #[serde(default)]
    link: RawLink,
    #[serde(default)]
    survey: RawSurvey,
    #[serde(default)]
    streams: RawStreams,
    #[serde(default)]
    clock: RawClock,
    #[serde(default)]
    truth: RawTruth,
    #[serde(default)]
    faults: RawFaults,
    gcs_timesync: Option<RawGcsTimesync>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawGcsTimesync {
    system_id: u8,
    component_id: u8,
    offset_ms: f64,
}

impl Default for RawGcsTimesync {
    fn default() -> Self {
        Self {
            system_id: 255,
            component_id: 190,
            offset_ms: 5000.0,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawLink {
    transport: String,
    path: Option<PathBuf>,
    baud: u32,
    bind: String,
    mavlink_version: u8,
    system_id: u8,
    component_id: u8,
    gcs: Option<String>,
}

impl Default for RawLink {
    fn default() -> Self {
        Self {
            transport: "pty".into(),
            path: None,
            baud: 921_600,
            bind: "127.0.0.1:0".into(),
            mavlink_version: 2,
            system_id: 1,
            component_id: 1,
            gcs: None,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawSurvey {
    pattern: String,
    origin_lat_deg: f64,
    origin_lon_deg: f64,
    origin_alt_m: f64,
    altitude_m: f64,
    heading_deg: f64,
    length_m: f64,
    lane_spacing_m: f64,
    lanes: u32,
    speed_mps: f64,
    accel_mps2: f64,
    wind_m: f64,
    wind_deg: f64,
}

impl Default for RawSurvey {
    fn default() -> Self {
        Self {
            pattern: "lawnmower".into(),
            origin_lat_deg: 47.397_742,
            origin_lon_deg: 8.545_594,
            origin_alt_m: 488.0,
            altitude_m: 40.0,
            heading_deg: 30.0,
            length_m: 400.0,
            lane_spacing_m: 30.0,
            lanes: 4,
            speed_mps: 10.0,
            accel_mps2: 2.5,
            wind_m: 0.3,
            wind_deg: 2.0,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawStreams {
    heartbeat_hz: f64,
    sys_status_hz: f64,
    attitude_hz: f64,
    attitude_quaternion_hz: f64,
    global_position_int_hz: f64,
    local_position_ned_hz: f64,
    gps_raw_int_hz: f64,
    system_time_hz: f64,
}

impl Default for RawStreams {
    fn default() -> Self {
        Self {
            heartbeat_hz: 1.0,
            sys_status_hz: 1.0,
            attitude_hz: 0.0,
            attitude_quaternion_hz: 10.0,
            global_position_int_hz: 10.0,
            local_position_ned_hz: 5.0,
            gps_raw_int_hz: 5.0,
            system_time_hz: 1.0,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawClock {
    drift_ppm: f64,
}

impl Default for RawClock {
    fn default() -> Self {
        Self { drift_ppm: 20.0 }
    }
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawTruth {
    path: Option<PathBuf>,
    every_step: bool,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawFaults {
    seed: u64,
    corrupt_byte_rate: f64,
    drop_rate: f64,
    latency_ms: f64,
    jitter_ms: f64,
    events: Vec<RawEvent>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEvent {
    at_s: f64,
    kind: String,
    #[serde(default)]
    duration_s: f64,
    #[serde(default)]
    offset_m: Option<[f64; 3]>,
}

fn secs(field: &'static str, v: f64) -> Result<Duration, ConfigError> {
    if !(v.is_finite() && (0.0..=1e6).contains(&v)) {
        return Err(bad(
            field,
            format!("must be between 0 and 1e6 seconds, got {v}"),
        ));
    }
    Ok(Duration::from_secs_f64(v))
}

fn positive(field: &'static str, v: f64) -> Result<f64, ConfigError> {
    if !(v.is_finite() && v > 0.0) {
        return Err(bad(field, format!("must be a positive number, got {v}")));
    }
    Ok(v)
}

fn non_negative(field: &'static str, v: f64) -> Result<f64, ConfigError> {
    if !(v.is_finite() && v >= 0.0) {
        return Err(bad(field, format!("must be zero or more, got {v}")));
    }
    Ok(v)
}

fn rate(field: &'static str, v: f64) -> Result<f64, ConfigError> {
    if !(v.is_finite() && (0.0..=1000.0).contains(&v)) {
        return Err(bad(field, format!("must be between 0 and 1000 Hz (periods are whole milliseconds of boot time), got {v}")));
    }
    Ok(v)
}

fn probability(field: &'static str, v: f64) -> Result<f64, ConfigError> {
    if !(0.0..=1.0).contains(&v) {
        return Err(bad(
            field,
            format!("must be a probability in [0, 1], got {v}"),
        ));
    }
    Ok(v)
}

/// Check a ground-station address: `udpout:HOST:PORT` with a numeric port.
pub fn check_gcs_address(address: &str) -> Result<(), String> {
    let bad = || format!("`{address}`: expected udpout:HOST:PORT, e.g. udpout:127.0.0.1:14550");
    let rest = address.strip_prefix("udpout:").ok_or_else(bad)?;
    let (host, port) = rest.rsplit_once(':').ok_or_else(bad)?;
    // Port 0 cannot be sent to: the station binds first and passes its real port.
    if host.is_empty() || !matches!(port.parse::<u16>(), Ok(p) if p > 0) {
        return Err(bad());
    }
    Ok(())
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig::from_toml("").expect("the defaults are valid")
    }
}

impl SimConfig {
    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let raw: Raw = toml::from_str(text).map_err(|e| ConfigError::Parse(e.to_string()))?;
        Self::validate(raw)
    }

    pub fn from_file(path: &std::path::Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.into(),
            source,
        })?;
        Self::from_toml(&text).map_err(|e| match e {
            ConfigError::Parse(m) => ConfigError::Parse(format!("{}: {m}", path.display())),
            other => other,
        })
    }

    fn validate(raw: Raw) -> Result<Self, ConfigError> {
        let l = raw.link;
        let transport = match l.transport.as_str() {
            "pty" => Transport::Pty { link: l.path },
            "serial" => Transport::Serial {
                path: l
                    .path
                    .ok_or_else(|| bad("link.path", "required when link.transport = \"serial\""))?,
                baud: l.baud,
            },
            "udp" => Transport::Udp { bind: l.bind },
            "tcp" => Transport::Tcp { bind: l.bind },
            other => {
                return Err(bad(
                    "link.transport",
                    format!("`{other}`: expected pty, serial, udp or tcp"),
                ))
            }
        };
        if !matches!(l.mavlink_version, 1 | 2) {
            return Err(bad(
                "link.mavlink_version",
                format!("{}: expected 1 or 2", l.mavlink_version),
            ));
        }
        if let Some(g) = &l.gcs {
            check_gcs_address(g).map_err(|e| bad("link.gcs", e))?;
        }
        if l.system_id == 0 {
            return Err(bad("link.system_id", "0 is the broadcast id"));
        }
        let s = raw.survey;
        let pattern = match s.pattern.as_str() {
            "line" => Pattern::Line,
            "lawnmower" => Pattern::Lawnmower,
            other => {
                return Err(bad(
                    "survey.pattern",
                    format!("`{other}`: expected line or lawnmower"),
                ))
            }
        };
        if !(-85.0..=85.0).contains(&s.origin_lat_deg) {
            return Err(bad("survey.origin_lat_deg", "must be within ±85°"));
        }
        if !(-180.0..=180.0).contains(&s.origin_lon_deg) {
            return Err(bad("survey.origin_lon_deg", "must be within ±180°"));
        }
        if pattern == Pattern::Lawnmower && s.lanes < 2 {
            return Err(bad("survey.lanes", "a lawnmower needs at least 2 lanes"));
        }
        let survey = Survey {
            pattern,
            origin_lat_deg: s.origin_lat_deg,
            origin_lon_deg: s.origin_lon_deg,
            origin_alt_m: s.origin_alt_m,
            altitude_m: non_negative("survey.altitude_m", s.altitude_m)?,
            heading_deg: s.heading_deg,
            length_m: positive("survey.length_m", s.length_m)?,
            lane_spacing_m: if pattern == Pattern::Lawnmower {
                positive("survey.lane_spacing_m", s.lane_spacing_m)?
            } else {
                0.0
            },
            lanes: s.lanes,
            speed_mps: positive("survey.speed_mps", s.speed_mps)?,
            accel_mps2: positive("survey.accel_mps2", s.accel_mps2)?,
            wind_m: non_negative("survey.wind_m", s.wind_m)?,
            wind_deg: non_negative("survey.wind_deg", s.wind_deg)?,
        };
        let r = raw.streams;
        let streams = Streams {
            heartbeat: rate("streams.heartbeat_hz", r.heartbeat_hz)?,
            sys_status: rate("streams.sys_status_hz", r.sys_status_hz)?,
            attitude: rate("streams.attitude_hz", r.attitude_hz)?,
            attitude_quaternion: rate("streams.attitude_quaternion_hz", r.attitude_quaternion_hz)?,
            global_position_int: rate("streams.global_position_int_hz", r.global_position_int_hz)?,
            local_position_ned: rate("streams.local_position_ned_hz", r.local_position_ned_hz)?,
            gps_raw_int: rate("streams.gps_raw_int_hz", r.gps_raw_int_hz)?,
            system_time: rate("streams.system_time_hz", r.system_time_hz)?,
        };
        if !(raw.clock.drift_ppm.is_finite() && raw.clock.drift_ppm.abs() <= 1000.0) {
            return Err(bad("clock.drift_ppm", "must be within ±1000 ppm"));
        }
        let f = raw.faults;
        let mut events = Vec::new();
        for e in f.events {
            let kind = match e.kind.as_str() {
                "link_loss" => FaultKind::LinkLoss,
                "reboot" => FaultKind::Reboot,
                "gps_glitch" => FaultKind::GpsGlitch,
                "silence" => FaultKind::Silence,
                other => {
                    return Err(bad(
                        "faults.events.kind",
                        format!("`{other}`: expected link_loss, reboot, gps_glitch or silence"),
                    ))
                }
            };
            events.push(FaultEvent {
                at: secs("faults.events.at_s", e.at_s)?,
                kind,
                duration: secs("faults.events.duration_s", e.duration_s)?,
                offset_m: e.offset_m.unwrap_or([30.0, 0.0, 0.0]),
            });
        }
        let faults = Faults {
            seed: f.seed,
            corrupt_byte_rate: probability("faults.corrupt_byte_rate", f.corrupt_byte_rate)?,
            drop_rate: probability("faults.drop_rate", f.drop_rate)?,
            latency: secs("faults.latency_ms", f.latency_ms / 1e3)?,
            jitter: secs("faults.jitter_ms", f.jitter_ms / 1e3)?,
            events,
        };
        let gcs_timesync = match raw.gcs_timesync {
            None => None,
            Some(g) => {
                if g.system_id == 0 || g.system_id == l.system_id {
                    return Err(bad(
                        "gcs_timesync.system_id",
                        format!(
                            "{}: must be non-zero and not the autopilot's ({})",
                            g.system_id, l.system_id
                        ),
                    ));
                }
                let qgc =
                    GcsTimesync::qgc(g.offset_ms).map_err(|e| bad("gcs_timesync.offset_ms", e))?;
                Some(GcsTimesync {
                    system_id: g.system_id,
                    component_id: g.component_id,
                    ..qgc
                })
            }
        };
        Ok(SimConfig {
            gcs_timesync,
            transport,
            mavlink_version: l.mavlink_version,
            system_id: l.system_id,
            component_id: l.component_id,
            gcs: l.gcs,
            survey,
            streams,
            clock_drift_ppm: raw.clock.drift_ppm,
            truth_path: raw.truth.path,
            truth_every_step: raw.truth.every_step,
            faults,
        })
    }
}
