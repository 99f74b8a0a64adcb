//! The writer loop (its own thread in flight, [`super::loops`]): owns the capture store (images, manifest, exports) and
//! `telemetry.tlog`. Captures come first and always become a manifest line: one whose frame
//! cannot be had before its deadline is logged without its image, with the reason. Telemetry
//! has its own queue that drops its oldest frame (counted) when full, so a telemetry burst
//! never delays a capture and a slow store never blocks the link.

use super::latency::CaptureStamps;
use super::run::BoxedStore;
use crate::capture::{
    encode_capture, exif_app1, jpeg, log_capture, parse_manifest, write_exports, CaptureRecord,
    ExifGps, ExportSummary, ImageFormat, TlogWriter,
};
use crate::link::unix_us_at;
use crate::link::{mono_ns, TapFrame};
use crate::source::{FrameAt, RawColor, Stamped};
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
    /// Images stored as the camera encoded them (MJPEG), not decoded and re-encoded.
    pub images_as_received: u64,
    /// Images whose size was not [camera]'s, logged without intrinsics.
    pub frames_off_size: u64,
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
    /// `[capture] keep_camera_jpeg`: store an MJPEG camera's frames as they came.
    pub keep_camera_jpeg: bool,
    pub frames: Option<Box<dyn FrameAt>>,
    pub space: Arc<Space>,
    pub make_model: (String, String),
}

