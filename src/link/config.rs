//! The `[mavlink]` section: raw TOML (unknown keys refused) checked once into a typed
//! `LinkConfig`; errors name the key (`mavlink.<key>`). The signing key is read here, once, from
//! a file only the service may read; it is never printed.

use crate::core::geo::Geodetic;
use serde::Deserialize;
use std::fmt;
use std::io::Read;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {problem}")]
pub struct LinkConfigError {
    pub field: String,
    pub problem: String,
}

fn bad(key: &str, problem: impl Into<String>) -> LinkConfigError {
    LinkConfigError {
        field: format!("mavlink.{key}"),
        problem: problem.into(),
    }
}

/// The section as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawLinkConfig {
    pub address: String,
    #[serde(default = "one")]
    pub system_id: u8,
    #[serde(default = "camera")]
    pub component_id: u8,
    #[serde(default = "autopilot_ids")]
    pub accept_system_ids: Vec<u8>,
    #[serde(default = "one")]
    pub autopilot_component_id: u8,
    #[serde(default = "two")]
    pub mavlink_version: u8,
    #[serde(default = "ten")]
    pub position_hz: f64,
    #[serde(default = "ten")]
    pub attitude_hz: f64,
    #[serde(default = "ten")]
    pub timesync_hz: f64,
    #[serde(default = "horizon")]
    pub pose_horizon_ms: u64,
    #[serde(default = "keep")]
    pub pose_keep_ms: u64,
    #[serde(default = "read_timeout")]
    pub read_timeout_ms: u64,
    #[serde(default = "silence")]
    pub silence_reconnect_ms: u64,
    #[serde(default = "initial")]
    pub reconnect_initial_ms: u64,
    #[serde(default = "max")]
    pub reconnect_max_ms: u64,
    pub home_lat_deg: Option<f64>,
    pub home_lon_deg: Option<f64>,
    pub home_alt_m: Option<f64>,
    #[serde(default = "tolerance")]
    pub glitch_tolerance_m: f64,
    #[serde(default = "reanchor")]
    pub glitch_reanchor_ms: u64,
    /// MAVLink 2 signing: a file holding the 32-byte secret as 64 hex characters.
    pub signing_key_file: Option<PathBuf>,
    /// Signing link id (default 0); only with `signing_key_file`.
    pub signing_link_id: Option<u8>,
    /// Accept unsigned frames while signing (default false); only with `signing_key_file`.
    pub accept_unsigned: Option<bool>,
    /// Poses for captures only while the vehicle is airborne (default true).
    #[serde(default = "yes")]
    pub require_airborne: bool,
    /// Without EXTENDED_SYS_STATE: airborne = armed and at least this high above home.
    #[serde(default = "min_rel_alt")]
    pub min_rel_alt_m: f64,
}

fn yes() -> bool {
    true
}
fn min_rel_alt() -> f64 {
    2.0
}
fn one() -> u8 {
    1
}
fn two() -> u8 {
    2
}
fn camera() -> u8 {
    100
}
fn autopilot_ids() -> Vec<u8> {
    vec![1]
}
fn ten() -> f64 {
    10.0
}
fn horizon() -> u64 {
    200
}
fn keep() -> u64 {
    5_000
}
fn read_timeout() -> u64 {
    1_000
}
fn silence() -> u64 {
    3_000
}
fn initial() -> u64 {
    50
}
fn max() -> u64 {
    500
}
fn tolerance() -> f64 {
    2.0
}
fn reanchor() -> u64 {
    10_000
}

/// The link's validated settings.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkConfig {
    /// A rust-mavlink address: `serial:PATH:BAUD`, `udpin:`, `udpout:`, `tcpout:`, `tcpin:`.
    pub address: String,
    pub system_id: u8,
    pub component_id: u8,
    pub accept_system_ids: Vec<u8>,
    pub autopilot_component_id: u8,
    pub mavlink_version: u8,
    pub position_hz: f64,
    pub attitude_hz: f64,
    pub timesync_hz: f64,
    pub pose_horizon: Duration,
    pub pose_keep: Duration,
    pub read_timeout: Duration,
    pub silence_reconnect: Duration,
    pub reconnect_initial: Duration,
    pub reconnect_max: Duration,
    pub home: Option<Geodetic>,
    pub glitch_tolerance_m: f64,
    pub glitch_reanchor: Duration,
    /// MAVLink 2 signing, when `signing_key_file` is set; `None`: nothing signed or checked.
    pub signing: Option<Signing>,
    /// Pose queries (what captures are logged with) fail while the vehicle is not airborne.
    pub require_airborne: bool,
    /// Airborne without a landed state from the autopilot: armed and at least this high (m)
    /// above home (GLOBAL_POSITION_INT.relative_alt).
    pub min_rel_alt_m: f64,
}

