//! `alfd tradeoff`: error against run time of every decimation level and model.

use super::{bad, emit, frame_size, load_config};
use alfd::config::SourceKind;
use alfd::core::{Estimator, Intrinsics, Model};
use alfd::depthio::{read_depth, DepthFormat, ReadOptions};
use alfd::tradeoff;
use anyhow::Result;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
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
    #[arg(long, default_value_t = 69.0, allow_negative_numbers = true)]
    hfov_deg: f64,
    /// Metres per unit of a 16-bit PNG --depth map (default: the --config's
    /// [depth] scale_m, else 0.001, a RealSense's); a PFM holds metres.
    #[arg(long, allow_negative_numbers = true)]
    depth_scale_m: Option<f64>,
    /// Config file.
    #[arg(long)]
    config: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let cfg = load_config(&a.config)?;
    frame_size(a.width, a.height)?;
    if !(1..=1000).contains(&a.repeats) {
        return Err(bad(format!(
            "--repeats {}: time each frame 1 to 1000 times (each is a full table's worth of estimates)",
            a.repeats
        )));
    }
    // Checked whether or not a --depth map uses them: a bad value is a typo
    // the user should hear about, not one that waits for the next map.
    Intrinsics::from_hfov_deg(a.width, a.height, a.hfov_deg, None)
        .map_err(|e| bad(format!("--hfov-deg: {e}")))?;
    if !a.pitch_deg.is_finite() {
        return Err(bad(format!(
            "--pitch-deg {}: must be a finite angle",
            a.pitch_deg
        )));
    }
    // A map dumped from the daemon's own depth camera is read at its scale (as
    // `alfd estimate` reads it): at 0.001 a 1 cm-per-unit map is ten times too near.
    let camera = (cfg.depth.kind() != SourceKind::None).then_some(&cfg.depth);
    let depth_scale_m = a
        .depth_scale_m
        .or(camera.map(|d| d.scale_m))
        .unwrap_or(0.001);
    if !(depth_scale_m.is_finite() && depth_scale_m > 0.0) {
        return Err(bad(format!(
            "--depth-scale-m {depth_scale_m}: must be a positive number of metres per unit"
        )));
    }
    let mut frames = tradeoff::reference_frames(a.width, a.height, 69.0);
    let mut described = format!(
        "{} reference frames of {}x{}",
        frames.len(),
        a.width,
        a.height
    );
    for path in &a.depth {
        let format = DepthFormat::from_path(path);
        // The reader's own answer would send the user to --width/--height,
        // which here size the reference scenes, not the map.
        if format == Some(DepthFormat::Z16) {
            return Err(bad(format!(
                "--depth {}: a raw Z16 map has no size to read; tradeoff takes a 16-bit PNG or a PFM \
                 (alfd estimate takes raw Z16 with --width and --height)",
                path.display()
            )));
        }
        let opts = ReadOptions {
            format,
            scale_m: depth_scale_m,
            ..ReadOptions::default()
        };
        let image = read_depth(path, &opts).map_err(|e| bad(e.to_string()))?;
        let intrinsics = Intrinsics::from_hfov_deg(image.width(), image.height(), a.hfov_deg, None)
            .map_err(|e| bad(format!("--hfov-deg: {e}")))?;
        // A map with no estimate at full resolution has none at any level
        // either, and the tables would read 0 % error for it.
        let mut estimator = Estimator::new(cfg.estimator.clone());
        let e = estimator
            .estimate_at(&image, &intrinsics, a.pitch_deg.to_radians(), 1)
            .map_err(|e| bad(format!("--depth {}: {e}", path.display())))?;
        if let Some(why) = e.no_estimate {
            return Err(bad(format!(
                "--depth {}: no estimate at full resolution, so no error to measure: {}",
                path.display(),
                alfd::report::no_estimate_reason(why, &e, &cfg.estimator)
            )));
        }
        let scale = if format == Some(DepthFormat::Pfm) {
            String::new()
        } else {
            format!(", {depth_scale_m} m per unit")
        };
        described.push_str(&format!(
            ", {} ({}x{}{scale})",
            path.display(),
            image.width(),
            image.height()
        ));
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
         ({described}, {}; score left out).\n\n{}",
        if a.repeats == 1 {
            "one run".to_owned()
        } else {
            format!("median of {} runs", a.repeats)
        },
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
