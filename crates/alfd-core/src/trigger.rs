//! The capture trigger: a pure state machine fed one opportunity (a frame, or a
//! command slot) at a time. A capture is due when the distance since the last
//! capture would exceed the tightest permissible spacing seen since it before
//! the next opportunity: it captures early, never knowingly late. The rate
//! limit can hold it back; the interval is then marked under-sampled, never
//! hidden.

/// Relative slack of the rate limit (see [`Trigger::update`]).
pub const RATE_TOLERANCE: f64 = 0.02;

/// Trigger settings, validated by the caller's config.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriggerParams {
    /// Camera and storage limit, captures per second.
    pub rate_max_hz: f64,
    /// Spacing used while the estimator gives no estimate (depth lost, sky,
    /// pitch out of range): conservative, never the last good value forever.
    pub fallback_spacing_m: f64,
    /// Capture this fraction before the spacing would be reached (0 = at it).
    pub margin: f64,
    /// Also measure each frame against the last capture (`core::closedloop`)
    /// and trigger on the tighter of the open and the closed loop.
    pub closed_loop: bool,
}

impl Default for TriggerParams {
    fn default() -> Self {
        TriggerParams {
            rate_max_hz: 30.0,
            fallback_spacing_m: 1.0,
            margin: 0.0,
            closed_loop: false,
        }
    }
}

