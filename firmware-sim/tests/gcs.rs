//! firmware-sim's ground-station port: a UDP socket on port 0 plays the GCS, a MAVLink
//! connection on the pty plays the companion (system 1, component 100). The GCS sees the
//! autopilot and the companion's frames byte for byte; its commands reach the companion, or the
//! autopilot when addressed to it; the wire's faults stay on the companion's side.

use firmware_sim::SimConfig;
use mavlink::dialects::ardupilotmega::*;
use mavlink::{AsyncMavConnection, MAVLinkMessageRaw, MavHeader, MavlinkVersion, Message};
use std::net::SocketAddr;
use std::time::Duration;
use tokio::net::UdpSocket;

const GIVE_UP: Duration = Duration::from_secs(30);

type Conn = mavlink::AsyncConnection<MavMessage>;

/// A ground station: decodes every frame of every datagram and remembers who sent them.
struct Gcs {
    sock: UdpSocket,
    sim: Option<SocketAddr>,
    seq: u8,
}

/// A frame as the GCS received it.
struct Frame {
    raw: Vec<u8>,
    header: MavHeader,
    msg: MavMessage,
}

impl Gcs {
    async fn bind() -> Gcs {
        Gcs {
            sock: UdpSocket::bind("127.0.0.1:0").await.unwrap(),
            sim: None,
            seq: 0,
        }
    }

    fn address(&self) -> String {
        format!("udpout:{}", self.sock.local_addr().unwrap())
    }

    async fn next(&mut self, what: &str, mut pred: impl FnMut(&Frame) -> bool) -> Frame {
        let found = tokio::time::timeout(GIVE_UP, async {
            let mut buf = vec![0u8; 65_536];
            loop {
                let (n, from) = self.sock.recv_from(&mut buf).await.unwrap();
                self.sim = Some(from);
                let mut reader = mavlink::MavlinkReader::new(&buf[..n]);
                while let Ok(raw) = reader.read_any_raw_message::<MavMessage>() {
                    let Ok(msg) = MavMessage::parse(raw.version(), raw.message_id(), raw.payload())
                    else {
                        continue;
                    };
                    let f = Frame {
                        raw: match &raw {
                            MAVLinkMessageRaw::V1(r) => r.raw_bytes().to_vec(),
                            MAVLinkMessageRaw::V2(r) => r.raw_bytes().to_vec(),
                        },
                        header: MavHeader {
                            system_id: raw.system_id(),
                            component_id: raw.component_id(),
                            sequence: raw.sequence(),
                        },
                        msg,
                    };
                    if pred(&f) {
                        return f;
                    }
                }
            }
        })
        .await;
        found.unwrap_or_else(|_| panic!("the GCS never received {what}"))
    }

    /// Send as system 255, component 190 (MAV_COMP_ID_MISSIONPLANNER), to where the sim spoke from.
    async fn send(&mut self, msg: &MavMessage) {
        let header = MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: self.seq,
        };
        self.seq = self.seq.wrapping_add(1);
        let mut bytes = Vec::new();
        mavlink::write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, msg).unwrap();
        let to = self.sim.expect("heard the sim first");
        self.sock.send_to(&bytes, to).await.unwrap();
    }
}

async fn companion(address: &str) -> Conn {
    let mut c = mavlink::connect_async::<MavMessage>(address)
        .await
        .expect("open the pty");
    c.set_allow_recv_any_version(true);
    c
}

async fn companion_next(
    c: &Conn,
    mut pred: impl FnMut(&MavHeader, &MavMessage) -> bool,
) -> (MavHeader, MavMessage) {
    tokio::time::timeout(GIVE_UP, async {
        loop {
            if let Ok((h, m)) = c.recv().await {
                if pred(&h, &m) {
                    return (h, m);
                }
            }
        }
    })
    .await
    .expect("the companion received it")
}

const CAMERA: MavHeader = MavHeader {
    system_id: 1,
    component_id: 100,
    sequence: 0,
};

fn command(target_component: u8, command: MavCmd, param1: f32) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        command,
        param1,
        target_system: 1,
        target_component,
        ..Default::default()
    })
}

