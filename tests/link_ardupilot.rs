//! alfd's link against ArduPilot's behaviours: firmware-sim's `ardupilot` profile over a pty
//! (positions at lat = lon = 0 until a late EKF origin, then a take-off with its landed state),
//! and a socket that sends the link frames as ArduPilot's routing may pass them on (MAVLink 1,
//! signed, undecodable), which `telemetry.tlog`'s tap must keep byte for byte.

use alfd::core::geo::{Geodetic, LocalFrame};
use alfd::link::{self, Airborne, AnchorSource, LinkConfig, PoseQueryError, TapFrame};
use firmware_sim::{SimConfig, SimEvent};
use mavlink::dialects::ardupilotmega::*;
use mavlink::{MavHeader, MavlinkVersion, SigningConfig, SigningData};
use std::future::Future;
use std::time::Duration;
use tokio::net::UdpSocket;
use tokio::sync::{mpsc, oneshot};

const GIVE_UP: Duration = Duration::from_secs(60);

async fn within<T>(what: &str, f: impl Future<Output = T>) -> T {
    tokio::time::timeout(GIVE_UP, f)
        .await
        .unwrap_or_else(|_| panic!("{what}: nothing within {GIVE_UP:?}"))
}

async fn sim_event(
    rx: &mut tokio::sync::broadcast::Receiver<SimEvent>,
    what: &str,
    pick: fn(&SimEvent) -> Option<u64>,
) -> u64 {
    within(what, async {
        loop {
            match rx.recv().await {
                Ok(e) => {
                    if let Some(t) = pick(&e) {
                        return t;
                    }
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(e) => panic!("{what}: {e}"),
            }
        }
    })
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_frame_waits_for_the_origin_and_poses_for_the_air() {
    let sim_cfg = SimConfig::from_toml(
        "autopilot = \"ardupilot\"\n\
         [vehicle]\norigin_delay_s = 2\nground_s = 4\nclimb_mps = 10\n\
         [survey]\npattern = \"line\"\nlength_m = 500\naltitude_m = 20\nwind_m = 0\n",
    )
    .unwrap();
    let sim = firmware_sim::start(sim_cfg).await.unwrap();
    let mut sim_events = sim.subscribe();
    let o = sim.origin();
    let origin = Geodetic {
        lat_deg: o[0],
        lon_deg: o[1],
        alt_m: o[2],
    };
    // No configured home: the link finds its frame by itself.
    let cfg = LinkConfig::for_address(sim.address());
    assert!(cfg.home.is_none() && cfg.require_airborne);
    let (task, link, _events) = link::new(cfg);
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(task.run(async {
        let _ = stopped.await;
    }));
    // Every vehicle state the link publishes, from the first.
    let mut state = link.state();
    let watcher = tokio::spawn(async move {
        let mut seen = Vec::new();
        while state.changed().await.is_ok() {
            if let Some(s) = state.borrow_and_update().clone() {
                seen.push(s);
                if seen.len() >= 5 {
                    return seen;
                }
            }
        }
        seen
    });
    let armed_at = sim_event(&mut sim_events, "armed", |e| match e {
        SimEvent::Armed { mono_ns } => Some(*mono_ns),
        _ => None,
    })
    .await;
    // Armed, anchored, in sync, but on the ground: no pose for a capture, and why.
    let t = link::mono_ns() - 100_000_000;
    let ground = link.pose_at_mono_ns(t).await;
    assert_eq!(
        ground,
        Err(PoseQueryError::NotAirborne(Airborne::Landed(1))),
        "{:?} s after arming",
        (t as f64 - armed_at as f64) * 1e-9
    );
    let seen = within("five vehicle states", watcher).await.unwrap();
    let first = &seen[0];
    // The first state the link ever published is in the frame of the EKF origin, not 0°, 0°.
    assert_eq!(first.origin_source, AnchorSource::Origin);
    let d = LocalFrame::new(origin).to_ned(first.home);
    assert!(d[0].hypot(d[1]) < 0.02 && d[2].abs() < 0.01, "{d:?}");
    assert!(first.position.lat_deg != 0.0 && first.position.lon_deg != 0.0);
    let truth = sim.truth_at_mono_ns(link::mono_ns());
    let here = LocalFrame::new(origin).to_ned(first.position);
    assert!(
        (here[0] - truth.pos_ned_m[0]).hypot(here[1] - truth.pos_ned_m[1]) < 0.5,
        "{here:?} vs {:?}",
        truth.pos_ned_m
    );
    sim_event(&mut sim_events, "in the air", |e| match e {
        SimEvent::InAir { mono_ns } => Some(*mono_ns),
        _ => None,
    })
    .await;
    let mut state = link.state();
    within(
        "the link sees the vehicle airborne",
        state.wait_for(|s| s.as_ref().is_some_and(|s| s.airborne.is_airborne())),
    )
    .await
    .unwrap();
    let t = link::mono_ns() - 150_000_000;
    let pose = link.pose_at_mono_ns(t).await.expect("a pose in the air");
    let truth = sim.truth_at_mono_ns(t);
    let err = (pose.pos_ned_m - glam::DVec3::from_array(truth.pos_ned_m)).length();
    assert!(
        err < 0.5,
        "pose {:?} vs truth {:?}",
        pose.pos_ned_m,
        truth.pos_ned_m
    );
    let h = link.health().borrow().clone();
    eprintln!(
        "FIGURE {} positions without an origin, {} anchor(s), {} glitches, {} origin requests; in-air pose {err:.3} m off the truth",
        h.positions_without_origin, h.origin_anchors, h.glitches, h.origin_requests
    );
    assert!(h.positions_without_origin >= 5);
    assert_eq!(h.origin_anchors, 1, "anchored once, never moved");
    assert_eq!(h.glitches, 0, "the origin's arrival is no GPS glitch");
    let _ = stop.send(());
    task.await.unwrap().unwrap();
    sim.shutdown().await;
}

/// X.25 CRC with MAVLink's CRC_EXTRA, over a frame's bytes after the start byte.
fn crc(bytes: &[u8], extra: u8) -> u16 {
    let mut c: u16 = 0xffff;
    for b in bytes.iter().chain([extra].iter()) {
        let mut t = b ^ (c & 0xff) as u8;
        t ^= t << 4;
        c = (c >> 8) ^ ((t as u16) << 8) ^ ((t as u16) << 3) ^ ((t as u16) >> 4);
    }
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_tap_keeps_every_frame_as_received() {
    let peer = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let port = peer.local_addr().unwrap().port();
    let mut cfg = LinkConfig::for_address(&format!("udpout:127.0.0.1:{port}"));
    cfg.silence_reconnect = Duration::from_secs(600);
    let (mut task, link, _events) = link::new(cfg);
    let (tap_tx, mut tap) = mpsc::channel::<TapFrame>(64);
    task.set_tap(tap_tx);
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(task.run(async {
        let _ = stopped.await;
    }));
    let mut buf = [0u8; 512];
    let (_, link_addr) = within("the link's first frame", peer.recv_from(&mut buf))
        .await
        .unwrap();
    let header = |sequence| MavHeader {
        system_id: 1,
        component_id: 1,
        sequence,
    };
    let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        mavlink_version: 3,
        ..Default::default()
    });
    // MAVLink 1, as a radio or an old ground station behind the autopilot sends it.
    let mut v1 = Vec::new();
    mavlink::write_versioned_msg(&mut v1, MavlinkVersion::V1, header(1), &hb).unwrap();
    // Signed (the link does not check signatures without a key of its own).
    let signing = SigningData::from_config(SigningConfig::new([7; 32], 3, true, false));
    let feedback = MavMessage::CAMERA_FEEDBACK(CAMERA_FEEDBACK_DATA {
        time_usec: 1_700_000_000_000_000,
        img_idx: 4,
        lat: 473_977_420,
        lng: 85_455_940,
        ..Default::default()
    });
    let mut signed = Vec::new();
    mavlink::write_versioned_msg_signed(
        &mut signed,
        MavlinkVersion::V2,
        header(2),
        &feedback,
        Some(&signing),
    )
    .unwrap();
    assert_eq!(signed[2] & 0x01, 0x01, "signed");
    // CRC-valid but undecodable: a HEARTBEAT whose vehicle type no enum has (200).
    let mut bad = Vec::new();
    mavlink::write_versioned_msg(&mut bad, MavlinkVersion::V2, header(3), &hb).unwrap();
    bad[10 + 4] = 200;
    let end = bad.len() - 2;
    let c = crc(&bad[1..end], 50);
    bad[end..].copy_from_slice(&c.to_le_bytes());
    let mut plain = Vec::new();
    mavlink::write_versioned_msg(&mut plain, MavlinkVersion::V2, header(4), &hb).unwrap();
    let sent = [v1, signed, bad, plain];
    for f in &sent {
        peer.send_to(f, link_addr).await.unwrap();
    }
    let mut got = Vec::new();
    while got.len() < sent.len() {
        let f = within("a tapped frame", tap.recv()).await.unwrap();
        got.push(f.bytes);
    }
    assert_eq!(got[0][0], 0xFE, "MAVLink 1 stays 1");
    for (k, (g, s)) in got.iter().zip(&sent).enumerate() {
        assert_eq!(g, s, "frame {k} as received");
    }
    let mut health = link.health();
    let h = within(
        "the CAMERA_FEEDBACK counted",
        health.wait_for(|h| h.camera_feedbacks == 1 && h.autopilot_heartbeats == 2),
    )
    .await
    .unwrap()
    .clone();
    assert_eq!(
        h.parse_errors, 1,
        "the undecodable frame is counted, not lost"
    );
    let _ = stop.send(());
    task.await.unwrap().unwrap();
}
