//! One estimate from one depth frame: inverse depth, the robust depth range, the
//! bounds of every model the frame needs, the chosen spacing and why. Only the
//! terms the scene and the model need are computed, and the result says which.

use super::depth::{DepthImage, Intrinsics, HORIZON_EPS};
use super::inverse::{
    count4, fill_grid, fill_grid_counted, percentile_ranks, InvGrid, Selector, FAR, INVALID,
};
use super::occlusion::{scan, BoundaryParams, BoundaryStats};
use super::params::{Decimation, EstimatorParams, GainModel, Model, Quality};
use super::plane::{fit, PlaneFit};
use super::score::{best, score, PitchScore};
use super::spacing::{
    coverage_m, disparity_gain_px, mmds_m, occlusion_degree, occlusion_density_per_m,
    occlusion_term_m, sspa_m,
};
use super::visibility::{
    visibility_interleaved, visibility_on, Interleave, SweepWorkers, Visibility,
    INTERLEAVE_REFRESH_REL,
};
use std::sync::Arc;
use thiserror::Error;

/// Why a frame gives no estimate. The caller falls back to a conservative spacing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoEstimate {
    /// Fewer valid pixels than `valid_fraction_min`.
    TooFewValidPixels,
    /// `|pitch|` above `pitch_max`: the camera looks along the track, where the
    /// translation model of DESIGN §1 (`b⊥ = b·cos φ`) no longer holds.
    PitchNearHorizontal,
    /// The pitch is not a finite number (a corrupted attitude).
    InvalidPitch,
    /// No depth frame arrived in time (the depth camera stalled).
    NoDepthFrame,
}

impl NoEstimate {
    pub fn as_str(self) -> &'static str {
        match self {
            NoEstimate::TooFewValidPixels => "too_few_valid_pixels",
            NoEstimate::PitchNearHorizontal => "pitch_near_horizontal",
            NoEstimate::InvalidPitch => "invalid_pitch",
            NoEstimate::NoDepthFrame => "no_depth_frame",
        }
    }
}

/// The bound that decided the chosen spacing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bound {
    /// `quality.parallax_px`: the disparity range per step.
    Parallax,
    /// `quality.forward_overlap` at the nearest depth.
    ForwardOverlap,
    /// `quality.unseen_fraction_max`: an in-between view's pixels neither
    /// neighbour sees (the visibility term, occluders only).
    Unseen,
    /// `quality.views_per_point_min`: every visible point in `k` captures.
    Views,
    Mmds,
    Sspa,
    Occlusion,
    Coverage,
    ConfigMin,
    ConfigMax,
    Fixed,
}

impl Bound {
    /// A number for a channel that carries only numbers (NAMED_VALUE_FLOAT
    /// `ALF_BND`): 1 parallax, 2 forward_overlap, 3 unseen_fraction,
    /// 4 views_per_point, 5 mmds, 6 sspa, 7 occlusion, 8 coverage,
    /// 9 config_min, 10 config_max, 11 fixed.
    pub fn code(self) -> u8 {
        match self {
            Bound::Parallax => 1,
            Bound::ForwardOverlap => 2,
            Bound::Unseen => 3,
            Bound::Views => 4,
            Bound::Mmds => 5,
            Bound::Sspa => 6,
            Bound::Occlusion => 7,
            Bound::Coverage => 8,
            Bound::ConfigMin => 9,
            Bound::ConfigMax => 10,
            Bound::Fixed => 11,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Bound::Parallax => "parallax",
            Bound::ForwardOverlap => "forward_overlap",
            Bound::Unseen => "unseen_fraction",
            Bound::Views => "views_per_point",
            Bound::Mmds => "mmds",
            Bound::Sspa => "sspa",
            Bound::Occlusion => "occlusion",
            Bound::Coverage => "coverage",
            Bound::ConfigMin => "config_min",
            Bound::ConfigMax => "config_max",
            Bound::Fixed => "fixed",
        }
    }
}

/// The terms computed for a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Terms {
    /// The quality model's parallax target (MMDS's formula at `parallax_px`).
    pub parallax: bool,
    pub forward_overlap: bool,
    /// The visibility sweep found occluders: the unseen-fraction bound and the
    /// occluders' share of views per point are in force.
    pub visibility: bool,
    /// Views per point (from the sweep; without occluders it is the overlap
    /// for `k` views at each sample's depth).
    pub views: bool,
    pub mmds: bool,
    pub sspa: bool,
    pub occlusion: bool,
    pub coverage: bool,
    pub score: bool,
    /// Not a bound but an assumption the range rests on: more of the frame
    /// than the low percentile's tail looked below the horizon and had no
    /// return, so the depth range's far end was taken at infinity.
    pub beyond_range: bool,
}

impl Terms {
    pub fn names(&self) -> Vec<&'static str> {
        [
            (self.parallax, "parallax"),
            (self.forward_overlap, "forward_overlap"),
            (self.visibility, "visibility"),
            (self.views, "views"),
            (self.mmds, "mmds"),
            (self.sspa, "sspa"),
            (self.occlusion, "occlusion"),
            (self.coverage, "coverage"),
            (self.score, "score"),
            (self.beyond_range, "beyond_range"),
        ]
        .into_iter()
        .filter_map(|(on, n)| on.then_some(n))
        .collect()
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InvDepth {
    pub min_per_m: f64,
    pub max_per_m: f64,
    pub opt_per_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Spacings {
    /// Largest spacing keeping the disparity range within `parallax_px`.
    pub parallax_m: Option<f64>,
    /// Largest spacing keeping `forward_overlap` at the nearest depth.
    pub forward_overlap_m: Option<f64>,
    /// Largest spacing keeping the unseen fraction within its target (`None`:
    /// no occluder, or too few occluded samples to exceed it at any spacing).
    pub unseen_m: Option<f64>,
    /// Largest spacing keeping every visible sample in `k` captures.
    pub views_m: Option<f64>,
    pub mmds_m: Option<f64>,
    pub sspa_m: Option<f64>,
    /// DESIGN's occlusion-aware spacing `min(MMDS, O_max/ρ)`; `None` without occlusion.
    pub occlusion_m: Option<f64>,
    pub coverage_m: Option<f64>,
    /// The model's spacing before the config limits (`None`: nothing bounds it).
    pub permissible_m: Option<f64>,
    /// What the trigger uses: the permissible spacing within the config limits.
    pub chosen_m: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Occlusion {
    pub boundaries: u64,
    pub lines: u64,
    /// `D`, 1/m.
    pub contrast_per_m: f64,
    /// `ρ`, per metre of baseline.
    pub density_per_m: f64,
    /// `O(b)` at the chosen spacing.
    pub degree: f64,
    pub max_degree: f64,
}

/// The targets in force and what this frame predicts for each at the chosen
/// spacing (`None`: the frame cannot say: no depth range, no surface sample).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityPrediction {
    pub targets: Quality,
    /// Disparity range between neighbouring captures, px.
    pub parallax_px: Option<f64>,
    /// Forward overlap at the nearest depth, in `[0, 1]`.
    pub forward_overlap: Option<f64>,
    /// Unseen fraction of the in-between view, worst phase.
    pub unseen_fraction: Option<f64>,
    /// Captures the least-seen visible sample is in, whatever the phase.
    pub views_per_point: Option<u32>,
}

/// What the visibility sweep saw (the term's inputs, for the log).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisibilitySummary {
    pub samples: u64,
    pub occluded_samples: u64,
    pub occluded_lines: u64,
    /// Shortest visibility interval of any surface sample, m.
    pub interval_min_m: Option<f64>,
    /// Shortest interval an occluder cuts, m.
    pub occluded_interval_min_m: Option<f64>,
    /// The sweep's sampling step, pixels both ways (above the estimate's own
    /// decimation where `visibility_samples_max` thinned it).
    pub step: usize,
    /// This frame swept one in `interleave` lines and took the others from the
    /// frames before (1: every line on this frame; `visibility_interleave`).
    pub interleave: usize,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    pub no_estimate: Option<NoEstimate>,
    pub decimation: usize,
    pub samples: usize,
    pub valid_samples: usize,
    pub sky_samples: usize,
    /// Samples with no return or beyond the range that look below the horizon:
    /// ground too far for the sensor (or a surface that returns nothing). They
    /// count in the depth range at the far end, as if at infinity, so that the
    /// parallax span is never understated (`terms.beyond_range` where they do).
    pub far_below_samples: usize,
    pub valid_fraction: f64,
    pub pitch_rad: f64,
    pub inv_depth: Option<InvDepth>,
    pub occlusion: Option<Occlusion>,
    pub visibility: Option<VisibilitySummary>,
    pub quality: Option<QualityPrediction>,
    /// What [`Estimate::predict_at`] needs: the disparity gain and half extent
    /// (px) and the sweep's intervals (shared, not copied, with every clone).
    basis: Option<PredictionBasis>,
    pub plane: Option<PlaneFit>,
    pub spacing: Spacings,
    pub active_bound: Option<Bound>,
    pub terms: Terms,
    pub pitch_scores: Vec<PitchScore>,
    pub best_pitch: Option<PitchScore>,
}

impl Estimate {
    /// The estimate of an opportunity without depth: nothing known, so the
    /// trigger falls back to its configured spacing.
    pub fn without_depth(pitch_rad: f64) -> Estimate {
        Estimate {
            no_estimate: Some(NoEstimate::NoDepthFrame),
            decimation: 1,
            samples: 0,
            valid_samples: 0,
            sky_samples: 0,
            far_below_samples: 0,
            valid_fraction: 0.0,
            pitch_rad: if pitch_rad.is_finite() {
                pitch_rad
            } else {
                0.0
            },
            inv_depth: None,
            occlusion: None,
            visibility: None,
            quality: None,
            basis: None,
            plane: None,
            spacing: Spacings::default(),
            active_bound: None,
            terms: Terms::default(),
            pitch_scores: Vec::new(),
            best_pitch: None,
        }
    }