/// One chance to capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Opportunity {
    /// Time of validity, seconds on the daemon's clock.
    pub time_s: f64,
    /// Distance travelled since start, metres (monotone).
    pub odometer_m: f64,
    /// Distance to the next opportunity, metres (speed × frame period).
    pub next_step_m: f64,
    /// The permissible spacing now; `None` when the frame gave no estimate.
    pub spacing_m: Option<f64>,
    /// False while the pose is stale: no capture may be logged without a pose.
    pub pose_fresh: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capture {
    /// Distance since the previous capture (`None` for the first).
    pub distance_since_last_m: Option<f64>,
    /// The tightest permissible spacing in force over the interval.
    pub spacing_m: f64,
    /// The interval is longer than `spacing_m`: the rate limit, a sudden drop
    /// of the spacing or too coarse opportunities made it late.
    pub undersampled: bool,
    /// Held back by the rate limit at some point in the interval.
    pub rate_limited: bool,
    /// The fallback spacing was in force at some point in the interval.
    pub fallback: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Decision {
    Capture(Capture),
    Wait,
    /// The pose is stale: nothing is captured until it is fresh again.
    Suspended,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Trigger {
    params: TriggerParams,
    last: Option<(f64, f64)>,
    tightest_m: f64,
    rate_limited: bool,
    fallback: bool,
    /// The spacing at the previous opportunity, for the trend.
    previous_m: Option<f64>,
}

impl Trigger {
    pub fn new(params: TriggerParams) -> Self {
        Trigger {
            params,
            last: None,
            tightest_m: f64::INFINITY,
            rate_limited: false,
            fallback: false,
            previous_m: None,
        }
    }

    /// Speed advice (DESIGN §1): the fastest ground speed at which the rate
    /// limit still meets `spacing_m`.
    pub fn speed_advice_mps(&self, spacing_m: f64) -> f64 {
        spacing_m * self.params.rate_max_hz
    }

    pub fn update(&mut self, o: &Opportunity) -> Decision {
        if !o.pose_fresh || !o.odometer_m.is_finite() || !o.time_s.is_finite() {
            return Decision::Suspended;
        }
        let spacing = match o.spacing_m {
            Some(s) if s.is_finite() && s > 0.0 => s,
            _ => {
                self.fallback = true;
                self.params.fallback_spacing_m
            }
        };
        self.tightest_m = self.tightest_m.min(spacing);
        // A falling spacing keeps falling until the next opportunity: expect
        // it one step further down (linearly, at most halving), so the capture
        // comes before the interval outgrows it, not one frame after.
        let expected_next = match self.previous_m {
            Some(prev) if spacing < prev => (2.0 * spacing - prev).max(0.5 * spacing),
            _ => spacing,
        };
        self.previous_m = Some(spacing);
        let Some((t_last, odo_last)) = self.last else {
            return Decision::Capture(self.fire(o, None));
        };
        let travelled = (o.odometer_m - odo_last).max(0.0);
        let next = travelled + o.next_step_m.max(0.0);
        // The same relative tolerance as the under-sampled flag, so rounding in
        // the odometer neither fires a frame early nor flags an exact interval.
        let limit = self.tightest_m.min(expected_next) * (1.0 - self.params.margin) * (1.0 + 1e-9);
        if next <= limit {
            return Decision::Wait;
        }
        // Due. The rate limit may hold it back. Frame clocks are rounded to
        // the nanosecond and jitter by a fraction of a millisecond: a frame
        // up to 2 % early against the limit still counts as at the rate.
        let min_period = 1.0 / self.params.rate_max_hz;
        if o.time_s - t_last < min_period * (1.0 - RATE_TOLERANCE) {
            self.rate_limited = true;
            return Decision::Wait;
        }
        Decision::Capture(self.fire(o, Some(travelled)))
    }

    /// The last capture was in fact `shift_m` further along than the odometer said when it
    /// fired (its position located once a later sample came, against the extrapolated one the
    /// odometer read): the interval since it is measured from there.
    pub fn shift_reference(&mut self, shift_m: f64) {
        if let Some((_, odo)) = self.last.as_mut() {
            if shift_m.is_finite() {
                *odo += shift_m;
            }
        }
    }

    fn fire(&mut self, o: &Opportunity, travelled: Option<f64>) -> Capture {
        let spacing = self.tightest_m;
        let c = Capture {
            distance_since_last_m: travelled,
            spacing_m: spacing,
            undersampled: undersampled(travelled, spacing),
            rate_limited: self.rate_limited,
            fallback: self.fallback,
        };
        self.last = Some((o.time_s, o.odometer_m));
        // The next interval starts with what is in force now.
        self.tightest_m = match o.spacing_m {
            Some(s) if s.is_finite() && s > 0.0 => s,
            _ => self.params.fallback_spacing_m,
        };
        self.rate_limited = false;
        self.fallback = o.spacing_m.is_none();
        c
    }
}

/// Whether an interval of `distance_since_last_m` (`None`: the first capture) outgrew the
/// tightest spacing in force over it, with the relative tolerance of the odometer's rounding.
/// The trigger's own rule, for captures another trigger fired (the autopilot's).
pub fn undersampled(distance_since_last_m: Option<f64>, spacing_m: f64) -> bool {
    distance_since_last_m.is_some_and(|d| d > spacing_m * (1.0 + 1e-9))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn opp(t: f64, x: f64, step: f64, s: Option<f64>) -> Opportunity {
        Opportunity {
            time_s: t,
            odometer_m: x,
            next_step_m: step,
            spacing_m: s,
            pose_fresh: true,
        }
    }

    /// Flies at `speed` with frames every `dt`, spacing given by `b(x)`.
    fn fly(
        p: TriggerParams,
        speed: f64,
        dt: f64,
        len: f64,
        b: impl Fn(f64) -> f64,
    ) -> Vec<(f64, Capture)> {
        let mut t = Trigger::new(p);
        let mut out = Vec::new();
        let mut k = 0.0;
        while k * dt * speed <= len {
            let x = k * dt * speed;
            if let Decision::Capture(c) = t.update(&opp(k * dt, x, speed * dt, Some(b(x)))) {
                out.push((x, c));
            }
            k += 1.0;
        }
        out
    }

    #[test]
    fn constant_spacing_captures_at_the_last_frame_before_it() {
        // 10 m/s, 100 fps: frames every 0.1 m; spacing 1 m. A capture is due at
        // the frame from which the next frame would be past 1 m: x = 0.9 after
        // the first one at 0, then every 0.9 m... but 0.9 + 0.1 = 1.0 is not
        // beyond 1.0, so the capture comes at 1.0 exactly: every 1.0 m.
        let caps = fly(TriggerParams::default(), 10.0, 0.01, 5.0, |_| 1.0);
        let xs: Vec<f64> = caps.iter().map(|c| (c.0 * 1e6).round() / 1e6).collect();
        assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
        assert!(caps.iter().all(|c| !c.1.undersampled));
    }

    #[test]
    fn a_drop_in_spacing_is_honoured_from_where_it_is_seen() {
        // Spacing 2 m until x = 3, then 0.5 m: the interval in progress is cut.
        let caps = fly(TriggerParams::default(), 10.0, 0.01, 4.0, |x| {
            if x < 3.0 {
                2.0
            } else {
                0.5
            }
        });
        let xs: Vec<f64> = caps.iter().map(|c| (c.0 * 1e6).round() / 1e6).collect();
        // 0, 2.0, then at 3.0 the distance since 2.0 is 1.0 > 0.5: captured at
        // once and flagged under-sampled (the drop came too late to avoid).
        assert_eq!(xs[..3], [0.0, 2.0, 3.0]);
        assert!(caps[2].1.undersampled);
        assert!(caps[3..].iter().all(|c| !c.1.undersampled));
    }

    #[test]
    fn rate_limit_holds_and_flags() {
        // Spacing 0.1 m at 10 m/s needs 100 captures/s; the limit is 30/s.
        let p = TriggerParams {
            rate_max_hz: 30.0,
            ..TriggerParams::default()
        };
        let caps = fly(p, 10.0, 0.01, 2.0, |_| 0.1);
        assert!(caps.len() <= 2 * 30 / 10 + 2, "{}", caps.len());
        assert!(caps[1..]
            .iter()
            .all(|c| c.1.undersampled && c.1.rate_limited));
        assert_eq!(Trigger::new(p).speed_advice_mps(0.1), 3.0);
    }

    #[test]
    fn a_steadily_falling_spacing_is_met_at_every_frame() {
        // Spacing falls 4.7 cm per 10 cm flown: without looking one step ahead
        // the frame that is due sees a spacing already smaller than the
        // distance flown.
        let caps = fly(TriggerParams::default(), 10.0, 0.01, 10.0, |x| {
            (3.03 - 0.47 * x).max(0.4)
        });
        assert!(caps.len() > 5);
        for w in caps.windows(2) {
            let d = w[1].0 - w[0].0;
            let tightest = (3.03 - 0.47 * w[1].0).max(0.4);
            assert!(
                d <= tightest * (1.0 + 1e-9),
                "{d} > {tightest} at {}",
                w[1].0
            );
            assert!(!w[1].1.undersampled);
        }
    }

    #[test]
    fn frames_at_exactly_the_rate_limit_are_not_held_back() {
        // 30 fps stamped to the nanosecond (33 333 333 ns, a hair under 1/30 s)
        // with the limit at 30/s and a spacing shorter than a frame step: every
        // frame captures, none is marked rate-limited.
        let p = TriggerParams {
            rate_max_hz: 30.0,
            ..TriggerParams::default()
        };
        let mut t = Trigger::new(p);
        let mut caps = 0;
        for k in 0..60u64 {
            let time_s = (k * 33_333_333) as f64 * 1e-9;
            let x = k as f64 * 0.333;
            match t.update(&opp(time_s, x, 0.333, Some(0.3))) {
                Decision::Capture(c) => {
                    caps += 1;
                    assert!(!c.rate_limited, "frame {k}");
                }
                d => panic!("frame {k}: {d:?}"),
            }
        }
        assert_eq!(caps, 60);
    }

    #[test]
    fn stale_pose_suspends_and_no_estimate_uses_the_fallback() {
        let mut t = Trigger::new(TriggerParams::default());
        let mut o = opp(0.0, 0.0, 0.1, Some(5.0));
        assert!(matches!(t.update(&o), Decision::Capture(_)));
        o = opp(1.0, 0.95, 0.1, None);
        o.pose_fresh = false;
        assert_eq!(t.update(&o), Decision::Suspended);
        o.pose_fresh = true;
        // Fallback 1 m: 0.95 + 0.1 > 1 → due, and the interval is marked.
        let Decision::Capture(c) = t.update(&o) else {
            panic!()
        };
        assert!(c.fallback && c.spacing_m == 1.0 && !c.undersampled);
    }

    proptest! {
        #[test]
        fn with_fine_frames_and_no_rate_limit_no_interval_is_late(
            b0 in 0.2f64..20.0, b1 in 0.2f64..20.0, switch in 0.0f64..100.0, speed in 1.0f64..20.0,
        ) {
            // Frames every 1 cm of travel and a slowly varying spacing (the
            // spacing changes only at `switch`, and rises, so no drop can make an
            // interval late): no interval may exceed the tightest spacing in it.
            let (lo, hi) = if b0 < b1 { (b0, b1) } else { (b1, b0) };
            let p = TriggerParams { rate_max_hz: 1e9, ..TriggerParams::default() };
            let caps = fly(p, speed, 0.01 / speed, 100.0, |x| if x < switch { lo } else { hi });
            let mut last = 0.0;
            for (x, c) in &caps[1..] {
                let d = x - last;
                prop_assert!(!c.undersampled);
                prop_assert!(d <= c.spacing_m + 1e-9);
                // Greedy: never more than one frame early.
                prop_assert!(d + 0.01 + 1e-9 > c.spacing_m);
                last = *x;
            }
        }
    }
}
