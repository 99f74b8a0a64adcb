//! TIMESYNC filter: maps the autopilot's boot clock to the companion's monotonic clock (offset
//! and drift) from two-way exchanges. Only the fastest round trips of a window are fitted (their
//! midpoints are the least biased by one-way delay), outliers are rejected, and the estimate is
//! reset when the boot clock restarts (a reboot). All times are nanoseconds passed in.

use std::collections::VecDeque;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeSyncConfig {
    /// Exchanges kept (the newest).
    pub window: usize,
    /// Exchanges needed after a reset before the estimate is used.
    pub min_samples: usize,
    /// Round trips slower than this are discarded outright.
    pub rtt_max_ns: u64,
    /// Exchanges within this of the window's fastest round trip are fitted.
    pub rtt_margin_ns: u64,
    /// A sample farther than half its round trip plus this from the fit is an outlier.
    pub outlier_ns: u64,
    /// This many outliers in a row mean the clock stepped: reset and follow.
    pub outliers_to_reset: u32,
    /// Drift is fitted only over at least this span of boot time (else it is kept).
    pub drift_span_ns: u64,
    /// Boot time going back by more than this is a reboot candidate...
    pub reboot_backstep_ns: u64,
    /// ...confirmed by this many timestamps agreeing on the new epoch.
    pub reboot_confirm: u32,
    /// A timestamp this far ahead of the last plausible one plus the local time elapsed since
    /// is implausible (a boot clock cannot run ahead of time; corrupted frames can).
    pub future_tolerance_ns: u64,
}

impl Default for TimeSyncConfig {
    fn default() -> Self {
        Self {
            window: 64,
            min_samples: 3,
            rtt_max_ns: 500_000_000,
            rtt_margin_ns: 250_000,
            outlier_ns: 20_000_000,
            outliers_to_reset: 5,
            drift_span_ns: 8_000_000_000,
            reboot_backstep_ns: 1_000_000_000,
            reboot_confirm: 3,
            future_tolerance_ns: 300_000_000,
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Sample {
    remote_ns: u64,
    /// Local midpoint of the exchange minus the remote time.
    offset_ns: f64,
    rtt_ns: u64,
}

/// The current mapping: `local = remote + offset_ns + drift * (remote - ref_remote_ns)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fit {
    pub ref_remote_ns: u64,
    pub offset_ns: f64,
    /// Dimensionless (1e-6 = 1 ppm): how much faster the local clock runs.
    pub drift: f64,
    /// The fastest round trip in the window.
    pub rtt_min_ns: u64,
}

impl Fit {
    fn offset_at(&self, remote_ns: u64) -> f64 {
        self.offset_ns + self.drift * (remote_ns as f64 - self.ref_remote_ns as f64)
    }
}

/// What became of one TIMESYNC exchange.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleOutcome {
    Accepted,
    /// Round trip above `rtt_max_ns`, or received before it was sent.
    Discarded,
    Outlier,
    /// The filter reset (clock step or reboot) and restarted from this sample.
    Reset,
}

/// What a boot timestamp on incoming telemetry says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimeCheck {
    Plausible,
    /// Backwards (unconfirmed) or from the future: skip the message, keep the state.
    Implausible,
    /// The boot clock restarted: the filter was reset; everything keyed by boot time is void.
    Rebooted,
}

#[derive(Clone, Debug)]
pub struct TimeSync {
    cfg: TimeSyncConfig,
    samples: VecDeque<Sample>,
    fit: Option<Fit>,
    since_reset: usize,
    outliers_in_row: u32,
    /// The last plausible boot timestamp and when it was received.
    last_remote: Option<(u64, u64)>,
    candidate: Option<(i128, u32)>,
    resets: u32,
}

impl TimeSync {
    pub fn new(cfg: TimeSyncConfig) -> Self {
        Self {
            cfg,
            samples: VecDeque::with_capacity(cfg.window),
            fit: None,
            since_reset: 0,
            outliers_in_row: 0,
            last_remote: None,
            candidate: None,
            resets: 0,
        }
    }

