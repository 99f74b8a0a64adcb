//! The synthetic depth camera: the scene renderer at the pose given for each
//! frame's instant (the simulator's truth, or the latest telemetry pose, so it
//! works against any autopilot), with a RealSense-like sensor model. The clock
//! is injected, so tests and replays run without waiting.

pub use super::{Clock, MonotonicClock};
use super::{ColorImage, DepthSource, FrameAt, RawColor, SourceError, Stamped};
use crate::core::attitude::{body_to_ned, camera_to_body};
use crate::core::{DepthImage, Intrinsics};
use crate::render::{render, render_depth, Camera, Frame, RenderOptions, SensorModel};
use crate::scene::Scene;
use glam::DMat3;
use std::sync::Arc;

/// Where the camera is at an instant (metres, world frame of the scene) and
/// how it is turned: the camera's own roll, pitch and yaw as [`Camera`] takes
/// them (all 0 = nadir, image columns towards `+x`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    pub position_m: [f64; 3],
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
}

impl CameraPose {
    /// The camera on a vehicle at `position_m` with the autopilot's roll, pitch,
    /// yaw (`rpy_rad`, ZYX) and the camera tilted forward by `mount_pitch_rad`
    /// about the vehicle's right axis: the composition the exports write
    /// (`capture::export::camera_gl_to_ned`), so a picture matches its logged pose.
    pub fn on_vehicle(position_m: [f64; 3], rpy_rad: [f64; 3], mount_pitch_rad: f64) -> Self {
        let [roll, pitch, yaw] = rpy_rad;
        if roll == 0.0 {
            // Rz(ψ)·Ry(θ)·Ry(m) = Rz(ψ)·Ry(θ + m): exact, and the pitch-only
            // poses keep the bits they had before roll and yaw were rendered.
            return CameraPose {
                position_m,
                roll_rad: 0.0,
                pitch_rad: pitch + mount_pitch_rad,
                yaw_rad: yaw,
            };
        }
        let m = body_to_ned(roll, pitch, yaw) * camera_to_body(mount_pitch_rad);
        let [roll_rad, pitch_rad, yaw_rad] = zyx_rad(m);
        CameraPose {
            position_m,
            roll_rad,
            pitch_rad,
            yaw_rad,
        }
    }

    /// The renderer's camera at this pose.
    pub fn camera(&self, intrinsics: Intrinsics) -> Camera {
        Camera {
            position_m: self.position_m,
            roll_rad: self.roll_rad,
            pitch_rad: self.pitch_rad,
            yaw_rad: self.yaw_rad,
            intrinsics,
        }
    }
}

/// `[roll, pitch, yaw]` with `m = Rz(yaw)·Ry(pitch)·Rx(roll)`. Looking straight
/// along ±x (pitch ±90°) only the difference of yaw and roll is defined: roll
/// is then 0 and yaw takes the whole turn.
fn zyx_rad(m: DMat3) -> [f64; 3] {
    let pitch = (-m.x_axis.z).clamp(-1.0, 1.0).asin();
    // cos(pitch) below this leaves roll and yaw to rounding.
    if m.x_axis.x.hypot(m.x_axis.y) < 1e-9 {
        return [0.0, pitch, (-m.y_axis.x).atan2(m.y_axis.y)];
    }
    [
        m.y_axis.z.atan2(m.z_axis.z),
        pitch,
        m.x_axis.y.atan2(m.x_axis.x),
    ]
}

/// The pose at a monotonic instant; `None` when unknown (stale telemetry).
pub trait PoseAt: Send {
    fn pose_at(&mut self, mono_ns: u64) -> Option<CameraPose>;
}

impl<F: FnMut(u64) -> Option<CameraPose> + Send> PoseAt for F {
    fn pose_at(&mut self, mono_ns: u64) -> Option<CameraPose> {
        self(mono_ns)
    }
}

/// Depth frames rendered at `fps` from the first instant the clock gives.
pub struct SyntheticDepth<P, C> {
    scene: Arc<Scene>,
    intrinsics: Intrinsics,
    sensor: SensorModel,
    period_ns: u64,
    next_ns: Option<u64>,
    seq: u64,
    pose: P,
    clock: C,
    tap: Option<DepthTap>,
}

