//! The configuration file: TOML into raw structs (`deny_unknown_fields`), then
//! validated once into typed parameters. Errors name the field (and the line,
//! where TOML knows it). Sections the estimator uses: `[sampling]`,
//! `[estimator]`, `[score]`; later parts of the daemon add their own.

use crate::core::inverse::DepthRange;
use crate::core::params::{Decimation, GainModel, DECIMATION_LEVELS};
use crate::core::{EstimatorParams, Model, ParamError, TrackAxis};
use serde::Deserialize;
use std::path::Path;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("config {path}: {message}")]
    Parse { path: String, message: String },
    #[error("config {path}: {source}")]
    Invalid {
        path: String,
        #[source]
        source: ParamError,
    },
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    #[serde(default)]
    pub sampling: RawSampling,
    #[serde(default)]
    pub estimator: RawEstimator,
    #[serde(default)]
    pub score: RawScore,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSampling {
    pub model: Option<String>,
    pub occlusion_max: Option<f64>,
    pub beta: Option<f64>,
    pub texture_bandwidth: Option<f64>,
    pub disparity_tolerance_px: Option<f64>,
    pub overlap_min: Option<f64>,
    pub spacing_min_m: Option<f64>,
    pub spacing_max_m: Option<f64>,
    pub fixed_spacing_m: Option<f64>,
    /// Compute these terms too, for comparison: "sspa", "occlusion".
    pub also: Option<Vec<String>>,
}

/// `decimation = "auto"` or a stride.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub enum RawDecimation {
    Stride(i64),
    Word(String),
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawEstimator {
    pub valid_fraction_min: Option<f64>,
    pub percentile_low: Option<f64>,
    pub percentile_high: Option<f64>,
    pub tau_abs_per_m: Option<f64>,
    pub tau_rel: Option<f64>,
    pub max_gap_px: Option<i64>,
    pub sky_is_scene: Option<bool>,
    pub depth_min_m: Option<f64>,
    pub depth_max_m: Option<f64>,
    pub pitch_max_deg: Option<f64>,
    pub track_axis: Option<String>,
    pub disparity_gain: Option<String>,
    pub decimation: Option<RawDecimation>,
    pub decimation_budget: Option<f64>,
    pub decimation_levels: Option<Vec<i64>>,
    pub sspa_iterations: Option<i64>,
    pub sspa_trim_sigma: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawScore {
    pub enabled: Option<bool>,
    /// `[min, max, step]` in degrees.
    pub pitch_candidates_deg: Option<[f64; 3]>,
    pub decimation: Option<i64>,
    pub min_coverage: Option<f64>,
}

fn bad(field: &'static str, message: impl Into<String>) -> ParamError {
    ParamError {
        field,
        message: message.into(),
    }
}

fn count(field: &'static str, v: i64) -> Result<usize, ParamError> {
    usize::try_from(v).map_err(|_| {
        bad(
            field,
            format!("must be a non-negative whole number, got {v}"),
        )
    })
}

/// Candidate pitches from `[min, max, step]` degrees, inclusive of both ends.
pub fn pitch_candidates_rad(
    min_deg: f64,
    max_deg: f64,
    step_deg: f64,
) -> Result<Vec<f64>, ParamError> {
    let field = "score.pitch_candidates_deg";
    if !(min_deg.is_finite() && max_deg.is_finite() && step_deg.is_finite())
        || min_deg > max_deg
        || step_deg <= 0.0
    {
        return Err(bad(
            field,
            "needs [min, max, step] with min <= max and step > 0",
        ));
    }
    let n = ((max_deg - min_deg) / step_deg + 1e-9).floor() as usize + 1;
    if n > 1000 {
        return Err(bad(
            field,
            format!("{n} candidates is too many (at most 1000)"),
        ));
    }
    Ok((0..n)
        .map(|k| (min_deg + k as f64 * step_deg).to_radians())
        .collect())
}

impl RawConfig {
    pub fn parse(text: &str, path: &str) -> Result<RawConfig, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_string(),
            message: e.to_string().trim_end().replace('\n', " | "),
        })
    }

    /// Typed, validated estimator parameters.
    pub fn estimator_params(&self) -> Result<EstimatorParams, ParamError> {
        let mut p = EstimatorParams::default();
        let s = &self.sampling;
        if let Some(m) = &s.model {
            p.model = Model::parse(m).ok_or_else(|| {
                bad(
                    "sampling.model",
                    format!(
                        "unknown model {m:?}: use \"occlusion\", \"mmds\", \"sspa\" or \"fixed\""
                    ),
                )
            })?;
        }
        macro_rules! set {
            ($src:expr, $dst:expr) => {
                if let Some(v) = $src {
                    $dst = v;
                }
            };
        }
        set!(s.occlusion_max, p.occlusion_max);
        set!(s.beta, p.beta);
        set!(s.texture_bandwidth, p.texture_bandwidth);
        set!(s.disparity_tolerance_px, p.disparity_tolerance_px);
        set!(s.overlap_min, p.overlap_min);
        set!(s.spacing_min_m, p.spacing_min_m);
        set!(s.spacing_max_m, p.spacing_max_m);
        set!(s.fixed_spacing_m, p.fixed_spacing_m);
        for term in s.also.iter().flatten() {
            match term.as_str() {
                "sspa" => p.with_sspa = true,
                "occlusion" => p.with_occlusion = true,
                "mmds" => {}
                other => {
                    return Err(bad(
                        "sampling.also",
                        format!("unknown term {other:?}: use \"sspa\", \"occlusion\" or \"mmds\""),
                    ))
                }
            }
        }
        let e = &self.estimator;
        set!(e.valid_fraction_min, p.valid_fraction_min);
        set!(e.percentile_low, p.percentile_low);
        set!(e.percentile_high, p.percentile_high);
        set!(e.tau_abs_per_m, p.tau_abs_per_m);
        set!(e.tau_rel, p.tau_rel);
        if let Some(g) = e.max_gap_px {
            p.max_gap_px = count("estimator.max_gap_px", g)?;
        }
        set!(e.sky_is_scene, p.sky_is_scene);
        p.depth_range = DepthRange {
            min_m: e.depth_min_m.unwrap_or(0.0),
            max_m: e.depth_max_m.unwrap_or(f64::INFINITY),
        };
        if let Some(d) = e.pitch_max_deg {
            p.pitch_max_rad = d.to_radians();
        }
        if let Some(a) = &e.track_axis {
            p.track_axis = match a.as_str() {
                "rows" => TrackAxis::Rows,
                "columns" => TrackAxis::Columns,
                other => {
                    return Err(bad(
                        "estimator.track_axis",
                        format!("unknown axis {other:?}: use \"rows\" or \"columns\""),
                    ))
                }
            };
        }
        if let Some(g) = &e.disparity_gain {
            p.gain_model = match g.as_str() {
                "axis" => GainModel::Axis,
                "pixel" => GainModel::Pixel,
                other => {
                    return Err(bad(
                        "estimator.disparity_gain",
                        format!("unknown gain {other:?}: use \"axis\" (DESIGN, f·cos φ) or \"pixel\" (f·cos φ − v·sin φ)"),
                    ))
                }
            };
        }
        let budget = e.decimation_budget.unwrap_or(0.05);
        let levels = match &e.decimation_levels {
            Some(l) => l
                .iter()
                .map(|&v| count("estimator.decimation_levels", v))
                .collect::<Result<Vec<_>, _>>()?,
            None => DECIMATION_LEVELS.to_vec(),
        };
        p.decimation = match &e.decimation {
            None => Decimation::Fixed(1),
            Some(RawDecimation::Stride(n)) => Decimation::Fixed(count("estimator.decimation", *n)?),
            Some(RawDecimation::Word(w)) if w == "auto" => Decimation::Auto { budget, levels },
            Some(RawDecimation::Word(w)) => {
                return Err(bad(
                    "estimator.decimation",
                    format!("must be \"auto\" or a stride, got {w:?}"),
                ))
            }
        };
        if let Some(n) = e.sspa_iterations {
            p.sspa_iterations = count("estimator.sspa_iterations", n)?;
        }
        set!(e.sspa_trim_sigma, p.sspa_trim_sigma);
        let sc = &self.score;
        if sc.enabled == Some(false) {
            p.score = None;
        } else if let Some(mut score) = p.score.take() {
            if let Some([lo, hi, step]) = sc.pitch_candidates_deg {
                score.candidates_rad = pitch_candidates_rad(lo, hi, step)?;
            }
            if let Some(d) = sc.decimation {
                score.step_px = count("score.decimation", d)?;
            }
            set!(sc.min_coverage, score.min_coverage);
            p.score = Some(score);
        }
        p.validate()?;
        Ok(p)
    }
}

