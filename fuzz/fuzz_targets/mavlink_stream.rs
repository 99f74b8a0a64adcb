//! Arbitrary bytes as the flight controller's side of the link, read the way the link reads
//! them: mavlink's `AsyncMavlinkReader` accepting MAVLink 1 and 2 (the link's
//! `set_allow_recv_any_version(true)`), in reads of fuzzer-chosen sizes, some of which time out
//! and are cancelled (the link wraps every read in `timeout`). Each message then goes where the
//! link sends a received message: its state machine (`link::Tracker`: TIMESYNC, the reboot
//! check, the glitch gate, the pose buffer, the vehicle state), the tap (re-encoded as a
//! MAVLink 2 frame for `telemetry.tlog`) and, for COMMAND_LONG, the camera protocol, whose
//! replies must all pass the send allow-list.
//!
//! Input: byte 0 seeds the read sizes; the rest is the stream. When byte 0's top bit is set,
//! the harness first rewrites the checksum of every frame it can find in the stream (the
//! dialect's CRC_EXTRA included), as a sender would: the fuzzer then reaches every message's
//! parser and the link's handling of it without having to forge a 16-bit CRC per message
//! id. With the bit clear the bytes go in as they are (line noise, forged CRCs). When bit 6
//! is set, the link side sees an autopilot with a consistent clock: a TIMESYNC reply answers
//! the harness's newest request (`ts1`) with the request time plus an offset the fuzzer
//! chose (its `tc1`), and the boot times of positions, attitudes and SYSTEM_TIME are that
//! clock's "now" give or take 128 ms (from their low bits), so time sync and the pose
//! queries are reached; with it clear every time field is taken as it came.
#![no_main]

use std::future::Future;
use std::pin::{pin, Pin};
use std::task::{Context, Poll, Waker};

use alfd::capture::tlog;
use alfd::core::allowlist::{self, Refusal, Trust};
use alfd::daemon::camera::{CameraInfo, CameraProtocol};
use alfd::link::{LinkConfig, Reaction, Tracker};
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::error::MessageReadError;
use mavlink::{AsyncMavlinkReader, MavHeader, MavlinkReader, Message};
use tokio::io::{AsyncRead, ReadBuf};

/// A byte stream that arrives in pieces of 1..=64 bytes, and sometimes not at all (`Pending`,
/// which the loop below treats as the link's read timeout firing).
struct Trickle<'a> {
    data: &'a [u8],
    state: u32,
    stalled: bool,
}

impl AsyncRead for Trickle<'_> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        _cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        // xorshift: deterministic for one input, different for each seed byte.
        let mut s = self.state;
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        self.state = s;
        if s.is_multiple_of(7) && !self.stalled && !self.data.is_empty() {
            self.stalled = true;
            return Poll::Pending;
        }
        self.stalled = false;
        let n = (1 + (s >> 8) as usize % 64)
            .min(self.data.len())
            .min(buf.remaining());
        let (head, tail) = self.data.split_at(n);
        buf.put_slice(head);
        self.data = tail;
        Poll::Ready(Ok(()))
    }
}

/// CRC-16/MCRF4XX, MAVLink's X.25 checksum.
fn crc_accumulate(crc: u16, bytes: &[u8]) -> u16 {
    bytes.iter().fold(crc, |crc, &b| {
        let mut t = b ^ (crc & 0xff) as u8;
        t ^= t << 4;
        (crc >> 8) ^ (u16::from(t) << 8) ^ (u16::from(t) << 3) ^ (u16::from(t) >> 4)
    })
}

/// Rewrites the checksum of each frame found in `stream` (scanning on from the end of each
/// one, or from the next byte when a start marker has no room for its frame).
fn repair_checksums(stream: &mut [u8]) {
    let mut i = 0;
    while i < stream.len() {
        // (header bytes after STX, message id); a 32-bit system id (incompat 0x02) moves the
        // component and message ids 3 bytes on.
        let (header, id) = match stream[i] {
            mavlink::MAV_STX if i + 6 <= stream.len() => (5, u32::from(stream[i + 5])),
            mavlink::MAV_STX_V2 if i + 3 <= stream.len() => {
                let at = i + if stream[i + 2] & 0x02 != 0 { 10 } else { 7 };
                let Some(id) = stream.get(at..at + 3) else {
                    i += 1;
                    continue;
                };
                (at - i + 2, u32::from_le_bytes([id[0], id[1], id[2], 0]))
            }
            _ => {
                i += 1;
                continue;
            }
        };
        let len = usize::from(stream[i + 1]);
        let end = i + 1 + header + len;
        if end + 2 > stream.len() {
            i += 1;
            continue;
        }
        let crc = crc_accumulate(0xffff, &stream[i + 1..end]);
        let crc = crc_accumulate(crc, &[MavMessage::extra_crc(id)]);
        stream[end..end + 2].copy_from_slice(&crc.to_le_bytes());
        let signed = stream[i] == mavlink::MAV_STX_V2 && stream[i + 2] & 0x01 != 0;
        i = end + 2 + if signed { 13 } else { 0 };
    }
}

