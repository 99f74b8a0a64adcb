//! The truth track: noise-free depth rendered at each true pose, through one
//! estimator in pose order (as the daemon runs it). Rendering is parallel;
//! estimating too when the decimation is fixed (no state between frames),
//! else sequential. In one batch after a flight ([`truth_estimates`]), or
//! streamed beside it ([`TruthStream`]) with the same samples.

use super::{TrackSample, TruthPose};
use crate::core::attitude::{body_to_ned, flight_axis};
use crate::core::{
    Decimation, DepthData, DepthImage, Estimator, EstimatorParams, Intrinsics, TrackAxis,
};
use crate::render::{render_depth, Camera};
use crate::scene::Scene;
use crate::source::synthetic::idle_this_thread;
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Poses rendered at once: keeps the depth maps in memory bounded.
const CHUNK: usize = 64;

/// The estimate at each pose from the scene's true depth (metres, `+inf` sky)
/// at `intrinsics` (which override the poses' own).
pub fn truth_estimates(
    scene: &Scene,
    intrinsics: Intrinsics,
    params: &EstimatorParams,
    poses: &[TruthPose],
) -> Vec<TrackSample> {
    let params = &per_frame(params);
    let mut out = Vec::with_capacity(poses.len());
    let mut estimator = Estimator::new(params.clone());
    let mut rendered = (0..poses.len()).map(|_| None).collect::<Vec<_>>();
    estimate_range(
        scene,
        intrinsics,
        params,
        (poses, &mut rendered),
        0..poses.len(),
        &mut estimator,
        &mut out,
    );
    out
}

/// The daemon's estimator with the visibility sweep over every sample of its
/// grid, every line on every frame: the truth judges the sweep's two CPU knobs
/// (`visibility_samples_max`'s thinning and `visibility_interleave`'s spreading
/// over frames) and shares neither. (So each fixed-decimation frame owes
/// nothing to the frames before, and they can be estimated in parallel.)
fn per_frame(params: &EstimatorParams) -> EstimatorParams {
    EstimatorParams {
        visibility_interleave: 1,
        visibility_samples_max: usize::MAX,
        ..params.clone()
    }
}

/// Appends the samples of `poses[range]` to `out`, each pose's flight axis from
/// its neighbours in `poses` (clamped at the ends: the caller leaves the last
/// pose out until its successor is known, or the track has ended). A pose's
/// depth is taken from `rendered` where the flight left it (the same render
/// at the same camera), else rendered here. A fixed decimation keeps no state
/// from frame to frame, so its poses are estimated in parallel, one estimator
/// per worker, with the same results; otherwise in pose order through
/// `sequential`, the depth rendered in parallel `CHUNK`s.
fn estimate_range(
    scene: &Scene,
    intrinsics: Intrinsics,
    params: &EstimatorParams,
    (poses, rendered): (&[TruthPose], &mut [Option<Vec<f32>>]),
    range: std::ops::Range<usize>,
    sequential: &mut Estimator,
    out: &mut Vec<TrackSample>,
) {
    let depth_at = |p: &TruthPose, slot: &mut Option<Vec<f32>>| {
        slot.take()
            .unwrap_or_else(|| render_depth(scene, &camera(p, intrinsics)))
    };
    if matches!(params.decimation, Decimation::Fixed(_)) {
        let samples: Vec<TrackSample> = rendered[range.clone()]
            .par_iter_mut()
            .zip(range.into_par_iter())
            .map_init(
                || Estimator::new(params.clone()),
                |estimator, (slot, k)| {
                    let p = &poses[k];
                    let depth = depth_at(p, slot);
                    let (axis, pitch_rad) = axis_pitch(poses, k, params.track_axis);
                    estimator.set_track_axis(axis);
                    sample(estimator, p, intrinsics, depth, pitch_rad)
                },
            )
            .collect();
        out.extend(samples);
        return;
    }
    for start in range.clone().step_by(CHUNK) {
        let chunk = start..(start + CHUNK).min(range.end);
        let depths: Vec<Vec<f32>> = poses[chunk.clone()]
            .par_iter()
            .zip(rendered[chunk.clone()].par_iter_mut())
            .map(|(p, slot)| depth_at(p, slot))
            .collect();
        for (k, depth) in chunk.zip(depths) {
            let (axis, pitch_rad) = axis_pitch(poses, k, params.track_axis);
            sequential.set_track_axis(axis);
            out.push(sample(sequential, &poses[k], intrinsics, depth, pitch_rad));
        }
    }
}