    pub fn is_ok(&self) -> bool {
        self.no_estimate.is_none()
    }

    /// `(chosen, permissible)` when `spacing_min_m` holds the chosen spacing above
    /// the permissible one: the floor is a config key, not a quality, so the
    /// targets are broken there.
    pub fn floor_over_permissible(&self) -> Option<(f64, f64)> {
        match (
            self.active_bound,
            self.spacing.chosen_m,
            self.spacing.permissible_m,
        ) {
            (Some(Bound::ConfigMin), Some(chosen), Some(permissible)) if chosen > permissible => {
                Some((chosen, permissible))
            }
            _ => None,
        }
    }

    /// The quality model's predictions at another spacing (the trigger's, when
    /// the rate limit holds it above the estimate's); `None` for other models.
    pub fn predict_at(&self, spacing_m: f64) -> Option<QualityPrediction> {
        let q = self.quality?;
        let b = self.basis.as_ref()?;
        Some(predict(
            &q.targets,
            self.inv_depth,
            b.parallax_per_m,
            b.gain_px,
            b.half_extent_px,
            b.visibility.as_deref(),
            spacing_m,
        ))
    }
}

#[derive(Debug, Clone, PartialEq)]
struct PredictionBasis {
    parallax_per_m: Option<f64>,
    gain_px: f64,
    half_extent_px: f64,
    visibility: Option<std::sync::Arc<Visibility>>,
}

/// Calling errors (a frame and intrinsics that do not belong together); scene
/// content never produces one.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum EstimateError {
    #[error("intrinsics are for {iw}x{ih} but the depth image is {dw}x{dh}")]
    SizeMismatch {
        iw: usize,
        ih: usize,
        dw: usize,
        dh: usize,
    },
}

/// Result of choosing a decimation level on a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct DecimationChoice {
    pub level: usize,
    pub budget: f64,
    /// `(level, relative spacing error against level 1)`: level 1, then each level
    /// tried, coarsest first (calibration stops at the first within budget).
    pub errors: Vec<(usize, f64)>,
}

/// Relative difference of two spacings; both unbounded is no error, one
/// unbounded is an infinite one.
pub fn relative_error(x: Option<f64>, reference: Option<f64>) -> f64 {
    match (x, reference) {
        (Some(a), Some(b)) => (a - b).abs() / b,
        (None, None) => 0.0,
        _ => f64::INFINITY,
    }
}

/// How much longer than `reference` a spacing is, relative (the unsafe side of
/// [`relative_error`]): 0 when shorter or equal, or when the reference is
/// unbounded; infinite when only the reference is bounded.
pub fn relative_excess(x: Option<f64>, reference: Option<f64>) -> f64 {
    match (x, reference) {
        (Some(a), Some(b)) => ((a - b) / b).max(0.0),
        (None, Some(_)) => f64::INFINITY,
        (_, None) => 0.0,
    }
}

/// An estimator with its scratch buffers, reused frame after frame.
#[derive(Debug, Clone)]
pub struct Estimator {
    params: EstimatorParams,
    grid: InvGrid,
    score_grid: InvGrid,
    selector: Selector,
    /// Per-sample disparity per metre of baseline (the parallax target's scratch).
    disparity: Vec<f32>,
    /// The visibility sweep's grid when it is coarser than the estimate's.
    vis_grid: InvGrid,
    /// `Decimation::Auto`'s level, the frame size it was calibrated on and the frames
    /// estimated at it since.
    auto: Option<AutoLevel>,
    /// Threads lent to the visibility sweep (`None`: the calling thread).
    sweep_workers: Option<Arc<dyn SweepWorkers>>,
    /// The flight's visibility sweep spread over frames
    /// (`visibility_interleave`; only [`Estimator::estimate`] uses it).
    interleave: Interleave,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct AutoLevel {
    level: usize,
    size: (usize, usize),
    frames: usize,
}

impl Estimator {
    /// `params` must have passed [`EstimatorParams::validate`].
    pub fn new(params: EstimatorParams) -> Self {
        let interleave = if params.visibility_refresh {
            Interleave::refreshing(INTERLEAVE_REFRESH_REL).watching()
        } else {
            Interleave::default()
        };
        Estimator {
            params,
            grid: InvGrid::default(),
            score_grid: InvGrid::default(),
            selector: Selector::default(),
            disparity: Vec::new(),
            vis_grid: InvGrid::default(),
            auto: None,
            sweep_workers: None,
            interleave,
        }
    }

    /// Lends the visibility sweep threads: the same estimate, sooner where
    /// cores are idle (its lines are merged in order, so the bits do not depend
    /// on who swept them).
    pub fn set_sweep_workers(&mut self, workers: Arc<dyn SweepWorkers>) {
        self.sweep_workers = Some(workers);
    }

    pub fn params(&self) -> &EstimatorParams {
        &self.params
    }

    /// Scan along another image axis from the next frame on (the direction of
    /// flight moved in the image: crabbing, sideways flight).
    pub fn set_track_axis(&mut self, axis: super::depth::TrackAxis) {
        if axis != self.params.track_axis {
            self.params.track_axis = axis;
            self.interleave.reset();
        }
    }

    /// The estimate of the next frame of a flight at the configured decimation. `Auto`
    /// calibrates on the first frame, every `recalibrate_frames` frames after, on a new
    /// frame size and whenever the calibrated level gives no estimate; the choice is
    /// returned on the frames it was made. With `visibility_interleave` above 1 the
    /// visibility term also takes lines swept on the frames before (calibration frames
    /// sweep every line and do not advance it): give the frames in order.
    pub fn estimate(
        &mut self,
        image: &DepthImage,
        intr: &Intrinsics,
        pitch_rad: f64,
    ) -> Result<(Estimate, Option<DecimationChoice>), EstimateError> {
        match self.params.decimation.clone() {
            Decimation::Fixed(n) => {
                Ok((self.estimate_step(image, intr, pitch_rad, n, true)?, None))
            }
            Decimation::Auto {
                budget,
                levels,
                recalibrate_frames,
            } => {
                let size = (image.width(), image.height());
                if let Some(a) = self
                    .auto
                    .filter(|a| a.size == size && a.frames < recalibrate_frames)
                {
                    let e = self.estimate_step(image, intr, pitch_rad, a.level, true)?;
                    if e.is_ok() {
                        self.auto = Some(AutoLevel {
                            frames: a.frames + 1,
                            ..a
                        });
                        return Ok((e, None));
                    }
                }
                let (e, c) = self.calibrate(image, intr, pitch_rad, budget, &levels)?;
                self.auto = Some(AutoLevel {
                    level: c.level,
                    size,
                    frames: 0,
                });
                Ok((e, Some(c)))
            }
        }
    }

