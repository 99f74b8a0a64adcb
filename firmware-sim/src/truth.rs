//! The true pose at an instant, and `truth.jsonl`: one line per trigger or capture (and per
//! telemetry step on request), with both clocks, so tests compare alfd's beliefs with what happened.

use serde::Serialize;

#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Truth {
    /// This machine's CLOCK_MONOTONIC.
    pub mono_ns: u64,
    /// The autopilot's boot clock at that instant (ms, fractional), in the current boot.
    pub time_boot_ms: f64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
    /// Local NED around the survey origin.
    pub pos_ned_m: [f64; 3],
    pub vel_ned_mps: [f64; 3],
    /// Roll, pitch, yaw (deg).
    pub rpy_deg: [f64; 3],
    /// Body to NED (w, x, y, z).
    pub q: [f64; 4],
}

#[derive(Serialize)]
pub(crate) struct Line<'a> {
    pub event: &'a str,
    pub seq: Option<u32>,
    #[serde(flatten)]
    pub truth: Truth,
}
