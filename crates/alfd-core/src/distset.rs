//! Setting the autopilot's own distance trigger online (MAV_CMD_DO_SET_CAM_TRIGG_DIST):
//! when to send a new distance. A shorter spacing is sent at once (the
//! autopilot would otherwise capture too far apart); a longer one only past a
//! hysteresis, so estimator noise does not flood the link; sends are rate
//! limited and repeated until acknowledged. Pure: time is an argument.

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceSetterParams {
    /// A longer distance is sent only when it exceeds the one in force by this fraction.
    pub hysteresis: f64,
    /// A shorter distance is sent when it is below the one in force by this fraction.
    pub shrink_tolerance: f64,
    /// At most one command per this many seconds (the first is never held).
    pub min_interval_s: f64,
    /// An unacknowledged command is sent again after this long.
    pub ack_timeout_s: f64,
}

impl Default for DistanceSetterParams {
    fn default() -> Self {
        DistanceSetterParams {
            hysteresis: 0.15,
            shrink_tolerance: 0.01,
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
        let reference = self.pending.map(|(d, _)| d).or(self.in_force_m);
        let due = match reference {
            None => true,
            Some(r) => {
                wanted_m < r * (1.0 - self.params.shrink_tolerance)
                    || wanted_m > r * (1.0 + self.params.hysteresis)
            }
        };
        let resend = match self.pending {
            Some((_, at)) => now_s - at >= self.params.ack_timeout_s,
            None => false,
        };
        if !due && !resend {
            return None;
        }
        if let Some(last) = self.last_sent_s {
            if now_s - last < self.params.min_interval_s {
                return None;
            }
        }
        // A resend carries the newest wish, not the stale one.
        let d = if due {
            wanted_m
        } else {
            self.pending.map_or(wanted_m, |(d, _)| d)
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

    #[test]
    fn the_first_distance_goes_at_once_and_holds_once_acknowledged() {
        let mut s = setter();
        assert_eq!(s.update(0.0, 5.0), Some(5.0));
        s.on_ack(true);
        assert_eq!(s.in_force_m(), Some(5.0));
        // Noise within the hysteresis sends nothing.
        for (k, d) in [5.2, 4.98, 5.6, 5.05].into_iter().enumerate() {
            assert_eq!(s.update(1.0 + k as f64, d), None, "{d}");
        }
        assert_eq!(s.sent, 1);
    }

    #[test]
    fn shorter_is_sent_promptly_longer_only_past_the_hysteresis() {
        let mut s = setter();
        s.update(0.0, 5.0);
        s.on_ack(true);
        assert_eq!(s.update(1.0, 4.0), Some(4.0));
        s.on_ack(true);
        assert_eq!(s.update(2.0, 4.5), None);
        assert_eq!(s.update(3.0, 4.7), Some(4.7));
    }

    #[test]
    fn the_rate_limit_holds_then_the_newest_wish_goes() {
        let mut s = setter();
        s.update(0.0, 5.0);
        s.on_ack(true);
        assert_eq!(s.update(0.1, 3.0), None, "0.1 s after the last send");
        assert_eq!(s.update(0.3, 2.0), None);
        assert_eq!(s.update(0.6, 2.5), Some(2.5));
    }

    #[test]
    fn an_unacknowledged_command_is_repeated_and_a_refusal_keeps_the_old_distance() {
        let mut s = setter();
        assert_eq!(s.update(0.0, 5.0), Some(5.0));
        assert_eq!(s.update(0.5, 5.0), None, "waiting for the ack");
        assert_eq!(s.update(1.0, 5.0), Some(5.0), "resent after the timeout");
        s.on_ack(false);
        assert_eq!(s.in_force_m(), None);
        assert_eq!(s.refused, 1);
        assert_eq!(s.update(2.0, 5.0), Some(5.0));
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
