//! The depth loop (owns the depth source) and the estimator loop (runs the pure
//! [`Pipeline`] on each frame at its pose), each on its own thread in flight
//! ([`super::loops`]). Queues: depth → estimator holds one frame (a
//! frame arriving while the estimator is busy is skipped and counted); the estimator's view
//! for the coordinator is a latest-value `watch`; its capture decisions go on a bounded
//! queue the estimator waits on (a decided capture is never dropped).

use super::coordinator::EstimatorView;
use super::run::{FrameSample, SampleHook};
use super::shutdown::Shutdown;
use super::step::{FrameInput, Pipeline, StepOutcome, StepParams};
use crate::capture::{CaptureMode, CaptureRecord};
use crate::config::Config;
use crate::core::geo::LocalFrame;
use crate::core::{DepthData, DepthImage, Intrinsics};
use crate::link::unix_us_at;
use crate::link::{mono_ns, LinkHandle};
use crate::source::{DepthSource, SourceError, Stamped};
use crate::workers::ThreadWorkers;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// Capture decisions waiting for the coordinator: at the rate limit (≤ 30/s) this is two
/// seconds of captures; the estimator waits when it is full rather than drop one.
pub const DECIDED_QUEUE: usize = 64;

/// What the estimator hands the coordinator besides its latest view.
pub enum Decided {
    Capture(Box<CaptureRecord>),
    SourceFailed(String),
}

#[derive(Default)]
pub struct Counters {
    pub depth_frames: AtomicU64,
    pub source_gaps: AtomicU64,
    pub skipped_busy: AtomicU64,
    pub bad_frames: AtomicU64,
    pub unposed_frames: AtomicU64,
}

/// What the estimator loop kept, returned when it ends.
#[derive(Default)]
pub struct EstimatorReport {
    pub samples: Vec<FrameSample>,
    pub frames_suspended: u64,
    pub busy_ns: u64,
}

/// A clock of opportunities when no depth camera exists (fixed spacing).
pub struct Ticks {
    pub period_ns: u64,
    pub next_ns: u64,
    pub seq: u64,
    pub intrinsics: Intrinsics,
}

