//! Where a capture's time goes, from its instant to the CAMERA_IMAGE_CAPTURED that
//! answers it (issue 14: "say where the time goes"): four stamps per capture on the
//! monotonic clock, kept as phases, summarised as median and worst at the stop. Pure: the
//! stamps are taken by the outbox and the writer and handed in.

/// The stamps of one capture, monotonic ns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CaptureStamps {
    /// The capture's instant (the frame's or the trigger's time of validity).
    pub instant_ns: u64,
    /// Its record went into the writer's queue: decided and located.
    pub queued_ns: u64,
    /// The writer took it up.
    pub started_ns: u64,
    /// Image (if any) and manifest line written.
    pub finished_ns: u64,
    /// CAMERA_IMAGE_CAPTURED handed to the link.
    pub answered_ns: u64,
}

/// The phases, in order: decided and located, waiting for the writer, writing, answering.
pub const PHASES: [&str; 4] = ["decide_and_locate", "writer_queue", "write", "answer"];

/// Captures whose phases are kept for the summary; beyond, they are counted only (a flight
/// of this many captures is far past any card's capacity at our image sizes).
pub const KEPT_MAX: usize = 200_000;

impl CaptureStamps {
    /// The four phases and the total, ns; a stamp earlier than the one before it (clock
    /// reads on different threads) counts as no time, never as negative.
    pub fn phases_ns(&self) -> ([u64; 4], u64) {
        let t = [
            self.instant_ns,
            self.queued_ns,
            self.started_ns,
            self.finished_ns,
            self.answered_ns,
        ];
        let mut p = [0u64; 4];
        let mut at = t[0];
        for k in 0..4 {
            let next = t[k + 1].max(at);
            p[k] = next - at;
            at = next;
        }
        (p, at - t[0])
    }
}

/// Median and worst of one phase, ms.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Spread {
    pub median_ms: f64,
    pub worst_ms: f64,
}

/// The stop's summary.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LatencySummary {
    pub captures: u64,
    /// Per [`PHASES`].
    pub phases: [Spread; 4],
    pub total: Spread,
}

impl std::fmt::Display for LatencySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "capture to CAMERA_IMAGE_CAPTURED over {} captures: median {:.0} ms, worst {:.0} ms (",
            self.captures, self.total.median_ms, self.total.worst_ms
        )?;
        for (k, (name, s)) in PHASES.iter().zip(&self.phases).enumerate() {
            let sep = if k == 0 { "" } else { ", " };
            write!(f, "{sep}{name} {:.0}/{:.0}", s.median_ms, s.worst_ms)?;
        }
        write!(f, " ms median/worst)")
    }
}

/// Every answered capture's phases.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LatencyLog {
    kept: Vec<([u64; 4], u64)>,
    count: u64,
}

impl LatencyLog {
    pub fn record(&mut self, s: &CaptureStamps) {
        self.count += 1;
        if self.kept.len() < KEPT_MAX {
            self.kept.push(s.phases_ns());
        }
    }

    /// `None` before the first answered capture.
    pub fn summary(&self) -> Option<LatencySummary> {
        if self.kept.is_empty() {
            return None;
        }
        let spread = |mut v: Vec<u64>| {
            v.sort_unstable();
            Spread {
                median_ms: v[v.len() / 2] as f64 * 1e-6,
                worst_ms: v[v.len() - 1] as f64 * 1e-6,
            }
        };
        Some(LatencySummary {
            captures: self.count,
            phases: std::array::from_fn(|k| spread(self.kept.iter().map(|p| p.0[k]).collect())),
            total: spread(self.kept.iter().map(|p| p.1).collect()),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn phases_add_up_to_the_total_and_never_go_negative() {
        let s = CaptureStamps {
            instant_ns: 1000 * MS,
            queued_ns: 1060 * MS,
            // Read on the writer's thread a hair before the outbox's clock read.
            started_ns: 1059 * MS,
            finished_ns: 1090 * MS,
            answered_ns: 1091 * MS,
        };
        let (p, total) = s.phases_ns();
        assert_eq!(p, [60 * MS, 0, 30 * MS, MS]);
        assert_eq!(total, 91 * MS);
        assert_eq!(p.iter().sum::<u64>(), total);
    }

    #[test]
    fn the_summary_gives_each_phase_its_median_and_worst() {
        let mut log = LatencyLog::default();
        assert!(log.summary().is_none());
        for k in 0..5u64 {
            log.record(&CaptureStamps {
                instant_ns: 0,
                queued_ns: (10 + k) * MS,
                started_ns: (10 + k) * MS,
                finished_ns: (10 + k + 100 * (k / 4)) * MS,
                answered_ns: (11 + k + 100 * (k / 4)) * MS,
            });
        }
        let s = log.summary().unwrap();
        assert_eq!(s.captures, 5);
        assert_eq!(s.phases[0].median_ms, 12.0);
        assert_eq!(s.phases[0].worst_ms, 14.0);
        assert_eq!(s.phases[2].median_ms, 0.0);
        assert_eq!(s.phases[2].worst_ms, 100.0);
        assert_eq!(s.total.worst_ms, 115.0);
        let text = s.to_string();
        assert!(text.contains("median 13 ms, worst 115 ms"), "{text}");
        assert!(text.contains("write 0/100"), "{text}");
    }
}
