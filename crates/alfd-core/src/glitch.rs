//! GPS glitch gate: a position is accepted only if it is where the last accepted one, moved by
//! the reported velocities, says it can be. A jump is flagged and not followed (the reference is
//! dead-reckoned through it); if it persists past `reanchor_after_ns`, the gate re-anchors to
//! it, loudly (`Reanchored`).

use glam::DVec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlitchConfig {
    /// Allowed disagreement at zero elapsed time (GPS noise, quantisation), metres.
    pub tolerance_m: f64,
    /// Plus half this acceleration times the elapsed time squared (manoeuvres), m/s².
    pub accel_max_mps2: f64,
    /// Speeds above this are not believed, m/s.
    pub speed_max_mps: f64,
    /// A jump that persists this long is followed (flagged as `Reanchored`).
    pub reanchor_after_ns: u64,
}

impl Default for GlitchConfig {
    fn default() -> Self {
        Self {
            tolerance_m: 2.0,
            accel_max_mps2: 6.0,
            speed_max_mps: 60.0,
            reanchor_after_ns: 10_000_000_000,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    Accept,
    /// Rejected: `jump_m` away from where it should be.
    Glitch {
        jump_m: f64,
    },
    /// Accepted after a persistent jump; consumers must know the track stepped.
    Reanchored {
        jump_m: f64,
    },
}

#[derive(Clone, Debug, Default)]
pub struct GlitchGate {
    cfg: GlitchConfig,
    last: Option<(u64, DVec3, DVec3)>,
    glitch_since_ns: Option<u64>,
}

impl GlitchGate {
    pub fn new(cfg: GlitchConfig) -> Self {
        Self {
            cfg,
            last: None,
            glitch_since_ns: None,
        }
    }

    /// Forget the track (after a reboot, when boot times restart).
    pub fn reset(&mut self) {
        self.last = None;
        self.glitch_since_ns = None;
    }

    /// True while positions are being rejected.
    pub fn active(&self) -> bool {
        self.glitch_since_ns.is_some()
    }

    pub fn check(&mut self, time_ns: u64, pos: DVec3, vel: DVec3) -> Verdict {
        if !pos.is_finite() || !vel.is_finite() || vel.length() > self.cfg.speed_max_mps {
            return Verdict::Glitch {
                jump_m: f64::INFINITY,
            };
        }
        let Some((t0, p0, v0)) = self.last else {
            self.last = Some((time_ns, pos, vel));
            return Verdict::Accept;
        };
        let dt = time_ns.saturating_sub(t0) as f64 * 1e-9;
        let predicted = p0 + (v0 + vel) * 0.5 * dt;
        let jump_m = (pos - predicted).length();
        let tol = self.cfg.tolerance_m + 0.5 * self.cfg.accel_max_mps2 * dt * dt;
        if jump_m <= tol {
            self.last = Some((time_ns, pos, vel));
            self.glitch_since_ns = None;
            return Verdict::Accept;
        }
        let since = *self.glitch_since_ns.get_or_insert(time_ns);
        if time_ns.saturating_sub(since) >= self.cfg.reanchor_after_ns {
            self.last = Some((time_ns, pos, vel));
            self.glitch_since_ns = None;
            return Verdict::Reanchored { jump_m };
        }
        // Dead-reckon through the glitch with the reported velocities, so the tolerance does not
        // grow with the glitch's length (which would end up accepting it silently).
        self.last = Some((time_ns, predicted, vel));
        Verdict::Glitch { jump_m }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_jump_is_flagged_then_followed_only_when_it_persists() {
        let mut g = GlitchGate::new(GlitchConfig::default());
        let v = DVec3::new(10.0, 0.0, 0.0);
        let at = |k: u64| (k * 100_000_000, v * (k as f64 * 0.1));
        for k in 0..10 {
            let (t, p) = at(k);
            assert_eq!(g.check(t, p, v), Verdict::Accept);
        }
        let (t, p) = at(10);
        assert!(matches!(
            g.check(t, p + DVec3::new(0.0, 30.0, 0.0), v),
            Verdict::Glitch { .. }
        ));
        assert!(g.active());
        let (t, p) = at(11);
        assert_eq!(g.check(t, p, v), Verdict::Accept);
        assert!(!g.active());
        let mut reanchored = false;
        for k in 12..=112 {
            let (t, p) = at(k);
            reanchored |= matches!(
                g.check(t, p + DVec3::new(0.0, 30.0, 0.0), v),
                Verdict::Reanchored { .. }
            );
        }
        assert!(reanchored);
    }
}
