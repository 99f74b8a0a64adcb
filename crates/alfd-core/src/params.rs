//! Estimator parameters, typed and validated once: every later stage may take
//! them as given. Defaults follow DESIGN §1; the reasons for each are in
//! `docs/estimator.md`.

use super::depth::TrackAxis;
use super::inverse::DepthRange;
use thiserror::Error;

/// Which sampling model decides the spacing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Model {
    /// The largest spacing meeting every quality target the operator states
    /// (`[quality]`, DESIGN §1): parallax, forward overlap, unseen fraction,
    /// views per point.
    #[default]
    Quality,
    /// The paper's occlusion-aware ALF sampling: `min(MMDS, O_max/ρ)`.
    Occlusion,
    Mmds,
    Sspa,
    /// A fixed distance, as `TRIG_DISTANCE` / `CAM_TRIGG_DIST` would give.
    Fixed,
}

impl Model {
    pub fn as_str(self) -> &'static str {
        match self {
            Model::Quality => "quality",
            Model::Occlusion => "occlusion",
            Model::Mmds => "mmds",
            Model::Sspa => "sspa",
            Model::Fixed => "fixed",
        }
    }
    /// Every model, the default first: the one list the config, the flags and their help
    /// read (names from [`Model::as_str`]).
    pub const ALL: [Model; 5] = [
        Model::Quality,
        Model::Occlusion,
        Model::Mmds,
        Model::Sspa,
        Model::Fixed,
    ];
    pub fn parse(s: &str) -> Option<Model> {
        Model::ALL.into_iter().find(|m| m.as_str() == s)
    }
}

/// A set of quality targets for a kind of reconstruction (DESIGN §1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Profile {
    /// Light-field / novel-view rendering: parallax 2 px, unseen 0.002, k = 2.
    #[default]
    Lightfield,
    /// Photogrammetry and Gaussian splatting: parallax as 80 % forward overlap
    /// at the nearest depth, unseen 0.002, k = 3.
    Mapping,
}

impl Profile {
    pub fn as_str(self) -> &'static str {
        match self {
            Profile::Lightfield => "lightfield",
            Profile::Mapping => "mapping",
        }
    }
    /// Every profile, the default first (names from [`Profile::as_str`]).
    pub const ALL: [Profile; 2] = [Profile::Lightfield, Profile::Mapping];
    pub fn parse(s: &str) -> Option<Profile> {
        Profile::ALL.into_iter().find(|p| p.as_str() == s)
    }
    /// The profile's targets, before any set directly.
    pub fn targets(self) -> Quality {
        match self {
            Profile::Lightfield => Quality {
                profile: self,
                parallax_px: Some(2.0),
                forward_overlap: None,
                unseen_fraction_max: 0.002,
                views_per_point_min: 2,
            },
            Profile::Mapping => Quality {
                profile: self,
                parallax_px: None,
                forward_overlap: Some(0.8),
                unseen_fraction_max: 0.002,
                views_per_point_min: 3,
            },
        }
    }
}

/// The quality targets in force (`[quality]`): the spacing is the largest that
/// meets every one. A target that is `None` is not in force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quality {
    pub profile: Profile,
    /// Largest disparity range between neighbouring captures, px (Chai's
    /// bound: `2·Δv/c_tex`).
    pub parallax_px: Option<f64>,
    /// Least forward overlap of neighbouring captures at the nearest depth.
    pub forward_overlap: Option<f64>,
    /// Largest fraction of an in-between view neither neighbour sees (1: off).
    pub unseen_fraction_max: f64,
    /// Captures every visible surface point must be in (1: coverage only).
    pub views_per_point_min: u32,
}

impl Default for Quality {
    fn default() -> Self {
        Profile::default().targets()
    }
}

impl Quality {
    /// `unseen_fraction_max` not in force: every view may go unseen.
    pub const UNSEEN_OFF: f64 = 1.0;
    /// `views_per_point_min` not in force: seen once, the coverage bound.
    pub const VIEWS_OFF: u32 = 1;
}

