//! Byte streams into alfd's parsers, as property tests over random and mutated inputs: the
//! MAVLink stream the link reads, the depth and camera-buffer decoders, scene and config files,
//! and what a flight directory holds (manifest, tlog, EXIF). Each must answer with a value or a
//! typed error, never a panic. The fuzz targets in `fuzz/` cover the same entry points for
//! longer (docs/fuzzing.md); every input they found crashing is a regression test at the end.
//! Cases per property: `ALFD_PROPTEST_CASES / 50` (default 2000).

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

use alfd::capture::exif::parse_exif_taken;
use alfd::capture::{
    exif_app1, find_exif_app1, geo_txt, parse_exif_gps, parse_manifest, tlog, transforms,
    CaptureRecord, ExifGps,
};
use alfd::config::Config;
use alfd::core::allowlist::{self, Trust};
use alfd::core::{DepthData, DepthImage};
use alfd::daemon::camera::{CameraInfo, CameraProtocol};
use alfd::depthio::{
    decode_depth, decode_pfm, decode_png16, decode_z16, encode_pfm, encode_png16, DepthFormat,
    ReadOptions,
};
use alfd::link::LinkConfig;
use alfd::scene::Scene;
use alfd::source::decode::{mjpeg_to_rgb, png_to_rgb, yuyv_to_rgb, z16_to_depth};
use firmware_sim::SimConfig;
use mavlink::dialects::ardupilotmega::*;
use mavlink::error::MessageReadError;
use mavlink::{AsyncMavlinkReader, MavHeader, MavlinkReader, Message};
use proptest::prelude::*;

/// One allocation larger than this aborts the test binary (run such tests through `in_child`):
/// every input here is at most tens of KiB, so an allocation this size is a decoder believing a
/// size field. On a system with less memory it would fail and abort anyway.
const ALLOC_LIMIT: usize = 256 << 20;

struct CappedAlloc;

unsafe impl std::alloc::GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        capped(layout.size());
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        capped(layout.size());
        unsafe { std::alloc::System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, size: usize) -> *mut u8 {
        capped(size);
        unsafe { std::alloc::System.realloc(ptr, layout, size) }
    }
}

fn capped(size: usize) {
    if size > ALLOC_LIMIT {
        let trace = std::backtrace::Backtrace::force_capture();
        eprintln!("allocation of {size} bytes (limit {ALLOC_LIMIT})\n{trace}");
        // Unwinding out of an allocator is not allowed.
        std::process::abort();
    }
}

#[global_allocator]
static ALLOC: CappedAlloc = CappedAlloc;

fn config() -> ProptestConfig {
    let n: u32 = std::env::var("ALFD_PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    ProptestConfig {
        cases: (n / 50).max(1),
        max_shrink_iters: 2000,
        ..ProptestConfig::default()
    }
}

// ---------------------------------------------------------------------------------------------
// Inputs: the repository's own files, and edits of them.

const Z16: &[u8] = include_bytes!("data/roof_160x120.z16");
const PNG: &[u8] = include_bytes!("data/buildings_320x240.png");
const PFM: &[u8] = include_bytes!("data/street_64x48.pfm");

const SCENES: &[&str] = &[
    include_str!("../scenes/building.toml"),
    include_str!("../scenes/district.toml"),
    include_str!("../scenes/edifice.toml"),
    include_str!("../scenes/open.toml"),
    include_str!("../scenes/roof.toml"),
    include_str!("../scenes/tree.toml"),
    include_str!("data/tower.toml"),
];

const CONFIGS: &[&str] = &[
    include_str!("../configs/estimator.toml"),
    include_str!("../configs/rpi-realsense.toml"),
    include_str!("../configs/sim.toml"),
];

/// firmware-sim configs (it ships none as files; these exercise every table).
const SIM_CONFIGS: &[&str] = &[
    "",
    "[link]\ntransport = \"udp\"\nbind = \"127.0.0.1:0\"\nmavlink_version = 1\ngcs = \"udpout:127.0.0.1:14550\"\n",
    "[survey]\npattern = \"line\"\nlength_m = 2000\nwind_m = 0\nlanes = 2\nspeed_mps = 5\n",
    "[streams]\nattitude_hz = 50\nglobal_position_int_hz = 20\nsystem_time_hz = 0\n[clock]\ndrift_ppm = -40\n",
    "[faults]\nseed = 7\ncorrupt_byte_rate = 0.001\ndrop_rate = 0.01\nlatency_ms = 5\njitter_ms = 2\n\
     [[faults.events]]\nat_s = 3\nkind = \"gps_glitch\"\nduration_s = 2\noffset_m = [30, 0, 0]\n\
     [[faults.events]]\nat_s = 8\nkind = \"reboot\"\n",
    "[truth]\npath = \"/tmp/truth.jsonl\"\nevery_step = true\n",
];

const MANIFEST_LINE: &str = r#"{"seq":7,"image":"IMG_000007.jpg","time_boot_us":121750000,"time_unix_us":1780000001750000,"mono_ns":6750000000,"position":{"lat_deg":47.39781,"lon_deg":8.545594,"alt_m":528.0,"rel_alt_m":40.0,"east_m":0.0,"north_m":7.7,"up_m":40.0},"attitude":{"roll_deg":1.5,"pitch_deg":-2.0,"yaw_deg":0.5,"camera_pitch_deg":0.0},"spacing":{"permissible_m":1.2,"chosen_m":1.2,"active_bound":"occlusion"},"distance_since_last_m":1.1,"occlusion":{"density_per_m":0.008,"degree":0.0096},"terms":["mmds","occlusion","coverage"],"model":"occlusion","capture_mode":"frame","undersampled":false,"rate_limited":false,"fallback":false,"pose_age_ms":42.0,"intrinsics":{"width":640,"height":480,"focal_px":465.0,"cx_px":320.0,"cy_px":240.0}}"#;

