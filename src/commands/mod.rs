//! The subcommands, one file each: its arguments (a clap `Args`) and its
//! handler, which calls the library. They share what is here: the error that
//! means exit code 2, stdout, the async runtime and the one shutdown path.
//! Nothing here depends on the command line that dispatches to them (`cli`).

pub mod check_config;
pub mod estimate;
#[cfg(feature = "sim")]
pub mod eval;
pub mod export;
pub mod logs;
pub mod run;
#[cfg(feature = "sim")]
pub mod sim;
pub mod tradeoff;

use alfd::config::{Config, QualityPatch};
use alfd::core::{Model, Profile, Quality};
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

/// Resolves on SIGTERM or Ctrl-C (SIGINT). Inside a runtime the handlers are installed when this is
/// called, not when the future is first polled: a SIGTERM while the daemon is still
/// starting (opening devices, the store) is then its shutdown once it runs, where it used
/// to be the signal's default action, the process killed mid-start. Outside a runtime
/// (the simulated clock builds its own) they are installed at the first poll.
fn termination() -> impl std::future::Future<Output = ()> {
    use tokio::signal::unix::{signal, Signal, SignalKind};
    let now = tokio::runtime::Handle::try_current().is_ok();
    let early = |kind| if now { signal(kind).ok() } else { None };
    let (term, int) = (
        early(SignalKind::terminate()),
        early(SignalKind::interrupt()),
    );
    async fn next(s: Option<Signal>, kind: SignalKind) {
        // A handler that cannot be installed leaves that signal's default action.
        match s.or_else(|| signal(kind).ok()) {
            Some(mut s) => {
                s.recv().await;
            }
            None => std::future::pending::<()>().await,
        }
    }
    async move {
        tokio::select! {
            _ = next(term, SignalKind::terminate()) => {}
            _ = next(int, SignalKind::interrupt()) => {}
        }
        second_signal_quits();
    }
}

/// After the first signal the handlers stay installed, so a second Ctrl-C would
/// do nothing while the command winds down (`alfd sim` judging the flight against
/// its truth, writing its report). A second SIGINT or SIGTERM ends the process at
/// once, as an operator pressing Ctrl-C again expects. On a thread of its own with
/// its own runtime: the one that heard the first signal may be gone by then (the
/// simulated clock's). Whatever is on disk stays; an image or manifest line cut
/// mid-write is recovered when the flight directory is next opened.
fn second_signal_quits() {
    use tokio::signal::unix::{signal, SignalKind};
    let armed = std::thread::Builder::new()
        .name("alfd-second-signal".into())
        .spawn(|| {
            let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            else {
                return;
            };
            rt.block_on(async {
                let (Ok(mut term), Ok(mut int)) = (
                    signal(SignalKind::terminate()),
                    signal(SignalKind::interrupt()),
                ) else {
                    return;
                };
                // Through the log, in its format: `--log-format json` is one
                // object a line, and a reader of it parses every line.
                tracing::info!("stopping; interrupt again to quit at once");
                tokio::select! {
                    _ = term.recv() => {}
                    _ = int.recv() => {}
                }
                tracing::warn!("second signal: quitting now, without the rest of the report");
                std::process::exit(130);
            });
        });
    if let Err(e) = armed {
        tracing::warn!("a second Ctrl-C will not quit at once: {e}");
    }
}

/// `--model`: the core's models by name, listed in the help and in clap's error (the core
/// does not know clap, so no `ValueEnum` derive there).
pub fn model_parser() -> impl TypedValueParser<Value = Model> {
    PossibleValuesParser::new(Model::ALL.map(Model::as_str))
        .try_map(|s| Model::parse(&s).ok_or_else(|| BadInput(format!("unknown model {s:?}"))))
}

/// The quality targets on a command line (`alfd estimate`, `alfd sim`), over
/// the config's.
#[derive(clap::Args, Debug, Default)]
pub struct QualityFlags {
    /// Quality profile: lightfield (parallax 2 px, unseen 0.002, 2 views) or
    /// mapping (80 % forward overlap, unseen 0.002, 3 views); the flags below override it.
    #[arg(long, value_parser = profile_parser())]
    profile: Option<Profile>,
    /// Largest disparity range per capture step, px ("off": not in force).
    #[arg(long, allow_hyphen_values = true)]
    parallax_px: Option<String>,
    /// Least forward overlap at the nearest depth, 0 to 0.99 ("off": not in force).
    #[arg(long, allow_hyphen_values = true)]
    forward_overlap: Option<String>,
    /// Largest fraction of an in-between view neither neighbouring capture sees,
    /// 0.000001 to 1 ("off" or 1: not in force).
    #[arg(long, allow_hyphen_values = true)]
    unseen_fraction_max: Option<String>,
    /// Captures every visible surface point must be in, 1 to 100 ("off" or 1:
    /// seen once, the coverage bound).
    #[arg(long, allow_hyphen_values = true)]
    views_per_point_min: Option<String>,
}

impl QualityFlags {
    /// The flags as a patch of the config's targets; a value that is not a
    /// number (or `off`) is refused naming its flag. Ranges are checked once the
    /// patch is applied, with the rest of the estimator's parameters.
    pub fn patch(&self) -> Result<QualityPatch> {
        let target = |flag: &str, v: &Option<String>| -> Result<Option<Option<f64>>> {
            let Some(v) = v else { return Ok(None) };
            if v == "off" {
                return Ok(Some(None));
            }
            v.parse::<f64>()
                .map(|x| Some(Some(x)))
                .map_err(|_| bad(format!("--{flag} {v}: a number, or off")))
        };
        let views_per_point_min = match self.views_per_point_min.as_deref() {
            None => None,
            Some("off") => Some(Quality::VIEWS_OFF),
            Some(v) => Some(v.parse().map_err(|_| {
                bad(format!(
                    "--views-per-point-min {v}: a whole number from 1 to 100, or off"
                ))
            })?),
        };
        Ok(QualityPatch {
            profile: self.profile,
            parallax_px: target("parallax-px", &self.parallax_px)?,
            forward_overlap: target("forward-overlap", &self.forward_overlap)?,
            unseen_fraction_max: target("unseen-fraction-max", &self.unseen_fraction_max)?
                .map(|v| v.unwrap_or(Quality::UNSEEN_OFF)),
            views_per_point_min,
        })
    }
}

/// `--profile`: the core's quality profiles by name.
pub fn profile_parser() -> impl TypedValueParser<Value = Profile> {
    PossibleValuesParser::new(Profile::ALL.map(Profile::as_str))
        .try_map(|s| Profile::parse(&s).ok_or_else(|| BadInput(format!("unknown profile {s:?}"))))
}
