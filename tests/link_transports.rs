//! The same link over MAVLink 1, UDP and TCP (ports chosen by the system, never fixed), and its
//! refusal to send a message id above 255 on a MAVLink 1 link.

mod link_support;

use alfd::link::SendError;
use firmware_sim::Transport;
use link_support::*;
use mavlink::dialects::ardupilotmega::*;
use std::time::Duration;

async fn poses_flow(p: &Pair, label: &str) {
    p.health_until("synced", |h| {
        h.synced && h.rates_acked && h.positions_accepted > 10
    })
    .await;
    let f = measure(p, 30, Duration::from_millis(400)).await;
    println!("{}", f.summary(label));
    assert_eq!(f.unanswered, 0);
    assert!(rms(&f.pos_err_m) < 0.05, "{}", f.summary(label));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mavlink_1_both_ways() {
    let mut sim = sim_config(41);
    sim.mavlink_version = 1;
    let p = start(sim, |c| c.mavlink_version = 1).await;
    poses_flow(&p, "MAVLink 1 over a pty").await;
    let captured = MavMessage::CAMERA_IMAGE_CAPTURED(CAMERA_IMAGE_CAPTURED_DATA::default());
    assert_eq!(p.link.send(captured).await, Err(SendError::NotInV1(263)));
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn udp() {
    let mut sim = sim_config(42);
    sim.transport = Transport::Udp {
        bind: "127.0.0.1:0".into(),
    };
    let p = start(sim, |_| {}).await;
    assert!(p.sim.address().starts_with("udpout:127.0.0.1:"));
    poses_flow(&p, "UDP").await;
    p.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tcp() {
    let mut sim = sim_config(43);
    sim.transport = Transport::Tcp {
        bind: "127.0.0.1:0".into(),
    };
    let p = start(sim, |_| {}).await;
    assert!(p.sim.address().starts_with("tcpout:127.0.0.1:"));
    poses_flow(&p, "TCP").await;
    p.stop().await;
}
