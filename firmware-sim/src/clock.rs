//! This machine's CLOCK_MONOTONIC in nanoseconds (the clock alfd's companion side and V4L2
//! timestamps use), or simulated time on a paused tokio clock; and the autopilot's boot clock
//! derived from it with a drift.

/// Simulated time on this thread (see [`simulate_on_this_thread`]): tokio's clock, paused by
/// the caller's runtime, counted from a fixed instant.
#[derive(Clone, Copy)]
struct Simulated {
    start: tokio::time::Instant,
    start_mono_ns: u64,
    start_unix_us: u64,
}

thread_local! {
    static SIMULATED: std::cell::Cell<Option<Simulated>> = const { std::cell::Cell::new(None) };
}

/// Until the guard drops, this thread's clock is the tokio runtime's (paused, in a
/// simulation that runs faster than real time and repeats exactly), starting at
/// `start_mono_ns` and Unix time `start_unix_us`. Call it inside the runtime, on the thread
/// that drives it (a current-thread runtime runs every task there).
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

/// CLOCK_MONOTONIC now, in nanoseconds (simulated time where set).
pub fn mono_ns() -> u64 {
    if let Some(s) = SIMULATED.get() {
        return s.start_mono_ns
            + tokio::time::Instant::now()
                .duration_since(s.start)
                .as_nanos() as u64;
    }
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Unix time now, in microseconds (simulated time where set).
pub fn unix_us() -> u64 {
    if let Some(s) = SIMULATED.get() {
        return s.start_unix_us
            + tokio::time::Instant::now()
                .duration_since(s.start)
                .as_micros() as u64;
    }
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// A tokio instant `ns` from now on the monotonic clock (now if in the past).
pub fn instant_at(mono: u64) -> tokio::time::Instant {
    let now = mono_ns();
    tokio::time::Instant::now() + std::time::Duration::from_nanos(mono.saturating_sub(now))
}

/// The autopilot's boot clock: restarted at `boot_mono_ns`, running `1 + drift` times as fast.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BootClock {
    pub boot_mono_ns: u64,
    pub drift: f64,
}

impl BootClock {
    pub fn boot_ns(&self, mono: u64) -> u64 {
        (mono.saturating_sub(self.boot_mono_ns) as f64 * (1.0 + self.drift)).round() as u64
    }

    pub fn mono_of_boot_ns(&self, boot_ns: u64) -> u64 {
        self.boot_mono_ns + (boot_ns as f64 / (1.0 + self.drift)).round() as u64
    }
}
