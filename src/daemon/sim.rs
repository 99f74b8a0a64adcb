//! `alfd sim`: firmware-sim on a pseudo-terminal flying a survey line over a
//! synthetic scene, the daemon against it with synthetic cameras, and the run
//! judged against the simulator's truth (`simreport`). Everything the flight
//! uses runs here too: the link, the pipeline, the writer, the exports.

use super::devices::{intrinsics, scene_camera_pose};
use super::run::{run, Devices, FrameSample, Frames, RunError, RunOptions, RunReport, SampleHook};
use crate::capture::CaptureMode;
use crate::config::{Config, QualityPatch, SimPose};
use crate::core::{EstimatorParams, Intrinsics, Model, Profile};
use crate::link::{mono_ns, LinkHandle};
use crate::notify::Notifier;
use crate::render::SensorModel;
use crate::scene::Scene;
use crate::simreport::{self, CaptureAt, DaemonSample, Summary, TrackSample, TruthPose};
use crate::source::synthetic::{
    Ahead, CameraPose, ColourAhead, DepthTap, MonotonicClock, SyntheticColor, SyntheticDepth,
};
use crate::source::SourceError;
use firmware_sim::{SimConfig, Transport, Truth};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

/// `alfd sim --sweep`: how the flight's estimator sweeps the visibility term.
/// Either way the truth sweeps every pixel of every frame, so the summary
/// judges the flight default's saving.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SimSweep {
    /// Every pixel on every frame (the bench has the CPU).
    #[default]
    EveryPixel,
    /// The daemon's defaults (`[estimator] visibility_samples_max` and
    /// `visibility_interleave` left out of the config): what a drone runs.
    Flight,
}

/// The scene `alfd sim` flies over when none is given.
pub const DEFAULT_SCENE: &str = include_str!("../../scenes/district.toml");

#[derive(Debug, Clone)]
pub struct SimArgs {
    /// A scene file; `None`: the built-in district.
    pub scene: Option<PathBuf>,
    /// A daemon config to start from (its link address is replaced by the simulator's).
    pub config: Option<PathBuf>,
    pub out: PathBuf,
    /// `None`: the scene's own `survey.speed_mps`.
    pub speed_mps: Option<f64>,
    pub telemetry_hz: f64,
    pub fps: f64,
    pub width: usize,
    pub height: usize,
    pub mode: CaptureMode,
    /// `None`: the quality model.
    pub model: Option<Model>,
    /// The quality targets over the config's (a profile, then each target given;
    /// empty: the config's, or lightfield for the built-in one).
    pub quality: QualityPatch,
    /// `[trigger] closed_loop`: also measure against the last capture.
    pub closed_loop: bool,
    /// How the estimator sweeps the visibility term.
    pub sweep: SimSweep,
    pub pose: SimPose,
    /// Forward MAVLink to a ground station (`udpout:HOST:PORT`).
    pub gcs: Option<String>,
    pub progress: bool,
    /// Stop after this much of the line (metres); `None`: all of it. With
    /// `lanes` > 1, the length of each lane.
    pub length_m: Option<f64>,
    /// Parallel lanes flown back and forth (a lawnmower), each `lane_spacing_m`
    /// east of the last; 1: the single line.
    pub lanes: u32,
    pub lane_spacing_m: f64,
    /// Whose HEARTBEAT and distance-trigger counting firmware-sim copies (only
    /// those, and for ArduPilot its servo camera's CAMERA_FEEDBACK instead of
    /// CAMERA_TRIGGER: the vehicle flies the same).
    pub autopilot: firmware_sim::Autopilot,
    pub seed: u64,
    /// firmware-sim's faults (corruption, drops, scheduled link loss, reboot,
    /// GPS glitch, silence), as in its config.
    pub faults: Option<firmware_sim::config::Faults>,
    /// Windows in which the synthetic depth camera fails.
    pub depth_outages: Vec<DepthOutage>,
}

/// A depth camera failure, from `start_s` after the simulator started.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthOutage {
    pub start_s: f64,
    pub duration_s: f64,
    pub kind: OutageKind,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutageKind {
    /// No frames at all (a stalled USB camera).
    Stall,
    /// Frames with no valid pixel (covered lens, all out of range).
    NoValidPixels,
}

/// An edit of the run's config.
pub type ConfigEdit = Box<dyn FnOnce(&mut Config) + Send>;

/// What a test may hand to a sim run besides its arguments.
#[derive(Default)]
pub struct SimHooks {
    /// Log captures here instead of the flight directory.
    pub store: Option<super::run::BoxedStore>,
    /// Called once the simulator runs (e.g. to inject faults at run time).
    pub on_sim: Option<Box<dyn FnOnce(Arc<firmware_sim::SimHandle>) + Send>>,
    /// Edits the daemon's config before it runs (e.g. a lower rate limit).
    pub on_config: Option<ConfigEdit>,
}

/// A depth source that fails in the given windows.
struct Outages<S> {
    inner: S,
    start_ns: u64,
    windows: Vec<DepthOutage>,
}

impl<S: crate::source::DepthSource> crate::source::DepthSource for Outages<S> {
    fn intrinsics(&self) -> Intrinsics {
        self.inner.intrinsics()
    }
    fn due_ns(&self) -> Option<u64> {
        self.inner.due_ns()
    }

    fn next_depth(
        &mut self,
    ) -> Result<Option<crate::source::Stamped<crate::core::DepthImage>>, SourceError> {
        let Some(mut f) = self.inner.next_depth()? else {
            return Ok(None);
        };
        let t = f.mono_ns.saturating_sub(self.start_ns) as f64 * 1e-9;
        let w = self
            .windows
            .iter()
            .find(|w| t >= w.start_s && t < w.start_s + w.duration_s);
        match w.map(|w| w.kind) {
            None => Ok(Some(f)),
            // The frame never comes: the gap in the frame counter says so.
            Some(OutageKind::Stall) => Err(SourceError::Missed { seq: f.seq }),
            Some(OutageKind::NoValidPixels) => {
                let (w, h) = (f.data.width(), f.data.height());
                f.data = crate::core::DepthImage::new(
                    w,
                    h,
                    crate::core::DepthData::Metres(vec![f32::NAN; w * h]),
                )
                .expect("same size as the frame it replaces");
                Ok(Some(f))
            }
        }
    }
}

