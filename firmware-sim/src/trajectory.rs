//! The flown survey as an analytic function of time: rest-to-rest segments with trapezoidal
//! speed profiles (acceleration-limited) through a closed loop of waypoints, plus a smooth
//! wind-like wander, so the true pose at any instant is exact. Optionally a prelude: time on the
//! ground, then a vertical climb to the survey altitude, before the survey starts.

use crate::config::{Pattern, Survey};
use std::f64::consts::{PI, TAU};

const G: f64 = 9.806_65;

/// The true state at an instant, in the local NED frame around the survey origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct State {
    pub pos_ned_m: [f64; 3],
    pub vel_ned_mps: [f64; 3],
    /// Roll, pitch, yaw (rad), body to NED, ZYX order.
    pub rpy_rad: [f64; 3],
    /// Body rates (rad/s).
    pub rates_rps: [f64; 3],
    /// Distance flown along the survey path (wander excluded), m.
    pub path_m: f64,
}

#[derive(Clone, Debug)]
struct Seg {
    start: [f64; 2],
    dir: [f64; 2],
    len: f64,
    t0: f64,
    dur: f64,
    t_acc: f64,
    v_peak: f64,
    s0: f64,
}

#[derive(Clone, Debug)]
pub struct Trajectory {
    segs: Vec<Seg>,
    period_s: f64,
    loop_m: f64,
    accel: f64,
    altitude_m: f64,
    wind_m: f64,
    wind_rad: f64,
    phases: [f64; 6],
    ground_s: f64,
    climb_mps: f64,
}

