//! The daemon wired together, and only that: the link first (its handle goes to whoever
//! needs it), then the writer loop ([`super::writer`]), the depth and estimator loops
//! ([`super::estimator_task`]), each a thread in flight and a task on simulated time
//! ([`super::loops`]), and the coordinator's loop ([`super::serve`]), which performs what
//! the pure [`Coordinator`] decides through [`super::outbox`]. One shutdown
//! ([`super::shutdown`]), its order written once at the end of [`run`]. Every queue is
//! bounded; each says its policy where it is made. What a run gives back is in
//! [`super::report`].

use super::colour::{ring_frames, stream_thread};
use super::coordinator::{Coordinator, EstimatorView, LOCATING_MAX};
use super::estimator_task::{
    depth_loop, estimator_loop, Counters, EstimatorCtx, EstimatorReport, Ticks, DECIDED_QUEUE,
};
use super::loops::{spawn_loop, Running};
use super::outbox::Outbox;
pub use super::report::{FrameSample, RunError, RunReport};
use super::serve::Loop;
use super::shutdown::{self, Stage};
use super::writer::{
    writer_loop, Space, TlogQueue, WriteJob, WriterCtx, WriterReport, Written, WRITE_QUEUE,
    WRITTEN_QUEUE,
};
use crate::capture::{parse_manifest, CaptureStore, DirStore};
use crate::config::Config;
use crate::core::Intrinsics;
use crate::link::{self, mono_ns, LinkHandle, TapFrame};
use crate::notify::Notifier;
use crate::source::{DepthSource, FrameAt, FrameSource};
use std::collections::VecDeque;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// CAMERA_IMAGE_CAPTURED follows its capture's instant within this (issue 14).
pub const CAPTURED_WITHIN_NS: u64 = 500_000_000;

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
    /// Connect through these in-memory streams instead of `mavlink.address` (`alfd sim` on
    /// simulated time: firmware-sim's `Transport::Memory`).
    pub memory_wire: Option<mpsc::Receiver<tokio::io::DuplexStream>>,
}

/// A flight directory's name: `flight-NNN`.
const FLIGHT_PREFIX: &str = "flight-";

/// The first free `flight-NNN` under `root`.
pub fn next_flight_dir(root: &Path) -> PathBuf {
    (1..)
        .map(|n| root.join(format!("{FLIGHT_PREFIX}{n:03}")))
        .find(|p| !p.exists())
        .expect("an endless range has a free name")
}

