//! The link's machine-dependent figures (issue 5), against firmware-sim over a pty:
//! - throughput: messages/s through the link, the link thread's CPU as a fraction of one core,
//!   and the process's resident memory over the run (`LINK_BENCH_SECS`, default 20; 600 for the
//!   10-minute figure);
//! - recovery: after a link loss, time from the pty's return to the first fresh pose; after a
//!   reboot, time to resynchronise (`LINK_BENCH_REPEATS`, default 5).
//!
//! The link runs on its own single-threaded runtime in its own thread, so that thread's CPU
//! time (CLOCK_THREAD_CPUTIME_ID) is the link's cost; the simulator runs on another thread.
//! Run: `cargo bench --bench link`.

use alfd::core::geo::Geodetic;
use alfd::link::{self, mono_ns, LinkConfig, LinkHandle};
use firmware_sim::{Fault, SimConfig, SimEvent};
use std::sync::mpsc as std_mpsc;
use std::time::Duration;

fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

fn rss_mib() -> f64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap_or_default();
    let pages: f64 = statm
        .split_whitespace()
        .nth(1)
        .and_then(|p| p.parse().ok())
        .unwrap_or(0.0);
    pages * 4096.0 / (1024.0 * 1024.0)
}

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Start the simulator on its own runtime thread; returns its handle's address and a way to
/// inject faults and watch events from other threads.
struct Sim {
    rt: tokio::runtime::Runtime,
    handle: firmware_sim::SimHandle,
}

fn sim(cfg: SimConfig) -> Sim {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let handle = rt
        .block_on(firmware_sim::start(cfg))
        .expect("simulator starts");
    Sim { rt, handle }
}

type Probe = tokio::sync::mpsc::Sender<tokio::sync::oneshot::Sender<u64>>;

/// Run the link on its own thread (a single-threaded runtime) until `stop` fires. The probe
/// asks that thread for its CPU time (a task on the same runtime answers).
fn link_thread(cfg: LinkConfig) -> (LinkHandle, std_mpsc::Sender<()>, Probe) {
    let (h_tx, h_rx) = std_mpsc::channel();
    let (stop_tx, stop_rx) = std_mpsc::channel::<()>();
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let (task, handle, _events) = link::new(cfg);
        let (probe_tx, mut probe_rx) =
            tokio::sync::mpsc::channel::<tokio::sync::oneshot::Sender<u64>>(1);
        h_tx.send((handle, probe_tx)).unwrap();
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        std::thread::spawn(move || {
            let _ = stop_rx.recv();
            let _ = tx.send(());
        });
        rt.spawn(async move {
            while let Some(reply) = probe_rx.recv().await {
                let _ = reply.send(thread_cpu_ns());
            }
        });
        rt.block_on(task.run(async {
            let _ = rx.await;
        }))
        .unwrap();
    });
    let (handle, probe) = h_rx.recv().unwrap();
    (handle, stop_tx, probe)
}

fn cpu_of(probe: &Probe) -> u64 {
    let (tx, rx) = tokio::sync::oneshot::channel();
    probe.blocking_send(tx).unwrap();
    rx.blocking_recv().unwrap()
}

fn link_cfg(s: &Sim) -> LinkConfig {
    let o = s.handle.origin();
    let mut c = LinkConfig::for_address(s.handle.address());
    c.home = Some(Geodetic {
        lat_deg: o[0],
        lon_deg: o[1],
        alt_m: o[2],
    });
    c
}