/// The scan axis and tilt at pose `k`, from the true attitude and the
/// direction of flight between the neighbouring poses (as the daemon's).
fn axis_pitch(poses: &[TruthPose], k: usize, track_axis: TrackAxis) -> (TrackAxis, f64) {
    let p = &poses[k];
    let (a, b) = (
        &poses[k.saturating_sub(1)],
        &poses[(k + 1).min(poses.len() - 1)],
    );
    let dt_s = b.mono_ns.saturating_sub(a.mono_ns) as f64 * 1e-9;
    let vel = if dt_s > 0.0 {
        DVec3::new(
            (b.north_m - a.north_m) / dt_s,
            (b.east_m - a.east_m) / dt_s,
            0.0,
        )
    } else {
        DVec3::ZERO
    };
    flight_axis(&cam_to_ned(&p.camera), vel, track_axis)
}

/// The truth track estimated while the flight runs, on a thread of its own:
/// the flight on simulated time keeps one core busy (its runtime is a single
/// thread), and this takes only what the cores have to spare (`SCHED_IDLE`). Poses go in as the
/// daemon's frames come; [`TruthStream::finish`] estimates what is left on
/// the caller's thread and every core and returns the same samples as
/// [`truth_estimates`] over the same poses. What is left is taken back from the
/// worker, not waited for: once the flight is over the process waits on it, and
/// at `SCHED_IDLE` any other load on the machine (an `alfd eval` beside the
/// flight) starved it, 57 s between an interrupt and the summary where an idle
/// machine takes 2.
///
/// The queue holds poses (a few dozen bytes each, the depth is rendered on the
/// worker) and is bounded at `STREAM_QUEUE`: when full, [`TruthStream::push`]
/// waits for the worker, which on simulated time freezes the clock with it, so
/// the flight is the same either way.
pub struct TruthStream {
    tx: Option<std::sync::mpsc::SyncSender<(TruthPose, Option<Vec<f32>>)>>,
    /// Depth maps given with poses and not yet taken by the worker.
    given: Arc<AtomicUsize>,
    /// Set by [`TruthStream::finish`]: the worker hands back what it has not
    /// estimated instead of going on.
    over: Arc<Over>,
    worker: Option<std::thread::JoinHandle<WorkerState>>,
    scene: Arc<Scene>,
    intrinsics: Intrinsics,
    params: EstimatorParams,
}

/// The flight is over (`true`), and a condition a held worker waits on.
type Over = (std::sync::Mutex<bool>, std::sync::Condvar);

/// What the worker hands back: the poses and depth maps it was given, its
/// samples so far, and the estimator whose state the rest continues.
type WorkerState = (
    Vec<TruthPose>,
    Vec<Option<Vec<f32>>>,
    Vec<TrackSample>,
    Estimator,
);

/// Poses the worker estimates between two looks at whether the flight is over.
const WORKER_BATCH: usize = 8;

/// Depth maps ([`TruthStream::push`]) queued at most (about 1.2 MB each at
/// 640 × 480); beyond, poses go without theirs and the worker renders them.
const GIVEN_MAX: usize = 32;

/// The poses a [`TruthStream`] was given and its samples at them.
type TruthStreamResult = (Vec<TruthPose>, Vec<TrackSample>);

/// Poses queued for the truth worker before [`TruthStream::push`] waits.
const STREAM_QUEUE: usize = 4096;

impl TruthStream {
    /// Starts the worker (thread `alfd-truth`, `SCHED_IDLE`, one rayon
    /// thread of its own while the flight runs). `None` when no thread could be
    /// started: the caller estimates after the flight instead.
    pub fn spawn(
        scene: Arc<Scene>,
        intrinsics: Intrinsics,
        params: EstimatorParams,
    ) -> Option<TruthStream> {
        Self::spawn_held(scene, intrinsics, params, false)
    }

