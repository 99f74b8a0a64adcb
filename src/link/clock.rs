//! The companion's clock: CLOCK_MONOTONIC in nanoseconds, the clock V4L2 stamps frames with, so
//! frames, telemetry (through TIMESYNC) and the simulator's truth all meet on one time line.

/// CLOCK_MONOTONIC now, in nanoseconds.
pub fn mono_ns() -> u64 {
    let ts = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}
