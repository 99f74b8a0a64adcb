//! The configuration file: TOML into raw structs (`deny_unknown_fields`), then
//! validated once into typed parameters. Errors name the field (and the line,
//! where TOML knows it). Sections the estimator uses: `[sampling]`,
//! `[estimator]`, `[score]`; the daemon's: `[mavlink]`, `[camera]`, `[depth]`,
//! `[sim]`, `[capture]`, `[trigger]`.

use crate::capture::{CaptureMode, ImageFormat};
use crate::core::inverse::DepthRange;
use crate::core::params::{
    Decimation, GainModel, AUTO_RECALIBRATE_FRAMES, DECIMATION_BUDGET, DECIMATION_LEVELS,
};
use crate::core::trigger::TriggerParams;
use crate::core::{EstimatorParams, Model, ParamError, Profile, Quality, TrackAxis};
use crate::link::{LinkConfig, RawLinkConfig};
use crate::source::select::DeviceSelector;
use serde::Deserialize;
use std::path::{Path, PathBuf};
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
    #[error("config {path}: {field}: {message}")]
    Invalid {
        path: String,
        field: String,
        message: String,
    },
}

impl ConfigError {
    fn invalid(path: &str, field: impl Into<String>, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            path: path.to_string(),
            field: field.into(),
            message: message.into(),
        }
    }
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    #[serde(default)]
    pub quality: RawQuality,
    #[serde(default)]
    pub sampling: RawSampling,
    #[serde(default)]
    pub estimator: RawEstimator,
    #[serde(default)]
    pub score: RawScore,
    pub mavlink: Option<RawLinkConfig>,
    #[serde(default)]
    pub camera: RawSource,
    #[serde(default)]
    pub depth: RawSource,
    #[serde(default)]
    pub sim: RawSim,
    #[serde(default)]
    pub capture: RawCapture,
    #[serde(default)]
    pub trigger: RawTrigger,
}

/// `[camera]` and `[depth]`: where frames come from.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSource {
    /// "synthetic", "v4l2", "recorded" or "none".
    pub source: Option<String>,
    /// V4L2: the device, by what survives re-enumeration.
    pub device_path: Option<PathBuf>,
    pub device_serial: Option<String>,
    pub device_bus: Option<String>,
    pub device_card: Option<String>,
    /// Colour only: "mjpeg" or "yuyv".
    pub format: Option<String>,
    pub width: Option<i64>,
    pub height: Option<i64>,
    pub fps: Option<f64>,
    /// Depth only: field of view across the width, degrees, and principal point.
    pub hfov_deg: Option<f64>,
    pub principal_px: Option<[f64; 2]>,
    /// Depth only: metres per Z16 unit.
    pub scale_m: Option<f64>,
    /// Synthetic depth only: noise `σ = k·d²` (k in 1/m), dropout fraction, range.
    pub noise_per_m: Option<f64>,
    pub dropout: Option<f64>,
    pub max_range_m: Option<f64>,
    /// Recorded: the recording's directory.
    pub dir: Option<PathBuf>,
    /// Recorded: "as_recorded" (the recorded timestamps, once through) or
    /// "live" (paced in real time, stamped with the current clock, looping:
    /// a stand-in for a live camera on the bench).
    pub replay: Option<String>,
    /// Tilt of the camera from nadir about the vehicle's right axis, degrees
    /// (0 = straight down, positive = forward).
    pub mount_pitch_deg: Option<f64>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSim {
    /// "truth" (render at the simulator's true pose) or "telemetry".
    pub pose: Option<String>,
    pub scene: Option<PathBuf>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCapture {
    pub dir: Option<PathBuf>,
    /// "frame", "camera_command" or "autopilot_distance".
    pub mode: Option<String>,
    /// "jpeg" or "png".
    pub image_format: Option<String>,
    pub jpeg_quality: Option<i64>,
    /// Store an MJPEG camera's frames as the camera encoded them (default true).
    pub keep_camera_jpeg: Option<bool>,
    /// For mode "camera_command": "image_start_capture" or "digicam_control".
    pub command: Option<String>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawTrigger {
    pub rate_max_hz: Option<f64>,
    pub fallback_spacing_m: Option<f64>,
    pub margin: Option<f64>,
    pub closed_loop: Option<bool>,
}

/// `[quality]`: a profile's targets, each settable directly (DESIGN §1).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawQuality {
    pub profile: Option<String>,
    /// A number of pixels, or `false` to take the target out of force.
    pub parallax_px: Option<RawTarget>,
    pub forward_overlap: Option<RawTarget>,
    /// A fraction, or `false`: not in force (1, every view may go unseen).
    pub unseen_fraction_max: Option<RawTarget>,
    /// A count, or `false`: not in force (1, seen once: the coverage bound).
    pub views_per_point_min: Option<RawTarget>,
}

/// Quality targets given on a command line (`alfd estimate`, `alfd sim`) over a
/// config's: a profile first replaces every target with its own, then each given
/// target replaces that one. Checked with the rest of the estimator's parameters
/// (`EstimatorParams::validate`) once applied.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct QualityPatch {
    pub profile: Option<Profile>,
    /// `Some(None)`: taken out of force.
    pub parallax_px: Option<Option<f64>>,
    pub forward_overlap: Option<Option<f64>>,
    pub unseen_fraction_max: Option<f64>,
    pub views_per_point_min: Option<u32>,
}

