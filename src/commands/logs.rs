//! The log set-up shared by every subcommand: stderr, text or JSON lines.

use std::io::IsTerminal;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// One line per event; colours only on a terminal (journald-friendly).
    Text,
    /// One JSON object per line.
    Json,
}

/// Logs to stderr: plain text for journald (no colours, no timestamps when
/// journald adds its own), or JSON lines for machines.
pub fn init(format: LogFormat, level: tracing::Level) {
    let journald = std::env::var_os("JOURNAL_STREAM").is_some();
    let builder = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_max_level(level)
        .with_target(false);
    let _ = match format {
        LogFormat::Json => builder.json().try_init(),
        LogFormat::Text if journald => builder.with_ansi(false).without_time().try_init(),
        LogFormat::Text => builder
            .with_ansi(std::io::stderr().is_terminal())
            .try_init(),
    };
}
