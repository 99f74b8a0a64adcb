//! The daemon wired together: the link task, one thread per source, the
//! estimator thread running the pure [`Pipeline`], the coordinator (capture
//! modes, the MAVLink camera protocol, STATUSTEXT, NAMED_VALUE_FLOAT, the
//! systemd watchdog) and the writer thread (encoding, manifest, exports,
//! `telemetry.tlog`). One shutdown path: stop the sources, drain, flush.

use super::camera::{camera_q_ned, CameraInfo, CameraProtocol, Captured, StorageState};
use super::step::{capture_record, FrameInput, Pipeline, RecordInputs, StepOutcome, StepParams};
use crate::capture::{
    encode_capture, log_capture, parse_manifest, write_exports, CaptureMode, CaptureRecord,
    CaptureStore, DirStore, ExifGps, ExportSummary, ImageFormat, TlogWriter,
};
use crate::config::{CameraCommand, Config};
use crate::core::distset::{DistanceSetter, DistanceSetterParams};
use crate::core::geo::LocalFrame;
use crate::core::trigger::Capture;
use crate::core::{DepthData, DepthImage, Estimate, Intrinsics};
use crate::link::{self, mono_ns, LinkEvent, LinkHandle, LinkHealth, TapFrame};
use crate::notify::Notifier;
use crate::source::{DepthSource, FrameAt, FrameRing, FrameSource, SourceError, Stamped};
use mavlink::dialects::ardupilotmega::*;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::{mpsc, watch};

/// Where colour frames come from.
pub enum Frames {
    /// Rendered or fetched at the capture's instant (synthetic).
    AtInstant(Box<dyn FrameAt>),
    /// A streaming camera: a thread keeps its last frames in a ring.
    Stream(Box<dyn FrameSource>),
}

/// The devices a run uses, opened by the caller (so `alfd sim` can hand in
/// sources that render at the simulator's truth).
#[derive(Default)]
pub struct Devices {
    /// `None`: opportunities come from a clock at `tick_hz` (fixed model only).
    pub depth: Option<Box<dyn DepthSource>>,
    pub frames: Option<Frames>,
    /// Opportunity rate without a depth source.
    pub tick_hz: f64,
}

/// Called with each frame's sample as it is made.
pub type SampleHook = Box<dyn FnMut(&FrameSample) + Send>;
/// Called once with the link's handle.
pub type LinkHook = Box<dyn FnOnce(&LinkHandle) + Send>;

/// Where a run's capture log goes when not a directory on disk (tests: a
/// store that fills up).
pub type BoxedStore = Box<dyn CaptureStore + Send>;

pub struct RunOptions {
    /// The flight directory (created; numbering continues after its manifest).
    pub flight_dir: PathBuf,
    /// Log here instead of a `DirStore` on `flight_dir`.
    pub store: Option<BoxedStore>,
    /// Keep every frame's estimate in the report (`alfd sim` plots them).
    pub keep_samples: bool,
    pub notifier: Notifier,
    /// Called with each frame's sample as it is made (progress display).
    pub on_sample: Option<SampleHook>,
    /// Called once with the link's handle (a source that follows telemetry).
    pub on_link: Option<LinkHook>,
}

/// What the estimator made of one depth frame.
#[derive(Debug, Clone, PartialEq)]
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
    pub frames_suspended: u64,
    pub captures_decided: u64,
    pub capture_errors: Vec<String>,
    /// Captures whose colour frame could not be had (logged without an image).
    pub frames_missing: u64,
    pub camera_commands: u64,
    pub camera_command_failures: u64,
    pub trigger_distances_sent: u64,
    pub trigger_distances_acked: u64,
    pub autopilot_triggers: u64,
    pub tlog_frames: u64,
    pub exports: Option<ExportSummary>,
    pub link: LinkHealth,
    /// The first STATUSTEXTs sent (at most 1000), and how many more.
    pub statustexts: Vec<String>,
    pub statustexts_dropped: u64,
    /// Capture errors beyond the first 1000 kept in `capture_errors`.
    pub capture_errors_dropped: u64,
    pub estimator_busy_ns: u64,
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error("capture directory {0}: {1}")]
    Store(PathBuf, String),
    #[error("depth source: {0}")]
    Source(String),
    #[error(transparent)]
    Link(#[from] link::LinkError),
    #[error("config: {0}")]
    Config(String),
}

enum EstOut {
    Sample(FrameSample, StepOutcome),
    SourceFailed(String),
}

enum WriterMsg {
    Capture(Box<CaptureRecord>),
    Tlog(TapFrame),
    Finish,
}

enum WriterEvent {
    Logged(Box<CaptureRecord>),
    Failed {
        record: Box<CaptureRecord>,
        error: String,
    },
}

/// Messages and errors kept in a run's report; beyond, only counted.
const REPORT_KEEP: usize = 1000;

#[derive(Default)]
struct WriterReport {
    records: Vec<CaptureRecord>,
    errors: Vec<String>,
    errors_dropped: u64,
    frames_missing: u64,
    tlog_frames: u64,
    exports: Option<ExportSummary>,
}