impl QualityPatch {
    pub fn apply(&self, q: &mut Quality) {
        if let Some(p) = self.profile {
            *q = p.targets();
        }
        if let Some(v) = self.parallax_px {
            q.parallax_px = v;
        }
        if let Some(v) = self.forward_overlap {
            q.forward_overlap = v;
        }
        if let Some(v) = self.unseen_fraction_max {
            q.unseen_fraction_max = v;
        }
        if let Some(v) = self.views_per_point_min {
            q.views_per_point_min = v;
        }
    }

    pub fn is_empty(&self) -> bool {
        *self == QualityPatch::default()
    }
}

/// A target's value, or `false`: not in force (`configs/estimator.toml` says
/// so of every `[quality]` key).
#[derive(Debug, Clone, Copy)]
pub enum RawTarget {
    Value(f64),
    Off(bool),
}

/// By hand rather than `#[serde(untagged)]`, whose error for a string or a
/// table ("did not match any variant") names neither what the key takes nor
/// what it got.
impl<'de> Deserialize<'de> for RawTarget {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = RawTarget;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number, or false to take the target out of force")
            }
            fn visit_bool<E>(self, v: bool) -> Result<RawTarget, E> {
                Ok(RawTarget::Off(v))
            }
            fn visit_f64<E>(self, v: f64) -> Result<RawTarget, E> {
                Ok(RawTarget::Value(v))
            }
            fn visit_i64<E>(self, v: i64) -> Result<RawTarget, E> {
                Ok(RawTarget::Value(v as f64))
            }
            fn visit_u64<E>(self, v: u64) -> Result<RawTarget, E> {
                Ok(RawTarget::Value(v as f64))
            }
        }
        d.deserialize_any(Visitor)
    }
}

impl RawTarget {
    fn resolve(self, field: &'static str) -> Result<Option<f64>, ParamError> {
        match self {
            RawTarget::Value(v) => Ok(Some(v)),
            RawTarget::Off(false) => Ok(None),
            RawTarget::Off(true) => Err(bad(field, "a number, or false to turn the target off")),
        }
    }
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
    pub decimation_recalibrate_frames: Option<i64>,
    pub sspa_iterations: Option<i64>,
    pub sspa_trim_sigma: Option<f64>,
    pub visibility_samples_max: Option<i64>,
    pub visibility_interleave: Option<i64>,
    pub visibility_refresh: Option<bool>,
    pub threads: Option<i64>,
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
    // Counted in f64 before any cast: a tiny step would otherwise saturate the
    // cast and overflow the `+ 1` (found by the config_file fuzz target).
    let n = ((max_deg - min_deg) / step_deg + 1e-9).floor() + 1.0;
    if n > 1000.0 {
        return Err(bad(
            field,
            format!("{n:.0} candidates is too many (at most 1000): make the step larger"),
        ));
    }
    let n = n as usize;
    Ok((0..n)
        .map(|k| (min_deg + k as f64 * step_deg).to_radians())
        .collect())
}

/// A TOML error on one line, as journald keeps it: where, the line itself, and
/// what was wrong in an operator's words (`expected f64` is serde's).
fn parse_message(e: &toml::de::Error, text: &str) -> String {
    let plain = |m: &str| {
        let m = m.trim_end().replace('\n', "; ");
        let m = m.replace("expected f64", "expected a number");
        [
            ("u8", " from 0 to 255"),
            ("u16", " from 0 to 65535"),
            ("u32", " from 0 to 4294967295"),
            ("i64", ""),
            ("u64", " from 0"),
            ("usize", " from 0"),
        ]
        .iter()
        .fold(m, |m, (t, range)| {
            m.replace(
                &format!("expected {t}"),
                &format!("expected a whole number{range}"),
            )
        })
    };
    let Some(before) = e.span().and_then(|s| text.get(..s.start)) else {
        return plain(&e.to_string()).replace("; ", " | ");
    };
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next().unwrap_or("").trim();
    format!(
        "line {}, column {} (`{line}`): {}",
        before.matches('\n').count() + 1,
        before[line_start..].chars().count() + 1,
        plain(e.message())
    )
}

