//! What several integration tests share: the external programs some talk to (Python with
//! pymavlink or pycolmap, exiftool): present, or the test is skipped with a message saying what
//! to install; in CI (`CI` set) a missing one fails the test instead, so CI never passes by
//! skipping. And the config of `alfd run` on synthetic cameras over the tower scene, and
//! `alfd sim` flown on either clock.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::thread::JoinHandle;

/// `alfd run`'s config against the autopilot at `address`: 160×120 synthetic depth and colour
/// over `tests/data/tower.toml`, posed from telemetry, captures in `captures` in `mode`.
pub fn synthetic_tower_config(address: &str, captures: &Path, mode: &str) -> String {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tower.toml");
    format!(
        r#"[mavlink]
address = "{address}"
[sim]
pose = "telemetry"
scene = "{scene}"
[depth]
source = "synthetic"
width = 160
height = 120
scale_m = 0.01
max_range_m = 300.0
[camera]
source = "synthetic"
width = 160
height = 120
[trigger]
fallback_spacing_m = 1.0
[capture]
dir = {captures:?}
mode = "{mode}"
"#
    )
}

/// firmware-sim on a pseudo-terminal in `dir`: a 500 m line north at 60 m and 10 m/s, no wind.
pub fn line_sim(dir: &Path) -> firmware_sim::SimConfig {
    let mut sc = firmware_sim::SimConfig {
        transport: firmware_sim::Transport::Pty {
            link: Some(dir.join("ttyFC")),
        },
        ..firmware_sim::SimConfig::default()
    };
    sc.survey.pattern = firmware_sim::Pattern::Line;
    sc.survey.altitude_m = 60.0;
    sc.survey.length_m = 500.0;
    sc.survey.speed_mps = 10.0;
    sc.survey.wind_m = 0.0;
    sc.survey.wind_deg = 0.0;
    sc
}

/// `alfd run --log-format json --config CONFIG` as a child, with `env` set (`Some`) or
/// removed (`None`), and a thread collecting its stderr's lines until it exits.
pub fn alfd_run(config: &Path, env: &[(&str, Option<&str>)]) -> (Child, JoinHandle<Vec<String>>) {
    let (child, lines) = alfd_run_lines(config, env);
    (child, std::thread::spawn(move || lines.iter().collect()))
}

/// [`alfd_run`], its stderr's lines sent as they come (for a test that acts on a line
/// while the daemon runs).
pub fn alfd_run_lines(config: &Path, env: &[(&str, Option<&str>)]) -> (Child, Receiver<String>) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_alfd"));
    cmd.args(["run", "--log-format", "json", "--config"])
        .arg(config)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    for (k, v) in env {
        match v {
            Some(v) => cmd.env(k, v),
            None => cmd.env_remove(k),
        };
    }
    let mut child = cmd.spawn().expect("alfd starts");
    let stderr = child.stderr.take().expect("stderr is piped");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    (child, rx)
}

fn required(present: bool, test: &str, what: &str, install: &str) -> bool {
    if !present {
        if std::env::var_os("CI").is_some() {
            panic!("{test}: CI is set but {what} is missing: {install}");
        }
        eprintln!("SKIPPED {test}: {what} is missing ({install})");
    }
    present
}

/// Whether `python3` can import `module`, installed by `pip install {module}`
/// (see the module doc for what happens if not).
fn python_module(test: &str, module: &str) -> bool {
    let present = Command::new("python3")
        .args(["-c", &format!("import {module}")])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    required(
        present,
        test,
        &format!("python3 with {module}"),
        &format!("pip install {module}, or run scripts/setup.sh"),
    )
}

/// Whether `python3` can import pymavlink.
pub fn pymavlink(test: &str) -> bool {
    python_module(test, "pymavlink")
}

/// Whether `python3` can import pycolmap.
pub fn pycolmap(test: &str) -> bool {
    python_module(test, "pycolmap")
}

/// Whether `exiftool` runs (see the module doc for what happens if not).
pub fn exiftool(test: &str) -> bool {
    let present = Command::new("exiftool")
        .arg("-ver")
        .output()
        .is_ok_and(|o| o.status.success());
    required(
        present,
        test,
        "exiftool",
        "apt-get install libimage-exiftool-perl, or run scripts/setup.sh",
    )
}

/// An `alfd sim` flight on simulated time (its own current-thread runtime), or in real time
/// over a pty on a two-worker runtime, the daemon's loops on their threads as in flight.
pub fn fly_sim(
    simulated: bool,
    args: alfd::daemon::sim::SimArgs,
    hooks: alfd::daemon::sim::SimHooks,
    shutdown: impl std::future::Future<Output = ()> + Send,
) -> Result<alfd::daemon::sim::SimOutcome, alfd::daemon::sim::SimRunError> {
    if simulated {
        alfd::daemon::sim::run_sim_on_simulated_time(args, hooks, shutdown)
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .expect("a runtime")
            .block_on(alfd::daemon::sim::run_sim_with(args, hooks, shutdown))
    }
}
