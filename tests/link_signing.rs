//! MAVLink 2 signing on alfd's link, against a peer the test plays over UDP (the system picks the
//! port): a peer with the same key is heard and hears only signed frames; one with another key,
//! unsigned or replaying is not heard (unless `accept_unsigned` lets unsigned frames in); pymavlink
//! and alfd verify each other's signatures; the key file is checked at start-up. Every "nothing
//! arrived" is closed by a correctly signed marker sent after it: the link keeps order, so once
//! the marker is through, everything before it has been judged. No sleeps.

mod tools;

use alfd::link::{self, LinkConfig, LinkConfigError, LinkEvent, LinkHandle, LinkHealth};
use mavlink::dialects::ardupilotmega::*;
use mavlink::{MAVLinkV2MessageRaw, MavHeader, MavlinkVersion, SigningConfig, SigningData};
use std::future::Future;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;
use tokio::net::UdpSocket;
use tokio::sync::{mpsc, oneshot};

/// Upper bound on any wait: a test that needs it has failed, it does not pace anything.
const GIVE_UP: Duration = Duration::from_secs(60);
const KEY_HEX: &str = "8f1c2a7e5b3d9c0146e2f7a8b9c0d1e2f3a4b5c6d7e8f9011223344556677889";
const OTHER_HEX: &str = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff";
/// The link id alfd signs with in these tests (not the default 0, to see it on the wire).
const LINK_ID: u8 = 7;

fn key(hex: &str) -> [u8; 32] {
    let mut k = [0u8; 32];
    for (i, b) in k.iter_mut().enumerate() {
        *b = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).expect("hex");
    }
    k
}

async fn within<T>(what: &str, f: impl Future<Output = T>) -> T {
    tokio::time::timeout(GIVE_UP, f)
        .await
        .unwrap_or_else(|_| panic!("gave up waiting for: {what}"))
}

fn write_key(dir: &Path, name: &str, contents: &[u8], mode: u32) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, contents).expect("key file written");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("chmod");
    path
}

fn config(address: &str, key_file: &Path, extra: &str) -> Result<LinkConfig, LinkConfigError> {
    LinkConfig::from_toml(&format!(
        "[mavlink]\naddress = {address:?}\nsigning_key_file = {:?}\n{extra}\n",
        key_file.display().to_string()
    ))
}

/// A signer as an autopilot or ground station would be: its own state, signing everything.
fn signer(hex: &str) -> SigningData {
    SigningData::from_config(SigningConfig::new(key(hex), 0, true, false))
}

/// A checker for the link's frames: signed with `hex` or refused.
fn checker(hex: &str) -> SigningData {
    SigningData::from_config(SigningConfig::new(key(hex), 0, false, false))
}

/// COMMAND_LONG to alfd (system 1, component 100); `tag` in param1 tells the frames apart.
fn command(tag: f32) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
        param1: tag,
        target_system: 1,
        target_component: 100,
        ..Default::default()
    })
}

fn autopilot_heartbeat() -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_STANDBY,
        mavlink_version: 3,
    })
}

/// alfd's link on `udpout:` to a socket the test holds, signing with `KEY_HEX`.
struct Rig {
    peer: UdpSocket,
    link_addr: SocketAddr,
    link: LinkHandle,
    events: mpsc::Receiver<LinkEvent>,
    /// The first datagram the link sent (its HEARTBEAT at connection).
    first: Vec<u8>,
    seq: u8,
    stop: oneshot::Sender<()>,
    task: tokio::task::JoinHandle<()>,
    _dir: tempfile::TempDir,
}

impl Rig {
    async fn start(accept_unsigned: bool) -> Rig {
        let dir = tempfile::tempdir().expect("temp dir");
        let key_file = write_key(
            dir.path(),
            "mavlink.key",
            format!("{KEY_HEX}\n").as_bytes(),
            0o600,
        );
        let peer = UdpSocket::bind("127.0.0.1:0").await.expect("bind");
        let port = peer.local_addr().expect("local address").port();
        // No silence reconnection during a test: a new connection would mean a new source port.
        let cfg = config(
            &format!("udpout:127.0.0.1:{port}"),
            &key_file,
            &format!(
                "signing_link_id = {LINK_ID}\naccept_unsigned = {accept_unsigned}\nsilence_reconnect_ms = 600000"
            ),
        )
        .expect("valid config");
        let (task, link, events) = link::new(cfg);
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(async move {
            task.run(async {
                let _ = stopped.await;
            })
            .await
            .expect("link runs");
        });
        let mut buf = vec![0u8; 512];
        let (n, link_addr) = within("the link's first frame", peer.recv_from(&mut buf))
            .await
            .expect("recv");
        buf.truncate(n);
        Rig {
            peer,
            link_addr,
            link,
            events,
            first: buf,
            seq: 0,
            stop,
            task,
            _dir: dir,
        }
    }