impl RawConfig {
    pub fn parse(text: &str, path: &str) -> Result<RawConfig, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_string(),
            message: parse_message(&e, text),
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
                        "unknown model {m:?}: use one of {:?}",
                        Model::ALL.map(Model::as_str)
                    ),
                )
            })?;
        }
        let q = &self.quality;
        if let Some(name) = &q.profile {
            p.quality = Profile::parse(name)
                .ok_or_else(|| {
                    bad(
                        "quality.profile",
                        format!(
                            "unknown profile {name:?}: use one of {:?}",
                            Profile::ALL.map(Profile::as_str)
                        ),
                    )
                })?
                .targets();
        }
        if let Some(t) = q.parallax_px {
            p.quality.parallax_px = t.resolve("quality.parallax_px")?;
        }
        if let Some(t) = q.forward_overlap {
            p.quality.forward_overlap = t.resolve("quality.forward_overlap")?;
        }
        if let Some(t) = q.unseen_fraction_max {
            p.quality.unseen_fraction_max = t
                .resolve("quality.unseen_fraction_max")?
                .unwrap_or(Quality::UNSEEN_OFF);
        }
        if let Some(t) = q.views_per_point_min {
            let k = t
                .resolve("quality.views_per_point_min")?
                .unwrap_or(Quality::VIEWS_OFF.into());
            p.quality.views_per_point_min = (k.fract() == 0.0
                && (0.0..=u32::MAX as f64).contains(&k))
            .then_some(k as u32)
            .ok_or_else(|| {
                bad(
                    "quality.views_per_point_min",
                    format!("must be a whole number from 1 to 100, got {k}"),
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
        if let Some(n) = e.visibility_samples_max {
            p.visibility_samples_max = count("estimator.visibility_samples_max", n)?;
        }
        if let Some(n) = e.visibility_interleave {
            p.visibility_interleave = count("estimator.visibility_interleave", n)?;
        }
        set!(e.visibility_refresh, p.visibility_refresh);
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
        let budget = e.decimation_budget.unwrap_or(DECIMATION_BUDGET);
        let recalibrate_frames = match e.decimation_recalibrate_frames {
            Some(v) => count("estimator.decimation_recalibrate_frames", v)?,
            None => AUTO_RECALIBRATE_FRAMES,
        };
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
            Some(RawDecimation::Word(w)) if w == "auto" => Decimation::Auto {
                budget,
                levels,
                recalibrate_frames,
            },
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

/// Where frames come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SourceKind {
    Synthetic,
    V4l2,
    Recorded,
    /// No camera (e.g. one the autopilot triggers), or no depth (fixed spacing).
    #[default]
    None,
}

/// Where a source's frames come from, with what only that kind needs: a recorded source
/// always has its directory, a V4L2 one its device, once the config is validated.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Source {
    Synthetic,
    V4l2 {
        device: DeviceSelector,
        mjpeg: bool,
    },
    Recorded {
        dir: PathBuf,
        /// Replay live (paced, re-stamped, looping), not as recorded.
        replay_live: bool,
    },
    #[default]
    None,
}

impl Source {
    pub fn kind(&self) -> SourceKind {
        match self {
            Source::Synthetic => SourceKind::Synthetic,
            Source::V4l2 { .. } => SourceKind::V4l2,
            Source::Recorded { .. } => SourceKind::Recorded,
            Source::None => SourceKind::None,
        }
    }
}

/// A validated `[camera]` or `[depth]` section.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SourceConfig {
    pub source: Source,
    pub width: usize,
    pub height: usize,
    pub fps: f64,
    pub hfov_deg: f64,
    pub principal_px: Option<(f64, f64)>,
    pub scale_m: f64,
    pub noise_per_m: f64,
    pub dropout: f64,
    pub max_range_m: f64,
    pub mount_pitch_rad: f64,
}

impl SourceConfig {
    pub fn kind(&self) -> SourceKind {
        self.source.kind()
    }
}

/// `[sim] pose` and `alfd sim --pose`: where the synthetic camera renders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SimPose {
    /// At the simulator's true pose (only `alfd sim` has it).
    #[default]
    Truth,
    /// At the pose alfd believes, from the telemetry.
    Telemetry,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum CameraCommand {
    #[default]
    #[value(name = "image_start_capture")]
    ImageStartCapture,
    #[value(name = "digicam_control")]
    DigicamControl,
}

/// `[camera] format`: what a V4L2 colour camera is asked to stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ColourFormat {
    Mjpeg,
    Yuyv,
}

/// `replay` of a recorded source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Replay {
    #[value(name = "as_recorded")]
    AsRecorded,
    Live,
}

/// `[capture] image_format`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ImageFormatName {
    Jpeg,
    Png,
}

#[derive(Debug, Clone, PartialEq)]
pub struct CaptureConfig {
    pub dir: PathBuf,
    pub mode: CaptureMode,
    pub image_format: ImageFormat,
    /// An MJPEG camera's frames are stored as it encoded them, with the EXIF segment
    /// added (no decoding, no second compression; `jpeg_quality` then applies only to
    /// other cameras' frames). False: decoded and re-encoded at `jpeg_quality`.
    pub keep_camera_jpeg: bool,
    pub command: CameraCommand,
}

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            dir: PathBuf::from("captures"),
            mode: CaptureMode::Frame,
            image_format: ImageFormat::Jpeg { quality: 90 },
            keep_camera_jpeg: true,
            command: CameraCommand::ImageStartCapture,
        }
    }
}

/// Everything a command needs from a config file, validated once.
#[derive(Debug, Clone, Default)]
pub struct Config {
    pub estimator: EstimatorParams,
    /// `[estimator] threads`: threads the visibility sweep runs on in the
    /// daemon's estimator (1, or 0 as `Default` gives: its own thread only).
    pub estimator_threads: usize,
    /// `None` without a `[mavlink]` section (estimate, eval).
    pub link: Option<LinkConfig>,
    pub camera: SourceConfig,
    pub depth: SourceConfig,
    pub sim_pose: SimPose,
    pub sim_scene: Option<PathBuf>,
    pub capture: CaptureConfig,
    pub trigger: TriggerParams,
}

/// A name of `T` as the command line accepts it (clap's `ValueEnum`), so the
/// config and the flags share one list of names.
fn named<T: clap::ValueEnum>(field: &str, value: &str) -> Result<T, (String, String)> {
    T::from_str(value, false).map_err(|_| {
        let names: Vec<String> = T::value_variants()
            .iter()
            .filter_map(|v| v.to_possible_value())
            .map(|p| format!("\"{}\"", p.get_name()))
            .collect();
        (
            field.to_string(),
            format!("unknown value {value:?}: use {}", names.join(", ")),
        )
    })
}

/// `v` (`default` when absent) if within `range`, else an error naming `field`.
fn whole_in(
    field: &str,
    v: Option<i64>,
    default: i64,
    range: std::ops::RangeInclusive<i64>,
) -> Result<i64, (String, String)> {
    match v.unwrap_or(default) {
        n if range.contains(&n) => Ok(n),
        n => Err((
            field.to_string(),
            format!("must be {} to {}, got {n}", range.start(), range.end()),
        )),
    }
}

