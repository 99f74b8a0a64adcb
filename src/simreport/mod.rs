//! Ground truth of an `alfd sim` run: the permissible spacing along the flown
//! path from noise-free renders at the true poses, the daemon's captures judged
//! against it, the fewest captures that would have met it, and the plots.
//!
//! # Definitions (the acceptance figures of [`summarize`])
//!
//! Positions are `along_m`, the true distance along the flown path. Truth
//! samples are the opportunities (one per depth frame); samples at the same
//! `along_m` count as one opportunity with the smallest of their spacings.
//!
//! - **Spacing in force** at a truth sample: its `spacing_m`, or
//!   `fallback_spacing_m` when it is `None` (or not a finite positive number),
//!   as the trigger does.
//! - **Feasible interval** `a → b`: `b − a ≤ m·(1 + 10⁻⁶)`, where `m` is the
//!   minimum spacing in force over the truth samples with `along ∈ [a, b]`
//!   (widened by 1 µm at each end for rounding). When no truth sample lies in
//!   it, `m` is taken over the nearest sample on each side.
//! - **Violation**: an interval between consecutive captures (by `along`) that
//!   is not feasible; `worst_excess_ratio` is the largest `(b − a)/m` among
//!   them. It is **unavoidable** when no truth sample lies strictly between `a`
//!   and `b` (1 µm inside each end: the captures were consecutive
//!   opportunities), or when `b − a ≤ step_limit_m` (at most one opportunity
//!   step apart, for truth sampled more sparsely than the daemon's frames, or
//!   an autopilot's distance trigger checked less often than they come: `alfd
//!   sim` passes a frame's way, in `autopilot_distance` at least one check's;
//!   pass 0 for the first rule alone). It is **at first sight** when the interval
//!   is feasible against every truth sample more than `step_limit_m` before
//!   where the trigger decided `b` (`b` itself, or before it when an external
//!   camera's picture came after the command): only the frame that closed it
//!   (the one the trigger captured at), or the way flown while the camera was
//!   taking the picture, showed the tighter spacing, so no trigger that acts on
//!   what it has seen could have closed it earlier (a gap or a wall entering
//!   the view; the ideal count, which knows the whole track, can). Avoidable = violations −
//!   unavoidable − at first sight.
//! - **Ideal count**: the fewest captures among the truth samples from the
//!   sample nearest the first capture to the sample nearest the last capture,
//!   every interval feasible, except that a step to the very next sample is
//!   always allowed (counted as `ideal_unavoidable` when infeasible). Computed
//!   greedily: from each capture, the farthest feasible sample, else the next.
//! - **Fixed-distance baseline**: the spacing is the minimum spacing in force
//!   over the stretch `[first capture, last capture]` (what a fixed trigger
//!   must use to be safe over the scene's worst part); fixed captures =
//!   `floor(stretch / spacing) + 1`; `data_ratio = captures / fixed captures`.
//! - Spacing min/median/max are over the truth samples in the stretch;
//!   `undersampled`, `rate_limited` and `fallback` count the daemon's flags.

mod plot;
mod summary;
mod truth;

pub use plot::plots;
pub use summary::{summarize, SpacingRange, Summary, Violation, ViolationClass};
pub use truth::{truth_estimates, TruthStream};

use serde::Serialize;

/// A true pose of the simulated vehicle at a depth frame's instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthPose {
    pub mono_ns: u64,
    /// True distance along the flown path, metres.
    pub along_m: f64,
    /// Where the camera is and its pitch, in the scene's frame.
    pub camera: crate::render::Camera,
    pub north_m: f64,
    pub east_m: f64,
}

/// What a noise-free depth frame at a true pose says.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrackSample {
    pub mono_ns: u64,
    pub along_m: f64,
    pub north_m: f64,
    pub east_m: f64,
    /// The estimate's chosen spacing; `None` when the frame gave none.
    pub spacing_m: Option<f64>,
    pub active_bound: Option<String>,
    pub occlusion_degree: Option<f64>,
    pub mmds_m: Option<f64>,
}

/// What the daemon estimated at one of its frames (for the plots).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DaemonSample {
    pub along_m: f64,
    pub spacing_m: Option<f64>,
    pub occlusion_degree: Option<f64>,
}

/// One capture of the daemon, placed on the true path.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CaptureAt {
    pub seq: u64,
    pub mono_ns: u64,
    /// Truth distance along the flown path at the capture instant, metres.
    pub along_m: f64,
    /// Where the trigger decided it: `along_m`, or before it when the picture came later (an
    /// external camera's delay after the command).
    pub decided_along_m: f64,
    pub north_m: f64,
    pub east_m: f64,
    pub undersampled: bool,
    pub rate_limited: bool,
    pub fallback: bool,
}