impl DepthSource for Ticks {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }
    fn due_ns(&self) -> Option<u64> {
        (self.next_ns != 0).then_some(self.next_ns)
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

pub async fn depth_loop(
    mut src: Box<dyn DepthSource>,
    tx: mpsc::Sender<Stamped<DepthImage>>,
    fail: mpsc::Sender<Decided>,
    shutdown: Shutdown,
    counters: Arc<Counters>,
) {
    let mut last_seq: Option<u64> = None;
    while !shutdown.is_stopping() {
        if let Some(t) = src.due_ns() {
            tokio::time::sleep_until(crate::link::clock::instant_at(t)).await;
        }
        let next = src.next_depth();
        crate::link::clock::settle().await;
        match next {
            Ok(Some(f)) => {
                counters.depth_frames.fetch_add(1, Ordering::Relaxed);
                // The source's own counter: a gap is a frame the camera (or the renderer
                // standing in for it) never delivered.
                if let Some(l) = last_seq {
                    let gap = f.seq.saturating_sub(l + 1);
                    counters.source_gaps.fetch_add(gap, Ordering::Relaxed);
                }
                last_seq = Some(f.seq);
                match tx.try_send(f) {
                    Ok(()) => {}
                    Err(mpsc::error::TrySendError::Full(_)) => {
                        counters.skipped_busy.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(mpsc::error::TrySendError::Closed(_)) => return,
                }
            }
            Ok(None) => return,
            Err(SourceError::Missed { .. }) => {}
            Err(SourceError::Unposed { .. }) => {
                counters.unposed_frames.fetch_add(1, Ordering::Relaxed);
            }
            Err(SourceError::BadFrame { .. }) => {
                counters.bad_frames.fetch_add(1, Ordering::Relaxed);
            }
            Err(SourceError::Lost(e)) => {
                counters.bad_frames.fetch_add(1, Ordering::Relaxed);
                tracing::warn!("depth source lost: {e}; retrying");
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(SourceError::Fatal(e)) => {
                let _ = fail.send(Decided::SourceFailed(e)).await;
                return;
            }
        }
    }
}

pub struct EstimatorCtx {
    pub link: LinkHandle,
    pub intrinsics: Intrinsics,
    /// The saved frames' (the colour camera's), when alfd saves them.
    pub image_intrinsics: Option<Intrinsics>,
    pub config: Config,
    pub last_seq: u64,
    pub shutdown: Shutdown,
    pub keep_samples: bool,
    pub on_sample: Option<SampleHook>,
}

pub async fn estimator_loop(
    mut ctx: EstimatorCtx,
    mut rx: mpsc::Receiver<Stamped<DepthImage>>,
    view: watch::Sender<Option<EstimatorView>>,
    decided: mpsc::Sender<Decided>,
) -> EstimatorReport {
    let mut report = EstimatorReport::default();
    let cfg = &ctx.config;
    let params = StepParams {
        camera_mount_pitch_rad: cfg.depth.mount_pitch_rad,
        frame_period_s: 1.0 / cfg.depth.fps,
        capture_mode: cfg.capture.mode,
        image_format: (cfg.capture.mode == CaptureMode::Frame).then_some(cfg.capture.image_format),
        image_intrinsics: ctx.image_intrinsics,
    };
    let mut pipeline: Option<Pipeline> = None;
    let state = ctx.link.state();
    // Without a depth frame for this long the camera has stalled: the trigger still gets
    // opportunities, at the fallback spacing, flagged; one per frame period while the stall
    // lasts, the step the trigger assumes.
    let stall = Duration::from_secs_f64((5.0 / cfg.depth.fps).max(0.15));
    let period = Duration::from_secs_f64(1.0 / cfg.depth.fps);
    let mut stalled = false;
    loop {
        let wait = if stalled { period } else { stall };
        let frame = match tokio::time::timeout(wait, rx.recv()).await {
            Ok(Some(f)) => {
                stalled = false;
                Some(f)
            }
            Err(_) => {
                stalled = true;
                None
            }
            Ok(None) => return report,
        };
        if ctx.shutdown.is_stopping() {
            return report;
        }
        // The frame's work on this machine's clock (a figure of load): on simulated time
        // the monotonic clock stands still while the estimator runs.
        let busy_from = std::time::Instant::now();
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
                if cfg.estimator_threads > 1 {
                    p.set_sweep_workers(Arc::new(ThreadWorkers::new(cfg.estimator_threads)));
                }
                pipeline = Some(p);
            }
        }
        // The autopilot's origin was set or moved (ArduPilot's EKF origin
        // after its first fixes): positions follow at once, no suspension.
        if let (Some(p), Some(home)) = (pipeline.as_mut(), state.borrow().as_ref().map(|s| s.home))
        {
            if home != p.local().home() {
                p.set_local(LocalFrame::new(home));
            }
        }
        let t = frame.as_ref().map_or(started, |f| f.mono_ns);
        let outcome = match pipeline.as_mut() {
            None => StepOutcome::Suspended {
                reason: "no position from the autopilot yet".into(),
            },
            Some(p) => {
                // The last capture's position, once later samples place it: the trigger
                // measures the interval from there, not from the pose extrapolated then.
                if let Some((seq, at_ns)) = p.unlocated_capture() {
                    match ctx.link.pose_at_mono_ns(at_ns).await {
                        Ok(l) if l.extrapolated_ns == 0 => p.capture_located(seq, l.pos_ned_m),
                        _ => {}
                    }
                }
                let pose = ctx.link.pose_at_mono_ns(t).await.map_err(|e| e.to_string());
                let boot_us = ctx.link.boot_ns_at_mono_ns(t).await.map(|ns| ns / 1000);
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
        let (estimate, record) = match outcome {
            StepOutcome::Suspended { reason } => {
                report.frames_suspended += 1;
                view.send_replace(Some(EstimatorView::Suspended { reason }));
                (None, None)
            }
            StepOutcome::Wait { estimate } => (Some(estimate), None),
            StepOutcome::Capture { estimate, record } => (Some(estimate), Some(record)),
        };
        let pos_ned_m = match &record {
            Some(r) => Some([r.position.north_m, r.position.east_m, -r.position.up_m]),
            None if estimate.is_some() => ctx
                .link
                .pose_at_mono_ns(t)
                .await
                .ok()
                .map(|p| p.pos_ned_m.to_array()),
            None => None,
        };
        let sample = FrameSample {
            mono_ns: t,
            pos_ned_m,
            spacing_m: estimate.as_ref().and_then(|e| e.spacing.chosen_m),
            occlusion_degree: estimate
                .as_ref()
                .and_then(|e| e.occlusion)
                .map(|o| o.degree),
            suspended: estimate.is_none(),
            captured: record.is_some(),
            busy_ns: busy_from.elapsed().as_nanos() as u64,
            swept_every_line: estimate
                .as_ref()
                .and_then(|e| e.visibility)
                .is_some_and(|v| v.interleave == 1),
        };
        report.busy_ns += sample.busy_ns;
        if let Some(cb) = ctx.on_sample.as_mut() {
            cb(&sample);
        }
        if ctx.keep_samples {
            report.samples.push(sample);
        }
        if let Some(e) = estimate {
            view.send_replace(Some(EstimatorView::Estimate {
                mono_ns: t,
                estimate: e,
            }));
        }
        if let Some(r) = record {
            if decided.send(Decided::Capture(r)).await.is_err() {
                return report;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source that answers from a script, then ends.
    struct Scripted(std::vec::IntoIter<Result<Option<Stamped<DepthImage>>, SourceError>>);

    impl DepthSource for Scripted {
        fn intrinsics(&self) -> Intrinsics {
            Intrinsics::from_hfov_deg(8, 6, 69.0, None).unwrap()
        }
        fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError> {
            self.0.next().unwrap_or(Ok(None))
        }
    }

    /// The bench's synthetic camera before the autopilot's first position used to
    /// count its frames as bad: 451 in 15 s of `alfd run` with no autopilot.
    #[tokio::test]
    async fn frames_without_a_pose_are_not_counted_bad() {
        let script = vec![
            Err(SourceError::Unposed { seq: 1 }),
            Err(SourceError::Unposed { seq: 2 }),
            Err(SourceError::BadFrame {
                seq: 3,
                reason: "truncated".into(),
            }),
        ];
        let (tx, _rx) = mpsc::channel(1);
        let (fail, _fail_rx) = mpsc::channel(1);
        let (_trigger, shutdown) = super::super::shutdown::channel();
        let counters = Arc::new(Counters::default());
        depth_loop(
            Box::new(Scripted(script.into_iter())),
            tx,
            fail,
            shutdown,
            counters.clone(),
        )
        .await;
        assert_eq!(counters.unposed_frames.load(Ordering::Relaxed), 2);
        assert_eq!(counters.bad_frames.load(Ordering::Relaxed), 1);
        assert_eq!(counters.depth_frames.load(Ordering::Relaxed), 0);
    }
}