impl Trajectory {
    pub fn new(s: &Survey, seed: u64) -> Self {
        let h = s.heading_deg.to_radians();
        let (along, across) = ([h.cos(), h.sin()], [-h.sin(), h.cos()]);
        let pt = |a: f64, c: f64| [along[0] * a + across[0] * c, along[1] * a + across[1] * c];
        let mut wps = vec![pt(0.0, 0.0), pt(s.length_m, 0.0)];
        if s.pattern == Pattern::Lawnmower {
            wps.clear();
            for lane in 0..s.lanes {
                let c = lane as f64 * s.lane_spacing_m;
                let (a0, a1) = if lane % 2 == 0 {
                    (0.0, s.length_m)
                } else {
                    (s.length_m, 0.0)
                };
                wps.push(pt(a0, c));
                wps.push(pt(a1, c));
            }
        }
        let mut segs = Vec::new();
        let (mut t0, mut s0) = (0.0, 0.0);
        for k in 0..wps.len() {
            let (a, b) = (wps[k], wps[(k + 1) % wps.len()]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            if len < 1e-9 {
                continue;
            }
            let (v, acc) = (s.speed_mps, s.accel_mps2);
            let (t_acc, v_peak, dur) = if v * v / acc >= len {
                let vp = (len * acc).sqrt();
                (vp / acc, vp, 2.0 * vp / acc)
            } else {
                (v / acc, v, 2.0 * v / acc + (len - v * v / acc) / v)
            };
            let dir = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
            segs.push(Seg {
                start: a,
                dir,
                len,
                t0,
                dur,
                t_acc,
                v_peak,
                s0,
            });
            t0 += dur;
            s0 += len;
        }
        let mut x = seed ^ 0x9e37_79b9_7f4a_7c15;
        let phases = [0; 6].map(|_| {
            x = x
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (x >> 11) as f64 / (1u64 << 53) as f64 * TAU
        });
        Self {
            segs,
            period_s: t0,
            loop_m: s0,
            accel: s.accel_mps2,
            altitude_m: s.altitude_m,
            wind_m: s.wind_m,
            wind_rad: s.wind_deg.to_radians(),
            phases,
            ground_s: 0.0,
            climb_mps: 1.0,
        }
    }

    /// Start on the ground at the survey's first point for `ground_s`, then climb vertically at
    /// `climb_mps` to the survey altitude; the survey follows.
    pub fn with_prelude(mut self, ground_s: f64, climb_mps: f64) -> Self {
        self.ground_s = ground_s.max(0.0);
        self.climb_mps = climb_mps;
        self
    }

    /// When the climb ends (0 without a prelude).
    pub fn takeoff_done_s(&self) -> f64 {
        if self.ground_s > 0.0 {
            self.ground_s + self.altitude_m / self.climb_mps
        } else {
            0.0
        }
    }

    /// When the take-off starts (0 without a prelude).
    pub fn ground_s(&self) -> f64 {
        self.ground_s
    }

    /// Distance along the path, speed and acceleration along it, and the segment, at `t` s.
    fn along(&self, t: f64) -> (f64, f64, f64, &Seg, u64) {
        let laps = (t / self.period_s).floor();
        let tl = t - laps * self.period_s;
        let i = self.segs.partition_point(|g| g.t0 <= tl).saturating_sub(1);
        let g = &self.segs[i];
        let tau = (tl - g.t0).clamp(0.0, g.dur);
        let a = self.accel;
        let (s, v, acc) = if tau < g.t_acc {
            (0.5 * a * tau * tau, a * tau, a)
        } else if tau <= g.dur - g.t_acc {
            (
                0.5 * g.v_peak * g.t_acc + g.v_peak * (tau - g.t_acc),
                g.v_peak,
                0.0,
            )
        } else {
            let r = g.dur - tau;
            (g.len - 0.5 * a * r * r, a * r, -a)
        };
        (s, v, acc, g, laps as u64)
    }

    fn wander(&self, t: f64, k: usize, amp: f64) -> (f64, f64) {
        let (w1, w2) = (
            TAU * (0.11 + 0.03 * k as f64),
            TAU * (0.29 + 0.05 * k as f64),
        );
        let (p1, p2) = (self.phases[k], self.phases[(k + 3) % 6]);
        let x = amp * (0.6 * (w1 * t + p1).sin() + 0.4 * (w2 * t + p2).sin());
        let dx = amp * (0.6 * w1 * (w1 * t + p1).cos() + 0.4 * w2 * (w2 * t + p2).cos());
        (x, dx)
    }

    fn yaw_at(&self, t: f64) -> f64 {
        let (_, _, _, g, _) = self.along(t);
        let i = self
            .segs
            .iter()
            .position(|s| std::ptr::eq(s, g))
            .unwrap_or(0);
        let prev = &self.segs[(i + self.segs.len() - 1) % self.segs.len()];
        let (y0, y1) = (prev.dir[1].atan2(prev.dir[0]), g.dir[1].atan2(g.dir[0]));
        let laps = (t / self.period_s).floor();
        let tau = (t - laps * self.period_s - g.t0).clamp(0.0, g.dur);
        let u = (tau / g.t_acc.max(1e-9)).min(1.0);
        let smooth = u * u * (3.0 - 2.0 * u);
        let mut d = (y1 - y0) % TAU;
        if d > PI {
            d -= TAU;
        } else if d < -PI {
            d += TAU;
        }
        y0 + d * smooth
    }

    /// Position along the path (wander excluded), north and east.
    fn path_pos(&self, t: f64) -> [f64; 2] {
        let (s, _, _, g, _) = self.along(t);
        [g.start[0] + g.dir[0] * s, g.start[1] + g.dir[1] * s]
    }

    fn rpy_at(&self, t: f64) -> [f64; 3] {
        // Tilt follows the acceleration averaged twice over the last second (a triangle over the
        // last two), p(t) - 2 p(t - 1 s) + p(t - 2 s) per s², where the trapezoid's acceleration
        // steps. Averaged once, (v(t) - v(t - 1 s)) / 1 s, the tilt was continuous but its rate
        // jumped a second after each step: what no vehicle does and no interpolation between
        // telemetry samples can follow. Averaged twice, the body rates are continuous too.
        let (p2, p1, p0) = (
            self.path_pos(t),
            self.path_pos(t - 1.0),
            self.path_pos(t - 2.0),
        );
        let (an, ae) = (p2[0] - 2.0 * p1[0] + p0[0], p2[1] - 2.0 * p1[1] + p0[1]);
        let yaw = self.yaw_at(t);
        let fwd = an * yaw.cos() + ae * yaw.sin();
        let right = -an * yaw.sin() + ae * yaw.cos();
        let (wr, _) = self.wander(t, 3, self.wind_rad);
        let (wp, _) = self.wander(t, 4, self.wind_rad);
        let (wy, _) = self.wander(t, 5, self.wind_rad * 0.5);
        let yaw = (yaw + wy).rem_euclid(TAU);
        [right.atan2(G) + wr, -fwd.atan2(G) + wp, yaw]
    }

    /// The true state `t` seconds after the start of the flight.
    pub fn state(&self, t: f64) -> State {
        let pre = self.takeoff_done_s();
        if self.ground_s <= 0.0 || t >= pre {
            return self.survey_state(t - pre);
        }
        let first = self.survey_state(0.0);
        let climbing = t >= self.ground_s;
        let up_m = if climbing {
            (t - self.ground_s) * self.climb_mps
        } else {
            0.0
        };
        State {
            pos_ned_m: [first.pos_ned_m[0], first.pos_ned_m[1], -up_m],
            vel_ned_mps: [0.0, 0.0, if climbing { -self.climb_mps } else { 0.0 }],
            rpy_rad: first.rpy_rad,
            rates_rps: [0.0; 3],
            path_m: 0.0,
        }
    }

    /// The survey's state `t` seconds after it started.
    fn survey_state(&self, t: f64) -> State {
        let (s, v, _, g, laps) = self.along(t);
        let mut pos = [
            g.start[0] + g.dir[0] * s,
            g.start[1] + g.dir[1] * s,
            -self.altitude_m,
        ];
        let mut vel = [g.dir[0] * v, g.dir[1] * v, 0.0];
        for (k, amp) in [(0, self.wind_m), (1, self.wind_m), (2, self.wind_m * 0.5)] {
            let (x, dx) = self.wander(t, k, amp);
            pos[k] += x;
            vel[k] += dx;
        }
        let rpy = self.rpy_at(t);
        let h = 1e-4;
        let (a, b) = (self.rpy_at(t - h), self.rpy_at(t + h));
        let mut d = [0.0; 3];
        for k in 0..3 {
            let mut x = (b[k] - a[k]) % TAU;
            if x > PI {
                x -= TAU;
            } else if x < -PI {
                x += TAU;
            }
            d[k] = x / (2.0 * h);
        }
        // Euler rates to body rates (ZYX).
        let (sr, cr, sp, cp) = (rpy[0].sin(), rpy[0].cos(), rpy[1].sin(), rpy[1].cos());
        let rates = [
            d[0] - sp * d[2],
            cr * d[1] + sr * cp * d[2],
            -sr * d[1] + cr * cp * d[2],
        ];
        State {
            pos_ned_m: pos,
            vel_ned_mps: vel,
            rpy_rad: rpy,
            rates_rps: rates,
            path_m: laps as f64 * self.loop_m + g.s0 + s,
        }
    }

    /// The first time after `t_from` at which the path distance reaches `path_m` (bisection).
    pub fn time_at_path(&self, t_from: f64, path_m: f64) -> f64 {
        let pre = self.takeoff_done_s();
        if path_m <= 0.0 {
            return t_from;
        }
        let t_from = (t_from - pre).max(0.0);
        let (mut lo, mut hi) = (t_from, t_from + 1.0);
        while self.survey_state(hi).path_m < path_m {
            lo = hi;
            hi += (hi - t_from).max(1.0);
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if self.survey_state(mid).path_m < path_m {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        pre + hi
    }
}

/// Body-to-NED quaternion (w, x, y, z) of roll, pitch, yaw (ZYX).
pub fn quat_from_rpy(rpy: [f64; 3]) -> [f64; 4] {
    let (cr, sr) = ((rpy[0] / 2.0).cos(), (rpy[0] / 2.0).sin());
    let (cp, sp) = ((rpy[1] / 2.0).cos(), (rpy[1] / 2.0).sin());
    let (cy, sy) = ((rpy[2] / 2.0).cos(), (rpy[2] / 2.0).sin());
    [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::SimConfig;

    #[test]
    fn velocity_is_the_derivative_of_position_and_speed_is_respected() {
        let c = SimConfig::default();
        let tr = Trajectory::new(&c.survey, 1);
        let h = 1e-4;
        for k in 0..400 {
            let t = k as f64 * 0.37;
            let (a, b, s) = (tr.state(t - h), tr.state(t + h), tr.state(t));
            for i in 0..3 {
                let num = (b.pos_ned_m[i] - a.pos_ned_m[i]) / (2.0 * h);
                assert!((num - s.vel_ned_mps[i]).abs() < 1e-3, "t {t} axis {i}");
            }
            assert!(s.vel_ned_mps[0].hypot(s.vel_ned_mps[1]) < c.survey.speed_mps + 1.0);
        }
    }

    #[test]
    fn the_prelude_waits_on_the_ground_then_climbs_to_the_survey() {
        let s = SimConfig::default().survey;
        let tr = Trajectory::new(&s, 1).with_prelude(10.0, 5.0);
        assert_eq!(tr.takeoff_done_s(), 10.0 + s.altitude_m / 5.0);
        let at = |t: f64| tr.state(t);
        assert_eq!(at(3.0).pos_ned_m[2], 0.0);
        assert_eq!(at(3.0).path_m, 0.0);
        assert!((at(12.0).pos_ned_m[2] + 10.0).abs() < 1e-9);
        assert_eq!(at(12.0).vel_ned_mps, [0.0, 0.0, -5.0]);
        let end = tr.takeoff_done_s();
        assert!((at(end).pos_ned_m[2] + s.altitude_m).abs() < s.wind_m);
        // The path distance starts with the survey, and inverts through the prelude.
        let t = tr.time_at_path(0.0, 50.0);
        assert!(t > end && (at(t).path_m - 50.0).abs() < 1e-6);
    }

    #[test]
    fn time_at_path_inverts_the_path_distance() {
        let tr = Trajectory::new(&SimConfig::default().survey, 1);
        let t = tr.time_at_path(3.0, 100.0);
        assert!((tr.state(t).path_m - 100.0).abs() < 1e-6);
    }

    /// The body rates are continuous over a whole lawnmower loop, through every start and
    /// end of an acceleration phase and every turn: no step of more than the change the
    /// largest angular acceleration makes in a millisecond. With the tilt following the
    /// acceleration averaged once, the pitch rate jumped by 0.31 rad/s a second after each
    /// step of the speed profile.
    #[test]
    fn body_rates_are_continuous() {
        let mut s = SimConfig::default().survey;
        s.pattern = Pattern::Lawnmower;
        s.lanes = 3;
        s.length_m = 60.0;
        s.lane_spacing_m = 25.0;
        let tr = Trajectory::new(&s, 7);
        let dt = 1e-3;
        let mut worst = 0.0f64;
        let mut last = tr.state(0.0).rates_rps;
        let steps = (tr.period_s / dt) as usize;
        for k in 1..=steps {
            let r = tr.state(k as f64 * dt).rates_rps;
            let jump = (0..3).map(|i| (r[i] - last[i]).abs()).fold(0.0, f64::max);
            worst = worst.max(jump);
            last = r;
        }
        // 2 rad/s² bounds the angular acceleration here (a 90° turn eased over 3.5 s peaks
        // at 0.8 rad/s², the tilt's at a few tenths), so 2 mrad/s per millisecond.
        assert!(worst < 2e-3, "rates jump by {worst} rad/s within 1 ms");
    }
}
