//! The command line, parsed once by clap into each subcommand's arguments, and
//! the dispatch to `commands`. `alfd sim` and `alfd eval` exist in the default
//! build only (feature `sim`); the lean flight build has the others.

use crate::commands::{self, logs};
use anyhow::Result;
use clap::{Parser, Subcommand};
use std::process::ExitCode;

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
    log_format: logs::LogFormat,
    /// Log level: error, warn, info, debug, trace.
    #[arg(long, global = true, default_value = "info")]
    log_level: tracing::Level,
}

#[derive(Subcommand)]
enum Command {
    /// The daemon on the simulated autopilot over a synthetic scene, judged against the truth.
    #[cfg(feature = "sim")]
    Sim(commands::sim::Args),
    /// The daemon: link, cameras, estimator, trigger and capture log, until SIGTERM.
    Run(commands::run::Args),
    /// One estimate of the permissible spacing from one depth map.
    Estimate(commands::estimate::Args),
    /// Validate a config file: prints the field and what is wrong, exit 2.
    CheckConfig(commands::check_config::Args),
    /// Error against run time of every decimation level and model.
    Tradeoff(commands::tradeoff::Args),
    /// Ground-truth evaluation on the synthetic scenes: tables, JSON and plots.
    #[cfg(feature = "sim")]
    Eval(commands::eval::Args),
}

pub fn run() -> Result<ExitCode> {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap prints its own help, version and usage errors (exit 2).
            e.exit();
        }
    };
    logs::init(cli.log_format, cli.log_level);
    match cli.command {
        #[cfg(feature = "sim")]
        Command::Sim(a) => commands::sim::run(a),
        Command::Run(a) => commands::run::run(a),
        Command::Estimate(a) => commands::estimate::run(a),
        Command::CheckConfig(a) => commands::check_config::run(a),
        Command::Tradeoff(a) => commands::tradeoff::run(a),
        #[cfg(feature = "sim")]
        Command::Eval(a) => commands::eval::run(a),
    }
}