    /// [`TruthStream::spawn`]; `held`: the worker estimates nothing before
    /// [`TruthStream::finish`] (a starved worker, for the tests).
    fn spawn_held(
        scene: Arc<Scene>,
        intrinsics: Intrinsics,
        params: EstimatorParams,
        held: bool,
    ) -> Option<TruthStream> {
        let params = per_frame(&params);
        let over: Arc<Over> = Arc::default();
        let (over_w, scene_w, params_w) = (over.clone(), scene.clone(), params.clone());
        let (tx, rx) = std::sync::mpsc::sync_channel::<(TruthPose, Option<Vec<f32>>)>(STREAM_QUEUE);
        let given = Arc::new(AtomicUsize::new(0));
        let taken = given.clone();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .thread_name(|_| "alfd-truth-render".into())
            .start_handler(|_| idle_this_thread())
            .build()
            .ok()?;
        let worker = std::thread::Builder::new()
            .name("alfd-truth".into())
            .spawn(move || {
                idle_this_thread();
                let (scene, params, over) = (scene_w, params_w, over_w);
                let is_over = || *over.0.lock().unwrap_or_else(|e| e.into_inner());
                if held {
                    let mut done = over.0.lock().unwrap_or_else(|e| e.into_inner());
                    while !*done {
                        done = over.1.wait(done).unwrap_or_else(|e| e.into_inner());
                    }
                }
                let mut poses: Vec<TruthPose> = Vec::new();
                let mut rendered: Vec<Option<Vec<f32>>> = Vec::new();
                let mut out: Vec<TrackSample> = Vec::new();
                let mut estimator = Estimator::new(params.clone());
                let take = |(p, depth): (TruthPose, Option<Vec<f32>>),
                            poses: &mut Vec<TruthPose>,
                            rendered: &mut Vec<Option<Vec<f32>>>| {
                    if depth.is_some() {
                        taken.fetch_sub(1, Ordering::AcqRel);
                    }
                    poses.push(p);
                    rendered.push(depth);
                };
                // While the flight runs: each pose once its successor is known
                // (its flight axis needs both neighbours), on the worker's own
                // thread so the flight's renders keep rayon's pool, a few at a
                // time so that the end of the flight is seen soon.
                while let Ok(first) = rx.recv() {
                    for item in std::iter::once(first).chain(rx.try_iter()) {
                        take(item, &mut poses, &mut rendered);
                    }
                    let ready = poses.len() - 1;
                    while out.len() < ready && !is_over() {
                        let end = (out.len() + WORKER_BATCH).min(ready);
                        pool.install(|| {
                            let range = out.len()..end;
                            let track = (&poses[..], &mut rendered[..]);
                            estimate_range(
                                &scene,
                                intrinsics,
                                &params,
                                track,
                                range,
                                &mut estimator,
                                &mut out,
                            )
                        });
                    }
                    if is_over() {
                        break;
                    }
                }
                // The flight is over: the rest is the caller's. Its sender is
                // gone, so this ends with what was queued.
                for item in rx.iter() {
                    take(item, &mut poses, &mut rendered);
                }
                (poses, rendered, out, estimator)
            })
            .ok()?;
        Some(TruthStream {
            tx: Some(tx),
            given,
            over,
            worker: Some(worker),
            scene,
            intrinsics,
            params,
        })
    }

    /// Queues the next pose (in pose order), with its exact depth if the
    /// caller has it (rendered at the pose's camera and intrinsics: the
    /// flight's own frame), which the worker then need not render; waits
    /// while the queue is full. A worker that has stopped (it panicked) takes
    /// nothing more, and [`TruthStream::finish`] says so.
    pub fn push(&self, pose: TruthPose, depth_m: Option<Vec<f32>>) {
        let Some(tx) = &self.tx else { return };
        // Past `GIVEN_MAX` the depth is dropped: the worker renders it.
        let depth_m = depth_m.filter(|_| {
            self.given
                .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                    (n < GIVEN_MAX).then_some(n + 1)
                })
                .is_ok()
        });
        // An error means the worker is gone: `finish` reports it.
        tx.send((pose, depth_m)).ok();
    }

    /// Estimates what is left, on this thread and rayon's pool, and returns
    /// the poses given and their samples; `None` if the worker panicked.
    pub fn finish(self) -> Option<TruthStreamResult> {
        self.finish_counted().map(|(result, _)| result)
    }

    /// [`TruthStream::finish`], and how many poses were left to it.
    fn finish_counted(mut self) -> Option<(TruthStreamResult, usize)> {
        *self.over.0.lock().unwrap_or_else(|e| e.into_inner()) = true;
        self.over.1.notify_all();
        drop(self.tx.take());
        let (poses, mut rendered, mut out, mut estimator) = self.worker.take()?.join().ok()?;
        let left = poses.len() - out.len();
        if left > CHUNK {
            tracing::info!("judging the flight's last {left} frames against the truth");
        }
        let range = out.len()..poses.len();
        estimate_range(
            &self.scene,
            self.intrinsics,
            &self.params,
            (&poses, &mut rendered),
            range,
            &mut estimator,
            &mut out,
        );
        Some(((poses, out), left))
    }
}