    /// One exchange: request sent at `local_sent_ns`, the autopilot stamped `remote_ns`, the
    /// reply arrived at `local_recv_ns`.
    pub fn on_exchange(
        &mut self,
        local_sent_ns: u64,
        remote_ns: u64,
        local_recv_ns: u64,
    ) -> SampleOutcome {
        let Some(rtt_ns) = local_recv_ns.checked_sub(local_sent_ns) else {
            return SampleOutcome::Discarded;
        };
        if rtt_ns > self.cfg.rtt_max_ns {
            return SampleOutcome::Discarded;
        }
        let mut outcome = SampleOutcome::Accepted;
        match self.check_remote_time(remote_ns, local_recv_ns) {
            TimeCheck::Implausible => return SampleOutcome::Outlier,
            TimeCheck::Rebooted => outcome = SampleOutcome::Reset,
            TimeCheck::Plausible => {}
        }
        let mid = local_sent_ns as f64 + rtt_ns as f64 / 2.0;
        let s = Sample {
            remote_ns,
            offset_ns: mid - remote_ns as f64,
            rtt_ns,
        };
        if let (Some(fit), true) = (self.fit, self.is_synced()) {
            let residual = (s.offset_ns - fit.offset_at(remote_ns)).abs();
            if residual > rtt_ns as f64 / 2.0 + self.cfg.outlier_ns as f64 {
                self.outliers_in_row += 1;
                if self.outliers_in_row < self.cfg.outliers_to_reset {
                    return SampleOutcome::Outlier;
                }
                self.reset();
                outcome = SampleOutcome::Reset;
            }
        }
        self.outliers_in_row = 0;
        if self.samples.len() == self.cfg.window.max(1) {
            self.samples.pop_front();
        }
        self.samples.push_back(s);
        self.since_reset += 1;
        self.refit();
        outcome
    }

    /// Check a boot timestamp from incoming telemetry received at `local_rx_ns`.
    pub fn check_remote_time(&mut self, remote_ns: u64, local_rx_ns: u64) -> TimeCheck {
        let Some((last, last_rx)) = self.last_remote else {
            self.last_remote = Some((remote_ns, local_rx_ns));
            return TimeCheck::Plausible;
        };
        if remote_ns.saturating_add(self.cfg.reboot_backstep_ns) < last {
            let epoch = local_rx_ns as i128 - remote_ns as i128;
            let tol = self.cfg.reboot_backstep_ns as i128 / 2;
            let n = match self.candidate {
                Some((e, n)) if (epoch - e).abs() < tol => n + 1,
                _ => 1,
            };
            self.candidate = Some((epoch, n));
            if n >= self.cfg.reboot_confirm {
                self.reset();
                self.last_remote = Some((remote_ns, local_rx_ns));
                return TimeCheck::Rebooted;
            }
            return TimeCheck::Implausible;
        }
        let elapsed = local_rx_ns.saturating_sub(last_rx);
        let limit = last + elapsed + elapsed / 1000 + self.cfg.future_tolerance_ns;
        if remote_ns > limit {
            return TimeCheck::Implausible;
        }
        self.candidate = None;
        if remote_ns >= last {
            self.last_remote = Some((remote_ns, local_rx_ns));
        }
        TimeCheck::Plausible
    }

    fn reset(&mut self) {
        self.samples.clear();
        self.fit = None;
        self.since_reset = 0;
        self.outliers_in_row = 0;
        self.candidate = None;
        self.last_remote = None;
        self.resets += 1;
    }

