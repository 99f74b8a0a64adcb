//! firmware-sim: run the simulated autopilot from a TOML config and flags; prints the address
//! to open (for a pty, `serial:<stable symlink>:921600`) and runs until Ctrl-C or SIGTERM.

use clap::Parser;
use firmware_sim::config::{Autopilot, FaultEvent};
use firmware_sim::{FaultKind, SimConfig, Transport};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(about = "A simulated MAVLink autopilot for alfd's tests and bench")]
struct Args {
    /// TOML config (every key optional; see docs/link.md).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Transport: pty, udp or tcp (overrides the config).
    #[arg(long)]
    transport: Option<String>,
    /// For a pty, the stable symlink to keep pointing at the current pty.
    #[arg(long)]
    link: Option<PathBuf>,
    /// A ground station to forward to, `udpout:HOST:PORT` (it listens there; overrides the
    /// config's `link.gcs`).
    #[arg(long, value_name = "ADDR")]
    gcs: Option<String>,
    /// MAVLink version to send (1 or 2).
    #[arg(long)]
    mavlink: Option<u8>,
    /// Write truth.jsonl here.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Fault seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Probability that a byte sent is corrupted.
    #[arg(long)]
    corrupt_byte_rate: Option<f64>,
    /// Probability that a frame sent is dropped.
    #[arg(long)]
    drop_rate: Option<f64>,
    /// One-way jitter on what is sent, ms.
    #[arg(long)]
    jitter_ms: Option<f64>,
    /// Position and attitude stream rate, Hz.
    #[arg(long)]
    telemetry_hz: Option<f64>,
    /// A timed fault, `KIND@AT_S[:DURATION_S]` (KIND: link_loss, reboot, gps_glitch, silence);
    /// repeat for more. Added to the config's `[[faults.events]]`.
    #[arg(long = "event", value_name = "KIND@AT_S[:DURATION_S]")]
    events: Vec<String>,
    /// A ground station (system 255, component 190) that answers every TIMESYNC request heard
    /// on the link, ahead of the autopilot, with a clock OFFSET_MS off the autopilot's
    /// (overrides the config's `[gcs_timesync]`).
    #[arg(long, value_name = "OFFSET_MS", allow_hyphen_values = true)]
    gcs_answers_timesync: Option<f64>,
    /// Behave like `generic` firmware-sim, like `px4` (the generic autopilot with PX4's
    /// HEARTBEAT and distance trigger) or like `ardupilot` (late origin after lat = lon = 0
    /// positions, take-off from the ground, landed state, IMAGE_START_CAPTURE to the camera
    /// and CAMERA_FEEDBACK instead of CAMERA_TRIGGER, a ground station answering TIMESYNC);
    /// overrides the config's `autopilot`.
    #[arg(long, value_name = "PROFILE")]
    autopilot: Option<String>,
}

fn event(spec: &str) -> Result<FaultEvent, String> {
    let bad = || format!("--event {spec}: expected KIND@AT_S[:DURATION_S], e.g. link_loss@10:2");
    let (kind, when) = spec.split_once('@').ok_or_else(bad)?;
    let (at, duration) = match when.split_once(':') {
        Some((a, d)) => (a, d),
        None => (when, "0"),
    };
    let secs = |v: &str| -> Result<Duration, String> {
        let x: f64 = v.parse().map_err(|_| bad())?;
        if !(x.is_finite() && x >= 0.0) {
            return Err(bad());
        }
        Ok(Duration::from_secs_f64(x))
    };
    let kind = match kind {
        "link_loss" => FaultKind::LinkLoss,
        "reboot" => FaultKind::Reboot,
        "gps_glitch" => FaultKind::GpsGlitch,
        "silence" => FaultKind::Silence,
        _ => {
            return Err(format!(
                "--event {spec}: unknown kind `{kind}` (link_loss, reboot, gps_glitch, silence)"
            ))
        }
    };
    Ok(FaultEvent {
        at: secs(at)?,
        kind,
        duration: secs(duration)?,
        offset_m: [30.0, 0.0, 0.0],
    })
}