/// Everything a command needs from a config file, validated.
#[derive(Debug, Clone, Default)]
pub struct Config {
    pub estimator: EstimatorParams,
}

impl Config {
    pub fn from_text(text: &str, path: &str) -> Result<Config, ConfigError> {
        let raw = RawConfig::parse(text, path)?;
        let estimator = raw
            .estimator_params()
            .map_err(|source| ConfigError::Invalid {
                path: path.to_string(),
                source,
            })?;
        Ok(Config { estimator })
    }

    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Config::from_text(&text, &path.display().to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_config_is_the_defaults() {
        let c = Config::from_text("", "x.toml").unwrap();
        assert_eq!(c.estimator, EstimatorParams::default());
    }

    #[test]
    fn fields_are_read_and_typed() {
        let c = Config::from_text(
            "[sampling]\nmodel = \"sspa\"\nocclusion_max = 0.02\nalso = [\"occlusion\"]\n\
             [estimator]\ndecimation = \"auto\"\ndecimation_budget = 0.1\ntrack_axis = \"columns\"\n\
             [score]\npitch_candidates_deg = [-10.0, 10.0, 10.0]\n",
            "x.toml",
        )
        .unwrap()
        .estimator;
        assert_eq!(c.model, Model::Sspa);
        assert_eq!(c.occlusion_max, 0.02);
        assert!(c.with_occlusion);
        assert_eq!(c.track_axis, TrackAxis::Columns);
        assert!(matches!(c.decimation, Decimation::Auto { budget, .. } if budget == 0.1));
        assert_eq!(c.score.unwrap().candidates_rad.len(), 3);
    }

    #[test]
    fn unknown_field_names_it_and_the_line() {
        let e = Config::from_text("[sampling]\nmodle = \"mmds\"\n", "x.toml").unwrap_err();
        let m = e.to_string();
        assert!(m.contains("modle") && m.contains("line 2"), "{m}");
    }

    #[test]
    fn out_of_range_value_names_the_field() {
        let e = Config::from_text("[sampling]\nocclusion_max = 2.0\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("sampling.occlusion_max"), "{e}");
        let e = Config::from_text("[sampling]\nmodel = \"best\"\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("sampling.model"), "{e}");
        let e = Config::from_text("[estimator]\ndecimation = -2\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("estimator.decimation"), "{e}");
    }
}
