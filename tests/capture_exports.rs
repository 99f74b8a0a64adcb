//! The exports against their formats: `geo.txt` lines, `transforms.json` fields and
//! matrices, EXIF GPS read back by exiftool, and `telemetry.tlog` entries.

mod tools;

use std::fs;
use std::process::Command;

use alfd::capture::exif::{find_exif_app1, parse_exif_gps, parse_exif_taken};
use alfd::capture::export::{Skip, GEO_TXT, TRANSFORMS_JSON};
use alfd::capture::tlog;
use alfd::capture::{
    encode_capture, encode_jpeg, exif_app1, image_file_name, log_capture, read_manifest,
    write_exports, Attitude, CameraIntrinsics, CaptureMode, CaptureRecord, CaptureStore, DirStore,
    ExifGps, ImageFormat, MemStore, Position, Spacing, TlogWriter,
};
use serde_json::Value;

const W: u32 = 32;
const H: u32 = 24;

fn record(seq: u64, lat: f64, lon: f64, alt: f64, yaw: f64, cam_pitch: f64) -> CaptureRecord {
    CaptureRecord {
        seq,
        image: Some(image_file_name(seq, ImageFormat::Jpeg { quality: 90 })),
        time_boot_us: 90_000_000 + seq,
        time_unix_us: Some(1_780_123_456_000_000 + seq * 500_000),
        mono_ns: seq * 500_000_000,
        position: Position {
            lat_deg: lat,
            lon_deg: lon,
            alt_m: alt,
            rel_alt_m: 40.0,
            east_m: 10.0 * seq as f64,
            north_m: -5.0,
            up_m: 40.0,
        },
        attitude: Attitude {
            roll_deg: 0.0,
            pitch_deg: 0.0,
            yaw_deg: yaw,
            camera_pitch_deg: cam_pitch,
        },
        spacing: Spacing {
            permissible_m: None,
            chosen_m: 10.0,
            active_bound: "config_max".into(),
        },
        distance_since_last_m: None,
        occlusion: None,
        terms: vec![],
        quality: None,
        closed_loop: None,
        model: "fixed".into(),
        capture_mode: CaptureMode::Frame,
        undersampled: false,
        rate_limited: false,
        fallback: true,
        pose_age_ms: 3.0,
        intrinsics: Some(CameraIntrinsics {
            width: W,
            height: H,
            focal_px: 27.7,
            cx_px: 16.0,
            cy_px: 12.0,
        }),
        requested_by: None,
        image_missing: None,
        picture_after_ms: None,
    }
}

fn flight() -> Vec<CaptureRecord> {
    let mut external = record(3, 47.1, 8.1, 500.0, 0.0, 0.0);
    external.image = None;
    external.capture_mode = CaptureMode::CameraCommand;
    external.intrinsics = None;
    vec![
        record(1, 47.397_742_1, 8.545_594_3, 528.25, 0.0, 0.0),
        record(2, -33.856_784_5, 151.215_297_2, 12.5, 90.0, 30.0),
        external,
    ]
}

#[test]
fn geo_txt_lists_captured_images_lon_lat_alt_and_angles() {
    let mut store = MemStore::default();
    let summary = write_exports(&mut store, &flight()).unwrap();
    assert_eq!(summary.geo_lines, 2);
    assert_eq!(summary.geo_skipped, [(3, Skip::NoImage)]);
    let text = String::from_utf8(store.exports[GEO_TXT].clone()).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "EPSG:4326");
    assert_eq!(lines.len(), 3, "{text}");
    let fields: Vec<Vec<&str>> = lines[1..].iter().map(|l| l.split(' ').collect()).collect();
    let num = |s: &str| s.parse::<f64>().unwrap();
    // image_name geo_x (lon) geo_y (lat) geo_z yaw pitch roll
    assert_eq!(fields[0][0], "IMG_000001.jpg");
    assert_eq!(fields[0].len(), 7);
    assert!(!lines[1].contains("-0.0000"), "{}", lines[1]);
    assert!((num(fields[0][1]) - 8.545_594_3).abs() < 1e-9);
    assert!((num(fields[0][2]) - 47.397_742_1).abs() < 1e-9);
    assert!((num(fields[0][3]) - 528.25).abs() < 1e-3);
    // Nadir at vehicle yaw 0: ODM's image top points west, yaw −90, level.
    assert!((num(fields[0][4]) + 90.0).abs() < 1e-3, "{}", lines[1]);
    assert!(num(fields[0][5]).abs() < 1e-3 && num(fields[0][6]).abs() < 1e-3);
    assert_eq!(fields[1][0], "IMG_000002.jpg");
    assert!((num(fields[1][1]) - 151.215_297_2).abs() < 1e-9);
    assert!((num(fields[1][2]) + 33.856_784_5).abs() < 1e-9);
    // Heading east with the camera 30° forward: ODM's forward (image top) is north,
    // and the forward tilt is a roll of the ODM body towards the vehicle's heading:
    // Rx(−30°) turns ODM's down axis (0,0,1) to (0, sin 30°, cos 30°), i.e. east.
    assert!(num(fields[1][4]).abs() < 1e-3, "{}", lines[2]);
    assert!(num(fields[1][5]).abs() < 1e-3, "{}", lines[2]);
    assert!((num(fields[1][6]) + 30.0).abs() < 1e-3, "{}", lines[2]);
}

