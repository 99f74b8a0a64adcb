//! `alfd run`: the daemon on the devices a config names, until SIGTERM or Ctrl-C.

use super::{bad, runtime, termination};
use alfd::capture::export::GEO_TXT;
use alfd::capture::store::MANIFEST;
use alfd::capture::{export_flight, StoreError};
use alfd::config::Config;
use alfd::daemon;
use alfd::daemon::devices::{self, LinkSlot};
use alfd::daemon::run::{last_flight_dir, next_flight_dir, RunOptions, RunReport};
use alfd::notify::Notifier;
use anyhow::Result;
use std::path::{Path, PathBuf};
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
        finish_last_flight(&config.capture.dir);
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

/// The last flight under `root`, when it stopped without its exports (power lost,
/// a SIGKILL; systemd then restarts the daemon into a new flight): written now, as
/// `alfd export` would, so no restart leaves a flight without them. One that took no
/// capture is left as it is.
fn finish_last_flight(root: &Path) {
    let Some(dir) = last_flight_dir(root) else {
        return;
    };
    let manifest_len = std::fs::metadata(dir.join(MANIFEST)).map_or(0, |m| m.len());
    if manifest_len == 0 || dir.join(GEO_TXT).exists() {
        return;
    }
    match export_flight(&dir) {
        Ok(done) => tracing::warn!(
            "{} stopped without its exports (power lost or killed): written now, {} captures{}",
            dir.display(),
            done.records,
            if done.missing_images.is_empty() {
                String::new()
            } else {
                format!(", {} listed images missing", done.missing_images.len())
            }
        ),
        // Not stopped: another daemon writes it (two on one capture.dir).
        Err(StoreError::InUse { .. }) => tracing::warn!(
            "{} is being written by another process: is a second alfd running on this capture.dir?",
            dir.display()
        ),
        Err(e) => tracing::warn!(
            "{} stopped without its exports; writing them failed: {e} (alfd export {} to retry)",
            dir.display(),
            dir.display()
        ),
    }
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
    if r.camera_commands > 0 {
        tracing::info!(
            pictures_reported = r.pictures_reported,
            pictures_unreported = r.pictures_unreported,
            pictures_refused = r.pictures_refused,
            reports_unmatched = r.reports_unmatched,
            "the external camera: {}",
            r.pictures_text(),
        );
    }
    if r.trigger_distances_sent > 0 || r.autopilot_triggers > 0 {
        tracing::info!(
            autopilot_triggers = r.autopilot_triggers,
            autopilot_feedbacks = r.autopilot_feedbacks,
            feedbacks_timed_on_arrival = r.feedbacks_timed_on_arrival,
            "the autopilot's distance trigger: {} DO_SET_CAM_TRIGG_DIST sent, {} acknowledged; {} of its pictures logged{}",
            r.trigger_distances_sent,
            r.trigger_distances_acked,
            r.autopilot_triggers,
            r.feedbacks_text(),
        );
    }
}