/// Unix time (µs) of a monotonic instant. The offset between the two clocks
/// is taken once (the tightest of a few paired readings): read afresh for
/// every message, a thread paused between the two reads stamped telemetry
/// out of order.
fn unix_us_at(mono: u64) -> Option<u64> {
    static OFFSET_US: std::sync::OnceLock<Option<i128>> = std::sync::OnceLock::new();
    let offset = (*OFFSET_US.get_or_init(|| {
        (0..5)
            .filter_map(|_| {
                let before = mono_ns();
                let unix = SystemTime::now().duration_since(UNIX_EPOCH).ok()?;
                let after = mono_ns();
                Some((
                    after - before,
                    unix.as_micros() as i128 - (before / 1000) as i128,
                ))
            })
            .min_by_key(|(spread, _)| *spread)
            .map(|(_, off)| off)
    }))?;
    u64::try_from((mono / 1000) as i128 + offset).ok()
}

/// The first free `flight-NNN` under `root`.
pub fn next_flight_dir(root: &Path) -> PathBuf {
    (1..)
        .map(|n| root.join(format!("flight-{n:03}")))
        .find(|p| !p.exists())
        .expect("an unbounded range has a free name")
}

/// A clock of opportunities when no depth camera exists (fixed spacing).
struct Ticks {
    period_ns: u64,
    next_ns: u64,
    seq: u64,
    intrinsics: Intrinsics,
}

impl DepthSource for Ticks {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }
    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError> {
        let now = mono_ns();
        if self.next_ns == 0 {
            self.next_ns = now;
        }
        if self.next_ns > now {
            std::thread::sleep(Duration::from_nanos(self.next_ns - now));
        }
        let t = self.next_ns;
        self.next_ns += self.period_ns;
        self.seq += 1;
        let data = DepthImage::new(1, 1, DepthData::Metres(vec![f32::NAN]))
            .map_err(|e| SourceError::Fatal(e.to_string()))?;
        Ok(Some(Stamped {
            mono_ns: t,
            seq: self.seq,
            data,
        }))
    }
}