/// The disparity gain an occlusion edge's contrast is multiplied by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GainModel {
    /// DESIGN §1: `f·cos φ`, the gain on the optical axis, for every edge.
    #[default]
    Axis,
    /// The exact first-order gain at the edge's own pixel, `f·cos φ − v·sin φ`
    /// (`docs/occlusion-check.md`: removes the `(v/f)·tan φ` bias off nadir).
    Pixel,
}

/// How finely the depth map is sampled.
#[derive(Debug, Clone, PartialEq)]
pub enum Decimation {
    /// Every `n`-th pixel along and across track.
    Fixed(usize),
    /// The coarsest of `levels` whose spacing stays within `budget` (relative)
    /// of full resolution on the frame it is calibrated on, calibrated again
    /// after `recalibrate_frames` frames at that level.
    Auto {
        budget: f64,
        levels: Vec<usize>,
        recalibrate_frames: usize,
    },
}

impl Decimation {
    /// `Auto` with the default budget, levels and recalibration period.
    pub fn auto() -> Decimation {
        Decimation::Auto {
            budget: DECIMATION_BUDGET,
            levels: DECIMATION_LEVELS.to_vec(),
            recalibrate_frames: AUTO_RECALIBRATE_FRAMES,
        }
    }
}

/// `Decimation::Auto`'s default budget: 5 % of the full-resolution spacing.
pub const DECIMATION_BUDGET: f64 = 0.05;

/// Frames `Decimation::Auto` estimates at its calibrated level before calibrating again by
/// default (a second at 30 fps): calibrating costs a full-resolution estimate, so doing it on
/// every frame would cost more than never decimating (`docs/performance.md`).
pub const AUTO_RECALIBRATE_FRAMES: usize = 30;

pub const DECIMATION_LEVELS: [usize; 5] = [1, 2, 4, 8, 16];

/// The occlusion score (eq. 15) over candidate pitches.
#[derive(Debug, Clone, PartialEq)]
pub struct ScoreParams {
    pub candidates_rad: Vec<f64>,
    /// Sampling stride for the score, pixels (at least the estimate's own).
    pub step_px: usize,
    /// Least fraction of a candidate's view this frame must cover.
    pub min_coverage: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorParams {
    pub model: Model,
    /// The targets of `Model::Quality` (other models ignore them).
    pub quality: Quality,
    /// Compute SSPA even when the model does not need it (comparisons).
    pub with_sspa: bool,
    /// Compute the occlusion term even when the model does not need it.
    pub with_occlusion: bool,
    pub score: Option<ScoreParams>,
    /// `O_max`, the largest tolerated occlusion degree per step.
    pub occlusion_max: f64,
    /// `β`, the ray weight of eq. 2/6.
    pub beta: f64,
    /// `c_tex`, texture bandwidth as a fraction of the pixel Nyquist rate.
    pub texture_bandwidth: f64,
    /// `Δv`, the disparity tolerance, pixels.
    pub disparity_tolerance_px: f64,
    pub overlap_min: f64,
    pub spacing_min_m: f64,
    pub spacing_max_m: f64,
    pub fixed_spacing_m: f64,
    pub valid_fraction_min: f64,
    pub percentile_low: f64,
    pub percentile_high: f64,
    pub tau_abs_per_m: f64,
    pub tau_rel: f64,
    pub max_gap_px: usize,
    pub sky_is_scene: bool,
    pub depth_range: DepthRange,
    pub pitch_max_rad: f64,
    pub track_axis: TrackAxis,
    pub gain_model: GainModel,
    pub decimation: Decimation,
    pub sspa_iterations: usize,
    pub sspa_trim_sigma: f64,
    /// The visibility sweep samples the frame more coarsely than the estimate
    /// when the estimate's grid has more samples than this: its cost per
    /// sample is ~25 reads, and at 640 × 480 it starved the daemon's camera
    /// and writer (docs/error-vs-runtime.md has the error it costs).
    pub visibility_samples_max: usize,
    /// A frame of a flight ([`crate::Estimator::estimate`]) sweeps one in this
    /// many lines across track for the visibility term and keeps the others'
    /// newest sweeps from the frames before; the views bound takes the
    /// shortest interval any of the last `2 ×` this many frames found (1:
    /// every line every frame, nothing held; `visibility::Interleave`).
    /// `visibility_samples_max` then bounds the samples one frame sweeps.
    pub visibility_interleave: usize,
    /// With `visibility_interleave` above 1, a frame whose own lines came out
    /// tighter than on their own last turn sweeps every line
    /// (`visibility::Interleave::refreshing`): where an occluder enters the view
    /// the kept lines are stale. A shorter interval does so only where the
    /// views spacing could decide the frame's spacing. Every frame also sweeps
    /// the lines beside the one holding the shortest interval
    /// (`visibility::Interleave::watching`): a narrow gap's floor shows there
    /// at some sub-pixel phases only, for a frame.
    pub visibility_refresh: bool,
}

impl EstimatorParams {
    /// The visibility term's parameters as the estimator runs it: the quality
    /// targets, the default phases, the middle half of the lines for the views.
    pub fn visibility_params(&self) -> crate::visibility::VisibilityParams {
        crate::visibility::VisibilityParams {
            unseen_fraction_max: self.quality.unseen_fraction_max,
            views_per_point_min: self.quality.views_per_point_min,
            phases: crate::visibility::DEFAULT_PHASES,
            views_band: 0.5,
            ..crate::visibility::VisibilityParams::default()
        }
    }

