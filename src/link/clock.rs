//! The companion's clock: CLOCK_MONOTONIC in nanoseconds, the clock V4L2 stamps frames with, so
//! frames, telemetry (through TIMESYNC) and the simulator's truth all meet on one time line;
//! and the Unix time of an instant on it, for the capture log.

use std::time::{SystemTime, UNIX_EPOCH};

/// CLOCK_MONOTONIC now, in nanoseconds.
pub fn mono_ns() -> u64 {
    let ts = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Unix time (µs) of a monotonic instant. The offset between the two clocks
/// is taken once (the tightest of a few paired readings): read afresh for
/// every message, a thread paused between the two reads stamped telemetry
/// out of order.
pub fn unix_us_at(mono: u64) -> Option<u64> {
    static OFFSET_US: std::sync::OnceLock<Option<i128>> = std::sync::OnceLock::new();
    let offset = (*OFFSET_US.get_or_init(|| {
        (0..5)
            .filter_map(|_| {
                let before = mono_ns();
                let unix = SystemTime::now().duration_since(UNIX_EPOCH).ok()?;
                let after = mono_ns();
                Some((
                    after - before,
                    unix.as_micros() as i128 - (before / 1000) as i128,
                ))
            })
            .min_by_key(|(spread, _)| *spread)
            .map(|(_, off)| off)
    }))?;
    u64::try_from((mono / 1000) as i128 + offset).ok()
}