fn depth_thread(
    mut src: Box<dyn DepthSource>,
    tx: std::sync::mpsc::SyncSender<Stamped<DepthImage>>,
    fail: mpsc::UnboundedSender<EstOut>,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
) {
    let mut last_seq: Option<u64> = None;
    while !stop.load(Ordering::Relaxed) {
        match src.next_depth() {
            Ok(Some(f)) => {
                counters.depth_frames.fetch_add(1, Ordering::Relaxed);
                // The source's own counter: a gap is a frame the camera (or the
                // renderer standing in for it) never delivered.
                if let Some(l) = last_seq {
                    let gap = f.seq.saturating_sub(l + 1);
                    counters.source_gaps.fetch_add(gap, Ordering::Relaxed);
                }
                last_seq = Some(f.seq);
                match tx.try_send(f) {
                    Ok(()) => {}
                    Err(std::sync::mpsc::TrySendError::Full(_)) => {
                        counters.skipped_busy.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(std::sync::mpsc::TrySendError::Disconnected(_)) => return,
                }
            }
            Ok(None) => return,
            Err(SourceError::BadFrame { .. }) => {
                counters.bad_frames.fetch_add(1, Ordering::Relaxed);
            }
            Err(SourceError::Lost(e)) => {
                counters.bad_frames.fetch_add(1, Ordering::Relaxed);
                tracing::warn!("depth source lost: {e}; retrying");
                std::thread::sleep(Duration::from_millis(200));
            }
            Err(SourceError::Fatal(e)) => {
                let _ = fail.send(EstOut::SourceFailed(e));
                return;
            }
        }
    }
}

#[derive(Default)]
struct Counters {
    depth_frames: AtomicU64,
    source_gaps: AtomicU64,
    skipped_busy: AtomicU64,
    bad_frames: AtomicU64,
}

struct EstimatorCtx {
    link: LinkHandle,
    rt: tokio::runtime::Handle,
    intrinsics: Intrinsics,
    config: Config,
    last_seq: u64,
    stop: Arc<AtomicBool>,
}

fn estimator_thread(
    ctx: EstimatorCtx,
    rx: std::sync::mpsc::Receiver<Stamped<DepthImage>>,
    out: mpsc::UnboundedSender<EstOut>,
) {
    let cfg = &ctx.config;
    let params = StepParams {
        camera_mount_pitch_rad: cfg.depth.mount_pitch_rad,
        frame_period_s: 1.0 / cfg.depth.fps,
        capture_mode: cfg.capture.mode,
        image_format: (cfg.capture.mode == CaptureMode::Frame).then_some(cfg.capture.image_format),
    };
    let mut pipeline: Option<Pipeline> = None;
    let state = ctx.link.state();
    // Without a depth frame for this long the camera has stalled: the trigger
    // still gets opportunities, at the fallback spacing, flagged; one per
    // frame period while the stall lasts, the step the trigger assumes.
    let stall = Duration::from_secs_f64((5.0 / cfg.depth.fps).max(0.15));
    let period = Duration::from_secs_f64(1.0 / cfg.depth.fps);
    let mut stalled = false;
    loop {
        let wait = if stalled { period } else { stall };
        let frame = match rx.recv_timeout(wait) {
            Ok(f) => {
                stalled = false;
                Some(f)
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                stalled = true;
                None
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return,
        };
        if ctx.stop.load(Ordering::Relaxed) {
            return;
        }
        let started = mono_ns();
        if pipeline.is_none() {
            if let Some(home) = state.borrow().as_ref().map(|s| s.home) {
                let mut p = Pipeline::new(
                    cfg.estimator.clone(),
                    cfg.trigger,
                    params,
                    LocalFrame::new(home),
                );
                p.set_last_seq(ctx.last_seq);
                pipeline = Some(p);
            }
        }
        let t = frame.as_ref().map_or(started, |f| f.mono_ns);
        let outcome = match pipeline.as_mut() {
            None => StepOutcome::Suspended {
                reason: "no position from the autopilot yet".into(),
            },
            Some(p) => {
                let pose = ctx
                    .rt
                    .block_on(ctx.link.pose_at_mono_ns(t))
                    .map_err(|e| e.to_string());
                let boot_us = ctx
                    .rt
                    .block_on(ctx.link.boot_ns_at_mono_ns(t))
                    .map(|ns| ns / 1000);
                p.on_frame(FrameInput {
                    mono_ns: t,
                    depth: frame.as_ref().map(|f| &f.data),
                    intrinsics: &ctx.intrinsics,
                    pose,
                    boot_us,
                    unix_us: unix_us_at(t),
                })
            }
        };
        let pos = match &outcome {
            StepOutcome::Capture { record, .. } => Some([
                record.position.north_m,
                record.position.east_m,
                -record.position.up_m,
            ]),
            _ => None,
        };
        let est = match &outcome {
            StepOutcome::Wait { estimate } | StepOutcome::Capture { estimate, .. } => {
                Some(estimate.as_ref())
            }
            StepOutcome::Suspended { .. } => None,
        };
        let pos_ned_m = pos.or_else(|| {
            est.is_some()
                .then(|| ctx.rt.block_on(ctx.link.pose_at_mono_ns(t)).ok())
                .flatten()
                .map(|p| p.pos_ned_m.to_array())
        });
        let sample = FrameSample {
            mono_ns: t,
            pos_ned_m,
            spacing_m: est.and_then(|e| e.spacing.chosen_m),
            occlusion_degree: est.and_then(|e| e.occlusion).map(|o| o.degree),
            suspended: est.is_none(),
            captured: matches!(outcome, StepOutcome::Capture { .. }),
            busy_ns: mono_ns().saturating_sub(started),
        };
        if out.send(EstOut::Sample(sample, outcome)).is_err() {
            return;
        }
    }
}

fn writer_thread(
    store: BoxedStore,
    format: ImageFormat,
    mut rx: mpsc::UnboundedReceiver<WriterMsg>,
    mut frames: Option<Box<dyn FrameAt>>,
    events: mpsc::UnboundedSender<WriterEvent>,
    free_bytes: Arc<AtomicU64>,
    make_model: (String, String),
) -> WriterReport {
    let mut report = WriterReport::default();
    let mut tlog_failed = false;
    // One store for the manifest and the tlog: the tlog writer owns it (it
    // syncs the telemetry once a second) and gives it back at the end.
    let mut st: TlogWriter<BoxedStore> = TlogWriter::new(store, 1_000_000);
    while let Some(msg) = rx.blocking_recv() {
        match msg {
            WriterMsg::Finish => break,
            WriterMsg::Tlog(f) => {
                if tlog_failed {
                    continue;
                }
                let unix = unix_us_at(f.mono_ns).unwrap_or(0);
                match st.write(unix, &f.bytes) {
                    Ok(()) => report.tlog_frames += 1,
                    Err(e) => {
                        tlog_failed = true;
                        report.errors.push(format!("telemetry.tlog: {e}"));
                    }
                }
            }
            WriterMsg::Capture(mut record) => {
                let seq = record.seq;
                let mut image: Option<Vec<u8>> = None;
                if record.image.is_some() {
                    let frame = frames.as_mut().and_then(|f| f.frame_at(record.mono_ns));
                    match frame {
                        Some(fr) => {
                            let gps = ExifGps::from_record(&record, &make_model.0, &make_model.1);
                            match encode_capture(
                                &fr.data.rgb,
                                fr.data.width as u32,
                                fr.data.height as u32,
                                format,
                                Some(&gps),
                            ) {
                                Ok((bytes, _)) => image = Some(bytes),
                                Err(e) => {
                                    report.errors.push(format!("capture {seq}: encoding: {e}"));
                                }
                            }
                        }
                        None => report.frames_missing += 1,
                    }
                    if image.is_none() {
                        // Logged without its image rather than lost: the pose and
                        // the spacing that decided it are still worth having.
                        record.image = None;
                        record.intrinsics = None;
                    }
                }
                let store = st.store_mut();
                let r = log_capture(store, &record, image.as_deref());
                if let Some(free) = store.free_bytes() {
                    free_bytes.store(free, Ordering::Relaxed);
                }
                let ev = match r {
                    Ok(()) => WriterEvent::Logged(record),
                    Err(e) => {
                        let error = format!("capture {seq} not logged: {e}");
                        if report.errors.len() < REPORT_KEEP {
                            report.errors.push(error.clone());
                        } else {
                            report.errors_dropped += 1;
                        }
                        WriterEvent::Failed { record, error }
                    }
                };
                let _ = events.send(ev);
            }
        }
    }
    if let Err(e) = st.sync() {
        report.errors.push(format!("telemetry.tlog: {e}"));
    }
    let mut store = st.into_inner();
    // The exports come from the manifest as stored: what a reconstruction
    // tool will read, and no list of every record kept in memory meanwhile.
    match store.manifest_bytes() {
        Ok(bytes) => {
            let m = parse_manifest(&bytes);
            match write_exports(&mut store, &m.records) {
                Ok(s) => report.exports = Some(s),
                Err(e) => report.errors.push(format!("exports: {e}")),
            }
            report.records = m.records;
        }
        Err(e) => report.errors.push(format!("manifest: {e}")),
    }
    report
}

/// Runs the daemon until `shutdown` resolves or the depth source ends.
pub async fn run(
    config: Config,
    devices: Devices,
    mut options: RunOptions,
    shutdown: impl Future<Output = ()>,
) -> Result<RunReport, RunError> {
    let link_cfg = config
        .link
        .clone()
        .ok_or_else(|| RunError::Config("no [mavlink] section: the daemon needs a link".into()))?;
    let store: BoxedStore = match options.store.take() {
        Some(s) => s,
        None => Box::new(
            DirStore::open(&options.flight_dir)
                .map_err(|e| RunError::Store(options.flight_dir.clone(), e.to_string()))?,
        ),
    };
    let last_seq = store
        .manifest_bytes()
        .map(|b| {
            parse_manifest(&b)
                .records
                .iter()
                .map(|r| r.seq)
                .max()
                .unwrap_or(0)
        })
        .unwrap_or(0);

    let (mut link_task, link, mut link_events) = link::new(link_cfg.clone());
    if let Some(f) = options.on_link.take() {
        f(&link);
    }
    let (tap_tx, mut tap_rx) = mpsc::channel::<TapFrame>(4096);
    link_task.set_tap(tap_tx);
    let (link_stop_tx, mut link_stop_rx) = watch::channel(false);
    let link_join = tokio::spawn(link_task.run(async move {
        let _ = link_stop_rx.wait_for(|s| *s).await;
    }));

    // Writer.
    let (writer_tx, writer_rx) = mpsc::unbounded_channel();
    let (wev_tx, mut wev_rx) = mpsc::unbounded_channel();
    let free_bytes = Arc::new(AtomicU64::new(store.free_bytes().unwrap_or(0)));
    let stop = Arc::new(AtomicBool::new(false));
    let (frame_at, frame_thread): (Option<Box<dyn FrameAt>>, _) = match devices.frames {
        None => (None, None),
        Some(Frames::AtInstant(f)) => (Some(f), None),
        Some(Frames::Stream(mut s)) => {
            let tol = (2e9 / config.camera.fps) as u64;
            let ring = FrameRing::new(8, tol);
            let feed = ring.clone();
            let stop = stop.clone();
            let h = std::thread::Builder::new()
                .name("alfd-camera".into())
                .spawn(move || {
                    while !stop.load(Ordering::Relaxed) {
                        match s.next_frame() {
                            Ok(Some(f)) => feed.push(f),
                            Ok(None) => return,
                            Err(SourceError::Fatal(e)) => {
                                tracing::error!("camera: {e}");
                                return;
                            }
                            Err(e) => tracing::warn!("camera: {e}"),
                        }
                    }
                })
                .expect("a thread starts");
            (
                Some(Box::new(WaitingRing(ring)) as Box<dyn FrameAt>),
                Some(h),
            )
        }
    };
    let quality_fmt = config.capture.image_format;
    let make_model = (
        "alfd".to_string(),
        format!("{} {}", config.camera.width, config.camera.height),
    );
    let fb = free_bytes.clone();
    let writer = std::thread::Builder::new()
        .name("alfd-writer".into())
        .spawn(move || {
            writer_thread(
                store,
                quality_fmt,
                writer_rx,
                frame_at,
                wev_tx,
                fb,
                make_model,
            )
        })
        .expect("a thread starts");
    let tap_forward = {
        let writer_tx = writer_tx.clone();
        tokio::spawn(async move {
            while let Some(f) = tap_rx.recv().await {
                if writer_tx.send(WriterMsg::Tlog(f)).is_err() {
                    return;
                }
            }
        })
    };

    // Sources and the estimator.
    let counters = Arc::new(Counters::default());
    let depth: Box<dyn DepthSource> = match devices.depth {
        Some(d) => d,
        None => Box::new(Ticks {
            period_ns: (1e9 / devices.tick_hz.max(1.0)) as u64,
            next_ns: 0,
            seq: 0,
            intrinsics: Intrinsics::from_hfov_deg(1, 1, 69.0, None)
                .map_err(|e| RunError::Config(e.to_string()))?,
        }),
    };
    let intrinsics = depth.intrinsics();
    let (depth_tx, depth_rx) = std::sync::mpsc::sync_channel(1);
    let (est_tx, mut est_rx) = mpsc::unbounded_channel();
    let depth_join = {
        let fail = est_tx.clone();
        let stop = stop.clone();
        let counters = counters.clone();
        std::thread::Builder::new()
            .name("alfd-depth".into())
            .spawn(move || depth_thread(depth, depth_tx, fail, stop, counters))
            .expect("a thread starts")
    };
    let est_join = {
        let ctx = EstimatorCtx {
            link: link.clone(),
            rt: tokio::runtime::Handle::current(),
            intrinsics,
            config: config.clone(),
            last_seq,
            stop: stop.clone(),
        };
        std::thread::Builder::new()
            .name("alfd-estimator".into())
            .spawn(move || estimator_thread(ctx, depth_rx, est_tx))
            .expect("a thread starts")
    };

    let mut co = Coordinator {
        link: link.clone(),
        config: config.clone(),
        camera: CameraProtocol::new(CameraInfo::for_alfd(
            config.camera.width as u16,
            config.camera.height as u16,
        )),
        setter: DistanceSetter::new(DistanceSetterParams::default()),
        suspended: None,
        fallback: false,
        terms: None,
        terms_said_ns: 0,
        skipped_said: 0,
        last_estimate: None,
        tightest_since_trigger: None,
        last_trigger_ne: None,
        seq: last_seq,
        report: RunReport {
            flight_dir: options.flight_dir.clone(),
            ..RunReport::default()
        },
        writer: writer_tx.clone(),
        keep_samples: options.keep_samples,
        free_bytes,
        skipped_busy: counters.clone(),
    };
    co.status(MavSeverity::MAV_SEVERITY_INFO, &co.ready_text())
        .await;
    let _ = options.notifier.ready();
    let pet = options
        .notifier
        .watchdog_interval()
        .unwrap_or(Duration::from_secs(3600));
    let mut watchdog = tokio::time::interval(pet);
    let mut second = tokio::time::interval(Duration::from_secs(1));
    second.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tokio::pin!(shutdown);
    let mut source_error = None;
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            o = est_rx.recv() => match o {
                None => break,
                Some(EstOut::SourceFailed(e)) => { source_error = Some(e); break; }
                Some(EstOut::Sample(s, outcome)) => {
                    if let Some(cb) = options.on_sample.as_mut() {
                        cb(&s);
                    }
                    co.on_outcome(s, outcome).await;
                }
            },
            Some(ev) = link_events.recv() => co.on_link_event(ev).await,
            Some(ev) = wev_rx.recv() => co.on_writer_event(ev).await,
            _ = second.tick() => co.every_second().await,
            _ = watchdog.tick() => { let _ = options.notifier.watchdog(); }
        }
    }

    // One way out: stop the sources, let the estimator finish its frame,
    // drain the decisions already made, flush the writer, stop the link.
    let _ = options.notifier.stopping();
    stop.store(true, Ordering::Relaxed);
    let deadline = tokio::time::Instant::now() + Duration::from_millis(600);
    while let Ok(Some(o)) = tokio::time::timeout_at(deadline, est_rx.recv()).await {
        if let EstOut::Sample(s, outcome) = o {
            co.on_outcome(s, outcome).await;
        }
    }
    // Threads blocked in a device read are left behind rather than holding
    // the exit past its budget; normally they end within a frame.
    let _ = tokio::time::timeout(
        Duration::from_millis(400),
        tokio::task::spawn_blocking(move || {
            let _ = depth_join.join();
            let _ = est_join.join();
        }),
    )
    .await;
    drop(frame_thread);
    let _ = writer_tx.send(WriterMsg::Finish);
    let wreport = tokio::task::spawn_blocking(move || writer.join())
        .await
        .ok()
        .and_then(|r| r.ok())
        .unwrap_or_else(|| WriterReport {
            errors: vec!["the writer thread did not finish".into()],
            ..WriterReport::default()
        });
    while let Ok(ev) = wev_rx.try_recv() {
        co.on_writer_event(ev).await;
    }
    tap_forward.abort();
    let _ = link_stop_tx.send(true);
    let link_result = tokio::time::timeout(Duration::from_secs(1), link_join).await;
    let mut report = co.report;
    report.link = link.health().borrow().clone();
    report.depth_frames = counters.depth_frames.load(Ordering::Relaxed);
    report.frames_skipped_busy = counters.skipped_busy.load(Ordering::Relaxed);
    report.frames_bad = counters.bad_frames.load(Ordering::Relaxed);
    report.frames_missed_by_source = counters.source_gaps.load(Ordering::Relaxed);
    report.capture_errors.extend(wreport.errors);
    report.capture_errors_dropped = wreport.errors_dropped;
    report.frames_missing = wreport.frames_missing;
    report.tlog_frames = wreport.tlog_frames;
    report.exports = wreport.exports;
    report.trigger_distances_sent = co.setter.sent;
    report.trigger_distances_acked = co.setter.acked;
    report.records = wreport.records;
    if let Ok(Ok(Err(e))) = link_result {
        return Err(e.into());
    }
    if let Some(e) = source_error {
        return Err(RunError::Source(e));
    }
    Ok(report)
}