#[test]
fn transforms_json_has_intrinsics_and_camera_to_world_matrices() {
    let mut store = MemStore::default();
    let summary = write_exports(&mut store, &flight()).unwrap();
    assert_eq!(summary.transform_frames, Some(2));
    let v: Value = serde_json::from_slice(&store.exports[TRANSFORMS_JSON]).unwrap();
    assert_eq!(v["camera_model"], "OPENCV");
    assert_eq!(v["fl_x"], 27.7);
    assert_eq!(v["fl_y"], 27.7);
    assert_eq!(
        (v["cx"].as_f64(), v["cy"].as_f64()),
        (Some(16.0), Some(12.0))
    );
    assert_eq!((v["w"].as_u64(), v["h"].as_u64()), (Some(32), Some(24)));
    for k in ["k1", "k2", "p1", "p2"] {
        assert_eq!(v[k], 0.0, "{k}");
    }
    let frames = v["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 2);
    assert_eq!(frames[0]["file_path"], "IMG_000001.jpg");
    assert!(
        frames[0].get("fl_x").is_none(),
        "same intrinsics: not repeated"
    );
    let m = |f: &Value| -> Vec<Vec<f64>> {
        f["transform_matrix"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                r.as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect()
            })
            .collect()
    };
    // Frame 1: nadir, yaw 0 (derivation in src/capture/export.rs tests): GL x → north,
    // GL y → west, GL z → up; translation = ENU position.
    let want1 = [
        [0.0, -1.0, 0.0, 10.0],
        [1.0, 0.0, 0.0, -5.0],
        [0.0, 0.0, 1.0, 40.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    // Frame 2: yaw 90 (east), camera 30° forward. FRD: CV x = (√3/2, 0, −½),
    // CV y = (0,1,0), CV z = (½, 0, √3/2). Rotated to NED by Rz(90°): (x,y,z) →
    // (−y, x, z): CV x = (0, √3/2, −½), CV y = (−1, 0, 0), CV z = (0, ½, √3/2).
    // ENU (y, x, −z): CV x = (√3/2, 0, ½), CV y = (0, −1, 0), CV z = (½, 0, −√3/2).
    // GL = (CV x, −CV y, −CV z): columns (√3/2, 0, ½), (0, 1, 0), (−½, 0, √3/2).
    let s3 = 3f64.sqrt() / 2.0;
    let want2 = [
        [s3, 0.0, -0.5, 20.0],
        [0.0, 1.0, 0.0, -5.0],
        [0.5, 0.0, s3, 40.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    for (f, want) in frames.iter().zip([want1, want2]) {
        let got = m(f);
        for (g, w) in got.iter().zip(want) {
            for (a, b) in g.iter().zip(w) {
                assert!((a - b).abs() < 1e-12, "{}: {got:?}", f["file_path"]);
            }
        }
    }
}

#[test]
fn transforms_json_is_not_written_without_any_camera() {
    let mut store = MemStore::default();
    let s = write_exports(&mut store, &flight()[2..]).unwrap();
    assert_eq!(s.transform_frames, None);
    assert!(!store.exports.contains_key(TRANSFORMS_JSON));
    assert_eq!(store.exports[GEO_TXT], b"EPSG:4326\n");
}

#[test]
fn exif_gps_in_logged_jpegs_reads_back_with_exiftool() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = DirStore::open(tmp.path()).unwrap();
    let rgb: Vec<u8> = (0..W * H * 3).map(|i| (i % 256) as u8).collect();
    let records = flight();
    for r in &records[..2] {
        let gps = ExifGps::from_record(r, "alfd", "synthetic");
        let fmt = ImageFormat::Jpeg { quality: 80 };
        let (jpeg, tagged) = encode_capture(&rgb, W, H, fmt, Some(&gps)).unwrap();
        assert!(tagged);
        // The pure parser first: it needs no tool.
        let p = parse_exif_gps(find_exif_app1(&jpeg).unwrap()).unwrap();
        assert!((p.lat_deg - r.position.lat_deg).abs() < 1e-9);
        assert!((p.lon_deg - r.position.lon_deg).abs() < 1e-9);
        assert!((p.alt_m - r.position.alt_m).abs() < 1e-3);
        assert_eq!(p.gps_time_unix_us, r.time_unix_us);
        let taken = parse_exif_taken(find_exif_app1(&jpeg).unwrap()).unwrap();
        assert_eq!(taken.resolution_s, 0.001);
        let want_s = r.time_unix_us.unwrap() as f64 / 1e6;
        assert!(
            (taken.clock_s - want_s).abs() < 1e-6,
            "{taken:?}, want {want_s}"
        );
        log_capture(&mut store, r, Some(&jpeg)).unwrap();
    }
    if !tools::exiftool("exif_gps_in_logged_jpegs_reads_back_with_exiftool") {
        return;
    }
    let manifest = read_manifest(&store.manifest_path()).unwrap();
    let names: Vec<String> = manifest
        .records
        .iter()
        .filter_map(|r| r.image.clone())
        .collect();
    let out = Command::new("exiftool")
        .args([
            "-n",
            "-j",
            "-GPSLatitude",
            "-GPSLongitude",
            "-GPSAltitude",
            "-Make",
            "-GPSDateTime",
            "-SubSecDateTimeOriginal",
        ])
        .args(names.iter().map(|n| tmp.path().join(n)))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let tags = v.as_array().unwrap();
    assert_eq!(tags.len(), 2);
    for (t, r) in tags.iter().zip(&manifest.records) {
        let f = |k: &str| {
            t[k].as_f64()
                .unwrap_or_else(|| panic!("{k} missing in {t}"))
        };
        assert!((f("GPSLatitude") - r.position.lat_deg).abs() < 1e-6, "{t}");
        assert!((f("GPSLongitude") - r.position.lon_deg).abs() < 1e-6, "{t}");
        assert!((f("GPSAltitude") - r.position.alt_m).abs() < 0.01, "{t}");
        assert_eq!(t["Make"], "alfd");
    }
    // 1780123456.5 s = 2026-05-30 06:44:16.5 UTC (capture 1).
    assert_eq!(tags[0]["GPSDateTime"], "2026:05:30 06:44:16.5Z");
    // The camera's time to the millisecond, as a tool that pairs by time reads it.
    assert_eq!(tags[0]["SubSecDateTimeOriginal"], "2026:05:30 06:44:16.500");
    // Exif 2.3's required tags are all there: exiftool finds nothing to complain about.
    let out = Command::new("exiftool")
        .args(["-validate", "-warning", "-a", "-j"])
        .arg(tmp.path().join(&names[0]))
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v[0]["Validate"], "OK", "{}", v[0]);
}

/// A MAVLink frame of `msg` as a ground station would receive it.
fn frame(
    version: mavlink::MavlinkVersion,
    seq: u8,
    msg: &mavlink::dialects::ardupilotmega::MavMessage,
) -> Vec<u8> {
    let header = mavlink::MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: seq,
    };
    let mut out = Vec::new();
    mavlink::write_versioned_msg(&mut out, version, header, msg).unwrap();
    out
}

#[test]
fn telemetry_tlog_holds_timestamped_frames_as_received() {
    use mavlink::dialects::ardupilotmega::{MavMessage, ATTITUDE_DATA, HEARTBEAT_DATA};
    use mavlink::MavlinkVersion::{V1, V2};
    let msgs = [
        (V2, MavMessage::HEARTBEAT(HEARTBEAT_DATA::default())),
        (
            V2,
            MavMessage::ATTITUDE(ATTITUDE_DATA {
                time_boot_ms: 123_456,
                roll: 0.1,
                pitch: -0.2,
                yaw: 1.5,
                ..ATTITUDE_DATA::default()
            }),
        ),
        (V1, MavMessage::HEARTBEAT(HEARTBEAT_DATA::default())),
        (V2, MavMessage::HEARTBEAT(HEARTBEAT_DATA::default())),
    ];
    let frames: Vec<Vec<u8>> = msgs
        .iter()
        .enumerate()
        .map(|(i, (v, m))| frame(*v, i as u8, m))
        .collect();
    let t0 = 1_780_000_000_000_000u64;
    let times = [t0, t0 + 100_000, t0 + 1_200_000, t0 + 1_300_000];

    let tmp = tempfile::tempdir().unwrap();
    let mut store = DirStore::open(tmp.path()).unwrap();
    {
        let mut w = TlogWriter::new(&mut store, 1_000_000);
        for (t, f) in times.iter().zip(&frames) {
            w.write(*t, f).unwrap();
        }
        assert!(
            w.write(t0, &frames[0][..5]).is_err(),
            "a partial frame is refused"
        );
        w.sync().unwrap();
    }
    let bytes = fs::read(tmp.path().join("telemetry.tlog")).unwrap();
    assert_eq!(
        bytes.len(),
        frames.iter().map(|f| 8 + f.len()).sum::<usize>()
    );
    assert_eq!(&bytes[..8], &t0.to_be_bytes());
    let (entries, err) = tlog::parse(&bytes);
    assert_eq!(err, None);
    assert_eq!(entries.len(), 4);
    for ((e, t), (f, (v, m))) in entries.iter().zip(times).zip(frames.iter().zip(&msgs)) {
        assert_eq!(e.unix_us, t);
        assert_eq!(e.frame, &f[..]);
        let (_, back) = mavlink::MavlinkReader::new(e.frame)
            .read_message::<MavMessage>(*v)
            .unwrap();
        assert_eq!(&back, m);
    }

    // Syncs come from the entries' own clock: one at t0 + 1.2 s, one at the end.
    let mut mem = MemStore::default();
    let mut w = TlogWriter::new(&mut mem, 1_000_000);
    for (t, f) in times.iter().zip(&frames) {
        w.write(*t, f).unwrap();
    }
    assert_eq!(w.store().telemetry_syncs, 1);
    assert_eq!(
        w.store().telemetry_synced,
        8 * 3 + frames[..3].iter().map(Vec::len).sum::<usize>()
    );
    w.sync().unwrap();
    assert_eq!(mem.telemetry_syncs, 2);
    assert_eq!(mem.telemetry_synced, mem.telemetry.len());
    assert!(mem.free_bytes().is_none());
}

/// `alfd export DIR`, its exit status and stdout, stderr.
fn alfd_export(dir: &std::path::Path) -> (std::process::ExitStatus, String, String) {
    alfd_export_with(dir, &[])
}

/// `alfd export DIR ARGS…`.
fn alfd_export_with(
    dir: &std::path::Path,
    args: &[&std::ffi::OsStr],
) -> (std::process::ExitStatus, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_alfd"))
        .arg("export")
        .arg(dir)
        .args(args)
        .output()
        .unwrap();
    (
        out.status,
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A flight cut short (power lost mid-append: a torn last line, a temporary) has its
/// images and manifest but no exports; `alfd export` writes the ones the daemon
/// would have written at its stop, from the complete lines.
#[test]
fn a_flight_cut_short_gets_its_exports_from_alfd_export() {
    let tmp = tempfile::tempdir().unwrap();
    let flight_dir = tmp.path().join("flight-001");
    let records = flight();
    {
        let mut store = DirStore::open(&flight_dir).unwrap();
        for r in &records {
            let image = r.image.as_ref().map(|_| vec![0xFFu8, 0xD8, 0xFF, 0xD9]);
            log_capture(&mut store, r, image.as_deref()).unwrap();
        }
    }
    let manifest = flight_dir.join("manifest.jsonl");
    let complete = fs::read(&manifest).unwrap();
    let mut torn = complete.clone();
    torn.extend_from_slice(b"{\"seq\":4,\"ima");
    fs::write(&manifest, &torn).unwrap();
    fs::write(flight_dir.join(".IMG_000004.jpg.tmp"), b"half").unwrap();
    assert!(!flight_dir.join(GEO_TXT).exists());

    let (status, stdout, stderr) = alfd_export(&flight_dir);
    assert!(status.success(), "{stderr}");
    let mut want = MemStore::default();
    write_exports(&mut want, &records).unwrap();
    for name in [GEO_TXT, TRANSFORMS_JSON] {
        assert_eq!(
            fs::read(flight_dir.join(name)).unwrap(),
            want.exports[name],
            "{name}"
        );
    }
    assert_eq!(
        fs::read(&manifest).unwrap(),
        complete,
        "the torn line is cut"
    );
    assert!(!flight_dir.join(".IMG_000004.jpg.tmp").exists());
    assert!(stdout.contains("3 captures in manifest.jsonl"), "{stdout}");
    assert!(stdout.contains("recovered        13 bytes"), "{stdout}");
    assert!(
        stdout.contains("geo.txt          2 images (1 skipped: no_image 1)"),
        "{stdout}"
    );
    assert!(stdout.contains("transforms.json  2 frames"), "{stdout}");
    assert!(
        stdout.contains(
            "COLMAP model     cameras.txt, images.txt, points3D.txt: the same 2 images and poses"
        ),
        "{stdout}"
    );
    let images_txt = fs::read_to_string(flight_dir.join("images.txt")).unwrap();
    let named: Vec<&str> = images_txt
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
        .map(|l| l.rsplit(' ').next().unwrap())
        .collect();
    let transforms: serde_json::Value =
        serde_json::from_slice(&fs::read(flight_dir.join(TRANSFORMS_JSON)).unwrap()).unwrap();
    let frames: Vec<&str> = transforms["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file_path"].as_str().unwrap())
        .collect();
    assert_eq!(named, frames);

    // An image lost since (a card copied in part) is named, not passed over.
    fs::remove_file(flight_dir.join("IMG_000002.jpg")).unwrap();
    let (status, stdout, _) = alfd_export(&flight_dir);
    assert!(status.success());
    assert!(
        stdout.contains("missing images   1 listed but not in the directory: IMG_000002.jpg"),
        "{stdout}"
    );
    // Left out of the exports: a reconstruction tool stops at a file it cannot open.
    assert!(
        stdout.contains("geo.txt          1 images (2 skipped: no_image 2)"),
        "{stdout}"
    );
    let geo = fs::read_to_string(flight_dir.join(GEO_TXT)).unwrap();
    assert!(!geo.contains("IMG_000002.jpg"), "{geo}");
    let transforms = fs::read_to_string(flight_dir.join(TRANSFORMS_JSON)).unwrap();
    assert!(!transforms.contains("IMG_000002.jpg"), "{transforms}");
}

/// `alfd export DIR --images CAMERA`, its exit status and stdout, stderr.
fn alfd_export_images(
    dir: &std::path::Path,
    camera: &std::path::Path,
) -> (std::process::ExitStatus, String, String) {
    alfd_export_with(dir, &["--images".as_ref(), camera.as_os_str()])
}

/// A picture as an external camera writes it: a JPEG whose EXIF holds the time
/// its own clock read (here an hour and 0.1 s ahead of UTC, to the millisecond).
fn camera_picture(time_unix_us: u64) -> Vec<u8> {
    let g = ExifGps {
        lat_deg: 0.0,
        lon_deg: 0.0,
        alt_m: 0.0,
        time_unix_us: Some(time_unix_us + 3_600_100_000),
        make: "SONY".into(),
        model: "ILCE-7RM4".into(),
    };
    let rgb = vec![128u8; (W * H * 3) as usize];
    encode_jpeg(&rgb, W, H, 80, Some(exif_app1(&g, W, H).unwrap())).unwrap()
}

/// `n` (at most 10) captures of an external camera in `mode`, logged in `flight_dir`: no
/// image, 1.1 m apart north, at uneven intervals (1.5 to 3.3 s) as an adaptive spacing
/// gives, with UTC and boot times.
fn external_flight(
    flight_dir: &std::path::Path,
    n: usize,
    mode: CaptureMode,
) -> Vec<alfd::capture::CaptureRecord> {
    let gaps_s = [0.0, 2.1, 1.5, 3.3, 2.7, 1.9, 2.4, 3.0, 1.6, 2.2];
    let mut t_us = 1_780_123_456_000_000u64;
    let mut store = DirStore::open(flight_dir).unwrap();
    gaps_s[..n]
        .iter()
        .enumerate()
        .map(|(k, gap)| {
            t_us += (gap * 1e6) as u64;
            let seq = k as u64 + 1;
            let mut r = record(seq, 47.0 + seq as f64 * 1e-5, 8.5, 500.0, 0.0, 0.0);
            r.image = None;
            r.intrinsics = None;
            r.capture_mode = mode;
            r.time_unix_us = Some(t_us);
            r.time_boot_us = t_us - 1_780_000_000_000_000;
            // The autopilot reported most of a commanded camera's pictures.
            if mode == CaptureMode::CameraCommand && seq % 3 != 0 {
                r.picture_after_ms = Some(40.0 + seq as f64);
            }
            log_capture(&mut store, &r, None).unwrap();
            r
        })
        .collect()
}

/// A `camera_command` flight: the camera keeps its pictures on its card, the
/// manifest has a line per trigger. `alfd export --images` pairs the card's
/// pictures with the captures (here by time: a shot on the ground before take-off
/// and a missed trigger leave the counts equal and the order wrong), writes their
/// names and positions into geo.txt, and says what it left out and why; pictures
/// it cannot pair leave the exports as they were.
#[test]
fn an_external_cameras_pictures_are_paired_with_their_captures() {
    let tmp = tempfile::tempdir().unwrap();
    let flight_dir = tmp.path().join("flight-001");
    let card = tmp.path().join("DCIM");
    fs::create_dir(&card).unwrap();
    let records = external_flight(&flight_dir, 10, CaptureMode::CameraCommand);
    // A shot on the ground five minutes before; capture 4's trigger missed.
    let first_us = records[0].time_unix_us.unwrap();
    fs::write(
        card.join("DSC00001.JPG"),
        camera_picture(first_us - 300_000_000),
    )
    .unwrap();
    let mut name_of = std::collections::BTreeMap::new();
    for r in records.iter().filter(|r| r.seq != 4) {
        let name = format!("DSC{:05}.JPG", name_of.len() + 2);
        // The camera exposes 80 ms after the trigger.
        fs::write(
            card.join(&name),
            camera_picture(r.time_unix_us.unwrap() + 80_000),
        )
        .unwrap();
        name_of.insert(r.seq, name);
    }
    fs::write(card.join("DSC00002.ARW"), b"raw").unwrap();

    // Without the card: the captures are counted, and the way to pair them said.
    let (status, stdout, stderr) = alfd_export(&flight_dir);
    assert!(status.success(), "{stderr}");
    assert!(
        stdout.contains("geo.txt          0 images (10 skipped: no_image 10)"),
        "{stdout}"
    );
    assert!(
        stdout.contains("external camera  10 captures were taken by an external camera: pair its pictures with `alfd export")
            && stdout.contains("--images DIR`"),
        "{stdout}"
    );

    let (status, stdout, stderr) = alfd_export_images(&flight_dir, &card);
    assert!(status.success(), "{stderr}");
    let geo = fs::read_to_string(flight_dir.join(GEO_TXT)).unwrap();
    let lines: Vec<&str> = geo.lines().collect();
    assert_eq!(lines[0], "EPSG:4326");
    assert_eq!(lines.len(), 10, "{geo}");
    for (line, (seq, name)) in lines[1..].iter().zip(&name_of) {
        let r = &records[*seq as usize - 1];
        // Position only: the camera's mounting is not alfd's to know.
        let want = format!(
            "{name} {:.9} {:.9} {:.3}",
            r.position.lon_deg, r.position.lat_deg, r.position.alt_m
        );
        assert_eq!(*line, want);
    }
    assert!(!geo.contains("DSC00001.JPG"), "{geo}");
    assert!(!flight_dir.join(TRANSFORMS_JSON).exists());
    for want in [
        "camera           10 JPEG pictures in",
        "in the order of their EXIF capture times",
        "left alone       1 other file (raw, video, sidecars: not JPEG)",
        "paired           9 of 10 captures by time: in order, a picture would be 300.1 s from its capture's time",
        "camera clock     1 h 0 min 0.2 s ahead of UTC",
        "not paired       1 picture no capture triggered (left out): DSC00001.JPG",
        "no picture       1 capture the camera has no picture for: seq 4",
        "placed           7 of 10 commanded captures where the autopilot reported their picture (45 ms after alfd decided them, median), the rest where alfd decided them; --camera-delay-s is the camera's lag after that",
        "geo.txt          9 images (1 skipped: no_image 1)",
        "transforms.json  not written",
    ] {
        assert!(stdout.contains(want), "{want:?} not in\n{stdout}");
    }
    assert!(!stdout.contains("external camera  "), "{stdout}");

    // Pictures that cannot be told apart leave the exports as they were.
    let other = tmp.path().join("other");
    fs::create_dir(&other).unwrap();
    for k in 0..4u64 {
        let t = first_us + 5_000_000_000 + k * 700_000;
        fs::write(other.join(format!("IMG_{k}.JPG")), camera_picture(t)).unwrap();
    }
    let (status, _, stderr) = alfd_export_images(&flight_dir, &other);
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("4 pictures for 10 captures, and no one clock offset pairs more than"),
        "{stderr}"
    );
    assert_eq!(fs::read_to_string(flight_dir.join(GEO_TXT)).unwrap(), geo);
    // A card's root, whose pictures are in folders of it: every folder is read (the
    // other flight's pictures are left out by time), and the pairing is the same.
    let (status, stdout, stderr) = alfd_export_images(&flight_dir, tmp.path());
    assert!(status.success(), "{stderr}");
    assert!(
        stdout.contains("camera           14 JPEG pictures in 2 folders (")
            && stdout.contains("not paired       5 pictures no capture triggered (left out): DSC00001.JPG, IMG_0.JPG"),
        "{stdout}"
    );
    assert_eq!(fs::read_to_string(flight_dir.join(GEO_TXT)).unwrap(), geo);
    let (status, _, stderr) = alfd_export_images(&flight_dir, &tmp.path().join("nowhere"));
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("not a directory"), "{stderr}");

    // The camera's delay stated: each picture where the vehicle was 80 ms after its
    // trigger, along the way to the next capture (the last: from the one before).
    let delay = |more: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec!["--images".as_ref(), card.as_os_str()];
        args.extend(more.iter().map(|a| std::ffi::OsStr::new(*a)));
        alfd_export_with(&flight_dir, &args)
    };
    let (status, stdout, stderr) = delay(&["--camera-delay-s", "0.08"]);
    assert!(status.success(), "{stderr}");
    let moved = fs::read_to_string(flight_dir.join(GEO_TXT)).unwrap();
    let moved: Vec<&str> = moved.lines().skip(1).collect();
    assert_eq!(moved.len(), 9);
    for (line, (seq, name)) in moved.iter().zip(&name_of) {
        let k = *seq as usize - 1;
        let (a, b) = if k + 1 < records.len() {
            (&records[k], &records[k + 1])
        } else {
            (&records[k - 1], &records[k])
        };
        let dt_s = (b.time_unix_us.unwrap() - a.time_unix_us.unwrap()) as f64 * 1e-6;
        let f = 0.08 / dt_s;
        let r = &records[k];
        let lat = r.position.lat_deg + (b.position.lat_deg - a.position.lat_deg) * f;
        let lon = r.position.lon_deg + (b.position.lon_deg - a.position.lon_deg) * f;
        let want = format!("{name} {lon:.9} {lat:.9} {:.3}", r.position.alt_m);
        assert_eq!(*line, want);
    }
    assert!(
        stdout.contains(
            "camera delay     0.080 s: 9 pictures moved to the exposure along the way flown"
        ),
        "{stdout}"
    );
    // The manifest keeps the triggers' places.
    let kept = alfd::capture::read_manifest(&flight_dir.join("manifest.jsonl")).unwrap();
    assert_eq!(kept.records, records);
    for bad in ["-0.1", "3", "nan"] {
        let (status, _, stderr) = delay(&["--camera-delay-s", bad]);
        assert_eq!(status.code(), Some(2), "{bad}: {stderr}");
        assert!(stderr.contains("0 to 2 s"), "{bad}: {stderr}");
    }
    let (status, _, stderr) =
        alfd_export_with(&flight_dir, &["--camera-delay-s".as_ref(), "0.08".as_ref()]);
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("--images"), "{stderr}");
}