    /// One frame from system 1, `component`, MAVLink 2 signed by `signing` (or unsigned).
    fn frame(&mut self, component: u8, msg: &MavMessage, signing: Option<&SigningData>) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1);
        let header = MavHeader {
            system_id: 1,
            component_id: component,
            sequence: self.seq,
        };
        let mut out = Vec::new();
        mavlink::write_versioned_msg_signed(&mut out, MavlinkVersion::V2, header, msg, signing)
            .expect("encoded");
        out
    }

    fn frame_v1(&mut self, msg: &MavMessage) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1);
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: self.seq,
        };
        let mut out = Vec::new();
        mavlink::write_versioned_msg(&mut out, MavlinkVersion::V1, header, msg).expect("encoded");
        out
    }

    async fn send(&self, bytes: &[u8]) {
        self.peer
            .send_to(bytes, self.link_addr)
            .await
            .expect("sent");
    }

    /// The tags of every `LinkEvent::Command` up to and including `marker`.
    async fn commands_until(&mut self, marker: f32) -> Vec<f32> {
        let events = &mut self.events;
        within("the marker command", async {
            let mut tags = Vec::new();
            while let Some(e) = events.recv().await {
                if let LinkEvent::Command { params, .. } = e {
                    tags.push(params[0]);
                    if params[0] == marker {
                        return tags;
                    }
                }
            }
            panic!("the link stopped");
        })
        .await
    }

    async fn health_until(&self, what: &str, pred: impl FnMut(&LinkHealth) -> bool) -> LinkHealth {
        let mut rx = self.link.health();
        let h = within(what, rx.wait_for(pred))
            .await
            .expect("link alive")
            .clone();
        h
    }

    async fn stop(self) {
        let _ = self.stop.send(());
        self.task.await.expect("link task ends cleanly");
    }
}