fn positive(field: &str, v: f64, max: f64) -> Result<f64, (String, String)> {
    if v.is_finite() && v > 0.0 && v <= max {
        Ok(v)
    } else {
        Err((
            field.to_string(),
            format!("must be positive and at most {max}, got {v}"),
        ))
    }
}

fn fraction(field: &str, v: f64, max: f64) -> Result<f64, (String, String)> {
    if v.is_finite() && (0.0..=max).contains(&v) {
        Ok(v)
    } else {
        Err((field.to_string(), format!("must be in [0, {max}], got {v}")))
    }
}

fn size(field: &str, v: Option<i64>, default: usize) -> Result<usize, (String, String)> {
    match v {
        None => Ok(default),
        Some(n) if (1..=16384).contains(&n) => Ok(n as usize),
        Some(n) => Err((
            field.to_string(),
            format!("must be 1 to 16384 pixels, got {n}"),
        )),
    }
}

/// Relative paths in a config are relative to the config file.
fn resolve(base: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}

/// An empty path or device name is refused by its field: `""` resolves to the
/// config file's own directory, and an empty card name is in every card's, so
/// either would be taken without a word (a template's unfilled value).
fn given(field: String, value: Option<&std::ffi::OsStr>) -> Result<(), (String, String)> {
    if value.is_some_and(|v| v.is_empty()) {
        return Err((
            field,
            "is empty: name it, or leave the key out for its default".into(),
        ));
    }
    Ok(())
}

fn source(section: &str, r: &RawSource, base: &Path) -> Result<SourceConfig, (String, String)> {
    let f = |key: &str| format!("{section}.{key}");
    given(f("dir"), r.dir.as_deref().map(Path::as_os_str))?;
    given(
        f("device_path"),
        r.device_path.as_deref().map(Path::as_os_str),
    )?;
    for (key, v) in [
        ("device_serial", &r.device_serial),
        ("device_bus", &r.device_bus),
        ("device_card", &r.device_card),
    ] {
        given(f(key), v.as_deref().map(std::ffi::OsStr::new))?;
    }
    let kind = match &r.source {
        Some(w) => named(&f("source"), w)?,
        None => SourceKind::None,
    };
    let mjpeg = match &r.format {
        Some(w) => named::<ColourFormat>(&f("format"), w)? == ColourFormat::Mjpeg,
        None => true,
    };
    let hfov_deg = r.hfov_deg.unwrap_or(69.0);
    if !(1.0..=170.0).contains(&hfov_deg) {
        return Err((
            f("hfov_deg"),
            format!("must be between 1 and 170 degrees, got {hfov_deg}"),
        ));
    }
    let replay_live = match &r.replay {
        Some(w) => named::<Replay>(&f("replay"), w)? == Replay::Live,
        None => false,
    };
    let mount_pitch_deg = r.mount_pitch_deg.unwrap_or(0.0);
    if !(mount_pitch_deg.is_finite() && (-90.0..=90.0).contains(&mount_pitch_deg)) {
        return Err((
            f("mount_pitch_deg"),
            format!("must be between -90 and 90 degrees, got {mount_pitch_deg}"),
        ));
    }
    let source = match kind {
        SourceKind::Synthetic => Source::Synthetic,
        SourceKind::None => Source::None,
        SourceKind::V4l2 => Source::V4l2 {
            device: DeviceSelector {
                path: r.device_path.clone(),
                serial: r.device_serial.clone(),
                bus: r.device_bus.clone(),
                card: r.device_card.clone(),
            },
            mjpeg,
        },
        SourceKind::Recorded => Source::Recorded {
            dir: r.dir.as_ref().map(|d| resolve(base, d)).ok_or_else(|| {
                (
                    f("dir"),
                    "a recorded source needs the recording's directory".to_string(),
                )
            })?,
            replay_live,
        },
    };
    Ok(SourceConfig {
        source,
        mount_pitch_rad: mount_pitch_deg.to_radians(),
        width: size(&f("width"), r.width, 640)?,
        height: size(&f("height"), r.height, 480)?,
        fps: positive(&f("fps"), r.fps.unwrap_or(30.0), 1000.0)?,
        hfov_deg,
        principal_px: r.principal_px.map(|[x, y]| (x, y)),
        scale_m: positive(&f("scale_m"), r.scale_m.unwrap_or(0.001), 100.0)?,
        noise_per_m: fraction(&f("noise_per_m"), r.noise_per_m.unwrap_or(0.0), 1.0)?,
        dropout: fraction(&f("dropout"), r.dropout.unwrap_or(0.0), 1.0)?,
        max_range_m: positive(&f("max_range_m"), r.max_range_m.unwrap_or(65.0), 1e6)?,
    })
}

