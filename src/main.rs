//! The `alfd` binary: `cli` parses the command line once and hands each
//! subcommand (`commands`, one file each) its arguments; the subcommands call
//! the library. Errors are mapped to exit codes in one place: 2 for bad input,
//! 1 for anything else.

mod cli;
mod commands;

use std::process::ExitCode;

fn main() -> ExitCode {
    match cli::run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("alfd: error: {e:#}");
            ExitCode::from(commands::exit_code(&e))
        }
    }
}
