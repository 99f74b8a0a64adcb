//! The writer thread: owns the capture store (images, manifest, exports) and
//! `telemetry.tlog`. Captures come first and always become a manifest line: one whose frame
//! cannot be had before its deadline is logged without its image, with the reason. Telemetry
//! has its own queue that drops its oldest frame (counted) when full, so a telemetry burst
//! never delays a capture and a slow store never blocks the link.

use super::latency::CaptureStamps;
use super::run::{unix_us_at, BoxedStore};
use crate::capture::{
    encode_capture, log_capture, parse_manifest, write_exports, CaptureRecord, ExifGps,
    ExportSummary, ImageFormat, TlogWriter,
};
use crate::link::{mono_ns, TapFrame};
use crate::source::FrameAt;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::{mpsc, Notify};

/// Captures waiting for the writer. The coordinator never waits on this queue (it keeps a
/// backlog it hands over as room frees); the writer drains it at manifest-line speed when
/// behind, since late captures skip their image.
pub const WRITE_QUEUE: usize = 32;
/// The writer's answers waiting for the coordinator; the writer waits when it is full (the
/// coordinator's loop always takes them, so this cannot deadlock).
pub const WRITTEN_QUEUE: usize = 64;
/// Telemetry frames kept for the tlog: about 10 s of a busy link.
pub const TLOG_QUEUE: usize = 4096;
/// Telemetry frames written between two looks at the capture queue.
const TLOG_BATCH: usize = 256;

/// A capture to log: its image, if any, must be made by `deadline_ns` (monotonic), or the
/// line goes without it.
pub struct WriteJob {
    pub record: Box<CaptureRecord>,
    pub deadline_ns: u64,
    /// When it went into the queue (monotonic ns), for [`super::latency`].
    pub queued_ns: u64,
}

/// The writer's answer: the record as logged (`image_missing` says why it has no image).
pub struct Written {
    pub record: Box<CaptureRecord>,
    pub result: Result<(), String>,
    /// Its stamps up to the end of the write (`answered_ns` is the outbox's).
    pub stamps: CaptureStamps,
}

/// The tlog's queue: bounded, dropping the oldest frame when full.
#[derive(Default)]
pub struct TlogQueue {
    frames: Mutex<VecDeque<TapFrame>>,
    dropped: AtomicU64,
    ready: Notify,
}

