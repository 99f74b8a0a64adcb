//! alfd's link against firmware-sim over a pty, one fault at a time (issue 5's targets):
//! link loss, reboot, 1 % corrupted bytes, GPS glitch, telemetry silence, 10 ms jitter, drops.
//! Every wait is on an event or a `watch` value; figures that depend on the machine's speed
//! (recovery times) are printed here and measured in `benches/link.rs`.

mod link_support;

use alfd::core::pose::PoseError;
use alfd::link::{mono_ns, LinkEvent, PoseQueryError};
use firmware_sim::{Fault, SimEvent};
use link_support::*;
use std::time::Duration;

const MS: u64 = 1_000_000;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn link_loss_reconnects_and_poses_come_back() {
    let mut p = start(sim_config(21), |_| {}).await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    let down = p
        .sim
        .inject(Fault::LinkLoss {
            duration: Duration::from_secs(2),
        })
        .await
        .unwrap();
    p.health_until("link seen down", |h| !h.connected).await;
    let SimEvent::LinkUp { mono_ns: up } = p
        .sim_event(
            "pty back",
            |e| matches!(e, SimEvent::LinkUp { mono_ns } if *mono_ns > down),
        )
        .await
    else {
        unreachable!()
    };
    let h = p
        .health_until("fresh pose after the pty came back", |h| {
            h.last_position_rx_mono_ns > up
        })
        .await;
    println!(
        "link loss: back to fresh poses {:.0} ms after the pty came back ({} connect failures, last backoff {} ms)",
        (h.last_position_rx_mono_ns - up) as f64 / 1e6,
        h.connect_failures,
        h.last_backoff_ms
    );
    assert_eq!(h.connects, 2, "one reconnection: {h:?}");
    assert!(
        h.last_backoff_ms <= 500,
        "backoff capped at reconnect_max_ms"
    );
    assert!(
        h.synced,
        "a link loss is not a reboot: the time estimate survives"
    );
    let f = measure(&p, 30, Duration::from_millis(400)).await;
    println!("{}", f.summary("after link loss"));
    assert!(rms(&f.pos_err_m) < 0.05, "{}", f.summary("after link loss"));
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reboot_resynchronises() {
    let mut p = start(sim_config(22), |_| {}).await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    let at = p
        .sim
        .inject(Fault::Reboot {
            silence: Duration::ZERO,
        })
        .await
        .unwrap();
    let h = p
        .health_until("resynchronised after the reboot", |h| {
            h.reboots == 1 && h.synced
        })
        .await;
    println!(
        "reboot: resynchronised {:.0} ms after the boot clock restarted (timesync resets {}, \
         implausible times {}, out-of-order positions {})",
        (h.synced_at_mono_ns - at) as f64 / 1e6,
        h.timesync_resets,
        h.rejected_time,
        h.out_of_order
    );
    assert!(h.synced_at_mono_ns > at);
    assert_eq!(h.rejected_position, 0, "{h:?}");
    loop {
        match tokio::time::timeout(GIVE_UP, p.events.recv())
            .await
            .expect("event")
            .expect("link")
        {
            LinkEvent::AutopilotRebooted => break,
            _ => continue,
        }
    }
    p.health_until("rates requested again and acknowledged", |h| h.rates_acked)
        .await;
    p.fresh_after(mono_ns() + 500 * MS).await;
    let f = measure(&p, 30, Duration::from_millis(400)).await;
    println!("{}", f.summary("after reboot"));
    assert_eq!(f.unanswered, 0);
    assert!(
        rms(&f.pos_err_m) < 0.05 && rms(&f.sync_err_ns) < 1e6,
        "{}",
        f.summary("after reboot")
    );
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_percent_corrupted_bytes_no_wrong_pose() {
    let mut sim = sim_config(23);
    sim.faults.corrupt_byte_rate = 0.01;
    let p = start(sim, |_| {}).await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    let f = measure(&p, 450, Duration::from_millis(400)).await;
    let h = p.link.health().borrow().clone();
    let s = p.sim.stats();
    println!("{}", f.summary("1 % corrupted bytes"));
    println!(
        "corruption: {} of {} frames corrupted ({} bytes); alfd saw {} sequence gaps, {} parse errors, {} implausible times",
        s.frames_corrupted, s.frames_sent, s.bytes_corrupted, h.seq_gaps, h.parse_errors, h.rejected_time
    );
    assert!(s.frames_corrupted > 100, "the fault was exercised");
    assert!(h.seq_gaps > 0);
    let wrong = f.pos_err_m.iter().filter(|e| **e > 0.5).count();
    assert_eq!(wrong, 0, "wrong poses accepted: {}", f.summary("1 %"));
    assert!(rms(&f.pos_err_m) < 0.05, "{}", f.summary("1 %"));
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gps_glitch_is_flagged_and_not_followed() {
    let mut p = start(sim_config(24), |_| {}).await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    let at = p
        .sim
        .inject(Fault::GpsGlitch {
            offset_m: [12.0, -5.0, 0.0],
            duration: Duration::from_secs(5),
        })
        .await
        .unwrap();
    let h = p.health_until("glitch flagged", |h| h.glitch_active).await;
    assert_eq!(h.glitches, 1);
    loop {
        match tokio::time::timeout(GIVE_UP, p.events.recv())
            .await
            .expect("event")
            .expect("link")
        {
            LinkEvent::GpsGlitch { jump_m } => {
                assert!(jump_m > 10.0, "{jump_m}");
                break;
            }
            _ => continue,
        }
    }
    // While the glitch lasts, every answer is either right (from good samples) or Stale.
    let f = measure(&p, 120, Duration::ZERO).await;
    println!(
        "{}",
        f.summary("during GPS glitch (live, extrapolated or stale)")
    );
    assert!(
        max(&f.pos_err_m) < 1.0,
        "followed the glitch: {}",
        f.summary("glitch")
    );
    let SimEvent::GlitchEnd { mono_ns: end } = p
        .sim_event("glitch over", |e| matches!(e, SimEvent::GlitchEnd { .. }))
        .await
    else {
        unreachable!()
    };
    assert!(end > at);
    let h = p
        .health_until("glitch cleared", |h| {
            !h.glitch_active && h.last_position_rx_mono_ns > end
        })
        .await;
    assert_eq!(h.reanchors, 0, "a 5 s glitch is never followed");
    assert!(h.glitch_rejected > 10, "{h:?}");
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn telemetry_silence_goes_stale_beyond_the_horizon() {
    let mut p = start(sim_config(25), |c| {
        c.pose_horizon = Duration::from_millis(200)
    })
    .await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    let beats = p.link.health().borrow().autopilot_heartbeats;
    p.sim
        .inject(Fault::Silence {
            duration: Duration::from_secs(5),
        })
        .await
        .unwrap();
    // Heartbeats go on at 1 Hz; the second one after the silence began was sent after it, and
    // the link keeps order, so every position sent before the silence has been digested: the
    // newest sample is fixed until the silence ends, more than 3 s later.
    p.health_until("two heartbeats into the silence", |h| {
        h.autopilot_heartbeats >= beats + 2
    })
    .await;
    let newest = p
        .link
        .state()
        .borrow()
        .as_ref()
        .and_then(|s| s.mono_ns)
        .expect("a pose");
    let inside = p.link.pose_at_mono_ns(newest + 150 * MS).await;
    assert!(
        inside.is_ok_and(|q| q.extrapolated_ns > 0),
        "extrapolated within the horizon: {inside:?}"
    );
    let stale = p.link.pose_at_mono_ns(newest + 250 * MS).await;
    assert!(
        matches!(stale, Err(PoseQueryError::Pose(PoseError::Stale { .. }))),
        "{stale:?}"
    );
    let SimEvent::SilenceEnd { mono_ns: end } = p
        .sim_event("silence over", |e| matches!(e, SimEvent::SilenceEnd { .. }))
        .await
    else {
        unreachable!()
    };
    let t = p.fresh_after(end).await;
    assert!(t > end);
    let h = p.link.health().borrow().clone();
    assert_eq!(h.connects, 1, "heartbeats kept the link: no reconnection");
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn time_sync_under_10_ms_jitter() {
    let mut sim = sim_config(26);
    sim.faults.jitter = Duration::from_millis(10);
    let p = start(sim, |_| {}).await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    p.fresh_after(mono_ns() + 3_000 * MS).await;
    let f = measure(&p, 300, Duration::from_millis(400)).await;
    println!("{}", f.summary("10 ms jitter"));
    assert_eq!(f.unanswered, 0);
    // The < 1 ms RMS target is asserted on simulated time, where the wall clock cannot
    // decide it (`link_core_props::timesync_rms_under_1_ms_with_10_ms_jitter_on_simulated_time`);
    // here the error over the pty is printed in the summary.
    assert!(rms(&f.pos_err_m) < 0.05, "{}", f.summary("10 ms jitter"));
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ten_percent_dropped_messages() {
    let mut sim = sim_config(27);
    sim.faults.drop_rate = 0.1;
    let p = start(sim, |_| {}).await;
    p.health_until("synced", |h| h.synced && h.positions_accepted > 10)
        .await;
    let f = measure(&p, 150, Duration::from_millis(400)).await;
    println!("{}", f.summary("10 % dropped"));
    assert!(p.sim.stats().frames_dropped > 0);
    assert!(rms(&f.pos_err_m) < 0.05, "{}", f.summary("10 % dropped"));
    p.stop().await;
}
