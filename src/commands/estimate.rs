//! `alfd estimate`: one estimate of the permissible spacing from one depth map.

use super::{bad, emit, load_config};
use alfd::core::{Decimation, Estimator, Intrinsics, Model, Profile, Quality};
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
    /// Override the sampling model (default: quality).
    #[arg(long, value_parser = super::model_parser())]
    model: Option<Model>,
    /// Quality profile: lightfield (parallax 2 px, unseen 0.002, 2 views) or
    /// mapping (80 % forward overlap, unseen 0.002, 3 views); the flags below override it.
    #[arg(long, value_parser = super::profile_parser())]
    profile: Option<Profile>,
    /// Largest disparity range per capture step, px ("off": not in force).
    #[arg(long)]
    parallax_px: Option<String>,
    /// Least forward overlap at the nearest depth, 0 to 0.99 ("off": not in force).
    #[arg(long)]
    forward_overlap: Option<String>,
    /// Largest fraction of an in-between view neither neighbouring capture sees,
    /// 0.000001 to 1 ("off" or 1: not in force).
    #[arg(long)]
    unseen_fraction_max: Option<String>,
    /// Captures every visible surface point must be in, 1 to 100 ("off" or 1:
    /// seen once, the coverage bound).
    #[arg(long)]
    views_per_point_min: Option<String>,
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
    if let Some(m) = a.model {
        p.model = m;
    }
    if let Some(profile) = a.profile {
        p.quality = profile.targets();
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
    if let Some(v) = &a.unseen_fraction_max {
        p.quality.unseen_fraction_max =
            target("unseen-fraction-max", v)?.unwrap_or(Quality::UNSEEN_OFF);
    }
    if let Some(v) = &a.views_per_point_min {
        p.quality.views_per_point_min = match v.as_str() {
            "off" => Quality::VIEWS_OFF,
            v => v.parse().map_err(|_| {
                bad(format!(
                    "--views-per-point-min {v}: a whole number from 1 to 100, or off"
                ))
            })?,
        };
    }
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
