//! alfd's link against firmware-sim over a pseudo-terminal, no faults: it announces itself,
//! gets its rates acknowledged, synchronises, and its poses at 30 fps frame instants match the
//! truth (issue 5: within 5 cm RMS at 10 m/s with 10 Hz telemetry; also 5 and 50 Hz).

mod link_support;

use link_support::*;
use std::time::Duration;

async fn pose_accuracy(telemetry_hz: f64) -> Figures {
    let mut sim = sim_config(11);
    sim.streams.global_position_int = 10.0;
    sim.streams.attitude_quaternion = 10.0;
    let p = start(sim, |c| {
        c.position_hz = telemetry_hz;
        c.attitude_hz = telemetry_hz;
    })
    .await;
    p.health_until("rates acknowledged and time synced", |h| {
        h.rates_acked && h.synced
    })
    .await;
    // The rate change takes effect at the autopilot; let a second of it into the buffer.
    let since = alfd::link::mono_ns();
    p.fresh_after(since + 1_000_000_000).await;
    let f = measure(&p, 150, Duration::from_millis(400)).await;
    let h = p.link.health().borrow().clone();
    println!("{}", f.summary(&format!("{telemetry_hz} Hz telemetry")));
    assert_eq!(f.unanswered, 0, "every frame instant gets a pose: {h:?}");
    assert_eq!(h.glitches, 0);
    assert_eq!(h.rejected_time, 0);
    p.stop().await;
    f
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pose_within_5_cm_rms_at_10_hz() {
    let f = pose_accuracy(10.0).await;
    assert!(rms(&f.pos_err_m) < 0.05, "{}", f.summary("10 Hz"));
    // The time sync's < 1 ms RMS is asserted on simulated time
    // (`link_core_props::timesync_rms_under_1_ms_with_10_ms_jitter_on_simulated_time`); over
    // the pty it is a figure of this machine, printed in the summary.
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pose_at_5_hz_and_50_hz() {
    let f5 = pose_accuracy(5.0).await;
    let f50 = pose_accuracy(50.0).await;
    // Reported, and bounded loosely: the target is stated for 10 Hz.
    assert!(rms(&f5.pos_err_m) < 0.10, "{}", f5.summary("5 Hz"));
    assert!(rms(&f50.pos_err_m) < 0.05, "{}", f50.summary("50 Hz"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn announces_a_camera_and_requests_rates() {
    let mut p = start(sim_config(12), |_| {}).await;
    let hb = p
        .sim_event("alfd's heartbeat", |e| {
            matches!(e, firmware_sim::SimEvent::Received { msg_id: 0, .. })
        })
        .await;
    let firmware_sim::SimEvent::Received {
        system_id,
        component_id,
        ..
    } = hb
    else {
        unreachable!()
    };
    assert_eq!((system_id, component_id), (1, 100));
    p.sim_event("SET_MESSAGE_INTERVAL", |e| {
        matches!(
            e,
            firmware_sim::SimEvent::Received {
                msg_id: 76,
                command: Some(511),
                ..
            }
        )
    })
    .await;
    p.health_until("rates acknowledged", |h| h.rates_acked)
        .await;
    p.stop().await;
}
