//! The autopilot's own local position (LOCAL_POSITION_NED) carried into the link's frame.
//!
//! GLOBAL_POSITION_INT is quantised to 1e-7° (1.1 cm north, 0.75 cm east at 47°): between two
//! samples an interval is off by up to about a centimetre, 1.5 % of a 0.65 m capture spacing.
//! LOCAL_POSITION_NED carries the same estimate in `f32` metres (about 30 µm at 500 m). Its
//! origin is the autopilot's (EKF origin), not necessarily the link's frame, so the offset between
//! the two is estimated from pairs of samples at nearly the same instant: a running mean, which
//! averages the quantisation away, restarted when the residual jumps (the autopilot reset its
//! local frame, or the link's frame moved). A local sample is trusted only where the last
//! accepted global position, moved by its velocity, says it can be: the global stream keeps the
//! glitch gate's authority.

use glam::DVec3;

/// A position at the autopilot's boot time: metres and metres per second, NED.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NedSample {
    pub time_ns: u64,
    pub pos_m: DVec3,
    pub vel_mps: DVec3,
}

/// Tolerances of the pairing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalConfig {
    /// A global and a local sample pair when this close in time (the local one is moved by
    /// its velocity to the global one's instant: `a·Δt²/2` is 0.45 mm at 2.25 m/s² and 20 ms).
    pub pair_window_ns: u64,
    /// Pairs the mean runs over at most: then an exponential mean with this weight, so a slowly
    /// changing offset (two map projections drifting apart over kilometres) is followed.
    pub mean_pairs: u32,
    /// A residual this far from the offset restarts it (far above quantisation and noise).
    pub restart_m: f64,
    /// The local stream is in use while its newest sample is at most this old (boot time).
    pub active_ns: u64,
    /// Horizon and tolerance of the check against the last accepted global position.
    pub check_horizon_ns: u64,
    pub check_tolerance_m: f64,
}

impl Default for LocalConfig {
    fn default() -> Self {
        LocalConfig {
            pair_window_ns: 20_000_000,
            mean_pairs: 64,
            restart_m: 0.5,
            active_ns: 500_000_000,
            check_horizon_ns: 1_000_000_000,
            check_tolerance_m: 2.0,
        }
    }
}

/// What a local sample gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LocalOutcome {
    /// The sample in the link's frame.
    Position(NedSample),
    /// No offset yet (no global sample paired with a local one).
    Unpaired,
    /// Not where the last accepted global position says it can be: dropped, the offset
    /// restarts from the next pair.
    Disagrees { by_m: f64 },
    /// Not finite.
    Invalid,
}

/// The offset from the autopilot's local frame to the link's, and the samples it pairs.
#[derive(Clone, Debug, Default)]
pub struct LocalTrack {
    cfg: LocalConfig,
    last_local: Option<NedSample>,
    /// The newest accepted global sample (link frame), and whether it is paired yet.
    last_global: Option<NedSample>,
    global_paired: bool,
    offset_m: Option<DVec3>,
    pairs: u32,
    /// Times the offset restarted after a jump (not its first estimate).
    pub restarts: u64,
}

impl LocalTrack {
    pub fn new(cfg: LocalConfig) -> LocalTrack {
        LocalTrack {
            cfg,
            ..LocalTrack::default()
        }
    }

    /// Forget the samples and the offset (a reboot, the link's frame moved, a re-anchored gate).
    pub fn reset(&mut self) {
        *self = LocalTrack {
            cfg: self.cfg,
            restarts: self.restarts,
            ..LocalTrack::default()
        };
    }

    /// The offset in use (link frame minus the autopilot's), metres.
    pub fn offset_m(&self) -> Option<DVec3> {
        self.offset_m
    }

    /// Whether positions come from the local stream at boot time `t_ns`: an offset is known
    /// and a local sample came within `active_ns` (otherwise the global stream serves).
    pub fn active(&self, t_ns: u64) -> bool {
        self.offset_m.is_some()
            && self
                .last_local
                .is_some_and(|l| t_ns.abs_diff(l.time_ns) <= self.cfg.active_ns)
    }

    /// An accepted global position, in the link's frame.
    pub fn on_global(&mut self, g: NedSample) {
        self.last_global = Some(g);
        self.global_paired = false;
        if let Some(l) = self.last_local {
            self.pair(g, l);
        }
    }

    /// A local position, in the autopilot's frame.
    pub fn on_local(&mut self, l: NedSample) -> LocalOutcome {
        if !(l.pos_m.is_finite() && l.vel_mps.is_finite()) {
            return LocalOutcome::Invalid;
        }
        self.last_local = Some(l);
        if let Some(g) = self.last_global.filter(|_| !self.global_paired) {
            self.pair(g, l);
        }
        let Some(off) = self.offset_m else {
            return LocalOutcome::Unpaired;
        };
        let s = NedSample {
            pos_m: l.pos_m + off,
            ..l
        };
        if let Some(g) = self.last_global {
            let dt_ns = s.time_ns as i128 - g.time_ns as i128;
            if dt_ns.unsigned_abs() <= self.cfg.check_horizon_ns as u128 {
                let expected = g.pos_m + g.vel_mps * (dt_ns as f64 * 1e-9);
                let by_m = (s.pos_m - expected).length();
                if by_m.is_nan() || by_m > self.cfg.check_tolerance_m {
                    self.offset_m = None;
                    self.pairs = 0;
                    return LocalOutcome::Disagrees { by_m };
                }
            }
        }
        LocalOutcome::Position(s)
    }

