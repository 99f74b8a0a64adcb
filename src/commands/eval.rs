//! `alfd eval`: the ground-truth evaluation on the synthetic scenes (feature `sim`).

use super::{bad, emit};
use anyhow::Result;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
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

pub fn run(a: Args) -> Result<ExitCode> {
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
