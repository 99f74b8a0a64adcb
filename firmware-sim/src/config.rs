//! The simulator's TOML config: parsed into raw structs (unknown keys refused), then checked into
//! a `SimConfig` whose errors name the field. `autopilot = "ardupilot"` is a profile: it turns on
//! ArduPilot's behaviours together (late origin, take-off from the ground, landed state, the
//! MAVLinkCamV2 camera backend, a ground station answering TIMESYNC); explicit keys still win.

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
    /// An in-memory byte stream in this process, handed out by
    /// [`crate::SimHandle::take_memory_wire`] (a new one after each link loss): for a
    /// simulation on a paused clock, where bytes in a kernel pty or socket would be in flight
    /// while the clock jumps ahead. Not in a config file.
    Memory,
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

/// Whose behaviour the simulator copies where autopilots differ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Autopilot {
    /// What firmware-sim always did: in the air from the start, origin known, CAMERA_TRIGGER;
    /// its distance trigger fires at the point. HEARTBEAT says MAV_AUTOPILOT_GENERIC.
    Generic,
    /// PX4 where it differs from the generic autopilot: its HEARTBEAT, and its distance trigger
    /// (`camera_trigger`: a new distance shoots once and counts from there, checked on a 50 ms
    /// poll; docs/link.md). Everything else is the generic autopilot's.
    Px4,
    /// ArduPilot (ArduCopter), as read in its sources (docs/link.md).
    ArduPilot,
}

/// How the distance trigger and capture commands take a picture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraBackend {
    /// The autopilot's own trigger output: a CAMERA_TRIGGER per picture.
    Trigger,
    /// ArduPilot's MAVLinkCamV2 (CAM1_TYPE = 6): finds a MAVLink camera (a HEARTBEAT of type
    /// CAMERA from component 100), reads its CAMERA_INFORMATION, then sends it
    /// MAV_CMD_IMAGE_START_CAPTURE per picture and reports CAMERA_FEEDBACK; no CAMERA_TRIGGER.
    MavlinkCamV2,
    /// ArduPilot's servo or relay camera (CAM1_TYPE = 1 or 2): it pulses an output, which
    /// always succeeds, and reports each picture by CAMERA_FEEDBACK alone (no CAMERA_TRIGGER,
    /// no command to anyone). The commonest survey set-up on ArduPilot.
    Servo,
}

/// The vehicle's life before the survey.
#[derive(Clone, Debug, PartialEq)]
pub struct Vehicle {
    /// Until then the EKF has no origin: GLOBAL_POSITION_INT reads lat = lon = 0, GPS_RAW_INT has
    /// no fix for the first half; then GPS_GLOBAL_ORIGIN and HOME_POSITION are sent once (and
    /// answered on MAV_CMD_REQUEST_MESSAGE). Zero: known from the start.
    pub origin_delay: Duration,
    /// Time on the ground (disarmed, then armed at 80 % of it) before a vertical take-off at
    /// `climb_mps` to the survey altitude; zero: in the air, armed, from the start.
    pub ground: Duration,
    pub climb_mps: f64,
}

impl Vehicle {
    /// When it arms (home is reset there, as ArduCopter does), after the start.
    pub fn arm_at(&self) -> Duration {
        self.ground.mul_f64(0.8)
    }
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
    /// EXTENDED_SYS_STATE (landed state).
    pub extended_sys_state: f64,
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
    pub autopilot: Autopilot,
    pub vehicle: Vehicle,
    pub camera: CameraBackend,
    /// From a capture command's arrival (DO_DIGICAM_CONTROL, IMAGE_START_CAPTURE) to its
    /// picture, which is reported at its own instant (as a hot-shoe feedback pin times it):
    /// the autopilot's scheduling and the camera's shutter lag. Zero: at the command.
    pub camera_delay: Duration,
    /// The first this many capture commands are refused (MAV_RESULT_TEMPORARILY_REJECTED,
    /// no picture), as an autopilot does while its camera is not ready.
    pub camera_refuse_first: u32,
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
    /// "generic" (default) or "ardupilot".
    autopilot: Option<String>,
    #[serde(default)]
    vehicle: RawVehicle,
    #[serde(default)]
    camera: RawCamera,
}