/// The highest-numbered `flight-NNN` under `root`, if any.
pub fn last_flight_dir(root: &Path) -> Option<PathBuf> {
    std::fs::read_dir(root)
        .ok()?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name();
            let n: u32 = name.to_str()?.strip_prefix(FLIGHT_PREFIX)?.parse().ok()?;
            Some((n, e.path()))
        })
        .max_by_key(|(n, _)| *n)
        .map(|(_, dir)| dir)
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
    let (store, last_seq) = open_store(&mut options)?;
    // The saved frames are the colour camera's: their intrinsics go in the manifest.
    let image_intrinsics = devices
        .frames
        .as_ref()
        .map(|_| super::devices::intrinsics(&config.camera))
        .transpose()
        .map_err(|e| RunError::Config(format!("camera: {e}")))?;
    let (stage, stop) = shutdown::channel();
    let rt = tokio::runtime::Handle::current();

    // The link first: everything else gets its handle.
    let (mut link_task, link, link_events) = link::new(link_cfg);
    if let Some(w) = options.memory_wire.take() {
        link_task.set_memory_wire(w);
    }
    if let Some(f) = options.on_link.take() {
        f(&link);
    }
    // The link's tap is bounded (its own policy); frames go on to the tlog's queue, which
    // drops its oldest when the writer is behind.
    let (tap_tx, tap_rx) = mpsc::channel::<TapFrame>(4096);
    link_task.set_tap(tap_tx);
    let link_join = {
        let mut stop = stop.clone();
        tokio::spawn(link_task.run(async move { stop.reached(Stage::Done).await }))
    };
    let tlog = Arc::new(TlogQueue::default());
    let tap_forward = tokio::spawn(forward_tap(tap_rx, tlog.clone(), stop.clone()));

    let w = spawn_writer(&config, store, devices.frames, tlog.clone(), &stop, &rt);
    let e = spawn_estimation(
        &config,
        image_intrinsics,
        devices.depth,
        devices.tick_hz,
        &link,
        &rt,
        last_seq,
        &stop,
        &mut options,
    )?;

    // The coordinator, last: it takes from all of the above.
    // Located poses: one per capture waiting for its pose, of which the coordinator keeps
    // at most LOCATING_MAX, so a send never finds it full.
    let (located_tx, located_rx) = mpsc::channel(LOCATING_MAX);
    let mut lp = Loop {
        co: Coordinator::new(&config, last_seq, image_intrinsics),
        out: Outbox {
            link: link.clone(),
            located: located_tx,
            writer: Some(w.jobs),
            backlog: VecDeque::new(),
        },
        link: link.clone(),
        link_events,
        decided: e.decided,
        views: e.views,
        written: w.written,
        located: located_rx,
        space: w.space,
        counters: e.counters.clone(),
    };
    lp.start().await;
    let _ = options.notifier.ready();
    // The caller's shutdown (SIGTERM) is heard in one place: it moves the stage, the one
    // cancellation every loop and thread follows. The coordinator's loop returns on it.
    let source_error = {
        let cancel = async {
            shutdown.await;
            stage.advance(Stage::Stopping);
            std::future::pending::<std::convert::Infallible>().await
        };
        tokio::select! {
            biased;
            e = lp.serve(stop.clone(), &options.notifier) => e,
            never = cancel => match never {},
        }
    };

    // The shutdown, in order: stop taking work (sources, estimator, interval captures);
    // log the captures already decided; close the writer's queue so it flushes the tlog and
    // writes the exports; say every capture's CAMERA_IMAGE_CAPTURED; stop the link last.
    let stop_began_ns = mono_ns();
    let _ = options.notifier.stopping();
    stage.advance(Stage::Stopping);
    lp.take_decided(Duration::from_millis(600)).await;
    // Threads blocked in a device read are left behind rather than holding the exit past
    // its budget; normally they end within a frame.
    let (depth_join, est_join) = (e.depth_join, e.est_join);
    let est_report = tokio::time::timeout(Duration::from_millis(400), async move {
        depth_join.join().await;
        est_join.join().await
    })
    .await
    .ok()
    .flatten()
    .unwrap_or_default();
    drop(w.frame_thread);
    lp.hand_over().await;
    lp.close_writer().await;
    let wreport = w.join.join().await.unwrap_or_else(|| WriterReport {
        errors: vec!["the writer did not finish".into()],
        ..WriterReport::default()
    });
    stage.advance(Stage::Done);
    let _ = tap_forward.await;
    let link_result = tokio::time::timeout(Duration::from_secs(1), link_join).await;

    if let Ok(Ok(Err(e))) = link_result {
        return Err(e.into());
    }
    if let Some(e) = source_error {
        return Err(RunError::Source(e));
    }
    let report = RunReport {
        flight_dir: options.flight_dir.clone(),
        tlog_frames_dropped: tlog.dropped(),
        shutdown_ns: mono_ns().saturating_sub(stop_began_ns),
        ..super::report::report(lp.co, est_report, &e.counters, &link, wreport)
    };
    if let Some(l) = &report.latency {
        tracing::info!("{l}");
    }
    Ok(report)
}

/// The writer's side of a run: its loop, its two queues, and the colour frames it
/// reads (a streaming camera's thread and ring, or a source rendering at an instant).
struct Writing {
    join: Running<WriterReport>,
    /// Captures to log: bounded, and never waited on (the coordinator keeps a backlog).
    jobs: mpsc::Sender<WriteJob>,
    /// The writer's answers: bounded; the writer waits when full.
    written: mpsc::Receiver<Written>,
    space: Arc<Space>,
    frame_thread: Option<std::thread::JoinHandle<()>>,
}