    /// Returns the coarsest level whose permissible spacing, and occlusion density where
    /// computed, are within `budget` of full resolution (level 1 always qualifies). The
    /// levels are tried coarsest first and the first within budget is taken: the same
    /// choice as trying all, without estimating the finer ones (`errors` lists the tried).
    pub fn calibrate(
        &mut self,
        image: &DepthImage,
        intr: &Intrinsics,
        pitch_rad: f64,
        budget: f64,
        levels: &[usize],
    ) -> Result<(Estimate, DecimationChoice), EstimateError> {
        let reference = self.estimate_at(image, intr, pitch_rad, 1)?;
        let mut errors = vec![(1usize, 0.0)];
        let mut sorted: Vec<usize> = levels.iter().copied().filter(|&l| l > 1).collect();
        sorted.sort_unstable();
        sorted.dedup();
        for &level in sorted.iter().rev() {
            let e = self.estimate_at(image, intr, pitch_rad, level)?;
            let err = if e.is_ok() != reference.is_ok() {
                f64::INFINITY
            } else {
                // The occlusion degree is logged with every capture, so its
                // error counts even where MMDS binds the spacing.
                let density =
                    |e: &Estimate| e.occlusion.map(|o| o.density_per_m).filter(|&d| d > 0.0);
                let density_err = match (&e.occlusion, &reference.occlusion) {
                    (Some(_), Some(_)) => relative_error(density(&e), density(&reference)),
                    _ => 0.0,
                };
                relative_error(e.spacing.permissible_m, reference.spacing.permissible_m)
                    .max(density_err)
            };
            errors.push((level, err));
            if err <= budget {
                return Ok((
                    e,
                    DecimationChoice {
                        level,
                        budget,
                        errors,
                    },
                ));
            }
        }
        Ok((
            reference,
            DecimationChoice {
                level: 1,
                budget,
                errors,
            },
        ))
    }

    /// The estimate sampling every `step`-th pixel along and across track, of
    /// this frame alone (the visibility sweep on every line of its grid).
    pub fn estimate_at(
        &mut self,
        image: &DepthImage,
        intr: &Intrinsics,
        pitch_rad: f64,
        step: usize,
    ) -> Result<Estimate, EstimateError> {
        self.estimate_step(image, intr, pitch_rad, step, false)
    }