    fn refit(&mut self) {
        let Some(rtt_min) = self.samples.iter().map(|s| s.rtt_ns).min() else {
            return;
        };
        let limit = rtt_min.saturating_add(self.cfg.rtt_margin_ns);
        let sel: Vec<&Sample> = self.samples.iter().filter(|s| s.rtt_ns <= limit).collect();
        let n = sel.len() as f64;
        let ref_remote_ns = sel.iter().map(|s| s.remote_ns).max().unwrap_or(0);
        let xs: Vec<f64> = sel
            .iter()
            .map(|s| s.remote_ns as f64 - ref_remote_ns as f64)
            .collect();
        let mx = xs.iter().sum::<f64>() / n;
        let my = sel.iter().map(|s| s.offset_ns).sum::<f64>() / n;
        let span = sel.iter().map(|s| s.remote_ns).max().unwrap_or(0)
            - sel.iter().map(|s| s.remote_ns).min().unwrap_or(0);
        let drift = if sel.len() >= 2 && span >= self.cfg.drift_span_ns {
            let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
            let sxy: f64 = xs
                .iter()
                .zip(&sel)
                .map(|(x, s)| (x - mx) * (s.offset_ns - my))
                .sum();
            (sxy / sxx).clamp(-1e-3, 1e-3)
        } else {
            self.fit.map_or(0.0, |f| f.drift)
        };
        self.fit = Some(Fit {
            ref_remote_ns,
            offset_ns: my - drift * mx,
            drift,
            rtt_min_ns: rtt_min,
        });
    }

    /// Enough exchanges since the last reset to use the estimate.
    pub fn is_synced(&self) -> bool {
        self.fit.is_some() && self.since_reset >= self.cfg.min_samples
    }

    pub fn fit(&self) -> Option<Fit> {
        self.fit.filter(|_| self.is_synced())
    }

    pub fn resets(&self) -> u32 {
        self.resets
    }

    /// The local monotonic time of a boot timestamp, once synced.
    pub fn remote_to_local(&self, remote_ns: u64) -> Option<u64> {
        let fit = self.fit()?;
        let local = remote_ns as f64 + fit.offset_at(remote_ns);
        (local >= 0.0).then_some(local.round() as u64)
    }

    /// The boot timestamp of a local monotonic time, once synced (it may be before boot: `None`).
    pub fn local_to_remote(&self, local_ns: u64) -> Option<u64> {
        let fit = self.fit()?;
        let mut remote = local_ns as f64 - fit.offset_ns;
        for _ in 0..3 {
            remote = local_ns as f64 - fit.offset_at(remote.max(0.0) as u64);
        }
        (remote >= 0.0).then_some(remote.round() as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn symmetric_exchanges_give_the_offset() {
        let mut ts = TimeSync::new(TimeSyncConfig::default());
        let boot_at = 5_000 * MS;
        for k in 0..5u64 {
            let sent = boot_at + 1_000 * MS + k * 250 * MS;
            let remote = sent + 2 * MS - boot_at;
            ts.on_exchange(sent, remote, sent + 4 * MS);
        }
        assert!(ts.is_synced());
        assert_eq!(ts.remote_to_local(10_000 * MS), Some(boot_at + 10_000 * MS));
        assert_eq!(ts.local_to_remote(boot_at + 7 * MS), Some(7 * MS));
    }

    #[test]
    fn a_reboot_needs_confirmation() {
        let mut ts = TimeSync::new(TimeSyncConfig::default());
        assert_eq!(
            ts.check_remote_time(60_000 * MS, 70_000 * MS),
            TimeCheck::Plausible
        );
        assert_eq!(
            ts.check_remote_time(10 * MS, 70_010 * MS),
            TimeCheck::Implausible
        );
        assert_eq!(
            ts.check_remote_time(60_020 * MS, 70_020 * MS),
            TimeCheck::Plausible
        );
        assert_eq!(
            ts.check_remote_time(90_000 * MS, 70_025 * MS),
            TimeCheck::Implausible
        );
        assert_eq!(
            ts.check_remote_time(30 * MS, 70_030 * MS),
            TimeCheck::Implausible
        );
        assert_eq!(
            ts.check_remote_time(40 * MS, 70_040 * MS),
            TimeCheck::Implausible
        );
        assert_eq!(
            ts.check_remote_time(50 * MS, 70_050 * MS),
            TimeCheck::Rebooted
        );
        assert_eq!(ts.resets(), 1);
    }
}
