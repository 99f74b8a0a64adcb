//! `alfd sim`: the daemon on the simulated autopilot over a synthetic scene,
//! judged against the truth (feature `sim`).

use super::{bad, emit, frame_size, runtime, termination, QualityFlags};
use alfd::capture::external::PairedBy;
use alfd::capture::CaptureMode;
use alfd::config::SimPose;
use alfd::core::Model;
use alfd::daemon::sim::{run_sim, run_sim_on_simulated_time, SimArgs, SimHooks, SimSweep};
use anyhow::Result;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// Scene file (default: the built-in district, scenes/district.toml).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Start from this daemon config (its link address is replaced).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output directory: each run writes a new flight-NNN in it.
    #[arg(long, default_value = "sim-out")]
    out: PathBuf,
    // Negative numbers are taken as values, so that the check below names
    // the flag (not clap's "unexpected argument").
    /// Ground speed along the survey (default: the scene's `survey.speed_mps`, 10 m/s
    /// for the built-in district).
    #[arg(long, allow_negative_numbers = true)]
    speed_mps: Option<f64>,
    /// Position and attitude stream rate, Hz [default: 10; with --config, its
    /// [mavlink] position_hz and attitude_hz].
    #[arg(long, allow_negative_numbers = true)]
    telemetry_hz: Option<f64>,
    /// Depth (and colour) frames per second [default: 30; with --config, its [depth] fps].
    #[arg(long, allow_negative_numbers = true)]
    fps: Option<f64>,
    /// Frame width, px [default: 640; with --config, its [depth] width].
    #[arg(long)]
    width: Option<usize>,
    /// Frame height, px [default: 480; with --config, its [depth] height].
    #[arg(long)]
    height: Option<usize>,
    /// How captures are taken [default: frame; with --config, its [capture] mode].
    #[arg(long, value_enum)]
    mode: Option<CaptureMode>,
    /// The sampling model (default: quality; over a --config's).
    #[arg(long, value_parser = super::model_parser())]
    model: Option<Model>,
    #[command(flatten)]
    quality: QualityFlags,
    /// Also measure each frame against the last capture ([trigger] closed_loop).
    #[arg(long)]
    closed_loop: bool,
    /// How the estimator sweeps the visibility term: every pixel of every
    /// frame, or the flight's defaults (a quarter of the lines a frame); the
    /// truth sweeps every pixel either way [default: every-pixel; with --config,
    /// its [estimator] settings].
    #[arg(long, value_enum)]
    sweep: Option<SimSweep>,
    /// Where the synthetic camera renders [default: truth; with --config, its [sim] pose].
    #[arg(long, value_enum)]
    pose: Option<SimPose>,
    /// Forward MAVLink to a ground station: udpout:HOST:PORT.
    #[arg(long)]
    gcs: Option<String>,
    /// Fly only this much of the line (metres, at most the scene's line); with
    /// --lanes, each lane's length.
    #[arg(long, allow_negative_numbers = true)]
    length_m: Option<f64>,
    /// Fly this many parallel lanes back and forth (a lawnmower: what a
    /// reconstruction wants; one strip leaves lateral position against roll).
    #[arg(long, default_value_t = 1)]
    lanes: u32,
    /// East of the previous lane, metres (with --lanes).
    #[arg(long, default_value_t = 40.0, allow_negative_numbers = true)]
    lane_spacing_m: f64,
    /// Whose behaviour firmware-sim copies where the capture depends on it:
    /// its HEARTBEAT and its distance trigger (generic: fires at the point;
    /// px4: a new distance shoots once, checked every 50 ms; ardupilot:
    /// counted from the last picture, checked at 50 Hz, each picture said by
    /// CAMERA_FEEDBACK alone, as its servo or relay camera does). The flight
    /// itself is the same.
    #[arg(long, value_enum, default_value_t = SimAutopilot::Generic)]
    autopilot: SimAutopilot,
    #[arg(long)]
    no_progress: bool,
    /// Fly in real time over a pseudo-terminal, as on the bench (needed by --gcs and
    /// --pose telemetry). Default: simulated time, as fast as the machine renders, the
    /// same flight every run.
    #[arg(long)]
    real_time: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum SimAutopilot {
    Generic,
    Px4,
    Ardupilot,
}

