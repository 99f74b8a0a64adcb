//! The `alfd` binary: parses the command line and calls the library. Errors are
//! mapped to exit codes in one place: 2 for bad input, 1 for anything else.

mod cli;
mod daemon_cmd;

use std::process::ExitCode;

fn main() -> ExitCode {
    match cli::run() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("alfd: error: {e:#}");
            ExitCode::from(cli::exit_code(&e))
        }
    }
}