/// MAVLink 2 signing settings, the key already read and checked.
#[derive(Clone, PartialEq, Eq)]
pub struct Signing {
    pub key_file: PathBuf,
    pub key: [u8; 32],
    pub link_id: u8,
    /// Unsigned (and MAVLink 1) frames are accepted too: for a transition only.
    pub accept_unsigned: bool,
}

impl fmt::Debug for Signing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Signing")
            .field("key_file", &self.key_file)
            .field("key", &"<redacted>")
            .field("link_id", &self.link_id)
            .field("accept_unsigned", &self.accept_unsigned)
            .finish()
    }
}

/// Read a signing key: 64 hex characters, optionally followed by one newline, in a regular file
/// that group and others cannot access (as ssh insists for private keys). Errors never quote
/// the file's content.
pub fn read_signing_key(path: &Path) -> Result<[u8; 32], String> {
    let shown = path.display();
    let file = std::fs::File::open(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            format!(
                "{shown}: no such file (create it with `openssl rand -hex 32 > {shown} && chmod 600 {shown}`)"
            )
        } else {
            format!("{shown}: cannot be read: {e}")
        }
    })?;
    let meta = file
        .metadata()
        .map_err(|e| format!("{shown}: cannot be read: {e}"))?;
    if !meta.is_file() {
        return Err(format!("{shown}: not a regular file"));
    }
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        return Err(format!(
            "{shown}: accessible to group or others (mode {mode:04o}); run `chmod 600 {shown}`"
        ));
    }
    let mut text = Vec::with_capacity(66);
    file.take(1024)
        .read_to_end(&mut text)
        .map_err(|e| format!("{shown}: cannot be read: {e}"))?;
    let hex = text
        .strip_suffix(b"\r\n")
        .or_else(|| text.strip_suffix(b"\n"))
        .unwrap_or(&text);
    if hex.len() != 64 {
        return Err(format!(
            "{shown}: expected 64 hex characters (a 32-byte key, e.g. `openssl rand -hex 32`), got {} bytes",
            text.len()
        ));
    }
    let mut key = [0u8; 32];
    for (i, pair) in hex.chunks_exact(2).enumerate() {
        let digit = |c: u8| (c as char).to_digit(16);
        match (digit(pair[0]), digit(pair[1])) {
            (Some(hi), Some(lo)) => key[i] = (hi * 16 + lo) as u8,
            _ => {
                return Err(format!(
                    "{shown}: expected 64 hex characters, found a non-hex byte at offset {}",
                    2 * i
                ))
            }
        }
    }
    if key == [0u8; 32] {
        return Err(format!(
            "{shown}: an all-zero key means \"signing off\" to autopilots; generate one with `openssl rand -hex 32`"
        ));
    }
    Ok(key)
}

impl LinkConfig {
    /// A config with every default for `address`.
    pub fn for_address(address: &str) -> Self {
        let raw: RawLinkConfig =
            toml::from_str(&format!("address = {address:?}")).expect("defaults parse");
        LinkConfig::try_from(raw).expect("defaults are valid")
    }

    /// Parse a document's `[mavlink]` table.
    pub fn from_toml(text: &str) -> Result<Self, LinkConfigError> {
        #[derive(Deserialize)]
        struct Doc {
            mavlink: RawLinkConfig,
        }
        let doc: Doc = toml::from_str(text).map_err(|e| LinkConfigError {
            field: "mavlink".into(),
            problem: e.to_string(),
        })?;
        LinkConfig::try_from(doc.mavlink)
    }
}

fn rate(key: &str, hz: f64) -> Result<f64, LinkConfigError> {
    if !(hz.is_finite() && hz > 0.0 && hz <= 1000.0) {
        return Err(bad(key, format!("{hz}: must be in (0, 1000] Hz")));
    }
    Ok(hz)
}

fn ms(key: &str, v: u64, min: u64, max: u64) -> Result<Duration, LinkConfigError> {
    if !(min..=max).contains(&v) {
        return Err(bad(key, format!("{v}: must be between {min} and {max} ms")));
    }
    Ok(Duration::from_millis(v))
}