pub fn run(a: Args) -> Result<ExitCode> {
    // A given config is the flight's: a flag it would silently override (or be
    // overridden by) is refused by name, with the key that sets it.
    if let Some(c) = &a.config {
        let set = [
            (
                "--telemetry-hz",
                a.telemetry_hz.is_some(),
                "[mavlink] position_hz and attitude_hz",
            ),
            ("--fps", a.fps.is_some(), "[depth] fps and [camera] fps"),
            (
                "--width",
                a.width.is_some(),
                "[depth] width and [camera] width",
            ),
            (
                "--height",
                a.height.is_some(),
                "[depth] height and [camera] height",
            ),
            ("--mode", a.mode.is_some(), "[capture] mode"),
            (
                "--sweep",
                a.sweep.is_some(),
                "[estimator] visibility_samples_max and visibility_interleave",
            ),
            ("--pose", a.pose.is_some(), "[sim] pose"),
        ];
        if let Some((flag, _, key)) = set.iter().find(|s| s.1) {
            return Err(bad(format!(
                "{flag}: with --config {}, this is the config's {key}: edit the config, or leave --config out",
                c.display()
            )));
        }
    }
    let quality = a.quality.patch()?;
    let model = a.model;
    let telemetry_hz = a.telemetry_hz.unwrap_or(10.0);
    let fps = a.fps.unwrap_or(30.0);
    let (width, height) = (a.width.unwrap_or(640), a.height.unwrap_or(480));
    for (name, v, max) in [
        ("--speed-mps", a.speed_mps, 50.0),
        ("--telemetry-hz", Some(telemetry_hz), 1000.0),
        ("--fps", Some(fps), 240.0),
    ] {
        let Some(v) = v else { continue };
        if !(v.is_finite() && v > 0.0 && v <= max) {
            return Err(bad(format!(
                "{name} {v}: must be positive and at most {max}"
            )));
        }
    }
    if !(1..=20).contains(&a.lanes) {
        return Err(bad(format!("--lanes {}: must be 1 to 20", a.lanes)));
    }
    if !(a.lane_spacing_m.is_finite() && a.lane_spacing_m > 0.0 && a.lane_spacing_m <= 1000.0) {
        return Err(bad(format!(
            "--lane-spacing-m {}: must be positive and at most 1000",
            a.lane_spacing_m
        )));
    }
    if let Some(l) = a.length_m {
        if !(l.is_finite() && l > 0.0) {
            return Err(bad(format!(
                "--length-m {l}: must be a positive number of metres"
            )));
        }
    }
    frame_size(width, height)?;
    let args = SimArgs {
        scene: a.scene,
        config: a.config,
        out: a.out,
        speed_mps: a.speed_mps,
        telemetry_hz,
        fps,
        width,
        height,
        mode: a.mode.unwrap_or(CaptureMode::Frame),
        model,
        quality,
        closed_loop: a.closed_loop,
        sweep: a.sweep.unwrap_or_default(),
        pose: a.pose.unwrap_or(SimPose::Truth),
        gcs: a.gcs,
        progress: !a.no_progress && std::io::stderr().is_terminal(),
        length_m: a.length_m,
        lanes: a.lanes,
        lane_spacing_m: a.lane_spacing_m,
        autopilot: match a.autopilot {
            SimAutopilot::Generic => firmware_sim::Autopilot::Generic,
            SimAutopilot::Px4 => firmware_sim::Autopilot::Px4,
            SimAutopilot::Ardupilot => firmware_sim::Autopilot::ArduPilot,
        },
        seed: 1,
        faults: None,
        depth_outages: Vec::new(),
    };
    let started = std::time::Instant::now();
    let out = if a.real_time {
        let rt = runtime()?;
        let out = rt.block_on(run_sim(args, termination()));
        rt.shutdown_timeout(std::time::Duration::from_millis(200));
        out
    } else {
        run_sim_on_simulated_time(args, SimHooks::default(), termination())
    }
    .map_err(|e| match e {
        alfd::daemon::sim::SimRunError::Setup(m) => bad(m),
        other => anyhow::Error::from(other),
    })?;
    let r = &out.report;
    let mut text = String::new();
    // The CPU beside the wall time: on a shared machine the wall time of the same
    // flight varies by a third (docs/performance.md); CPU over wall time says how
    // busy the cores were, and so whether the flight or the machine was slow.
    text.push_str(&format!(
        "alfd sim: {} in {:.0} s, {:.0} s of CPU\n",
        out.flight_dir.display(),
        started.elapsed().as_secs_f64(),
        process_cpu_s()
    ));
    text.push_str(out.summary.render_text().trim_end());
    text.push('\n');
    text.push_str(&format!(
        "depth frames    {} ({} missed by the source, {} skipped while the estimator was busy, {} bad), estimator {:.1} ms per frame\n",
        r.depth_frames,
        r.frames_missed_by_source,
        r.frames_skipped_busy,
        r.frames_bad,
        r.estimator_busy_ns as f64 * 1e-6 / r.samples.len().max(1) as f64
    ));
    text.push_str(&format!("sweep           {}\n", out.sweep));
    // A capture logged without its image says so in the manifest; the summary counts them,
    // so a loaded machine's lost images are not a surprise at reconstruction.
    let with_image = r.records.iter().filter(|c| c.image.is_some()).count();
    let without: Vec<&str> = r
        .records
        .iter()
        .filter_map(|c| c.image_missing.as_deref())
        .collect();
    if with_image + without.len() > 0 {
        text.push_str(&format!(
            "images saved    {with_image} of {} captures{}\n",
            r.records.len(),
            if without.is_empty() {
                String::new()
            } else {
                format!(
                    "; {} logged without their image (e.g. \"{}\")",
                    without.len(),
                    without[0]
                )
            }
        ));
    }
    if let Some(card) = &out.camera_card {
        text.push_str(&format!(
            "camera card     {} pictures by firmware-sim's camera in {}",
            card.pictures,
            card.dir.display()
        ));
        match &card.paired {
            Ok((p, geo_lines)) => {
                let how = match p.by {
                    PairedBy::Order { checked: true } => "in order, their times agreeing",
                    PairedBy::Order { checked: false } => "in order",
                    PairedBy::Time => "by time",
                };
                let clock = p.camera_ahead_of_utc_s.map_or(String::new(), |s| {
                    format!(", its clock {s:.2} s ahead of UTC")
                });
                text.push_str(&format!(
                    "{clock}: {} of {} captures paired {how}; geo.txt names {geo_lines} (alfd export --images)\n",
                    p.pairs.len(),
                    p.pairs.len() + p.unpaired_captures.len(),
                ));
            }
            Err(e) => text.push_str(&format!(": not paired: {e}\n")),
        }
    }
    if let Some(l) = &r.latency {
        text.push_str(&format!("answered        {l}\n"));
    }
    if r.camera_commands > 0 {
        text.push_str(&format!("camera cmd      {}\n", r.pictures_text()));
    }
    // The autopilot's own trigger: how often alfd had to move its distance.
    if r.trigger_distances_sent > 0 {
        text.push_str(&format!(
            "trigger dist    {} DO_SET_CAM_TRIGG_DIST sent ({} also triggering once), {} acknowledged, {} autopilot triggers{}\n",
            r.trigger_distances_sent,
            r.trigger_distances_with_picture,
            r.trigger_distances_acked,
            r.autopilot_triggers,
            r.feedbacks_text()
        ));
    }
    text.push_str(&format!(
        "images          {:.1} MB, telemetry.tlog {} messages, exports: geo.txt {} lines, transforms.json and the COLMAP model {} frames\n",
        out.image_bytes as f64 / 1e6,
        r.tlog_frames,
        // The card's pictures, once paired, are geo.txt's lines.
        match out.camera_card.as_ref().map(|c| &c.paired) {
            Some(Ok((_, lines))) => *lines,
            _ => r.exports.as_ref().map_or(0, |e| e.geo_lines),
        },
        r.exports.as_ref().and_then(|e| e.transform_frames).unwrap_or(0),
    ));
    for (name, ok, line) in out.summary.targets() {
        text.push_str(&format!(
            "target          {:<28} {:<7} {line}\n",
            name,
            if ok { "met" } else { "NOT met" }
        ));
    }
    for p in &out.plots {
        text.push_str(&format!("plot            {}\n", p.display()));
    }
    for e in &r.capture_errors {
        text.push_str(&format!("error           {e}\n"));
    }
    emit(&text)?;
    Ok(ExitCode::SUCCESS)
}

/// CPU seconds of this process so far, every thread's, user and system (the kernel's
/// process CPU clock, as `alfd-clock` reads the monotonic one).
fn process_cpu_s() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}