    /// [`Estimator::estimate_at`]; `in_flight`: a frame of the flight, whose
    /// visibility sweep may be spread over frames (`visibility_interleave`).
    fn estimate_step(
        &mut self,
        image: &DepthImage,
        intr: &Intrinsics,
        pitch_rad: f64,
        step: usize,
        in_flight: bool,
    ) -> Result<Estimate, EstimateError> {
        if intr.width() != image.width() || intr.height() != image.height() {
            return Err(EstimateError::SizeMismatch {
                iw: intr.width(),
                ih: intr.height(),
                dw: image.width(),
                dh: image.height(),
            });
        }
        let p = &self.params;
        let step = step.max(1);
        // The Z16 values are counted in the same pass: the percentiles below
        // then need no pass of their own.
        fill_grid_counted(image, p.track_axis, step, &p.depth_range, &mut self.grid);
        let samples = self.grid.samples();
        let mut est = Estimate {
            no_estimate: None,
            decimation: step,
            samples,
            valid_samples: self.grid.valid,
            sky_samples: self.grid.sky,
            valid_fraction: self.grid.valid as f64 / samples as f64,
            ..Estimate::without_depth(pitch_rad)
        };
        // Beyond the range below the horizon is far ground, not sky: it joins
        // the depth range at inverse depth 0, its far end (the percentiles of
        // the samples with it, the far ones below the rest). Counted on every
        // frame, also one that gives no estimate (all of it out of range).
        let far = far_below_horizon(&self.grid, &intr.track(p.track_axis), pitch_rad) as u64;
        est.far_below_samples = far as usize;
        if !pitch_rad.is_finite() {
            est.no_estimate = Some(NoEstimate::InvalidPitch);
            return Ok(est);
        }
        if pitch_rad.abs() > p.pitch_max_rad {
            est.no_estimate = Some(NoEstimate::PitchNearHorizontal);
            return Ok(est);
        }
        // The fixed model needs no depth (a rig without a depth camera).
        if p.model != Model::Fixed
            && (est.valid_fraction < p.valid_fraction_min || self.grid.valid == 0)
        {
            est.no_estimate = Some(NoEstimate::TooFewValidPixels);
            return Ok(est);
        }
        let geom = intr.track(p.track_axis);
        let gain = disparity_gain_px(geom.focal_px, pitch_rad);
        let c_tex = p.texture_bandwidth;
        let dv = p.disparity_tolerance_px;

        let n_range = (self.grid.valid - if p.sky_is_scene { 0 } else { self.grid.sky }) as u64;
        // Disparity range per metre of baseline, px/m (`None`: MMDS's `f·cos φ·Δw`).
        let mut parallax_per_m: Option<f64> = None;
        if n_range > 0 {
            let ranks = percentile_ranks(n_range + far, p.percentile_low, p.percentile_high);
            est.terms.beyond_range = ranks[0] < far;
            let (grid, selector) = (&self.grid, &mut self.selector);
            let selected = with_far(ranks, far, |r| grid.select2(selector, p.sky_is_scene, r));
            if let Some([lo, hi]) = selected {
                let (lo, hi) = (lo as f64, hi as f64);
                est.inv_depth = Some(InvDepth {
                    min_per_m: lo,
                    max_per_m: hi,
                    opt_per_m: 0.5 * (lo + hi),
                });
                est.terms.mmds = true;
                est.terms.coverage = true;
                est.spacing.mmds_m = mmds_m(gain, hi - lo, c_tex, dv);
                est.spacing.coverage_m = coverage_m(p.overlap_min, geom.half_extent_px, gain, hi);
                if p.model == Model::Quality {
                    let q = &p.quality;
                    if let Some(px) = q.parallax_px {
                        est.terms.parallax = true;
                        let pct = (p.percentile_low, p.percentile_high);
                        // One fill serves the span over every pixel and the
                        // spans in frame of every step tried.
                        let mut spans = InFrameSpans::new(
                            &self.grid,
                            &geom,
                            pitch_rad,
                            pct,
                            far,
                            &mut self.disparity,
                        );
                        let all_per_m = if pitch_rad == 0.0 {
                            // Nadir: every pixel's gain is f, so this is MMDS's
                            // `gain·Δw` on the depth range's own percentiles.
                            Some(gain * (hi - lo))
                        } else {
                            spans.span_all()
                        };
                        if let Some(all_per_m) = all_per_m {
                            let (per_m, spacing_m) =
                                parallax_in_frame(all_per_m, px, |b| spans.span_at(b));
                            parallax_per_m = Some(per_m);
                            est.spacing.parallax_m = spacing_m;
                        }
                    }
                    if let Some(fo) = q.forward_overlap {
                        est.terms.forward_overlap = true;
                        est.spacing.forward_overlap_m =
                            coverage_m(fo, geom.half_extent_px, gain, hi);
                    }
                }
            }
        }
        let mut vis: Option<Visibility> = None;
        if p.model == Model::Quality {
            // At most `visibility_samples_max` samples, by a coarser stride
            // both ways. Thinning the lines alone (every sample along track)
            // was measured worse: the views bound is a minimum over lines, and
            // skipped lines miss the narrowest gap (docs/error-vs-runtime.md).
            let (stride, vstep) = p.visibility_sampling(self.grid.samples(), step, in_flight);
            let vgrid = if vstep == step {
                &self.grid
            } else {
                fill_grid(
                    image,
                    p.track_axis,
                    vstep,
                    &p.depth_range,
                    &mut self.vis_grid,
                );
                &self.vis_grid
            };
            let vparams = p.visibility_params();
            let workers = self.sweep_workers.as_deref();
            let v = if stride > 1 {
                // What the frame's other terms allow: a tightening of the
                // views spacing far above it need not sweep every line.
                let s = &est.spacing;
                let others_m = [s.parallax_m, s.forward_overlap_m, s.coverage_m]
                    .into_iter()
                    .flatten()
                    .reduce(f64::min);
                visibility_interleaved(
                    vgrid,
                    &geom,
                    pitch_rad,
                    &vparams,
                    workers,
                    stride,
                    others_m,
                    &mut self.interleave,
                )
            } else {
                visibility_on(vgrid, &geom, pitch_rad, &vparams, workers)
            };
            if v.samples > 0 {
                est.terms.views = true;
                est.spacing.views_m = v.spacing_views_m;
            }
            // No occluder on any line: the unseen fraction is 0 at every
            // spacing the footprint allows, so the term is left out; and
            // with the target not in force it bounds nothing either.
            if v.has_occluders() && p.quality.unseen_fraction_max < Quality::UNSEEN_OFF {
                est.terms.visibility = true;
                est.spacing.unseen_m = v.spacing_unseen_m;
            }
            est.visibility = Some(VisibilitySummary {
                samples: v.samples,
                occluded_samples: v.occluded_samples,
                occluded_lines: v.occluded_lines,
                interval_min_m: v.interval_min_m,
                occluded_interval_min_m: v.occluded_interval_min_m,
                step: vstep,
                interleave: if stride > 1 && !self.interleave.swept_every_line() {
                    stride
                } else {
                    1
                },
            });
            vis = Some(v);
        }

        let mut density = 0.0;
        let mut stats = BoundaryStats::default();
        let bparams = BoundaryParams {
            tau_abs_per_m: p.tau_abs_per_m,
            tau_rel: p.tau_rel,
            max_gap_px: p.max_gap_px,
            sky_is_scene: p.sky_is_scene,
        };
        let want_occlusion = p.model == Model::Occlusion || p.with_occlusion;
        if want_occlusion {
            let weights: Option<Vec<f64>> = (p.gain_model == GainModel::Pixel).then(|| {
                // Relative to the axis gain f·cos φ, which ρ's formula carries.
                let (s, c) = pitch_rad.sin_cos();
                let axis = geom.focal_px * c;
                self.grid
                    .along_idx
                    .iter()
                    .map(|&i| ((axis - geom.v_px(i) * s) / axis).abs())
                    .collect()
            });
            stats = scan(&self.grid, &bparams, weights.as_deref());
            density = occlusion_density_per_m(
                p.beta,
                gain,
                stats.mean_contrast_per_m(),
                geom.half_extent_px,
            );
            // No boundary, no term: the result is then exactly MMDS.
            if stats.boundaries > 0 && density > 0.0 {
                est.terms.occlusion = true;
                let term = occlusion_term_m(p.occlusion_max, density);
                est.spacing.occlusion_m = min_opt(est.spacing.mmds_m, term);
            }
        }
        if p.model == Model::Sspa || p.with_sspa {
            est.terms.sspa = true;
            est.plane = fit(
                &self.grid,
                &geom,
                pitch_rad,
                p.sspa_iterations,
                p.sspa_trim_sigma,
                &mut self.selector,
            );
            est.spacing.sspa_m = est
                .plane
                .and_then(|pl| sspa_m(gain, pl.delta_w_per_m, pl.extent_m, c_tex, dv));
        }

        let s = &est.spacing;
        let candidates: &[(Bound, Option<f64>)] = match p.model {
            Model::Quality => &[
                (Bound::Parallax, s.parallax_m),
                (Bound::ForwardOverlap, s.forward_overlap_m),
                (Bound::Coverage, s.coverage_m),
                (Bound::Views, s.views_m),
                (Bound::Unseen, s.unseen_m),
            ],
            Model::Occlusion => &[
                (Bound::Mmds, s.mmds_m),
                (Bound::Occlusion, s.occlusion_m),
                (Bound::Coverage, s.coverage_m),
            ],
            Model::Mmds => &[(Bound::Mmds, s.mmds_m), (Bound::Coverage, s.coverage_m)],
            Model::Sspa => &[(Bound::Sspa, s.sspa_m), (Bound::Coverage, s.coverage_m)],
            Model::Fixed => &[(Bound::Fixed, Some(p.fixed_spacing_m))],
        };
        // Strictly smaller wins, so ties keep the earlier (MMDS before occlusion).
        let mut permissible: Option<(Bound, f64)> = None;
        for &(bound, value) in candidates {
            if let Some(v) = value {
                if permissible.is_none_or(|(_, cur)| v < cur) {
                    permissible = Some((bound, v));
                }
            }
        }
        est.spacing.permissible_m = permissible.map(|(_, v)| v);
        let (bound, chosen) = match permissible {
            None => (Bound::ConfigMax, p.spacing_max_m),
            Some((_, v)) if v < p.spacing_min_m => (Bound::ConfigMin, p.spacing_min_m),
            Some((_, v)) if v > p.spacing_max_m => (Bound::ConfigMax, p.spacing_max_m),
            Some((b, v)) => (b, v),
        };
        est.active_bound = Some(bound);
        est.spacing.chosen_m = Some(chosen);
        if p.model == Model::Quality {
            let parallax_per_m =
                parallax_per_m.or(est.inv_depth.map(|r| gain * (r.max_per_m - r.min_per_m)));
            est.quality = Some(predict(
                &p.quality,
                est.inv_depth,
                parallax_per_m,
                gain,
                geom.half_extent_px,
                vis.as_ref(),
                chosen,
            ));
            est.basis = Some(PredictionBasis {
                parallax_per_m,
                gain_px: gain,
                half_extent_px: geom.half_extent_px,
                visibility: vis.map(std::sync::Arc::new),
            });
        }

        if want_occlusion {
            est.occlusion = Some(Occlusion {
                boundaries: stats.boundaries,
                lines: stats.lines,
                contrast_per_m: stats.mean_contrast_per_m(),
                density_per_m: density,
                degree: occlusion_degree(density, chosen),
                max_degree: p.occlusion_max,
            });
            if let (Some(sp), true) = (&p.score, est.terms.occlusion) {
                est.terms.score = true;
                let score_step = sp.step_px.max(step);
                let grid = if score_step == step {
                    &self.grid
                } else {
                    fill_grid(
                        image,
                        p.track_axis,
                        score_step,
                        &p.depth_range,
                        &mut self.score_grid,
                    );
                    &self.score_grid
                };
                est.pitch_scores = score(
                    grid,
                    &geom,
                    pitch_rad,
                    &sp.candidates_rad,
                    chosen,
                    p.beta,
                    &bparams,
                    sp.min_coverage,
                );
                est.best_pitch = best(&est.pitch_scores, pitch_rad);
            }
        }
        Ok(est)
    }
}

/// The sampling step of the visibility sweep: the estimate's `step`, or a
/// coarser one both ways so that a grid of `samples` at `step` thins to at most
/// about `samples_max` (docs/error-vs-runtime.md).
pub fn visibility_step(samples: usize, step: usize, samples_max: usize) -> usize {
    let ratio = samples as f64 / samples_max as f64;
    if ratio > 1.0 {
        (step as f64 * ratio.sqrt()).ceil() as usize
    } else {
        step
    }
}

/// Order statistics `ranks` of a set whose `far` smallest members are 0 (far
/// samples) and the rest are what `select` gives at its own ranks.
fn with_far(
    ranks: [u64; 2],
    far: u64,
    select: impl FnOnce([u64; 2]) -> Option<[f32; 2]>,
) -> Option<[f32; 2]> {
    if far == 0 {
        return select(ranks);
    }
    if ranks[1] < far {
        return Some([0.0, 0.0]);
    }
    let [lo, hi] = select(ranks.map(|r| r.saturating_sub(far)))?;
    Some([if ranks[0] < far { 0.0 } else { lo }, hi])
}

/// `FAR` samples whose ray looks below the horizon (the along-track tilt
/// `pitch_rad`, as the rest of the estimate; roll is not known here).
fn far_below_horizon(grid: &InvGrid, geom: &super::depth::TrackGeometry, pitch_rad: f64) -> usize {
    if grid.far == 0 || !(pitch_rad.is_finite() && geom.focal_px > 0.0) {
        return 0;
    }
    let (s, c) = pitch_rad.sin_cos();
    let below = |i: usize| geom.ray_down(i, s, c) > HORIZON_EPS;
    // The downward component is linear in the pixel: the ends decide whether every
    // sample looks down (at nadir, always), and then no sample need be looked at.
    if grid.along_idx.first().is_none_or(|&i| below(i))
        && grid.along_idx.last().is_none_or(|&i| below(i))
    {
        return grid.far;
    }
    let down: Vec<bool> = grid.along_idx.iter().map(|&i| below(i)).collect();
    (0..grid.lines)
        .map(|a| {
            grid.line(a)
                .iter()
                .zip(&down)
                .filter(|&(&w, &d)| d && w == FAR)
                .count()
        })
        .sum()
}

/// The robust span (the percentiles `pct` of the depth range) of the
/// disparity per metre of horizontal baseline over the surface samples and
/// `far` samples beyond the range below the horizon (disparity 0, the
/// smallest). Off nadir the disparity of a sample at along-track offset `u`
/// and across-track offset `v` (px) is `(b/z)·|(f·cos φ − u·sin φ, v·sin φ)|`:
/// the camera also moves along its optical axis by `b·sin φ`, which MMDS's
/// `f·cos φ` leaves out. The truth (`eval::truth`) measures this span, so the
/// parallax target is held on it.
///
/// With `within_m = Some(b)` only the samples both captures of a step `b`
/// keep in frame count (the truth's pixel set: a pixel one capture does not
/// see has no parallax between them): those whose linearised shift by `b/2`
/// either way, along and across track, stays inside the image's edges.
///
/// One call fills the disparities once; [`InFrameSpans`] serves several
/// steps from one fill.
#[allow(clippy::too_many_arguments)]
pub fn disparity_span_per_m(
    grid: &InvGrid,
    geom: &super::depth::TrackGeometry,
    pitch_rad: f64,
    pct: (f64, f64),
    far: u64,
    within_m: Option<f64>,
    scratch: &mut Vec<f32>,
) -> Option<f64> {
    let mut spans = InFrameSpans::new(grid, geom, pitch_rad, pct, far, scratch);
    match within_m {
        None => spans.span_all(),
        Some(b) => spans.span_at(b),
    }
}

/// The spans of [`disparity_span_per_m`] of one frame, over every surface
/// sample and over those both captures of a step keep, from one fill of the
/// disparities and one count of their top 16 bits (a bin is 1/128 of an
/// octave). A step's set is every sample less those that leave the frame,
/// and only samples near an edge can leave (a margin below the largest
/// shift), so a step costs a walk of the edge bands, a look-up in the count
/// less those samples, and one pass for the few values in the percentiles'
/// bins: not a fill, a count and a selection over the frame each (the span
/// in frame was 3 of the 6.4 ms of a 640×480 estimate). An order statistic
/// is a value, so the result is the same bits however it is found.
pub struct InFrameSpans<'a> {
    grid: &'a InvGrid,
    geom: &'a super::depth::TrackGeometry,
    sin_pitch: f64,
    pct: (f64, f64),
    far: u64,
    along_gain: Vec<f64>,
    /// Per sample: its disparity per metre where `w > 0`, else `w` itself.
    values: &'a [f32],
    /// Count of the positive values by their top 16 bits; bins below
    /// [`FINE_FIRST`] (+0.0, the sky, and subnormals) are not counted.
    fine: Vec<u32>,
    /// Sums of `fine` over blocks of [`FINE_BLOCK`] bins.
    blocks: Vec<u32>,
    /// The largest inverse depth of a surface sample (0 if none).
    w_top: f32,
    /// The values (bits) of the bins `gathered_bins`, each ascending (when
    /// both ranks share a bin, the first holds it).
    gathered: [Vec<u32>; 2],
    gathered_bins: [usize; 2],
    leaving_in_bin: Vec<u32>,
}