/// The exact depth (metres, before the sensor) of the last frame a
/// [`SyntheticDepth`] rendered, its instant and its camera: `alfd sim`'s
/// truth track, which renders the same frame at the same true pose, takes it
/// instead of rendering it again.
#[derive(Clone, Default)]
pub struct DepthTap(Arc<std::sync::Mutex<Option<TappedDepth>>>);

/// A frame in a [`DepthTap`].
struct TappedDepth {
    mono_ns: u64,
    camera: Camera,
    depth_m: Vec<f32>,
}

impl DepthTap {
    /// The last frame, if it is the one of `mono_ns` seen by `camera` (bit
    /// for bit: then its depth is the render's at that camera).
    pub fn take_if(&self, mono_ns: u64, camera: &Camera) -> Option<Vec<f32>> {
        let mut slot = self.0.lock().unwrap_or_else(|p| p.into_inner());
        match slot.take() {
            Some(t) if t.mono_ns == mono_ns && t.camera == *camera => Some(t.depth_m),
            other => {
                *slot = other;
                None
            }
        }
    }

    fn put(&self, frame: TappedDepth) {
        *self.0.lock().unwrap_or_else(|p| p.into_inner()) = Some(frame);
    }
}

impl<P: PoseAt, C: Clock> SyntheticDepth<P, C> {
    pub fn new(
        scene: Arc<Scene>,
        intrinsics: Intrinsics,
        sensor: SensorModel,
        fps: f64,
        pose: P,
        clock: C,
    ) -> Self {
        SyntheticDepth {
            scene,
            intrinsics,
            sensor,
            period_ns: (1e9 / fps.max(1e-3)).round() as u64,
            next_ns: None,
            seq: 0,
            pose,
            clock,
            tap: None,
        }
    }

    /// Leaves each frame's exact depth in `tap`.
    pub fn with_tap(mut self, tap: DepthTap) -> Self {
        self.tap = Some(tap);
        self
    }
}

impl<P: PoseAt, C: Clock> DepthSource for SyntheticDepth<P, C> {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn due_ns(&self) -> Option<u64> {
        self.next_ns
    }

    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError> {
        let t = *self.next_ns.get_or_insert_with(|| self.clock.now_ns());
        self.clock.wait_until(t);
        // A slow render skips the frames it missed rather than falling behind.
        let now = self.clock.now_ns();
        let behind = now.saturating_sub(t) / self.period_ns;
        self.next_ns = Some(t + (behind + 1) * self.period_ns);
        // This frame is the one due at `t`; the missed ones leave a gap in seq.
        self.seq += 1;
        let seq = self.seq;
        self.seq += behind;
        let Some(pose) = self.pose.pose_at(t) else {
            return Err(SourceError::Unposed { seq });
        };
        let camera = pose.camera(self.intrinsics);
        let frame = Frame {
            width: self.intrinsics.width(),
            height: self.intrinsics.height(),
            rgb: Vec::new(),
            depth_m: render_depth(&self.scene, &camera),
        };
        // Each frame its own noise and dropout, reproducibly.
        let sensor = SensorModel {
            seed: self.sensor.seed ^ seq.wrapping_mul(0x9E37_79B9_7F4A_7C15),
            ..self.sensor
        };
        let data = frame.z16(&sensor);
        if let Some(tap) = &self.tap {
            tap.put(TappedDepth {
                mono_ns: t,
                camera,
                depth_m: frame.depth_m,
            });
        }
        Ok(Some(Stamped {
            mono_ns: t,
            seq,
            data,
        }))
    }
}

/// The synthetic colour camera: renders the scene at the pose of the instant
/// asked for (a capture's), so only captured frames cost a render.
pub struct SyntheticColor<P> {
    scene: Arc<Scene>,
    intrinsics: Intrinsics,
    options: RenderOptions,
    pose: P,
    seq: u64,
    /// Frames rendered ahead by a [`ColourAhead`], collected here.
    ahead: Option<Ahead>,
    /// Its own single thread: a colour render (several depth frames' worth)
    /// must not take the cores the depth camera's frames are rendered on,
    /// or the depth camera would miss frames a real one delivers.
    pool: Option<rayon::ThreadPool>,
}