impl TlogQueue {
    pub fn push(&self, f: TapFrame) {
        {
            let mut q = self.frames.lock().unwrap_or_else(|p| p.into_inner());
            if q.len() >= TLOG_QUEUE {
                q.pop_front();
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
            q.push_back(f);
        }
        self.ready.notify_one();
    }

    fn take(&self, max: usize) -> Vec<TapFrame> {
        let mut q = self.frames.lock().unwrap_or_else(|p| p.into_inner());
        let n = q.len().min(max);
        q.drain(..n).collect()
    }

    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// The store's space, for STORAGE_INFORMATION (bytes; 0 while unknown).
#[derive(Default)]
pub struct Space {
    pub free_bytes: AtomicU64,
    pub total_bytes: AtomicU64,
}

#[derive(Default)]
pub struct WriterReport {
    pub records: Vec<crate::capture::CaptureRecord>,
    pub errors: Vec<String>,
    pub errors_dropped: u64,
    pub frames_missing: u64,
    pub tlog_frames: u64,
    pub exports: Option<ExportSummary>,
}

impl WriterReport {
    fn error(&mut self, e: String) {
        if self.errors.len() < super::coordinator::REPORT_KEEP {
            self.errors.push(e);
        } else {
            self.errors_dropped += 1;
        }
    }
}

pub struct WriterCtx {
    pub store: BoxedStore,
    pub format: ImageFormat,
    pub frames: Option<Box<dyn FrameAt>>,
    pub space: Arc<Space>,
    pub make_model: (String, String),
    pub rt: tokio::runtime::Handle,
}

/// Runs until the capture queue is closed (the coordinator is done), then flushes the
/// telemetry and writes the exports from the manifest as stored.
pub fn writer_thread(
    mut ctx: WriterCtx,
    mut jobs: mpsc::Receiver<WriteJob>,
    tlog: Arc<TlogQueue>,
    written: mpsc::Sender<Written>,
) -> WriterReport {
    let mut report = WriterReport::default();
    let mut tlog_failed = false;
    let mut pace = ImagePace::default();
    let space = |store: &BoxedStore| {
        if let Some(free) = store.free_bytes() {
            ctx.space.free_bytes.store(free, Ordering::Relaxed);
        }
        if let Some(total) = store.total_bytes() {
            ctx.space.total_bytes.store(total, Ordering::Relaxed);
        }
    };
    space(&ctx.store);
    // One store for the manifest and the tlog: the tlog writer owns it (it syncs the
    // telemetry once a second) and gives it back at the end.
    let mut st: TlogWriter<BoxedStore> = TlogWriter::new(ctx.store, 1_000_000);
    loop {
        // Captures first: they have a deadline, telemetry has none.
        let job = match jobs.try_recv() {
            Ok(j) => Some(j),
            Err(mpsc::error::TryRecvError::Disconnected) => break,
            Err(mpsc::error::TryRecvError::Empty) => {
                let frames = tlog.take(TLOG_BATCH);
                if !frames.is_empty() {
                    write_tlog(&mut st, frames, &mut report, &mut tlog_failed);
                    continue;
                }
                let ready = &tlog.ready;
                match ctx.rt.block_on(async {
                    tokio::select! {
                        j = jobs.recv() => Some(j),
                        _ = ready.notified() => None,
                    }
                }) {
                    Some(None) => break,
                    Some(Some(j)) => Some(j),
                    None => None,
                }
            }
        };
        let Some(WriteJob {
            mut record,
            deadline_ns,
            queued_ns,
        }) = job
        else {
            continue;
        };
        let seq = record.seq;
        let mut image: Option<Vec<u8>> = None;
        let started = mono_ns();
        if record.image.is_some() {
            let missing = if !pace.admit(started, deadline_ns) {
                Some("writer behind: no time to make the image before its deadline".to_string())
            } else {
                match ctx.frames.as_mut().and_then(|f| f.frame_at(record.mono_ns)) {
                    None => Some("no colour frame at the capture's instant".to_string()),
                    Some(fr) => {
                        let gps =
                            ExifGps::from_record(&record, &ctx.make_model.0, &ctx.make_model.1);
                        match encode_capture(
                            &fr.data.rgb,
                            fr.data.width as u32,
                            fr.data.height as u32,
                            ctx.format,
                            Some(&gps),
                        ) {
                            Ok((bytes, _)) => {
                                image = Some(bytes);
                                None
                            }
                            Err(e) => Some(format!("encoding: {e}")),
                        }
                    }
                }
            };
            if let Some(why) = missing {
                // Logged without its image rather than lost: the pose and the spacing that
                // decided it are still worth having.
                report.frames_missing += 1;
                record.image = None;
                record.intrinsics = None;
                record.image_missing = Some(why);
            }
        }
        let store = st.store_mut();
        let r = log_capture(store, &record, image.as_deref());
        space(store);
        let finished = mono_ns();
        if image.is_some() && r.is_ok() {
            pace.made(finished.saturating_sub(started));
        }
        let result = r.map_err(|e| {
            let error = format!("capture {seq} not logged: {e}");
            report.error(error.clone());
            error
        });
        let stamps = CaptureStamps {
            instant_ns: record.mono_ns,
            queued_ns,
            started_ns: started,
            finished_ns: finished,
            answered_ns: 0,
        };
        if written
            .blocking_send(Written {
                record,
                result,
                stamps,
            })
            .is_err()
        {
            tracing::warn!("capture {seq}: the coordinator is gone");
        }
    }
    // The queue is closed: the rest of the telemetry, then the exports.
    loop {
        let frames = tlog.take(TLOG_BATCH);
        if frames.is_empty() || tlog_failed {
            break;
        }
        write_tlog(&mut st, frames, &mut report, &mut tlog_failed);
    }
    if let Err(e) = st.sync() {
        report.error(format!("telemetry.tlog: {e}"));
    }
    let mut store = st.into_inner();
    // The exports come from the manifest as stored: what a reconstruction tool will read,
    // and no list of every record kept in memory meanwhile.
    match store.manifest_bytes() {
        Ok(bytes) => {
            let m = parse_manifest(&bytes);
            match write_exports(&mut store, &m.records) {
                Ok(s) => report.exports = Some(s),
                Err(e) => report.error(format!("exports: {e}")),
            }
            report.records = m.records;
        }
        Err(e) => report.error(format!("manifest: {e}")),
    }
    report
}

/// How long making an image takes (frame, encoding and file; the recent worst), to skip one
/// that cannot be made by its deadline instead of making every later capture late.
#[derive(Debug, Default, Clone, Copy)]
struct ImagePace {
    image_ns: u64,
}

impl ImagePace {
    /// Whether an image started at `started_ns` can be made by `deadline_ns`.
    fn admit(&mut self, started_ns: u64, deadline_ns: u64) -> bool {
        if started_ns.saturating_add(self.image_ns) <= deadline_ns {
            return true;
        }
        // The estimate learns only from images made: without this decay one slow image
        // (a stall, a busy CPU) would skip every image after it.
        self.image_ns -= self.image_ns / 4;
        false
    }

    /// An image was made in `took_ns`: a decaying maximum, so one fast image does not talk
    /// the writer into a slow one it has no time for.
    fn made(&mut self, took_ns: u64) {
        self.image_ns = took_ns.max(self.image_ns - self.image_ns / 8);
    }
}

/// Appends telemetry frames to `telemetry.tlog` until a write fails; from then on the
/// tlog is given up (the error said once) and frames are dropped.
fn write_tlog(
    st: &mut TlogWriter<BoxedStore>,
    frames: Vec<TapFrame>,
    report: &mut WriterReport,
    failed: &mut bool,
) {
    for f in frames {
        if *failed {
            return;
        }
        let unix = unix_us_at(f.mono_ns).unwrap_or(0);
        match st.write(unix, &f.bytes) {
            Ok(()) => report.tlog_frames += 1,
            Err(e) => {
                *failed = true;
                report.error(format!("telemetry.tlog: {e}"));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::ImagePace;

    const MS: u64 = 1_000_000;

    /// One image slow beyond the budget (a stall) costs a few images, not the rest of the
    /// flight: the case CI found, where every capture after a 400 ms stall had no image.
    #[test]
    fn one_slow_image_does_not_skip_every_later_one() {
        let mut pace = ImagePace::default();
        pace.made(900 * MS);
        let mut skipped = 0;
        let mut made = 0;
        for k in 0..40u64 {
            let t = k * 1000 * MS;
            if pace.admit(t, t + 400 * MS) {
                pace.made(20 * MS);
                made += 1;
            } else {
                skipped += 1;
            }
        }
        assert!((1..=4).contains(&skipped), "{skipped} skipped");
        assert_eq!(made + skipped, 40);
    }

    /// A writer truly slower than the budget still skips: the decay does not make it try
    /// every image.
    #[test]
    fn a_writer_always_too_slow_skips_most_images() {
        let mut pace = ImagePace::default();
        let mut made = 0;
        for k in 0..40u64 {
            let t = k * 1000 * MS;
            if pace.admit(t, t + 400 * MS) {
                pace.made(700 * MS);
                made += 1;
            }
        }
        assert!(made <= 15, "{made} of 40 attempted at 700 ms each");
    }
}