/// Bins of [`InFrameSpans`]'s count: the top 16 bits of a positive `f32`.
const FINE_BINS: usize = 1 << 15;
/// Values below `2^21` in bits (zero and the smallest subnormals) are left
/// out, as [`Selector::select2`] leaves out its bin 0 without the sky.
const FINE_FIRST: usize = 1 << 5;
const FINE_BLOCK: usize = 64;

/// A value's bin in [`InFrameSpans`]'s count (past the count if negative).
#[inline]
fn fine_bin(v: f32) -> usize {
    (v.to_bits() >> 16) as usize
}

impl<'a> InFrameSpans<'a> {
    pub fn new(
        grid: &'a InvGrid,
        geom: &'a super::depth::TrackGeometry,
        pitch_rad: f64,
        pct: (f64, f64),
        far: u64,
        scratch: &'a mut Vec<f32>,
    ) -> InFrameSpans<'a> {
        let (s, c) = pitch_rad.sin_cos();
        let axis = geom.focal_px * c;
        let along_gain: Vec<f64> = grid
            .along_idx
            .iter()
            .map(|&i| axis - geom.v_px(i) * s)
            .collect();
        let along2: Vec<f64> = along_gain.iter().map(|g| g * g).collect();
        let per_line = grid.per_line;
        // Every value is written below: resizing to the same size writes nothing.
        scratch.resize(grid.w.len(), INVALID);
        let mut gain = vec![0f64; per_line];
        // The `across²` whose gains `gain` holds: at zero pitch every line's.
        let mut gain_of: Option<u64> = None;
        let across = |a: usize| geom.across_px(grid.across_idx[a]) * s;
        // Lines mirrored about the principal point share their gains (the same
        // `across²` bits): each gain row is computed once and serves both.
        let mut done = vec![false; grid.lines];
        for a in 0..grid.lines {
            if done[a] {
                continue;
            }
            let c2 = across(a) * across(a);
            if gain_of != Some(c2.to_bits()) {
                for (g, &g_along2) in gain.iter_mut().zip(&along2) {
                    *g = (g_along2 + c2).sqrt();
                }
                gain_of = Some(c2.to_bits());
            }
            let mirror = grid.lines - 1 - a;
            let pair = (mirror > a && (across(mirror) * across(mirror)).to_bits() == c2.to_bits())
                .then_some(mirror);
            for l in std::iter::once(a).chain(pair) {
                done[l] = true;
                let out = &mut scratch[l * per_line..(l + 1) * per_line];
                for ((o, &w), &g) in out.iter_mut().zip(grid.line(l)).zip(&gain) {
                    // Sky (0) and invalid (negative) stay out of the selection.
                    // Computed for every sample and then chosen, which vectorises.
                    let d = (g * w as f64) as f32;
                    *o = if w > 0.0 { d } else { w };
                }
            }
        }
        // Four interleaved counts (with two, the count was still half of this
        // function's time); negative values (sign bit) fall past the end.
        let mut fine = vec![0u32; 4 * FINE_BINS];
        count4::<FINE_BINS>(&mut fine, scratch, fine_bin);
        fine.truncate(FINE_BINS);
        fine[..FINE_FIRST].fill(0);
        let blocks = fine
            .chunks_exact(FINE_BLOCK)
            .map(|b| b.iter().sum())
            .collect();
        // `f32::max` passes over NaN (no NaN is a surface sample); vectorises.
        let w_top = grid.w.iter().fold(0f32, |m, &w| m.max(w));
        InFrameSpans {
            grid,
            geom,
            sin_pitch: s,
            pct,
            far,
            along_gain,
            values: scratch,
            fine,
            blocks,
            w_top,
            gathered: [Vec::new(), Vec::new()],
            leaving_in_bin: Vec::new(),
            // No value has these bins (they are past the count).
            gathered_bins: [FINE_BINS; 2],
        }
    }

    /// Every surface sample (`w > 0`: valid ones less sky).
    fn surface(&self) -> u64 {
        (self.grid.valid - self.grid.sky) as u64
    }

    /// The span over every surface sample and the `far` ones.
    pub fn span_all(&mut self) -> Option<f64> {
        let ranks = percentile_ranks(self.surface() + self.far, self.pct.0, self.pct.1);
        let [lo, hi] = with_far(ranks, self.far, |r| self.select2(r, &[]))?;
        Some((hi - lo) as f64)
    }

    /// The span over the samples both captures `b` apart keep in frame (and
    /// the `far` ones, which never move).
    pub fn span_at(&mut self, b: f64) -> Option<f64> {
        let (grid, geom) = (self.grid, self.geom);
        // The largest inverse depth a sample may have and stay in both frames:
        // its margin to the nearer edge (pixel edges at index −0.5 and n − 0.5)
        // over its shift per 1/m at `b/2`.
        let limit = |shift_per_w: f64, index: usize, extent: usize| -> f64 {
            let margin = (index as f64 + 0.5).min(extent as f64 - index as f64 - 0.5);
            let shift = 0.5 * b * shift_per_w.abs();
            if shift > 0.0 {
                margin / shift
            } else {
                f64::INFINITY
            }
        };
        let along_max: Vec<f64> = grid
            .along_idx
            .iter()
            .zip(&self.along_gain)
            .map(|(&i, &g)| limit(g, i, geom.along_px))
            .collect();
        let line_max: Vec<f64> = grid
            .across_idx
            .iter()
            .map(|&j| limit(geom.across_px(j) * self.sin_pitch, j, geom.across_px))
            .collect();
        let inside = |w: f32, i: usize, l: usize| (w as f64) <= along_max[i].min(line_max[l]);
        // No sample deeper in than its limit can leave: only the columns and
        // lines whose limit is below the largest inverse depth are walked.
        let w_top = self.w_top as f64;
        let edge_cols: Vec<usize> = (0..grid.per_line)
            .filter(|&i| along_max[i].is_nan() || along_max[i] < w_top)
            .collect();
        // The samples that leave, taken out of the count for this step and
        // put back after it.
        let mut left: Vec<(usize, f32)> = Vec::new();
        let mut leaving = 0u64;
        for (l, &lm) in line_max.iter().enumerate() {
            let line = grid.line(l);
            let values = &self.values[l * grid.per_line..(l + 1) * grid.per_line];
            let mut test = |i: usize| {
                let w = line[i];
                if w > 0.0 && !inside(w, i, l) {
                    leaving += 1;
                    let bin = fine_bin(values[i]);
                    if (FINE_FIRST..FINE_BINS).contains(&bin) {
                        left.push((bin, values[i]));
                    }
                }
            };
            if w_top <= lm {
                edge_cols.iter().for_each(|&i| test(i));
            } else {
                (0..grid.per_line).for_each(&mut test);
            }
        }
        let kept = self.surface() - leaving;
        let ranks = percentile_ranks(kept + self.far, self.pct.0, self.pct.1);
        for &(bin, _) in &left {
            self.fine[bin] -= 1;
            self.blocks[bin / FINE_BLOCK] -= 1;
        }
        let found = with_far(ranks, self.far, |r| self.select2(r, &left));
        for &(bin, _) in &left {
            self.fine[bin] += 1;
            self.blocks[bin / FINE_BLOCK] += 1;
        }
        let [lo, hi] = found?;
        Some((hi - lo) as f64)
    }

    /// The values of 0-based `ranks` among every counted value less the
    /// multiset `left` (`(bin, value)` of the samples that leave, already out
    /// of `fine`); `None` past their number.
    fn select2(&mut self, ranks: [u64; 2], left: &[(usize, f32)]) -> Option<[f32; 2]> {
        let total: u64 = self.blocks.iter().map(|&c| c as u64).sum();
        if ranks.iter().any(|&r| r >= total) {
            return None;
        }
        // The bin holding each rank, by blocks then bins, and the rank in it.
        let locate = |rank: u64| {
            let mut rem = rank;
            let mut bin = 0;
            for (k, &c) in self.blocks.iter().enumerate() {
                if rem < c as u64 {
                    bin = k * FINE_BLOCK;
                    break;
                }
                rem -= c as u64;
            }
            while rem >= self.fine[bin] as u64 {
                rem -= self.fine[bin] as u64;
                bin += 1;
            }
            (bin, rem as usize)
        };
        let at = ranks.map(locate);
        self.gather([at[0].0, at[1].0]);
        let mut out = [0f32; 2];
        for (t, &(bin, rem)) in at.iter().enumerate() {
            // Every value of the bin, ascending (positive floats order as
            // their bits), and those of it that leave, ascending: the
            // `rem`-th of what is kept is the value of `all` at `rem` plus
            // each leaving value at or below it.
            let all = &self.gathered[usize::from(self.gathered_bins[0] != bin)];
            self.leaving_in_bin.clear();
            self.leaving_in_bin
                .extend(left.iter().filter(|l| l.0 == bin).map(|l| l.1.to_bits()));
            self.leaving_in_bin.sort_unstable();
            let mut k = rem;
            for &l in &self.leaving_in_bin {
                match all.get(k) {
                    Some(&v) if l <= v => k += 1,
                    _ => break,
                }
            }
            // The count and the bin's values agree, so `k` is inside.
            debug_assert!(k < all.len(), "{k} of {}", all.len());
            out[t] = f32::from_bits(*all.get(k).or(all.last())?);
        }
        Some(out)
    }

    /// Every value of `bins`, each bin's ascending, unless a pass of this
    /// frame gathered them already (its steps mostly land in the same bins).
    fn gather(&mut self, bins: [usize; 2]) {
        if bins.iter().all(|b| self.gathered_bins.contains(b)) {
            return;
        }
        self.gathered_bins = bins;
        let [g0, g1] = &mut self.gathered;
        g0.clear();
        g1.clear();
        for chunk in self.values.chunks(8) {
            // Without a branch per value (vectorises): most chunks hold none.
            let any = chunk.iter().fold(false, |a, &v| {
                a | (fine_bin(v) == bins[0]) | (fine_bin(v) == bins[1])
            });
            if !any {
                continue;
            }
            for &v in chunk {
                if fine_bin(v) == bins[0] {
                    g0.push(v.to_bits());
                } else if fine_bin(v) == bins[1] {
                    g1.push(v.to_bits());
                }
            }
        }
        g0.sort_unstable();
        g1.sort_unstable();
    }
}