    fn pair(&mut self, g: NedSample, l: NedSample) {
        let dt_ns = g.time_ns as i128 - l.time_ns as i128;
        if dt_ns.unsigned_abs() > self.cfg.pair_window_ns as u128 {
            return;
        }
        self.global_paired = true;
        let residual = g.pos_m - (l.pos_m + l.vel_mps * (dt_ns as f64 * 1e-9));
        if !residual.is_finite() {
            return;
        }
        match self.offset_m {
            Some(off) if (residual - off).length() <= self.cfg.restart_m => {
                self.pairs = (self.pairs + 1).min(self.cfg.mean_pairs.max(1));
                self.offset_m = Some(off + (residual - off) / self.pairs as f64);
            }
            prev => {
                self.restarts += prev.is_some() as u64;
                self.offset_m = Some(residual);
                self.pairs = 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(t_ms: u64, north_m: f64, vel_n: f64) -> NedSample {
        NedSample {
            time_ns: t_ms * 1_000_000,
            pos_m: DVec3::new(north_m, 0.0, -100.0),
            vel_mps: DVec3::new(vel_n, 0.0, 0.0),
        }
    }

    /// 1e-7° of latitude in metres, as GLOBAL_POSITION_INT rounds it.
    fn quantised(north_m: f64) -> f64 {
        let q = 0.011_131_9;
        (north_m / q).round() * q
    }

    #[test]
    fn the_offset_averages_the_global_quantisation_away() {
        // The autopilot's frame is 3.2 m north of the link's; 10 m/s north, global and local
        // at 10 Hz, 1 ms apart (firmware-sim's phases).
        let mut t = LocalTrack::new(LocalConfig::default());
        let true_off = 3.2;
        let mut worst_late = 0.0f64;
        for k in 0..300u64 {
            let tg = 100 * k + 5;
            let north = 10.0 * tg as f64 * 1e-3;
            t.on_global(at(tg, quantised(north + true_off), 10.0));
            let tl = tg + 1;
            let north_l = 10.0 * tl as f64 * 1e-3;
            let out = t.on_local(at(tl, north_l, 10.0));
            let LocalOutcome::Position(s) = out else {
                panic!("sample {k}: {out:?}");
            };
            let err = (s.pos_m.x - (north_l + true_off)).abs();
            // The first pair carries one quantisation error (≤ 5.6 mm); the mean shrinks it.
            assert!(err <= 0.0056, "sample {k}: {err}");
            if k >= 100 {
                worst_late = worst_late.max(err);
            }
        }
        assert!(worst_late < 0.0015, "after 100 pairs: {worst_late} m");
        assert!(t.active(29_906_000_000));
        assert_eq!(t.restarts, 0);
    }

    #[test]
    fn a_jump_of_the_local_frame_restarts_the_offset() {
        let mut t = LocalTrack::new(LocalConfig::default());
        for k in 0..10u64 {
            t.on_global(at(100 * k, 1.0, 0.0));
            assert!(matches!(
                t.on_local(at(100 * k + 1, 0.0, 0.0)),
                LocalOutcome::Position(_)
            ));
        }
        assert!((t.offset_m().unwrap().x - 1.0).abs() < 1e-12);
        // The autopilot moves its local frame by 1.5 m: the pair at that instant restarts the
        // offset, and the sample is right at once.
        t.on_global(at(1000, 1.0, 0.0));
        let o = t.on_local(at(1001, -1.5, 0.0));
        assert!(matches!(o, LocalOutcome::Position(s) if (s.pos_m.x - 1.0).abs() < 1e-12));
        assert_eq!(t.restarts, 1);
        // A 5 m jump is beyond the check: dropped until the next pair.
        t.on_global(at(1100, 1.0, 0.0));
        let o = t.on_local(at(1150, -6.5, 0.0));
        assert!(
            matches!(o, LocalOutcome::Disagrees { by_m } if (by_m - 5.0).abs() < 1e-9),
            "{o:?}"
        );
        assert!(!t.active(1_150_000_000));
        t.on_global(at(1200, 1.0, 0.0));
        let o = t.on_local(at(1201, -6.5, 0.0));
        assert!(
            matches!(o, LocalOutcome::Position(s) if (s.pos_m.x - 1.0).abs() < 1e-12),
            "{o:?}"
        );
    }

    #[test]
    fn samples_far_apart_in_time_do_not_pair_and_a_stale_stream_is_not_used() {
        let mut t = LocalTrack::new(LocalConfig::default());
        t.on_global(at(0, 1.0, 0.0));
        assert_eq!(t.on_local(at(50, 0.0, 0.0)), LocalOutcome::Unpaired);
        assert!(!t.active(50_000_000));
        t.on_global(at(60, 1.0, 0.0));
        assert!(t.active(60_000_000));
        assert!(!t.active(560_000_001));
        assert_eq!(
            t.on_local(at(50, f64::NAN, 0.0)),
            LocalOutcome::Invalid,
            "a NaN is refused before it is kept"
        );
        t.reset();
        assert!(t.offset_m().is_none() && !t.active(60_000_000));
    }
}
