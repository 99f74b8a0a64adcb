//! Choosing captures online with the daemon's own trigger
//! ([`crate::core::trigger`]), fed at every dense view with that view's
//! spacing, and the equal-capture scaling of a method's spacing.

use crate::core::closedloop::{ClosedLoop, ClosedLoopTargets, View};
use crate::core::step::tighter;
use crate::core::trigger::{Decision, Opportunity, Trigger, TriggerParams};

/// Trigger settings of the evaluation: no rate limit (the comparison is of
/// spacings, not of a camera), captures exactly at the spacing (no margin).
pub fn trigger_params() -> TriggerParams {
    TriggerParams {
        rate_max_hz: 1e9,
        ..TriggerParams::default()
    }
}

/// Flies `n` dense views `step_m` apart through the daemon's trigger:
/// `view(k, offer)` is called for each view in order and offers that view's
/// spacing; `offer` returns whether the trigger captured there. The last view
/// is always captured (the end of the survey line), so every view lies
/// between two captures. Returns the capture indices.
fn fly(
    n: usize,
    step_m: f64,
    speed_mps: f64,
    mut view: impl FnMut(usize, &mut dyn FnMut(Option<f64>) -> bool),
) -> Vec<usize> {
    let mut t = Trigger::new(trigger_params());
    let mut out = Vec::new();
    for k in 0..n {
        let mut offer = |spacing_m: Option<f64>| {
            let o = Opportunity {
                time_s: k as f64 * step_m / speed_mps,
                odometer_m: k as f64 * step_m,
                next_step_m: step_m,
                spacing_m,
                pose_fresh: true,
            };
            let captured = matches!(t.update(&o), Decision::Capture(_));
            if captured {
                out.push(k);
            }
            captured
        };
        view(k, &mut offer);
    }
    if let Some(&last) = out.last() {
        if last + 1 < n {
            out.push(n - 1);
        }
    }
    out
}

/// Capture indices among `spacings.len()` dense views `step_m` apart, each
/// view's spacing multiplied by `scale`. The last view is always captured
/// (the end of the survey line), so every view lies between two captures.
pub fn captures(spacings: &[Option<f64>], step_m: f64, speed_mps: f64, scale: f64) -> Vec<usize> {
    fly(spacings.len(), step_m, speed_mps, |k, offer| {
        offer(spacings[k].map(|v| v * scale));
    })
}

/// What the closed loop decided along a line flown with it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClosedLoopFlight {
    pub captures: Vec<usize>,
    /// Captures whose spacing the closed loop set, by its bound's name
    /// (`parallax`, `unseen_fraction`).
    pub by_bound: Vec<(&'static str, usize)>,
}

/// Capture indices as [`captures`] at scale 1, with the closed loop on as in
/// the daemon (`core::step`): each view's `open` spacing and the closed
/// loop's measure of its kept depth `kept[k]` against the last capture, the
/// tighter of the two. The views lie `step_m` apart.
pub fn closed_loop_captures(
    open: &[Option<f64>],
    kept: &[View],
    step_m: f64,
    speed_mps: f64,
    targets: &ClosedLoopTargets,
) -> ClosedLoopFlight {
    let mut cl = ClosedLoop::default();
    let mut by_bound: Vec<(&'static str, usize)> = Vec::new();
    let n = open.len().min(kept.len());
    let captures = fly(n, step_m, speed_mps, |k, offer| {
        let odometer_m = k as f64 * step_m;
        let measure = cl.on_frame(kept[k].clone(), odometer_m, step_m, targets);
        if !offer(tighter(open[k], measure.and_then(|m| m.spacing_m))) {
            return;
        }
        cl.on_capture(kept[k].clone(), odometer_m);
        // The closed loop set it when it was the tighter.
        if let Some((c, b)) = measure.and_then(|m| m.spacing_m.zip(m.bound)) {
            if open[k].is_none_or(|o| c < o) {
                match by_bound.iter_mut().find(|e| e.0 == b) {
                    Some(e) => e.1 += 1,
                    None => by_bound.push((b, 1)),
                }
            }
        }
    });
    ClosedLoopFlight { captures, by_bound }
}

/// The scale (one constant for the whole line) at which the method captures
/// `target` views, found by bisection on `log(scale)`; the closest count is
/// returned when `target` is not reachable exactly. Returns `(scale, captures)`.
pub fn scale_to_count(
    spacings: &[Option<f64>],
    step_m: f64,
    speed_mps: f64,
    target: usize,
) -> (f64, Vec<usize>) {
    let count = |s: f64| captures(spacings, step_m, speed_mps, s);
    let (mut lo, mut hi) = (1e-4f64, 1e4f64);
    let mut best = (1.0, count(1.0));
    let better = |c: &Vec<usize>, b: &Vec<usize>| {
        (c.len() as i64 - target as i64).abs() < (b.len() as i64 - target as i64).abs()
    };
    for _ in 0..80 {
        let mid = (lo * hi).sqrt();
        let c = count(mid);
        if c.len() == target {
            return (mid, c);
        }
        if better(&c, &best.1) {
            best = (mid, c.clone());
        }
        // Larger spacings, fewer captures.
        if c.len() > target {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi / lo < 1.0 + 1e-12 {
            break;
        }
    }
    best
}

/// Relative precision of [`largest_passing_scale`]: the bracket's ends are
/// at most this ratio apart when it stops (0.3 %, finer than one capture in
/// a few hundred).
pub const SCALE_PRECISION: f64 = 1.003;

/// The largest scale `s` (within `[1e-4, 1e4]`) for which `ok(s)` holds,
/// searched from `start`: downwards by halving until one passes, upwards by
/// doubling until one fails, then bisection on `log(s)` to
/// [`SCALE_PRECISION`]. `ok` need not be monotone (a plan's phase can make a
/// longer spacing pass where a shorter one failed): the answer is a scale
/// that passes with the next one tried above it failing, never one that
/// fails. `None` when nothing down to `1e-4` passes.
pub fn largest_passing_scale(start: f64, mut ok: impl FnMut(f64) -> bool) -> Option<f64> {
    const LO: f64 = 1e-4;
    const HI: f64 = 1e4;
    let mut lo = start.clamp(LO, HI);
    while !ok(lo) {
        if lo <= LO {
            return None;
        }
        lo = (lo / 2.0).max(LO);
    }
    let mut hi = lo;
    loop {
        if hi >= HI {
            return Some(HI);
        }
        let up = (hi * 2.0).min(HI);
        if ok(up) {
            lo = up;
            hi = up;
        } else {
            hi = up;
            break;
        }
    }
    while hi / lo > SCALE_PRECISION {
        let mid = (lo * hi).sqrt();
        if ok(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(lo)
}
