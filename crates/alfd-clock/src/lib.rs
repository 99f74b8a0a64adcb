//! The clock alfd and firmware-sim read. In flight: CLOCK_MONOTONIC in nanoseconds (the
//! clock V4L2 stamps frames with, so frames, telemetry through TIMESYNC and the
//! simulator's truth meet on one time line) and the Unix time of an instant on it. In a
//! simulation: the tokio runtime's clock, paused and moved by the runtime only when every
//! task waits ([`simulate_on_this_thread`]), counted from a fixed instant. The daemon and
//! the simulated autopilot read the same one, so a simulated flight runs as fast as its
//! work allows and repeats exactly.
//!
//! Its own crate so that both programs read one clock, and so that the flight build
//! (which links no simulator) still has it.

use std::cell::Cell;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Simulated time on this thread: tokio's clock counted from a fixed instant.
#[derive(Clone, Copy)]
struct Simulated {
    start: tokio::time::Instant,
    start_mono_ns: u64,
    start_unix_us: u64,
}

thread_local! {
    static SIMULATED: Cell<Option<Simulated>> = const { Cell::new(None) };
    static OWED_NS: Cell<u64> = const { Cell::new(0) };
}

/// Until the guard drops, this thread's clock is the tokio runtime's (paused by the
/// caller, so time moves only when every task waits), starting at `start_mono_ns` and
/// Unix time `start_unix_us`. Call it inside the runtime, on the thread that drives it: a
/// current-thread runtime runs every task there, so everything on it reads this clock.
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

/// The runtime's timer instant of a monotonic instant (now, if it is past): what a loop
/// sleeps until to wake at a frame's or a tick's instant, on either clock.
pub fn instant_at(mono: u64) -> tokio::time::Instant {
    tokio::time::Instant::now() + Duration::from_nanos(mono.saturating_sub(mono_ns()))
}

/// Unix time (µs) of a monotonic instant. In flight the offset between the two clocks
/// is taken once (the tightest of a few paired readings): read afresh for every
/// message, a thread paused between the two reads stamped telemetry out of order.
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

/// Unix time now, in microseconds (simulated time where set).
pub fn unix_us() -> u64 {
    unix_us_at(mono_ns()).unwrap_or(0)
}

/// A simulated device's own duration (a slow store, a slow camera in a test). In real
/// time the calling thread sleeps it. On simulated time it is owed: the loop that called
/// the device waits it on the runtime's timer ([`settle`]) while the other tasks run, as
/// the other threads would in flight.
pub fn spend(d: Duration) {
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
        tokio::time::sleep(Duration::from_nanos(owed)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a paused runtime the clock starts where it is told and moves with the runtime's
    /// timers, not the wall clock; the Unix time follows it; the guard gives the thread
    /// its real clock back.
    #[test]
    fn simulated_time_starts_where_told_and_moves_with_the_timers() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .start_paused(true)
            .build()
            .unwrap();
        rt.block_on(async {
            let guard = simulate_on_this_thread(1_000_000_000_000, 1_782_036_000_000_000);
            assert!(simulated());
            assert_eq!(mono_ns(), 1_000_000_000_000);
            assert_eq!(unix_us(), 1_782_036_000_000_000);
            tokio::time::sleep(Duration::from_secs(3600)).await;
            assert_eq!(mono_ns(), 1_000_000_000_000 + 3_600_000_000_000);
            tokio::time::sleep_until(instant_at(mono_ns() + 1_000_000)).await;
            assert_eq!(mono_ns(), 1_000_000_000_000 + 3_600_001_000_000);
            tokio::time::sleep_until(instant_at(0)).await;
            assert_eq!(
                mono_ns(),
                1_000_000_000_000 + 3_600_001_000_000,
                "a past instant is now"
            );
            assert_eq!(
                unix_us_at(1_000_000_000_000 - 1_000),
                Some(1_782_035_999_999_999)
            );
            spend(Duration::from_millis(250));
            settle().await;
            assert_eq!(mono_ns(), 1_000_000_000_000 + 3_600_251_000_000);
            drop(guard);
            assert!(!simulated());
        });
        let (a, b) = (mono_ns(), mono_ns());
        assert!(b >= a && a > 0);
        assert!(unix_us_at(a).is_some_and(|u| u > 1_700_000_000_000_000));
    }
}
