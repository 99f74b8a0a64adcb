//! The whole daemon against firmware-sim, in each capture mode, on simulated time (`alfd
//! sim`'s default: the same flight every run, `docs/daemon.md`): the manifest is checked
//! against the simulator's truth, the exports against their formats, and the simulator's
//! own view of what alfd commanded against the manifest. The daemon over a pty in real
//! time is flown by `daemon_faults` (unplug), `daemon_kill9`, `gcs_camera`,
//! `mavsdk_camera` and `daemon_speed_advice`.

mod tools;

use alfd::capture::{parse_exif_gps, read_manifest, tlog, CaptureMode, CaptureRecord};
use alfd::config::QualityPatch;
use alfd::core::attitude::body_to_ned;
use alfd::core::Model;
use alfd::daemon::sim::{
    run_sim_on_simulated_time, SimArgs, SimHooks, SimOutcome, SIMULATED_START_UNIX_US,
};
use alfd::simreport::ViolationClass;
use glam::{DMat3, DQuat};
use std::path::Path;

/// A short line over a tower at a small resolution: the same code paths as
/// the main job, in seconds.
fn args(out: &Path, mode: CaptureMode) -> SimArgs {
    SimArgs {
        out: out.to_path_buf(),
        width: 160,
        height: 120,
        mode,
        progress: false,
        length_m: Some(70.0),
        scene: Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tower.toml")),
        ..SimArgs::default()
    }
}

fn sim(mode: CaptureMode) -> (tempfile::TempDir, SimOutcome) {
    let dir = tempfile::tempdir().unwrap();
    let out = run_sim_on_simulated_time(
        args(dir.path(), mode),
        SimHooks::default(),
        std::future::pending(),
    )
    .expect("the sim runs");
    (dir, out)
}

/// On simulated time the writer is never behind (its deadline handling is
/// daemon_overload's to test), so no capture goes without its image.
fn every_capture_has_its_image(records: &[CaptureRecord]) {
    for r in records {
        assert!(
            r.image.is_some(),
            "capture {}: no image ({:?})",
            r.seq,
            r.image_missing
        );
    }
}

/// One pixel of `alfd sim`'s default camera (640 px wide, 465.6 px focal length: what the
/// COLMAP test reconstructs), in degrees. This test's own frames are smaller (a pixel is
/// 0.49 deg), too coarse to show a pose that misses its picture by a third of a degree.
const PIXEL_DEG: f64 = 0.123;

/// No interval longer than the truth's spacing where the daemon's own frames
/// could have said so (the list printed if not).
fn assert_no_avoidable_violation(out: &SimOutcome) {
    let s = &out.summary;
    assert_eq!(
        s.avoidable_violations,
        0,
        "{:?}",
        s.violation_list
            .iter()
            .filter(|v| v.class == ViolationClass::Avoidable)
            .collect::<Vec<_>>()
    );
}

