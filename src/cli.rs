//! Command-line arguments, parsed once into validated values, and the handlers
//! of each subcommand.

use alfd::config::Config;
use alfd::core::{Decimation, Estimator, Intrinsics, Model, Profile};
use alfd::depthio::{read_depth, DepthFormat, ReadOptions};
use alfd::report::{estimate_json, estimate_text, InputInfo};
use alfd::tradeoff;
use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// Bad input from the user (a file, a flag, a config): exit code 2.
#[derive(Debug)]
pub struct BadInput(pub String);

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for BadInput {}

pub fn bad(msg: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(BadInput(msg.into()))
}

pub fn exit_code(e: &anyhow::Error) -> u8 {
    if e.downcast_ref::<BadInput>().is_some() {
        2
    } else {
        1
    }
}

#[derive(Parser)]
#[command(
    name = "alfd",
    version,
    about = "Occlusion-aware light-field sampling for drone captures"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Log format on stderr.
    #[arg(long, global = true, value_enum, default_value = "text")]
    log_format: crate::daemon_cmd::LogFormat,
    /// Log level: error, warn, info, debug, trace.
    #[arg(long, global = true, default_value = "info")]
    log_level: tracing::Level,
}

#[derive(Subcommand)]
enum Command {
    /// The daemon on the simulated autopilot over a synthetic scene, judged against the truth.
    Sim(crate::daemon_cmd::SimCliArgs),
    /// The daemon: link, cameras, estimator, trigger and capture log, until SIGTERM.
    Run(crate::daemon_cmd::RunArgs),
    /// One estimate of the permissible spacing from one depth map.
    Estimate(EstimateArgs),
    /// Validate a config file: prints the field and what is wrong, exit 2.
    CheckConfig {
        /// The TOML config file.
        file: PathBuf,
    },
    /// Error against run time of every decimation level and model.
    Tradeoff(TradeoffArgs),
    /// Ground-truth evaluation on the synthetic scenes: tables, JSON and plots.
    Eval(EvalArgs),
}

#[derive(clap::Args)]
struct EvalArgs {
    /// Output directory (results.json, report.md, decimation.md, plots).
    #[arg(long, default_value = "eval")]
    out: PathBuf,
    /// Directory of the scene files.
    #[arg(long, default_value = "scenes")]
    scenes_dir: PathBuf,
    /// Only these scenes (names in the scene directory, or paths); default all eight.
    #[arg(long = "scene")]
    scenes: Vec<String>,
    /// A small run (a third of the resolution, three times the view step), for CI.
    #[arg(long)]
    quick: bool,
    /// No progress bar.
    #[arg(long)]
    no_progress: bool,
    /// Also judge each method's captures at equal counts with COLMAP
    /// (pycolmap, `scripts/colmap_judge.py`) on canyon, courtyard and orchard,
    /// or on every scene named with `--scene`.
    #[arg(long)]
    colmap: bool,
    /// The COLMAP judge script.
    #[arg(long, default_value = "scripts/colmap_judge.py")]
    colmap_script: PathBuf,
}

#[derive(clap::Args)]
struct EstimateArgs {
    /// Depth map: raw Z16 (.z16/.raw), 16-bit grey PNG (.png) or PFM float metres (.pfm).
    #[arg(long)]
    depth: PathBuf,
    /// Horizontal field of view, degrees (1 to 170), across the image width.
    #[arg(long, allow_negative_numbers = true)]
    hfov_deg: f64,
    /// Camera pitch, degrees: 0 is nadir, positive tilts forward.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pitch_deg: f64,
    /// File format (default: from the extension).
    #[arg(long, value_parser = ["z16", "png16", "pfm"])]
    format: Option<String>,
    /// Image width in pixels (required for raw Z16).
    #[arg(long)]
    width: Option<usize>,
    /// Image height in pixels (required for raw Z16).
    #[arg(long)]
    height: Option<usize>,
    /// Metres per Z16/PNG unit.
    #[arg(long, default_value_t = 0.001)]
    depth_scale_m: f64,
    /// Config file ([sampling], [estimator], [score]).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override the sampling model: quality (the default), occlusion, mmds, sspa, fixed.
    #[arg(long)]
    model: Option<String>,
    /// Quality profile: lightfield (parallax 2 px, unseen 0.002, 2 views) or
    /// mapping (80 % forward overlap, unseen 0.002, 3 views); the flags below override it.
    #[arg(long)]
    profile: Option<String>,
    /// Largest disparity range per capture step, px ("off": not in force).
    #[arg(long)]
    parallax_px: Option<String>,
    /// Least forward overlap at the nearest depth, 0 to 0.99 ("off": not in force).
    #[arg(long)]
    forward_overlap: Option<String>,
    /// Largest fraction of an in-between view neither neighbouring capture sees.
    #[arg(long)]
    unseen_fraction_max: Option<f64>,
    /// Captures every visible surface point must be in.
    #[arg(long)]
    views_per_point_min: Option<u32>,
    /// Also compute SSPA (the single slanted plane).
    #[arg(long)]
    sspa: bool,
    /// Decimation: "auto" or a stride (overrides the config).
    #[arg(long)]
    decimation: Option<String>,
    /// Print the JSON object of DESIGN §4 instead of a summary.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct TradeoffArgs {
    /// Frame width of the synthetic reference scenes.
    #[arg(long, default_value_t = 640)]
    width: usize,
    /// Frame height of the synthetic reference scenes.
    #[arg(long, default_value_t = 480)]
    height: usize,
    /// Timing repeats per frame and level (the median is kept).
    #[arg(long, default_value_t = 15)]
    repeats: usize,
    /// Also measure on these self-describing depth maps (16-bit PNG or PFM).
    #[arg(long)]
    depth: Vec<PathBuf>,
    /// Camera pitch of the --depth maps, degrees.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pitch_deg: f64,
    /// Horizontal field of view for --depth maps, degrees.
    #[arg(long, default_value_t = 69.0)]
    hfov_deg: f64,
    /// Config file.
    #[arg(long)]
    config: Option<PathBuf>,
}