/// A flight the camera spread over two folders of its card (it starts a new one every
/// 999 or 9999 pictures): named both with `--images` twice, or the card's DCIM, the
/// pictures are one camera's. Names shared by the two folders carry their folder.
#[test]
fn a_flight_over_two_folders_of_the_card_is_paired_as_one() {
    let tmp = tempfile::tempdir().unwrap();
    let flight_dir = tmp.path().join("flight-001");
    let dcim = tmp.path().join("DCIM");
    let (a, b) = (dcim.join("100MEDIA"), dcim.join("101MEDIA"));
    fs::create_dir_all(&a).unwrap();
    fs::create_dir_all(&b).unwrap();
    let records = external_flight(&flight_dir, 8, CaptureMode::AutopilotDistance);
    // The first five in 100MEDIA (DJI_0995 … DJI_0999), the rest in 101MEDIA.
    let mut want = Vec::new();
    for (k, r) in records.iter().enumerate() {
        let (dir, name) = if k < 5 {
            (&a, format!("DJI_{:04}.JPG", 995 + k))
        } else {
            (&b, format!("DJI_{:04}.JPG", 1000 + k - 5))
        };
        fs::write(
            dir.join(&name),
            camera_picture(r.time_unix_us.unwrap() + 50_000),
        )
        .unwrap();
        want.push(format!(
            "{name} {:.9} {:.9} {:.3}",
            r.position.lon_deg, r.position.lat_deg, r.position.alt_m
        ));
    }
    let geo_lines = |stdout: &str| {
        let geo = fs::read_to_string(flight_dir.join(GEO_TXT)).unwrap();
        assert!(
            stdout.contains("paired           8 of 8 captures in order, and their times agree"),
            "{stdout}"
        );
        geo.lines().skip(1).map(str::to_owned).collect::<Vec<_>>()
    };
    // Both folders named.
    let (status, stdout, stderr) = alfd_export_with(
        &flight_dir,
        &[
            "--images".as_ref(),
            a.as_os_str(),
            "--images".as_ref(),
            b.as_os_str(),
        ],
    );
    assert!(status.success(), "{stderr}");
    assert!(
        stdout.contains("8 JPEG pictures in 2 folders ("),
        "{stdout}"
    );
    assert!(!stdout.contains("names            "), "{stdout}");
    assert_eq!(geo_lines(&stdout), want);
    // The card's DCIM: its folders in the order of their names.
    fs::remove_file(flight_dir.join(GEO_TXT)).unwrap();
    let (status, stdout, stderr) = alfd_export_images(&flight_dir, &dcim);
    assert!(status.success(), "{stderr}");
    assert_eq!(geo_lines(&stdout), want);
    // The card's mount point, holding DCIM beside the camera's other folders.
    fs::remove_file(flight_dir.join(GEO_TXT)).unwrap();
    fs::create_dir_all(tmp.path().join("PRIVATE/M4ROOT")).unwrap();
    let (status, stdout, stderr) = alfd_export_images(&flight_dir, tmp.path());
    assert!(status.success(), "{stderr}");
    assert_eq!(geo_lines(&stdout), want);
    // A camera that numbered the new folder from 1 again: DJI_0001.JPG in both would
    // be two pictures by one name, so every name carries its folder.
    fs::rename(b.join("DJI_1000.JPG"), b.join("DJI_0995.JPG")).unwrap();
    let (status, stdout, stderr) = alfd_export_images(&flight_dir, &dcim);
    assert!(status.success(), "{stderr}");
    assert!(
        stdout.contains("names            with their folder (DJI_0995.JPG is in two of them)"),
        "{stdout}"
    );
    let qualified: Vec<String> = want
        .iter()
        .enumerate()
        .map(|(k, l)| {
            let l = l.replace("DJI_1000.JPG", "DJI_0995.JPG");
            format!("{}/{l}", if k < 5 { "100MEDIA" } else { "101MEDIA" })
        })
        .collect();
    assert_eq!(geo_lines(&stdout), qualified);
    // The same folder twice is one folder.
    let (status, _, stderr) = alfd_export_with(
        &flight_dir,
        &[
            "--images".as_ref(),
            a.as_os_str(),
            "--images".as_ref(),
            a.as_os_str(),
        ],
    );
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("given twice"), "{stderr}");
}