/// Every record's pose is where firmware-sim says the vehicle truly was at the
/// record's instant, on both clocks.
fn check_against_truth(out: &SimOutcome, records: &[CaptureRecord]) {
    assert!(!records.is_empty());
    let mut worst_deg = 0.0_f64;
    for (k, r) in records.iter().enumerate() {
        assert_eq!(
            r.seq,
            k as u64 + 1,
            "sequence numbers run from 1 without gaps"
        );
        // Position: within 0.3 m of the truth at the same instant (the pose is
        // interpolated from 10 Hz telemetry; the vehicle flies at 10 m/s).
        let tr = &out.truth_at_records[k];
        let dn = (r.position.lat_deg - tr.lat_deg).to_radians() * 6_371_000.0;
        let de = (r.position.lon_deg - tr.lon_deg).to_radians()
            * 6_371_000.0
            * tr.lat_deg.to_radians().cos();
        assert!(
            dn.hypot(de) < 0.3,
            "capture {}: {dn:.3} m N, {de:.3} m E off the truth",
            r.seq
        );
        assert!(
            (r.position.alt_m - tr.alt_m).abs() < 0.3,
            "{} vs {}",
            r.position.alt_m,
            tr.alt_m
        );
        // Height above home: the truth's local frame has its origin on the ground.
        assert!((r.position.rel_alt_m + tr.pos_ned_m[2]).abs() < 0.3);
        // Autopilot clock: within 5 ms of the truth's boot time.
        let boot_ms = r.time_boot_us as f64 / 1000.0;
        assert!(
            (boot_ms - tr.time_boot_ms).abs() < 5.0,
            "capture {}: boot {boot_ms} ms vs truth {} ms",
            r.seq,
            tr.time_boot_ms
        );
        assert_eq!(
            r.pose_age_ms, 0.0,
            "capture {}: its pose was extrapolated",
            r.seq
        );
        // Attitude: the logged roll, pitch and yaw against the truth's quaternion at the
        // same instant, as one angle, within one pixel of the default camera (the picture is
        // rendered at the truth). A pose extrapolated past the newest 10 Hz
        // sample overshot the end of the start-up turn by 0.3 deg: it is interpolated
        // once the sample after the capture is in.
        let a = &r.attitude;
        let logged = body_to_ned(
            a.roll_deg.to_radians(),
            a.pitch_deg.to_radians(),
            a.yaw_deg.to_radians(),
        );
        let [w, x, y, z] = tr.q;
        let truth = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize());
        let d = logged.transpose() * truth;
        let cos = ((d.x_axis.x + d.y_axis.y + d.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0);
        let off_deg = cos.acos().to_degrees();
        worst_deg = worst_deg.max(off_deg);
        assert!(
            off_deg < PIXEL_DEG,
            "capture {}: attitude {off_deg:.3} deg off the truth, a pixel is {PIXEL_DEG} deg (logged r/p/y {:.2}/{:.2}/{:.2}, truth {:.2?})",
            r.seq,
            a.roll_deg,
            a.pitch_deg,
            a.yaw_deg,
            tr.rpy_deg
        );
    }
    println!(
        "{} captures: attitude at most {worst_deg:.3} deg off the truth",
        records.len()
    );
}

