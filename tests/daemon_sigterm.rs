//! One shutdown path: `alfd run` against firmware-sim, stopped by SIGTERM
//! while capturing. The captures in flight are finished, the manifest and the
//! exports flushed, and the process exits by itself (the time it took is
//! printed; the 2 s budget is measured by `cargo bench --bench daemon`, not
//! asserted here).

use alfd::capture::{read_manifest, tlog};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_flushes_the_manifest_and_exports_and_exits() {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = firmware_sim::SimConfig {
        transport: firmware_sim::Transport::Pty {
            link: Some(dir.path().join("ttyFC")),
        },
        ..firmware_sim::SimConfig::default()
    };
    sc.survey.pattern = firmware_sim::Pattern::Line;
    sc.survey.altitude_m = 60.0;
    sc.survey.length_m = 500.0;
    sc.survey.speed_mps = 10.0;
    sc.survey.wind_m = 0.0;
    sc.survey.wind_deg = 0.0;
    let sim = firmware_sim::start(sc).await.unwrap();
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tower.toml");
    let captures = dir.path().join("captures");
    let config = dir.path().join("alfd.toml");
    std::fs::write(
        &config,
        format!(
            r#"[mavlink]
address = "{addr}"
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
"#,
            addr = sim.address()
        ),
    )
    .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_alfd"))
        .args(["run", "--log-format", "json", "--config"])
        .arg(&config)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let log = std::thread::spawn(move || {
        BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
            .collect::<Vec<_>>()
    });
    // Wait until captures are being written, then stop it mid-flight.
    let manifest = captures.join("flight-001").join("manifest.jsonl");
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let n = std::fs::read_to_string(&manifest).map_or(0, |t| t.lines().count());
        if n >= 10 {
            break;
        }
        assert!(Instant::now() < deadline, "no captures within 60 s");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // SAFETY: kill sends a signal to the child we started, by its id.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let term = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if term.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            panic!("alfd run did not exit within 20 s of SIGTERM");
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
    eprintln!(
        "FIGURE alfd run exited {:.0} ms after SIGTERM",
        term.elapsed().as_secs_f64() * 1e3
    );
    assert!(status.success(), "exit status {status}");
    let lines = log.join().unwrap();
    // --log-format json: one JSON object per line, levels named.
    for l in &lines {
        let v: serde_json::Value = serde_json::from_str(l).unwrap_or_else(|e| panic!("{l}: {e}"));
        assert!(v["level"].is_string(), "{l}");
    }
    assert!(lines.iter().any(|l| l.contains("stopped:")));

    let flight = captures.join("flight-001");
    let m = read_manifest(&manifest).unwrap();
    assert_eq!(m.torn_tail_bytes, 0);
    assert!(m.bad_lines.is_empty());
    assert!(m.records.len() >= 10);
    for r in &m.records {
        let name = r.image.as_ref().unwrap();
        let bytes = std::fs::read(flight.join(name)).unwrap();
        jpeg_decoder::Decoder::new(&bytes[..]).decode().unwrap();
    }
    // Exports written at the stop, from the whole manifest.
    let geo = std::fs::read_to_string(flight.join("geo.txt")).unwrap();
    assert_eq!(geo.lines().count(), m.records.len() + 1);
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(flight.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(t["frames"].as_array().unwrap().len(), m.records.len());
    // The telemetry log ends on a complete entry (synced at the stop).
    let bytes = std::fs::read(flight.join("telemetry.tlog")).unwrap();
    assert_eq!(tlog::complete_prefix_len(&bytes), bytes.len());
    assert!(!bytes.is_empty());
    sim.shutdown().await;
}
