//! `alfd check-config`: validates a config file, and says what this build lacks.

use super::{bad, emit};
use alfd::config::Config;
use anyhow::Result;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The TOML config file.
    file: PathBuf,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let file = a.file;
    let cfg = Config::load(&file).map_err(|e| bad(e.to_string()))?;
    // The lean build has no scene parser; its note below names the synthetic source.
    #[cfg(feature = "sim")]
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