#[test]
fn gcs_address_is_checked() {
    let ok = SimConfig::from_toml("[link]\ngcs = \"udpout:127.0.0.1:14550\"\n").unwrap();
    assert_eq!(ok.gcs.as_deref(), Some("udpout:127.0.0.1:14550"));
    assert_eq!(SimConfig::default().gcs, None);
    for bad in [
        "udpin:127.0.0.1:14550",
        "udpout:127.0.0.1",
        "udpout:127.0.0.1:0",
        "udpout::14550",
    ] {
        let e = SimConfig::from_toml(&format!("[link]\ngcs = \"{bad}\"\n"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("link.gcs"), "{bad}: {e}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gcs_sees_the_autopilot_and_the_companion_and_commands_reach_the_companion() {
    let mut gcs = Gcs::bind().await;
    let cfg = SimConfig {
        gcs: Some(gcs.address()),
        ..Default::default()
    };
    let sim = firmware_sim::start(cfg).await.unwrap();
    let mut cam = companion(sim.address()).await;

    // The autopilot's own heartbeat, sent to the GCS directly.
    let hb = gcs
        .next("the autopilot's heartbeat", |f| {
            matches!(f.msg, MavMessage::HEARTBEAT(_)) && f.header.component_id == 1
        })
        .await;
    assert_eq!(hb.header.system_id, 1);
    let MavMessage::HEARTBEAT(h) = hb.msg else {
        unreachable!()
    };
    assert_eq!(h.mavtype, MavType::MAV_TYPE_QUADROTOR);

    // The companion's frames, forwarded unchanged: its ids, and the MAVLink 1 framing it chose
    // (re-encoding would have made it MAVLink 2).
    let heartbeat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_CAMERA,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        ..Default::default()
    });
    cam.send(&CAMERA, &heartbeat).await.unwrap();
    cam.set_protocol_version(MavlinkVersion::V1);
    let mut name = [0u8; 10];
    name[..7].copy_from_slice(b"ALF_SPC");
    let value = MavMessage::NAMED_VALUE_FLOAT(NAMED_VALUE_FLOAT_DATA {
        time_boot_ms: 1234,
        value: 12.5,
        name: name.into(),
    });
    cam.send(&CAMERA, &value).await.unwrap();
    cam.set_protocol_version(MavlinkVersion::V2);
    let from_cam = |f: &Frame| f.header.system_id == 1 && f.header.component_id == 100;
    let f = gcs
        .next("the companion's heartbeat", |f| {
            from_cam(f) && matches!(f.msg, MavMessage::HEARTBEAT(_))
        })
        .await;
    assert_eq!(f.msg, heartbeat);
    assert_eq!(f.raw[0], 0xFD, "MAVLink 2 as sent");
    let f = gcs
        .next("the companion's NAMED_VALUE_FLOAT", |f| {
            from_cam(f) && matches!(f.msg, MavMessage::NAMED_VALUE_FLOAT(_))
        })
        .await;
    assert_eq!(f.msg, value);
    assert_eq!(
        f.raw[0], 0xFE,
        "MAVLink 1 as sent: the bytes were not re-encoded"
    );

    // A command for the autopilot alone is answered to the GCS and not forwarded; one for the
    // camera is forwarded. Both travel the same ordered path, so if the first had been
    // forwarded the companion would see it before the second.
    gcs.send(&command(1, MavCmd::MAV_CMD_REQUEST_MESSAGE, 0.0))
        .await;
    gcs.send(&command(100, MavCmd::MAV_CMD_REQUEST_MESSAGE, 259.0))
        .await;
    let ack = gcs
        .next("the autopilot's COMMAND_ACK", |f| {
            f.header.component_id == 1 && matches!(f.msg, MavMessage::COMMAND_ACK(_))
        })
        .await;
    let MavMessage::COMMAND_ACK(a) = ack.msg else {
        unreachable!()
    };
    assert_eq!(a.command, MavCmd::MAV_CMD_REQUEST_MESSAGE);
    assert_eq!(a.result, MavResult::MAV_RESULT_ACCEPTED);
    assert_eq!((a.target_system, a.target_component), (255, 190));
    let (h, m) = companion_next(&cam, |h, m| {
        h.system_id == 255 && matches!(m, MavMessage::COMMAND_LONG(_))
    })
    .await;
    assert_eq!(h.component_id, 190);
    let MavMessage::COMMAND_LONG(c) = m else {
        unreachable!()
    };
    assert_eq!(
        c.target_component, 100,
        "the autopilot's own command was not forwarded"
    );
    assert_eq!(c.param1, 259.0);

    let s = sim.stats();
    assert!(s.forwarded_to_gcs >= 2, "{s:?}");
    assert!(s.forwarded_from_gcs >= 1, "{s:?}");
    assert!(s.gcs_sent >= 2, "{s:?}");
    sim.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn faults_stay_on_the_main_transport() {
    let mut gcs = Gcs::bind().await;
    let mut cfg = SimConfig::from_toml("[faults]\ndrop_rate = 1.0\n").unwrap();
    cfg.gcs = Some(gcs.address());
    let sim = firmware_sim::start(cfg).await.unwrap();
    for _ in 0..2 {
        gcs.next("a heartbeat", |f| matches!(f.msg, MavMessage::HEARTBEAT(_)))
            .await;
    }
    let s = sim.stats();
    assert_eq!(s.frames_sent, 0, "{s:?}");
    assert!(s.frames_dropped >= 2 && s.gcs_sent >= 2, "{s:?}");
    sim.shutdown().await;
}