#[test]
fn frame_mode_logs_images_at_the_true_poses_with_valid_exports() {
    let (dir, out) = sim(CaptureMode::Frame);
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    assert_eq!(m.torn_tail_bytes, 0);
    assert!(m.bad_lines.is_empty(), "{:?}", m.bad_lines);
    check_against_truth(&out, &m.records);
    every_capture_has_its_image(&m.records);
    eprintln!("frame mode: {} captures", m.records.len());
    // Every capture was answered, and where its time went is reported (issue 14's figure:
    // `cargo test --test daemon_sim frame_mode -- --nocapture`).
    let latency = out.report.latency.as_ref().expect("answered captures");
    assert_eq!(latency.captures as usize, m.records.len());
    let phases: f64 = latency.phases.iter().map(|p| p.worst_ms).sum();
    assert!(latency.total.worst_ms <= phases + 1e-9);
    eprintln!("FIGURE nominal load: {latency}");
    let with_image: Vec<&CaptureRecord> = m.records.iter().filter(|r| r.image.is_some()).collect();
    assert!(!with_image.is_empty(), "frame mode saved no image");
    for r in with_image.iter().copied() {
        assert_eq!(r.capture_mode, CaptureMode::Frame);
        let name = r.image.as_ref().unwrap();
        let bytes = std::fs::read(out.flight_dir.join(name)).unwrap();
        let app1 = alfd::capture::find_exif_app1(&bytes).expect("EXIF in every JPEG");
        let gps = parse_exif_gps(app1).unwrap();
        assert!((gps.lat_deg - r.position.lat_deg).abs() < 1e-6);
        assert!((gps.lon_deg - r.position.lon_deg).abs() < 1e-6);
        let intr = r.intrinsics.expect("saved frames carry their intrinsics");
        assert_eq!((intr.width, intr.height), (160, 120));
    }
    // exiftool reads the same position back from the daemon's JPEGs.
    if tools::exiftool("daemon_sim's exiftool read-back") {
        let first = with_image[0];
        let path = out.flight_dir.join(first.image.as_ref().unwrap());
        let o = std::process::Command::new("exiftool")
            .args(["-n", "-j", "-GPSLatitude", "-GPSLongitude", "-GPSAltitude"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(o.status.success());
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let lat = v[0]["GPSLatitude"].as_f64().expect("GPSLatitude");
        let lon = v[0]["GPSLongitude"].as_f64().expect("GPSLongitude");
        assert!((lat - first.position.lat_deg).abs() < 1e-7, "{lat}");
        assert!((lon - first.position.lon_deg).abs() < 1e-7, "{lon}");
    }
    // geo.txt: a header, then one line per image with its lon, lat, alt.
    let geo = std::fs::read_to_string(out.flight_dir.join("geo.txt")).unwrap();
    let mut lines = geo.lines();
    assert_eq!(lines.next(), Some("EPSG:4326"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split_whitespace().collect()).collect();
    assert_eq!(rows.len(), with_image.len());
    for (row, r) in rows.iter().zip(with_image.iter().copied()) {
        assert_eq!(Some(row[0]), r.image.as_deref());
        let lon: f64 = row[1].parse().unwrap();
        let lat: f64 = row[2].parse().unwrap();
        assert!((lon - r.position.lon_deg).abs() < 1e-7 && (lat - r.position.lat_deg).abs() < 1e-7);
    }
    // transforms.json: one frame per image, a rigid camera-to-world matrix
    // whose translation is the ENU position.
    let t: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.flight_dir.join("transforms.json")).unwrap())
            .unwrap();
    let frames = t["frames"].as_array().unwrap();
    assert_eq!(frames.len(), with_image.len());
    for (f, r) in frames.iter().zip(with_image.iter().copied()) {
        let mtx: Vec<Vec<f64>> = serde_json::from_value(f["transform_matrix"].clone()).unwrap();
        for i in 0..3 {
            for j in 0..3 {
                let dot: f64 = (0..3).map(|k| mtx[k][i] * mtx[k][j]).sum();
                assert!((dot - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9);
            }
        }
        assert!((mtx[0][3] - r.position.east_m).abs() < 1e-6);
        assert!((mtx[1][3] - r.position.north_m).abs() < 1e-6);
        assert!((mtx[2][3] - r.position.up_m).abs() < 1e-6);
        assert_eq!(mtx[3], vec![0.0, 0.0, 0.0, 1.0]);
    }
    assert!(t["fl_x"].as_f64().unwrap() > 0.0 && t["w"].as_u64() == Some(160));
    // telemetry.tlog: complete entries, the autopilot's telemetry in it.
    let bytes = std::fs::read(out.flight_dir.join("telemetry.tlog")).unwrap();
    let (entries, err) = tlog::parse(&bytes);
    assert!(err.is_none(), "{err:?}");
    assert!(entries.len() > 100, "{} tlog entries", entries.len());
    assert!(entries.windows(2).all(|w| w[0].unix_us <= w[1].unix_us));
    // The summary judged the run against the truth at every frame it had.
    assert!(out.summary.captures == m.records.len());
    assert!(out.summary.ideal_captures >= Some(1));
    assert!(out.plots.iter().all(|p| p.exists()));
    drop(dir);
}

#[test]
fn camera_command_mode_commands_the_camera_once_per_logged_capture() {
    let (_dir, out) = sim(CaptureMode::CameraCommand);
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    check_against_truth(&out, &m.records);
    assert!(m
        .records
        .iter()
        .all(|r| r.image.is_none() && r.capture_mode == CaptureMode::CameraCommand));
    // firmware-sim received one IMAGE_START_CAPTURE (2000) per record, and
    // answered each with a CAMERA_TRIGGER.
    let commanded = out.sim_commands.iter().filter(|c| c.1 == 2000).count();
    assert_eq!(out.sim_events_lost, 0);
    assert_eq!(commanded, m.records.len());
    assert_eq!(out.report.camera_command_failures, 0);
    // Its camera takes each picture 50 ms after the command; the CAMERA_TRIGGER says when,
    // and every record is placed at its own picture's instant (through TIMESYNC), not at
    // the decision 50 ms (0.5 m) before it.
    assert_eq!(out.sim_triggers.len(), m.records.len());
    let delay_ms = alfd::daemon::sim::SIM_CAMERA_DELAY.as_secs_f64() * 1e3;
    for (r, (picture_ns, _)) in m.records.iter().zip(&out.sim_triggers) {
        let off_ms = (r.mono_ns as f64 - *picture_ns as f64) * 1e-6;
        assert!(
            off_ms.abs() < 1.0,
            "capture {}: {off_ms} ms from its picture",
            r.seq
        );
        let after = r.picture_after_ms.expect("placed at its picture");
        assert!((after - delay_ms).abs() < 2.0, "{after} ms");
    }
    assert_eq!(out.report.pictures_reported, m.records.len() as u64);
    assert_eq!(out.report.pictures_unreported, 0);
    // A line of 40 m ends within the camera's delay of its last command: the stop reads
    // that picture's report (the link stops last), and the capture is placed too.
    let dir = tempfile::tempdir().unwrap();
    let short = SimArgs {
        length_m: Some(40.0),
        ..args(dir.path(), CaptureMode::CameraCommand)
    };
    let out = run_sim_on_simulated_time(short, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    let last = m.records.last().expect("captures");
    assert!(last.picture_after_ms.is_some(), "{last:?}");
    assert_eq!(
        (out.report.pictures_reported, out.report.pictures_unreported),
        (m.records.len() as u64, 0)
    );
    camera_card_pairs_with_the_manifest(&out, &m.records);
}

/// firmware-sim's camera's card: one picture per picture it took, each paired
/// with its capture and named in geo.txt at the capture's position, the camera's
/// clock found an hour and 0.35 s ahead of UTC.
fn camera_card_pairs_with_the_manifest(out: &SimOutcome, records: &[CaptureRecord]) {
    let card = out.camera_card.as_ref().expect("a camera card");
    assert_eq!(card.pictures, out.sim_triggers.len());
    let (p, geo_lines) = card.paired.as_ref().expect("the card pairs");
    assert_eq!(p.pairs.len(), records.len(), "{p:?}");
    assert_eq!(*geo_lines, records.len());
    let ahead = p.camera_ahead_of_utc_s.expect("the pictures have times");
    // The camera fires when the command arrives, within a frame of the capture.
    assert!((ahead - 3600.35).abs() < 0.1, "{ahead}");
    let geo = std::fs::read_to_string(out.flight_dir.join("geo.txt")).unwrap();
    let names: Vec<String> = std::fs::read_dir(&card.dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), card.pictures);
    for (line, &(seq, picture)) in geo.lines().skip(1).zip(&p.pairs) {
        let r = &records[seq as usize - 1];
        assert_eq!(r.seq, seq);
        let want = format!(
            "DSC{:05}.JPG {:.9} {:.9} {:.3}",
            picture + 1,
            r.position.lon_deg,
            r.position.lat_deg,
            r.position.alt_m
        );
        assert_eq!(line, want);
    }
}

#[test]
fn autopilot_distance_mode_sets_the_distance_and_logs_the_autopilots_triggers() {
    let (_dir, out) = sim(CaptureMode::AutopilotDistance);
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    check_against_truth(&out, &m.records);
    let set = out.sim_commands.iter().filter(|c| c.1 == 206).count();
    assert!(set >= 1, "DO_SET_CAM_TRIGG_DIST sent {set} times");
    assert!(out.report.trigger_distances_acked >= 1);
    // A falling spacing reaches the autopilot at once (a 2-per-second limit
    // on shorter distances left it capturing up to 2.5x too far apart on
    // `alfd sim --mode autopilot_distance`): no interval longer than the
    // truth's spacing where alfd's own frames could have said so.
    assert_no_avoidable_violation(&out);
    // firmware-sim's generic autopilot counts a new distance from the
    // command: every command triggers once.
    assert_eq!(
        out.report.trigger_distances_with_picture,
        out.report.trigger_distances_sent
    );
    // Every CAMERA_TRIGGER of the autopilot after time sync is in the manifest.
    assert_eq!(out.sim_events_lost, 0);
    assert!(!out.sim_triggers.is_empty());
    assert_eq!(m.records.len() as u64, out.report.autopilot_triggers);
    assert!(m.records.len() + 1 >= out.sim_triggers.len());
    for r in &m.records {
        assert_eq!(r.capture_mode, CaptureMode::AutopilotDistance);
        assert!(r.image.is_none());
    }
    camera_card_pairs_with_the_manifest(&out, &m.records);
}

/// ArduPilot (`AP_Camera`) counts a new distance from its last picture: alfd
/// sends it without "trigger once" after the first, so no command costs a
/// capture, and asks for the tightest spacing of every frame since that
/// picture, which the interval spans, less the way flown in one of its 50 Hz
/// checks (firmware-sim fires at the first check past the distance). The
/// promise holds all the same: without either of the two, avoidable
/// violations (mutation-checked).
#[test]
fn autopilot_distance_on_ardupilot_shoots_only_at_the_distance() {
    let (_dir, out) = autopilot_distance_flight(firmware_sim::Autopilot::ArduPilot, 10.0);
    assert_eq!(
        out.report.trigger_distances_with_picture, 1,
        "only the first"
    );
    // ArduPilot's servo camera says its pictures by CAMERA_FEEDBACK alone (no
    // CAMERA_TRIGGER): every one was logged from it, placed by its GPS time.
    assert!(out.report.autopilot_feedbacks > 0);
    assert_eq!(
        out.report.autopilot_feedbacks,
        out.report.autopilot_triggers
    );
    assert_eq!(out.report.feedbacks_timed_on_arrival, 0);
}

/// An `autopilot_distance` flight of the tower line on `autopilot` at `speed_mps`, and what
/// every autopilot must give: every capture where the truth says, at least two distances
/// sent, no avoidable violation, every trigger in the manifest.
fn autopilot_distance_flight(
    autopilot: firmware_sim::Autopilot,
    speed_mps: f64,
) -> (tempfile::TempDir, SimOutcome) {
    let dir = tempfile::tempdir().unwrap();
    let a = SimArgs {
        autopilot,
        speed_mps: Some(speed_mps),
        ..args(dir.path(), CaptureMode::AutopilotDistance)
    };
    let out = run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    check_against_truth(&out, &m.records);
    let r = &out.report;
    assert!(
        r.trigger_distances_sent >= 2,
        "{}",
        r.trigger_distances_sent
    );
    assert_no_avoidable_violation(&out);
    assert_eq!(out.sim_events_lost, 0);
    assert_eq!(m.records.len() as u64, r.autopilot_triggers);
    assert_flags_are_the_violations(&out, &m.records);
    (dir, out)
}

/// Each autopilot record says whether its interval ran past the spacing alfd
/// wanted over it, judged over the frames of that interval (split at the
/// picture's own instant): on these flights, exactly the truth's violations
/// (the ArduPilot tower flight has one).
fn assert_flags_are_the_violations(out: &SimOutcome, records: &[CaptureRecord]) {
    let flagged: Vec<u64> = records
        .iter()
        .filter(|r| r.undersampled)
        .map(|r| r.seq)
        .collect();
    let violated: Vec<u64> = out
        .summary
        .violation_list
        .iter()
        .map(|v| v.to_seq)
        .collect();
    assert_eq!(flagged, violated);
}

/// Over a stretch of the district (houses from 100 m), the generic autopilot:
/// no interval too long, and none flagged. Judged from when each picture was
/// heard of (about 100 ms late, the frames in between counted to the closed
/// interval), capture 4 was flagged with nothing wrong.
#[test]
fn autopilot_distance_flags_only_what_the_truth_finds_too_long() {
    let dir = tempfile::tempdir().unwrap();
    let a = SimArgs {
        scene: None,
        length_m: Some(100.0),
        ..args(dir.path(), CaptureMode::AutopilotDistance)
    };
    let out = run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    assert!(m.records.len() >= 20, "{}", m.records.len());
    assert_flags_are_the_violations(&out, &m.records);
}

/// PX4 (`camera_trigger`) shoots once for every new distance and checks it on
/// a 50 ms poll. Flown at 4 m/s (a poll is 0.2 m), where the spacing stays
/// within one poll's reach: every command has its picture, alfd asks the
/// distance less a poll's way (without it, avoidable violations:
/// mutation-checked), and every trigger is in the manifest.
#[test]
fn autopilot_distance_on_px4_allows_for_its_poll() {
    let (_dir, out) = autopilot_distance_flight(firmware_sim::Autopilot::Px4, 4.0);
    let r = &out.report;
    assert_eq!(r.trigger_distances_with_picture, r.trigger_distances_sent);
}

/// Two lanes flown back and forth (`alfd sim --lanes 2`): every lane is flown, the flight ends
/// at the end of the last one, and every pose is where its picture was taken, also while the
/// vehicle turns 90° between lanes: between 10 Hz attitude samples the pose follows the body
/// rates, where slerp cut through a turn's angular acceleration by 0.17° (core::pose's
/// `a_turn_between_samples_follows_the_body_rates`).
#[test]
fn a_lawnmower_flies_every_lane_and_logs_its_turns_at_the_true_attitude() {
    let dir = tempfile::tempdir().unwrap();
    let spacing_m = 30.0;
    let a = SimArgs {
        lanes: 2,
        lane_spacing_m: spacing_m,
        length_m: Some(30.0),
        ..args(dir.path(), CaptureMode::Frame)
    };
    let out = run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    let m = read_manifest(&out.flight_dir.join("manifest.jsonl")).unwrap();
    let records = &m.records;
    let on_lane = |r: &CaptureRecord, east_m: f64| (r.position.east_m - east_m).abs() < 1.0;
    assert!(
        records.iter().any(|r| on_lane(r, 0.0)),
        "none on the first lane"
    );
    assert!(
        records.iter().any(|r| on_lane(r, spacing_m)),
        "none on the second lane"
    );
    let last = records.last().expect("captures");
    assert!(
        on_lane(last, spacing_m) && last.position.north_m < 3.0,
        "the flight ends where the second lane does (its south end): last capture at {:.1} m N, {:.1} m E",
        last.position.north_m,
        last.position.east_m
    );
    // Captures inside the turns (more than 2° off every lane and transit heading) are there.
    let turning = records
        .iter()
        .filter(|r| {
            let y = r.attitude.yaw_deg.rem_euclid(90.0);
            y > 2.0 && y < 88.0
        })
        .count();
    assert!(turning >= 6, "{turning} captures inside the turns");
    check_against_truth(&out, records);
}

/// On simulated time (the default of `alfd sim`) the same arguments fly the same flight:
/// two runs log byte-identical manifests, exports, telemetry logs and summaries. The flight
/// is still the true one (the poses match the simulator's truth at every record's instant,
/// every capture has its image, each CAMERA_IMAGE_CAPTURED comes within 0.5 s of simulated
/// time), and it starts at the fixed instant the simulated clock counts from.
#[test]
fn simulated_time_flies_the_same_flight_twice() {
    let fly = || {
        let dir = tempfile::tempdir().unwrap();
        let out = run_sim_on_simulated_time(
            args(dir.path(), CaptureMode::Frame),
            SimHooks::default(),
            std::future::pending(),
        )
        .expect("the sim runs");
        (dir, out)
    };
    let (_a, first) = fly();
    let (_b, second) = fly();
    for name in [
        "manifest.jsonl",
        "transforms.json",
        "geo.txt",
        "telemetry.tlog",
        "summary.json",
        "truth_track.jsonl",
    ] {
        let read = |o: &SimOutcome| std::fs::read(o.flight_dir.join(name)).unwrap();
        let (x, y) = (read(&first), read(&second));
        assert!(!x.is_empty(), "{name} is empty");
        assert!(x == y, "{name} differs between two runs of the same flight");
    }
    let m = read_manifest(&first.flight_dir.join("manifest.jsonl")).unwrap();
    check_against_truth(&first, &m.records);
    every_capture_has_its_image(&m.records);
    let latency = first
        .report
        .latency
        .as_ref()
        .expect("captures were answered");
    assert_eq!(latency.captures, m.records.len() as u64);
    assert!(
        latency.total.worst_ms <= 500.0,
        "CAMERA_IMAGE_CAPTURED {} ms after its capture",
        latency.total.worst_ms
    );
    let first_unix_us = m.records[0].time_unix_us.expect("a Unix time");
    assert!(
        first_unix_us > SIMULATED_START_UNIX_US
            && first_unix_us < SIMULATED_START_UNIX_US + 60_000_000,
        "the first capture at Unix {first_unix_us} us, not within a minute of the simulated start"
    );
    eprintln!(
        "simulated time: {} captures, identical twice; answered {latency}",
        m.records.len()
    );
}

/// A line longer than the scene's is refused, naming the flag and the scene's
/// line: it was flown cut to the scene's line without a word. (The other
/// flights here fly tower's whole 70 m.)
#[test]
fn a_line_longer_than_the_scenes_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let long = SimArgs {
        length_m: Some(70.5),
        ..args(dir.path(), CaptureMode::Frame)
    };
    let err = match run_sim_on_simulated_time(long, SimHooks::default(), std::future::pending()) {
        Ok(_) => panic!("a 70.5 m line over tower's 70 m was flown"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains("--length-m 70.5") && err.contains("tower") && err.contains("70 m"),
        "{err}"
    );
}

/// With `--config` naming its own scene, that scene is the one flown and the one
/// copied next to the captures (`scene.toml`, so that the run can be redone): the copy
/// was `--scene`'s, or the built-in district, whatever the config flew.
#[test]
fn a_configs_own_scene_is_flown_and_copied() {
    let dir = tempfile::tempdir().unwrap();
    let tower = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tower.toml");
    let config = dir.path().join("alfd.toml");
    // The bench's config of `alfd run`, posed from the simulator's truth (a flight on
    // simulated time cannot wait for telemetry); its capture dir is replaced by the sim's.
    let text = tools::synthetic_tower_config("serial:/dev/null:921600", dir.path(), "frame")
        .replace("pose = \"telemetry\"", "pose = \"truth\"");
    assert!(text.contains("pose = \"truth\""));
    std::fs::write(&config, text).unwrap();
    let a = SimArgs {
        config: Some(config),
        scene: None,
        length_m: Some(20.0),
        ..args(dir.path(), CaptureMode::Frame)
    };
    let out = run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    let copied = std::fs::read_to_string(out.flight_dir.join("scene.toml")).unwrap();
    assert_eq!(copied, std::fs::read_to_string(&tower).unwrap());
    assert!(
        out.report.records.len() > 5,
        "{} captures",
        out.report.records.len()
    );
}

/// A scene is flown at its own `survey.speed_mps` unless `--speed-mps` says
/// otherwise: the sim flew every scene at 10 m/s, the eval scenes' 5 m/s never, so
/// `alfd sim --scene scenes/roof.toml` was "too fast" with most intervals unavoidably
/// long.
#[test]
fn a_scene_is_flown_at_its_own_speed() {
    let dir = tempfile::tempdir().unwrap();
    let tower = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tower.toml");
    let text = std::fs::read_to_string(&tower).unwrap();
    assert!(text.contains("speed_mps = 10.0"));
    let slow = dir.path().join("tower_slow.toml");
    std::fs::write(&slow, text.replace("speed_mps = 10.0", "speed_mps = 5.0")).unwrap();
    let a = SimArgs {
        scene: Some(slow),
        ..args(&dir.path().join("out"), CaptureMode::Frame)
    };
    let out = run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    let r = &out.report.records;
    assert!(r.len() > 20, "{} captures", r.len());
    // Over the middle half of the line, past the climb-out and before the end.
    let (a, b) = (&r[r.len() / 4], &r[3 * r.len() / 4]);
    let way_m =
        (b.position.north_m - a.position.north_m).hypot(b.position.east_m - a.position.east_m);
    let speed_mps = way_m / ((b.mono_ns - a.mono_ns) as f64 * 1e-9);
    assert!((speed_mps - 5.0).abs() < 0.5, "flown at {speed_mps:.2} m/s");
}

/// Another model flies judged by the operator's targets, not by itself: the
/// truth estimated every flight with the flown model, so `--model fixed` met
/// "0 avoidable violations" at any spacing (the fixed model on exact depth
/// allows what it flew), a flight that holds none of the targets.
#[test]
fn a_flight_of_another_model_is_judged_by_the_targets() {
    let dir = tempfile::tempdir().unwrap();
    let fly = |model: Option<Model>, out: &str| {
        let a = SimArgs {
            model,
            ..args(&dir.path().join(out), CaptureMode::Frame)
        };
        run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
            .expect("the sim runs")
    };
    let quality = fly(None, "quality");
    let fixed = fly(Some(Model::Fixed), "fixed");
    // The tower scene's line at the fixed model's 5 m: past the targets'
    // spacing over the tower, and the truth says so.
    assert!(
        fixed.summary.avoidable_violations > 0,
        "{:?}",
        fixed.summary
    );
    let judged = fixed
        .summary
        .judged_by
        .as_deref()
        .expect("a judged-by line");
    assert!(
        judged.starts_with("the lightfield targets (parallax 2 px")
            && judged.ends_with("the fixed model flew"),
        "{judged}"
    );
    assert!(fixed
        .summary
        .render_text()
        .contains("judged by       the lightfield targets"));
    // One judge for both flights: the same truth, so the same ideal and the
    // same fixed baseline to compare their captures with.
    assert_eq!(quality.summary.judged_by, None);
    assert_eq!(
        quality.summary.fixed_spacing_m,
        fixed.summary.fixed_spacing_m
    );
    assert_eq!(quality.summary.avoidable_violations, 0);
}

/// `alfd sim --config`: the config is the flight, rendered at its frame rate
/// (15 fps here: the flags' 30 ticked the renders and set the opportunity step
/// beside it), while the command line's model and targets go over it (they were
/// silently dropped: `--model fixed` flew the config's quality model).
#[test]
fn a_given_config_flies_as_written_with_the_command_lines_model_and_targets() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("alfd.toml");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tower.toml");
    std::fs::write(
        &config,
        format!(
            r#"[mavlink]
address = "serial:/dev/null:921600"
[sim]
pose = "truth"
scene = "{scene}"
[depth]
source = "synthetic"
width = 160
height = 120
fps = 15.0
scale_m = 0.01
max_range_m = 300.0
[camera]
source = "synthetic"
width = 160
height = 120
fps = 15.0
[trigger]
fallback_spacing_m = 1.0
[capture]
dir = "unused"
mode = "frame"
"#
        ),
    )
    .unwrap();
    let a = SimArgs {
        config: Some(config),
        model: Some(Model::Fixed),
        quality: QualityPatch {
            parallax_px: Some(Some(3.0)),
            ..QualityPatch::default()
        },
        speed_mps: Some(6.0),
        ..args(&dir.path().join("out"), CaptureMode::Frame)
    };
    let out = run_sim_on_simulated_time(a, SimHooks::default(), std::future::pending())
        .expect("the sim runs");
    // A frame's way at the config's 15 fps: 6 m/s / 15.
    assert!(
        (out.summary.step_limit_m - 0.4).abs() < 1e-9,
        "{}",
        out.summary.step_limit_m
    );
    let judged = out.summary.judged_by.as_deref().expect("a judged-by line");
    assert!(
        judged.starts_with("the lightfield targets (parallax 3 px")
            && judged.ends_with("the fixed model flew"),
        "{judged}"
    );
    let records = read_manifest(&out.flight_dir.join("manifest.jsonl"))
        .unwrap()
        .records;
    assert!(!records.is_empty());
    assert!(
        records.iter().all(|r| r.model == "fixed"),
        "{:?}",
        records[0].model
    );
}