/// A ring that waits briefly for the frame of an instant it has not seen yet
/// (the colour frame of a depth instant may arrive a little later).
struct WaitingRing(FrameRing);

impl FrameAt for WaitingRing {
    fn frame_at(&mut self, mono: u64) -> Option<Stamped<crate::source::ColorImage>> {
        for _ in 0..20 {
            if let Some(f) = self.0.frame_at(mono) {
                return Some(f);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        None
    }
}

struct Coordinator {
    link: LinkHandle,
    config: Config,
    camera: CameraProtocol,
    setter: DistanceSetter,
    suspended: Option<String>,
    fallback: bool,
    /// The terms last announced, and when (announcements at most every 10 s).
    terms: Option<crate::core::estimate::Terms>,
    terms_said_ns: u64,
    skipped_said: u64,
    last_estimate: Option<Box<Estimate>>,
    tightest_since_trigger: Option<f64>,
    last_trigger_ne: Option<[f64; 2]>,
    seq: u64,
    report: RunReport,
    writer: mpsc::UnboundedSender<WriterMsg>,
    keep_samples: bool,
    free_bytes: Arc<AtomicU64>,
    skipped_busy: Arc<Counters>,
}

impl Coordinator {
    fn ready_text(&self) -> String {
        let c = &self.config;
        let terms = match c.estimator.model {
            crate::core::Model::Fixed => "fixed".to_string(),
            m => format!("{} model", m.as_str()),
        };
        format!(
            "alfd ready: {terms}, capture {}",
            match c.capture.mode {
                CaptureMode::Frame => "frames",
                CaptureMode::CameraCommand => "by camera command",
                CaptureMode::AutopilotDistance => "by autopilot distance",
            }
        )
    }

    async fn status(&mut self, severity: MavSeverity, text: &str) {
        tracing::info!("{text}");
        // A long flight must not grow memory with its messages: the first
        // ones are kept for the report, the rest counted.
        if self.report.statustexts.len() < REPORT_KEEP {
            self.report.statustexts.push(text.to_string());
        } else {
            self.report.statustexts_dropped += 1;
        }
        for m in CameraProtocol::statustext(severity, text) {
            let _ = self.link.send(m).await;
        }
    }

    async fn on_outcome(&mut self, s: FrameSample, outcome: StepOutcome) {
        self.report.estimator_busy_ns += s.busy_ns;
        if self.keep_samples {
            self.report.samples.push(s.clone());
        }
        match outcome {
            StepOutcome::Suspended { reason } => {
                self.report.frames_suspended += 1;
                if self.suspended.as_deref() != Some(reason.as_str()) {
                    if self.suspended.is_none() {
                        let text = format!("alfd: triggers suspended: {reason}");
                        self.status(MavSeverity::MAV_SEVERITY_WARNING, &text).await;
                    }
                    self.suspended = Some(reason);
                }
            }
            StepOutcome::Wait { estimate } => {
                self.resumed().await;
                self.on_estimate(estimate, s.mono_ns).await;
            }
            StepOutcome::Capture { estimate, record } => {
                self.resumed().await;
                self.on_estimate(estimate, s.mono_ns).await;
                self.on_capture(*record).await;
            }
        }
    }

    async fn resumed(&mut self) {
        if self.suspended.take().is_some() {
            self.status(MavSeverity::MAV_SEVERITY_NOTICE, "alfd: triggers resumed")
                .await;
        }
    }

    async fn on_estimate(&mut self, e: Box<Estimate>, mono: u64) {
        let spacing = e
            .spacing
            .chosen_m
            .unwrap_or(self.config.trigger.fallback_spacing_m);
        let fallback = e.spacing.chosen_m.is_none();
        if fallback != self.fallback {
            self.fallback = fallback;
            let text = match (&e.no_estimate, fallback) {
                (Some(why), true) => format!(
                    "alfd: no estimate ({why:?}), fallback spacing {:.1} m",
                    self.config.trigger.fallback_spacing_m
                ),
                (_, true) => "alfd: no estimate, fallback spacing".to_string(),
                (_, false) => "alfd: estimating again".to_string(),
            };
            self.status(MavSeverity::MAV_SEVERITY_NOTICE, &text).await;
        }
        // Which terms the estimate used: said when they change (a scene
        // without occlusion boundaries drops the occlusion term), not more
        // than every 10 s.
        if e.is_ok() && self.terms != Some(e.terms) && mono >= self.terms_said_ns + 10_000_000_000 {
            self.terms = Some(e.terms);
            self.terms_said_ns = mono;
            let bound = e.active_bound.map_or("config limit", |b| b.as_str());
            let text = format!("alfd: terms {}; bound {bound}", e.terms.names().join(", "));
            self.status(MavSeverity::MAV_SEVERITY_INFO, &text).await;
        }
        self.tightest_since_trigger = Some(
            self.tightest_since_trigger
                .map_or(spacing, |t| t.min(spacing)),
        );
        if self.config.capture.mode == CaptureMode::AutopilotDistance {
            if let Some(d) = self.setter.update(mono as f64 * 1e-9, spacing) {
                let msg = command(
                    self.config.link.as_ref().map_or(1, |l| l.system_id),
                    1,
                    MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST,
                    [d as f32, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
                );
                let _ = self.link.send(msg).await;
            }
        }
        self.last_estimate = Some(e);
    }

    async fn on_capture(&mut self, record: CaptureRecord) {
        self.report.captures_decided += 1;
        match self.config.capture.mode {
            CaptureMode::Frame => {}
            CaptureMode::CameraCommand => {
                let sys = self.config.link.as_ref().map_or(1, |l| l.system_id);
                let msg = match self.config.capture.command {
                    CameraCommand::ImageStartCapture => command(
                        sys,
                        0,
                        MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
                        [0.0, 0.0, 1.0, record.seq as f32, 0.0, 0.0, 0.0],
                    ),
                    CameraCommand::DigicamControl => command(
                        sys,
                        0,
                        MavCmd::MAV_CMD_DO_DIGICAM_CONTROL,
                        [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
                    ),
                };
                self.report.camera_commands += 1;
                if let Err(e) = self.link.send(msg).await {
                    self.report.camera_command_failures += 1;
                    let text = format!("alfd: camera command not sent: {e}");
                    self.status(MavSeverity::MAV_SEVERITY_ERROR, &text).await;
                }
            }
            // The autopilot takes the pictures; its CAMERA_TRIGGER feedback is logged.
            CaptureMode::AutopilotDistance => return,
        }
        self.seq = record.seq;
        let _ = self.writer.send(WriterMsg::Capture(Box::new(record)));
    }

    async fn on_link_event(&mut self, ev: LinkEvent) {
        match ev {
            LinkEvent::Command {
                system_id,
                component_id,
                command,
                params,
                trust,
            } => {
                let boot_ms = self.boot_ms_now().await;
                for m in
                    self.camera
                        .on_command(command, params, system_id, component_id, trust, boot_ms)
                {
                    let _ = self.link.send(m).await;
                }
            }
            LinkEvent::CommandAck { command, result } => {
                let accepted = result == MavResult::MAV_RESULT_ACCEPTED as u8;
                if command == MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST as u32 {
                    self.setter.on_ack(accepted);
                } else if !accepted {
                    self.report.camera_command_failures += 1;
                    let text = format!("alfd: camera command {command} refused ({result})");
                    self.status(MavSeverity::MAV_SEVERITY_WARNING, &text).await;
                }
            }
            LinkEvent::CameraTrigger {
                mono_ns: Some(t), ..
            } if self.config.capture.mode == CaptureMode::AutopilotDistance => {
                self.on_autopilot_trigger(t).await;
            }
            LinkEvent::CameraTrigger { mono_ns: None, .. }
                if self.config.capture.mode == CaptureMode::AutopilotDistance =>
            {
                self.status(
                    MavSeverity::MAV_SEVERITY_WARNING,
                    "alfd: autopilot trigger before time sync: not logged",
                )
                .await;
            }
            LinkEvent::AutopilotRebooted => {
                self.status(
                    MavSeverity::MAV_SEVERITY_WARNING,
                    "alfd: autopilot rebooted, resynchronising time",
                )
                .await;
            }
            LinkEvent::GpsGlitch { jump_m } => {
                let text = format!("alfd: GPS glitch ({jump_m:.1} m jump), position held");
                self.status(MavSeverity::MAV_SEVERITY_WARNING, &text).await;
            }
            _ => {}
        }
    }

    async fn on_autopilot_trigger(&mut self, t: u64) {
        self.report.autopilot_triggers += 1;
        let pose = match self.link.pose_at_mono_ns(t).await {
            Ok(p) => p,
            Err(e) => {
                let text = format!("alfd: autopilot trigger without a pose ({e}): not logged");
                self.status(MavSeverity::MAV_SEVERITY_WARNING, &text).await;
                return;
            }
        };
        let Some(home) = self.link.state().borrow().as_ref().map(|s| s.home) else {
            return;
        };
        let ne = [pose.pos_ned_m.x, pose.pos_ned_m.y];
        let distance = self
            .last_trigger_ne
            .map(|l| (ne[0] - l[0]).hypot(ne[1] - l[1]));
        self.last_trigger_ne = Some(ne);
        let tightest = self
            .tightest_since_trigger
            .take()
            .unwrap_or(self.config.trigger.fallback_spacing_m);
        let spacing = self.setter.in_force_m().unwrap_or(tightest);
        let capture = Capture {
            distance_since_last_m: distance,
            spacing_m: spacing.min(tightest),
            undersampled: distance.is_some_and(|d| d > tightest * (1.0 + 1e-9)),
            rate_limited: false,
            fallback: self.fallback,
        };
        self.seq += 1;
        let boot_us = self.link.boot_ns_at_mono_ns(t).await.map(|n| n / 1000);
        let record = capture_record(&RecordInputs {
            seq: self.seq,
            mono_ns: t,
            pose: &pose,
            boot_us,
            unix_us: unix_us_at(t),
            local: &LocalFrame::new(home),
            estimate: self.last_estimate.as_deref(),
            closed_loop: None,
            capture: &capture,
            model: self.config.estimator.model.as_str(),
            mode: CaptureMode::AutopilotDistance,
            image_format: None,
            intrinsics: None,
            mount_pitch_rad: self.config.depth.mount_pitch_rad,
        });
        let _ = self.writer.send(WriterMsg::Capture(Box::new(record)));
    }

    async fn on_writer_event(&mut self, ev: WriterEvent) {
        match ev {
            WriterEvent::Logged(r) => self.image_captured(&r, true).await,
            WriterEvent::Failed { record, error } => {
                // The ground station hears of the failure too: no gap in its image indices.
                self.image_captured(&record, false).await;
                self.status(MavSeverity::MAV_SEVERITY_ERROR, &format!("alfd: {error}"))
                    .await;
            }
        }
    }

    async fn image_captured(&mut self, r: &CaptureRecord, success: bool) {
        {
            {
                let boot_ms = (r.time_boot_us / 1000) as u32;
                let q = camera_quaternion(r);
                let msg = self.camera.image_captured(&Captured {
                    time_boot_ms: boot_ms,
                    time_unix_us: r.time_unix_us,
                    lat_deg: r.position.lat_deg,
                    lon_deg: r.position.lon_deg,
                    alt_m: r.position.alt_m,
                    rel_alt_m: r.position.rel_alt_m,
                    q_camera_ned: q,
                    image_index: (r.seq as i32) - 1,
                    file_name: r.image.clone(),
                    success,
                });
                let _ = self.link.send(msg).await;
            }
        }
    }

    async fn every_second(&mut self) {
        let boot_ms = self.boot_ms_now().await;
        let (spacing, occ) = match &self.last_estimate {
            Some(e) => (
                Some(
                    e.spacing
                        .chosen_m
                        .unwrap_or(self.config.trigger.fallback_spacing_m),
                ),
                e.occlusion.map(|o| o.degree),
            ),
            None => (None, None),
        };
        for m in CameraProtocol::named_values(spacing, occ, boot_ms) {
            let _ = self.link.send(m).await;
        }
        let free = self.free_bytes.load(Ordering::Relaxed);
        self.camera.set_storage(StorageState::from_free_bytes(free));
        // The estimator runs on as many frames as its budget allows: say when
        // it could not keep up.
        let skipped = self.skipped_busy.skipped_busy.load(Ordering::Relaxed);
        if skipped > self.skipped_said {
            let text = format!(
                "alfd: estimator behind, {} depth frames skipped",
                skipped - self.skipped_said
            );
            self.skipped_said = skipped;
            self.status(MavSeverity::MAV_SEVERITY_NOTICE, &text).await;
        }
    }

    async fn boot_ms_now(&self) -> u32 {
        self.link
            .boot_ns_at_mono_ns(mono_ns())
            .await
            .map_or(0, |ns| (ns / 1_000_000) as u32)
    }
}

fn command(target_system: u8, target_component: u8, cmd: MavCmd, p: [f32; 7]) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        target_system,
        target_component,
        command: cmd,
        confirmation: 0,
        param1: p[0],
        param2: p[1],
        param3: p[2],
        param4: p[3],
        param5: p[4],
        param6: p[5],
        param7: p[6],
    })
}

/// The camera's orientation in NED (w, x, y, z) from a record's attitude.
fn camera_quaternion(r: &CaptureRecord) -> [f32; 4] {
    let a = &r.attitude;
    camera_q_ned(
        a.roll_deg.to_radians(),
        a.pitch_deg.to_radians(),
        a.yaw_deg.to_radians(),
        a.camera_pitch_deg.to_radians(),
    )
    .unwrap_or([f32::NAN, 0.0, 0.0, 0.0])
}
