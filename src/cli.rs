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
    /// Write a flight's exports (geo.txt, transforms.json) from its manifest: for a
    /// flight that stopped without them (power cut, SIGKILL), or with an external
    /// camera's pictures paired with its captures (--images).
    Export(commands::export::Args),
    /// Ground-truth evaluation on the synthetic scenes: tables, JSON and plots.
    #[cfg(feature = "sim")]
    Eval(commands::eval::Args),
}

pub fn run() -> Result<ExitCode> {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => match unknown_name(&e) {
            // A word outside a flag's names is bad input like any other: one line, exit 2.
            Some(line) => return Err(commands::bad(line)),
            // clap prints its own help, version and usage errors (exit 2).
            None => e.exit(),
        },
    };
    logs::init(cli.log_format, cli.log_level);
    match cli.command {
        #[cfg(feature = "sim")]
        Command::Sim(a) => commands::sim::run(a),
        Command::Run(a) => commands::run::run(a),
        Command::Estimate(a) => commands::estimate::run(a),
        Command::CheckConfig(a) => commands::check_config::run(a),
        Command::Tradeoff(a) => commands::tradeoff::run(a),
        Command::Export(a) => commands::export::run(a),
        #[cfg(feature = "sim")]
        Command::Eval(a) => commands::eval::run(a),
    }
}

/// `--mode x: use frame, camera_command or autopilot_distance` for a value
/// outside a `ValueEnum`'s names; `None` for every other clap error.
fn unknown_name(e: &clap::Error) -> Option<String> {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    if e.kind() != ErrorKind::InvalidValue {
        return None;
    }
    let (Some(ContextValue::String(arg)), Some(ContextValue::String(value))) = (
        e.get(ContextKind::InvalidArg),
        e.get(ContextKind::InvalidValue),
    ) else {
        return None;
    };
    let Some(ContextValue::Strings(names)) = e.get(ContextKind::ValidValue) else {
        return None;
    };
    let flag = arg.split_whitespace().next().unwrap_or(arg);
    let names = match names.split_last() {
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
        None => return None,
    };
    Some(format!("{flag} {value}: use {names}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_error(args: &[&str]) -> clap::Error {
        match Cli::try_parse_from([&["alfd"], args].concat()) {
            Ok(_) => panic!("{args:?} parsed"),
            Err(e) => e,
        }
    }

    #[test]
    fn a_name_outside_the_choices_is_one_line_naming_them() {
        let e = parse_error(&[
            "estimate",
            "--depth",
            "x",
            "--hfov-deg",
            "69",
            "--format",
            "exr",
        ]);
        assert_eq!(
            unknown_name(&e).as_deref(),
            Some("--format exr: use z16, png16 or pfm")
        );
        let e = parse_error(&["--log-format", "xml", "check-config", "x.toml"]);
        assert_eq!(
            unknown_name(&e).as_deref(),
            Some("--log-format xml: use text or json")
        );
        // Other usage errors keep clap's own message and help.
        assert_eq!(unknown_name(&parse_error(&["estimate"])), None);
        assert_eq!(unknown_name(&parse_error(&["fly"])), None);
    }

    #[cfg(feature = "sim")]
    #[test]
    fn sim_takes_the_capture_modes_and_poses_by_their_config_names() {
        let e = parse_error(&["sim", "--mode", "command"]);
        assert_eq!(
            unknown_name(&e).as_deref(),
            Some("--mode command: use frame, camera_command or autopilot_distance")
        );
        let e = parse_error(&["sim", "--pose", "gps"]);
        assert_eq!(
            unknown_name(&e).as_deref(),
            Some("--pose gps: use truth or telemetry")
        );
        for mode in ["frame", "camera_command", "autopilot_distance"] {
            for pose in ["truth", "telemetry"] {
                assert!(
                    Cli::try_parse_from(["alfd", "sim", "--mode", mode, "--pose", pose]).is_ok(),
                    "{mode} {pose}"
                );
            }
        }
    }
}