fn config(a: &Args) -> Result<SimConfig, String> {
    let mut c = match &a.config {
        Some(p) => SimConfig::from_file(p).map_err(|e| e.to_string())?,
        None => SimConfig::default(),
    };
    match a.transport.as_deref() {
        None => {}
        Some("pty") => {
            c.transport = Transport::Pty {
                link: a.link.clone(),
            }
        }
        Some("udp") => {
            c.transport = Transport::Udp {
                bind: "127.0.0.1:0".into(),
            }
        }
        Some("tcp") => {
            c.transport = Transport::Tcp {
                bind: "127.0.0.1:0".into(),
            }
        }
        Some(t) => return Err(format!("--transport: `{t}`: expected pty, udp or tcp")),
    }
    if let (Some(l), Transport::Pty { link }) = (&a.link, &mut c.transport) {
        *link = Some(l.clone());
    }
    if let Some(g) = &a.gcs {
        firmware_sim::config::check_gcs_address(g).map_err(|e| format!("--gcs: {e}"))?;
        c.gcs = Some(g.clone());
    }
    if let Some(v) = a.mavlink {
        if !matches!(v, 1 | 2) {
            return Err(format!("--mavlink: {v}: expected 1 or 2"));
        }
        c.mavlink_version = v;
    }
    let prob = |name: &str, v: f64| {
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(format!("--{name}: {v}: must be in [0, 1]"))
        }
    };
    if let Some(v) = a.corrupt_byte_rate {
        c.faults.corrupt_byte_rate = prob("corrupt-byte-rate", v)?;
    }
    if let Some(v) = a.drop_rate {
        c.faults.drop_rate = prob("drop-rate", v)?;
    }
    if let Some(v) = a.jitter_ms {
        if !(v.is_finite() && v >= 0.0) {
            return Err(format!("--jitter-ms: {v}: must be zero or more"));
        }
        c.faults.jitter = Duration::from_secs_f64(v / 1e3);
    }
    if let Some(hz) = a.telemetry_hz {
        if !(hz > 0.0 && hz <= 1000.0) {
            return Err(format!("--telemetry-hz: {hz}: must be in (0, 1000]"));
        }
        c.streams.global_position_int = hz;
        c.streams.attitude_quaternion = hz;
    }
    if let Some(s) = a.seed {
        c.faults.seed = s;
    }
    for e in &a.events {
        c.faults.events.push(event(e)?);
    }
    if let Some(ms) = a.gcs_answers_timesync {
        let g = firmware_sim::GcsTimesync::qgc(ms)
            .map_err(|e| format!("--gcs-answers-timesync: {e}"))?;
        if g.system_id == c.system_id {
            return Err(format!(
                "--gcs-answers-timesync: the autopilot is system {} too",
                c.system_id
            ));
        }
        c.gcs_timesync = Some(g);
    }
    c.truth_path = a.truth.clone().or(c.truth_path);
    match a.autopilot.as_deref() {
        None | Some("generic") => {}
        Some("px4") => c.autopilot = Autopilot::Px4,
        Some("ardupilot") => c = c.ardupilot(),
        Some(p) => {
            return Err(format!(
                "--autopilot: `{p}`: expected generic, px4 or ardupilot"
            ))
        }
    }
    Ok(c)
}

fn main() -> ExitCode {
    let args = Args::parse();
    let cfg = match config(&args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("firmware-sim: {e}");
            return ExitCode::from(2);
        }
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("tokio runtime");
    rt.block_on(async {
        let sim = match firmware_sim::start(cfg).await {
            Ok(s) => s,
            Err(e) => {
                eprintln!("firmware-sim: {e}");
                return ExitCode::FAILURE;
            }
        };
        println!("{}", sim.address());
        // Ctrl-C or SIGTERM: shut down cleanly, so the pty's temporary symlink is removed.
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .expect("SIGTERM handler");
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
        sim.shutdown().await;
        ExitCode::SUCCESS
    })
}