/// Runs until the capture queue is closed (the coordinator is done), then flushes the
/// telemetry and writes the exports from the manifest as stored.
pub async fn writer_loop(
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
                match tokio::select! {
                    biased;
                    j = jobs.recv() => Some(j),
                    _ = ready.notified() => None,
                } {
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
                let frame = ctx.frames.as_mut().and_then(|f| f.raw_at(record.mono_ns));
                crate::link::clock::settle().await;
                match frame {
                    None => Some("no colour frame at the capture's instant".to_string()),
                    Some(fr) => {
                        let gps =
                            ExifGps::from_record(&record, &ctx.make_model.0, &ctx.make_model.1);
                        match image_of(&fr, ctx.format, ctx.keep_camera_jpeg, &gps) {
                            Ok(made) => {
                                image = Some(made.bytes);
                                report.images_as_received += u64::from(made.as_received);
                                check_size(&mut record, made.size, &mut report);
                                None
                            }
                            Err(e) => Some(e),
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
        crate::link::clock::settle().await;
        let finished = mono_ns();
        if image.is_some() && r.is_ok() {
            pace.made(finished.saturating_sub(started), finished);
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
            .send(Written {
                record,
                result,
                stamps,
            })
            .await
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

/// How long an image takes, to skip one that cannot be made by its deadline instead of
/// making every later capture late. The estimate is the larger of two parts:
/// - the median of the last few images (`TYPICAL_OF`): under a sustained overload every
///   image takes about as long, and the median keeps that, so the writer does not start
///   one it cannot finish (an estimate that decayed with every skip fell to 170 ms for
///   300 ms images after two skips in a burst: an answer 519 ms after its capture);
/// - the slowest recent image, halving every `STALL_HALF_LIFE_NS` since it was made: one
///   stall (an fsync on a shared disk) weighs for a second or two, not for the flight.
///
/// The median holds for `TYPICAL_HOLD_NS` after the last image made (a writer under
/// overload makes one at least that often), then halves every `TYPICAL_HALF_LIFE_NS`: the
/// estimate learns only from images made, so without that a slow spell would stop the
/// images for good.
#[derive(Debug, Default, Clone)]
struct ImagePace {
    /// The last images' durations, newest last.
    recent_ns: VecDeque<u64>,
    /// The slowest recent image, as of `made_at_ns`.
    slowest_ns: u64,
    made_at_ns: u64,
}

const TYPICAL_OF: usize = 5;
const STALL_HALF_LIFE_NS: u64 = 1_000_000_000;
const TYPICAL_HOLD_NS: u64 = 1_000_000_000;
const TYPICAL_HALF_LIFE_NS: u64 = 4_000_000_000;

/// The intrinsics a record carries are [camera]'s: a frame of another size (a camera
/// delivering another mode than configured) is not described by them. The image is kept
/// and its intrinsics left out (an export then has none to guess from), and the first
/// such frame says so, naming the settings to fix.
fn check_size(record: &mut CaptureRecord, (w, h): (u32, u32), report: &mut WriterReport) {
    let Some(i) = record.intrinsics else { return };
    if (i.width, i.height) == (w, h) {
        return;
    }
    record.intrinsics = None;
    report.frames_off_size += 1;
    if report.frames_off_size == 1 {
        let e = format!(
            "capture {}: the camera's frame is {w}x{h}, [camera] width and height say {}x{}: \
             its intrinsics are left out of the manifest (every such capture's)",
            record.seq, i.width, i.height
        );
        tracing::warn!("{e}");
        report.error(e);
    }
}

/// An image to store.
#[derive(Debug)]
struct Made {
    bytes: Vec<u8>,
    /// The camera's JPEG as received, not re-encoded.
    as_received: bool,
    /// Width and height, px.
    size: (u32, u32),
}

/// The stored image of a captured frame, whether it is the camera's own JPEG, and its
/// size. An MJPEG frame is kept as it came (with the EXIF segment) when the format is
/// JPEG and `keep_camera_jpeg`; one whose structure does not hold up is decoded and
/// re-encoded instead, so it is either whole or refused with the decoder's reason.
fn image_of(
    frame: &Stamped<RawColor>,
    format: ImageFormat,
    keep_camera_jpeg: bool,
    gps: &ExifGps,
) -> Result<Made, String> {
    let mut kept_reason = None;
    if let (RawColor::Mjpeg(jpeg), ImageFormat::Jpeg { .. }, true) =
        (&frame.data, format, keep_camera_jpeg)
    {
        // An invalid position leaves the image untagged rather than lost.
        match jpeg::as_received(jpeg, |w, h| exif_app1(gps, w, h).ok()) {
            Ok(f) => {
                return Ok(Made {
                    bytes: f.bytes,
                    as_received: true,
                    size: (f.width, f.height),
                })
            }
            Err(e) => kept_reason = Some(e),
        }
    }
    let decoded;
    let rgb = match &frame.data {
        // Already pixels (a synthetic camera): no copy.
        RawColor::Rgb(c) => c,
        other => {
            decoded = other.decode().map_err(|e| match &kept_reason {
                Some(k) => format!("colour frame {}: {k}; decoding: {e}", frame.seq),
                None => format!("colour frame {} does not decode: {e}", frame.seq),
            })?;
            &decoded
        }
    };
    let size = (rgb.width as u32, rgb.height as u32);
    encode_capture(&rgb.rgb, size.0, size.1, format, Some(gps))
        .map(|(bytes, _)| Made {
            bytes,
            as_received: false,
            size,
        })
        .map_err(|e| format!("encoding: {e}"))
}

fn halved(ns: u64, elapsed_ns: u64, half_life_ns: u64) -> u64 {
    (ns as f64 * (-(elapsed_ns as f64) / half_life_ns as f64).exp2()) as u64
}

impl ImagePace {
    /// The expected duration of an image started at `now_ns`.
    fn estimate_ns(&self, now_ns: u64) -> u64 {
        let elapsed = now_ns.saturating_sub(self.made_at_ns);
        let mut sorted: Vec<u64> = self.recent_ns.iter().copied().collect();
        sorted.sort_unstable();
        // The lower median: one stall among two images is not the typical one.
        let typical = sorted
            .get(sorted.len().saturating_sub(1) / 2)
            .copied()
            .unwrap_or(0);
        let held = elapsed.saturating_sub(TYPICAL_HOLD_NS);
        halved(typical, held, TYPICAL_HALF_LIFE_NS).max(halved(
            self.slowest_ns,
            elapsed,
            STALL_HALF_LIFE_NS,
        ))
    }

    /// Whether an image started at `started_ns` can be made by `deadline_ns`.
    fn admit(&self, started_ns: u64, deadline_ns: u64) -> bool {
        started_ns.saturating_add(self.estimate_ns(started_ns)) <= deadline_ns
    }

    /// An image took `took_ns`, done at `at_ns`.
    fn made(&mut self, took_ns: u64, at_ns: u64) {
        let slowest = halved(
            self.slowest_ns,
            at_ns.saturating_sub(self.made_at_ns),
            STALL_HALF_LIFE_NS,
        );
        self.slowest_ns = slowest.max(took_ns);
        self.made_at_ns = at_ns;
        if self.recent_ns.len() == TYPICAL_OF {
            self.recent_ns.pop_front();
        }
        self.recent_ns.push_back(took_ns);
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
    const S: u64 = 1000 * MS;

    /// Captures once a second for 40 s, the first at `t0`; each image admitted takes
    /// `took(k)`. Returns the images made.
    fn fly(pace: &mut ImagePace, t0: u64, took: impl Fn(u64) -> u64) -> usize {
        let mut made = 0;
        for k in 0..40u64 {
            let t = t0 + k * S;
            if pace.admit(t, t + 400 * MS) {
                pace.made(took(k), t + took(k));
                made += 1;
            }
        }
        made
    }

    /// One image slow beyond the budget (a stall) among fast ones costs a second or two of
    /// images, not the rest of the flight: the case CI found, where every capture after a
    /// 400 ms stall had no image.
    #[test]
    fn one_stall_among_fast_images_skips_a_second_or_two() {
        let mut pace = ImagePace::default();
        for k in 0..5 {
            pace.made(20 * MS, k * S + 20 * MS);
        }
        pace.made(900 * MS, 5 * S + 900 * MS);
        let made = fly(&mut pace, 6 * S, |_| 20 * MS);
        assert!(
            (37..=39).contains(&made),
            "{made} of 40 made after the stall"
        );
    }

    /// Even a stall with no history before it (the flight's first image) does not stop
    /// the images: the estimate halves with the time since.
    #[test]
    fn a_first_image_that_stalls_skips_a_few_seconds() {
        let mut pace = ImagePace::default();
        pace.made(900 * MS, 900 * MS);
        let made = fly(&mut pace, S, |_| 20 * MS);
        assert!(
            (33..=39).contains(&made),
            "{made} of 40 made after the stall"
        );
    }

    /// A writer truly slower than the budget still skips: the decay does not make it try
    /// every image.
    #[test]
    fn a_writer_always_too_slow_skips_most_images() {
        let mut pace = ImagePace::default();
        pace.made(700 * MS, 700 * MS);
        let made = fly(&mut pace, S, |_| 700 * MS);
        assert!(
            (1..=15).contains(&made),
            "{made} of 40 attempted at 700 ms each"
        );
    }

    /// Sustained overload: 300 ms images, a capture every 133 ms, one writer in order. No
    /// image is started that cannot be made by its deadline, and about one in three is
    /// made (the writer's whole capacity).
    #[test]
    fn under_sustained_overload_no_image_misses_its_deadline() {
        let mut pace = ImagePace::default();
        let took = 300 * MS;
        pace.made(took, took);
        let mut free_at = took;
        let (mut made, mut late) = (0, 0);
        for k in 0..300u64 {
            let capture = S + k * 133 * MS;
            let started = capture.max(free_at);
            let deadline = capture + 400 * MS;
            if pace.admit(started, deadline) {
                free_at = started + took;
                pace.made(took, free_at);
                made += 1;
                late += (free_at > deadline) as usize;
            } else {
                free_at = started + MS; // the manifest line alone
            }
        }
        assert_eq!(late, 0, "{late} of {made} images made past their deadline");
        assert!((80..=150).contains(&made), "{made} of 300 made");
    }
}

#[cfg(test)]
mod image_tests {
    use super::*;
    use crate::source::decode::mjpeg_to_rgb;
    use crate::source::ColorImage;

    fn gps() -> ExifGps {
        ExifGps {
            lat_deg: 47.4,
            lon_deg: 8.5,
            alt_m: 500.0,
            time_unix_us: None,
            make: "alfd".into(),
            model: "uvc".into(),
        }
    }

    fn rgb(w: usize, h: usize) -> ColorImage {
        ColorImage {
            width: w,
            height: h,
            rgb: (0..w * h * 3).map(|i| (i * 13 % 251) as u8).collect(),
        }
    }

    fn stamped(data: RawColor) -> Stamped<RawColor> {
        Stamped {
            mono_ns: 1,
            seq: 7,
            data,
        }
    }

    const JPEG: ImageFormat = ImageFormat::Jpeg { quality: 90 };

    /// An MJPEG frame is stored with its scan untouched, unless re-encoding is asked for or
    /// the format is PNG; other frames are encoded; every JPEG carries the EXIF segment.
    #[test]
    fn an_mjpeg_frame_is_kept_as_the_camera_encoded_it() {
        let c = rgb(40, 24);
        let (camera, _) = encode_capture(&c.rgb, 40, 24, ImageFormat::Jpeg { quality: 50 }, None)
            .expect("encodes");
        let frame = stamped(RawColor::Mjpeg(camera.clone()));
        let Made {
            bytes: kept,
            as_received,
            size,
        } = image_of(&frame, JPEG, true, &gps()).unwrap();
        assert_eq!(size, (40, 24));
        assert!(as_received);
        let sos = camera.windows(2).position(|w| w == [0xFF, 0xDA]).unwrap();
        assert!(
            kept.ends_with(&camera[sos..]),
            "the camera's scan, byte for byte"
        );
        assert_eq!(mjpeg_to_rgb(&kept), mjpeg_to_rgb(&camera));
        assert!(crate::capture::find_exif_app1(&kept).is_some());

        // Re-encoded at quality 90: other bytes, same size, still tagged.
        let Made {
            bytes: again,
            as_received,
            size,
        } = image_of(&frame, JPEG, false, &gps()).unwrap();
        assert_eq!(size, (40, 24));
        assert!(!as_received);
        assert!(!again.ends_with(&camera[sos..]));
        let d = mjpeg_to_rgb(&again).unwrap();
        assert_eq!((d.width, d.height), (40, 24));
        assert!(crate::capture::find_exif_app1(&again).is_some());

        let Made {
            bytes: png,
            as_received,
            ..
        } = image_of(&frame, ImageFormat::Png, true, &gps()).unwrap();
        assert!(!as_received);
        assert_eq!(&png[1..4], b"PNG");

        let Made {
            bytes: from_rgb,
            as_received,
            size,
        } = image_of(&stamped(RawColor::Rgb(c)), JPEG, true, &gps()).unwrap();
        assert_eq!(size, (40, 24));
        assert!(!as_received);
        assert_eq!(mjpeg_to_rgb(&from_rgb).unwrap().width, 40);
    }

    /// A frame cut short in its scan is not stored as if whole: re-encoded from what the
    /// decoder makes of it, or refused with both reasons and the frame's number.
    #[test]
    fn a_broken_mjpeg_frame_is_re_encoded_or_refused_with_its_reason() {
        let c = rgb(40, 24);
        let (camera, _) = encode_capture(&c.rgb, 40, 24, JPEG, None).unwrap();
        let cut = stamped(RawColor::Mjpeg(camera[..camera.len() - 40].to_vec()));
        match image_of(&cut, JPEG, true, &gps()) {
            Ok(Made {
                bytes, as_received, ..
            }) => {
                assert!(!as_received);
                assert!(jpeg::as_received(&bytes, |_, _| None).is_ok(), "whole now");
            }
            Err(e) => assert!(
                e.contains("colour frame 7")
                    && e.contains("end-of-image")
                    && e.contains("decoding"),
                "{e}"
            ),
        }
        let garbage = stamped(RawColor::Mjpeg(vec![0xFF, 0xD8, 1, 2, 3]));
        let e = image_of(&garbage, JPEG, true, &gps()).unwrap_err();
        assert!(
            e.starts_with("colour frame 7: byte 2: expected a marker; decoding:"),
            "{e}"
        );
        let e = image_of(&garbage, JPEG, false, &gps()).unwrap_err();
        assert!(e.starts_with("colour frame 7 does not decode:"), "{e}");
    }

    /// A frame of another size than [camera]'s keeps its image and loses the intrinsics
    /// that do not describe it; the first such capture says so, the others are counted.
    #[test]
    fn a_frame_of_another_size_loses_its_intrinsics_and_says_so() {
        let mut report = WriterReport::default();
        let mut r = crate::capture::record::tests::sample(3);
        let i = r.intrinsics.expect("the sample has intrinsics");
        check_size(&mut r, (i.width, i.height), &mut report);
        assert_eq!(r.intrinsics, Some(i));
        assert!(report.errors.is_empty());
        check_size(&mut r, (i.width * 2, i.height * 2), &mut report);
        assert_eq!(r.intrinsics, None);
        let mut r4 = crate::capture::record::tests::sample(4);
        check_size(&mut r4, (1, 1), &mut report);
        assert_eq!(r4.intrinsics, None);
        assert_eq!(report.frames_off_size, 2);
        assert_eq!(report.errors.len(), 1, "{:?}", report.errors);
        let e = &report.errors[0];
        assert!(
            e.starts_with("capture 3:")
                && e.contains(&format!("{}x{}", i.width * 2, i.height * 2))
                && e.contains("[camera] width and height"),
            "{e}"
        );
    }
}