/// Evaluations of the span in frame ([`parallax_in_frame`]): the pixel set
/// changes only at the image's edges, so the spacing settles in two or three.
pub const IN_FRAME_PASSES: usize = 3;

/// The parallax term over the pixels both captures of a step keep in frame:
/// `(span per metre, spacing)`. `all_per_m` is the span over every surface
/// sample; `span_at(b)` the span over those both captures `b` apart keep
/// ([`disparity_span_per_m`] with `within_m`). Starting from `px / all_per_m`,
/// each spacing whose own pixel set's span keeps the parallax within `px` is
/// accepted and the next tried is `px` over that span: fewer pixels, never a
/// larger span, so the spacing only grows. The last spacing accepted is
/// returned with its span, so `span · spacing ≤ px` holds for the pixel set
/// the spacing itself leaves (checked, not assumed: a robust percentile can
/// move outward when pixels leave). Where no pixel stays in both frames, or
/// their span is 0, the term bounds nothing: `(0, None)`, as for a frame of
/// one depth. If no spacing is accepted, `all_per_m`'s, as over every pixel.
pub fn parallax_in_frame(
    all_per_m: f64,
    px: f64,
    mut span_at: impl FnMut(f64) -> Option<f64>,
) -> (f64, Option<f64>) {
    let Some(first) = mmds_m(1.0, all_per_m, 1.0, 0.5 * px) else {
        return (all_per_m, None);
    };
    let mut b = first;
    let mut accepted = None;
    for _ in 0..IN_FRAME_PASSES {
        // No pixel in both frames, or no parallax between them: from here on
        // (fewer pixels still) this term holds nothing back, as over a frame
        // of one depth (the coverage term bounds such a step).
        let span = span_at(b).unwrap_or(0.0);
        if span == 0.0 {
            return (0.0, None);
        }
        // A relative 1e-12: `b = px / span` by division, the product back may
        // round up. A NaN span is not within.
        let within = span * b <= px * (1.0 + 1e-12);
        if !within {
            break;
        }
        accepted = Some((span, b));
        match mmds_m(1.0, span, 1.0, 0.5 * px) {
            Some(next) if next > b => b = next,
            _ => break,
        }
    }
    match accepted {
        Some((span, b)) => (span, Some(b)),
        None => (all_per_m, Some(first)),
    }
}

