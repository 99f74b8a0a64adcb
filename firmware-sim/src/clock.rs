//! This machine's CLOCK_MONOTONIC in nanoseconds (the clock alfd's companion side and V4L2
//! timestamps use), or simulated time on a paused tokio clock, both from `alfd-clock`, the
//! crate alfd reads too; and the autopilot's boot clock derived from it with a drift.

pub use alfd_clock::{instant_at, mono_ns, unix_us};

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