    /// How one frame sweeps the visibility term on a grid of `samples` at
    /// `step`, as `(stride, step)`: one in `stride` lines (`visibility_interleave`
    /// for a frame of a flight, else every line), every `step`-th pixel both
    /// ways, coarser than the grid where the frame's share of the lines would
    /// exceed `visibility_samples_max`. A flight's frame whose share would
    /// exceed it takes fewer lines first, up to one in
    /// [`VISIBILITY_INTERLEAVE_MAX`], and keeps every pixel: a coarser grid
    /// leaves the narrowest gaps' floors out of every frame, a longer turn only
    /// sees them later (at 848 × 480 and the defaults, one line in 6 at every
    /// pixel instead of one in 4 at every second: docs/error-vs-runtime.md).
    pub fn visibility_sampling(
        &self,
        samples: usize,
        step: usize,
        in_flight: bool,
    ) -> (usize, usize) {
        let mut stride = if in_flight {
            self.visibility_interleave.max(1)
        } else {
            1
        };
        let max = self.visibility_samples_max.max(1);
        if stride > 1 && samples.div_ceil(stride) > max {
            let needed = samples.div_ceil(max);
            if needed <= VISIBILITY_INTERLEAVE_MAX {
                stride = stride.max(needed);
            }
        }
        let vstep = crate::estimate::visibility_step(
            samples.div_ceil(stride),
            step,
            self.visibility_samples_max,
        );
        (stride, vstep)
    }
}

/// Most frames one visibility sweep may be spread over: at 30 fps, a line's
/// sweep at most a quarter of a second old.
pub const VISIBILITY_INTERLEAVE_MAX: usize = 8;

impl Default for EstimatorParams {
    fn default() -> Self {
        EstimatorParams {
            model: Model::Quality,
            quality: Quality::default(),
            with_sspa: false,
            with_occlusion: false,
            score: Some(ScoreParams {
                candidates_rad: (-9..=9).map(|k| (k as f64 * 5.0).to_radians()).collect(),
                step_px: 8,
                min_coverage: 0.75,
            }),
            occlusion_max: 0.01,
            beta: 1.0,
            texture_bandwidth: 1.0,
            disparity_tolerance_px: 1.0,
            overlap_min: 0.6,
            spacing_min_m: 0.05,
            spacing_max_m: 100.0,
            fixed_spacing_m: 5.0,
            valid_fraction_min: 0.2,
            percentile_low: 0.005,
            percentile_high: 0.995,
            tau_abs_per_m: 1e-4,
            tau_rel: 0.03,
            max_gap_px: 8,
            sky_is_scene: false,
            depth_range: DepthRange::default(),
            pitch_max_rad: 80f64.to_radians(),
            track_axis: TrackAxis::Rows,
            gain_model: GainModel::Axis,
            decimation: Decimation::Fixed(1),
            sspa_iterations: 3,
            sspa_trim_sigma: 2.5,
            visibility_samples_max: 80_000,
            // At 640 × 480, every pixel once in four frames costs what every
            // second pixel both ways on every frame did, and misses far less
            // (docs/error-vs-runtime.md, "Spreading the sweep over frames").
            visibility_interleave: 4,
            visibility_refresh: true,
        }
    }
}

/// A parameter out of its range, named by its config path.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("{field}: {message}")]
pub struct ParamError {
    pub field: &'static str,
    pub message: String,
}

fn check(
    ok: bool,
    field: &'static str,
    message: impl FnOnce() -> String,
) -> Result<(), ParamError> {
    if ok {
        Ok(())
    } else {
        Err(ParamError {
            field,
            message: message(),
        })
    }
}

fn in_range(x: f64, lo: f64, hi: f64) -> bool {
    x.is_finite() && x >= lo && x <= hi
}

impl EstimatorParams {
    /// The defaults with another model (the tests of the paper's occlusion
    /// model, the comparisons).
    pub fn with_model(model: Model) -> Self {
        EstimatorParams {
            model,
            ..EstimatorParams::default()
        }
    }

