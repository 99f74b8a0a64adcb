//! Speed advice (issue 13) against firmware-sim: alfd publishes NAMED_VALUE_FLOAT
//! `ALF_VMAX`, the fastest ground speed at which the rate limit still meets the spacing
//! (spacing × rate limit), once a second, and a STATUSTEXT when the vehicle flies faster,
//! at most one per 10 s. A ground station on firmware-sim's forwarding (a UDP socket of
//! this test, on a port the system picks) hears both. Cruising at 10 m/s past the tower
//! with a 2 Hz rate limit it is told; with 30 Hz it is not.

use alfd::daemon::sim::{run_sim_with, SimArgs, SimHooks};
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::MavlinkReader;
use std::net::UdpSocket;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// alfd's camera component.
const CAMERA_COMPONENT: u8 = 100;

#[derive(Default, Debug)]
struct Heard {
    /// (time_boot_ms, ALF_SPC, ALF_VMAX) of each second's pair.
    advice: Vec<(u32, f32, f32)>,
    /// Each "too fast" text, with the time_boot_ms of the last named value before it.
    too_fast: Vec<(u32, String)>,
}

/// Listens until `stop`, decoding what firmware-sim forwards.
fn listen(sock: UdpSocket, stop: Arc<AtomicBool>) -> Heard {
    sock.set_read_timeout(Some(Duration::from_millis(100)))
        .unwrap();
    let mut heard = Heard::default();
    let mut spc: Option<(u32, f32)> = None;
    let mut last_ms = 0;
    let mut buf = [0u8; 2048];
    while !stop.load(Ordering::Relaxed) {
        let Ok(n) = sock.recv(&mut buf) else { continue };
        let mut r = MavlinkReader::new(&buf[..n]);
        while let Ok((h, m)) = r.read_any_message::<MavMessage>() {
            if h.component_id != CAMERA_COMPONENT {
                continue;
            }
            match m {
                MavMessage::NAMED_VALUE_FLOAT(v) => {
                    last_ms = v.time_boot_ms;
                    match v.name.to_str().unwrap_or("") {
                        "ALF_SPC" => spc = Some((v.time_boot_ms, v.value)),
                        "ALF_VMAX" => {
                            let (t, s) = spc.expect("ALF_SPC comes first");
                            assert_eq!(t, v.time_boot_ms, "ALF_VMAX with its ALF_SPC");
                            heard.advice.push((t, s, v.value));
                        }
                        _ => {}
                    }
                }
                MavMessage::STATUSTEXT(t) => {
                    let text = t.text.to_str().unwrap_or("").to_owned();
                    if text.contains("too fast") {
                        heard.too_fast.push((last_ms, text));
                    }
                }
                _ => {}
            }
        }
    }
    heard
}

async fn fly(rate_max_hz: f64) -> Heard {
    let dir = tempfile::tempdir().unwrap();
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = sock.local_addr().unwrap().port();
    let args = SimArgs {
        out: dir.path().to_path_buf(),
        width: 160,
        height: 120,
        progress: false,
        length_m: Some(100.0),
        seed: 13,
        gcs: Some(format!("udpout:127.0.0.1:{port}")),
        scene: Some(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/faults/tower_long.toml"),
        ),
        ..SimArgs::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let listener = {
        let stop = stop.clone();
        std::thread::spawn(move || listen(sock, stop))
    };
    let hooks = SimHooks {
        on_config: Some(Box::new(move |c| c.trigger.rate_max_hz = rate_max_hz)),
        ..SimHooks::default()
    };
    let out = run_sim_with(args, hooks, std::future::pending())
        .await
        .expect("the sim runs");
    stop.store(true, Ordering::Relaxed);
    let heard = listener.join().expect("the listener ends");
    assert!(!out.report.records.is_empty());
    heard
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn alf_vmax_every_second_and_too_fast_said_at_most_every_ten() {
    for (rate_hz, told) in [(2.0, true), (30.0, false)] {
        let h = fly(rate_hz).await;
        assert!(h.advice.len() >= 5, "{rate_hz} Hz: {h:?}");
        for (t, spacing_m, vmax) in &h.advice {
            let want = spacing_m * rate_hz as f32;
            assert!((vmax - want).abs() <= 1e-4 * want, "{t}: {vmax} vs {want}");
        }
        // Once a second, by the messages' own clock.
        for w in h.advice.windows(2) {
            let gap_ms = w[1].0 - w[0].0;
            assert!(
                (900..=2100).contains(&gap_ms),
                "{rate_hz} Hz: gap {gap_ms} ms"
            );
        }
        let fastest = h.advice.iter().map(|a| a.2).fold(0.0f32, f32::max);
        let slowest = h.advice.iter().map(|a| a.2).fold(f32::INFINITY, f32::min);
        if told {
            assert!(
                slowest < 9.0,
                "ALF_VMAX never below the cruise speed: {h:?}"
            );
            assert!(!h.too_fast.is_empty(), "never told: {h:?}");
            for w in h.too_fast.windows(2) {
                assert!(w[1].0 - w[0].0 >= 9_000, "too often: {:?}", h.too_fast);
            }
        } else {
            assert!(h.too_fast.is_empty(), "{:?}", h.too_fast);
        }
        eprintln!(
            "FIGURE speed advice at {rate_hz} Hz: {} ALF_VMAX, {slowest:.1}..{fastest:.1} m/s; \
             {} too-fast texts, e.g. {:?}",
            h.advice.len(),
            h.too_fast.len(),
            h.too_fast.first().map(|t| &t.1)
        );
    }
}