/// Unset keys take the profile's value.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawVehicle {
    origin_delay_s: Option<f64>,
    ground_s: Option<f64>,
    climb_mps: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawCamera {
    /// "trigger", "mavlink_cam_v2" or "servo" (also "relay").
    backend: Option<String>,
    /// Command to picture, ms (0 to 2000).
    delay_ms: f64,
    /// Capture commands refused at the start (0 to 1000).
    refuse_first: u32,
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
    /// Unset: the profile's (ArduPilot streams it in its EXTENDED_STATUS group).
    extended_sys_state_hz: Option<f64>,
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
            extended_sys_state_hz: None,
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

/// In the air with an origin from the start, as firmware-sim always flew.
static GENERIC_VEHICLE: Vehicle = Vehicle {
    origin_delay: Duration::ZERO,
    ground: Duration::ZERO,
    climb_mps: 3.0,
};

/// ArduCopter after power-on: some seconds until the EKF has an origin, armed later, then a
/// take-off. 10 s on the ground also covers MAVLinkCamV2's wait before it looks for a camera.
static ARDUPILOT_VEHICLE: Vehicle = Vehicle {
    origin_delay: Duration::from_secs(6),
    ground: Duration::from_secs(10),
    climb_mps: 5.0,
};

/// EXTENDED_SYS_STATE's rate in the profile (ArduPilot's default stream rate for its group).
const ARDUPILOT_EXTENDED_SYS_STATE_HZ: f64 = 2.0;

/// QGroundControl behind ArduPilot, answering the TIMESYNC requests it forwards, its clock 5 s off.
fn ardupilot_gcs() -> GcsTimesync {
    GcsTimesync::qgc(5000.0).expect("a valid offset")
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

    /// The ArduPilot profile on top of a config (as `--autopilot ardupilot` does): each
    /// behaviour the profile sets that the config left at its generic default.
    pub fn ardupilot(mut self) -> Self {
        let generic = SimConfig::default();
        self.autopilot = Autopilot::ArduPilot;
        if self.vehicle == generic.vehicle {
            self.vehicle = ARDUPILOT_VEHICLE.clone();
        }
        if self.camera == generic.camera {
            self.camera = CameraBackend::MavlinkCamV2;
        }
        if self.streams.extended_sys_state == generic.streams.extended_sys_state {
            self.streams.extended_sys_state = ARDUPILOT_EXTENDED_SYS_STATE_HZ;
        }
        if self.gcs_timesync.is_none() {
            self.gcs_timesync = Some(ardupilot_gcs());
        }
        self
    }

    fn validate(raw: Raw) -> Result<Self, ConfigError> {
        let l = raw.link;
        let autopilot = match raw.autopilot.as_deref() {
            None | Some("generic") => Autopilot::Generic,
            Some("px4") => Autopilot::Px4,
            Some("ardupilot") => Autopilot::ArduPilot,
            Some(other) => {
                return Err(bad(
                    "autopilot",
                    format!("`{other}`: expected generic, px4 or ardupilot"),
                ))
            }
        };
        let ap = autopilot == Autopilot::ArduPilot;
        let v = raw.vehicle;
        let profile = if ap {
            ARDUPILOT_VEHICLE.clone()
        } else {
            GENERIC_VEHICLE.clone()
        };
        let vehicle = Vehicle {
            origin_delay: match v.origin_delay_s {
                Some(s) => secs("vehicle.origin_delay_s", s)?,
                None => profile.origin_delay,
            },
            ground: match v.ground_s {
                Some(s) => secs("vehicle.ground_s", s)?,
                None => profile.ground,
            },
            climb_mps: match v.climb_mps {
                Some(c) => positive("vehicle.climb_mps", c)?,
                None => profile.climb_mps,
            },
        };
        if !vehicle.ground.is_zero() && vehicle.origin_delay > vehicle.arm_at() {
            return Err(bad(
                "vehicle.origin_delay_s",
                format!(
                    "{:?}: an autopilot arms only with an origin, at 80 % of ground_s ({:?})",
                    vehicle.origin_delay,
                    vehicle.arm_at()
                ),
            ));
        }
        let camera = match raw.camera.backend.as_deref() {
            None if ap => CameraBackend::MavlinkCamV2,
            None | Some("trigger") => CameraBackend::Trigger,
            Some("mavlink_cam_v2") => CameraBackend::MavlinkCamV2,
            Some("servo" | "relay") => CameraBackend::Servo,
            Some(other) => {
                return Err(bad(
                    "camera.backend",
                    format!("`{other}`: expected trigger, mavlink_cam_v2, servo or relay"),
                ))
            }
        };
        let delay_ms = raw.camera.delay_ms;
        if !(delay_ms.is_finite() && (0.0..=2000.0).contains(&delay_ms)) {
            return Err(bad(
                "camera.delay_ms",
                format!("{delay_ms}: from a capture command to its picture is 0 to 2000 ms"),
            ));
        }
        let camera_delay = Duration::from_secs_f64(delay_ms * 1e-3);
        let camera_refuse_first = raw.camera.refuse_first;
        if camera_refuse_first > 1000 {
            return Err(bad(
                "camera.refuse_first",
                format!(
                    "{camera_refuse_first}: capture commands refused at the start are 0 to 1000"
                ),
            ));
        }
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
            extended_sys_state: match r.extended_sys_state_hz {
                Some(hz) => rate("streams.extended_sys_state_hz", hz)?,
                None if ap => ARDUPILOT_EXTENDED_SYS_STATE_HZ,
                None => 0.0,
            },
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
            None if ap => Some(ardupilot_gcs()),
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
            autopilot,
            vehicle,
            camera,
            camera_delay,
            camera_refuse_first,
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