/// The camera's rotation, OpenCV axes → NED: the renderer's ZYX angles, the
/// exports' composition.
fn cam_to_ned(c: &Camera) -> DMat3 {
    body_to_ned(c.roll_rad, c.pitch_rad, c.yaw_rad)
}

fn camera(p: &TruthPose, intrinsics: Intrinsics) -> Camera {
    Camera {
        intrinsics,
        ..p.camera
    }
}

fn sample(
    estimator: &mut Estimator,
    p: &TruthPose,
    intrinsics: Intrinsics,
    depth_m: Vec<f32>,
    pitch_rad: f64,
) -> TrackSample {
    // The image is built from the intrinsics' own size, so neither step can
    // fail; if one did, the sample says "no estimate" rather than panicking.
    let estimate = DepthImage::new(
        intrinsics.width(),
        intrinsics.height(),
        DepthData::Metres(depth_m),
    )
    .ok()
    .and_then(|img| estimator.estimate(&img, &intrinsics, pitch_rad).ok())
    .map(|(e, _)| e);
    TrackSample {
        mono_ns: p.mono_ns,
        along_m: p.along_m,
        north_m: p.north_m,
        east_m: p.east_m,
        spacing_m: estimate.as_ref().and_then(|e| e.spacing.chosen_m),
        active_bound: estimate
            .as_ref()
            .and_then(|e| e.active_bound.map(|b| b.as_str().to_string())),
        occlusion_degree: estimate
            .as_ref()
            .and_then(|e| e.occlusion.map(|o| o.degree)),
        mmds_m: estimate.as_ref().and_then(|e| e.spacing.mmds_m),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Frame;

    const SCENE: &str = r#"
name = "tiny"
[survey]
altitude_m = 40.0
speed_mps = 5.0
hfov_deg = 69.0
width = 64
height = 48
start_x_m = -10.0
end_x_m = 10.0
view_step_m = 0.5
[ground]
texture = { colour = [0.4, 0.5, 0.3], contrast = 0.4, seed = 1 }
[[box]]
min_m = [-6.0, -5.0, 0.0]
max_m = [6.0, 5.0, 18.0]
texture = { colour = [0.7, 0.6, 0.6], contrast = 0.3, seed = 2 }
"#;

    fn poses(intr: Intrinsics) -> Vec<TruthPose> {
        (0..5)
            .map(|k| {
                let x = -10.0 + 5.0 * k as f64;
                TruthPose {
                    mono_ns: k * 200_000_000,
                    along_m: x + 10.0,
                    camera: Camera {
                        position_m: [x, 0.0, 40.0],
                        roll_rad: 0.0,
                        pitch_rad: 0.1,
                        yaw_rad: 0.0,
                        intrinsics: intr,
                    },
                    north_m: x + 10.0,
                    east_m: 0.0,
                }
            })
            .collect()
    }

    #[test]
    fn truth_estimates_equal_a_direct_estimate_at_each_pose() {
        let scene = Scene::parse(SCENE, "inline").expect("the inline scene parses");
        let intr = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
        // The occlusion model, so the degree passes through too.
        let params = EstimatorParams::with_model(crate::core::Model::Occlusion);
        let poses = poses(intr);
        let track = truth_estimates(&scene, intr, &params, &poses);
        assert_eq!(track.len(), poses.len());
        for (s, p) in track.iter().zip(&poses) {
            assert_eq!(
                (s.mono_ns, s.along_m, s.north_m),
                (p.mono_ns, p.along_m, p.north_m)
            );
            let spacing = s.spacing_m.expect("a textured scene gives an estimate");
            assert!(spacing.is_finite() && spacing > 0.0, "{spacing}");
            // The same pose through a fresh estimator, straight from the renderer.
            let frame = Frame {
                width: 64,
                height: 48,
                rgb: Vec::new(),
                depth_m: render_depth(&scene, &p.camera),
            };
            let (e, _) = Estimator::new(params.clone())
                .estimate(&frame.depth_image(), &intr, p.camera.pitch_rad)
                .unwrap();
            assert_eq!(s.spacing_m, e.spacing.chosen_m);
            assert_eq!(s.mmds_m, e.spacing.mmds_m);
            assert_eq!(s.occlusion_degree, e.occlusion.map(|o| o.degree));
            assert_eq!(
                s.active_bound.as_deref(),
                e.active_bound.map(|b| b.as_str())
            );
        }
        // Over the building's edge the occlusion term is in play.
        assert!(track.iter().any(|s| s.occlusion_degree.is_some()));
    }

    /// The inline scene, its intrinsics and poses along its line.
    fn inline_track() -> (Arc<Scene>, Intrinsics, Vec<TruthPose>) {
        let scene = Arc::new(Scene::parse(SCENE, "inline").expect("the inline scene parses"));
        let intr = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
        (scene, intr, poses(intr))
    }

    /// Fixed decimation (parallel estimates) and auto (one estimator in pose
    /// order, whose state carries from frame to frame).
    fn both_decimations() -> [EstimatorParams; 2] {
        [
            EstimatorParams::default(),
            EstimatorParams {
                decimation: Decimation::auto(),
                ..EstimatorParams::default()
            },
        ]
    }

    #[test]
    fn the_stream_gives_the_batch_samples() {
        let (scene, intr, poses) = inline_track();
        for params in both_decimations() {
            let batch = truth_estimates(&scene, intr, &params, &poses);
            assert_eq!(batch.len(), poses.len());
            let stream = TruthStream::spawn(scene.clone(), intr, params.clone())
                .expect("a thread for the stream");
            // Every other pose with its depth as the flight rendered it.
            for (k, p) in poses.iter().enumerate() {
                let depth = (k % 2 == 0).then(|| render_depth(&scene, &camera(p, intr)));
                stream.push(*p, depth);
            }
            let (given, streamed) = stream.finish().expect("the worker finishes");
            assert_eq!(given, poses);
            assert_eq!(streamed, batch, "{:?}", params.decimation);
            // A depth given is the one estimated: open ground 1 km below
            // instead of the building gives another sample.
            let stream = TruthStream::spawn(scene.clone(), intr, params.clone()).unwrap();
            for (k, p) in poses.iter().enumerate() {
                stream.push(*p, (k == 2).then(|| vec![1000.0; 64 * 48]));
            }
            let (_, other) = stream.finish().unwrap();
            assert_ne!(other[2], batch[2]);
            assert_eq!(other[..2], batch[..2]);
        }
        // A stream given nothing gives nothing.
        let stream = TruthStream::spawn(scene, intr, EstimatorParams::default()).unwrap();
        assert_eq!(stream.finish(), Some((Vec::new(), Vec::new())));
    }

    /// A worker starved until the flight ends (`SCHED_IDLE` beside another
    /// load) leaves every pose to `finish`, which estimates them on the
    /// caller's thread: the batch's samples, in order, estimator state included.
    #[test]
    fn a_starved_worker_hands_its_poses_back_to_finish() {
        let (scene, intr, poses) = inline_track();
        for params in both_decimations() {
            let batch = truth_estimates(&scene, intr, &params, &poses);
            let stream = TruthStream::spawn_held(scene.clone(), intr, params.clone(), true)
                .expect("a thread for the stream");
            for (k, p) in poses.iter().enumerate() {
                stream.push(
                    *p,
                    (k % 3 == 0).then(|| render_depth(&scene, &camera(p, intr))),
                );
            }
            let ((given, streamed), left) = stream.finish_counted().expect("the worker finishes");
            assert_eq!(left, poses.len());
            assert_eq!(given, poses);
            assert_eq!(streamed, batch, "{:?}", params.decimation);
        }
    }

    #[test]
    fn no_poses_give_no_samples() {
        let scene = Scene::parse(SCENE, "inline").unwrap();
        let intr = Intrinsics::from_hfov_deg(64, 48, 69.0, None).unwrap();
        assert!(truth_estimates(&scene, intr, &EstimatorParams::default(), &[]).is_empty());
    }
}
