//! One shutdown path: `alfd run` against firmware-sim, stopped by SIGTERM
//! while capturing. The captures in flight are finished, the manifest and the
//! exports flushed, and the process exits by itself (the time it took is
//! printed; the 2 s budget is measured by `cargo bench --bench daemon`, not
//! asserted here).
//!
//! It runs under a stand-in for systemd's notify socket, with the unit's
//! `WatchdogSec`: READY=1 before the captures, WATCHDOG=1 from the main loop
//! (how far apart is a wall-clock figure: printed here, held to the timeout by
//! `cargo bench --bench daemon`), STOPPING=1 at the stop.

mod tools;

use alfd::capture::{read_manifest, tlog};
use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};

/// `WatchdogSec=5` in systemd/alfd.service, as systemd passes it.
const WATCHDOG_USEC: u64 = 5_000_000;

/// READY=1 first and before SIGTERM, then WATCHDOG=1 (the longest gap printed; the
/// bench holds it to the timeout), STOPPING=1 after SIGTERM and before the exit.
fn check_notifications(notes: &[(Instant, String)], term: Instant, exited: Instant) {
    let texts: Vec<&str> = notes.iter().map(|(_, t)| t.as_str()).collect();
    assert_eq!(texts.first(), Some(&"READY=1"), "notifications: {texts:?}");
    assert!(notes[0].0 < term, "READY=1 only after SIGTERM");
    let stopping = notes
        .iter()
        .position(|(_, t)| t == "STOPPING=1")
        .unwrap_or_else(|| panic!("no STOPPING=1 in {texts:?}"));
    assert!(notes[stopping].0 >= term && notes[stopping].0 <= exited);
    let pets: Vec<Instant> = notes[..stopping]
        .iter()
        .filter(|(_, t)| t == "WATCHDOG=1")
        .map(|(at, _)| *at)
        .collect();
    assert!(!pets.is_empty(), "never fed the watchdog: {texts:?}");
    let timeout = Duration::from_micros(WATCHDOG_USEC);
    let mut last = notes[0].0;
    let mut longest = Duration::ZERO;
    for at in pets.iter().copied().chain([notes[stopping].0]) {
        longest = longest.max(at - last);
        last = at;
    }
    eprintln!(
        "FIGURE {} WATCHDOG=1 before the stop, longest gap {:.0} ms (timeout {} ms)",
        pets.len(),
        longest.as_secs_f64() * 1e3,
        timeout.as_millis()
    );
    // Whether the longest gap stays under the timeout is a wall-clock figure of this machine:
    // `cargo bench --bench daemon` measures it over its runs (with its verdict), this test
    // prints it.
    assert!(longest > Duration::ZERO);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_flushes_the_manifest_and_exports_and_exits() {
    let dir = tempfile::tempdir().unwrap();
    let sim = firmware_sim::start(tools::line_sim(dir.path()))
        .await
        .unwrap();
    let captures = dir.path().join("captures");
    let config = dir.path().join("alfd.toml");
    std::fs::write(
        &config,
        tools::synthetic_tower_config(sim.address(), &captures, "frame"),
    )
    .unwrap();
    // systemd's side of sd_notify: one datagram per state change, stamped on arrival.
    let notify_path = dir.path().join("notify.sock");
    let notify_sock = UnixDatagram::bind(&notify_path).unwrap();
    notify_sock
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let notify_stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let notify_log = {
        let stop = notify_stop.clone();
        std::thread::spawn(move || {
            let mut got = Vec::new();
            let mut buf = [0u8; 4096];
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(n) = notify_sock.recv(&mut buf) {
                    // One datagram holds newline-separated assignments, as systemd reads them.
                    let at = Instant::now();
                    for line in String::from_utf8_lossy(&buf[..n]).lines() {
                        got.push((at, line.to_owned()));
                    }
                }
            }
            got
        })
    };
    let watchdog_usec = WATCHDOG_USEC.to_string();
    let (mut child, log) = tools::alfd_run(
        &config,
        &[
            ("NOTIFY_SOCKET", notify_path.to_str()),
            ("WATCHDOG_USEC", Some(&watchdog_usec)),
            ("WATCHDOG_PID", None),
        ],
    );
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
    // Taken before the signal: the daemon now stops within milliseconds, and its STOPPING=1
    // was seen stamped before an instant taken after kill() returned.
    let term = Instant::now();
    // SAFETY: kill sends a signal to the child we started, by its id.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
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
    let exited = Instant::now();
    notify_stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let notes = notify_log.join().unwrap();
    check_notifications(&notes, term, exited);
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
    // Each line has its image, or was logged without it because the writer was behind its
    // deadline (a storage stall on a shared disk); nothing else takes an image away.
    let mut images = 0;
    for r in &m.records {
        match (&r.image, &r.image_missing) {
            (Some(name), None) => {
                let bytes = std::fs::read(flight.join(name)).unwrap();
                jpeg_decoder::Decoder::new(&bytes[..]).decode().unwrap();
                images += 1;
            }
            (None, Some(why)) => assert!(why.starts_with("writer behind"), "{}: {why}", r.seq),
            other => panic!("capture {}: {other:?}", r.seq),
        }
    }
    assert!(images > 0, "no capture has its image");
    // Exports written at the stop, from the whole manifest: one entry per image.
    let geo = std::fs::read_to_string(flight.join("geo.txt")).unwrap();
    assert_eq!(geo.lines().count(), images + 1);
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(flight.join("transforms.json")).unwrap()).unwrap();
    assert_eq!(t["frames"].as_array().unwrap().len(), images);
    // The telemetry log ends on a complete entry (synced at the stop).
    let bytes = std::fs::read(flight.join("telemetry.tlog")).unwrap();
    assert_eq!(tlog::complete_prefix_len(&bytes), bytes.len());
    assert!(!bytes.is_empty());
    sim.shutdown().await;
}
