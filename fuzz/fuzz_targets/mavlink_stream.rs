//! Arbitrary bytes as the flight controller's side of the link, read the way the link reads
//! them: mavlink's `AsyncMavlinkReader` accepting MAVLink 1 and 2 (the link's
//! `set_allow_recv_any_version(true)`), in reads of fuzzer-chosen sizes, some of which time out
//! and are cancelled (the link wraps every read in `timeout`). Each message then goes where the
//! link sends a received message that leaves the private tracker: the tap (re-encoded as a
//! MAVLink 2 frame for `telemetry.tlog`) and, for COMMAND_LONG, the camera protocol, whose
//! replies must all pass the send allow-list.
//!
//! Input: byte 0 seeds the read sizes; the rest is the stream.
#![no_main]

use std::future::Future;
use std::pin::{pin, Pin};
use std::task::{Context, Poll, Waker};

use alfd::capture::tlog;
use alfd::core::allowlist;
use alfd::daemon::camera::{CameraInfo, CameraProtocol};
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();
use mavlink::dialects::common::MavMessage;
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

fn command_of(msg: &MavMessage) -> Option<u32> {
    match msg {
        MavMessage::COMMAND_LONG(c) => Some(c.command as u32),
        _ => None,
    }
}

/// What the link does with one received message, minus the private tracker.
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
    // The allow-list is consulted for received ids only through replies; it must answer
    // every id without panicking.
    let _ = allowlist::may_send(msg.message_id(), command_of(msg));
    if let MavMessage::COMMAND_LONG(c) = msg {
        let params = [
            c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
        ];
        let replies = camera.on_command(
            c.command as u32,
            params,
            h.system_id as u8,
            h.component_id,
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
    let mut reader = AsyncMavlinkReader::new(Trickle {
        data: stream,
        state: 0x9E37_79B9 ^ u32::from(seed),
        stalled: false,
    });
    let mut camera = CameraProtocol::new(CameraInfo::for_alfd(640, 480));
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