impl<P: PoseAt> SyntheticColor<P> {
    pub fn new(scene: Arc<Scene>, intrinsics: Intrinsics, supersample: usize, pose: P) -> Self {
        SyntheticColor {
            scene,
            intrinsics,
            options: RenderOptions {
                supersample: supersample.max(1),
            },
            pose,
            seq: 0,
            ahead: None,
            pool: rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .thread_name(|_| "alfd-synth-color".into())
                .start_handler(|_| lower_this_threads_priority())
                .build()
                .ok(),
        }
    }
}

impl<P> SyntheticColor<P> {
    /// Renders on the caller's thread and rayon's shared pool: where no depth stream
    /// renders meanwhile (a flight on simulated time).
    pub fn on_all_cores(mut self) -> Self {
        self.pool = None;
        self
    }

    /// Collects the frames `ahead` holds before rendering one itself.
    pub fn with_ahead(mut self, ahead: Ahead) -> Self {
        self.ahead = Some(ahead);
        self
    }
}

/// Colour frames rendered before the writer asks for them: what a streaming
/// camera's ring already holds when a capture's image is made. Filled by a
/// [`ColourAhead`] when a capture is decided, emptied by [`SyntheticColor`]
/// when the writer asks for that instant. On simulated time the render then
/// overlaps the flight's next frames instead of holding the runtime's thread;
/// the frame is the same (the renderer is deterministic), and the writer's
/// simulated time is unchanged (a render takes none).
#[derive(Clone, Default)]
pub struct Ahead(Arc<std::sync::Mutex<AheadQueue>>);

type AheadQueue = std::collections::VecDeque<(u64, std::sync::mpsc::Receiver<ColorImage>)>;

/// Renders ahead at most; beyond it a frame is rendered when asked (a writer
/// far behind its captures gains nothing from more in flight).
pub const AHEAD_MAX: usize = 8;

impl Ahead {
    fn queue(&self) -> std::sync::MutexGuard<'_, AheadQueue> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The frame of `mono_ns` if it was rendered ahead (waiting for it to
    /// finish). Earlier instants are dropped: the writer asks in order, so
    /// they were captures whose image it did not make.
    fn take(&self, mono_ns: u64) -> Option<ColorImage> {
        let rx = {
            let mut q = self.queue();
            while q.front().is_some_and(|(t, _)| *t < mono_ns) {
                q.pop_front();
            }
            match q.front() {
                Some((t, _)) if *t == mono_ns => q.pop_front().map(|(_, rx)| rx),
                _ => None,
            }
        };
        // A render that panicked sent nothing: the caller renders it again.
        rx?.recv().ok()
    }
}

/// Starts the colour renders of captures as they are decided, on threads of
/// its own (the depth frames keep rayon's shared pool), into an [`Ahead`].
pub struct ColourAhead<P> {
    scene: Arc<Scene>,
    intrinsics: Intrinsics,
    options: RenderOptions,
    pose: P,
    ahead: Ahead,
    pool: Option<rayon::ThreadPool>,
}

impl<P: PoseAt> ColourAhead<P> {
    /// Renders as [`SyntheticColor::new`] with the same arguments would.
    pub fn new(
        scene: Arc<Scene>,
        intrinsics: Intrinsics,
        supersample: usize,
        pose: P,
        ahead: Ahead,
    ) -> Self {
        ColourAhead {
            scene,
            intrinsics,
            options: RenderOptions {
                supersample: supersample.max(1),
            },
            pose,
            ahead,
            // As many threads as cores: when the writer waits for a frame
            // nothing else runs on the flight's side, so it gets them all.
            pool: rayon::ThreadPoolBuilder::new()
                .num_threads(std::thread::available_parallelism().map_or(1, |n| n.get()))
                .thread_name(|_| "alfd-color-ahead".into())
                .build()
                .ok(),
        }
    }

    /// Starts rendering the frame of `mono_ns` (nothing when [`AHEAD_MAX`]
    /// are in flight, no pose is known or no thread could be had: the frame
    /// is then rendered when asked).
    pub fn prepare(&mut self, mono_ns: u64) {
        let Some(pool) = &self.pool else { return };
        if self.ahead.queue().len() >= AHEAD_MAX {
            return;
        }
        let Some(pose) = self.pose.pose_at(mono_ns) else {
            return;
        };
        let camera = pose.camera(self.intrinsics);
        let (scene, options) = (self.scene.clone(), self.options);
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        pool.spawn(move || {
            let frame = render(&scene, &camera, &options);
            // The writer may have stopped waiting (the run ended): nothing to do.
            let _ = tx.send(colour_image(&frame));
        });
        self.ahead.queue().push_back((mono_ns, rx));
    }
}