/// A directory a daemon still writes is refused (its temporaries are images in
/// flight), and a path without a manifest is not made a flight directory.
#[test]
fn alfd_export_refuses_a_flight_in_use_and_a_path_without_a_manifest() {
    let tmp = tempfile::tempdir().unwrap();
    let flight_dir = tmp.path().join("flight-001");
    let mut store = DirStore::open(&flight_dir).unwrap();
    let r = &flight()[0];
    log_capture(&mut store, r, Some(&[0xFF, 0xD8, 0xFF, 0xD9])).unwrap();
    fs::write(flight_dir.join(".IMG_000002.jpg.tmp"), b"being written").unwrap();
    let (status, _, stderr) = alfd_export(&flight_dir);
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("in use by another process"), "{stderr}");
    assert!(flight_dir.join(".IMG_000002.jpg.tmp").exists());
    assert!(!flight_dir.join(GEO_TXT).exists());
    drop(store);

    let nowhere = tmp.path().join("flight-002");
    let (status, _, stderr) = alfd_export(&nowhere);
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("no manifest.jsonl here"), "{stderr}");
    assert!(!nowhere.exists());
}

/// `alfd run` restarted after a flight that stopped without its exports (systemd
/// restarts a killed daemon into a new flight) writes them before it starts the new
/// one, and says so; the new flight goes to the next directory.
#[test]
fn alfd_run_writes_the_exports_its_last_flight_stopped_without() {
    let tmp = tempfile::tempdir().unwrap();
    let captures = tmp.path().join("captures");
    let last = captures.join("flight-001");
    let records = flight();
    {
        let mut store = DirStore::open(&last).unwrap();
        for r in &records {
            let image = r.image.as_ref().map(|_| vec![0xFFu8, 0xD8, 0xFF, 0xD9]);
            log_capture(&mut store, r, image.as_deref()).unwrap();
        }
    }
    let seen = alfd_run_until_it_starts(tmp.path(), &captures);
    assert!(
        seen.iter()
            .any(|l| l.contains("flight-001 stopped without its exports")
                && l.contains("written now, 3 captures")),
        "{seen:#?}"
    );
    assert!(seen.last().unwrap().contains("flight-002"), "{seen:#?}");
    let mut want = MemStore::default();
    write_exports(&mut want, &records).unwrap();
    assert_eq!(fs::read(last.join(GEO_TXT)).unwrap(), want.exports[GEO_TXT]);
}