/// Decode one datagram from the link, checking its signature with `check`.
fn decode(bytes: &[u8], check: &SigningData) -> Option<(MavHeader, MavMessage)> {
    mavlink::MavlinkReader::new(bytes)
        .read_any_message_signed(Some(check))
        .ok()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_peer_with_the_key_is_heard_and_hears_only_signed_frames() {
    let mut rig = Rig::start(false).await;

    // What alfd sends is signed: flag set, its link id, verified with the key and not without.
    let f = rig.first.clone();
    assert_eq!(f[0], 0xFD, "MAVLink 2");
    assert_eq!(f[2] & 0x01, 0x01, "IFLAG_SIGNED");
    assert_eq!(f[f.len() - 13], LINK_ID, "signature link id");
    let (h, m) = decode(&f, &checker(KEY_HEX)).expect("verified with the key");
    assert_eq!((h.system_id, h.component_id), (1, 100));
    assert!(
        matches!(m, MavMessage::HEARTBEAT(ref hb) if hb.mavtype == MavType::MAV_TYPE_CAMERA),
        "{m:?}"
    );
    assert!(
        decode(&f, &checker(OTHER_HEX)).is_none(),
        "another key does not verify it"
    );

    // A signed autopilot is heard: its heartbeat, then a command to us.
    let ap = signer(KEY_HEX);
    let hb = rig.frame(1, &autopilot_heartbeat(), Some(&ap));
    rig.send(&hb).await;
    let cmd = rig.frame(190, &command(1.0), Some(&ap));
    rig.send(&cmd).await;
    assert_eq!(rig.commands_until(1.0).await, vec![1.0]);
    let h = rig
        .health_until("two messages counted", |h| h.messages_rx >= 2)
        .await;
    assert_eq!((h.messages_rx, h.autopilot_heartbeats), (2, 1), "{h:?}");

    // A replayed frame (same bytes, same timestamp) is dropped; a fresh one gets through.
    rig.send(&cmd).await;
    let fresh = rig.frame(190, &command(2.0), Some(&ap));
    rig.send(&fresh).await;
    assert_eq!(rig.commands_until(2.0).await, vec![2.0], "replay dropped");

    // Everything alfd sends afterwards is signed too, with increasing timestamps (one checker
    // across all frames refuses a timestamp that does not grow): up to its rate requests, which
    // the autopilot's heartbeat prompted.
    let check = checker(KEY_HEX);
    let mut buf = vec![0u8; 512];
    let mut frames = 0;
    within("alfd's SET_MESSAGE_INTERVAL", async {
        loop {
            let (n, _) = rig.peer.recv_from(&mut buf).await.expect("recv");
            frames += 1;
            let (_, m) = decode(&buf[..n], &check)
                .unwrap_or_else(|| panic!("frame {frames} from alfd is not signed with the key"));
            if matches!(m, MavMessage::COMMAND_LONG(ref c) if c.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL)
            {
                break;
            }
        }
    })
    .await;
    rig.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn other_keys_unsigned_and_stale_frames_are_not_heard() {
    let mut rig = Rig::start(false).await;
    let wrong = signer(OTHER_HEX);
    for bytes in [
        rig.frame(1, &autopilot_heartbeat(), Some(&wrong)),
        rig.frame(190, &command(1.0), Some(&wrong)),
        rig.frame(1, &autopilot_heartbeat(), None),
        rig.frame(190, &command(2.0), None),
        rig.frame_v1(&command(3.0)),
        stale_frame(&command(4.0)),
    ] {
        rig.send(&bytes).await;
    }
    let marker = rig.frame(190, &command(99.0), Some(&signer(KEY_HEX)));
    rig.send(&marker).await;
    assert_eq!(rig.commands_until(99.0).await, vec![99.0]);
    let h = rig
        .health_until("the marker counted", |h| h.messages_rx >= 1)
        .await;
    assert_eq!(
        (h.messages_rx, h.autopilot_heartbeats, h.parse_errors),
        (1, 0, 0),
        "only the marker was accepted, and rejections are not parse errors: {h:?}"
    );
    rig.stop().await;
}

/// Signed with the right key, from a new stream (component 191), but stamped two minutes before
/// now: rust-mavlink refuses a new stream more than one minute behind its own timestamp.
fn stale_frame(msg: &MavMessage) -> Vec<u8> {
    let since_2015 = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("clock after 1970")
        .as_micros() as u64
        - 1_420_070_400_000_000;
    let stamp = since_2015 / 10 - 120 * 100_000;
    let mut raw = MAVLinkV2MessageRaw::new();
    let header = MavHeader {
        system_id: 1,
        component_id: 191,
        sequence: 0,
    };
    raw.serialize_message_for_signing(header, msg);
    *raw.signature_link_id_mut() = 0;
    raw.signature_timestamp_bytes_mut()
        .copy_from_slice(&stamp.to_le_bytes()[..6]);
    let mut sig = [0u8; 6];
    raw.calculate_signature(&key(KEY_HEX), &mut sig);
    raw.signature_value_mut().copy_from_slice(&sig);
    raw.raw_bytes().to_vec()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn accept_unsigned_lets_unsigned_frames_in_but_not_bad_signatures() {
    let mut rig = Rig::start(true).await;
    for bytes in [
        rig.frame(190, &command(1.0), Some(&signer(OTHER_HEX))),
        rig.frame(190, &command(2.0), None),
        rig.frame_v1(&command(3.0)),
    ] {
        rig.send(&bytes).await;
    }
    let marker = rig.frame(190, &command(99.0), Some(&signer(KEY_HEX)));
    rig.send(&marker).await;
    assert_eq!(rig.commands_until(99.0).await, vec![2.0, 3.0, 99.0]);
    // alfd still signs what it sends.
    assert!(decode(&rig.first, &checker(KEY_HEX)).is_some());
    rig.stop().await;
}

/// pymavlink (the reference implementation's signing) and alfd verify each other.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymavlink_and_alfd_verify_each_other() {
    if !tools::pymavlink("pymavlink_and_alfd_verify_each_other") {
        return;
    }
    // A ground station on udpin: it waits for alfd's signed camera heartbeat (pymavlink refuses
    // unsigned or badly signed frames once signing is set up), then sends a signed command.
    let script = r#"
import os, sys
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
m = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=1, source_component=190)
print("PORT", m.port.getsockname()[1], flush=True)
m.setup_signing(bytes.fromhex(sys.argv[1]), sign_outgoing=True, allow_unsigned_callback=None, link_id=3)
hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=30)
ok = hb is not None and hb.get_srcComponent() == 100 and hb._signed and hb._link_id == int(sys.argv[2])
m.mav.command_long_send(1, 100, 512, 0, 42, 0, 0, 0, 0, 0, 0)
print("SAW", "signed" if ok else "nothing", flush=True)
"#;
    let mut child = Command::new("python3")
        .args(["-c", script, KEY_HEX, &LINK_ID.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .expect("python3 runs");
    let mut out = BufReader::new(child.stdout.take().expect("stdout"));
    let mut first = String::new();
    out.read_line(&mut first).expect("the port line");
    let port: u16 = first
        .trim()
        .strip_prefix("PORT ")
        .and_then(|p| p.parse().ok())
        .expect("PORT <n>");
    let dir = tempfile::tempdir().expect("temp dir");
    let key_file = write_key(dir.path(), "mavlink.key", KEY_HEX.as_bytes(), 0o600);
    let cfg = config(
        &format!("udpout:127.0.0.1:{port}"),
        &key_file,
        &format!("signing_link_id = {LINK_ID}"),
    )
    .expect("valid config");
    let (task, _link, mut events) = link::new(cfg);
    let (stop, stopped) = oneshot::channel::<()>();
    let running = tokio::spawn(task.run(async {
        let _ = stopped.await;
    }));
    let got = within("pymavlink's signed command", async {
        loop {
            match events.recv().await {
                Some(LinkEvent::Command { params, .. }) => return params[0],
                Some(_) => continue,
                None => panic!("the link stopped"),
            }
        }
    })
    .await;
    assert_eq!(got, 42.0);
    let (line, status) = within(
        "python to exit",
        tokio::task::spawn_blocking(move || {
            let mut line = String::new();
            out.read_line(&mut line).expect("the verdict line");
            (line, child.wait().expect("python exits"))
        }),
    )
    .await
    .expect("joined");
    let _ = stop.send(());
    running.await.expect("joined").expect("link ran");
    assert!(status.success(), "python failed: {line}");
    assert_eq!(
        line.trim(),
        "SAW signed",
        "pymavlink verified alfd's heartbeat and link id"
    );
}

#[test]
fn key_file_problems_name_the_field() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let addr = "udpin:127.0.0.1:14550";
    let cases: Vec<(&str, PathBuf, &str, &str)> = vec![
        (
            "raw 32 bytes",
            write_key(d, "raw", &key(KEY_HEX), 0o600),
            "",
            "expected 64 hex characters",
        ),
        (
            "31 bytes in hex",
            write_key(d, "short", &KEY_HEX.as_bytes()[..62], 0o600),
            "",
            "got 62 bytes",
        ),
        (
            "not hex",
            write_key(d, "nothex", "zz".repeat(32).as_bytes(), 0o600),
            "",
            "non-hex",
        ),
        (
            "all zero",
            write_key(d, "zero", "00".repeat(32).as_bytes(), 0o600),
            "",
            "all-zero",
        ),
        (
            "group-readable",
            write_key(d, "group", KEY_HEX.as_bytes(), 0o640),
            "",
            "chmod 600",
        ),
        (
            "others-readable",
            write_key(d, "others", KEY_HEX.as_bytes(), 0o604),
            "",
            "chmod 600",
        ),
        ("missing", d.join("absent.key"), "", "no such file"),
        ("a directory", d.to_path_buf(), "", "not a regular file"),
        (
            "MAVLink 1",
            write_key(d, "v1", KEY_HEX.as_bytes(), 0o600),
            "mavlink_version = 1",
            "mavlink_version = 2",
        ),
    ];
    for (what, path, extra, says) in cases {
        let e = config(addr, &path, extra).expect_err(what);
        assert_eq!(e.field, "mavlink.signing_key_file", "{what}: {e}");
        assert!(e.problem.contains(says), "{what}: {e}");
        if extra.is_empty() {
            let shown = path.display().to_string();
            assert!(e.problem.contains(&shown), "{what}: names the file: {e}");
        }
        assert!(
            !e.problem.contains("zz") && !e.problem.contains(&KEY_HEX[..16]),
            "{what}: {e}"
        );
    }

    // The settings that only mean something with a key are refused without one.
    for (extra, field) in [
        ("accept_unsigned = true", "mavlink.accept_unsigned"),
        ("signing_link_id = 3", "mavlink.signing_link_id"),
    ] {
        let e = LinkConfig::from_toml(&format!("[mavlink]\naddress = {addr:?}\n{extra}\n"))
            .expect_err(extra);
        assert_eq!(e.field, field);
    }

    // Good files: with or without a final newline (LF or CRLF), upper or lower case.
    for (name, text) in [
        ("bare", KEY_HEX.to_string()),
        ("lf", format!("{KEY_HEX}\n")),
        ("crlf", format!("{}\r\n", KEY_HEX.to_uppercase())),
    ] {
        let path = write_key(d, name, text.as_bytes(), 0o400);
        let cfg = config(addr, &path, "").expect(name);
        let s = cfg.signing.as_ref().expect("signing on");
        assert_eq!(
            (s.key, s.link_id, s.accept_unsigned, s.key_file.clone()),
            (key(KEY_HEX), 0, false, path)
        );
        let shown = format!("{cfg:?}");
        assert!(
            shown.contains("<redacted>") && !shown.contains("key: ["),
            "{shown}"
        );
    }
    assert_eq!(
        LinkConfig::for_address(addr).signing,
        None,
        "off by default"
    );
}