fn colour_image(frame: &Frame) -> ColorImage {
    ColorImage {
        width: frame.width,
        height: frame.height,
        rgb: frame.rgb8(),
    }
}

/// Nice 19 for the calling thread (Linux keeps a nice value per thread): the
/// colour renders queue behind the depth stream instead of delaying it.
pub(crate) fn lower_this_threads_priority() {
    // `None` is who = 0: the calling thread. Failure only leaves the priority as is.
    let _ = rustix::process::setpriority_process(None, 19);
}

/// `SCHED_IDLE` for the calling thread: it runs only on a core nothing else
/// wants, where nice 19 still takes a share of a busy one. (Measured in
/// `alfd sim`: the flight's estimate took 10.4 ms a frame beside the truth
/// worker at either setting, 8.8 ms with no worker; what is left is the
/// shared cache and memory, not the scheduler.) Falls back to nice 19 where
/// the policy cannot be set.
pub(crate) fn idle_this_thread() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pid 0 is the calling thread; `param` is a valid, initialised
    // sched_param that outlives the call, and SCHED_IDLE takes priority 0.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) };
    if rc != 0 {
        lower_this_threads_priority();
    }
}

impl<P: PoseAt> FrameAt for SyntheticColor<P> {
    fn raw_at(&mut self, mono_ns: u64) -> Option<Stamped<RawColor>> {
        let image = match self.ahead.as_ref().and_then(|a| a.take(mono_ns)) {
            Some(image) => image,
            None => {
                let pose = self.pose.pose_at(mono_ns)?;
                let camera = pose.camera(self.intrinsics);
                colour_image(&match &self.pool {
                    Some(pool) => pool.install(|| render(&self.scene, &camera, &self.options)),
                    None => render(&self.scene, &camera, &self.options),
                })
            }
        };
        self.seq += 1;
        Some(Stamped {
            mono_ns,
            seq: self.seq,
            data: RawColor::Rgb(image),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::DepthData;
    use std::sync::atomic::{AtomicU64, Ordering};

    /// A clock that jumps to whatever instant it is asked to wait for.
    #[derive(Default)]
    struct Stepped(AtomicU64);
    impl Clock for Stepped {
        fn now_ns(&self) -> u64 {
            self.0.load(Ordering::SeqCst)
        }
        fn wait_until(&self, t_ns: u64) {
            self.0.fetch_max(t_ns, Ordering::SeqCst);
        }
    }

    /// A 10 fps synthetic camera over the roof scene on a stepped clock.
    fn at_10fps<P: PoseAt>(intr: Intrinsics, pose: P) -> SyntheticDepth<P, Stepped> {
        SyntheticDepth::new(
            roof(),
            intr,
            SensorModel::default(),
            10.0,
            pose,
            Stepped::default(),
        )
    }

    fn nadir(position_m: [f64; 3]) -> CameraPose {
        CameraPose::on_vehicle(position_m, [0.0; 3], 0.0)
    }

    fn roof() -> Arc<Scene> {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/roof.toml");
        Arc::new(Scene::load(&path).expect("the roof scene parses"))
    }

    /// The renderer's basis for a pose on a vehicle is the exports' camera →
    /// NED rotation, carried into the scene's (north, west, up).
    #[test]
    fn a_pose_on_a_vehicle_looks_as_the_exports_say() {
        use crate::capture::export::{camera_gl_to_ned, GL_TO_CV};
        use crate::capture::record::Attitude;
        let intr = Intrinsics::from_hfov_deg(8, 6, 69.0, None).unwrap();
        let cases = [
            [0.0, 0.0, 0.0, 0.0],
            [0.0, 5.0, 90.0, 20.0],
            [20.0, 0.0, 90.0, 0.0],
            [-35.0, 10.0, -150.0, 30.0],
            [10.0, 80.0, 45.0, 10.0],   // looks straight ahead: pitch 90°
            [30.0, -20.0, 200.0, 90.0], // a forward camera
        ];
        for [roll, pitch, yaw, mount] in cases {
            let rpy = [roll, pitch, yaw].map(f64::to_radians);
            let cam = CameraPose::on_vehicle([0.0; 3], rpy, mount.to_radians()).camera(intr);
            let (a, u, v) = cam.basis();
            let att = Attitude {
                roll_deg: roll,
                pitch_deg: pitch,
                yaw_deg: yaw,
                camera_pitch_deg: mount,
            };
            let cv_to_ned = camera_gl_to_ned(&att) * GL_TO_CV;
            let world = |c: glam::DVec3| [c.x, -c.y, -c.z];
            let want = [cv_to_ned.z_axis, cv_to_ned.x_axis, cv_to_ned.y_axis].map(world);
            for (got, want) in [a, u, v].iter().zip(want) {
                for k in 0..3 {
                    assert!(
                        (got[k] - want[k]).abs() < 1e-9,
                        "rpy {rpy:?} mount {mount}: {got:?} vs {want:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn level_flight_keeps_the_pitch_only_camera_bit_for_bit() {
        let pose = CameraPose::on_vehicle([1.0, 2.0, 3.0], [0.0, 0.1, 0.0], 0.3);
        let cam = pose.camera(Intrinsics::from_hfov_deg(8, 6, 69.0, None).unwrap());
        let (s, c) = (0.1f64 + 0.3).sin_cos();
        let bits =
            |(a, u, v): ([f64; 3], [f64; 3], [f64; 3])| [a, u, v].map(|w| w.map(f64::to_bits));
        // The basis the renderer had when it rendered pitch only.
        let pitch_only = ([s, 0.0, -c], [c, 0.0, s], [0.0, -1.0, 0.0]);
        assert_eq!(bits(cam.basis()), bits(pitch_only));
    }

    #[test]
    fn frames_come_at_the_frame_rate_and_see_the_roof_then_the_ground() {
        let intr = Intrinsics::from_hfov_deg(40, 30, 69.0, None).unwrap();
        // Flying along +x at 10 m/s from x = 0 (over the roof) at 40 m.
        let pose = |t: u64| Some(nadir([10.0 * t as f64 * 1e-9, 0.0, 40.0]));
        let mut src = at_10fps(intr, pose);
        let centre = |d: &DepthImage| match d.data() {
            DepthData::Z16 { data, .. } => data[15 * 40 + 20],
            _ => unreachable!(),
        };
        let f0 = src.next_depth().unwrap().unwrap();
        assert_eq!((f0.mono_ns, f0.seq), (0, 1));
        // Over the 20 m roof from 40 m: 20 m along the axis at the centre.
        assert_eq!(centre(&f0.data), 20_000);
        let mut last = f0;
        for _ in 0..12 {
            let f = src.next_depth().unwrap().unwrap();
            assert_eq!(f.mono_ns - last.mono_ns, 100_000_000);
            assert_eq!(f.seq, last.seq + 1);
            last = f;
        }
        // At t = 1.2 s the camera is at x = 12 m, past the roof's edge at 8 m.
        assert_eq!(centre(&last.data), 40_000);
    }

    #[test]
    fn no_pose_is_a_skipped_frame_not_a_stop() {
        let intr = Intrinsics::from_hfov_deg(8, 6, 69.0, None).unwrap();
        let pose = |t: u64| (t != 100_000_000).then_some(nadir([0.0, 0.0, 40.0]));
        let mut src = at_10fps(intr, pose);
        assert!(src.next_depth().is_ok());
        assert!(matches!(
            src.next_depth(),
            Err(SourceError::Unposed { seq: 2 })
        ));
        assert_eq!(src.next_depth().unwrap().unwrap().mono_ns, 200_000_000);
    }

    #[test]
    fn a_slow_render_skips_missed_frames_and_counts_them() {
        // A clock already 0.35 s ahead when the second frame is due: frames at
        // 0.1, 0.2 and 0.3 s are missed; the next one is stamped 0.4 s.
        struct Late(AtomicU64);
        impl Clock for Late {
            fn now_ns(&self) -> u64 {
                self.0.load(Ordering::SeqCst)
            }
            fn wait_until(&self, t_ns: u64) {
                let jump = if t_ns == 100_000_000 {
                    350_000_000
                } else {
                    t_ns
                };
                self.0.fetch_max(jump, Ordering::SeqCst);
            }
        }
        let intr = Intrinsics::from_hfov_deg(8, 6, 69.0, None).unwrap();
        let pose = |_| Some(nadir([0.0, 0.0, 40.0]));
        let mut src = SyntheticDepth::new(
            roof(),
            intr,
            SensorModel::default(),
            10.0,
            pose,
            Late(AtomicU64::new(0)),
        );
        src.next_depth().unwrap();
        let f = src.next_depth().unwrap().unwrap();
        assert_eq!((f.mono_ns, f.seq), (100_000_000, 2));
        let g = src.next_depth().unwrap().unwrap();
        // Due at 0.1 s but rendered at 0.35 s: 0.2 and 0.3 s are skipped.
        assert_eq!((g.mono_ns, g.seq), (400_000_000, 5));
    }

    /// A frame rendered ahead is the frame rendered when asked, bit for bit,
    /// and is collected once; an instant asked past is dropped, and one not
    /// rendered ahead is rendered then.
    #[test]
    fn a_frame_rendered_ahead_is_the_frame_rendered_when_asked() {
        let intr = Intrinsics::from_hfov_deg(40, 30, 69.0, None).unwrap();
        // A pose that moves with time, so each instant has its own frame.
        let pose = |t: u64| Some(nadir([t as f64 * 1e-9, 0.0, 40.0]));
        let rgb = |f: Option<Stamped<RawColor>>| match f.map(|f| f.data) {
            Some(RawColor::Rgb(c)) => c.rgb,
            _ => panic!("no colour frame"),
        };
        let mut direct = SyntheticColor::new(roof(), intr, 1, pose).on_all_cores();
        let ahead = Ahead::default();
        let mut start = ColourAhead::new(roof(), intr, 1, pose, ahead.clone());
        let mut cam = SyntheticColor::new(roof(), intr, 1, pose)
            .on_all_cores()
            .with_ahead(ahead.clone());
        for t in [1_000_000_000, 2_000_000_000, 3_000_000_000] {
            start.prepare(t);
        }
        assert_eq!(ahead.queue().len(), 3);
        // The writer skipped the first capture's image.
        let second = rgb(cam.raw_at(2_000_000_000));
        assert_eq!(second, rgb(direct.raw_at(2_000_000_000)));
        assert_eq!(
            ahead.queue().len(),
            1,
            "the first dropped, the second taken"
        );
        assert_ne!(second, rgb(direct.raw_at(3_000_000_000)));
        assert_eq!(
            rgb(cam.raw_at(3_000_000_000)),
            rgb(direct.raw_at(3_000_000_000))
        );
        assert!(ahead.queue().is_empty());
        // Not rendered ahead: rendered when asked.
        assert_eq!(
            rgb(cam.raw_at(4_000_000_000)),
            rgb(direct.raw_at(4_000_000_000))
        );
        // No more than AHEAD_MAX in flight.
        for k in 0..2 * AHEAD_MAX as u64 {
            start.prepare(5_000_000_000 + k);
        }
        assert_eq!(ahead.queue().len(), AHEAD_MAX);
    }

    /// The tap holds the last frame's exact depth (before the sensor's noise
    /// and range), given once and only for its own instant and camera.
    #[test]
    fn the_tap_gives_the_last_frames_exact_depth_for_its_own_camera() {
        let intr = Intrinsics::from_hfov_deg(8, 6, 69.0, None).unwrap();
        let pose = |_| Some(nadir([0.0, 0.0, 40.0]));
        let tap = DepthTap::default();
        let sensor = SensorModel {
            noise_per_m: 0.01,
            dropout: 0.2,
            ..SensorModel::default()
        };
        let mut src = SyntheticDepth::new(roof(), intr, sensor, 10.0, pose, Stepped::default())
            .with_tap(tap.clone());
        let f = src.next_depth().unwrap().unwrap();
        let camera = nadir([0.0, 0.0, 40.0]).camera(intr);
        let other = nadir([0.5, 0.0, 40.0]).camera(intr);
        assert_eq!(tap.take_if(f.mono_ns + 1, &camera), None);
        assert_eq!(tap.take_if(f.mono_ns, &other), None);
        assert_eq!(
            tap.take_if(f.mono_ns, &camera),
            Some(render_depth(&roof(), &camera))
        );
        assert_eq!(tap.take_if(f.mono_ns, &camera), None, "given once");
    }
}
