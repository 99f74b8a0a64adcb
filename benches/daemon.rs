//! The daemon's load at 30 fps 640×480 depth (issue 6: < 25 % of one core,
//! RSS < 40 MB): the real `alfd run` as a child process against firmware-sim
//! over a pty, fed by a live replay of a recording rendered along the default
//! scene's line. Its CPU and memory are read from /proc once a second after a
//! warm-up; the same daemon with `model = "fixed"` (no estimator work) is the
//! baseline measured in the same run, as this machine is shared and noisy.
//! Then the stages one frame costs, timed in this process, to explain the sum.
//!
//! Run: `cargo bench --bench daemon` (`ALFD_BENCH_SECONDS`, default 30, is the
//! measured window of each run; 600 for the soak; `ALFD_BENCH_SIZE=848x480` and
//! `ALFD_BENCH_DECIMATION=N` for another frame size and stride; `ALFD_BENCH_COLOUR=mjpeg`
//! for an MJPEG camera's frames and `ALFD_BENCH_KEEP_JPEG=0` to re-encode them). Writes
//! `target/bench-daemon.json`.

use alfd::capture::{encode_capture, read_manifest, ImageFormat};
use alfd::config::Config;
use alfd::core::{Estimator, Intrinsics};
use alfd::daemon::sim::DEFAULT_SCENE;
use alfd::render::{render, Camera, RenderOptions, SensorModel};
use alfd::scene::Scene;
use alfd::source::decode::{mjpeg_to_rgb, yuyv_to_rgb};
use alfd::source::recorded::{Recorder, Recording, RecordingMeta};
use alfd::source::{ColorImage, DepthSource, FrameSource};
use firmware_sim::{SimConfig, Transport};
use serde_json::json;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Frame size of both streams: `ALFD_BENCH_SIZE=WIDTHxHEIGHT`, default 640x480 (848x480
/// is the D4xx's native depth mode).
fn size() -> (usize, usize) {
    let Ok(v) = std::env::var("ALFD_BENCH_SIZE") else {
        return (640, 480);
    };
    v.split_once('x')
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .filter(|&(w, h): &(usize, usize)| w >= 16 && h >= 16)
        .unwrap_or_else(|| panic!("ALFD_BENCH_SIZE={v}: want WIDTHxHEIGHT, e.g. 848x480"))
}

/// `[estimator] decimation` of both daemons: `ALFD_BENCH_DECIMATION=N` (default: the
/// config's default, full resolution).
fn decimation_line() -> String {
    std::env::var("ALFD_BENCH_DECIMATION")
        .ok()
        .map(|n| {
            let n: u64 = n
                .parse()
                .unwrap_or_else(|_| panic!("ALFD_BENCH_DECIMATION={n}: want a stride"));
            format!("\n[estimator]\ndecimation = {n}\n")
        })
        .unwrap_or_default()
}
/// How the recording holds its colour frames: `ALFD_BENCH_COLOUR=png` (default: decoded
/// on every replayed frame, a bench cost) or `mjpeg` (an MJPEG camera's buffers, without
/// Huffman tables as many UVC cameras send them; kept raw until captured).
fn colour_is_mjpeg() -> bool {
    match std::env::var("ALFD_BENCH_COLOUR").as_deref() {
        Err(_) | Ok("png") => false,
        Ok("mjpeg") => true,
        Ok(v) => panic!("ALFD_BENCH_COLOUR={v}: want png or mjpeg"),
    }
}

/// `[capture] keep_camera_jpeg` of both daemons: `ALFD_BENCH_KEEP_JPEG=0` re-encodes an
/// MJPEG camera's frames (default 1, the config's default: stored as they came).
fn keep_camera_jpeg() -> bool {
    env_u64("ALFD_BENCH_KEEP_JPEG", 1) != 0
}

const FRAMES: usize = 90;
const STEP_M: f64 = 0.333;
const PERIOD_NS: u64 = 33_333_333;
/// 1 cm per Z16 unit: 1 mm saturates at 65.5 m and the scene is flown at 100 m.
const SCALE_M: f64 = 0.01;
const WARM_UP: Duration = Duration::from_secs(5);
/// `WatchdogSec=5` in systemd/alfd.service, as systemd passes it.
const WATCHDOG_USEC: u64 = 5_000_000;

/// Telemetry stream rate, Hz, of each of the three pose streams
/// (`ALFD_BENCH_TELEMETRY_HZ`; 700 gives the soak's 2,000+ messages/s).
fn telemetry_hz() -> f64 {
    env_u64("ALFD_BENCH_TELEMETRY_HZ", 10).max(1) as f64
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// The recording: `FRAMES` views 0.333 m apart at the survey altitude, centred
/// on the district's 45 m tower (x = 0), the line's most occluded stretch.
/// Returns the length flown (m).
fn render_recording(scene: &Scene, dir: &Path) -> f64 {
    let s = &scene.survey;
    let (w, h) = size();
    let intr = Intrinsics::from_hfov_deg(w, h, s.hfov_deg, None).expect("a valid field of view");
    let (cx_px, cy_px) = intr.principal_px();
    let meta = RecordingMeta {
        width: w,
        height: h,
        focal_px: intr.focal_px(),
        cx_px,
        cy_px,
        depth_scale_m: SCALE_M,
    };
    let sensor = SensorModel {
        scale_m: SCALE_M,
        max_range_m: 3.0 * s.altitude_m,
        ..SensorModel::default()
    };
    let mut rec = Recorder::create(dir, meta).expect("the recording directory is writable");
    let length_m = FRAMES as f64 * STEP_M;
    let x0 = -0.5 * length_m;
    for i in 0..FRAMES {
        let camera = Camera {
            position_m: [x0 + i as f64 * STEP_M, s.y_m, s.altitude_m],
            roll_rad: 0.0,
            pitch_rad: s.pitch_rad,
            yaw_rad: 0.0,
            intrinsics: intr,
        };
        let frame = render(scene, &camera, &RenderOptions { supersample: 1 });
        let color = ColorImage {
            width: w,
            height: h,
            rgb: frame.rgb8(),
        };
        let t = 1_000_000_000 + i as u64 * PERIOD_NS;
        let depth = frame.z16(&sensor);
        if colour_is_mjpeg() {
            let (jpeg, _) = encode_capture(
                &color.rgb,
                w as u32,
                h as u32,
                ImageFormat::Jpeg { quality: 90 },
                None,
            )
            .expect("a JPEG");
            let uvc = alfd::capture::jpeg::without_huffman_tables(&jpeg);
            rec.push_mjpeg(i as u64 + 1, t, Some(&depth), &uvc)
        } else {
            rec.push(i as u64 + 1, t, Some(&depth), Some(&color))
        }
        .expect("a frame is recorded");
    }
    length_m
}

fn config_text(address: &str, recording: &Path, captures: &Path, model: &str) -> String {
    let hz = telemetry_hz();
    let (w, h) = size();
    let decimation = decimation_line();
    format!(
        r#"[mavlink]
address = "{address}"
system_id = 1
component_id = 100
accept_system_ids = [1, 255]
position_hz = {hz}
attitude_hz = {hz}

[camera]
source = "recorded"
dir = {recording:?}
replay = "live"
width = {w}
height = {h}
fps = 30.0

[depth]
source = "recorded"
dir = {recording:?}
replay = "live"
width = {w}
height = {h}
fps = 30.0
hfov_deg = 69.0
scale_m = {SCALE_M}

[sampling]
model = "{model}"
{decimation}
[trigger]
rate_max_hz = 30.0
fallback_spacing_m = 1.0

[capture]
dir = {captures:?}
mode = "frame"
image_format = "jpeg"
jpeg_quality = 90
keep_camera_jpeg = {keep}
"#,
        keep = keep_camera_jpeg(),
    )
}

/// User and system CPU of a process, seconds.
fn cpu_parts_s(pid: u32, tick_hz: f64) -> Option<(f64, f64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces): state is field 3,
    // utime and stime fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |k: usize| f.get(k)?.parse::<f64>().ok();
    Some((ticks(11)? / tick_hz, ticks(12)? / tick_hz))
}

/// (VmRSS, VmHWM) of a process, MiB.
fn memory_mib(pid: u32) -> Option<(f64, f64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kib = |key: &str| -> Option<f64> {
        let line = status.lines().find(|l| l.starts_with(key))?;
        line.split_whitespace().nth(1)?.parse().ok()
    };
    Some((kib("VmRSS:")? / 1024.0, kib("VmHWM:")? / 1024.0))
}

fn manifest_lines(captures: &Path) -> usize {
    let path = captures.join("flight-001").join("manifest.jsonl");
    std::fs::read(path).map_or(0, |b| b.iter().filter(|&&c| c == b'\n').count())
}

/// One daemon run's figures.
#[derive(Debug, Default)]
struct RunFigures {
    model: String,
    cpu_mean_pct: f64,
    /// Of `cpu_mean_pct`, in the kernel (writes, the pty, timers).
    cpu_system_pct: f64,
    cpu_max_pct: f64,
    cpu_per_second_pct: Vec<f64>,
    rss_warm_mib: f64,
    rss_end_mib: f64,
    hwm_mib: f64,
    exit_ms: f64,
    exit_code: Option<i32>,
    /// systemd's watchdog as the unit sets it (`WatchdogSec=5`): the longest time between
    /// two WATCHDOG=1 (READY=1 and STOPPING=1 count as the ends), and how many came.
    watchdog_longest_gap_ms: f64,
    watchdog_pets: usize,
    captures_in_window: usize,
    captures_total: usize,
    images: usize,
    /// Median permissible and chosen spacing of the captures (m), and how
    /// many came at the fallback spacing.
    permissible_median_m: Option<f64>,
    chosen_median_m: Option<f64>,
    fallback_captures: usize,
    depth_frames: Option<u64>,
    skipped_busy: Option<u64>,
    bad: Option<u64>,
    lifetime_s: f64,
    stopped_line: Option<String>,
    /// What firmware-sim sent during the measured window, messages/s.
    telemetry_msgs_per_s: f64,
}

/// The numbers of the daemon's last words: "stopped: N captures in DIR, M
/// depth frames (K skipped while busy, B bad), E errors".
fn parse_stopped(line: &str) -> Option<(u64, u64, u64)> {
    let after = |key: &str| -> Option<u64> {
        let i = line.find(key)?;
        line[..i]
            .split_whitespace()
            .last()?
            .trim_start_matches('(')
            .parse()
            .ok()
    };
    Some((
        after(" depth frames")?,
        after(" skipped while busy")?,
        after(" bad)")?,
    ))
}

fn run_daemon(
    rt: &tokio::runtime::Runtime,
    tmp: &Path,
    recording: &Path,
    length_m: f64,
    altitude_m: f64,
    model: &str,
    secs: u64,
) -> RunFigures {
    // A fresh simulator per run, so both runs see the same flight from its start.
    let mut sc = SimConfig {
        transport: Transport::Pty {
            link: Some(tmp.join(format!("ttyFC-{model}"))),
        },
        ..SimConfig::default()
    };
    // A lawnmower long enough for the whole run: the vehicle keeps flying
    // (and the trigger keeps capturing) instead of hovering at a line's end.
    sc.survey.pattern = firmware_sim::Pattern::Lawnmower;
    sc.survey.lane_spacing_m = 10.0;
    sc.survey.lanes = (((secs as f64 + 10.0) * 10.0 / length_m.max(1.0)).ceil() as u32 + 2).max(2);
    sc.survey.altitude_m = altitude_m;
    sc.survey.heading_deg = 0.0;
    sc.survey.length_m = length_m;
    sc.survey.speed_mps = 10.0;
    sc.survey.wind_m = 0.0;
    sc.survey.wind_deg = 0.0;
    let hz = telemetry_hz();
    sc.streams.attitude_quaternion = hz;
    sc.streams.global_position_int = hz;
    sc.streams.local_position_ned = hz;
    let sim = rt
        .block_on(firmware_sim::start(sc))
        .expect("firmware-sim starts");

    let captures = tmp.join(format!("captures-{model}"));
    let config_path = tmp.join(format!("alfd-{model}.toml"));
    let text = config_text(sim.address(), recording, &captures, model);
    Config::from_text(&text, &config_path.display().to_string())
        .expect("the bench's daemon config is valid");
    std::fs::write(&config_path, &text).expect("the config is written");

    // systemd's side of sd_notify, with the unit's watchdog: each datagram stamped on arrival.
    let notify_path = tmp.join(format!("notify-{model}.sock"));
    let notify_sock = std::os::unix::net::UnixDatagram::bind(&notify_path).expect("a socket");
    notify_sock
        .set_read_timeout(Some(Duration::from_millis(100)))
        .expect("a read timeout");
    let notify_stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let notify_log = {
        let stop = notify_stop.clone();
        std::thread::spawn(move || {
            let (mut got, mut buf) = (Vec::new(), [0u8; 4096]);
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(n) = notify_sock.recv(&mut buf) {
                    let at = Instant::now();
                    for line in String::from_utf8_lossy(&buf[..n]).lines() {
                        got.push((at, line.to_owned()));
                    }
                }
            }
            got
        })
    };

    let started = Instant::now();
    let mut child: Child = Command::new(env!("CARGO_BIN_EXE_alfd"))
        .args(["run", "--config"])
        .arg(&config_path)
        .env("NOTIFY_SOCKET", &notify_path)
        .env("WATCHDOG_USEC", WATCHDOG_USEC.to_string())
        .env_remove("WATCHDOG_PID")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("alfd starts");
    let pid = child.id();
    let stderr = child.stderr.take().expect("stderr is piped");
    let log = std::thread::spawn(move || {
        BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
            .collect::<Vec<String>>()
    });

    // SAFETY: sysconf reads a constant of the system; no memory of ours.
    let tick_hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    std::thread::sleep(WARM_UP);
    let mut f = RunFigures {
        model: model.to_string(),
        ..RunFigures::default()
    };
    let (rss, _) = memory_mib(pid).expect("the daemon is running after the warm-up");
    f.rss_warm_mib = rss;
    let captures_warm = manifest_lines(&captures);
    let sent_warm = sim.stats().frames_sent;
    let t0 = Instant::now();
    // (when, user + system, system): one read of /proc/pid/stat each.
    let (user, system) = cpu_parts_s(pid, tick_hz).expect("the daemon's /proc/pid/stat");
    let mut last = (t0, user + system, system);
    let first = last;
    for k in 1..=secs {
        let due = t0 + Duration::from_secs(k);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        let Some((user, system)) = cpu_parts_s(pid, tick_hz) else {
            eprintln!("daemon/{model}: the daemon exited early");
            break;
        };
        let cpu = user + system;
        let now = Instant::now();
        f.cpu_per_second_pct
            .push(100.0 * (cpu - last.1) / (now - last.0).as_secs_f64());
        last = (now, cpu, system);
        if let Some((rss, hwm)) = memory_mib(pid) {
            f.rss_end_mib = rss;
            f.hwm_mib = hwm;
        }
    }
    let window_s = (last.0 - t0).as_secs_f64().max(1e-9);
    f.cpu_mean_pct = 100.0 * (last.1 - first.1) / window_s;
    f.cpu_system_pct = 100.0 * (last.2 - first.2) / window_s;
    f.cpu_max_pct = f.cpu_per_second_pct.iter().copied().fold(0.0, f64::max);
    f.captures_in_window = manifest_lines(&captures).saturating_sub(captures_warm);
    f.telemetry_msgs_per_s =
        (sim.stats().frames_sent - sent_warm) as f64 / (last.0 - t0).as_secs_f64().max(1e-9);

    // SAFETY: kill sends a signal to the child we started, by its id.
    unsafe { libc::kill(pid as libc::pid_t, libc::SIGTERM) };
    let term = Instant::now();
    f.lifetime_s = (term - started).as_secs_f64();
    let status = loop {
        if let Some(s) = child.try_wait().expect("waiting for the daemon") {
            break s;
        }
        if term.elapsed() > Duration::from_secs(20) {
            eprintln!("daemon/{model}: no exit 20 s after SIGTERM; killing it");
            let _ = child.kill();
            break child.wait().expect("waiting for the daemon");
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    f.exit_ms = term.elapsed().as_secs_f64() * 1e3;
    f.exit_code = status.code();
    notify_stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let notes = notify_log.join().unwrap_or_default();
    let pets: Vec<Instant> = notes
        .iter()
        .filter(|(_, t)| matches!(t.as_str(), "READY=1" | "WATCHDOG=1" | "STOPPING=1"))
        .map(|(at, _)| *at)
        .collect();
    f.watchdog_pets = notes.iter().filter(|(_, t)| t == "WATCHDOG=1").count();
    f.watchdog_longest_gap_ms = pets
        .windows(2)
        .map(|w| (w[1] - w[0]).as_secs_f64() * 1e3)
        .fold(f64::NAN, f64::max);
    let lines = log.join().unwrap_or_default();
    f.stopped_line = lines.iter().rev().find(|l| l.contains("stopped:")).cloned();
    if let Some((d, s, b)) = f.stopped_line.as_deref().and_then(parse_stopped) {
        (f.depth_frames, f.skipped_busy, f.bad) = (Some(d), Some(s), Some(b));
    }
    if f.stopped_line.is_none() || !status.success() {
        eprintln!("daemon/{model}: exit {status}; its last log lines:");
        for l in lines.iter().rev().take(10).rev() {
            eprintln!("  {l}");
        }
    }
    if let Ok(m) = read_manifest(&captures.join("flight-001").join("manifest.jsonl")) {
        f.captures_total = m.records.len();
        f.images = m.records.iter().filter(|r| r.image.is_some()).count();
        // A capture without its image says why: the first few reasons, so a short count
        // in the table can be read.
        for r in m.records.iter().filter(|r| r.image.is_none()).take(5) {
            eprintln!(
                "daemon/{model}: capture {} without its image: {}",
                r.seq,
                r.image_missing.as_deref().unwrap_or("no reason given")
            );
        }
        f.fallback_captures = m.records.iter().filter(|r| r.fallback).count();
        let median = |v: Vec<f64>| (!v.is_empty()).then(|| median(v));
        f.permissible_median_m = median(
            m.records
                .iter()
                .filter_map(|r| r.spacing.permissible_m)
                .collect(),
        );
        f.chosen_median_m = median(m.records.iter().map(|r| r.spacing.chosen_m).collect());
    }
    rt.block_on(sim.shutdown());
    f
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// What one frame costs in this process, stage by stage (median ms over the
/// recording): the depth read + decode, the colour PNG read + decode, the
/// estimate with the daemon's parameters, one capture's JPEG encoding, and
/// what a V4L2 colour frame would cost instead of the PNG. The estimate also
/// as its mean, which is what it costs a core: a flight's frames are not alike
/// (one in `visibility_interleave` sweeps a class of lines, a frame whose lines
/// tightened sweeps every line), and the median is the cheap kind.
fn stage_costs(recording: &Path, config_text: &str) -> serde_json::Value {
    let (w, h) = size();
    let config = Config::from_text(config_text, "bench").expect("valid");
    let mut rec = Recording::open(recording).expect("the recording opens");
    let intr = rec.intrinsics();
    let (mut depth_ms, mut est_ms) = (Vec::new(), Vec::new());
    let mut est = Estimator::new(config.estimator.clone());
    loop {
        let t = Instant::now();
        let Some(f) = rec.next_depth().expect("a depth frame") else {
            break;
        };
        depth_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        let _ = std::hint::black_box(est.estimate(&f.data, &intr, 0.0));
        est_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let (mut color_ms, mut jpeg_ms) = (Vec::new(), Vec::new());
    let (mut read_ms, mut keep_ms) = (Vec::new(), Vec::new());
    let mut rec = Recording::open(recording).expect("the recording opens");
    loop {
        let t = Instant::now();
        let Some(f) = rec.next_frame().expect("a colour frame") else {
            break;
        };
        read_ms.push(t.elapsed().as_secs_f64() * 1e3);
        if let alfd::source::RawColor::Mjpeg(b) = &f.data {
            // What keeping a captured frame as it came costs instead of the two below.
            let t = Instant::now();
            std::hint::black_box(alfd::capture::jpeg::as_received(b, |_, _| None).expect("whole"));
            keep_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        // What a capture costs to decode (the daemon decodes captured frames only).
        let t = Instant::now();
        let f = f.data.decode().expect("the recorded frame decodes");
        color_ms.push(t.elapsed().as_secs_f64() * 1e3);
        if jpeg_ms.len() < 10 {
            let t = Instant::now();
            let _ = std::hint::black_box(encode_capture(
                &f.rgb,
                w as u32,
                h as u32,
                ImageFormat::Jpeg { quality: 90 },
                None,
            ));
            jpeg_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    // What the colour stream costs from a V4L2 camera instead: an MJPEG
    // frame (one of ours, encoded) or a YUYV frame into RGB.
    let mut rec = Recording::open(recording).expect("the recording opens");
    let rgb = rec
        .next_frame()
        .ok()
        .flatten()
        .expect("a colour frame")
        .data
        .decode()
        .expect("the recorded PNG decodes")
        .rgb;
    let (mjpeg, _) = encode_capture(
        &rgb,
        w as u32,
        h as u32,
        ImageFormat::Jpeg { quality: 90 },
        None,
    )
    .expect("a JPEG");
    let yuyv = vec![128u8; w * h * 2];
    let (mut mjpeg_ms, mut yuyv_ms) = (Vec::new(), Vec::new());
    for _ in 0..20 {
        let t = Instant::now();
        std::hint::black_box(mjpeg_to_rgb(&mjpeg).expect("our JPEG decodes"));
        mjpeg_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        std::hint::black_box(yuyv_to_rgb(w, h, &yuyv).expect("a YUYV frame converts"));
        yuyv_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    json!({
        "v4l2_mjpeg_decode_ms": median(mjpeg_ms),
        "v4l2_yuyv_convert_ms": median(yuyv_ms),
        "depth_read_decode_ms": median(depth_ms),
        "estimate_mean_ms": est_ms.iter().sum::<f64>() / est_ms.len().max(1) as f64,
        "estimate_ms": median(est_ms),
        "colour_format": if colour_is_mjpeg() { "mjpeg" } else { "png" },
        "color_read_ms": median(read_ms),
        "color_decode_ms": median(color_ms),
        "jpeg_encode_ms": median(jpeg_ms),
        "mjpeg_keep_as_received_ms": (!keep_ms.is_empty()).then(|| median(keep_ms)),
    })
}

fn figures_json(f: &RunFigures) -> serde_json::Value {
    let window_s = f.cpu_per_second_pct.len() as f64;
    json!({
        "model": f.model,
        "telemetry_msgs_per_s": f.telemetry_msgs_per_s,
        "cpu_mean_pct_of_one_core": f.cpu_mean_pct,
        "cpu_system_pct_of_one_core": f.cpu_system_pct,
        "cpu_max_per_second_pct": f.cpu_max_pct,
        "cpu_per_second_pct": f.cpu_per_second_pct,
        "rss_warm_mib": f.rss_warm_mib,
        "rss_end_mib": f.rss_end_mib,
        "rss_growth_mib": f.rss_end_mib - f.rss_warm_mib,
        "vm_hwm_mib": f.hwm_mib,
        "exit_after_sigterm_ms": f.exit_ms,
        "watchdog_longest_gap_ms": f.watchdog_longest_gap_ms,
        "watchdog_pets": f.watchdog_pets,
        "exit_code": f.exit_code,
        "captures_in_window": f.captures_in_window,
        "captures_per_s": f.captures_in_window as f64 / window_s.max(1.0),
        "captures_total": f.captures_total,
        "images_total": f.images,
        "permissible_spacing_median_m": f.permissible_median_m,
        "chosen_spacing_median_m": f.chosen_median_m,
        "fallback_captures": f.fallback_captures,
        "depth_frames": f.depth_frames,
        "depth_frames_per_s": f.depth_frames.map(|d| d as f64 / f.lifetime_s),
        "depth_skipped_busy": f.skipped_busy,
        "depth_bad": f.bad,
        "lifetime_s": f.lifetime_s,
        "stopped_line": f.stopped_line,
    })
}

fn main() {
    // `cargo bench` passes `--bench`; nothing here takes arguments.
    let secs = env_u64("ALFD_BENCH_SECONDS", 30).max(1);
    let scene = Scene::parse(DEFAULT_SCENE, "district (built in)").expect("the default scene");
    let tmp = tempfile::tempdir().expect("a temporary directory");
    let recording = tmp.path().join("recording");
    let t = Instant::now();
    let length_m = render_recording(&scene, &recording);
    println!(
        "daemon: rendered {FRAMES} frames {}x{} (depth + colour) in {:.1} s",
        size().0,
        size().1,
        t.elapsed().as_secs_f64()
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("a runtime");
    let alt = scene.survey.altitude_m;
    let mut runs = Vec::new();
    // The daemon's default model against the fixed baseline; `ALFD_BENCH_MODELS=quality` for a
    // soak of one model alone.
    let models: Vec<String> = std::env::var("ALFD_BENCH_MODELS")
        .unwrap_or_else(|_| "fixed,quality".into())
        .split(',')
        .map(str::to_string)
        .collect();
    for model in models.iter().map(String::as_str) {
        println!("daemon: {model}: {WARM_UP:?} warm-up, then {secs} s measured");
        runs.push(run_daemon(
            &rt,
            tmp.path(),
            &recording,
            length_m,
            alt,
            model,
            secs,
        ));
    }
    let occ = runs
        .iter()
        .find(|r| r.model != "fixed")
        .unwrap_or(&runs[runs.len() - 1]);
    // The stages timed with the estimating model's own config.
    let stages = stage_costs(
        &recording,
        &config_text(
            "serial:/dev/null:921600",
            &recording,
            tmp.path(),
            &occ.model,
        ),
    );
    // A soak of one model alone has no baseline: both columns are that run.
    let base = runs.iter().find(|r| r.model == "fixed").unwrap_or(occ);
    if std::ptr::eq(base, occ) {
        println!(
            "daemon: one model run ({}), no baseline in this run",
            occ.model
        );
    }

    println!();
    println!(
        "| {:<30} | {:>10} | {:>10} |",
        "figure", base.model, occ.model
    );
    println!("|{:-<32}|{:-<12}|{:-<12}|", "", "", "");
    let row = |name: &str, a: String, b: String| println!("| {name:<30} | {a:>10} | {b:>10} |");
    let f1 = |v: f64| format!("{v:.1}");
    let opt = |v: Option<u64>| v.map_or("-".into(), |v| v.to_string());
    for (name, get) in [
        (
            "CPU mean, % of one core",
            (|r: &RunFigures| r.cpu_mean_pct) as fn(&RunFigures) -> f64,
        ),
        ("  of which in the kernel, %", |r: &RunFigures| {
            r.cpu_system_pct
        }),
        ("CPU max per second, %", |r| r.cpu_max_pct),
        ("RSS at warm-up end, MiB", |r| r.rss_warm_mib),
        ("RSS at the end, MiB", |r| r.rss_end_mib),
        ("RSS growth, MiB", |r| r.rss_end_mib - r.rss_warm_mib),
        ("VmHWM, MiB", |r| r.hwm_mib),
        ("exit after SIGTERM, ms", |r| r.exit_ms),
        ("watchdog: longest gap, ms", |r| r.watchdog_longest_gap_ms),
        ("captures/s in window", |r| {
            r.captures_in_window as f64 / r.cpu_per_second_pct.len().max(1) as f64
        }),
        ("telemetry messages/s", |r| r.telemetry_msgs_per_s),
        ("depth frames/s", |r| {
            r.depth_frames.map_or(f64::NAN, |d| d as f64 / r.lifetime_s)
        }),
    ] {
        row(name, f1(get(base)), f1(get(occ)));
    }
    row(
        "depth frames",
        opt(base.depth_frames),
        opt(occ.depth_frames),
    );
    row(
        "skipped while busy",
        opt(base.skipped_busy),
        opt(occ.skipped_busy),
    );
    let m2 = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.2}"));
    row(
        "permissible spacing median, m",
        m2(base.permissible_median_m),
        m2(occ.permissible_median_m),
    );
    row(
        "chosen spacing median, m",
        m2(base.chosen_median_m),
        m2(occ.chosen_median_m),
    );
    row(
        "captures at the fallback",
        base.fallback_captures.to_string(),
        occ.fallback_captures.to_string(),
    );
    row(
        "captures (images)",
        format!("{} ({})", base.captures_total, base.images),
        format!("{} ({})", occ.captures_total, occ.images),
    );
    let ratio = occ.cpu_mean_pct / base.cpu_mean_pct;
    println!();
    println!(
        "daemon: {} CPU {:.1} % of one core = {ratio:.2}x the fixed-model baseline ({:.1} %); above it by {:.1} points (the estimate and the image work of its more frequent captures)",
        occ.model,
        occ.cpu_mean_pct,
        base.cpu_mean_pct,
        occ.cpu_mean_pct - base.cpu_mean_pct
    );
    println!(
        "daemon: targets: CPU < 25 % ({}), RSS < 40 MB ({}), exit <= 2 s ({}), watchdog fed within {} s ({}: longest gap {:.0} ms over {} WATCHDOG=1)",
        if occ.cpu_mean_pct < 25.0 {
            "met"
        } else {
            "NOT met"
        },
        if occ.hwm_mib * 1.048_576 < 40.0 {
            "met"
        } else {
            "NOT met"
        },
        if occ.exit_ms <= 2000.0 {
            "met"
        } else {
            "NOT met"
        },
        WATCHDOG_USEC / 1_000_000,
        // NaN (no pets seen) is not met.
        if occ.watchdog_longest_gap_ms < WATCHDOG_USEC as f64 / 1e3 {
            "met"
        } else {
            "NOT met"
        },
        occ.watchdog_longest_gap_ms,
        occ.watchdog_pets,
    );
    println!("daemon: stages in this process (median ms): {stages}");
    // What the stages predict, as % of one core: per second, 30 depth frames read and
    // decoded, 30 colour frames read, 30 estimates, one image per capture.
    let ms = |k: &str| stages[k].as_f64().unwrap_or(f64::NAN);
    let per_s =
        |r: &RunFigures| r.captures_in_window as f64 / r.cpu_per_second_pct.len().max(1) as f64;
    // One captured image: kept as it came, or decoded and encoded.
    let image_ms = if colour_is_mjpeg() && keep_camera_jpeg() {
        ms("mjpeg_keep_as_received_ms")
    } else {
        ms("color_decode_ms") + ms("jpeg_encode_ms")
    };
    let estimator_pct = 3.0 * ms("estimate_mean_ms");
    let extra_images_pct = (per_s(occ) - per_s(base)) * image_ms / 10.0;
    let predicted = json!({
        // The colour frames are read and kept raw; only a captured one is decoded.
        "replay_pct": 3.0 * (ms("depth_read_decode_ms") + ms("color_read_ms")),
        "estimator_pct": estimator_pct,
        "capture_image_ms": image_ms,
        "capture_images_fixed_pct": per_s(base) * image_ms / 10.0,
        "capture_images_estimating_pct": per_s(occ) * image_ms / 10.0,
    });
    println!("daemon: the stages predict (% of one core): {predicted}");
    // The fixed model's run holds what both runs pay (the link, the replay,
    // the runtime), so the difference is what the stages should explain.
    println!(
        "daemon: the quality model above the fixed one: {:.1} points measured; the stages predict {:.1} (the estimate's mean {:.1}, the extra captures' images {:.1})",
        occ.cpu_mean_pct - base.cpu_mean_pct,
        estimator_pct + extra_images_pct,
        estimator_pct,
        extra_images_pct,
    );

    let out = json!({
        "colour": if colour_is_mjpeg() { "mjpeg" } else { "png" },
        "keep_camera_jpeg": keep_camera_jpeg(),
        "width": size().0,
        "height": size().1,
        "fps": 30,
        "recording_frames": FRAMES,
        "warm_up_s": WARM_UP.as_secs(),
        "measured_s": secs,
        "cores": std::thread::available_parallelism().map_or(0, |n| n.get()),
        "baseline": figures_json(base),
        "estimating": figures_json(occ),
        "estimating_cpu_ratio_to_baseline": ratio,
        "stages_ms": stages,
        "stages_predict_pct": predicted,
    });
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target"));
    let path = target.join("bench-daemon.json");
    match std::fs::write(
        &path,
        serde_json::to_string_pretty(&out).expect("json") + "\n",
    ) {
        Ok(()) => println!("daemon: wrote {}", path.display()),
        Err(e) => eprintln!("daemon: {}: {e}", path.display()),
    }
}