/// One edit of a byte string: overwrite, insert or delete at a position (taken modulo the length).
#[derive(Clone, Debug)]
enum Edit {
    Set(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    Truncate(usize),
}

fn edits(max: usize) -> impl Strategy<Value = Vec<Edit>> {
    let edit = prop_oneof![
        4 => (any::<usize>(), any::<u8>()).prop_map(|(p, b)| Edit::Set(p, b)),
        2 => (any::<usize>(), prop::collection::vec(any::<u8>(), 1..8)).prop_map(|(p, b)| Edit::Insert(p, b)),
        2 => (any::<usize>(), 1usize..16).prop_map(|(p, n)| Edit::Delete(p, n)),
        1 => any::<usize>().prop_map(Edit::Truncate),
    ];
    prop::collection::vec(edit, 0..max)
}

fn apply(base: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut v = base.to_vec();
    for e in edits {
        let at = |p: usize, len: usize| if len == 0 { 0 } else { p % (len + 1) };
        match e {
            Edit::Set(p, b) if !v.is_empty() => {
                let i = p % v.len();
                v[i] = *b;
            }
            Edit::Set(..) => {}
            Edit::Insert(p, bytes) => {
                let i = at(*p, v.len());
                v.splice(i..i, bytes.iter().copied());
            }
            Edit::Delete(p, n) => {
                let i = at(*p, v.len());
                let j = (i + n).min(v.len());
                v.drain(i..j);
            }
            Edit::Truncate(p) => {
                let i = at(*p, v.len());
                v.truncate(i);
            }
        }
    }
    v
}

/// Tokens that break TOML values in interesting ways (types, ranges, non-finite numbers).
const TOKENS: &[&str] = &[
    "0",
    "-1",
    "1e400",
    "-1e400",
    "nan",
    "inf",
    "-inf",
    "1e308",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "4294967296",
    "\"\"",
    "\"x\"",
    "[]",
    "[1, 2]",
    "{}",
    "true",
    "0.0",
    "1e-320",
    "\"serial:/dev/null:0\"",
    "\"udpin:0.0.0.0:0\"",
    "\"é\"",
];

/// A TOML text with some values replaced by `TOKENS`, some lines dropped or doubled, and some
/// characters changed (the result is always UTF-8).
fn toml_variant(bases: &'static [&'static str]) -> impl Strategy<Value = String> {
    let line_edit = (any::<usize>(), 0u8..4, 0..TOKENS.len());
    (
        0..bases.len(),
        prop::collection::vec(line_edit, 0..6),
        prop::collection::vec((any::<usize>(), any::<char>()), 0..3),
    )
        .prop_map(move |(i, line_edits, chars)| {
            let mut lines: Vec<String> = bases[i].lines().map(str::to_string).collect();
            for (p, op, t) in line_edits {
                if lines.is_empty() {
                    break;
                }
                let k = p % lines.len();
                match op {
                    0 | 1 => {
                        if let Some((key, _)) = lines[k].split_once('=') {
                            lines[k] = format!("{key}= {}", TOKENS[t]);
                        }
                    }
                    2 => {
                        lines.remove(k);
                    }
                    _ => {
                        let l = lines[k].clone();
                        lines.insert(k, l);
                    }
                }
            }
            let mut text = lines.join("\n");
            for (p, c) in chars {
                let idx: Vec<usize> = text.char_indices().map(|(i, _)| i).collect();
                if idx.is_empty() {
                    break;
                }
                let at = idx[p % idx.len()];
                text.insert(at, c);
            }
            text
        })
}

// ---------------------------------------------------------------------------------------------
// MAVLink: frames as the autopilot sends them, read as the link reads them.

/// The link's reader on a byte stream: MAVLink 1 and 2 (`set_allow_recv_any_version(true)`),
/// frames whose payload the dialect rejects skipped (the link counts them), to end of stream.
fn read_link_stream(bytes: &[u8]) -> Vec<(MavHeader, MavMessage)> {
    let mut reader = AsyncMavlinkReader::new(bytes);
    let mut cx = Context::from_waker(Waker::noop());
    let mut out = Vec::new();
    loop {
        let read = pin!(reader.read_any_message::<MavMessage>());
        // A byte slice is always ready, so one poll finishes the read.
        let Poll::Ready(r) = read.poll(&mut cx) else {
            panic!("a read from memory did not finish")
        };
        match r {
            Ok(m) => out.push(m),
            Err(MessageReadError::Parse(_)) => {}
            Err(MessageReadError::Io(_)) => return out,
        }
    }
}

fn encode(h: MavHeader, m: &MavMessage, v1: bool) -> Vec<u8> {
    let mut out = Vec::new();
    if v1 {
        mavlink::write_v1_msg(&mut out, h, m).expect("encodes as MAVLink 1");
    } else {
        mavlink::write_v2_msg(&mut out, h, m).expect("encodes as MAVLink 2");
    }
    out
}

/// What the link and the camera protocol do with one received message that can be checked
/// from outside: the tap frame fits the telemetry log and reads back; a COMMAND_LONG's
/// replies are all on the send allow-list.
fn digest(h: MavHeader, m: &MavMessage, camera: &mut CameraProtocol) {
    let tap = encode(h, m, false);
    assert_eq!(
        tlog::frame_len(&tap),
        Some(tap.len()),
        "tlog would refuse the tap of {h:?} {}",
        m.message_name()
    );
    let mut back = MavlinkReader::new(&tap[..]);
    let (h2, _) = back
        .read_any_message::<MavMessage>()
        .expect("a tapped frame reads back");
    assert_eq!(h2, h);
    if let MavMessage::COMMAND_LONG(c) = m {
        let p = [
            c.param1, c.param2, c.param3, c.param4, c.param5, c.param6, c.param7,
        ];
        let trust = if h.system_id == 1 {
            Trust::Accepted
        } else {
            Trust::Foreign
        };
        for r in camera.on_command(
            c.command as u32,
            p,
            h.system_id as u8,
            h.component_id,
            trust,
            0,
        ) {
            let cmd = match &r {
                MavMessage::COMMAND_LONG(c) => Some(c.command as u32),
                _ => None,
            };
            assert_eq!(allowlist::may_send(r.message_id(), cmd), Ok(()), "{r:?}");
        }
    }
}

