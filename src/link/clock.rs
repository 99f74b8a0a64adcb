//! The companion's clock: CLOCK_MONOTONIC in nanoseconds, the clock V4L2 stamps frames with, so
//! frames, telemetry (through TIMESYNC) and the simulator's truth all meet on one time line;
//! and the Unix time of an instant on it, for the capture log. In a simulation the clock is
//! the tokio runtime's, paused and advanced by the runtime when every task waits
//! ([`simulate_on_this_thread`]): `alfd sim` runs faster than real time and repeats exactly.
//! It lives in the `alfd-clock` crate, which firmware-sim reads too: one clock for both.

pub use alfd_clock::{
    instant_at, mono_ns, settle, simulate_on_this_thread, simulated, spend, unix_us_at,
    SimulatedTime,
};