/// Each target's predicted value at `spacing_m`, from this frame.
fn predict(
    targets: &Quality,
    range: Option<InvDepth>,
    parallax_per_m: Option<f64>,
    gain_px: f64,
    half_extent_px: f64,
    vis: Option<&Visibility>,
    spacing_m: f64,
) -> QualityPrediction {
    let finite = |x: f64| x.is_finite().then_some(x);
    QualityPrediction {
        targets: *targets,
        parallax_px: parallax_per_m.and_then(|d| finite(d * spacing_m)),
        forward_overlap: range.and_then(|r| {
            finite(1.0 - spacing_m * gain_px * r.max_per_m / (2.0 * half_extent_px))
                .map(|o| o.clamp(0.0, 1.0))
        }),
        unseen_fraction: vis
            .filter(|v| v.samples > 0)
            .map(|v| v.unseen_at(spacing_m)),
        views_per_point: vis.and_then(|v| v.interval_min_m).and_then(|l| {
            // floor(L/b) captures fall in an interval of length L whatever the
            // phase (a relative 1e-9 so that b = L/k, as the bound sets it, is k).
            let n = (l / spacing_m * (1.0 + 1e-9)).floor();
            (n.is_finite() && n >= 0.0).then(|| n.min(u32::MAX as f64) as u32)
        }),
    }
}

fn min_opt(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(x), Some(y)) => Some(x.min(y)),
        (x, None) => x,
        (None, y) => y,
    }
}