    /// Samples a frame's grid needs for its robust depth range to be robust:
    /// with fewer than `1 / percentile_low`, the low percentile's rank is the
    /// first sample and the range is the extremes of a few samples (at
    /// decimation 256 a 320 × 240 frame is one sample, and its spacing 63×
    /// the full frame's).
    pub fn grid_samples_min(&self) -> usize {
        if self.percentile_low > 0.0 {
            (1.0 / self.percentile_low - 1e-9).ceil() as usize
        } else {
            2
        }
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        let p = self;
        let q = &p.quality;
        if let Some(v) = q.parallax_px {
            check(in_range(v, 1e-3, 1e4), "quality.parallax_px", || {
                format!("must be in [0.001, 10000] px, got {v}")
            })?;
        }
        if let Some(v) = q.forward_overlap {
            check(in_range(v, 0.0, 0.99), "quality.forward_overlap", || {
                format!("must be in [0, 0.99], got {v}")
            })?;
        }
        check(
            in_range(q.unseen_fraction_max, 1e-6, 1.0),
            "quality.unseen_fraction_max",
            || {
                format!(
                    "must be in [0.000001, 1] (1, or false, turns it off), got {}",
                    q.unseen_fraction_max
                )
            },
        )?;
        check(
            (1..=100).contains(&q.views_per_point_min),
            "quality.views_per_point_min",
            || {
                format!(
                    "must be a whole number from 1 to 100, got {}",
                    q.views_per_point_min
                )
            },
        )?;
        check(
            p.model != Model::Quality || q.parallax_px.is_some() || q.forward_overlap.is_some(),
            "quality.parallax_px",
            || {
                "the quality model needs parallax_px or forward_overlap: without either nothing bounds the spacing on open ground".into()
            },
        )?;
        check(
            p.occlusion_max > 0.0 && p.occlusion_max <= 1.0,
            "sampling.occlusion_max",
            || format!("must be in (0, 1], got {}", p.occlusion_max),
        )?;
        check(p.beta > 0.0 && p.beta.is_finite(), "sampling.beta", || {
            format!("must be finite and positive, got {}", p.beta)
        })?;
        check(
            p.texture_bandwidth > 0.0 && p.texture_bandwidth <= 1.0,
            "sampling.texture_bandwidth",
            || format!("must be in (0, 1], got {}", p.texture_bandwidth),
        )?;
        check(
            in_range(p.disparity_tolerance_px, 1e-3, 1e3),
            "sampling.disparity_tolerance_px",
            || {
                format!(
                    "must be in [0.001, 1000] px, got {}",
                    p.disparity_tolerance_px
                )
            },
        )?;
        check(
            in_range(p.overlap_min, 0.0, 0.99),
            "sampling.overlap_min",
            || format!("must be in [0, 0.99], got {}", p.overlap_min),
        )?;
        check(
            in_range(p.spacing_min_m, 1e-6, 1e6),
            "sampling.spacing_min_m",
            || format!("must be in [1e-6, 1e6] m, got {}", p.spacing_min_m),
        )?;
        check(
            in_range(p.spacing_max_m, p.spacing_min_m, 1e6),
            "sampling.spacing_max_m",
            || {
                format!(
                    "must be at least spacing_min_m ({}) and at most 1e6 m, got {}",
                    p.spacing_min_m, p.spacing_max_m
                )
            },
        )?;
        check(
            in_range(p.fixed_spacing_m, 1e-6, 1e6),
            "sampling.fixed_spacing_m",
            || format!("must be in [1e-6, 1e6] m, got {}", p.fixed_spacing_m),
        )?;
        check(
            in_range(p.valid_fraction_min, 0.0, 1.0),
            "estimator.valid_fraction_min",
            || format!("must be in [0, 1], got {}", p.valid_fraction_min),
        )?;
        check(
            in_range(p.percentile_low, 0.0, 0.5),
            "estimator.percentile_low",
            || format!("must be in [0, 0.5], got {}", p.percentile_low),
        )?;
        check(
            in_range(p.percentile_high, 0.5, 1.0) && p.percentile_high >= p.percentile_low,
            "estimator.percentile_high",
            || format!("must be in [0.5, 1], got {}", p.percentile_high),
        )?;
        check(
            in_range(p.tau_abs_per_m, 0.0, 1e3),
            "estimator.tau_abs_per_m",
            || format!("must be in [0, 1000] 1/m, got {}", p.tau_abs_per_m),
        )?;
        check(in_range(p.tau_rel, 0.0, 10.0), "estimator.tau_rel", || {
            format!("must be in [0, 10], got {}", p.tau_rel)
        })?;
        check(
            p.tau_abs_per_m > 0.0 || p.tau_rel > 0.0,
            "estimator.tau_abs_per_m",
            || {
                "tau_abs_per_m and tau_rel cannot both be 0: every rounding step would be an edge"
                    .into()
            },
        )?;
        check(
            p.depth_range.min_m >= 0.0
                && !p.depth_range.min_m.is_nan()
                && !p.depth_range.max_m.is_nan()
                && p.depth_range.max_m > p.depth_range.min_m,
            "estimator.depth_max_m",
            || {
                format!(
                    "valid depths need 0 <= depth_min_m < depth_max_m, got {} and {}",
                    p.depth_range.min_m, p.depth_range.max_m
                )
            },
        )?;
        check(
            in_range(p.pitch_max_rad.to_degrees(), 0.0, 89.0),
            "estimator.pitch_max_deg",
            || {
                format!(
                    "must be in [0, 89] degrees, got {}",
                    p.pitch_max_rad.to_degrees()
                )
            },
        )?;
        match &p.decimation {
            Decimation::Fixed(n) => check((1..=256).contains(n), "estimator.decimation", || {
                format!("must be \"auto\" or a stride from 1 to 256, got {n}")
            })?,
            Decimation::Auto {
                budget,
                levels,
                recalibrate_frames,
            } => {
                check(
                    (1..=100_000).contains(recalibrate_frames),
                    "estimator.decimation_recalibrate_frames",
                    || format!("must be from 1 to 100000 frames, got {recalibrate_frames}"),
                )?;
                check(
                    in_range(*budget, 0.0, 1.0),
                    "estimator.decimation_budget",
                    || format!("must be in [0, 1], got {budget}"),
                )?;
                check(
                    !levels.is_empty() && levels.iter().all(|n| (1..=256).contains(n)),
                    "estimator.decimation_levels",
                    || "must list strides from 1 to 256".into(),
                )?;
            }
        }
        check(
            p.visibility_samples_max >= 100,
            "estimator.visibility_samples_max",
            || format!("must be at least 100, got {}", p.visibility_samples_max),
        )?;
        check(
            (1..=VISIBILITY_INTERLEAVE_MAX).contains(&p.visibility_interleave),
            "estimator.visibility_interleave",
            || {
                format!(
                    "must be in [1, {VISIBILITY_INTERLEAVE_MAX}], got {}",
                    p.visibility_interleave
                )
            },
        )?;
        check(
            (1..=100).contains(&p.sspa_iterations),
            "estimator.sspa_iterations",
            || format!("must be in [1, 100], got {}", p.sspa_iterations),
        )?;
        check(
            in_range(p.sspa_trim_sigma, 0.5, 100.0),
            "estimator.sspa_trim_sigma",
            || format!("must be in [0.5, 100], got {}", p.sspa_trim_sigma),
        )?;
        if let Some(s) = &p.score {
            check(
                !s.candidates_rad.is_empty()
                    && s.candidates_rad
                        .iter()
                        .all(|c| c.is_finite() && c.abs() <= p.pitch_max_rad),
                "score.pitch_candidates_deg",
                || "candidates must be finite and within pitch_max_deg".into(),
            )?;
            check((1..=256).contains(&s.step_px), "score.decimation", || {
                format!("must be in [1, 256], got {}", s.step_px)
            })?;
            check(
                in_range(s.min_coverage, 0.0, 1.0),
                "score.min_coverage",
                || format!("must be in [0, 1], got {}", s.min_coverage),
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{EstimatorParams, Model, Profile, VISIBILITY_INTERLEAVE_MAX};

    /// A flight's frame over `visibility_samples_max` takes fewer lines before
    /// a coarser grid, up to one in `VISIBILITY_INTERLEAVE_MAX`; beyond that,
    /// a single frame, or every line asked for, thins the grid as before.
    #[test]
    fn a_flight_over_the_sample_budget_takes_fewer_lines_before_fewer_pixels() {
        let p = EstimatorParams::default();
        assert_eq!(
            (p.visibility_interleave, p.visibility_samples_max),
            (4, 80_000)
        );
        let px = |w: usize, h: usize| w * h;
        // 76,800 a frame: within the budget.
        assert_eq!(p.visibility_sampling(px(640, 480), 1, true), (4, 1));
        // 407,040: a quarter is 101,760; a sixth, 67,840, at every pixel.
        assert_eq!(p.visibility_sampling(px(848, 480), 1, true), (6, 1));
        // At decimation 2 a quarter of 848 × 480 is within it.
        assert_eq!(p.visibility_sampling(px(424, 240), 2, true), (4, 2));
        // 921,600 needs 12 turns, over the most: a quarter, every second pixel.
        assert!(921_600usize.div_ceil(80_000) > VISIBILITY_INTERLEAVE_MAX);
        assert_eq!(p.visibility_sampling(px(1280, 720), 1, true), (4, 2));
        // A single frame, and a flight asking for every line, thin the grid.
        assert_eq!(p.visibility_sampling(px(848, 480), 1, false), (1, 3));
        let every_line = EstimatorParams {
            visibility_interleave: 1,
            ..p.clone()
        };
        assert_eq!(
            every_line.visibility_sampling(px(848, 480), 1, true),
            (1, 3)
        );
        // A larger turn asked for is kept; a budget that fits keeps the turn.
        let eight = EstimatorParams {
            visibility_interleave: 8,
            ..p.clone()
        };
        assert_eq!(eight.visibility_sampling(px(848, 480), 1, true), (8, 1));
        let roomy = EstimatorParams {
            visibility_interleave: 2,
            visibility_samples_max: 307_200,
            ..p
        };
        assert_eq!(roomy.visibility_sampling(px(848, 480), 1, true), (2, 1));
    }

    /// The lists are the one table of names: every variant is in its list (a new variant
    /// stops the matches compiling until it has an index here), and every name parses
    /// back to its variant.
    #[test]
    fn every_model_and_profile_is_listed_and_its_name_parses_back() {
        let model_index = |m: Model| match m {
            Model::Quality => 0,
            Model::Occlusion => 1,
            Model::Mmds => 2,
            Model::Sspa => 3,
            Model::Fixed => 4,
        };
        let mut listed = [false; 5];
        for m in Model::ALL {
            listed[model_index(m)] = true;
            assert_eq!(Model::parse(m.as_str()), Some(m));
        }
        assert!(listed.iter().all(|&l| l), "a model missing from Model::ALL");
        let profile_index = |p: Profile| match p {
            Profile::Lightfield => 0,
            Profile::Mapping => 1,
        };
        let mut listed = [false; 2];
        for p in Profile::ALL {
            listed[profile_index(p)] = true;
            assert_eq!(Profile::parse(p.as_str()), Some(p));
        }
        assert!(
            listed.iter().all(|&l| l),
            "a profile missing from Profile::ALL"
        );
        assert_eq!(Model::ALL[0], Model::default());
        assert_eq!(Profile::ALL[0], Profile::default());
        assert_eq!(Model::parse("Quality"), None, "names are exact");
    }
}