fn throughput(secs: u64) {
    let mut cfg = SimConfig::default();
    cfg.streams.local_position_ned = 500.0;
    cfg.streams.gps_raw_int = 250.0;
    cfg.streams.attitude = 250.0;
    let s = sim(cfg);
    let mut lc = link_cfg(&s);
    lc.position_hz = 500.0;
    lc.attitude_hz = 500.0;
    let (handle, stop, probe) = link_thread(lc);
    let mut health = handle.health();
    s.rt.block_on(async {
        tokio::time::timeout(
            Duration::from_secs(30),
            health.wait_for(|h| h.rates_acked && h.synced),
        )
        .await
        .expect("rates acknowledged")
        .unwrap();
    });
    // Warm up two seconds, then measure.
    std::thread::sleep(Duration::from_secs(2));
    let h0 = handle.health().borrow().clone();
    let (t0, cpu0, rss0) = (mono_ns(), cpu_of(&probe), rss_mib());
    let mut rss = vec![rss0];
    for _ in 0..secs {
        std::thread::sleep(Duration::from_secs(1));
        rss.push(rss_mib());
    }
    let h1 = handle.health().borrow().clone();
    let (t1, cpu1) = (mono_ns(), cpu_of(&probe));
    stop.send(()).unwrap();
    let wall = (t1 - t0) as f64 * 1e-9;
    let msgs = (h1.messages_rx - h0.messages_rx) as f64;
    let cpu_frac = (cpu1 - cpu0) as f64 * 1e-9 / wall;
    let (first, last) = (rss[0], *rss.last().unwrap());
    let peak = rss.iter().cloned().fold(0.0, f64::max);
    let half = rss.len() / 2;
    let late_growth = last - rss[half];
    println!(
        "link/throughput: {:.0} messages/s over {wall:.0} s ({:.2}x the 2000/s target)",
        msgs / wall,
        msgs / wall / 2000.0
    );
    println!(
        "link/cpu: {:.2} % of one core for the link thread (ratio to the 5 % budget: {:.2})",
        cpu_frac * 100.0,
        cpu_frac / 0.05
    );
    println!(
        "link/memory: RSS {first:.1} MiB at start, {last:.1} MiB at end, peak {peak:.1} MiB; second half grew {late_growth:+.2} MiB"
    );
    println!(
        "link/health: {} positions accepted, {} sequence gaps, {} parse errors",
        h1.positions_accepted - h0.positions_accepted,
        h1.seq_gaps - h0.seq_gaps,
        h1.parse_errors - h0.parse_errors
    );
    s.rt.block_on(s.handle.shutdown());
}

fn recovery(repeats: u64) {
    let s = sim(SimConfig::default());
    let (handle, stop, _probe) = link_thread(link_cfg(&s));
    let mut loss_ms = Vec::new();
    let mut resync_ms = Vec::new();
    s.rt.block_on(async {
        let mut health = handle.health();
        let mut events = s.handle.subscribe();
        health
            .wait_for(|h| h.synced && h.positions_accepted > 10)
            .await
            .unwrap();
        for _ in 0..repeats {
            let down = s
                .handle
                .inject(Fault::LinkLoss {
                    duration: Duration::from_millis(1500),
                })
                .await
                .unwrap();
            let up = loop {
                if let Ok(SimEvent::LinkUp { mono_ns }) = events.recv().await {
                    if mono_ns > down {
                        break mono_ns;
                    }
                }
            };
            let h = health
                .wait_for(|h| h.last_position_rx_mono_ns > up)
                .await
                .unwrap()
                .clone();
            loss_ms.push((h.last_position_rx_mono_ns - up) as f64 / 1e6);
            let reboots = h.reboots;
            let at = s
                .handle
                .inject(Fault::Reboot {
                    silence: Duration::ZERO,
                })
                .await
                .unwrap();
            let h = health
                .wait_for(|h| h.reboots > reboots && h.synced)
                .await
                .unwrap()
                .clone();
            resync_ms.push((h.synced_at_mono_ns - at) as f64 / 1e6);
            health
                .wait_for(|h| {
                    h.positions_accepted > 0 && h.last_position_rx_mono_ns > at + 500_000_000
                })
                .await
                .unwrap();
        }
    });
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.partial_cmp(b).unwrap());
        (v[0], v[v.len() / 2], v[v.len() - 1])
    };
    let (a, b, c) = stats(&mut loss_ms);
    println!("link/link-loss: fresh pose after the pty came back: min {a:.0} ms, median {b:.0} ms, max {c:.0} ms over {repeats} (target 1000 ms; ratio of max {:.2})", c / 1000.0);
    let (a, b, c) = stats(&mut resync_ms);
    println!("link/reboot: resynchronised after the boot clock restarted: min {a:.0} ms, median {b:.0} ms, max {c:.0} ms over {repeats} (target 2000 ms; ratio of max {:.2})", c / 2000.0);
    stop.send(()).unwrap();
    s.rt.block_on(s.handle.shutdown());
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` runs it briefly.
    let quick = !std::env::args().any(|a| a == "--bench");
    let secs = if quick {
        2
    } else {
        env_u64("LINK_BENCH_SECS", 20)
    };
    let repeats = if quick {
        1
    } else {
        env_u64("LINK_BENCH_REPEATS", 5)
    };
    throughput(secs);
    recovery(repeats);
}