/// The messages an autopilot sends alfd, one of each (the fuzz seeds).
fn specimens() -> Vec<MavMessage> {
    vec![
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 4,
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
            base_mode: MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }),
        MavMessage::SYSTEM_TIME(SYSTEM_TIME_DATA {
            time_unix_usec: 1_780_000_000_000_000,
            time_boot_ms: 120_000,
        }),
        MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
            time_boot_ms: 120_100,
            lat: 473_977_420,
            lon: 85_455_940,
            alt: 528_000,
            relative_alt: 40_000,
            vx: 1000,
            vy: -20,
            vz: 3,
            hdg: 9000,
        }),
        MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: 120_101,
            x: 1.2,
            y: -0.3,
            z: -40.0,
            vx: 10.0,
            vy: -0.2,
            vz: 0.03,
        }),
        MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
            time_boot_ms: 120_100,
            q1: 0.9990482,
            q2: 0.0,
            q3: -0.0436194,
            q4: 0.0,
            rollspeed: 0.01,
            ..Default::default()
        }),
        MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: 120_150,
            roll: 0.02,
            pitch: -0.05,
            yaw: 1.57,
            ..Default::default()
        }),
        MavMessage::GPS_RAW_INT(GPS_RAW_INT_DATA {
            time_usec: 120_100_000,
            lat: 473_977_420,
            lon: 85_455_940,
            fix_type: GpsFixType::GPS_FIX_TYPE_3D_FIX,
            satellites_visible: 14,
            ..Default::default()
        }),
        MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 120_000_000_000,
            target_system: 0,
            target_component: 0,
        }),
        MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 120_000_000_500,
            ts1: 6_000_000_000,
            target_system: 1,
            target_component: 100,
        }),
        MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            result: MavResult::MAV_RESULT_ACCEPTED,
            ..Default::default()
        }),
        MavMessage::CAMERA_TRIGGER(CAMERA_TRIGGER_DATA {
            time_usec: 120_200_000,
            seq: 3,
        }),
        MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
            param1: 259.0,
            target_system: 1,
            target_component: 100,
            ..Default::default()
        }),
        MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            command: MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            param3: 1.0,
            target_system: 1,
            target_component: 0,
            ..Default::default()
        }),
    ]
}

/// A finite f32 (NaN breaks the equality the stream property compares by).
fn f() -> impl Strategy<Value = f32> {
    prop_oneof![-1e6f32..1e6, Just(0.0f32), Just(f32::MAX)]
}

/// A message of the kinds an autopilot sends alfd, with random fields.
fn message() -> impl Strategy<Value = MavMessage> {
    prop_oneof![
        (any::<u32>(), any::<u8>()).prop_map(|(custom_mode, v)| MavMessage::HEARTBEAT(
            HEARTBEAT_DATA {
                custom_mode,
                mavtype: MavType::MAV_TYPE_QUADROTOR,
                autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
                base_mode: MavModeFlag::empty(),
                system_status: MavState::MAV_STATE_STANDBY,
                mavlink_version: v,
            }
        )),
        (any::<u64>(), any::<u32>()).prop_map(|(u, b)| MavMessage::SYSTEM_TIME(SYSTEM_TIME_DATA {
            time_unix_usec: u,
            time_boot_ms: b
        })),
        (any::<u32>(), any::<[i32; 4]>(), any::<[i16; 3]>()).prop_map(|(t, p, v)| {
            MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
                time_boot_ms: t,
                lat: p[0],
                lon: p[1],
                alt: p[2],
                relative_alt: p[3],
                vx: v[0],
                vy: v[1],
                vz: v[2],
                hdg: 0,
            })
        }),
        (any::<u32>(), [f(), f(), f()], [f(), f(), f()]).prop_map(|(t, p, v)| {
            MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
                time_boot_ms: t,
                x: p[0],
                y: p[1],
                z: p[2],
                vx: v[0],
                vy: v[1],
                vz: v[2],
            })
        }),
        (any::<u32>(), [f(), f(), f(), f()], [f(), f(), f(), f()]).prop_map(|(t, q, r)| {
            MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
                time_boot_ms: t,
                q1: q[0],
                q2: q[1],
                q3: q[2],
                q4: q[3],
                rollspeed: r[0],
                pitchspeed: r[1],
                yawspeed: r[2],
                repr_offset_q: [r[3], 0.0, 0.0, 0.0],
            })
        }),
        (any::<i64>(), any::<i64>(), any::<u8>()).prop_map(|(tc1, ts1, s)| MavMessage::TIMESYNC(
            TIMESYNC_DATA {
                tc1,
                ts1,
                target_system: s,
                target_component: 1,
            }
        )),
        (any::<u64>(), any::<u32>()).prop_map(|(t, seq)| MavMessage::CAMERA_TRIGGER(
            CAMERA_TRIGGER_DATA { time_usec: t, seq }
        )),
        ([f(), f(), f()], any::<u8>()).prop_map(|(p, s)| MavMessage::COMMAND_LONG(
            COMMAND_LONG_DATA {
                command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
                param1: p[0],
                param2: p[1],
                param3: p[2],
                target_system: s,
                target_component: 100,
                ..Default::default()
            }
        )),
    ]
}

fn header() -> impl Strategy<Value = MavHeader> {
    (1u32..=255, any::<u8>(), any::<u8>()).prop_map(|(system_id, component_id, sequence)| {
        MavHeader {
            system_id,
            component_id,
            sequence,
        }
    })
}

/// Line noise: random bytes, half the time salted with start markers (0xFE, 0xFD) and the
/// header bytes that make a candidate frame look plausible.
fn garbage() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..40),
        prop::collection::vec(
            prop_oneof![3 => any::<u8>(), 1 => Just(0xFDu8), 1 => Just(0xFEu8), 1 => Just(0u8)],
            0..40
        ),
    ]
}

/// What the reader makes of the candidate frame a start marker at `p` opens, by the MAVLink
/// framing rules (v1: 8 bytes plus the payload; v2: 12 plus the payload, plus 13 when signed
/// and 3 with a 32-bit system id; the CRC covers the header and payload and the message's extra
/// CRC byte).
enum Candidate {
    /// The stream ends before the frame does: the reader waits for bytes that never come.
    Cut,
    /// The bytes pass the CRC: the reader takes them (as a message, or as a frame it cannot
    /// parse) and skips what they cover.
    Taken(usize),
    /// The reader drops it and looks again from the next byte.
    Dropped,
}

