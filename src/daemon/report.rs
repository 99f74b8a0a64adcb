//! What a run gives back: each frame's sample, the counters of every part, the manifest as
//! stored, and the errors that end a run.

use super::coordinator::Coordinator;
use super::estimator_task::{Counters, EstimatorReport};
use super::writer::WriterReport;
use crate::capture::{CaptureRecord, ExportSummary};
use crate::link::{self, LinkHandle, LinkHealth};
use std::path::PathBuf;
use std::sync::atomic::Ordering;

/// What the estimator made of one depth frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameSample {
    pub mono_ns: u64,
    /// Local NED of the pose used, when there was one.
    pub pos_ned_m: Option<[f64; 3]>,
    pub spacing_m: Option<f64>,
    pub occlusion_degree: Option<f64>,
    pub suspended: bool,
    pub captured: bool,
    /// Wall time the estimator spent on the frame (ns).
    pub busy_ns: u64,
    /// The frame's visibility sweep took every line itself (not the kept
    /// sweeps of earlier frames: `[estimator] visibility_interleave`).
    pub swept_every_line: bool,
}

/// Counters of a run, and what it logged.
#[derive(Debug, Default)]
pub struct RunReport {
    pub flight_dir: PathBuf,
    /// The manifest read back at the end (what a reconstruction tool will see).
    pub records: Vec<CaptureRecord>,
    pub samples: Vec<FrameSample>,
    pub depth_frames: u64,
    /// Frames dropped because the estimator was still busy with an earlier one.
    pub frames_skipped_busy: u64,
    /// Frames the source never delivered (gaps in its frame counter).
    pub frames_missed_by_source: u64,
    pub frames_bad: u64,
    /// Simulated depth frames not rendered for want of a pose (the bench only).
    pub frames_unposed: u64,
    pub frames_suspended: u64,
    pub captures_decided: u64,
    pub capture_errors: Vec<String>,
    /// Captures whose colour frame could not be had (logged without an image).
    pub frames_missing: u64,
    /// Images stored as an MJPEG camera encoded them (`capture.keep_camera_jpeg`).
    pub images_as_received: u64,
    /// Images whose size was not [camera]'s width and height: logged without intrinsics.
    pub frames_off_size: u64,
    pub camera_commands: u64,
    pub camera_command_failures: u64,
    pub trigger_distances_sent: u64,
    /// Of those, the ones that also triggered once (param3 = 1).
    pub trigger_distances_with_picture: u64,
    pub trigger_distances_acked: u64,
    pub autopilot_triggers: u64,
    /// Of those, known by CAMERA_FEEDBACK alone, and of these placed at its arrival.
    pub autopilot_feedbacks: u64,
    pub feedbacks_timed_on_arrival: u64,
    /// `camera_command`: captures placed where the autopilot reported their picture, those
    /// logged where decided (no report within `PICTURE_WAIT_NS`), and reports no capture took.
    pub pictures_reported: u64,
    pub pictures_unreported: u64,
    /// Of the captures logged where decided, those whose command the autopilot refused.
    pub pictures_refused: u64,
    pub reports_unmatched: u64,
    pub tlog_frames: u64,
    pub exports: Option<ExportSummary>,
    pub link: LinkHealth,
    /// The first STATUSTEXTs sent (at most 1000), and how many more.
    pub statustexts: Vec<String>,
    pub statustexts_dropped: u64,
    /// Capture errors beyond the first 1000 kept in `capture_errors`.
    pub capture_errors_dropped: u64,
    pub estimator_busy_ns: u64,
    /// Captures ground stations commanded (each image of an interval capture counted).
    pub command_captures: u64,
    /// Captures logged without their image or not logged, each said by a failed
    /// CAMERA_IMAGE_CAPTURED or a STATUSTEXT.
    pub captures_failed: u64,
    /// Telemetry frames the tlog's queue dropped (oldest first) while the writer was behind.
    pub tlog_frames_dropped: u64,
    /// From the shutdown (or the end of the depth source) to everything logged, said and
    /// stopped (monotonic ns).
    pub shutdown_ns: u64,
    /// From each capture's instant to its CAMERA_IMAGE_CAPTURED, by phase.
    pub latency: Option<super::latency::LatencySummary>,
}

