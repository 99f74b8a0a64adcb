//! Setting the autopilot's own distance trigger online (MAV_CMD_DO_SET_CAM_TRIGG_DIST):
//! when to send a new distance. The distance sent is the wished spacing
//! shortened by a margin, so estimator noise within the margin sends nothing.
//! A wish below the distance in force (or on its way) is sent at once, by any
//! amount and whatever the rate limit: the autopilot would otherwise capture
//! too far apart, and each such send lowers the distance by at least the
//! margin, so a falling spacing costs at most one command per estimate. A
//! longer one waits for a hysteresis and the rate limit, so noise does not
//! flood the link; unacknowledged commands are repeated. Pure: time is an
//! argument.

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceSetterParams {
    /// A longer distance is sent only when it exceeds the one in force by this fraction.
    pub hysteresis: f64,
    /// The distance sent is the wish shortened by this fraction (taken within
    /// `[0, 0.5]`; NaN: 0).
    pub margin: f64,
    /// At most one longer distance or repeat per this many seconds (the first
    /// and every shorter one are never held).
    pub min_interval_s: f64,
    /// An unacknowledged command is sent again after this long.
    pub ack_timeout_s: f64,
}

impl Default for DistanceSetterParams {
    fn default() -> Self {
        DistanceSetterParams {
            hysteresis: 0.15,
            // Meant to sit above the spacing's jitter from frame to frame on
            // noisy Z16, so a steady spacing holds one distance: set before
            // any flight was judged with it, and that jitter not measured.
            margin: 0.03,
            min_interval_s: 0.5,
            ack_timeout_s: 1.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct DistanceSetter {
    params: DistanceSetterParams,
    /// The distance the autopilot acknowledged.
    in_force_m: Option<f64>,
    /// Sent, not yet acknowledged: (distance, when).
    pending: Option<(f64, f64)>,
    last_sent_s: Option<f64>,
    pub sent: u64,
    pub acked: u64,
    pub refused: u64,
}

impl DistanceSetter {
    pub fn new(params: DistanceSetterParams) -> Self {
        DistanceSetter {
            params,
            in_force_m: None,
            pending: None,
            last_sent_s: None,
            sent: 0,
            acked: 0,
            refused: 0,
        }
    }

    /// The distance the autopilot has acknowledged.
    pub fn in_force_m(&self) -> Option<f64> {
        self.in_force_m
    }

    /// Feed the spacing wanted now; returns a distance to send, if one is due.
    pub fn update(&mut self, now_s: f64, wanted_m: f64) -> Option<f64> {
        if !(wanted_m.is_finite() && wanted_m > 0.0 && now_s.is_finite()) {
            return None;
        }
        let margin = if self.params.margin.is_finite() {
            self.params.margin.clamp(0.0, 0.5)
        } else {
            0.0
        };
        let d = wanted_m * (1.0 - margin);
        let reference = self.pending.map(|(d, _)| d).or(self.in_force_m);
        // Below what the autopilot holds (or will): too far apart from now on.
        let shorter = reference.is_none_or(|r| wanted_m < r);
        let longer = reference.is_some_and(|r| d > r * (1.0 + self.params.hysteresis));
        let resend = match self.pending {
            Some((_, at)) => now_s - at >= self.params.ack_timeout_s,
            None => false,
        };
        if !(shorter || longer || resend) {
            return None;
        }
        if !shorter {
            if let Some(last) = self.last_sent_s {
                if now_s - last < self.params.min_interval_s {
                    return None;
                }
            }
        }
        // A resend carries the newest wish, not the stale one.
        let d = if shorter || longer {
            d
        } else {
            self.pending.map_or(d, |(d, _)| d)
        };
        self.pending = Some((d, now_s));
        self.last_sent_s = Some(now_s);
        self.sent += 1;
        Some(d)
    }

    /// The autopilot's answer to the last command sent.
    pub fn on_ack(&mut self, accepted: bool) {
        let Some((d, _)) = self.pending.take() else {
            return;
        };
        if accepted {
            self.in_force_m = Some(d);
            self.acked += 1;
        } else {
            self.refused += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setter() -> DistanceSetter {
        DistanceSetter::new(DistanceSetterParams::default())
    }

    /// The distance sent for a wish: 3 % shorter.
    fn sent(wanted_m: f64) -> Option<f64> {
        Some(wanted_m * 0.97)
    }

    #[test]
    fn the_first_distance_goes_at_once_and_holds_once_acknowledged() {
        let mut s = setter();
        assert_eq!(s.update(0.0, 5.0), sent(5.0));
        s.on_ack(true);
        assert_eq!(s.in_force_m(), sent(5.0));
        // Noise within the margin and the hysteresis sends nothing.
        for (k, d) in [5.2, 4.9, 5.6, 5.05].into_iter().enumerate() {
            assert_eq!(s.update(1.0 + k as f64, d), None, "{d}");
        }
        assert_eq!(s.sent, 1);
    }

    #[test]
    fn shorter_is_sent_by_any_amount_longer_only_past_the_hysteresis() {
        let mut s = setter();
        s.update(0.0, 5.0);
        s.on_ack(true);
        // 4.85 m in force: a wish 0.1 % below it is sent (no dead band past
        // the promise).
        assert_eq!(s.update(1.0, 4.845), sent(4.845));
        s.on_ack(true);
        assert_eq!(s.update(2.0, 5.5), None, "within the hysteresis");
        assert_eq!(s.update(3.0, 5.8), sent(5.8));
    }

    #[test]
    fn a_falling_spacing_is_followed_at_every_estimate_whatever_the_rate_limit() {
        let mut s = setter();
        s.update(0.0, 1.0);
        s.on_ack(true);
        // 30 estimates a second, the spacing falling 2 % each, no ack yet for
        // most: each wish below the last distance sent goes out.
        let mut wish = 1.0;
        let mut sends = 0;
        for k in 1..=30 {
            wish *= 0.98;
            let t = k as f64 / 30.0;
            if let Some(d) = s.update(t, wish) {
                assert_eq!(d, wish * 0.97);
                sends += 1;
            }
            // Every wish at or above what the autopilot is asked to hold.
            let asked = s.pending.map(|p| p.0).or(s.in_force_m()).unwrap();
            assert!(asked <= wish, "{asked} asked for a wish of {wish}");
        }
        // Each send lowers the distance by the margin: not one per estimate.
        assert!((10..=16).contains(&sends), "{sends} sends");
    }

    #[test]
    fn the_rate_limit_holds_longer_distances_then_the_newest_wish_goes() {
        let mut s = setter();
        s.update(0.0, 2.0);
        s.on_ack(true);
        assert_eq!(s.update(0.1, 3.0), None, "0.1 s after the last send");
        assert_eq!(s.update(0.3, 4.0), None);
        assert_eq!(s.update(0.6, 3.5), sent(3.5));
    }

    #[test]
    fn an_unacknowledged_command_is_repeated_and_a_refusal_keeps_the_old_distance() {
        let mut s = setter();
        assert_eq!(s.update(0.0, 5.0), sent(5.0));
        assert_eq!(s.update(0.5, 5.0), None, "waiting for the ack");
        assert_eq!(s.update(1.0, 5.0), sent(5.0), "resent after the timeout");
        s.on_ack(false);
        assert_eq!(s.in_force_m(), None);
        assert_eq!(s.refused, 1);
        assert_eq!(s.update(2.0, 5.0), sent(5.0));
    }

    #[test]
    fn bad_wishes_send_nothing() {
        let mut s = setter();
        for d in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            assert_eq!(s.update(0.0, d), None);
        }
        assert_eq!(s.update(f64::NAN, 3.0), None);
    }
}