/// A last flight another process still writes (a second daemon on the same
/// capture directory) is not taken for one that stopped, nor touched.
#[test]
fn alfd_run_leaves_a_last_flight_another_process_writes() {
    let tmp = tempfile::tempdir().unwrap();
    let captures = tmp.path().join("captures");
    let last = captures.join("flight-001");
    let mut store = DirStore::open(&last).unwrap();
    log_capture(&mut store, &flight()[0], Some(&[0xFF, 0xD8, 0xFF, 0xD9])).unwrap();
    let seen = alfd_run_until_it_starts(tmp.path(), &captures);
    assert!(
        seen.iter()
            .any(|l| l.contains("flight-001 is being written by another process")),
        "{seen:#?}"
    );
    assert!(!last.join(GEO_TXT).exists());
    drop(store);
}

/// `alfd run` (the tower bench config, no autopilot) over `captures` until it says
/// where its captures go, then SIGTERM: its log lines to that point.
fn alfd_run_until_it_starts(dir: &std::path::Path, captures: &std::path::Path) -> Vec<String> {
    let config = dir.join("alfd.toml");
    let address = format!("serial:{}:921600", dir.join("no-tty").display());
    fs::write(
        &config,
        tools::synthetic_tower_config(&address, captures, "frame"),
    )
    .unwrap();
    let (mut child, lines) = tools::alfd_run_lines(&config, &[]);
    let mut seen = Vec::new();
    while !seen.iter().any(|l: &String| l.contains("captures go to")) {
        match lines.recv_timeout(std::time::Duration::from_secs(60)) {
            Ok(l) => seen.push(l),
            Err(_) => {
                child.kill().ok();
                panic!("no start within 60 s: {seen:#?}");
            }
        }
    }
    // SAFETY: signalling our own child by its pid.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    assert!(child.wait().unwrap().success());
    seen
}
