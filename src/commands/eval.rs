//! `alfd eval`: the ground-truth evaluation on the synthetic scenes (feature `sim`).

use super::{bad, emit};
use anyhow::Result;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};

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
    check(&a)?;
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

/// What would fail only after minutes of evaluation, refused before the first
/// scene: the output path, the scene directory, and COLMAP's script and module.
fn check(a: &Args) -> Result<()> {
    if a.out.exists() && !a.out.is_dir() {
        return Err(bad(format!(
            "--out {}: exists and is not a directory",
            a.out.display()
        )));
    }
    let from_dir = a.scenes.is_empty() || a.scenes.iter().any(|s| !Path::new(s).exists());
    if from_dir && !a.scenes_dir.is_dir() {
        return Err(bad(format!(
            "--scenes-dir {}: no such directory (the scene files: run from the repository, or name it)",
            a.scenes_dir.display()
        )));
    }
    if a.colmap {
        if !a.colmap_script.is_file() {
            return Err(bad(format!(
                "--colmap-script {}: no such file",
                a.colmap_script.display()
            )));
        }
        let imports = Command::new("python3")
            .args(["-c", "import pycolmap"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if !imports {
            return Err(bad(
                "--colmap: python3 cannot import pycolmap (pip install pycolmap)",
            ));
        }
    }
    Ok(())
}