impl RunReport {
    /// How the autopilot's pictures were known, as the summary and the log say it: empty
    /// when none came by CAMERA_FEEDBACK.
    pub fn feedbacks_text(&self) -> String {
        match (self.autopilot_feedbacks, self.feedbacks_timed_on_arrival) {
            (0, _) => String::new(),
            (n, 0) => format!(" ({n} by CAMERA_FEEDBACK, placed by its GPS time)"),
            (n, k) => format!(
                " ({n} by CAMERA_FEEDBACK, {k} placed at its arrival: no UTC from SYSTEM_TIME to map its GPS time)"
            ),
        }
    }

    /// How the camera commands' pictures were placed, as the summary and the log say it.
    pub fn pictures_text(&self) -> String {
        let after = crate::capture::record::pictures_after_ms(&self.records);
        let median = match after.as_slice() {
            [] => String::new(),
            a => format!(
                " ({:.0} ms after the decision, median; {:.0} ms at most)",
                a[a.len() / 2],
                a[a.len() - 1]
            ),
        };
        let mut s = format!(
            "{} commands sent, {} captures placed where the autopilot reported their picture{median}, {} where decided (no report within {} s, or before the stop)",
            self.camera_commands,
            self.pictures_reported,
            self.pictures_unreported,
            super::coordinator::PICTURE_WAIT_NS as f64 * 1e-9,
        );
        if self.pictures_refused > 0 {
            s += &format!(
                ", {} where decided as the autopilot refused their command",
                self.pictures_refused
            );
        }
        if self.reports_unmatched > 0 {
            s += &format!(
                ", {} reports of no capture's picture",
                self.reports_unmatched
            );
        }
        s
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The store's error names its path (the directory, or the file in it).
    #[error("capture directory: {0}")]
    Store(crate::capture::StoreError),
    #[error("depth source: {0}")]
    Source(String),
    #[error(transparent)]
    Link(#[from] link::LinkError),
    #[error("config: {0}")]
    Config(String),
}

/// The run's counters from the parts that kept them.
pub(crate) fn report(
    co: Coordinator,
    est: EstimatorReport,
    counters: &Counters,
    link: &LinkHandle,
    w: WriterReport,
) -> RunReport {
    let c = co.report.clone();
    RunReport {
        records: w.records,
        capture_errors: w.errors,
        capture_errors_dropped: w.errors_dropped,
        frames_missing: w.frames_missing,
        images_as_received: w.images_as_received,
        frames_off_size: w.frames_off_size,
        tlog_frames: w.tlog_frames,
        exports: w.exports,
        samples: est.samples,
        depth_frames: counters.depth_frames.load(Ordering::Relaxed),
        frames_skipped_busy: counters.skipped_busy.load(Ordering::Relaxed),
        frames_missed_by_source: counters.source_gaps.load(Ordering::Relaxed),
        frames_bad: counters.bad_frames.load(Ordering::Relaxed),
        frames_unposed: counters.unposed_frames.load(Ordering::Relaxed),
        frames_suspended: est.frames_suspended,
        captures_decided: c.captures_decided,
        camera_commands: c.camera_commands,
        camera_command_failures: c.camera_command_failures,
        trigger_distances_sent: co.setter().sent,
        trigger_distances_with_picture: co.setter().sent_with_picture,
        trigger_distances_acked: co.setter().acked,
        autopilot_triggers: c.autopilot_triggers,
        autopilot_feedbacks: c.autopilot_feedbacks,
        feedbacks_timed_on_arrival: c.feedbacks_timed_on_arrival,
        pictures_reported: c.pictures_reported,
        pictures_unreported: c.pictures_unreported,
        pictures_refused: c.pictures_refused,
        reports_unmatched: c.reports_unmatched,
        link: link.health().borrow().clone(),
        statustexts: c.statustexts,
        statustexts_dropped: c.statustexts_dropped,
        estimator_busy_ns: est.busy_ns,
        command_captures: c.command_captures,
        captures_failed: c.captures_failed,
        latency: c.latency.summary(),
        ..RunReport::default()
    }
}