fn candidate(b: &[u8], p: usize) -> Candidate {
    let Some(&n) = b.get(p + 1) else {
        return Candidate::Cut;
    };
    let n = usize::from(n);
    let (header, id_at) = if b[p] == 0xFE {
        (5, 5)
    } else {
        let Some(&flags) = b.get(p + 2) else {
            return Candidate::Cut;
        };
        if flags & !0x03 != 0 {
            return Candidate::Dropped;
        }
        if flags & 0x02 != 0 {
            (12, 10)
        } else {
            (9, 7)
        }
    };
    let signature = if b[p] == 0xFD && b[p + 2] & 0x01 != 0 {
        13
    } else {
        0
    };
    let len = 1 + header + n + 2 + signature;
    let Some(f) = b.get(p..p + len) else {
        return Candidate::Cut;
    };
    let id = if b[p] == 0xFE {
        u32::from(f[id_at])
    } else {
        u32::from_le_bytes([f[id_at], f[id_at + 1], f[id_at + 2], 0])
    };
    let end = 1 + header + n;
    let crc = u16::from_le_bytes([f[end], f[end + 1]]);
    if mavlink::calculate_crc(&f[1..end], MavMessage::extra_crc(id)) == crc {
        Candidate::Taken(len)
    } else {
        Candidate::Dropped
    }
}

struct Stream {
    bytes: Vec<u8>,
    /// Each real frame's byte range and what it decodes to on its own.
    frames: Vec<(std::ops::Range<usize>, (MavHeader, MavMessage))>,
    /// Stream positions of garbage bytes.
    garbage: Vec<usize>,
}

fn build_stream(parts: &[(MavHeader, MavMessage, bool, Vec<u8>)], tail: &[u8]) -> Stream {
    let mut s = Stream {
        bytes: Vec::new(),
        frames: Vec::new(),
        garbage: Vec::new(),
    };
    for (h, m, v1, noise) in parts {
        s.garbage.extend(s.bytes.len()..s.bytes.len() + noise.len());
        s.bytes.extend_from_slice(noise);
        let frame = encode(*h, m, *v1);
        // What this frame means on its own (MAVLink 1 drops extension fields).
        let alone = read_link_stream(&frame);
        assert_eq!(alone.len(), 1, "a lone frame reads as one message");
        let start = s.bytes.len();
        s.bytes.extend_from_slice(&frame);
        s.frames.push((start..s.bytes.len(), alone[0].clone()));
    }
    s.garbage.extend(s.bytes.len()..s.bytes.len() + tail.len());
    s.bytes.extend_from_slice(tail);
    s
}

/// Frames the garbage may have cost: those that overlap a candidate frame opened by a start
/// marker in the garbage that the reader takes (it passes its CRC by chance) or waits on until
/// the stream ends. A frame lost that way exposes its own marker bytes as candidates too, so
/// the set grows to a fixed point. (Conservative: candidates inside a taken one are never seen.)
fn touched(s: &Stream) -> Vec<bool> {
    let harm = |p: usize| match s.bytes[p] {
        0xFD | 0xFE => match candidate(&s.bytes, p) {
            Candidate::Cut => Some((p, usize::MAX)),
            Candidate::Taken(len) => Some((p, p + len)),
            Candidate::Dropped => None,
        },
        _ => None,
    };
    let mut spans: Vec<(usize, usize)> = s.garbage.iter().filter_map(|&p| harm(p)).collect();
    let mut hit = vec![false; s.frames.len()];
    loop {
        let mut grew = false;
        for (i, (r, _)) in s.frames.iter().enumerate() {
            if !hit[i] && spans.iter().any(|&(p, end)| p < r.end && r.start < end) {
                hit[i] = true;
                grew = true;
                spans.extend(r.clone().filter_map(harm));
            }
        }
        if !grew {
            return hit;
        }
    }
}