impl Default for SimArgs {
    fn default() -> Self {
        SimArgs {
            scene: None,
            config: None,
            out: PathBuf::from("sim-out"),
            speed_mps: None,
            telemetry_hz: 10.0,
            fps: 30.0,
            width: 640,
            height: 480,
            mode: CaptureMode::Frame,
            model: None,
            quality: QualityPatch::default(),
            closed_loop: false,
            sweep: SimSweep::EveryPixel,
            pose: SimPose::Truth,
            gcs: None,
            progress: true,
            length_m: None,
            lanes: 1,
            lane_spacing_m: 40.0,
            autopilot: firmware_sim::Autopilot::Generic,
            seed: 1,
            faults: None,
            depth_outages: Vec::new(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SimRunError {
    #[error("{0}")]
    Setup(String),
    #[error(transparent)]
    Run(#[from] RunError),
}

/// What `alfd sim` produced.
pub struct SimOutcome {
    pub flight_dir: PathBuf,
    pub summary: Summary,
    pub report: RunReport,
    pub plots: Vec<PathBuf>,
    pub truth: Vec<TrackSample>,
    /// The simulator's truth at each logged record's instant (same order).
    pub truth_at_records: Vec<Truth>,
    /// Bytes of the images written.
    pub image_bytes: u64,
    /// What firmware-sim saw: COMMAND_LONGs from alfd (instant, command id),
    /// the CAMERA_TRIGGERs it sent (instant, seq), and its counters.
    pub sim_commands: Vec<(u64, u32)>,
    pub sim_triggers: Vec<(u64, u32)>,
    pub sim_events_lost: u64,
    pub sim_stats: firmware_sim::SimStats,
    /// How the flight's estimator swept the visibility term ([`sweep_text`]).
    pub sweep: String,
    /// In `camera_command` and `autopilot_distance`: firmware-sim's camera's
    /// pictures, on a card in the flight directory ([`super::camera_card`]).
    pub camera_card: Option<CameraCard>,
}

/// How an estimator with `p` sweeps the visibility term on `width × height`
/// depth frames, in words for the summary; the truth sweeps every pixel of
/// every frame whatever `p` says (`simreport::truth`).
pub fn sweep_text(p: &crate::core::EstimatorParams, width: usize, height: usize) -> String {
    if p.model != Model::Quality {
        return "none (the quality model's term)".into();
    }
    // The estimator's own choice, on its grid of every `n`-th pixel.
    let n = match p.decimation {
        crate::core::Decimation::Fixed(n) => n.max(1),
        crate::core::Decimation::Auto { .. } => 1,
    };
    let (interleave, step) = p.visibility_sampling(width.div_ceil(n) * height.div_ceil(n), n, true);
    let pixels = match (&p.decimation, step) {
        (crate::core::Decimation::Auto { .. }, _) => {
            "at the level decimation \"auto\" takes".to_string()
        }
        (_, 1) => "every pixel".to_string(),
        (_, step) => format!("one pixel in {step} both ways"),
    };
    let held = 2 * interleave;
    let lines = if interleave == 1 {
        "every line on every frame".to_string()
    } else if p.visibility_refresh {
        format!(
            "one line in {interleave} a frame, the others' newest sweeps kept, the views bound's shortest interval held {held} frames, every line when a frame's own lines tighten and the lines beside the shortest interval on every frame"
        )
    } else {
        format!("one line in {interleave} a frame, the others' newest sweeps kept, the views bound's shortest interval held {held} frames")
    };
    format!("{pixels}, {lines}{JUDGED}")
}

/// The bench's external camera (`camera_command`): each picture this long after its command
/// reaches the autopilot (the autopilot's scheduling and the camera's trigger lag; a stated
/// figure, not a measured one), and reported at its own instant.
pub const SIM_CAMERA_DELAY: std::time::Duration = std::time::Duration::from_millis(50);

/// The end of [`sweep_text`]: what the sim's truth sweeps.
const JUDGED: &str = "; judged against every pixel of every frame";

fn sim_config_text(a: &SimArgs, scene_path: &Path, flight_dir: &Path, scene: &Scene) -> String {
    let mode = match a.mode {
        CaptureMode::Frame => "frame",
        CaptureMode::CameraCommand => "camera_command",
        CaptureMode::AutopilotDistance => "autopilot_distance",
        // Not a mode one configures: the config refuses it by name.
        CaptureMode::Command => "command",
    };
    let model = a.model.unwrap_or(Model::Quality).as_str();
    let profile = a.quality.profile.unwrap_or_default().as_str();
    let targets = quality_lines(&a.quality);
    let closed_loop = a.closed_loop;
    let pose = match a.pose {
        SimPose::Truth => "truth",
        SimPose::Telemetry => "telemetry",
    };
    let camera = if a.mode == CaptureMode::Frame {
        "synthetic"
    } else {
        "none"
    };
    format!(
        r#"[mavlink]
address = "serial:/dev/null:921600"
system_id = 1
component_id = 100
accept_system_ids = [1, 255, 245, 190]
position_hz = {hz}
attitude_hz = {hz}

[sim]
pose = "{pose}"
scene = {scene_path:?}

[camera]
source = "{camera}"
width = {w}
height = {h}
fps = {fps}
hfov_deg = {hfov}

[depth]
source = "synthetic"
width = {w}
height = {h}
fps = {fps}
hfov_deg = {hfov}
mount_pitch_deg = {pitch}
# 1 cm per Z16 unit: 1 mm (a RealSense's default) saturates at 65.5 m.
scale_m = 0.01
max_range_m = {range}

[quality]
profile = "{profile}"
{targets}
[estimator]
{sweep}# The sweep's lines on every core of the bench: the same estimate, sooner.
threads = {threads}

[sampling]
model = "{model}"

[trigger]
rate_max_hz = {fps}
fallback_spacing_m = 1.0
closed_loop = {closed_loop}

[capture]
dir = {dir:?}
mode = "{mode}"
image_format = "jpeg"
jpeg_quality = 90
"#,
        hz = a.telemetry_hz,
        w = a.width,
        h = a.height,
        sweep = match a.sweep {
            SimSweep::EveryPixel => format!(
                "# The visibility sweep on every pixel of every frame: with the flight's
# defaults (alfd sim --sweep flight: every pixel once in four frames) this
# flight had 13 avoidable violations, thinned to every second pixel on every
# frame (the default until 2026-11-27) 58 (docs/error-vs-runtime.md). The
# bench has the CPU; on a drone it is these two settings' trade.
visibility_samples_max = {}
visibility_interleave = 1
",
                (a.width * a.height).max(100)
            ),
            SimSweep::Flight =>
                "# The flight's defaults for the visibility sweep (alfd sim --sweep flight).\n"
                    .to_string(),
        },
        threads = std::thread::available_parallelism().map_or(1, |n| n.get().min(64)),
        fps = a.fps,
        hfov = scene.survey.hfov_deg,
        pitch = scene.survey.pitch_rad.to_degrees(),
        range = (scene.survey.altitude_m * 3.0).max(65.0),
        dir = flight_dir,
    )
}

/// The `[quality]` lines of the targets given over the profile.
fn quality_lines(q: &QualityPatch) -> String {
    let target = |key: &str, v: Option<f64>| match v {
        Some(x) => format!("{key} = {x:?}\n"),
        None => format!("{key} = false\n"),
    };
    let mut s = String::new();
    if let Some(v) = q.parallax_px {
        s += &target("parallax_px", v);
    }
    if let Some(v) = q.forward_overlap {
        s += &target("forward_overlap", v);
    }
    if let Some(v) = q.unseen_fraction_max {
        s += &target("unseen_fraction_max", Some(v));
    }
    if let Some(v) = q.views_per_point_min {
        s += &format!("views_per_point_min = {v}\n");
    }
    s
}

/// Runs `alfd sim` to its summary.
pub async fn run_sim(
    args: SimArgs,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<SimOutcome, SimRunError> {
    run_sim_with(args, SimHooks::default(), shutdown).await
}

/// Where a flight on simulated time starts: 1000 s after the companion's boot, at
/// 2026-06-21 10:00:00 UTC. Fixed, so two runs log the same instants.
pub const SIMULATED_START_MONO_NS: u64 = 1_000_000_000_000;
pub const SIMULATED_START_UNIX_US: u64 = 1_782_036_000_000_000;

/// [`run_sim_with`] on simulated time: a current-thread runtime whose paused clock the
/// daemon and firmware-sim both read (`alfd-clock`, [`crate::link::simulate_on_this_thread`]),
/// moved by the runtime only when every task waits. The daemon's loops run as its tasks and talk
/// to the simulator through memory, so renders and estimates take no simulated time, the
/// flight runs as fast as they allow, and the same arguments give the same flight. It
/// builds its own runtime: call it from outside one.
pub fn run_sim_on_simulated_time(
    args: SimArgs,
    hooks: SimHooks,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<SimOutcome, SimRunError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(|e| SimRunError::Setup(format!("runtime: {e}")))?;
    rt.block_on(async {
        // One clock for the daemon and firmware-sim (`alfd-clock`).
        let _clock =
            crate::link::simulate_on_this_thread(SIMULATED_START_MONO_NS, SIMULATED_START_UNIX_US);
        run_sim_with(args, hooks, shutdown).await
    })
}

/// [`run_sim`] with hooks for tests.
pub async fn run_sim_with(
    mut args: SimArgs,
    mut hooks: SimHooks,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<SimOutcome, SimRunError> {
    let setup = |e: String| SimRunError::Setup(e);
    // On simulated time the daemon and the simulator share one runtime thread and talk
    // through memory (`link::wire`); in real time, through a pty as on the bench.
    let simulated = crate::link::simulated();
    // Refused before anything is written.
    if simulated && args.pose == SimPose::Telemetry && args.config.is_none() {
        return Err(setup(
            "--pose telemetry renders at the link's answer, which a flight on simulated time cannot wait for: add --real-time".into(),
        ));
    }
    if simulated && args.gcs.is_some() {
        return Err(setup(
            "--gcs: a ground station watches in real time; add --real-time".into(),
        ));
    }
    // The scene and a given config, read and checked before any directory is made:
    // a bad one leaves no empty flight behind.
    let given = match &args.config {
        Some(p) => {
            let c = Config::load(p).map_err(|e| setup(e.to_string()))?;
            // An estimator config (`configs/estimator.toml`) validates on its own;
            // the daemon then stopped for want of a link, after the flight's
            // directory was made.
            if c.link.is_none() {
                return Err(setup(format!(
                    "--config {}: no [mavlink] section, so not a daemon config: alfd sim starts from \
                     a whole daemon config (configs/sim.toml) and replaces only its link's address",
                    p.display()
                )));
            }
            // The command line over the config: the model, the targets and the
            // closed loop.
            let mut c = c;
            if let Some(m) = args.model {
                c.estimator.model = m;
            }
            args.quality.apply(&mut c.estimator.quality);
            c.trigger.closed_loop |= args.closed_loop;
            c.estimator.validate().map_err(|e| {
                setup(format!(
                    "the quality targets given over {}: {e}",
                    p.display()
                ))
            })?;
            if simulated && c.sim_pose == SimPose::Telemetry {
                return Err(setup(format!(
                    "--config {}: sim.pose \"telemetry\" renders at the link's answer, which a flight on simulated time cannot wait for: add --real-time",
                    p.display()
                )));
            }
            Some(c)
        }
        None => {
            // Written into the built-in config: checked here, by what was given,
            // rather than as the built-in config's error.
            let mut p = EstimatorParams::default();
            args.quality.apply(&mut p.quality);
            p.validate()
                .map_err(|e| setup(format!("the quality targets given: {e}")))?;
            None
        }
    };
    // The scene flown: a given config's own, else --scene's, else the built-in one.
    let (scene_text, scene_name) = match (
        given.as_ref().and_then(|c| c.sim_scene.as_ref()),
        &args.scene,
    ) {
        (Some(p), _) => (
            std::fs::read_to_string(p)
                .map_err(|e| setup(format!("sim.scene {}: {e}", p.display())))?,
            p.display().to_string(),
        ),
        (None, Some(p)) => (
            std::fs::read_to_string(p)
                .map_err(|e| setup(format!("--scene {}: {e}", p.display())))?,
            p.display().to_string(),
        ),
        (None, None) => (DEFAULT_SCENE.to_string(), "district (built in)".to_string()),
    };
    let scene = Scene::parse(&scene_text, &scene_name).map_err(|e| setup(e.to_string()))?;
    // A line longer than the scene's would fly off the rendered ground: said,
    // not cut short without a word.
    let line_m = scene.survey.end_x_m - scene.survey.start_x_m;
    // The scene's survey is flown at its own speed unless told otherwise: the eval
    // scenes' 5 m/s, not the district's 10.
    let speed_mps = args.speed_mps.unwrap_or(scene.survey.speed_mps);
    if speed_mps > 50.0 {
        return Err(setup(format!(
            "scene {}'s survey.speed_mps {speed_mps}: alfd sim flies at most 50 m/s; give --speed-mps",
            scene.name
        )));
    }
    if let Some(l) = args.length_m.filter(|&l| l > line_m) {
        return Err(setup(format!(
            "--length-m {l}: scene {}'s survey line is {line_m} m; fly at most that",
            scene.name
        )));
    }
    // Named by its flag: "afile: File exists (os error 17)" did not say what to change.
    std::fs::create_dir_all(&args.out).map_err(|e| {
        setup(if args.out.exists() && !args.out.is_dir() {
            format!("--out {}: a file, not a directory", args.out.display())
        } else {
            format!("--out {}: {e}", args.out.display())
        })
    })?;
    let flight_dir = super::run::next_flight_dir(&args.out);
    std::fs::create_dir_all(&flight_dir)
        .map_err(|e| setup(format!("{}: {e}", flight_dir.display())))?;
    // The scene flown is copied next to the captures: the run can be redone.
    let scene_path = flight_dir.join("scene.toml");
    std::fs::write(&scene_path, &scene_text)
        .map_err(|e| setup(format!("{}: {e}", scene_path.display())))?;

    let mut config = match given {
        Some(mut c) => {
            c.capture.dir = flight_dir.clone();
            c
        }
        None => {
            let text = sim_config_text(&args, &scene_path, &flight_dir, &scene);
            let path = flight_dir.join("alfd.toml");
            std::fs::write(&path, &text).map_err(|e| setup(format!("{}: {e}", path.display())))?;
            Config::from_text(&text, &path.display().to_string())
                .map_err(|e| setup(format!("the built-in sim config: {e}")))?
        }
    };
    if let Some(f) = hooks.on_config.take() {
        f(&mut config);
    }
    // From here the flight is the config's: its frame rate ticks the renders, its
    // capture mode sets the opportunity step, its pose source renders and its
    // rates are firmware-sim's streams (a given config's, where they used to be
    // the flags' defaults: 30 fps and 10 Hz beside a config's 15 fps).
    args.fps = config.depth.fps;
    args.mode = config.capture.mode;
    args.pose = config.sim_pose;
    let (position_hz, attitude_hz) = config
        .link
        .as_ref()
        .map_or((args.telemetry_hz, args.telemetry_hz), |l| {
            (l.position_hz, l.attitude_hz)
        });
    let scene = Arc::new(scene);

    // The simulated autopilot: a line north over the scene's survey, or lanes
    // east of it flown back and forth (one strip leaves a reconstruction's
    // lateral positions to trade against roll; a second one fixes them).
    let mut sc = SimConfig {
        transport: if simulated {
            Transport::Memory
        } else {
            Transport::Pty {
                link: Some(flight_dir.join("ttyFC")),
            }
        },
        gcs: args.gcs.clone(),
        autopilot: args.autopilot,
        // ArduPilot never sends CAMERA_TRIGGER: with a servo- or relay-triggered camera,
        // the commonest survey set-up, each picture is a CAMERA_FEEDBACK alone.
        camera: match args.autopilot {
            firmware_sim::Autopilot::ArduPilot => firmware_sim::CameraBackend::Servo,
            _ => firmware_sim::CameraBackend::Trigger,
        },
        camera_delay: SIM_CAMERA_DELAY,
        ..SimConfig::default()
    };
    sc.survey.pattern = firmware_sim::Pattern::Line;
    sc.survey.altitude_m = scene.survey.altitude_m;
    sc.survey.heading_deg = 0.0;
    sc.survey.length_m = line_m;
    sc.survey.lanes = 1;
    let lanes = args.lanes.max(1);
    let stop_at_m = args.length_m.unwrap_or(line_m).min(line_m);
    if lanes > 1 {
        sc.survey.pattern = firmware_sim::Pattern::Lawnmower;
        sc.survey.length_m = stop_at_m;
        sc.survey.lanes = lanes;
        sc.survey.lane_spacing_m = args.lane_spacing_m;
    }
    // The way from the start to the end of the last lane.
    let path_m = stop_at_m * lanes as f64 + args.lane_spacing_m * (lanes - 1) as f64;
    // Where the last lane ends: north at the far end after an odd number of
    // lanes, back at the start after an even one.
    let last_lane_east_m = args.lane_spacing_m * (lanes - 1) as f64;
    let ends_north = lanes % 2 == 1;
    sc.survey.speed_mps = speed_mps;
    // Without wander, as while the synthetic camera rendered pitch only (it now
    // renders the whole attitude, issue 14): the sim's documented figures were
    // flown so.
    sc.survey.wind_m = 0.0;
    sc.survey.wind_deg = 0.0;
    sc.streams.attitude_quaternion = attitude_hz;
    sc.streams.global_position_int = position_hz;
    sc.streams.local_position_ned = position_hz;
    if let Some(f) = &args.faults {
        sc.faults = f.clone();
    }
    sc.faults.seed = args.seed;
    let sim = Arc::new(
        firmware_sim::start(sc)
            .await
            .map_err(|e| setup(format!("firmware-sim: {e}")))?,
    );
    let sim_start_ns = mono_ns();
    let memory_wire = sim.take_memory_wire();
    if let Some(l) = config.link.as_mut() {
        l.address = sim.address().to_string();
    }
    if let Some(f) = hooks.on_sim.take() {
        f(sim.clone());
    }
    let watcher = {
        let mut rx = sim.subscribe();
        tokio::spawn(async move {
            let (mut commands, mut triggers, mut lost) = (Vec::new(), Vec::new(), 0u64);
            let mut pictures = Vec::new();
            loop {
                match rx.recv().await {
                    Ok(firmware_sim::SimEvent::Received {
                        mono_ns,
                        component_id: 100,
                        command: Some(c),
                        ..
                    }) => commands.push((mono_ns, c)),
                    Ok(firmware_sim::SimEvent::Capture {
                        mono_ns,
                        seq,
                        truth,
                    }) => {
                        triggers.push((mono_ns, seq));
                        pictures.push((mono_ns, truth));
                    }
                    Ok(_) => {}
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => lost += n,
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => {
                        return (commands, triggers, lost, pictures)
                    }
                }
            }
        })
    };

    let mount = config.depth.mount_pitch_rad;
    let link_slot: Arc<OnceLock<LinkHandle>> = Arc::new(OnceLock::new());
    let pose_source = |scene: Arc<Scene>| -> Box<dyn FnMut(u64) -> Option<CameraPose> + Send> {
        match args.pose {
            SimPose::Truth => {
                let sim = sim.clone();
                Box::new(move |t: u64| {
                    let tr = sim.truth_at_mono_ns(t);
                    Some(scene_camera_pose(
                        &scene,
                        mount,
                        tr.pos_ned_m,
                        tr.rpy_deg.map(f64::to_radians),
                    ))
                })
            }
            SimPose::Telemetry => Box::new(super::devices::telemetry_pose(
                scene,
                mount,
                link_slot.clone(),
            )),
        }
    };
    let intr = intrinsics(&config.depth).map_err(|e| setup(format!("depth: {e}")))?;
    let sensor = SensorModel {
        scale_m: config.depth.scale_m,
        noise_per_m: config.depth.noise_per_m,
        dropout: config.depth.dropout,
        max_range_m: config.depth.max_range_m,
        seed: args.seed,
    };
    // Each depth frame's exact render, for the truth track below.
    let tap = DepthTap::default();
    let depth = SyntheticDepth::new(
        scene.clone(),
        intr,
        sensor,
        config.depth.fps,
        pose_source(scene.clone()),
        MonotonicClock,
    )
    .with_tap(tap.clone());
    // On simulated time a capture's colour frame is rendered as soon as the
    // capture is decided, on a thread of its own, while the flight goes on to
    // its next frames: a streaming camera has the frame by the time the writer
    // asks for it, and the runtime's thread no longer waits for the render.
    let mut colour_ahead = None;
    let frames = (config.capture.mode == CaptureMode::Frame).then(|| {
        // The colour camera's own intrinsics, as the manifest records them.
        let ci = super::devices::intrinsics(&config.camera).unwrap_or(intr);
        let colour = SyntheticColor::new(scene.clone(), ci, 1, pose_source(scene.clone()));
        Frames::AtInstant(Box::new(if simulated {
            let ahead = Ahead::default();
            colour_ahead = Some(ColourAhead::new(
                scene.clone(),
                ci,
                1,
                pose_source(scene.clone()),
                ahead.clone(),
            ));
            // On simulated time nothing renders beside it: all cores.
            colour.on_all_cores().with_ahead(ahead)
        } else {
            colour
        }))
    });

    // Progress along the line, from the frames the daemon processes.
    let bar = args.progress.then(|| {
        let b = indicatif::ProgressBar::new(path_m.ceil() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{spinner} {bar:40} {pos}/{len} m  {msg}")
                .expect("a valid template"),
        );
        b
    });
    let captures_seen = Arc::new(Mutex::new(0u64));
    let mut progress = bar.clone().map(|b| {
        let seen = captures_seen.clone();
        let (mut flown_m, mut last) = (0.0f64, None::<[f64; 3]>);
        move |s: &FrameSample| {
            if let Some(p) = s.pos_ned_m {
                if let Some(l) = last {
                    flown_m += (p[0] - l[0]).hypot(p[1] - l[1]);
                }
                last = Some(p);
                b.set_position(flown_m as u64);
            }
            if s.captured {
                let mut n = seen.lock().unwrap_or_else(|p| p.into_inner());
                *n += 1;
                let spacing = s.spacing_m.map_or("-".into(), |v| format!("{v:.2} m"));
                b.set_message(format!("{n} captures, spacing {spacing}"));
            }
        }
    });
    // The truth track, estimated beside the flight from the true pose at each
    // frame the daemon processes (the same poses as after it: `truth_track`).
    let judge = judge_params(&config.estimator);
    let truth_stream =
        simreport::TruthStream::spawn(scene.clone(), intr, judge.clone()).map(Arc::new);
    let mut feed = truth_stream.clone().map(|stream| {
        let sim = sim.clone();
        let mut tracker = TruthTracker::new(scene.clone(), intr, mount);
        let tap = tap.clone();
        move |s: &FrameSample| {
            let pose = tracker.pose(s.mono_ns, &sim.truth_at_mono_ns(s.mono_ns));
            // The depth camera's own render of this frame, when it is this
            // pose's: the truth need not render it again.
            let depth = tap.take_if(s.mono_ns, &pose.camera);
            stream.push(pose, depth)
        }
    });
    let on_sample: Option<SampleHook> =
        (progress.is_some() || feed.is_some() || colour_ahead.is_some()).then(|| {
            Box::new(move |s: &FrameSample| {
                if let Some(f) = progress.as_mut() {
                    f(s);
                }
                if let Some(f) = feed.as_mut() {
                    f(s);
                }
                if let Some(c) = colour_ahead.as_mut().filter(|_| s.captured) {
                    c.prepare(s.mono_ns);
                }
            }) as SampleHook
        });

    let done = {
        let sim = sim.clone();
        async move {
            // Past the end of the line (or the requested length), or a deadline
            // well past the time the line takes, whichever is first.
            let limit = mono_ns() + ((path_m / speed_mps.max(0.1) + 30.0) * 1e9) as u64;
            loop {
                tokio::time::sleep(Duration::from_millis(50)).await;
                let [north, east, _] = sim.truth_at_mono_ns(mono_ns()).pos_ned_m;
                let on_last_lane = east >= last_lane_east_m - 0.05;
                let at_end = if ends_north {
                    north >= stop_at_m - 0.05
                } else {
                    north <= 0.05
                };
                if (on_last_lane && at_end) || mono_ns() > limit {
                    return;
                }
            }
        }
    };
    let options = RunOptions {
        flight_dir: flight_dir.clone(),
        store: hooks.store.take(),
        keep_samples: true,
        notifier: Notifier::disabled(),
        on_sample,
        memory_wire,
        on_link: Some({
            let slot = link_slot.clone();
            Box::new(move |l: &LinkHandle| {
                let _ = slot.set(l.clone());
            })
        }),
    };
    let report = run(
        config.clone(),
        Devices {
            depth: Some(if args.depth_outages.is_empty() {
                Box::new(depth)
            } else {
                Box::new(Outages {
                    inner: depth,
                    start_ns: sim_start_ns,
                    windows: args.depth_outages.clone(),
                })
            }),
            frames,
            tick_hz: args.fps,
        },
        options,
        async move {
            tokio::select! {
                biased;
                _ = done => {}
                _ = shutdown => {}
            }
        },
    )
    .await;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let report = report?;

    // Judge the run against the truth at the instants the daemon had frames.
    let truth_at = |t: u64| sim.truth_at_mono_ns(t);
    let (poses, daemon) = truth_track(&scene, &config, &report.samples, &truth_at);
    // The hook that fed the stream went with the daemon's tasks: this is the
    // last handle.
    let streamed = match truth_stream.map(Arc::try_unwrap) {
        Some(Ok(stream)) => stream.finish().map_or_else(
            || Err("its worker stopped"),
            |(streamed_poses, truth)| {
                (streamed_poses == poses)
                    .then_some(truth)
                    .ok_or("its poses differ from the run's frames")
            },
        ),
        Some(Err(_)) => Err("it is still fed"),
        None => Err("no thread for it"),
    };
    let truth = streamed.unwrap_or_else(|why| {
        tracing::warn!("truth track not streamed ({why}): estimated after the flight");
        simreport::truth_estimates(&scene, intr, &judge, &poses)
    });
    let captures = capture_positions(&report, &poses, &truth_at);
    let summary = simreport::summarize(
        &truth,
        &captures,
        config.trigger.fallback_spacing_m,
        opportunity_step_m(&args, speed_mps),
    )
    .with_records(&report.records)
    .judged_by(judged_by(&config.estimator, &judge));
    let plots = simreport::plots(&truth, &daemon, &captures, &flight_dir)
        .map_err(|e| setup(format!("plots: {e}")))?;
    let mut track = String::new();
    for t in &truth {
        track.push_str(&serde_json::to_string(t).expect("a sample serialises"));
        track.push('\n');
    }
    std::fs::write(flight_dir.join("truth_track.jsonl"), track)
        .map_err(|e| setup(format!("truth_track.jsonl: {e}")))?;
    let json = serde_json::to_string_pretty(&summary).expect("the summary serialises");
    std::fs::write(flight_dir.join("summary.json"), json + "\n")
        .map_err(|e| setup(format!("summary.json: {e}")))?;
    let image_bytes = report
        .records
        .iter()
        .filter_map(|r| r.image.as_ref())
        .filter_map(|n| std::fs::metadata(flight_dir.join(n)).ok())
        .map(|m| m.len())
        .sum();
    let truth_at_records = report
        .records
        .iter()
        .map(|r| sim.truth_at_mono_ns(r.mono_ns))
        .collect();
    let sim_stats = sim.stats();
    match Arc::try_unwrap(sim) {
        Ok(s) => s.shutdown().await,
        Err(_) => tracing::warn!("firmware-sim still referenced; left to stop with the process"),
    }
    let (sim_commands, sim_triggers, sim_events_lost, pictures) =
        match tokio::time::timeout(Duration::from_secs(2), watcher).await {
            Ok(Ok(r)) => r,
            _ => (Vec::new(), Vec::new(), u64::MAX, Vec::new()),
        };
    // An external camera's flight: its card, rendered, and paired with the
    // manifest as `alfd export --images` pairs a real card.
    let camera_card =
        (config.capture.mode != CaptureMode::Frame && !pictures.is_empty()).then(|| {
            let ci = super::devices::intrinsics(&config.camera).unwrap_or(intr);
            camera_card(&flight_dir, &scene, ci, mount, &pictures)
        });
    let sweep = sweep_text(&config.estimator, config.depth.width, config.depth.height);
    // Only a sweep's text ends in JUDGED: a model without the visibility term
    // (no frame sweeps a line) gets no count, rather than "0 of n".
    let sweep = match sweep.strip_suffix(JUDGED) {
        Some(how) => format!("{how}{}{JUDGED}", swept_every_line_text(&report.samples)),
        None => sweep,
    };
    Ok(SimOutcome {
        flight_dir,
        summary,
        report,
        plots,
        truth,
        truth_at_records,
        image_bytes,
        sim_commands,
        sim_triggers,
        sim_events_lost,
        sim_stats,
        sweep,
        camera_card,
    })
}

/// firmware-sim's camera's card of a flight, and how it paired with the manifest.
#[derive(Debug)]
pub struct CameraCard {
    pub dir: PathBuf,
    pub pictures: usize,
    /// The pairing and the `geo.txt` lines it gave, or why there was none.
    pub paired: Result<(crate::capture::external::Pairing, usize), String>,
}

fn camera_card(
    flight_dir: &Path,
    scene: &Scene,
    intrinsics: Intrinsics,
    mount_pitch_rad: f64,
    pictures: &[(u64, Truth)],
) -> CameraCard {
    use crate::capture::external::read_camera_dir;
    let dir = flight_dir.join(super::camera_card::CARD_DIR);
    let paired = super::camera_card::write_card(
        flight_dir,
        scene,
        intrinsics,
        mount_pitch_rad,
        pictures,
        crate::link::unix_us_at,
    )
    .and_then(|dir| read_camera_dir(&dir).map_err(|e| e.to_string()))
    .and_then(|card| {
        crate::capture::export_flight_with_camera(flight_dir, &card, None)
            .map_err(|e| e.to_string())
    })
    .map(|(done, pairing, _)| (pairing, done.exports.geo_lines));
    CameraCard {
        dir,
        pictures: pictures.len(),
        paired,
    }
}

/// What the truth judges a flight by: the quality model at the config's
/// targets, whatever model flies. Judged by its own model on exact depth, a
/// fixed or MMDS flight meets it by construction (`--model fixed` had 0
/// violations at any spacing), which says nothing of the promise the
/// operator set. Targets that leave the quality model nothing to bound
/// (parallax and forward overlap both off) give the default profile's.
pub(crate) fn judge_params(flown: &EstimatorParams) -> EstimatorParams {
    let judge = EstimatorParams {
        model: Model::Quality,
        ..flown.clone()
    };
    if judge.validate().is_ok() {
        return judge;
    }
    EstimatorParams {
        quality: Profile::default().targets(),
        ..judge
    }
}

/// The summary's `judged by` line for a flight of another model than the judge's.
fn judged_by(flown: &EstimatorParams, judge: &EstimatorParams) -> Option<String> {
    (flown.model != judge.model).then(|| {
        let t = &judge.quality;
        format!(
            "the {} targets ({}), by the quality model on the truth's depth; the {} model flew",
            t.profile.as_str(),
            crate::report::targets_text(
                t.parallax_px,
                t.forward_overlap,
                t.unseen_fraction_max,
                t.views_per_point_min
            ),
            flown.model.as_str()
        )
    })
}

/// How many estimated frames swept every line, where not all did (an
/// interleaved sweep: its first frame, and the frames whose lines tightened).
fn swept_every_line_text(samples: &[FrameSample]) -> String {
    let swept = samples.iter().filter(|s| !s.suspended);
    let (n, every) = swept.fold((0usize, 0usize), |(n, e), s| {
        (n + 1, e + s.swept_every_line as usize)
    });
    if every == n {
        String::new()
    } else {
        format!(" (every line on {every} of {n} frames)")
    }
}

/// True poses at the daemon's frame instants, with the distance flown along
/// the truth path; and the daemon's own estimates at the same places.
fn truth_track(
    scene: &Arc<Scene>,
    config: &Config,
    samples: &[FrameSample],
    truth_at: &dyn Fn(u64) -> Truth,
) -> (Vec<TruthPose>, Vec<DaemonSample>) {
    let intr = intrinsics(&config.depth).expect("validated when the run started");
    let mut tracker = TruthTracker::new(scene.clone(), intr, config.depth.mount_pitch_rad);
    samples
        .iter()
        .map(|s| {
            let pose = tracker.pose(s.mono_ns, &truth_at(s.mono_ns));
            let daemon = DaemonSample {
                along_m: pose.along_m,
                spacing_m: s.spacing_m,
                occlusion_degree: s.occlusion_degree,
            };
            (pose, daemon)
        })
        .unzip()
}

/// The true camera pose at each frame in turn, with the distance flown along
/// the truth path since the first.
struct TruthTracker {
    scene: Arc<Scene>,
    intr: Intrinsics,
    mount_pitch_rad: f64,
    along_m: f64,
    last: Option<[f64; 3]>,
}

impl TruthTracker {
    fn new(scene: Arc<Scene>, intr: Intrinsics, mount_pitch_rad: f64) -> TruthTracker {
        TruthTracker {
            scene,
            intr,
            mount_pitch_rad,
            along_m: 0.0,
            last: None,
        }
    }

    fn pose(&mut self, mono_ns: u64, tr: &Truth) -> TruthPose {
        if let Some(l) = self.last {
            self.along_m += (tr.pos_ned_m[0] - l[0]).hypot(tr.pos_ned_m[1] - l[1]);
        }
        self.last = Some(tr.pos_ned_m);
        let cp = scene_camera_pose(
            &self.scene,
            self.mount_pitch_rad,
            tr.pos_ned_m,
            tr.rpy_deg.map(f64::to_radians),
        );
        TruthPose {
            mono_ns,
            along_m: self.along_m,
            camera: cp.camera(self.intr),
            north_m: tr.pos_ned_m[0],
            east_m: tr.pos_ned_m[1],
        }
    }
}

/// Where each logged capture truly was, as distance along the truth path.
fn capture_positions(
    report: &RunReport,
    poses: &[TruthPose],
    truth_at: &dyn Fn(u64) -> Truth,
) -> Vec<CaptureAt> {
    report
        .records
        .iter()
        .map(|r| {
            // The truth sample at or before an instant, plus the way since it.
            let along_at = |mono_ns: u64| {
                let tr = truth_at(mono_ns);
                let k = poses.partition_point(|p| p.mono_ns <= mono_ns);
                let along = match k.checked_sub(1).and_then(|i| poses.get(i)) {
                    Some(p) => {
                        p.along_m + (tr.pos_ned_m[0] - p.north_m).hypot(tr.pos_ned_m[1] - p.east_m)
                    }
                    None => poses.first().map_or(0.0, |p| {
                        p.along_m - (tr.pos_ned_m[0] - p.north_m).hypot(tr.pos_ned_m[1] - p.east_m)
                    }),
                };
                (along, tr)
            };
            let (along, tr) = along_at(r.mono_ns);
            // A camera command's picture came after the decision (`picture_after_ms`).
            let decided_along_m = match r.picture_after_ms {
                Some(ms) if ms > 0.0 => along_at(r.mono_ns.saturating_sub((ms * 1e6) as u64)).0,
                _ => along,
            };
            CaptureAt {
                seq: r.seq,
                mono_ns: r.mono_ns,
                along_m: along,
                decided_along_m,
                north_m: tr.pos_ned_m[0],
                east_m: tr.pos_ned_m[1],
                undersampled: r.undersampled,
                rate_limited: r.rate_limited,
                fallback: r.fallback,
            }
        })
        .collect()
}

/// The way between two chances to capture (the summary's `step_limit_m`): a
/// depth frame's for alfd's own trigger; in `autopilot_distance` at least one
/// of the autopilot's distance checks (PX4 polls every 50 ms: 0.5 m at
/// 10 m/s), since it cannot fire between them whatever it was asked.
fn opportunity_step_m(args: &SimArgs, speed_mps: f64) -> f64 {
    let frame_m = speed_mps / args.fps;
    match args.mode {
        CaptureMode::AutopilotDistance => {
            let check_s = firmware_sim::trigger::check_period_ns(args.autopilot)
                .map_or(0.0, |ns| ns as f64 * 1e-9);
            frame_m.max(speed_mps * check_s)
        }
        _ => frame_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The summary's opportunity step: a frame's way, or in autopilot_distance
    /// one of the autopilot's checks where that is longer (PX4 at 10 m/s).
    #[test]
    fn an_autopilot_checking_less_often_than_frames_sets_the_opportunity_step() {
        use firmware_sim::Autopilot;
        let step = |mode, autopilot| {
            opportunity_step_m(
                &SimArgs {
                    mode,
                    autopilot,
                    fps: 30.0,
                    ..SimArgs::default()
                },
                10.0,
            )
        };
        let frame = 10.0 / 30.0;
        let d = CaptureMode::AutopilotDistance;
        assert!((step(d, Autopilot::Px4) - 0.5).abs() < 1e-12);
        assert_eq!(step(d, Autopilot::ArduPilot), frame);
        assert_eq!(step(d, Autopilot::Generic), frame);
        assert_eq!(step(CaptureMode::Frame, Autopilot::Px4), frame);
    }

    /// The bench sweeps every pixel: thinned, the district's views-per-point
    /// spacing came out up to 5.3x long (docs/performance.md).
    #[test]
    fn the_summary_says_how_the_estimator_sweeps() {
        let p = crate::core::EstimatorParams::default();
        let judged = JUDGED;
        let thinned = crate::core::EstimatorParams {
            visibility_interleave: 1,
            ..p.clone()
        };
        assert_eq!(
            sweep_text(&thinned, 640, 480),
            format!("one pixel in 2 both ways, every line on every frame{judged}")
        );
        // Decimation 2 at 640 × 480: 76,800 samples, a quarter of them a frame.
        let decimated = crate::core::EstimatorParams {
            decimation: crate::core::Decimation::Fixed(2),
            ..p.clone()
        };
        assert_eq!(
            sweep_text(&decimated, 640, 480),
            format!("one pixel in 2 both ways, one line in 4 a frame, the others' newest sweeps kept, the views bound's shortest interval held 8 frames, every line when a frame's own lines tighten and the lines beside the shortest interval on every frame{judged}")
        );
        let unrefreshed = crate::core::EstimatorParams {
            visibility_refresh: false,
            ..decimated.clone()
        };
        assert_eq!(
            sweep_text(&unrefreshed, 640, 480),
            format!("one pixel in 2 both ways, one line in 4 a frame, the others' newest sweeps kept, the views bound's shortest interval held 8 frames{judged}")
        );
        let auto = crate::core::EstimatorParams {
            decimation: crate::core::Decimation::auto(),
            ..p.clone()
        };
        assert!(sweep_text(&auto, 640, 480).starts_with("at the level decimation \"auto\" takes"));
        let mmds = crate::core::EstimatorParams::with_model(Model::Mmds);
        assert_eq!(
            sweep_text(&mmds, 640, 480),
            "none (the quality model's term)"
        );
    }

    #[test]
    fn the_summary_counts_the_frames_that_swept_every_line() {
        let frame = |suspended, swept_every_line| FrameSample {
            suspended,
            swept_every_line,
            ..FrameSample::default()
        };
        let all = [frame(false, true), frame(true, false), frame(false, true)];
        assert_eq!(swept_every_line_text(&all), "");
        assert_eq!(swept_every_line_text(&[]), "");
        let some = [
            frame(false, true),
            frame(false, false),
            frame(true, false),
            frame(false, false),
            frame(false, true),
        ];
        assert_eq!(
            swept_every_line_text(&some),
            " (every line on 2 of 4 frames)"
        );
    }

    #[test]
    fn the_sim_config_sweeps_every_pixel() {
        let scene_path = Path::new("scenes/district.toml");
        let scene = Scene::load(scene_path).expect("the default scene loads");
        for (width, height) in [(640, 480), (848, 480), (1280, 720), (4, 3)] {
            let a = SimArgs {
                width,
                height,
                ..SimArgs::default()
            };
            let text = sim_config_text(&a, scene_path, Path::new("/tmp/flight"), &scene);
            let config = crate::config::Config::from_text(&text, "sim").expect("it validates");
            let samples = config.estimator.visibility_samples_max;
            assert!(samples >= width * height, "{width}x{height}: {samples}");
            assert_eq!(config.estimator.visibility_interleave, 1);
            // `--sweep flight`: the daemon's own defaults.
            let flight = SimArgs {
                sweep: SimSweep::Flight,
                ..a
            };
            let text = sim_config_text(&flight, scene_path, Path::new("/tmp/flight"), &scene);
            assert_eq!(
                sweep_text(&config.estimator, width, height),
                "every pixel, every line on every frame; judged against every pixel of every frame"
            );
            let config = crate::config::Config::from_text(&text, "sim").expect("it validates");
            let defaults = crate::core::EstimatorParams::default();
            assert_eq!(
                (
                    config.estimator.visibility_samples_max,
                    config.estimator.visibility_interleave,
                    config.estimator.visibility_refresh
                ),
                (
                    defaults.visibility_samples_max,
                    defaults.visibility_interleave,
                    defaults.visibility_refresh
                )
            );
            // A quarter of the lines a frame: every pixel of them up to
            // 80,000 samples; beyond, fewer lines (a sixth at 848 × 480), and
            // more coarsely past one in 8.
            let (pixels, lines, held) = match (width, height) {
                (1280, 720) => ("one pixel in 2 both ways", 4, 8),
                (848, 480) => ("every pixel", 6, 12),
                _ => ("every pixel", 4, 8),
            };
            assert_eq!(
                sweep_text(&config.estimator, width, height),
                format!(
                    "{pixels}, one line in {lines} a frame, the others' newest sweeps kept, the views bound's shortest interval held {held} frames, every line when a frame's own lines tighten and the lines beside the shortest interval on every frame; judged against every pixel of every frame"
                )
            );
            assert_eq!(
                crate::core::estimate::visibility_step(width * height, 1, samples),
                1
            );
        }
    }
}