impl RawConfig {
    /// The daemon's sections, checked alone and against each other.
    fn daemon(&self, estimator: &EstimatorParams, base: &Path) -> Result<Config, (String, String)> {
        let link = match &self.mavlink {
            Some(raw) => Some(LinkConfig::try_from(raw.clone()).map_err(|e| (e.field, e.problem))?),
            None => None,
        };
        let camera = source("camera", &self.camera, base)?;
        let depth = source("depth", &self.depth, base)?;
        let sim_pose = match &self.sim.pose {
            Some(w) => named("sim.pose", w)?,
            None => SimPose::Truth,
        };
        given(
            "sim.scene".into(),
            self.sim.scene.as_deref().map(Path::as_os_str),
        )?;
        let sim_scene = self.sim.scene.as_ref().map(|p| resolve(base, p));
        let uses_synthetic =
            camera.kind() == SourceKind::Synthetic || depth.kind() == SourceKind::Synthetic;
        if uses_synthetic && sim_scene.is_none() {
            return Err((
                "sim.scene".into(),
                "a synthetic camera or depth source needs a scene file".into(),
            ));
        }
        if depth.kind() == SourceKind::None
            && estimator.model != Model::Fixed
            && self.mavlink.is_some()
        {
            return Err((
                "depth.source".into(),
                format!(
                    "the {} model needs depth: give a depth source, or use sampling.model = \"fixed\"",
                    estimator.model.as_str()
                ),
            ));
        }
        let c = &self.capture;
        given("capture.dir".into(), c.dir.as_deref().map(Path::as_os_str))?;
        let mode = match &c.mode {
            Some(w) => named("capture.mode", w)?,
            None => CaptureMode::Frame,
        };
        if mode == CaptureMode::Frame && camera.kind() == SourceKind::None && self.mavlink.is_some()
        {
            return Err((
                "capture.mode".into(),
                "\"frame\" saves the camera's frames, but camera.source is \"none\": use \"camera_command\" or \"autopilot_distance\"".into(),
            ));
        }
        let quality = whole_in("capture.jpeg_quality", c.jpeg_quality, 90, 1..=100)? as u8;
        let image_format = match c
            .image_format
            .as_deref()
            .map(|w| named("capture.image_format", w))
        {
            None | Some(Ok(ImageFormatName::Jpeg)) => ImageFormat::Jpeg { quality },
            Some(Ok(ImageFormatName::Png)) => ImageFormat::Png,
            Some(Err(e)) => return Err(e),
        };
        if c.keep_camera_jpeg == Some(true) && image_format == ImageFormat::Png {
            return Err((
                "capture.keep_camera_jpeg".into(),
                "the camera's JPEG cannot be kept when image_format is \"png\"".into(),
            ));
        }
        let command = match &c.command {
            Some(w) => named("capture.command", w)?,
            None => CameraCommand::ImageStartCapture,
        };
        let estimator_threads =
            whole_in("estimator.threads", self.estimator.threads, 1, 1..=64)? as usize;
        // A stride that leaves the depth frame a handful of samples gives a
        // spacing from the extremes of those (at 256, one sample of a 320 × 240
        // frame: 63× the full frame's), on every frame of the flight.
        if let (Decimation::Fixed(n), SourceKind::Synthetic | SourceKind::V4l2) =
            (&estimator.decimation, depth.kind())
        {
            let min = estimator.grid_samples_min();
            let samples = crate::core::inverse::grid_samples(depth.width, depth.height, *n);
            let coarsest = crate::core::inverse::coarsest_step(depth.width, depth.height, min);
            // A frame too small even at every pixel is no stride's fault.
            if samples < min && *n > coarsest {
                return Err((
                    "estimator.decimation".into(),
                    format!(
                        "{n} leaves {samples} samples of the {}x{} depth frame, fewer than the {min} \
                         its {} % percentile needs: at most {} for this frame",
                        depth.width,
                        depth.height,
                        100.0 * estimator.percentile_low,
                        coarsest
                    ),
                ));
            }
        }
        let t = &self.trigger;
        let defaults = TriggerParams::default();
        let trigger = TriggerParams {
            rate_max_hz: positive(
                "trigger.rate_max_hz",
                t.rate_max_hz.unwrap_or(defaults.rate_max_hz),
                1000.0,
            )?,
            // The default never looser than the longest spacing an estimate may choose.
            fallback_spacing_m: positive(
                "trigger.fallback_spacing_m",
                t.fallback_spacing_m
                    .unwrap_or(defaults.fallback_spacing_m.min(estimator.spacing_max_m)),
                1e4,
            )?,
            margin: fraction("trigger.margin", t.margin.unwrap_or(defaults.margin), 0.5)?,
            closed_loop: t.closed_loop.unwrap_or(defaults.closed_loop),
        };
        // The fallback holds while the depth is lost: longer than any spacing an
        // estimate may choose, it would be the flight's least conservative spacing.
        if trigger.fallback_spacing_m > estimator.spacing_max_m {
            return Err((
                "trigger.fallback_spacing_m".into(),
                format!(
                    "{} m is longer than sampling.spacing_max_m ({} m): the fallback holds while \
                     the depth is lost, and must not be looser than any estimate",
                    trigger.fallback_spacing_m, estimator.spacing_max_m
                ),
            ));
        }
        Ok(Config {
            estimator: estimator.clone(),
            estimator_threads,
            link,
            camera,
            depth,
            sim_pose,
            sim_scene,
            capture: CaptureConfig {
                dir: resolve(base, c.dir.as_deref().unwrap_or(Path::new("captures"))),
                mode,
                image_format,
                keep_camera_jpeg: c.keep_camera_jpeg.unwrap_or(true),
                command,
            },
            trigger,
        })
    }
}

impl Config {
    /// `path` names the file in errors; relative paths resolve against its directory.
    pub fn from_text(text: &str, path: &str) -> Result<Config, ConfigError> {
        let raw = RawConfig::parse(text, path)?;
        let estimator = raw
            .estimator_params()
            .map_err(|e| ConfigError::invalid(path, e.field, e.message))?;
        let base = Path::new(path).parent().unwrap_or(Path::new("."));
        raw.daemon(&estimator, base)
            .map_err(|(field, message)| ConfigError::invalid(path, field, message))
    }