/// What rust-mavlink's address parser leaves to the connection: a baud rate of
/// 0 and a port past 65535 parse, and fail (or hang up the line) only when the
/// daemon connects, in flight. A listener may take port 0 (an ephemeral port,
/// as the tests' links do); a peer to send to may not.
fn endpoint(address: &str) -> Result<(), String> {
    let Some((protocol, rest)) = address.split_once(':') else {
        return Ok(());
    };
    match protocol {
        "serial" => {
            let baud = rest.split_once(':').map_or("", |(_, b)| b);
            if baud.parse::<u32>().is_ok_and(|b| b == 0) {
                return Err("a baud rate of 0 hangs up the line".into());
            }
        }
        "udpin" | "udpout" | "udpbcast" | "tcpin" | "tcpout" => {
            let Some((host, port)) = rest.rsplit_once(':') else {
                return Err("expected HOST:PORT after the protocol".into());
            };
            if host.is_empty() {
                return Err("no host before the port".into());
            }
            let listener = matches!(protocol, "udpin" | "tcpin");
            match port.parse::<u16>() {
                Ok(0) if !listener => {
                    return Err(format!("port 0: {protocol} needs the peer's port"))
                }
                Ok(_) => {}
                Err(_) => return Err(format!("port {port}: expected a port from 1 to 65535")),
            }
        }
        // rust-mavlink reads a file as a link: the daemon would replay a log from its
        // start again at every end of file, an autopilot "rebooting" every few ms.
        "file" => {
            return Err(
                "a file is a recorded log, not an autopilot: use serial:, udpin:, udpout:, tcpout: or tcpin:".into(),
            )
        }
        _ => {}
    }
    Ok(())
}

impl TryFrom<RawLinkConfig> for LinkConfig {
    type Error = LinkConfigError;