/// One-shot estimate with fresh buffers (tests, the command line).
pub fn estimate(
    image: &DepthImage,
    intr: &Intrinsics,
    pitch_rad: f64,
    params: &EstimatorParams,
) -> Result<(Estimate, Option<DecimationChoice>), EstimateError> {
    Estimator::new(params.clone()).estimate(image, intr, pitch_rad)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::depth::{DepthData, TrackAxis};
    use crate::inverse::DepthRange;

    /// The span as it was first written (one square root per sample, pushed
    /// in order): the mirrored-line reuse must give the same bits.
    fn span_reference(
        grid: &InvGrid,
        geom: &super::super::depth::TrackGeometry,
        pitch_rad: f64,
        ranks: [u64; 2],
    ) -> Option<f64> {
        let (s, c) = pitch_rad.sin_cos();
        let axis = geom.focal_px * c;
        let mut v = Vec::new();
        for a in 0..grid.lines {
            let across = geom.across_px(grid.across_idx[a]) * s;
            for (&w, &i) in grid.line(a).iter().zip(&grid.along_idx) {
                let g = axis - geom.v_px(i) * s;
                v.push(if w > 0.0 {
                    ((g * g + across * across).sqrt() * w as f64) as f32
                } else {
                    w
                });
            }
        }
        let [lo, hi] = Selector::default().select2(&v, false, ranks)?;
        Some((hi - lo) as f64)
    }

    #[test]
    fn relative_excess_counts_only_the_longer_side() {
        assert_eq!(relative_excess(Some(3.0), Some(2.0)), 0.5);
        assert_eq!(relative_excess(Some(1.0), Some(2.0)), 0.0);
        assert_eq!(relative_excess(None, Some(2.0)), f64::INFINITY);
        assert_eq!(relative_excess(Some(1.0), None), 0.0);
        assert_eq!(relative_excess(None, None), 0.0);
    }

    #[test]
    fn disparity_span_equals_one_root_per_sample() {
        let (w, h) = (96usize, 61usize);
        let data: Vec<f32> = (0..w * h)
            .map(|i| match i % 37 {
                0 => 0.0,
                1 => f32::INFINITY,
                k => 10.0 + (i % w) as f32 * 0.3 + k as f32 * 0.11,
            })
            .collect();
        let img = DepthImage::new(w, h, DepthData::Metres(data)).unwrap();
        for cy in [None, Some((30.0, 30.0)), Some((47.5, 23.25))] {
            let intr = Intrinsics::from_hfov_deg(w, h, 69.0, cy).unwrap();
            for axis in [TrackAxis::Rows, TrackAxis::Columns] {
                for step in [1usize, 2, 3] {
                    let mut grid = InvGrid::default();
                    fill_grid(&img, axis, step, &DepthRange::default(), &mut grid);
                    let geom = intr.track(axis);
                    let n = (grid.valid - grid.sky) as u64;
                    for pitch in [0.3f64, -0.7, 1.2] {
                        for pct in [(0.005, 0.995), (0.0, 1.0)] {
                            let ranks = percentile_ranks(n, pct.0, pct.1);
                            let got = disparity_span_per_m(
                                &grid,
                                &geom,
                                pitch,
                                pct,
                                0,
                                None,
                                &mut Vec::new(),
                            );
                            let want = span_reference(&grid, &geom, pitch, ranks);
                            assert_eq!(
                                got.map(f64::to_bits),
                                want.map(f64::to_bits),
                                "{cy:?} {axis:?} step {step} pitch {pitch}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// The span over the samples both captures `b` apart keep in frame, by
    /// moving each sample's image position `b/2` each way and asking whether
    /// both positions are inside the image (index −0.5 to n − 0.5).
    fn span_in_frame_reference(
        grid: &InvGrid,
        geom: &super::super::depth::TrackGeometry,
        pitch_rad: f64,
        pct: (f64, f64),
        b: f64,
    ) -> Option<f64> {
        let (s, c) = pitch_rad.sin_cos();
        let axis = geom.focal_px * c;
        let inside = |x: f64, n: usize| (-0.5..=n as f64 - 0.5).contains(&x);
        let mut v = Vec::new();
        for a in 0..grid.lines {
            let j = grid.across_idx[a];
            let across = geom.across_px(j) * s;
            for (&w, &i) in grid.line(a).iter().zip(&grid.along_idx) {
                let g = axis - geom.v_px(i) * s;
                let w64 = w as f64;
                let kept = [-0.5 * b, 0.5 * b].iter().all(|&h| {
                    inside(i as f64 + h * g * w64, geom.along_px)
                        && inside(j as f64 + h * across * w64, geom.across_px)
                });
                if w > 0.0 && kept {
                    v.push(((g * g + across * across).sqrt() * w64) as f32);
                }
            }
        }
        let ranks = percentile_ranks(v.len() as u64, pct.0, pct.1);
        let [lo, hi] = Selector::default().select2(&v, false, ranks)?;
        Some((hi - lo) as f64)
    }

    /// One fill serving many steps, in any order, on depth in plateaus (runs
    /// of equal disparities, as Z16 ground gives, across the percentiles'
    /// bins and the edges): every span the same bits as the reference's. The
    /// second frame's sample count is not a multiple of the count's four
    /// lanes, and the scratch comes from the frames before (stale values).
    #[test]
    fn one_fill_serves_every_step_with_the_reference_spans() {
        let mut scratch = vec![f32::NAN; 7000];
        for (w, h) in [(90usize, 70usize), (91, 69)] {
            one_fill_on(w, h, &mut scratch);
        }
    }

    fn one_fill_on(w: usize, h: usize, scratch: &mut Vec<f32>) {
        let data: Vec<f32> = (0..w * h)
            .map(|k| {
                let (u, r) = (k % w, k / w);
                if k % 53 == 0 {
                    0.0
                } else {
                    // Half-metre plateaus from 9 to 14 m, a roof block at 6 m.
                    let d = 9.0 + ((u + 2 * r) / 40) as f32 * 0.5;
                    if (30..50).contains(&u) && (20..40).contains(&r) {
                        6.0
                    } else {
                        d
                    }
                }
            })
            .collect();
        let img = DepthImage::new(w, h, DepthData::Metres(data)).unwrap();
        let intr = Intrinsics::from_hfov_deg(w, h, 69.0, None).unwrap();
        for axis in [TrackAxis::Rows, TrackAxis::Columns] {
            let mut grid = InvGrid::default();
            fill_grid(&img, axis, 1, &DepthRange::default(), &mut grid);
            let geom = intr.track(axis);
            for pitch in [0.0f64, 0.4] {
                for pct in [(0.005, 0.995), (0.1, 0.9), (0.5, 0.5)] {
                    let mut spans = InFrameSpans::new(&grid, &geom, pitch, pct, 0, scratch);
                    assert!(spans.span_all().is_some());
                    for b in [0.3, 1.0, 2.5, 0.1, 6.0, 1.0, 40.0] {
                        let want = span_in_frame_reference(&grid, &geom, pitch, pct, b);
                        assert_eq!(
                            spans.span_at(b).map(f64::to_bits),
                            want.map(f64::to_bits),
                            "{axis:?} pitch {pitch} pct {pct:?} b {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn the_span_in_frame_counts_what_both_captures_keep() {
        let (w, h) = (96usize, 61usize);
        // Near ground with a slope, and the forward edge far away: the
        // samples there leave the frame last, but their disparity is the smallest.
        let data: Vec<f32> = (0..w * h)
            .map(|k| {
                let (u, r) = (k % w, k / w);
                if k % 41 == 0 {
                    0.0
                } else if u >= w - 2 {
                    60.0
                } else {
                    8.0 + u as f32 * 0.05 + r as f32 * 0.02
                }
            })
            .collect();
        let img = DepthImage::new(w, h, DepthData::Metres(data)).unwrap();
        for cy in [None, Some((40.0, 20.0))] {
            let intr = Intrinsics::from_hfov_deg(w, h, 69.0, cy).unwrap();
            for axis in [TrackAxis::Rows, TrackAxis::Columns] {
                for step in [1usize, 2] {
                    let mut grid = InvGrid::default();
                    fill_grid(&img, axis, step, &DepthRange::default(), &mut grid);
                    let geom = intr.track(axis);
                    for pitch in [0.0f64, 0.3, -0.7] {
                        for b in [0.05, 0.4, 1.5, 6.0] {
                            for pct in [(0.005, 0.995), (0.0, 1.0)] {
                                let got = disparity_span_per_m(
                                    &grid,
                                    &geom,
                                    pitch,
                                    pct,
                                    0,
                                    Some(b),
                                    &mut Vec::new(),
                                );
                                let want = span_in_frame_reference(&grid, &geom, pitch, pct, b);
                                assert_eq!(
                                    got.map(f64::to_bits),
                                    want.map(f64::to_bits),
                                    "{cy:?} {axis:?} step {step} pitch {pitch} b {b}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_spacing_in_frame_keeps_its_own_pixels_within_the_target() {
        // A span that shrinks as pixels leave the frame.
        let span_at = |b: f64| Some(if b < 0.9 { 2.5 } else { 2.0 });
        let (per_m, b) = parallax_in_frame(3.0, 2.0, span_at);
        let b = b.unwrap();
        assert!(b > 2.0 / 3.0, "{b}");
        assert!(per_m * b <= 2.0 * (1.0 + 1e-12), "{per_m} {b}");
        assert_eq!(span_at(b), Some(per_m));
        // Settled where the spacing's own span gives the spacing back (it does
        // not jump to 1.0, where the span would be 2.0: that spacing is never
        // reached from below).
        assert_eq!((per_m, b), (2.5, 0.8));
        // A span that grows when pixels leave (a percentile moving outward):
        // no spacing beyond the one over every pixel is accepted.
        assert_eq!(
            parallax_in_frame(3.0, 2.0, |_| Some(3.5)),
            (3.0, Some(2.0 / 3.0))
        );
        // No pixel left in both frames, or none with parallax: nothing to hold.
        assert_eq!(parallax_in_frame(3.0, 2.0, |_| None), (0.0, None));
        assert_eq!(
            parallax_in_frame(3.0, 2.0, |b| Some(if b < 0.7 { 2.5 } else { 0.0 })),
            (0.0, None)
        );
        // No span at all, a degenerate target.
        assert_eq!(parallax_in_frame(0.0, 2.0, |_| Some(1.0)), (0.0, None));
        assert_eq!(parallax_in_frame(f64::NAN, 2.0, |_| Some(1.0)).1, None);
        let (per_m, b) = parallax_in_frame(3.0, 2.0, |_| Some(f64::NAN));
        assert_eq!((per_m, b), (3.0, Some(2.0 / 3.0)));
    }

    #[test]
    fn far_ground_entering_the_forward_edge_does_not_shorten_the_spacing() {
        // Ground 10 m below with a gentle slope; the last along-track column
        // looks past an edge at ground 20 m away. The captures of a step do
        // not both see that column, so its disparity is not a parallax between them.
        let (w, h) = (120usize, 90usize);
        let depth = |far_edge: bool| -> Vec<f32> {
            (0..w * h)
                .map(|k| {
                    let (u, r) = (k % w, k / w);
                    if far_edge && u == w - 1 {
                        20.0
                    } else {
                        10.0 + u as f32 * 0.02 + r as f32 * 0.01
                    }
                })
                .collect()
        };
        let intr = Intrinsics::from_hfov_deg(w, h, 69.0, None).unwrap();
        let params = EstimatorParams::default();
        for pitch in [0.0f64, 0.2] {
            let spacing = |far_edge: bool| {
                let img = DepthImage::new(w, h, DepthData::Metres(depth(far_edge))).unwrap();
                estimate_at_step(&img, &intr, pitch, &params)
                    .spacing
                    .parallax_m
                    .unwrap()
            };
            let (plain, with_edge) = (spacing(false), spacing(true));
            // Over every pixel the far column would shorten it by a third or more.
            let mut grid = InvGrid::default();
            let img = DepthImage::new(w, h, DepthData::Metres(depth(true))).unwrap();
            fill_grid(&img, params.track_axis, 1, &params.depth_range, &mut grid);
            let all = disparity_span_per_m(
                &grid,
                &intr.track(params.track_axis),
                pitch,
                (params.percentile_low, params.percentile_high),
                0,
                None,
                &mut Vec::new(),
            )
            .unwrap();
            assert!(
                2.0 / all < 0.67 * plain,
                "pitch {pitch}: {} {plain}",
                2.0 / all
            );
            assert!(
                (with_edge / plain - 1.0).abs() < 0.02,
                "pitch {pitch}: {with_edge} against {plain}"
            );
        }
    }

    fn estimate_at_step(
        img: &DepthImage,
        intr: &Intrinsics,
        pitch: f64,
        params: &EstimatorParams,
    ) -> Estimate {
        Estimator::new(params.clone())
            .estimate_at(img, intr, pitch, 1)
            .unwrap()
    }
}