    /// What this build cannot do that the config asks for (a valid config may
    /// still need a feature: `alfd run` refuses to start, `check-config` says so).
    pub fn unsupported_by_build(&self) -> Option<String> {
        let section = |kind| {
            [("camera", &self.camera), ("depth", &self.depth)]
                .into_iter()
                .find(|(_, s)| s.kind() == kind)
                .map(|(name, _)| name)
        };
        match (section(SourceKind::V4l2), section(SourceKind::Synthetic)) {
            (Some(section), _) if !cfg!(feature = "v4l2") => Some(format!(
                "{section}.source = \"v4l2\" needs V4L2 support, which this build lacks: build with `cargo build --release --features v4l2`"
            )),
            (_, Some(section)) if !cfg!(feature = "sim") => Some(format!(
                "{section}.source = \"synthetic\" needs the scene renderer, which this lean build lacks: build with the default features (`cargo build --release`)"
            )),
            _ => None,
        }
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
    fn pitch_candidate_counts_that_overflow_are_an_error() {
        for (lo, hi, step) in [
            (-45.0, 6.7e30, 45.0),
            (0.0, 1.0, 1e-300),
            (-1e308, 1e308, 1.0),
        ] {
            let e = pitch_candidates_rad(lo, hi, step).unwrap_err();
            assert_eq!(e.field, "score.pitch_candidates_deg");
            assert!(e.message.contains("too many"), "{e:?}");
        }
        assert_eq!(pitch_candidates_rad(-45.0, 45.0, 5.0).unwrap().len(), 19);
        assert_eq!(pitch_candidates_rad(0.0, 999.0, 1.0).unwrap().len(), 1000);
        assert!(pitch_candidates_rad(0.0, 1000.0, 1.0).is_err());
    }

    #[test]
    fn empty_config_is_the_defaults() {
        let c = Config::from_text("", "x.toml").unwrap();
        assert_eq!(c.estimator, EstimatorParams::default());
    }

    #[test]
    fn fields_are_read_and_typed() {
        let c = Config::from_text(
            "[sampling]\nmodel = \"sspa\"\nocclusion_max = 0.02\nalso = [\"occlusion\"]\n\
             [estimator]\ndecimation = \"auto\"\ndecimation_budget = 0.1\ndecimation_recalibrate_frames = 90\n\
             track_axis = \"columns\"\n\
             [score]\npitch_candidates_deg = [-10.0, 10.0, 10.0]\n",
            "x.toml",
        )
        .unwrap()
        .estimator;
        assert_eq!(c.model, Model::Sspa);
        assert_eq!(c.occlusion_max, 0.02);
        assert!(c.with_occlusion);
        assert_eq!(c.track_axis, TrackAxis::Columns);
        assert!(
            matches!(c.decimation, Decimation::Auto { budget, recalibrate_frames, .. }
            if budget == 0.1 && recalibrate_frames == 90)
        );
        assert_eq!(c.score.unwrap().candidates_rad.len(), 3);
    }

    #[test]
    fn unknown_field_names_it_and_the_line() {
        let e = Config::from_text("[sampling]\nmodle = \"mmds\"\n", "x.toml").unwrap_err();
        let m = e.to_string();
        assert!(m.contains("modle") && m.contains("line 2"), "{m}");
    }

    /// `configs/estimator.toml`: "false takes it out of force", of every
    /// `[quality]` key; and a value of the wrong type says what the key takes,
    /// where, in words.
    #[test]
    fn every_quality_target_turns_off_and_a_wrong_type_says_what_the_key_takes() {
        let q = Config::from_text(
            "[quality]\nparallax_px = false\nforward_overlap = 0.8\n\
             unseen_fraction_max = false\nviews_per_point_min = false\n",
            "x.toml",
        )
        .unwrap()
        .estimator
        .quality;
        assert_eq!(q.parallax_px, None);
        assert_eq!(q.forward_overlap, Some(0.8));
        assert_eq!(q.unseen_fraction_max, Quality::UNSEEN_OFF);
        assert_eq!(q.views_per_point_min, Quality::VIEWS_OFF);
        let q = Config::from_text("[quality]\nviews_per_point_min = 3\n", "x.toml")
            .unwrap()
            .estimator
            .quality;
        assert_eq!(q.views_per_point_min, 3);
        let e = Config::from_text("[quality]\nparallax_px = \"2px\"\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 2, column 15 (`parallax_px = \"2px\"`)")
                && e.contains("a number, or false"),
            "{e}"
        );
        let e = Config::from_text("[quality]\nunseen_fraction_max = true\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("quality.unseen_fraction_max: a number, or false"),
            "{e}"
        );
        let e = Config::from_text("[quality]\nviews_per_point_min = 2.5\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(
                "quality.views_per_point_min: must be a whole number from 1 to 100, got 2.5"
            ),
            "{e}"
        );
        let e = Config::from_text("[sampling]\nspacing_min_m = \"5\"\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 2, column 17 (`spacing_min_m = \"5\"`)")
                && e.contains("expected a number")
                && !e.contains("f64"),
            "{e}"
        );
        // A whole number out of its type's range is not "not a whole number".
        let e = Config::from_text("[mavlink]\nsystem_id = 300\n", "x.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("expected a whole number from 0 to 255"), "{e}");
    }

    #[test]
    fn out_of_range_value_names_the_field() {
        let e = Config::from_text("[sampling]\nocclusion_max = 2.0\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("sampling.occlusion_max"), "{e}");
        let e = Config::from_text("[sampling]\nmodel = \"best\"\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("sampling.model"), "{e}");
        let e = Config::from_text("[estimator]\ndecimation = -2\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("estimator.decimation"), "{e}");
        for frames in ["0", "-1", "100001", "5000000000"] {
            let e = Config::from_text(
                &format!("[estimator]\ndecimation = \"auto\"\ndecimation_recalibrate_frames = {frames}\n"),
                "x.toml",
            )
            .unwrap_err();
            assert!(
                e.to_string()
                    .contains("estimator.decimation_recalibrate_frames"),
                "{e}"
            );
        }
        for threads in ["0", "-1", "65"] {
            let e = Config::from_text(&format!("[estimator]\nthreads = {threads}\n"), "x.toml")
                .unwrap_err();
            assert!(e.to_string().contains("estimator.threads"), "{e}");
        }
        let c = Config::from_text("[estimator]\nthreads = 4\n", "x.toml").unwrap();
        assert_eq!(c.estimator_threads, 4);
        assert_eq!(
            Config::from_text("", "x.toml").unwrap().estimator_threads,
            1
        );
        for n in ["0", "-1", "9"] {
            let e = Config::from_text(
                &format!("[estimator]\nvisibility_interleave = {n}\n"),
                "x.toml",
            )
            .unwrap_err();
            assert!(
                e.to_string().contains("estimator.visibility_interleave"),
                "{e}"
            );
        }
        let c = Config::from_text("[estimator]\nvisibility_interleave = 1\n", "x.toml").unwrap();
        assert_eq!(c.estimator.visibility_interleave, 1);
        assert_eq!(
            Config::from_text("", "x.toml")
                .unwrap()
                .estimator
                .visibility_interleave,
            4
        );
        assert!(
            Config::from_text("", "x.toml")
                .unwrap()
                .estimator
                .visibility_refresh
        );
        let c = Config::from_text("[estimator]\nvisibility_refresh = false\n", "x.toml").unwrap();
        assert!(!c.estimator.visibility_refresh);
        let e = Config::from_text("[estimator]\nvisibility_refresh = 1\n", "x.toml").unwrap_err();
        assert!(e.to_string().contains("visibility_refresh"), "{e}");
    }

    #[test]
    fn daemon_sections_are_typed_and_paths_resolve_against_the_file() {
        let c = Config::from_text(
            "[mavlink]\naddress = \"udpout:127.0.0.1:14550\"\n\
             [sim]\nscene = \"scenes/roof.toml\"\npose = \"telemetry\"\n\
             [depth]\nsource = \"synthetic\"\nwidth = 320\nheight = 240\n\
             [camera]\nsource = \"recorded\"\ndir = \"rec\"\n\
             [capture]\nmode = \"frame\"\nimage_format = \"png\"\n\
             [trigger]\nrate_max_hz = 15.0\n",
            "/etc/alfd/alfd.toml",
        )
        .unwrap();
        assert!(c.link.is_some());
        assert_eq!(c.sim_pose, SimPose::Telemetry);
        assert_eq!(
            c.sim_scene.as_deref(),
            Some(Path::new("/etc/alfd/scenes/roof.toml"))
        );
        assert_eq!(
            (c.depth.kind(), c.depth.width, c.depth.height),
            (SourceKind::Synthetic, 320, 240)
        );
        assert_eq!(
            c.camera.source,
            Source::Recorded {
                dir: PathBuf::from("/etc/alfd/rec"),
                replay_live: false
            }
        );
        assert_eq!(c.capture.image_format, ImageFormat::Png);
        assert_eq!(c.trigger.rate_max_hz, 15.0);
    }

    /// Every word-valued field takes its documented names (one list each, clap's
    /// `ValueEnum`, shared with the command line where it has the flag), and an unknown
    /// word is refused naming the field and the names it takes.
    #[test]
    fn word_fields_take_their_names_and_refuse_others_listing_them() {
        let ok = |text: &str| Config::from_text(text, "x.toml").unwrap();
        for (word, live) in [("live", true), ("as_recorded", false)] {
            let c = ok(&format!(
                "[camera]\nsource = \"recorded\"\ndir = \"r\"\nreplay = \"{word}\"\n"
            ));
            assert!(
                matches!(c.camera.source, Source::Recorded { replay_live, .. } if replay_live == live),
                "replay = {word}"
            );
        }
        for (word, mjpeg) in [("mjpeg", true), ("yuyv", false)] {
            let c = ok(&format!(
                "[camera]\nsource = \"v4l2\"\ndevice_serial = \"1\"\nformat = \"{word}\"\n"
            ));
            assert!(matches!(c.camera.source, Source::V4l2 { mjpeg: m, .. } if m == mjpeg));
        }
        assert_eq!(
            ok("[capture]\nimage_format = \"png\"\n")
                .capture
                .image_format,
            ImageFormat::Png
        );
        for (word, cmd) in [
            ("image_start_capture", CameraCommand::ImageStartCapture),
            ("digicam_control", CameraCommand::DigicamControl),
        ] {
            let c = ok(&format!("[capture]\ncommand = \"{word}\"\n"));
            assert_eq!(c.capture.command, cmd);
        }
        assert_eq!(
            ok("[depth]\nsource = \"none\"\n").depth.kind(),
            SourceKind::None
        );
        for (text, field, names) in [
            (
                "[camera]\nsource = \"webcam\"\n",
                "camera.source",
                "\"synthetic\", \"v4l2\", \"recorded\", \"none\"",
            ),
            (
                "[camera]\nformat = \"h264\"\n",
                "camera.format",
                "\"mjpeg\", \"yuyv\"",
            ),
            (
                "[depth]\nreplay = \"fast\"\n",
                "depth.replay",
                "\"as_recorded\", \"live\"",
            ),
            (
                "[capture]\nimage_format = \"tiff\"\n",
                "capture.image_format",
                "\"jpeg\", \"png\"",
            ),
            (
                "[capture]\ncommand = \"shoot\"\n",
                "capture.command",
                "\"image_start_capture\", \"digicam_control\"",
            ),
        ] {
            let e = Config::from_text(text, "x.toml").unwrap_err().to_string();
            assert!(e.contains(field) && e.contains(names), "{text:?}: {e}");
        }
    }

    #[test]
    fn an_empty_path_or_device_name_is_refused_by_its_field() {
        for (text, field) in [
            ("[capture]\ndir = \"\"\n", "capture.dir"),
            (
                "[camera]\nsource = \"recorded\"\ndir = \"\"\n",
                "camera.dir",
            ),
            (
                "[depth]\nsource = \"v4l2\"\ndevice_path = \"\"\n",
                "depth.device_path",
            ),
            (
                "[depth]\nsource = \"v4l2\"\ndevice_serial = \"\"\n",
                "depth.device_serial",
            ),
            (
                "[camera]\nsource = \"v4l2\"\ndevice_bus = \"\"\n",
                "camera.device_bus",
            ),
            (
                "[camera]\nsource = \"v4l2\"\ndevice_card = \"\"\n",
                "camera.device_card",
            ),
            ("[sim]\nscene = \"\"\n", "sim.scene"),
        ] {
            let e = Config::from_text(text, "x.toml").unwrap_err().to_string();
            assert!(e.contains(field) && e.contains("empty"), "{text:?}: {e}");
        }
        // A name given is taken as before.
        let c = Config::from_text("[capture]\ndir = \"flights\"\n", "/etc/alfd/x.toml").unwrap();
        assert_eq!(c.capture.dir, std::path::Path::new("/etc/alfd/flights"));
    }

    #[test]
    fn contradictions_between_sections_name_the_field() {
        let cases = [
            // A synthetic source without a scene to render.
            ("[depth]\nsource = \"synthetic\"\n", "sim.scene"),
            // The occlusion model without depth, on a daemon config.
            ("[mavlink]\naddress = \"udpout:127.0.0.1:14550\"\n[camera]\nsource = \"none\"\n[capture]\nmode = \"camera_command\"\n", "depth.source"),
            // Saving frames with no camera.
            ("[mavlink]\naddress = \"udpout:127.0.0.1:14550\"\n[sampling]\nmodel = \"fixed\"\n", "capture.mode"),
            ("[camera]\nsource = \"recorded\"\n", "camera.dir"),
            ("[camera]\nsource = \"webcam\"\n", "camera.source"),
            ("[trigger]\nrate_max_hz = 0.0\n", "trigger.rate_max_hz"),
            ("[capture]\njpeg_quality = 101\n", "capture.jpeg_quality"),
            ("[mavlink]\naddress = \"carrier-pigeon:1\"\n", "mavlink.address"),
            // A fallback looser than any estimate.
            ("[sampling]\nspacing_max_m = 50.0\n[trigger]\nfallback_spacing_m = 60.0\n", "trigger.fallback_spacing_m"),
        ];
        for (text, field) in cases {
            let e = Config::from_text(text, "x.toml").unwrap_err().to_string();
            assert!(e.contains(field), "{text:?}: {e}");
        }
        // A stride that leaves the depth frame fewer samples than its robust
        // range needs: 640 / 128 × 480 / 128 = 15; 37 is the coarsest with 200.
        let depth =
            "[depth]\nsource = \"v4l2\"\ndevice_serial = \"1\"\nwidth = 640\nheight = 480\n";
        let e = Config::from_text(&format!("{depth}[estimator]\ndecimation = 128\n"), "x.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("estimator.decimation: 128 leaves 15 samples of the 640x480 depth frame")
                && e.contains("at most 37 for this frame"),
            "{e}"
        );
        Config::from_text(&format!("{depth}[estimator]\ndecimation = 37\n"), "x.toml").unwrap();
        // The default fallback (1 m) is no looser than a shorter cap.
        let c = Config::from_text("[sampling]\nspacing_max_m = 0.5\n", "x.toml").unwrap();
        assert_eq!(c.trigger.fallback_spacing_m, 0.5);
        // Fixed spacing with an autopilot-triggered camera needs neither source.
        Config::from_text(
            "[mavlink]\naddress = \"udpout:127.0.0.1:14550\"\n[sampling]\nmodel = \"fixed\"\n[capture]\nmode = \"autopilot_distance\"\n",
            "x.toml",
        )
        .unwrap();
    }

    #[test]
    fn a_v4l2_config_is_valid_and_the_build_says_what_it_lacks() {
        let c = Config::from_text(
            "[depth]\nsource = \"v4l2\"\ndevice_serial = \"1\"\n",
            "x.toml",
        )
        .unwrap();
        let Source::V4l2 { device, mjpeg } = &c.depth.source else {
            panic!("a v4l2 source: {:?}", c.depth.source);
        };
        assert_eq!((device.serial.as_deref(), *mjpeg), (Some("1"), true));
        assert_eq!(c.unsupported_by_build().is_some(), !cfg!(feature = "v4l2"));
    }

    #[test]
    fn a_synthetic_config_is_valid_and_the_lean_build_says_what_it_lacks() {
        let c = Config::from_text(
            "[sim]\nscene = \"scenes/roof.toml\"\npose = \"telemetry\"\n[camera]\nsource = \"synthetic\"\n",
            "x.toml",
        )
        .unwrap();
        let note = c.unsupported_by_build();
        assert_eq!(note.is_some(), !cfg!(feature = "sim"), "{note:?}");
        if let Some(note) = note {
            assert!(note.starts_with("camera.source = \"synthetic\""), "{note}");
        }
    }
}