    fn try_from(r: RawLinkConfig) -> Result<Self, LinkConfigError> {
        mavlink::ConnectionAddress::parse_address(&r.address).map_err(|e| {
            bad(
                "address",
                format!(
                    "`{}`: {e} (expected serial:PATH:BAUD, or udpin:, udpout:, udpbcast:, tcpin: or tcpout: then HOST:PORT)",
                    r.address
                ),
            )
        })?;
        endpoint(&r.address).map_err(|why| bad("address", format!("`{}`: {why}", r.address)))?;
        if r.system_id == 0 {
            return Err(bad("system_id", "0 is the broadcast id"));
        }
        if r.component_id == 0 {
            return Err(bad("component_id", "0 is the broadcast id"));
        }
        if r.accept_system_ids.is_empty() || r.accept_system_ids.contains(&0) {
            return Err(bad(
                "accept_system_ids",
                "needs at least one id, none of them 0",
            ));
        }
        if !matches!(r.mavlink_version, 1 | 2) {
            return Err(bad(
                "mavlink_version",
                format!("{}: expected 1 or 2", r.mavlink_version),
            ));
        }
        let home = match (r.home_lat_deg, r.home_lon_deg, r.home_alt_m) {
            (None, None, None) => None,
            (Some(lat), Some(lon), alt) => {
                if !(-90.0..=90.0).contains(&lat) {
                    return Err(bad("home_lat_deg", format!("{lat}: must be within ±90°")));
                }
                if !(-180.0..=180.0).contains(&lon) {
                    return Err(bad("home_lon_deg", format!("{lon}: must be within ±180°")));
                }
                Some(Geodetic {
                    lat_deg: lat,
                    lon_deg: lon,
                    alt_m: alt.unwrap_or(0.0),
                })
            }
            _ => {
                return Err(bad(
                    "home_lat_deg",
                    "home_lat_deg and home_lon_deg go together",
                ))
            }
        };
        if !(r.glitch_tolerance_m.is_finite() && r.glitch_tolerance_m > 0.0) {
            return Err(bad(
                "glitch_tolerance_m",
                "must be a positive number of metres",
            ));
        }
        let signing = match r.signing_key_file {
            None => {
                if r.signing_link_id.is_some() {
                    return Err(bad(
                        "signing_link_id",
                        "only meaningful with signing_key_file",
                    ));
                }
                if r.accept_unsigned.is_some() {
                    return Err(bad(
                        "accept_unsigned",
                        "only meaningful with signing_key_file",
                    ));
                }
                None
            }
            Some(key_file) => {
                if r.mavlink_version != 2 {
                    return Err(bad(
                        "signing_key_file",
                        "signing needs mavlink_version = 2 (MAVLink 1 frames carry no signature)",
                    ));
                }
                let key = read_signing_key(&key_file).map_err(|e| bad("signing_key_file", e))?;
                Some(Signing {
                    key_file,
                    key,
                    link_id: r.signing_link_id.unwrap_or(0),
                    accept_unsigned: r.accept_unsigned.unwrap_or(false),
                })
            }
        };
        if !(r.min_rel_alt_m.is_finite() && (0.0..=10_000.0).contains(&r.min_rel_alt_m)) {
            return Err(bad(
                "min_rel_alt_m",
                format!("{}: must be between 0 and 10000 m", r.min_rel_alt_m),
            ));
        }
        let reconnect_initial = ms("reconnect_initial_ms", r.reconnect_initial_ms, 1, 60_000)?;
        let reconnect_max = ms("reconnect_max_ms", r.reconnect_max_ms, 1, 60_000)?;
        if reconnect_max < reconnect_initial {
            return Err(bad(
                "reconnect_max_ms",
                "must be at least reconnect_initial_ms",
            ));
        }
        Ok(LinkConfig {
            address: r.address,
            system_id: r.system_id,
            component_id: r.component_id,
            accept_system_ids: r.accept_system_ids,
            autopilot_component_id: r.autopilot_component_id,
            mavlink_version: r.mavlink_version,
            position_hz: rate("position_hz", r.position_hz)?,
            attitude_hz: rate("attitude_hz", r.attitude_hz)?,
            timesync_hz: rate("timesync_hz", r.timesync_hz)?,
            pose_horizon: ms("pose_horizon_ms", r.pose_horizon_ms, 0, 10_000)?,
            pose_keep: ms("pose_keep_ms", r.pose_keep_ms, 100, 600_000)?,
            read_timeout: ms("read_timeout_ms", r.read_timeout_ms, 10, 60_000)?,
            silence_reconnect: ms("silence_reconnect_ms", r.silence_reconnect_ms, 100, 600_000)?,
            reconnect_initial,
            reconnect_max,
            home,
            glitch_tolerance_m: r.glitch_tolerance_m,
            glitch_reanchor: ms("glitch_reanchor_ms", r.glitch_reanchor_ms, 0, 3_600_000)?,
            signing,
            require_airborne: r.require_airborne,
            min_rel_alt_m: r.min_rel_alt_m,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_the_key() {
        let cases = [
            ("address = \"carrier:pigeon\"", "mavlink.address"),
            (
                "address = \"serial:/dev/ttyS0:921600\"\nsystem_id = 0",
                "mavlink.system_id",
            ),
            (
                "address = \"udpin:0.0.0.0:14550\"\naccept_system_ids = []",
                "mavlink.accept_system_ids",
            ),
            (
                "address = \"udpin:0.0.0.0:14550\"\nposition_hz = 0",
                "mavlink.position_hz",
            ),
            (
                "address = \"udpin:0.0.0.0:14550\"\nreconnect_max_ms = 10",
                "mavlink.reconnect_max_ms",
            ),
            (
                "address = \"udpin:0.0.0.0:14550\"\nhome_lat_deg = 91\nhome_lon_deg = 0",
                "mavlink.home_lat_deg",
            ),
            (
                "address = \"udpin:0.0.0.0:14550\"\nmin_rel_alt_m = -1",
                "mavlink.min_rel_alt_m",
            ),
            ("address = \"udpin:0.0.0.0:14550\"\nadress = 1", "mavlink"),
            // What rust-mavlink parses and the connection would refuse in flight.
            ("address = \"serial:/dev/ttyS0:0\"", "mavlink.address"),
            ("address = \"udpin:0.0.0.0:99999\"", "mavlink.address"),
            ("address = \"udpout:127.0.0.1:0\"", "mavlink.address"),
            ("address = \"tcpout:localhost:x\"", "mavlink.address"),
            ("address = \"tcpout:5760\"", "mavlink.address"),
            ("address = \"udpin::14550\"", "mavlink.address"),
            ("address = \"file:/var/log/flight.tlog\"", "mavlink.address"),
        ];
        for (body, field) in cases {
            let e = LinkConfig::from_toml(&format!("[mavlink]\n{body}\n")).unwrap_err();
            assert_eq!(e.field, field, "{body}: {e}");
        }
        let ok = LinkConfig::from_toml("[mavlink]\naddress = \"tcpout:127.0.0.1:5760\"\n").unwrap();
        assert_eq!(
            (ok.component_id, ok.system_id, ok.accept_system_ids.clone()),
            (100, 1, vec![1])
        );
        assert_eq!(ok.reconnect_max, Duration::from_millis(500));
        for address in [
            "udpin:127.0.0.1:0",
            "udpout:[::1]:14550",
            "serial:/dev/ttyAMA0:921600",
            "tcpin:0.0.0.0:5760",
        ] {
            let text = format!("[mavlink]\naddress = {address:?}\n");
            assert!(LinkConfig::from_toml(&text).is_ok(), "{address}");
        }
    }
}