/// The link's state machine fed as the link task feeds it: every message at its receive
/// instant, a TIMESYNC request before each one (so a reply can match), and the pose and
/// state it publishes checked for what the estimator and the capture log rely on.
struct LinkSide {
    tracker: Tracker,
    rx_ns: u64,
    /// Bit 6 of byte 0: the autopilot's clock made consistent (see the module doc).
    consistent_clock: bool,
    /// The autopilot's clock minus ours, as the last TIMESYNC reply set it.
    offset_ns: i64,
}

impl LinkSide {
    fn new(consistent_clock: bool) -> Self {
        LinkSide {
            tracker: Tracker::new(LinkConfig::for_address("udpin:127.0.0.1:14550")),
            rx_ns: 5_000_000_000,
            consistent_clock,
            offset_ns: 0,
        }
    }

    fn remote_ns(&self, local_ns: u64) -> u64 {
        (local_ns as i64).saturating_add(self.offset_ns).max(1) as u64
    }

    /// The autopilot's "now" in ms, moved by -128..=127 ms from the fuzzed value's low byte.
    fn boot_ms(&self, fuzzed: u32) -> u32 {
        let now_ms = (self.remote_ns(self.rx_ns) / 1_000_000) as i64;
        (now_ms + i64::from(fuzzed as u8) - 128).clamp(0, i64::from(u32::MAX)) as u32
    }

    /// `msg` as an autopilot whose clock is consistent with ours would have sent it.
    fn as_autopilot(&mut self, msg: &MavMessage, request_ns: u64) -> MavMessage {
        let mut m = msg.clone();
        match &mut m {
            MavMessage::TIMESYNC(t) if t.tc1 != 0 => {
                // tc1 read as the clock offset, within ±2^41 ns (about ±37 min).
                self.offset_ns = (t.tc1 as u64 % (1 << 42)) as i64 - (1 << 41);
                t.ts1 = request_ns as i64;
                t.tc1 = self.remote_ns(request_ns + 500) as i64;
            }
            MavMessage::GLOBAL_POSITION_INT(p) => p.time_boot_ms = self.boot_ms(p.time_boot_ms),
            MavMessage::ATTITUDE(a) => a.time_boot_ms = self.boot_ms(a.time_boot_ms),
            MavMessage::ATTITUDE_QUATERNION(a) => a.time_boot_ms = self.boot_ms(a.time_boot_ms),
            MavMessage::SYSTEM_TIME(t) => t.time_boot_ms = self.boot_ms(t.time_boot_ms),
            _ => {}
        }
        m
    }

    fn on_message(&mut self, h: &MavHeader, msg: &MavMessage, step_ns: u64) {
        self.rx_ns += step_ns;
        let request_ns = self.rx_ns;
        let request = self.tracker.timesync_request(request_ns);
        assert_eq!(
            allowlist::may_send(request.message_id(), None),
            Ok(()),
            "TIMESYNC request"
        );
        self.rx_ns += 1_000;
        let adjusted;
        let msg = if self.consistent_clock {
            adjusted = self.as_autopilot(msg, request_ns);
            &adjusted
        } else {
            msg
        };
        for r in self.tracker.on_message(h, msg, self.rx_ns) {
            if let Reaction::Reply(m) = r {
                assert_eq!(
                    allowlist::may_send(m.message_id(), command_of(&m)),
                    Ok(()),
                    "link reply {} is not on the allow-list",
                    m.message_name()
                );
            }
        }
        for at in [self.rx_ns, self.rx_ns.saturating_sub(150_000_000)] {
            if let Ok(p) = self.tracker.pose_at(at) {
                assert!(
                    p.pos_ned_m.is_finite() && p.vel_ned_mps.is_finite() && p.q.is_finite(),
                    "non-finite pose {p:?} at {at}"
                );
                assert!(
                    (p.q.length() - 1.0).abs() < 1e-6,
                    "pose attitude not a unit quaternion: {p:?}"
                );
            }
        }
        if let Some(s) = &self.tracker.state {
            assert!(
                s.pos_ned_m
                    .iter()
                    .chain(&s.vel_ned_mps)
                    .chain(&s.q)
                    .all(|v| v.is_finite()),
                "non-finite vehicle state {s:?}"
            );
        }
    }
}

