//! The companion's clock: CLOCK_MONOTONIC in nanoseconds, the clock V4L2 stamps frames with, so
//! frames, telemetry (through TIMESYNC) and the simulator's truth all meet on one time line;
//! and the Unix time of an instant on it, for the capture log. In a simulation the clock is
//! the tokio runtime's, paused and advanced by the runtime when every task waits
//! ([`simulate_on_this_thread`]): `alfd sim` runs faster than real time and repeats exactly.

use std::time::{SystemTime, UNIX_EPOCH};

/// Simulated time on this thread: tokio's clock counted from a fixed instant.
#[derive(Clone, Copy)]
struct Simulated {
    start: tokio::time::Instant,
    start_mono_ns: u64,
    start_unix_us: u64,
}

thread_local! {
    static SIMULATED: std::cell::Cell<Option<Simulated>> = const { std::cell::Cell::new(None) };
}

/// Until the guard drops, this thread's clock is the tokio runtime's (paused by the caller,
/// so time moves only when every task waits), starting at `start_mono_ns` and Unix time
/// `start_unix_us`. Call it inside the runtime, on the thread that drives it: a
/// current-thread runtime runs every task there, so the link, the estimator, the writer
/// and the coordinator all read it. firmware-sim keeps its own (`firmware_sim::clock`).
pub fn simulate_on_this_thread(start_mono_ns: u64, start_unix_us: u64) -> SimulatedTime {
    let s = Simulated {
        start: tokio::time::Instant::now(),
        start_mono_ns,
        start_unix_us,
    };
    SimulatedTime(SIMULATED.replace(Some(s)))
}

/// Restores the thread's clock when dropped.
pub struct SimulatedTime(Option<Simulated>);

impl Drop for SimulatedTime {
    fn drop(&mut self) {
        SIMULATED.set(self.0.take());
    }
}

thread_local! {
    static OWED_NS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// A simulated device's own duration (a slow store, a slow camera in a test). In real
/// time the calling thread sleeps it. On simulated time it is owed: the loop that called
/// the device waits it on the runtime's timer ([`settle`]) while the other tasks run, as
/// the other threads would in flight.
pub fn spend(d: std::time::Duration) {
    if simulated() {
        OWED_NS.set(OWED_NS.get().saturating_add(d.as_nanos() as u64));
    } else {
        std::thread::sleep(d);
    }
}

/// Waits what the devices called since the last settle [`spend`]t (nothing in real time).
pub async fn settle() {
    let owed = OWED_NS.replace(0);
    if owed > 0 {
        tokio::time::sleep(std::time::Duration::from_nanos(owed)).await;
    }
}

/// Whether this thread runs on simulated time.
pub fn simulated() -> bool {
    SIMULATED.get().is_some()
}

/// CLOCK_MONOTONIC now, in nanoseconds (simulated time where set).
pub fn mono_ns() -> u64 {
    if let Some(s) = SIMULATED.get() {
        let since = tokio::time::Instant::now().duration_since(s.start);
        return s.start_mono_ns + since.as_nanos() as u64;
    }
    let ts = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Unix time (µs) of a monotonic instant. The offset between the two clocks
/// is taken once (the tightest of a few paired readings): read afresh for
/// every message, a thread paused between the two reads stamped telemetry
/// out of order.
pub fn unix_us_at(mono: u64) -> Option<u64> {
    if let Some(s) = SIMULATED.get() {
        let since_us = (mono as i128 - s.start_mono_ns as i128).div_euclid(1000);
        return u64::try_from(s.start_unix_us as i128 + since_us).ok();
    }
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
