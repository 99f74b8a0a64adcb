//! Pose buffer: recent positions (local NED metres) and attitudes (quaternions) keyed by the
//! autopilot's boot time, interpolated at any instant (linear position, slerp attitude) and
//! extrapolated with velocity and body rates only up to a horizon; beyond it the answer is `Stale`.

use glam::{DQuat, DVec3};
use std::collections::VecDeque;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionSample {
    pub time_ns: u64,
    pub pos_ned_m: DVec3,
    pub vel_ned_mps: DVec3,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeSample {
    pub time_ns: u64,
    /// Body to NED.
    pub q: DQuat,
    /// Body rates (roll, pitch, yaw rate), rad/s.
    pub rates_rps: DVec3,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseBufferConfig {
    /// How far past the newest sample an answer may be extrapolated.
    pub horizon_ns: u64,
    /// Samples older than this behind the newest are dropped.
    pub keep_ns: u64,
    /// And never more than this many of each kind.
    pub max_samples: usize,
}

/// A pose at an instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub time_ns: u64,
    pub pos_ned_m: DVec3,
    pub vel_ned_mps: DVec3,
    pub q: DQuat,
    /// How far past the newest sample this answer reaches (0 when interpolated).
    pub extrapolated_ns: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PoseError {
    #[error("no position or attitude yet")]
    Empty,
    #[error("instant is before the oldest sample kept")]
    BeforeBuffer,
    #[error("stale: {age_ns} ns past the newest sample, horizon {horizon_ns} ns")]
    Stale { age_ns: u64, horizon_ns: u64 },
}

/// Why a sample was not stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PushError {
    /// Not newer than the newest sample of its kind.
    OutOfOrder,
    /// Non-finite numbers, or a quaternion that is not a unit one.
    Invalid,
}

#[derive(Clone, Debug)]
pub struct PoseBuffer {
    cfg: PoseBufferConfig,
    pos: VecDeque<PositionSample>,
    att: VecDeque<AttitudeSample>,
}

fn trim<T>(q: &mut VecDeque<T>, t: impl Fn(&T) -> u64, cfg: &PoseBufferConfig) {
    let newest = q.back().map_or(0, &t);
    while q.len() > cfg.max_samples.max(2)
        || (q.len() > 2 && q.front().is_some_and(|s| newest - t(s) > cfg.keep_ns))
    {
        q.pop_front();
    }
}

/// Index of the last sample at or before `t` and the one after it (if any).
fn bracket<T>(
    q: &VecDeque<T>,
    t_ns: u64,
    time: impl Fn(&T) -> u64,
) -> Option<(usize, Option<usize>)> {
    let i = q.partition_point(|s| time(s) <= t_ns);
    if i == 0 {
        return None;
    }
    Some((i - 1, (i < q.len()).then_some(i)))
}

impl PoseBuffer {
    pub fn new(cfg: PoseBufferConfig) -> Self {
        Self {
            cfg,
            pos: VecDeque::new(),
            att: VecDeque::new(),
        }
    }

    pub fn clear(&mut self) {
        self.pos.clear();
        self.att.clear();
    }

    /// Re-express every kept position with `f` (old local NED to new), when the local frame's
    /// anchor moves: the history stays continuous, so interpolation needs no new samples.
    pub fn map_positions(&mut self, f: impl Fn(DVec3) -> DVec3) {
        for s in &mut self.pos {
            s.pos_ned_m = f(s.pos_ned_m);
        }
    }

    pub fn newest_position(&self) -> Option<&PositionSample> {
        self.pos.back()
    }

    pub fn push_position(&mut self, s: PositionSample) -> Result<(), PushError> {
        if !(s.pos_ned_m.is_finite() && s.vel_ned_mps.is_finite()) {
            return Err(PushError::Invalid);
        }
        if self.pos.back().is_some_and(|b| b.time_ns >= s.time_ns) {
            return Err(PushError::OutOfOrder);
        }
        self.pos.push_back(s);
        trim(&mut self.pos, |s| s.time_ns, &self.cfg);
        Ok(())
    }

    pub fn push_attitude(&mut self, s: AttitudeSample) -> Result<(), PushError> {
        if !(s.q.is_finite() && s.rates_rps.is_finite()) || (s.q.length() - 1.0).abs() > 1e-3 {
            return Err(PushError::Invalid);
        }
        if self.att.back().is_some_and(|b| b.time_ns >= s.time_ns) {
            return Err(PushError::OutOfOrder);
        }
        self.att.push_back(AttitudeSample {
            q: s.q.normalize(),
            ..s
        });
        trim(&mut self.att, |s| s.time_ns, &self.cfg);
        Ok(())
    }

    fn position_at(&self, t_ns: u64) -> Result<(DVec3, DVec3, u64), PoseError> {
        let (i, j) = bracket(&self.pos, t_ns, |s| s.time_ns).ok_or(if self.pos.is_empty() {
            PoseError::Empty
        } else {
            PoseError::BeforeBuffer
        })?;
        let a = self.pos[i];
        match j {
            Some(j) => {
                let b = self.pos[j];
                let u = (t_ns - a.time_ns) as f64 / (b.time_ns - a.time_ns) as f64;
                Ok((
                    a.pos_ned_m.lerp(b.pos_ned_m, u),
                    a.vel_ned_mps.lerp(b.vel_ned_mps, u),
                    0,
                ))
            }
            None => {
                let age = t_ns - a.time_ns;
                self.check_horizon(age)?;
                let dt = age as f64 * 1e-9;
                Ok((a.pos_ned_m + a.vel_ned_mps * dt, a.vel_ned_mps, age))
            }
        }
    }

    fn attitude_at(&self, t_ns: u64) -> Result<(DQuat, u64), PoseError> {
        let (i, j) = bracket(&self.att, t_ns, |s| s.time_ns).ok_or(if self.att.is_empty() {
            PoseError::Empty
        } else {
            PoseError::BeforeBuffer
        })?;
        let a = self.att[i];
        match j {
            Some(j) => {
                let b = self.att[j];
                let u = (t_ns - a.time_ns) as f64 / (b.time_ns - a.time_ns) as f64;
                Ok((a.q.slerp(b.q, u), 0))
            }
            None => {
                let age = t_ns - a.time_ns;
                self.check_horizon(age)?;
                let turn = DQuat::from_scaled_axis(a.rates_rps * (age as f64 * 1e-9));
                Ok(((a.q * turn).normalize(), age))
            }
        }
    }

    fn check_horizon(&self, age_ns: u64) -> Result<(), PoseError> {
        if age_ns > self.cfg.horizon_ns {
            return Err(PoseError::Stale {
                age_ns,
                horizon_ns: self.cfg.horizon_ns,
            });
        }
        Ok(())
    }

    /// The pose at boot time `t_ns`.
    pub fn at(&self, t_ns: u64) -> Result<Pose, PoseError> {
        let (pos_ned_m, vel_ned_mps, ep) = self.position_at(t_ns)?;
        let (q, ea) = self.attitude_at(t_ns)?;
        Ok(Pose {
            time_ns: t_ns,
            pos_ned_m,
            vel_ned_mps,
            q,
            extrapolated_ns: ep.max(ea),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn buf() -> PoseBuffer {
        PoseBuffer::new(PoseBufferConfig {
            horizon_ns: 200_000_000,
            keep_ns: 5_000_000_000,
            max_samples: 500,
        })
    }

    #[test]
    fn interpolates_extrapolates_then_goes_stale() {
        let mut b = buf();
        assert_eq!(b.at(0), Err(PoseError::Empty));
        let v = DVec3::new(10.0, 0.0, 0.0);
        for k in 0..3u64 {
            let t = 1_000_000_000 + k * 100_000_000;
            b.push_position(PositionSample {
                time_ns: t,
                pos_ned_m: v * (k as f64 * 0.1),
                vel_ned_mps: v,
            })
            .unwrap();
            let q = DQuat::from_rotation_z(k as f64 * 0.1);
            b.push_attitude(AttitudeSample {
                time_ns: t,
                q,
                rates_rps: DVec3::new(0.0, 0.0, 1.0),
            })
            .unwrap();
        }
        let p = b.at(1_050_000_000).unwrap();
        assert!((p.pos_ned_m.x - 0.5).abs() < 1e-9 && p.extrapolated_ns == 0);
        assert!((p.q.to_euler(glam::EulerRot::ZYX).0 - 0.05).abs() < 1e-9);
        let e = b.at(1_300_000_000).unwrap();
        assert!((e.pos_ned_m.x - 3.0).abs() < 1e-9 && e.extrapolated_ns == 100_000_000);
        assert!((e.q.to_euler(glam::EulerRot::ZYX).0 - 0.3).abs() < 1e-9);
        assert!(matches!(b.at(1_500_000_000), Err(PoseError::Stale { .. })));
        assert_eq!(b.at(999_999_999), Err(PoseError::BeforeBuffer));
        let dup = PositionSample {
            time_ns: 1_000_000_000,
            pos_ned_m: DVec3::ZERO,
            vel_ned_mps: v,
        };
        assert_eq!(b.push_position(dup), Err(PushError::OutOfOrder));
    }
}
