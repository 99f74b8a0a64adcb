//! `alfd estimate`: one estimate of the permissible spacing from one depth map.

use super::{bad, emit, load_config, QualityFlags};
use alfd::config::SourceKind;
use alfd::core::{Decimation, Estimator, Intrinsics, Model};
use alfd::depthio::{read_depth, DepthFormat, ReadOptions};
use alfd::report::{estimate_json, estimate_text, InputInfo};
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// Depth map: raw Z16 (.z16/.raw), 16-bit grey PNG (.png) or PFM float metres (.pfm).
    #[arg(long)]
    depth: PathBuf,
    /// Horizontal field of view, degrees (1 to 170), across the image width
    /// (default: the --config's [depth] hfov_deg, when it has a depth source).
    #[arg(long, allow_negative_numbers = true)]
    hfov_deg: Option<f64>,
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
    /// Metres per Z16/PNG unit (default: the --config's [depth] scale_m, when
    /// it has a depth source, else 0.001).
    #[arg(long)]
    depth_scale_m: Option<f64>,
    /// Config file ([quality], [sampling], [estimator], [score]; a daemon
    /// config's [depth] gives the field of view and the depth scale).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override the sampling model (default: quality).
    #[arg(long, value_parser = super::model_parser())]
    model: Option<Model>,
    #[command(flatten)]
    quality: QualityFlags,
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

pub fn run(a: Args) -> Result<ExitCode> {
    let mut cfg = load_config(&a.config)?;
    // A frame dumped from the daemon's own depth camera is read as the daemon
    // reads it: with the config's scale (a RealSense at 0.01 m per unit read at
    // the default 0.001 put every depth ten times too near) and field of view.
    let camera = (cfg.depth.kind() != SourceKind::None).then_some(&cfg.depth);
    let hfov_deg =
        match (a.hfov_deg, camera) {
            (Some(h), _) => h,
            (None, Some(d)) => d.hfov_deg,
            (None, None) => return Err(bad(
                "--hfov-deg: the depth camera's horizontal field of view is needed (or a --config \
                 whose [depth] section gives it)",
            )),
        };
    let depth_scale_m = a
        .depth_scale_m
        .or(camera.map(|d| d.scale_m))
        .unwrap_or(0.001);
    if !(1.0..=170.0).contains(&hfov_deg) {
        return Err(bad(format!(
            "--hfov-deg {hfov_deg}: the field of view must be between 1 and 170 degrees"
        )));
    }
    if !a.pitch_deg.is_finite() {
        return Err(bad(format!(
            "--pitch-deg {}: must be a finite angle",
            a.pitch_deg
        )));
    }
    if !(depth_scale_m.is_finite() && depth_scale_m > 0.0) {
        return Err(bad(format!(
            "--depth-scale-m {depth_scale_m}: must be a positive number of metres per unit"
        )));
    }
    let p = &mut cfg.estimator;
    if let Some(m) = a.model {
        p.model = m;
    }
    a.quality.patch()?.apply(&mut p.quality);
    p.with_sspa |= a.sspa;
    if let Some(d) = &a.decimation {
        p.decimation = if d == "auto" {
            match &p.decimation {
                Decimation::Auto { .. } => p.decimation.clone(),
                _ => Decimation::auto(),
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
        scale_m: depth_scale_m,
    };
    let image = read_depth(&a.depth, &opts).map_err(|e| bad(e.to_string()))?;
    // The config's principal point belongs to its frame size only.
    let principal_px = camera
        .filter(|d| (d.width, d.height) == (image.width(), image.height()))
        .and_then(|d| d.principal_px);
    let intr = Intrinsics::from_hfov_deg(image.width(), image.height(), hfov_deg, principal_px)
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
        depth_scale_m: (format != Some(DepthFormat::Pfm)).then_some(depth_scale_m),
    };
    if a.json {
        let v = estimate_json(&e, &cfg.estimator, choice.as_ref(), &input, elapsed_us);
        emit(&format!("{}\n", serde_json::to_string_pretty(&v)?))?;
    } else {
        let mut text = estimate_text(&e, &cfg.estimator, choice.as_ref(), &input, elapsed_us);
        // What the config chose instead of a flag, said under the input line.
        let mut taken = Vec::new();
        if a.hfov_deg.is_none() {
            taken.push(format!("hfov {hfov_deg} deg"));
        }
        if a.depth_scale_m.is_none() && camera.is_some() && format != Some(DepthFormat::Pfm) {
            taken.push(format!("{depth_scale_m} m per unit"));
        }
        if let (false, Some(path)) = (taken.is_empty(), &a.config) {
            let at = text.find('\n').map_or(text.len(), |i| i + 1);
            text.insert_str(
                at,
                &format!(
                    "from config    {} ([depth] of {})\n",
                    taken.join(", "),
                    path.display()
                ),
            );
        }
        emit(&text)?;
    }
    Ok(ExitCode::SUCCESS)
}
