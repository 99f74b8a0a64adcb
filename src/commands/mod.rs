//! The subcommands, one file each: its arguments (a clap `Args`) and its
//! handler, which calls the library. They share what is here: the error that
//! means exit code 2, stdout, the async runtime and the one shutdown path.
//! Nothing here depends on the command line that dispatches to them (`cli`).

pub mod check_config;
pub mod estimate;
#[cfg(feature = "sim")]
pub mod eval;
pub mod logs;
pub mod run;
#[cfg(feature = "sim")]
pub mod sim;
pub mod tradeoff;

use alfd::config::Config;
use alfd::core::{Model, Profile};
use anyhow::{Context, Result};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use std::path::PathBuf;

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

/// `--width` and `--height` of a rendered frame (`alfd sim`, `alfd tradeoff`'s
/// reference scenes): at least 16×12, so that decimation 16 keeps a sample a
/// row, and at most 4096×4096 (a frame and its estimator's grids stay a few
/// hundred megabytes; beyond, the allocation would abort the process).
pub fn frame_size(width: usize, height: usize) -> Result<()> {
    if !(16..=4096).contains(&width) || !(12..=4096).contains(&height) {
        return Err(bad(format!(
            "--width {width} --height {height}: 16×12 to 4096×4096 pixels"
        )));
    }
    Ok(())
}

/// 2 for bad input, 1 for anything else.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    if e.downcast_ref::<BadInput>().is_some() {
        2
    } else {
        1
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

/// The config file, or the defaults without one; a bad file is bad input.
fn load_config(path: &Option<PathBuf>) -> Result<Config> {
    match path {
        Some(p) => Config::load(p).map_err(|e| bad(e.to_string())),
        None => Ok(Config::default()),
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// Resolves on SIGTERM or Ctrl-C.
async fn termination() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = term => {}
        _ = tokio::signal::ctrl_c() => {}
    }
}

/// `--model`: the core's models by name, listed in the help and in clap's error (the core
/// does not know clap, so no `ValueEnum` derive there).
pub fn model_parser() -> impl TypedValueParser<Value = Model> {
    PossibleValuesParser::new(Model::ALL.map(Model::as_str))
        .try_map(|s| Model::parse(&s).ok_or_else(|| BadInput(format!("unknown model {s:?}"))))
}

/// `--profile`: the core's quality profiles by name.
pub fn profile_parser() -> impl TypedValueParser<Value = Profile> {
    PossibleValuesParser::new(Profile::ALL.map(Profile::as_str))
        .try_map(|s| Profile::parse(&s).ok_or_else(|| BadInput(format!("unknown profile {s:?}"))))
}