proptest! {
    #![proptest_config(config())]

    /// K frames with line noise between them: every frame the noise did not touch is read, in
    /// order and unchanged, so at least K minus the touched frames come out.
    #[test]
    fn mavlink_frames_survive_line_noise(
        parts in prop::collection::vec((header(), message(), any::<bool>(), garbage()), 1..24),
        tail in garbage(),
        live in any::<bool>(),
    ) {
        // A live link keeps sending: a candidate the noise opened near the end then completes
        // (and fails its CRC) instead of waiting for bytes that never come.
        let mut tail = tail;
        if live {
            tail.extend([0u8; 300]);
        }
        let s = build_stream(&parts, &tail);
        let hit = touched(&s);
        let got = read_link_stream(&s.bytes);
        let k = s.frames.len();
        let lost_at_most = hit.iter().filter(|h| **h).count();
        // Untouched frames form a subsequence of what was read.
        let mut it = got.iter();
        for ((_, want), touched) in s.frames.iter().zip(&hit) {
            if *touched {
                continue;
            }
            prop_assert!(it.any(|g| g == want), "frame {want:?} was not read; hit {hit:?}");
        }
        let real = s.frames.iter().filter(|(_, m)| got.contains(m)).count();
        prop_assert!(real >= k - lost_at_most, "{real} of {k} frames read, {lost_at_most} touched");
        // Clean noise (no start marker) costs nothing.
        if s.garbage.iter().all(|&p| !matches!(s.bytes[p], 0xFD | 0xFE)) {
            prop_assert_eq!(got.len(), k);
        }
    }

    /// Random bytes and edited frame streams through the link's reader and what it feeds.
    #[test]
    fn mavlink_stream_of_any_bytes(
        parts in prop::collection::vec((header(), message(), any::<bool>()), 0..8),
        edits in edits(12),
    ) {
        let mut bytes = Vec::new();
        for (h, m, v1) in &parts {
            bytes.extend(encode(*h, m, *v1));
        }
        let bytes = apply(&bytes, &edits);
        let got = read_link_stream(&bytes);
        prop_assert!(got.len() * 8 <= bytes.len());
        let mut camera = CameraProtocol::new(CameraInfo::for_alfd(640, 480));
        for (h, m) in &got {
            // 32-bit system ids: see `tap_of_a_32_bit_system_id_fits_the_tlog` below.
            if h.system_id <= 255 {
                digest(*h, m, &mut camera);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Depth files and camera buffers.

fn check_depth(img: &DepthImage) {
    let n = img.width() * img.height();
    let len = match img.data() {
        DepthData::Z16 { data, .. } => data.len(),
        DepthData::Metres(d) => d.len(),
    };
    assert!(n > 0);
    assert_eq!(len, n);
}

fn small_jpeg(w: u32, h: u32) -> Vec<u8> {
    let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
    alfd::capture::encode_jpeg(&rgb, w, h, 80, None).expect("encodes")
}

/// Whether any SOF marker segment in `jpeg` claims more than `pixels`.
fn jpeg_claims_over(jpeg: &[u8], pixels: u64) -> bool {
    jpeg.windows(9).any(|w| {
        w[0] == 0xFF
            && matches!(w[1], 0xC0..=0xCF)
            && !matches!(w[1], 0xC4 | 0xC8 | 0xCC)
            && u64::from(u16::from_be_bytes([w[5], w[6]]))
                * u64::from(u16::from_be_bytes([w[7], w[8]]))
                > pixels
    })
}

proptest! {
    #![proptest_config(config())]

    /// Edited depth files: an image of exactly width × height values, or an error of one line.
    #[test]
    fn depth_files_with_edits(which in 0usize..3, edits in edits(8), expect in any::<bool>()) {
        let (base, format, w, h) = match which {
            0 => (Z16, DepthFormat::Z16, 160, 120),
            1 => (PNG, DepthFormat::Png16, 320, 240),
            _ => (PFM, DepthFormat::Pfm, 64, 48),
        };
        let bytes = apply(base, &edits);
        let opts = ReadOptions {
            format: Some(format),
            width: (expect || format == DepthFormat::Z16).then_some(w),
            height: (expect || format == DepthFormat::Z16).then_some(h),
            scale_m: 0.001,
        };
        match decode_depth(&bytes, format, &opts) {
            Ok(img) => check_depth(&img),
            Err(e) => prop_assert!(!e.to_string().contains('\n'), "{e}"),
        }
    }

    /// Raw bytes with any stated size, through every decoder that takes one.
    #[test]
    fn depth_and_camera_buffers_of_any_bytes(
        bytes in prop::collection::vec(any::<u8>(), 0..512),
        w in prop_oneof![0usize..40, Just(usize::MAX), Just(1usize << 32)],
        h in prop_oneof![0usize..40, Just(usize::MAX), Just(1usize << 32)],
    ) {
        if let Ok(img) = decode_z16(&bytes, w, h, 0.001) {
            check_depth(&img);
        }
        if let Ok(img) = z16_to_depth(w, h, &bytes, 0.001) {
            check_depth(&img);
        }
        for img in [decode_png16(&bytes, 0.001, None), decode_pfm(&bytes, None)].into_iter().flatten() {
            check_depth(&img);
        }
        if w < 1 << 16 && h < 1 << 16 {
            if let Ok(c) = yuyv_to_rgb(w, h, &bytes) {
                prop_assert_eq!(c.rgb.len(), w * h * 3);
            }
        }
        if let Ok(c) = mjpeg_to_rgb(&bytes) {
            prop_assert_eq!(c.rgb.len(), c.width * c.height * 3);
        }
    }

    /// Edited camera frames: MJPEG with and without its Huffman tables, and a recorded
    /// session's PNG.
    #[test]
    fn camera_frames_with_edits(which in 0u8..3, edits in edits(6)) {
        let jpeg = small_jpeg(24, 16);
        let mjpeg = |b: Vec<u8>| {
            // Until `mjpeg_frame_claiming_a_huge_size_is_refused_before_allocating` passes.
            (!jpeg_claims_over(&b, 16 << 20)).then(|| mjpeg_to_rgb(&b).ok()).flatten()
        };
        let c = match which {
            0 => mjpeg(apply(&jpeg, &edits)),
            1 => mjpeg(apply(&alfd::capture::jpeg::without_huffman_tables(&jpeg), &edits)),
            _ => {
                let rgb: Vec<u8> = (0..12 * 8 * 3).map(|i| (i * 7) as u8).collect();
                let png = alfd::capture::encode_png(&rgb, 12, 8).unwrap();
                png_to_rgb(&apply(&png, &edits)).ok()
            }
        };
        if let Some(c) = c {
            prop_assert_eq!(c.rgb.len(), c.width * c.height * 3);
        }
    }

    /// An edited MJPEG frame kept as the camera encoded it (`capture.keep_camera_jpeg`)
    /// is refused, or stored with the EXIF segment; when the frame decodes, the stored
    /// one decodes to the same pixels: keeping a frame never changes it. (A frame that
    /// does not decode may once kept: `mjpeg_to_rgb` refuses a header claiming more
    /// pixels than the frame's bytes could carry, and the kept frame has the EXIF and
    /// table bytes added.)
    #[test]
    fn camera_jpeg_kept_as_received_decodes_as_the_frame(tables in any::<bool>(), edits in edits(6)) {
        let jpeg = small_jpeg(24, 16);
        let frame = apply(&if tables { jpeg } else { alfd::capture::jpeg::without_huffman_tables(&jpeg) }, &edits);
        // As in `camera_frames_with_edits`.
        prop_assume!(!jpeg_claims_over(&frame, 16 << 20));
        let gps = alfd::capture::ExifGps {
            lat_deg: 47.4,
            lon_deg: 8.5,
            alt_m: 500.0,
            time_unix_us: None,
            make: "alfd".into(),
            model: "uvc".into(),
        };
        let kept = alfd::capture::jpeg::as_received(&frame, |w, h| alfd::capture::exif_app1(&gps, w, h).ok());
        if let Ok(k) = kept {
            prop_assert!(alfd::capture::find_exif_app1(&k.bytes).is_some());
            if let Ok(want) = mjpeg_to_rgb(&frame) {
                let got = mjpeg_to_rgb(&k.bytes);
                prop_assert!(
                    got.as_ref() == Ok(&want),
                    "{}x{} kept as {:?}",
                    want.width,
                    want.height,
                    got.map(|c| (c.width, c.height))
                );
            }
        }
    }

    /// A PFM or PNG that decodes encodes back to the same values.
    #[test]
    fn decoded_depth_round_trips(w in 1usize..20, h in 1usize..20, seed in any::<u32>()) {
        let n = w * h;
        let z: Vec<u16> = (0..n as u32).map(|i| (i.wrapping_mul(seed) >> 7) as u16).collect();
        let png = encode_png16(w, h, &z).unwrap();
        let img = decode_png16(&png, 0.001, Some((w, h))).unwrap();
        prop_assert_eq!(img.data(), &DepthData::Z16 { data: z, scale_m: 0.001 });
        let m: Vec<f32> = (0..n as u32).map(|i| f32::from_bits(i.wrapping_mul(seed))).collect();
        let img = decode_pfm(&encode_pfm(w, h, &m), Some((w, h))).unwrap();
        let DepthData::Metres(back) = img.data() else { panic!() };
        prop_assert_eq!(back.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        m.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    }
}

// ---------------------------------------------------------------------------------------------
// Scene and config files.

proptest! {
    #![proptest_config(config())]

    #[test]
    fn scene_files_with_edits(text in toml_variant(SCENES)) {
        match Scene::parse(&text, "edited.toml") {
            Ok(s) => {
                prop_assert!((8..=8192).contains(&s.survey.width));
                prop_assert!(s.survey.view_count() <= 100_001);
            }
            Err(e) => {
                prop_assert!(!e.to_string().is_empty());
                if let Some(line) = e.line() {
                    prop_assert!(line >= 1 && line <= text.lines().count() + 1);
                }
            }
        }
    }

    /// An edited daemon config either parses (and the same text gives the same value) or its
    /// error names what is wrong: a field path, or the line of a TOML syntax error.
    #[test]
    fn config_files_with_edits(text in toml_variant(CONFIGS)) {
        check_config(&text)?;
    }

    #[test]
    fn sim_config_files_with_edits(text in toml_variant(SIM_CONFIGS)) {
        check_sim_config(&text)?;
    }

    #[test]
    fn any_text_as_a_scene_or_config(text in "\\PC{0,200}") {
        if let Err(e) = Scene::parse(&text, "any.toml") {
            prop_assert!(!e.to_string().is_empty());
        }
        check_config(&text)?;
        check_sim_config(&text)?;
    }
}

/// A field path as the config errors name one: `section.key`, a section alone, or an index.
fn is_field_path(f: &str) -> bool {
    !f.is_empty()
        && f.split('.').all(|p| {
            !p.is_empty()
                && p.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "_[]".contains(c))
        })
}

fn check_config(text: &str) -> Result<(), TestCaseError> {
    use alfd::config::ConfigError;
    match Config::from_text(text, "edited.toml") {
        Ok(c) => {
            let again = Config::from_text(text, "edited.toml").expect("the same text parses again");
            prop_assert_eq!(format!("{c:?}"), format!("{again:?}"));
        }
        Err(ConfigError::Invalid { field, message, .. }) => {
            prop_assert!(is_field_path(&field), "field {:?}: {}", field, message);
            prop_assert!(!message.is_empty());
        }
        Err(ConfigError::Parse { message, .. }) => {
            prop_assert!(message.contains("line"), "{}", message);
        }
        Err(e) => prop_assert!(false, "reading from text cannot fail to read: {}", e),
    }
    if let Err(e) = LinkConfig::from_toml(text) {
        prop_assert!(
            is_field_path(&e.field),
            "field {:?}: {}",
            e.field,
            e.problem
        );
        prop_assert!(!e.problem.is_empty());
    }
    Ok(())
}

fn check_sim_config(text: &str) -> Result<(), TestCaseError> {
    use firmware_sim::config::ConfigError;
    match SimConfig::from_toml(text) {
        Ok(c) => {
            let again = SimConfig::from_toml(text).expect("the same text parses again");
            prop_assert_eq!(format!("{c:?}"), format!("{again:?}"));
        }
        Err(ConfigError::Invalid { field, problem }) => {
            prop_assert!(is_field_path(field), "field {:?}: {}", field, problem);
        }
        Err(ConfigError::Parse(message)) => {
            prop_assert!(message.contains("line"), "{}", message);
        }
        Err(e) => prop_assert!(false, "reading from text cannot fail to read: {}", e),
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Flight directories: manifest, telemetry log, EXIF.

proptest! {
    #![proptest_config(config())]

    /// A manifest of good and edited lines: every complete line is a record or a bad line, and
    /// the exports take whatever records came out.
    #[test]
    fn manifests_with_edits(lines in prop::collection::vec(edits(3), 0..6), torn in any::<bool>()) {
        let mut bytes = Vec::new();
        for e in &lines {
            bytes.extend(apply(MANIFEST_LINE.as_bytes(), e));
            bytes.push(b'\n');
        }
        if torn {
            bytes.extend_from_slice(&MANIFEST_LINE.as_bytes()[..40]);
        }
        let m = parse_manifest(&bytes);
        let complete = bytes.iter().filter(|&&b| b == b'\n').count();
        prop_assert_eq!(m.records.len() + m.bad_lines.len(), complete);
        for r in &m.records {
            prop_assert!(CaptureRecord::from_json_line(&r.to_json_line()).is_ok());
        }
        // Every record is a line of geo.txt or a stated skip; the same for transforms.json.
        let (geo, skipped) = geo_txt(&m.records);
        prop_assert_eq!(geo.lines().count() - 1 + skipped.len(), m.records.len());
        let (nerf, skipped) = transforms(&m.records);
        prop_assert_eq!(nerf.map_or(0, |t| t.frames.len()) + skipped.len(), m.records.len());
    }

    /// A telemetry log of whole entries reads back entry for entry; after damage, the entries
    /// before it still do, and a restart keeps at least them.
    #[test]
    fn tlogs_read_back(
        frames in prop::collection::vec((header(), message(), any::<bool>(), any::<u64>()), 0..10),
        edits in edits(4),
    ) {
        let mut bytes = Vec::new();
        let mut encoded = Vec::new();
        for (h, m, v1, t) in &frames {
            let f = encode(*h, m, *v1);
            tlog::encode_entry(*t, &f, &mut bytes);
            encoded.push((*t, f));
        }
        let (entries, err) = tlog::parse(&bytes);
        prop_assert!(err.is_none());
        let got: Vec<(u64, Vec<u8>)> = entries.iter().map(|e| (e.unix_us, e.frame.to_vec())).collect();
        prop_assert_eq!(&got, &encoded);

        let damaged = apply(&bytes, &edits);
        let first_diff = bytes.iter().zip(&damaged).position(|(a, b)| a != b)
            .unwrap_or(bytes.len().min(damaged.len()));
        let (entries, _) = tlog::parse(&damaged);
        let mut end = 0;
        for (t, f) in &encoded {
            if end + 8 + f.len() > first_diff {
                break;
            }
            let e = entries.iter().find(|e| e.frame.as_ptr() == damaged[end + 8..].as_ptr());
            prop_assert!(e.is_some_and(|e| e.unix_us == *t && e.frame == &f[..]));
            end += 8 + f.len();
        }
        prop_assert!(tlog::complete_prefix_len(&damaged) >= end);
        prop_assert!(tlog::complete_prefix_len(&damaged) <= damaged.len());
    }

    /// EXIF segments as alfd writes them, edited, and JPEG files around them.
    #[test]
    fn exif_with_edits(edits in edits(6), lat in -90.0f64..90.0, lon in -180.0f64..180.0) {
        let g = ExifGps {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: 500.0,
            time_unix_us: Some(1_780_000_000_000_000),
            make: "alfd".into(),
            model: "sim".into(),
        };
        let app1 = exif_app1(&g, 640, 480).unwrap();
        // Damage may lose the position; what is read back is a position, never garbage.
        let sane = |p: &alfd::capture::exif::ParsedExif| {
            (-90.0..=90.0).contains(&p.lat_deg) && (-180.0..=180.0).contains(&p.lon_deg) && p.alt_m.is_finite()
        };
        // A capture time read back is a time: finite, its step a power of ten up to 1 s.
        let timely = |t: &alfd::capture::exif::TakenAt| {
            t.clock_s.is_finite() && t.resolution_s > 0.0 && t.resolution_s <= 1.0
        };
        let edited = apply(&app1, &edits);
        if let Ok(p) = parse_exif_gps(&edited) {
            prop_assert!(sane(&p), "{:?}", p);
        }
        if let Some(t) = parse_exif_taken(&edited) {
            prop_assert!(timely(&t), "{:?}", t);
        }
        let jpeg = alfd::capture::encode_jpeg(&[0; 8 * 8 * 3], 8, 8, 50, Some(app1)).unwrap();
        let jpeg = apply(&jpeg, &edits);
        if let Some(seg) = find_exif_app1(&jpeg) {
            if let Ok(p) = parse_exif_gps(seg) {
                prop_assert!(sane(&p), "{:?}", p);
            }
            if let Some(t) = parse_exif_taken(seg) {
                prop_assert!(timely(&t), "{:?}", t);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Regressions: inputs the fuzz targets found (docs/fuzzing.md).

/// A MAVLink 2 frame from a 32-bit system id (incompatibility flag 0x02, three more header
/// bytes) is a valid frame the link receives and taps; the telemetry log must measure it as
/// one frame, or the capture writer refuses it and stops logging telemetry for the flight.
/// Found by `mavlink_stream` (crash-2b8fb8c2…: a SYS_STATUS from system 3944045056).
#[test]
fn tap_of_a_32_bit_system_id_fits_the_tlog() {
    let h = MavHeader {
        system_id: 300,
        component_id: 1,
        sequence: 0,
    };
    let m = &specimens()[0];
    let frame = encode(h, m, false);
    assert_eq!(
        frame[2] & 0x02,
        0x02,
        "the frame carries the 32-bit system id flag"
    );
    let got = read_link_stream(&frame);
    assert_eq!(got, vec![(h, m.clone())], "the link reads it");
    assert_eq!(tlog::frame_len(&frame), Some(frame.len()));
    let mut log = Vec::new();
    tlog::encode_entry(1, &frame, &mut log);
    tlog::encode_entry(2, &frame, &mut log);
    let (entries, err) = tlog::parse(&log);
    assert_eq!(err, None);
    assert_eq!(entries.len(), 2);
}

/// V4L2 reports frame sizes as `u32`; sizes whose byte count overflows `usize` must give an
/// error, not an overflow (a panic with overflow checks, a wrongly sized image without).
/// Found by `depth_decoders` (crash-fa591c33…); the sizes are the crash's.
#[test]
fn yuyv_sizes_that_overflow_are_an_error() {
    let (w, h) = (0xC5C5_0008usize, 0xC5C5_C5C5usize);
    assert!(yuyv_to_rgb(w, h, &[0x11; 96]).is_err());
}

/// `[score] pitch_candidates_deg = [min, max, step]` whose count does not fit a `usize`: the
/// count was cast before it was checked, so the `+ 1` overflowed (a panic with overflow checks;
/// without them, zero candidates and no error). Found by `config_file` (crash-4840aa90…).
#[test]
fn config_with_an_overflowing_pitch_candidate_count_is_an_error() {
    let text = include_str!("data/fuzz/config-pitch-candidates-overflow.toml");
    let e = Config::from_text(text, "crash.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("score.pitch_candidates_deg") && e.contains("too many"),
        "{e}"
    );
}

/// Runs `body` in a child copy of this test binary: a failed allocation aborts the process,
/// which would take every other test down with it.
fn in_child(name: &str, body: impl FnOnce()) {
    if std::env::var("ALFD_BYTE_STREAMS_CHILD").as_deref() == Ok(name) {
        body();
        return;
    }
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args([name, "--exact", "--test-threads=1"])
        .env("ALFD_BYTE_STREAMS_CHILD", name)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{name} (in a child process): {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A recorded session's PNG frame whose header claims 65536 × 2147483656 RGB pixels, and holds
/// none: `png_to_rgb` allocated the claimed 422 TB up front, which aborts the process. Found by
/// `depth_decoders` before `camera_frames` split from it (crash-4b8b6788…, minimised to 41
/// bytes; its IHDR CRC recomputed, as fuzz
/// builds of the png crate skip CRC checks).
#[test]
fn png_frame_claiming_a_huge_size_is_an_error() {
    in_child("png_frame_claiming_a_huge_size_is_an_error", || {
        let png = include_bytes!("data/fuzz/png-ihdr-65536x2147483656.png");
        assert!(png_to_rgb(png).is_err());
    });
}

/// An MJPEG frame whose SOF0 claims 24600 × 60927 pixels in 194 bytes (as a USB transfer
/// error can garble a UVC camera's frame header): the decoder allocated 1.5 GB for it before
/// finding the data missing. On the flight computer that aborts the daemon or wakes the OOM
/// killer. Found by `depth_decoders` before `camera_frames` split from it (crash-22f69a33…,
/// minimised).
#[test]
fn mjpeg_frame_claiming_a_huge_size_is_refused_before_allocating() {
    in_child(
        "mjpeg_frame_claiming_a_huge_size_is_refused_before_allocating",
        || {
            let jpeg = include_bytes!("data/fuzz/mjpeg-sof-24600x60927.jpg");
            assert!(mjpeg_to_rgb(jpeg).is_err());
        },
    );
}

// ---------------------------------------------------------------------------------------------
// The fuzz seed corpus, written from the inputs above.

/// Writes `fuzz/corpus/<target>/seed-*`. Run by hand after changing a seed:
/// `cargo test --test byte_streams -- --ignored write_fuzz_seeds`.
#[test]
#[ignore = "writes the fuzz seed corpus into fuzz/corpus; run by hand"]
fn write_fuzz_seeds() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let put = |target: &str, name: &str, bytes: &[u8]| {
        let dir = root.join(target);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
    };

    // mavlink_stream: byte 0 seeds the read sizes.
    let autopilot = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    let gcs = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 9,
    };
    let mut flight = vec![0u8];
    for (i, m) in specimens().iter().enumerate() {
        let h = if matches!(m, MavMessage::COMMAND_LONG(_)) {
            gcs
        } else {
            autopilot
        };
        let h = MavHeader {
            sequence: i as u8,
            ..h
        };
        for v1 in [false, true] {
            let mut one = vec![i as u8];
            one.extend(encode(h, m, v1));
            put(
                "mavlink_stream",
                &format!("{}-v{}", m.message_name(), if v1 { 1 } else { 2 }),
                &one,
            );
        }
        flight.extend(encode(h, m, false));
    }
    put("mavlink_stream", "flight", &flight);
    let mut noisy = vec![7u8, 0xFD, 0x09, 0x00];
    for m in specimens() {
        noisy.extend_from_slice(&[0xFE, 0x21, 0x55]);
        noisy.extend(encode(autopilot, &m, false));
    }
    put("mavlink_stream", "noisy", &noisy);

    // depth_decoders: byte 0 picks the decoder, bytes 1..5 are width and height;
    // camera_frames: bit 7 of byte 0 picks PNG over MJPEG.
    let dims = |sel: u8, w: u16, h: u16| {
        let mut v = vec![sel];
        v.extend(w.to_le_bytes());
        v.extend(h.to_le_bytes());
        v
    };
    put(
        "depth_decoders",
        "z16",
        &[dims(0, 160, 120), Z16.to_vec()].concat(),
    );
    put(
        "depth_decoders",
        "z16-v4l2",
        &[dims(4, 160, 120), Z16.to_vec()].concat(),
    );
    put(
        "depth_decoders",
        "png16",
        &[dims(2 | 0x10, 320, 240), PNG.to_vec()].concat(),
    );
    put("depth_decoders", "pfm", &[&[3u8][..], PFM].concat());
    put(
        "depth_decoders",
        "depth-z16",
        &[dims(1 | 0x10, 160, 120), Z16.to_vec()].concat(),
    );
    put(
        "depth_decoders",
        "depth-png",
        &[dims(1 | 0x30, 320, 240), PNG.to_vec()].concat(),
    );
    put(
        "depth_decoders",
        "depth-pfm",
        &[dims(1 | 0x50, 64, 48), PFM.to_vec()].concat(),
    );
    let small_z: Vec<u16> = (0..48).map(|i| i * 1000).collect();
    let small_png = encode_png16(8, 6, &small_z).unwrap();
    put(
        "depth_decoders",
        "png16-small",
        &[dims(2, 8, 6), small_png].concat(),
    );
    let small_m: Vec<f32> = (0..48).map(|i| i as f32 * 0.5).collect();
    put(
        "depth_decoders",
        "pfm-small",
        &[&[3u8][..], &encode_pfm(8, 6, &small_m)].concat(),
    );
    let yuyv: Vec<u8> = (0..8 * 6 * 2).map(|i| (i * 13) as u8).collect();
    put("depth_decoders", "yuyv", &[dims(5, 8, 6), yuyv].concat());
    let jpeg = small_jpeg(24, 16);
    put("camera_frames", "mjpeg", &[&[6u8][..], &jpeg].concat());
    put(
        "camera_frames",
        "mjpeg-uvc",
        &[
            &[6u8][..],
            &alfd::capture::jpeg::without_huffman_tables(&jpeg),
        ]
        .concat(),
    );
    let rgb: Vec<u8> = (0..12 * 8 * 3).map(|i| (i * 7) as u8).collect();
    let png = alfd::capture::encode_png(&rgb, 12, 8).unwrap();
    put(
        "camera_frames",
        "png-rgb",
        &[&[6u8 | 0x80][..], &png].concat(),
    );
    let mut wide = dims(7, 0, 0);
    wide.extend(8u32.to_le_bytes());
    wide.extend(6u32.to_le_bytes());
    wide.extend(vec![0x11; 96]);
    put("depth_decoders", "wide", &wide);

    // scene_file, config_file.
    for (i, s) in SCENES.iter().enumerate() {
        put("scene_file", &i.to_string(), s.as_bytes());
    }
    for (i, s) in CONFIGS.iter().enumerate() {
        put("config_file", &format!("alfd-{i}"), s.as_bytes());
    }
    for (i, s) in SIM_CONFIGS.iter().enumerate().skip(1) {
        put("config_file", &format!("sim-{i}"), s.as_bytes());
    }

    // capture_manifest: a manifest, a tlog and an EXIF'd JPEG.
    let manifest = format!("{MANIFEST_LINE}\n{MANIFEST_LINE}\n{{\"seq\":");
    put("capture_manifest", "manifest", manifest.as_bytes());
    let mut log = Vec::new();
    for (i, m) in specimens().iter().enumerate() {
        tlog::encode_entry(
            1_780_000_000_000_000 + i as u64,
            &encode(autopilot, m, i % 3 == 0),
            &mut log,
        );
    }
    put("capture_manifest", "tlog", &log);
    let g = ExifGps {
        lat_deg: 47.39781,
        lon_deg: 8.545594,
        alt_m: 528.0,
        time_unix_us: Some(1_780_000_001_750_000),
        make: "alfd".into(),
        model: "sim".into(),
    };
    let app1 = exif_app1(&g, 8, 8).unwrap();
    put("capture_manifest", "exif", &app1);
    let jpeg = alfd::capture::encode_jpeg(&[90; 8 * 8 * 3], 8, 8, 50, Some(app1)).unwrap();
    put("capture_manifest", "jpeg", &jpeg);
}