fn spawn_writer(
    config: &Config,
    store: BoxedStore,
    frames: Option<Frames>,
    tlog: Arc<TlogQueue>,
    stop: &shutdown::Shutdown,
    rt: &tokio::runtime::Handle,
) -> Writing {
    let (frame_at, frame_thread) = match frames {
        None => (None, None),
        Some(Frames::AtInstant(f)) => (Some(f), None),
        Some(Frames::Stream(s)) => {
            let (ring, h) = stream_thread(
                s,
                ring_frames(config.camera.fps),
                (2e9 / config.camera.fps) as u64,
                stop.clone(),
            );
            (Some(Box::new(ring) as Box<dyn FrameAt>), Some(h))
        }
    };
    let space = Arc::new(Space::default());
    let (jobs, jobs_rx) = mpsc::channel::<WriteJob>(WRITE_QUEUE);
    let (written_tx, written) = mpsc::channel::<Written>(WRITTEN_QUEUE);
    let ctx = WriterCtx {
        store,
        format: config.capture.image_format,
        keep_camera_jpeg: config.capture.keep_camera_jpeg,
        frames: frame_at,
        space: space.clone(),
        make_model: (
            "alfd".to_string(),
            format!("{} {}", config.camera.width, config.camera.height),
        ),
    };
    let join = spawn_loop(
        "alfd-writer",
        rt,
        writer_loop(ctx, jobs_rx, tlog, written_tx),
    );
    Writing {
        join,
        jobs,
        written,
        space,
        frame_thread,
    }
}

/// The depth and estimator loops, and what the coordinator reads of them.
struct Estimation {
    counters: Arc<Counters>,
    decided: mpsc::Receiver<super::estimator_task::Decided>,
    views: watch::Receiver<Option<EstimatorView>>,
    depth_join: Running<()>,
    est_join: Running<EstimatorReport>,
}

/// Depth → estimator holds one frame (a frame arriving while the estimator is busy is
/// skipped and counted). Without a depth source, opportunities tick at `tick_hz`.
#[allow(clippy::too_many_arguments)]
fn spawn_estimation(
    config: &Config,
    image_intrinsics: Option<Intrinsics>,
    depth: Option<Box<dyn DepthSource>>,
    tick_hz: f64,
    link: &LinkHandle,
    rt: &tokio::runtime::Handle,
    last_seq: u64,
    stop: &shutdown::Shutdown,
    options: &mut RunOptions,
) -> Result<Estimation, RunError> {
    let counters = Arc::new(Counters::default());
    let depth: Box<dyn DepthSource> = match depth {
        Some(d) => d,
        None => Box::new(Ticks {
            period_ns: (1e9 / tick_hz.max(1.0)) as u64,
            next_ns: 0,
            seq: 0,
            intrinsics: Intrinsics::from_hfov_deg(1, 1, 69.0, None)
                .map_err(|e| RunError::Config(e.to_string()))?,
        }),
    };
    let intrinsics = depth.intrinsics();
    let (depth_tx, depth_rx) = mpsc::channel(1);
    let (decided_tx, decided) = mpsc::channel(DECIDED_QUEUE);
    let (view_tx, views) = watch::channel::<Option<EstimatorView>>(None);
    let depth_join = {
        let (fail, stop, counters) = (decided_tx.clone(), stop.clone(), counters.clone());
        spawn_loop(
            "alfd-depth",
            rt,
            depth_loop(depth, depth_tx, fail, stop, counters),
        )
    };
    let ctx = EstimatorCtx {
        link: link.clone(),
        intrinsics,
        image_intrinsics,
        config: config.clone(),
        last_seq,
        shutdown: stop.clone(),
        keep_samples: options.keep_samples,
        on_sample: options.on_sample.take(),
    };
    let est_join = spawn_loop(
        "alfd-estimator",
        rt,
        estimator_loop(ctx, depth_rx, view_tx, decided_tx),
    );
    Ok(Estimation {
        counters,
        decided,
        views,
        depth_join,
        est_join,
    })
}

/// The capture store (a directory on disk unless the caller handed one in) and the last
/// sequence number of its manifest, which numbering continues after.
fn open_store(options: &mut RunOptions) -> Result<(BoxedStore, u64), RunError> {
    let store: BoxedStore = match options.store.take() {
        Some(s) => s,
        None => Box::new(DirStore::open(&options.flight_dir).map_err(RunError::Store)?),
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
    Ok((store, last_seq))
}

/// The link's tapped frames into the tlog's queue, until the link stops.
async fn forward_tap(
    mut tap: mpsc::Receiver<TapFrame>,
    tlog: Arc<TlogQueue>,
    mut stop: shutdown::Shutdown,
) {
    loop {
        tokio::select! {
            biased;
            f = tap.recv() => match f {
                Some(f) => tlog.push(f),
                None => return,
            },
            _ = stop.reached(Stage::Done) => return,
        }
    }
}
