//! `alfd run`: the daemon on the devices a config names, until SIGTERM or Ctrl-C.

use super::{bad, runtime, termination};
use alfd::config::Config;
use alfd::daemon;
use alfd::daemon::devices::{self, LinkSlot};
use alfd::daemon::run::{next_flight_dir, RunOptions, RunReport};
use alfd::notify::Notifier;
use anyhow::Result;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The daemon's config file (see configs/).
    #[arg(long)]
    config: PathBuf,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let config = Config::load(&a.config).map_err(|e| bad(e.to_string()))?;
    if config.link.is_none() {
        return Err(bad(format!(
            "{}: [mavlink]: the daemon needs a link to the flight controller",
            a.config.display()
        )));
    }
    let rt = runtime()?;
    let report = rt.block_on(async {
        // First: a SIGTERM from here on stops the daemon by its one shutdown path.
        let stop = termination();
        let slot = LinkSlot::default();
        let devices = devices::open(&config, slot.clone())
            .map_err(|e| bad(format!("{}: {e}", a.config.display())))?;
        let flight_dir = next_flight_dir(&config.capture.dir);
        tracing::info!("captures go to {}", flight_dir.display());
        let options = RunOptions {
            flight_dir,
            store: None,
            keep_samples: false,
            notifier: Notifier::from_env(),
            on_sample: None,
            on_link: Some(Box::new(move |l| {
                let _ = slot.set(l.clone());
            })),
            memory_wire: None,
        };
        daemon::run::run(config, devices, options, stop)
            .await
            .map_err(anyhow::Error::from)
    })?;
    print_report(&report);
    rt.shutdown_timeout(std::time::Duration::from_millis(200));
    Ok(ExitCode::SUCCESS)
}

fn print_report(r: &RunReport) {
    // Only the bench's synthetic camera waits for a pose; a real one never does.
    let unposed = match r.frames_unposed {
        0 => String::new(),
        n => format!(", {n} not rendered before the autopilot gave a position"),
    };
    tracing::info!(
        "stopped: {} captures in {} ({} without an image, {} images as the camera encoded them), {} depth frames ({} skipped while busy, {} bad{unposed}), {} errors",
        r.records.len(),
        r.flight_dir.display(),
        r.frames_missing,
        r.images_as_received,
        r.depth_frames,
        r.frames_skipped_busy,
        r.frames_bad,
        r.capture_errors.len()
    );
    for e in &r.capture_errors {
        tracing::warn!("{e}");
    }
}