pub fn run() -> Result<ExitCode> {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap prints its own help, version and usage errors (exit 2).
            e.exit();
        }
    };
    crate::daemon_cmd::init_logs(cli.log_format, cli.log_level);
    match cli.command {
        Command::Sim(a) => crate::daemon_cmd::sim(a),
        Command::Run(a) => crate::daemon_cmd::run_daemon(a),
        Command::Estimate(a) => estimate(a),
        Command::CheckConfig { file } => {
            let cfg = Config::load(&file).map_err(|e| bad(e.to_string()))?;
            if let Some(scene) = &cfg.sim_scene {
                alfd::scene::Scene::load(scene)
                    .map_err(|e| bad(format!("{}: sim.scene: {e}", file.display())))?;
            }
            emit(&format!("{}: ok\n", file.display()))?;
            if let Some(note) = cfg.unsupported_by_build() {
                emit(&format!("note: {note}\n"))?;
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Tradeoff(a) => run_tradeoff(a),
        Command::Eval(a) => run_eval(a),
    }
}

/// Writes to stdout; a closed pipe (`alfd ... | head`) is not an error.
pub fn emit(text: &str) -> Result<()> {
    use std::io::Write;
    match std::io::stdout().lock().write_all(text.as_bytes()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("writing to stdout"),
    }
}

fn load_config(path: &Option<PathBuf>) -> Result<Config> {
    match path {
        Some(p) => Config::load(p).map_err(|e| bad(e.to_string())),
        None => Ok(Config::default()),
    }
}

fn estimate(a: EstimateArgs) -> Result<ExitCode> {
    let mut cfg = load_config(&a.config)?;
    if !(1.0..=170.0).contains(&a.hfov_deg) {
        return Err(bad(format!(
            "--hfov-deg {}: the field of view must be between 1 and 170 degrees",
            a.hfov_deg
        )));
    }
    if !a.pitch_deg.is_finite() {
        return Err(bad(format!(
            "--pitch-deg {}: must be a finite angle",
            a.pitch_deg
        )));
    }
    if !(a.depth_scale_m.is_finite() && a.depth_scale_m > 0.0) {
        return Err(bad(format!(
            "--depth-scale-m {}: must be a positive number of metres per unit",
            a.depth_scale_m
        )));
    }
    let p = &mut cfg.estimator;
    if let Some(m) = &a.model {
        p.model = Model::parse(m).ok_or_else(|| {
            bad(format!(
                "--model {m}: use quality, occlusion, mmds, sspa or fixed"
            ))
        })?;
    }
    if let Some(name) = &a.profile {
        p.quality = Profile::parse(name)
            .ok_or_else(|| bad(format!("--profile {name}: use lightfield or mapping")))?
            .targets();
    }
    let target = |flag: &str, v: &str| -> Result<Option<f64>> {
        if v == "off" {
            return Ok(None);
        }
        v.parse::<f64>()
            .map(Some)
            .map_err(|_| bad(format!("--{flag} {v}: a number, or off")))
    };
    if let Some(v) = &a.parallax_px {
        p.quality.parallax_px = target("parallax-px", v)?;
    }
    if let Some(v) = &a.forward_overlap {
        p.quality.forward_overlap = target("forward-overlap", v)?;
    }
    if let Some(v) = a.unseen_fraction_max {
        p.quality.unseen_fraction_max = v;
    }
    if let Some(v) = a.views_per_point_min {
        p.quality.views_per_point_min = v;
    }
    p.with_sspa |= a.sspa;
    if let Some(d) = &a.decimation {
        p.decimation = if d == "auto" {
            match &p.decimation {
                Decimation::Auto { .. } => p.decimation.clone(),
                _ => Decimation::Auto {
                    budget: 0.05,
                    levels: alfd::core::params::DECIMATION_LEVELS.to_vec(),
                },
            }
        } else {
            let n: usize = d
                .parse()
                .ok()
                .filter(|n| (1..=256).contains(n))
                .ok_or_else(|| {
                    bad(format!(
                        "--decimation {d}: use auto or a stride from 1 to 256"
                    ))
                })?;
            Decimation::Fixed(n)
        };
    }
    p.validate().map_err(|e| bad(e.to_string()))?;

    let format = match &a.format {
        Some(f) => DepthFormat::parse(f),
        None => DepthFormat::from_path(&a.depth),
    };
    let opts = ReadOptions {
        format,
        width: a.width,
        height: a.height,
        scale_m: a.depth_scale_m,
    };
    let image = read_depth(&a.depth, &opts).map_err(|e| bad(e.to_string()))?;
    let intr = Intrinsics::from_hfov_deg(image.width(), image.height(), a.hfov_deg, None)
        .map_err(|e| bad(format!("--hfov-deg: {e}")))?;
    let mut est = Estimator::new(cfg.estimator.clone());
    let start = Instant::now();
    let (e, choice) = est
        .estimate(&image, &intr, a.pitch_deg.to_radians())
        .context("estimating")?;
    let elapsed_us = start.elapsed().as_micros() as u64;
    let input = InputInfo {
        file: a.depth.display().to_string(),
        format: format.map_or("?", |f| f.as_str()),
        width: image.width(),
        height: image.height(),
        focal_px: intr.focal_px(),
        pitch_deg: a.pitch_deg,
    };
    if a.json {
        let v = estimate_json(&e, &cfg.estimator, choice.as_ref(), &input, elapsed_us);
        emit(&format!("{}\n", serde_json::to_string_pretty(&v)?))?;
    } else {
        emit(&estimate_text(
            &e,
            &cfg.estimator,
            choice.as_ref(),
            &input,
            elapsed_us,
        ))?;
    }
    Ok(ExitCode::SUCCESS)
}

fn run_tradeoff(a: TradeoffArgs) -> Result<ExitCode> {
    let cfg = load_config(&a.config)?;
    if a.width == 0 || a.height == 0 {
        return Err(bad("--width and --height must be at least 1"));
    }
    let mut frames = tradeoff::reference_frames(a.width, a.height, 69.0);
    for path in &a.depth {
        let opts = ReadOptions {
            format: DepthFormat::from_path(path),
            ..ReadOptions::default()
        };
        let image = read_depth(path, &opts).map_err(|e| bad(e.to_string()))?;
        let intrinsics = Intrinsics::from_hfov_deg(image.width(), image.height(), a.hfov_deg, None)
            .map_err(|e| bad(format!("--hfov-deg: {e}")))?;
        frames.push(tradeoff::Frame {
            name: path
                .file_name()
                .map_or("map".into(), |n| n.to_string_lossy().into_owned()),
            image,
            intrinsics,
            pitch_rad: a.pitch_deg.to_radians(),
        });
    }
    let models = [Model::Mmds, Model::Sspa, Model::Occlusion, Model::Quality];
    let rows = tradeoff::measure(
        &frames,
        &cfg.estimator,
        &models,
        &alfd::core::params::DECIMATION_LEVELS,
        a.repeats,
    );
    emit(&format!(
        "Spacing error of each decimation level against full resolution, and time per frame \
         ({} frames of {}x{}, median of {} runs; score left out).\n\n{}",
        frames.len(),
        a.width,
        a.height,
        a.repeats,
        tradeoff::markdown(&frames, &rows)
    ))?;
    let mut mapping = cfg.estimator.clone();
    mapping.quality = alfd::core::Profile::Mapping.targets();
    emit(&format!(
        "\nThe visibility sweep's sampling (quality model, decimation 1; spacing error against the sweep on every sample).\n\nlightfield profile:\n\n{}\nmapping profile:\n\n{}",
        tradeoff::visibility_markdown(
            &frames,
            &cfg.estimator,
            &[usize::MAX, 160_000, 80_000, 40_000, 20_000, 10_000],
            a.repeats
        ),
        tradeoff::visibility_markdown(
            &frames,
            &mapping,
            &[usize::MAX, 160_000, 80_000, 40_000, 20_000, 10_000],
            a.repeats
        )
    ))?;
    Ok(ExitCode::SUCCESS)
}

fn run_eval(a: EvalArgs) -> Result<ExitCode> {
    let opts = alfd::eval::EvalOptions {
        scenes_dir: a.scenes_dir,
        out_dir: a.out,
        scenes: a.scenes,
        quick: a.quick,
        progress: !a.no_progress,
        decimation_table: true,
        colmap: a.colmap.then_some(a.colmap_script),
    };
    let report = alfd::eval::run(&opts).map_err(|e| match e {
        alfd::eval::EvalError::Write { .. } => anyhow::Error::new(e),
        other => bad(other.to_string()),
    })?;
    emit(&format!("wrote {}\n", report.display()))?;
    Ok(ExitCode::SUCCESS)
}