/// Messages that set modes, missions, attitude, position or sticks: SET_MODE,
/// MISSION_ITEM, MANUAL_CONTROL, RC_CHANNELS_OVERRIDE, MISSION_ITEM_INT, COMMAND_INT,
/// SET_ATTITUDE_TARGET, SET_POSITION_TARGET_LOCAL_NED and _GLOBAL_INT.
const FLIGHT_MESSAGES: [u32; 9] = [11, 39, 69, 70, 73, 75, 82, 84, 86];
/// Commands that move or arm the vehicle: NAV_WAYPOINT, NAV_RETURN_TO_LAUNCH, NAV_LAND,
/// NAV_TAKEOFF, DO_SET_MODE, DO_REPOSITION, COMPONENT_ARM_DISARM.
const FLIGHT_COMMANDS: [u32; 7] = [16, 20, 21, 22, 176, 192, 400];

fn command_of(msg: &MavMessage) -> Option<u32> {
    match msg {
        MavMessage::COMMAND_LONG(c) => Some(c.command as u32),
        _ => None,
    }
}

/// What the link does with one received message besides its state machine (`LinkSide`).
fn digest(h: MavHeader, msg: &MavMessage, camera: &mut CameraProtocol) {
    // The tap: the link re-encodes every received message as a MAVLink 2 frame and the
    // capture writer appends it to telemetry.tlog, which refuses (and then stops logging)
    // anything `tlog::frame_len` does not measure as exactly one frame.
    let mut bytes = Vec::new();
    if mavlink::write_v2_msg(&mut bytes, h, msg).is_ok() {
        assert_eq!(
            tlog::frame_len(&bytes),
            Some(bytes.len()),
            "tlog would refuse the tap of {h:?} {}",
            msg.message_name()
        );
        // The tapped frame reads back as the same message, and re-encodes to the same bytes.
        let mut back = MavlinkReader::new(&bytes[..]);
        let (h2, m2) = back
            .read_any_message::<MavMessage>()
            .expect("a tapped frame reads back");
        assert_eq!(h2, h);
        let mut again = Vec::new();
        mavlink::write_v2_msg(&mut again, h2, &m2).expect("re-encodes");
        assert_eq!(again, bytes);
    }
    // Whatever comes in, nothing that flies the vehicle may go out: the allow-list refuses
    // every flight-control message and command (this list is independent of its tables).
    let answer = allowlist::may_send(msg.message_id(), command_of(msg));
    if FLIGHT_MESSAGES.contains(&msg.message_id()) {
        assert_eq!(answer, Err(Refusal::Message(msg.message_id())));
    }
    if let Some(cmd) = command_of(msg).filter(|c| FLIGHT_COMMANDS.contains(c)) {
        assert_eq!(answer, Err(Refusal::Command(cmd)));
    }
    if let MavMessage::COMMAND_LONG(c) = msg {
        let params = [
            c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
        ];
        let replies = camera.on_command(
            c.command as u32,
            params,
            h.system_id as u8,
            h.component_id,
            if h.system_id == 1 {
                Trust::Accepted
            } else {
                Trust::Foreign
            },
            1_000,
        );
        for r in &replies {
            assert_eq!(
                allowlist::may_send(r.message_id(), command_of(r)),
                Ok(()),
                "camera reply {} to {:?} is not on the allow-list",
                r.message_name(),
                c.command
            );
            let mut out = Vec::new();
            mavlink::write_v2_msg(&mut out, h, r).expect("a reply encodes");
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&seed, stream)) = data.split_first() else {
        return;
    };
    let mut repaired;
    let stream = if seed & 0x80 != 0 {
        repaired = stream.to_vec();
        repair_checksums(&mut repaired);
        &repaired[..]
    } else {
        stream
    };
    let mut reader = AsyncMavlinkReader::new(Trickle {
        data: stream,
        state: 0x9E37_79B9 ^ u32::from(seed),
        stalled: false,
    });
    let mut camera = CameraProtocol::new(CameraInfo::for_alfd(640, 480));
    let mut link = LinkSide::new(seed & 0x40 != 0);
    let mut cx = Context::from_waker(Waker::noop());
    let mut messages = 0usize;
    loop {
        let poll = {
            let read = pin!(reader.read_any_message::<MavMessage>());
            read.poll(&mut cx)
            // Dropped here when pending: the link's read timeout cancels the read the same way.
        };
        match poll {
            Poll::Pending => continue,
            Poll::Ready(Ok((h, msg))) => {
                messages += 1;
                // 0..=40 ms between messages, from the seed: bursts and gaps alike.
                let step_ns =
                    u64::from(seed.wrapping_mul(37).wrapping_add(messages as u8) % 41) * 1_000_000;
                link.on_message(&h, &msg, step_ns);
                digest(h, &msg, &mut camera);
            }
            // A frame with a good CRC and a payload the dialect rejects: the link counts it.
            Poll::Ready(Err(MessageReadError::Parse(_))) => {}
            Poll::Ready(Err(MessageReadError::Io(_))) => break,
        }
    }
    // Frames do not overlap and the shortest (MAVLink 1, empty payload) is 8 bytes.
    assert!(
        messages * 8 <= stream.len(),
        "{messages} messages from {} bytes",
        stream.len()
    );
});
