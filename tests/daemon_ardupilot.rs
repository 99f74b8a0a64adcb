//! `alfd run` against firmware-sim behaving like ArduPilot (`autopilot = "ardupilot"`) over a
//! pseudo-terminal: positions read lat = lon = 0 until the EKF origin arrives late, the vehicle
//! waits on the ground, arms and takes off. No pose may be logged before the origin, the first
//! capture is where the vehicle truly was (not 0°, 0°), nothing is captured before it is
//! airborne, and the origin's arrival suspends nothing (before, it was a 10 s GPS glitch).

mod tools;

use alfd::capture::{read_manifest, CaptureRecord};
use firmware_sim::{SimConfig, SimEvent};
use std::path::{Path, PathBuf};
use std::process::Child;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const ALTITUDE_M: f64 = 60.0;

/// The simulator's milestones, as they happen.
#[derive(Default, Debug)]
struct Milestones {
    origin: Option<u64>,
    armed: Option<u64>,
    in_air: Option<u64>,
    captures: u64,
    /// The instants of the camera's pictures.
    pictures: Vec<u64>,
}

struct Flight {
    dir: tempfile::TempDir,
    sim: firmware_sim::SimHandle,
    milestones: Arc<Mutex<Milestones>>,
    child: Child,
    log: std::thread::JoinHandle<Vec<String>>,
}

/// firmware-sim in the ArduPilot profile (origin after 4 s, on the ground for 5 s, a 3 s
/// climb to 60 m, then a 150 m line) with its camera `backend`, and `alfd run` on its pty
/// with `mode`.
async fn fly(mode: &str, backend: &str) -> Flight {
    fly_with_camera(mode, backend, "").await
}

/// [`fly`], the camera taking a commanded picture `delay_ms` after the command.
/// A flight whose camera has `camera` besides its backend (TOML lines of firmware-sim's
/// `[camera]`).
async fn fly_with_camera(mode: &str, backend: &str, camera: &str) -> Flight {
    let dir = tempfile::tempdir().unwrap();
    let mut sc = SimConfig::from_toml(&format!(
        "autopilot = \"ardupilot\"\n\
         [vehicle]\norigin_delay_s = 4\nground_s = 5\nclimb_mps = 20\n\
         [survey]\npattern = \"line\"\nlength_m = 150\nspeed_mps = 10\nwind_m = 0\nwind_deg = 0\n\
         [camera]\nbackend = \"{backend}\"\n{camera}\n",
    ))
    .unwrap();
    sc.survey.altitude_m = ALTITUDE_M;
    sc.transport = firmware_sim::Transport::Pty {
        link: Some(dir.path().join("ttyFC")),
    };
    let sim = firmware_sim::start(sc).await.unwrap();
    let milestones: Arc<Mutex<Milestones>> = Arc::default();
    {
        let mut rx = sim.subscribe();
        let m = milestones.clone();
        tokio::spawn(async move {
            use tokio::sync::broadcast::error::RecvError;
            loop {
                match rx.recv().await {
                    Ok(SimEvent::OriginSet { mono_ns }) => m.lock().unwrap().origin = Some(mono_ns),
                    Ok(SimEvent::Armed { mono_ns }) => m.lock().unwrap().armed = Some(mono_ns),
                    Ok(SimEvent::InAir { mono_ns }) => m.lock().unwrap().in_air = Some(mono_ns),
                    Ok(SimEvent::Capture { mono_ns, .. }) => {
                        let mut m = m.lock().unwrap();
                        m.captures += 1;
                        m.pictures.push(mono_ns);
                    }
                    Ok(_) | Err(RecvError::Lagged(_)) => {}
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    let captures = dir.path().join("captures");
    let config = dir.path().join("alfd.toml");
    std::fs::write(
        &config,
        tools::synthetic_tower_config(sim.address(), &captures, mode),
    )
    .unwrap();
    let (child, log) = tools::alfd_run(&config, &[("NOTIFY_SOCKET", None)]);
    Flight {
        dir,
        sim,
        milestones,
        child,
        log,
    }
}

impl Flight {
    fn manifest(&self) -> PathBuf {
        self.dir.path().join("captures/flight-001/manifest.jsonl")
    }

    /// Wait (bounded) until `n` captures are logged or the simulator's camera counted `n`.
    async fn until(&self, what: &str, done: impl Fn(&Path, &Milestones) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(90);
        while !done(&self.manifest(), &self.milestones.lock().unwrap()) {
            assert!(Instant::now() < deadline, "{what}: not within 90 s");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// SIGTERM, wait for the exit, and hand back the manifest and the log.
    async fn land(mut self) -> (Vec<CaptureRecord>, Vec<String>, Milestones, Self) {
        // SAFETY: kill sends a signal to the child we started, by its id.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let term = Instant::now();
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if term.elapsed() > Duration::from_secs(20) {
                let _ = self.child.kill();
                panic!("alfd run did not exit within 20 s of SIGTERM");
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        };
        assert!(status.success(), "exit status {status}");
        let log = std::mem::replace(&mut self.log, std::thread::spawn(Vec::new))
            .join()
            .unwrap();
        let m = read_manifest(&self.manifest()).unwrap();
        let ms = std::mem::take(&mut *self.milestones.lock().unwrap());
        (m.records, log, ms, self)
    }
}

fn lines(path: &Path) -> usize {
    std::fs::read_to_string(path).map_or(0, |t| t.lines().count())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ardupilot_late_origin_and_take_off_frame_mode() {
    let f = fly("frame", "mavlink_cam_v2").await;
    f.until("10 captures", |m, _| lines(m) >= 10).await;
    let (records, log, ms, f) = f.land().await;
    let origin = ms.origin.expect("the origin was set");
    let armed = ms.armed.expect("armed");
    let in_air = ms.in_air.expect("in the air");
    assert!(origin <= armed && armed < in_air);
    assert!(records.len() >= 10);
    let o = f.sim.origin();
    for r in &records {
        // Nothing before the origin, nor before the take-off had ended: the vehicle was
        // airborne at every capture (truth at the record's instant).
        assert!(r.mono_ns > origin, "capture {} before the origin", r.seq);
        let truth = f.sim.truth_at_mono_ns(r.mono_ns);
        assert!(
            -truth.pos_ned_m[2] > ALTITUDE_M - 1.0,
            "capture {} at {:.1} m: not airborne",
            r.seq,
            -truth.pos_ned_m[2]
        );
        // Where the vehicle truly was, in a frame on the EKF origin (not 0°, 0°, not 5,000 km).
        let dn = (r.position.lat_deg - truth.lat_deg).to_radians() * 6_371_000.0;
        let de = (r.position.lon_deg - truth.lon_deg).to_radians()
            * 6_371_000.0
            * truth.lat_deg.to_radians().cos();
        assert!(
            dn.hypot(de) < 0.3,
            "capture {}: {dn:.3} m N, {de:.3} m E off the truth",
            r.seq
        );
        assert!(
            (r.position.rel_alt_m - ALTITUDE_M).abs() < 0.5,
            "{}",
            r.position.rel_alt_m
        );
        assert!(
            (r.position.lat_deg - o[0]).abs() < 0.01 && (r.position.lon_deg - o[1]).abs() < 0.01
        );
    }
    // No suspension when the origin arrived: the first capture comes right after the climb
    // (a 10 s GPS-glitch hold at the origin, 4 s before the climb ended, would delay it 6 s).
    let first = &records[0];
    let after_s = (first.mono_ns as f64 - in_air as f64) * 1e-9;
    eprintln!(
        "FIGURE first capture {after_s:.2} s after the climb ended ({:.1} s after the origin); {} captures",
        (first.mono_ns as f64 - origin as f64) * 1e-9,
        records.len()
    );
    assert!(
        after_s < 3.0,
        "first capture {after_s:.2} s after the climb"
    );
    let glitches: Vec<&String> = log.iter().filter(|l| l.contains("GPS glitch")).collect();
    assert!(glitches.is_empty(), "{glitches:?}");
    f.sim.shutdown().await;
}

/// In `autopilot_distance` mode ArduPilot's MAVLinkCamV2 backend sends alfd one
/// IMAGE_START_CAPTURE per distance trigger; each must become a manifest line. alfd sends
/// the distance without "trigger once" after the first (ArduPilot counts from its last
/// picture), so after the first the photos are the distance trigger's own.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ardupilot_distance_trigger_through_the_mavlink_camera() {
    distance_trigger_photos_are_logged_where_taken("mavlink_cam_v2", 0).await;
}

/// With a servo- or relay-triggered camera (CAM1_TYPE 1 or 2, the commonest survey set-up)
/// ArduPilot says each picture by CAMERA_FEEDBACK alone: each must become a manifest line,
/// where the vehicle was at the picture (its GPS time stamp mapped through SYSTEM_TIME).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ardupilot_distance_trigger_through_a_servo_camera() {
    distance_trigger_photos_are_logged_where_taken("servo", 5).await;
}

/// `camera_command` on ArduPilot with a servo camera whose picture comes 80 ms after the
/// command (the autopilot's scheduling and the camera's lag, timed by a feedback pin): each
/// capture waits for the CAMERA_FEEDBACK and is logged at the picture's instant and place,
/// not where alfd decided it (0.8 m and more before, at 10 m/s).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ardupilot_camera_command_capture_is_logged_at_its_picture() {
    // The camera is 80 ms late, and not ready for the first command: the autopilot refuses it.
    let f = fly_with_camera("camera_command", "servo", "delay_ms = 80\nrefuse_first = 1").await;
    f.until("5 captures logged", |m, _| lines(m) >= 5).await;
    let (records, log, ms, f) = f.land().await;
    assert!(records.len() >= 5);
    let field = |name: &str| {
        log.iter()
            .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
            .filter_map(|v| v["fields"][name].as_u64())
            .next_back()
            .unwrap_or_else(|| panic!("{name} in the run's log"))
    };
    let reported = field("pictures_reported");
    assert_eq!(field("pictures_refused"), 1);
    // The refused command's capture is logged where it was decided, with no picture.
    assert_eq!(records[0].picture_after_ms, None);
    // The last capture may be cut by the stop before its picture's report.
    assert!(
        reported + 2 >= records.len() as u64,
        "{reported} of {}",
        records.len()
    );
    // Each placed capture took its own command's picture, not the next one's (which the
    // first report, going to the oldest capture waiting, would give every capture after a
    // refused one): its picture is late by the camera's 80 ms and the command's way to the
    // autopilot, less than the time from one decision to the next.
    let decided_ns: Vec<f64> = records
        .iter()
        .map(|r| r.mono_ns as f64 - r.picture_after_ms.unwrap_or(0.0) * 1e6)
        .collect();
    let gap_ms = decided_ns
        .windows(2)
        .map(|w| (w[1] - w[0]) * 1e-6)
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "captures decided {gap_ms:.0} ms apart at least; pictures {:?} ms after",
        records
            .iter()
            .map(|r| r.picture_after_ms)
            .collect::<Vec<_>>()
    );
    for r in records.iter().filter(|r| r.picture_after_ms.is_some()) {
        let after = r.picture_after_ms.unwrap();
        assert!(after > 79.0, "capture {}: {after} ms", r.seq);
        assert!(
            after < 80.0 + gap_ms,
            "capture {}: {after} ms, captures decided {gap_ms} ms apart at least",
            r.seq
        );
        let nearest = ms
            .pictures
            .iter()
            .map(|p| (*p as f64 - r.mono_ns as f64).abs() * 1e-6)
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest < 3.0,
            "capture {}: {nearest} ms from a picture",
            r.seq
        );
        let truth = f.sim.truth_at_mono_ns(r.mono_ns);
        let dn = (r.position.lat_deg - truth.lat_deg).to_radians() * 6_371_000.0;
        let de = (r.position.lon_deg - truth.lon_deg).to_radians()
            * 6_371_000.0
            * truth.lat_deg.to_radians().cos();
        assert!(dn.hypot(de) < 0.3, "capture {}", r.seq);
    }
    f.sim.shutdown().await;
}

/// An `autopilot_distance` flight on ArduPilot with its camera `backend`: at least five
/// photos logged, none more than the camera took, each where the vehicle was (0.5 m); and
/// `feedbacks` of them, at least, known by CAMERA_FEEDBACK alone (from the daemon's log).
async fn distance_trigger_photos_are_logged_where_taken(backend: &str, feedbacks: u64) {
    let f = fly("autopilot_distance", backend).await;
    f.until("5 photos by the autopilot", |_, m| m.captures >= 5)
        .await;
    // Let the last command's capture be written.
    f.until("5 captures logged", |m, _| lines(m) >= 5).await;
    let (records, log, ms, f) = f.land().await;
    let in_air = ms.in_air.expect("in the air");
    assert!(records.len() as u64 >= 5);
    let said: u64 = log
        .iter()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v["fields"]["autopilot_feedbacks"].as_u64())
        .next_back()
        .expect("the run's report in the log");
    if feedbacks == 0 {
        assert_eq!(
            said, 0,
            "MAVLinkCamV2's feedbacks are echoes of its commands"
        );
    } else {
        assert!(said >= feedbacks && said == records.len() as u64, "{said}");
    }
    assert!(
        records.len() as u64 <= ms.captures,
        "{} > {}",
        records.len(),
        ms.captures
    );
    for r in &records {
        assert!(r.mono_ns > in_air);
        let truth = f.sim.truth_at_mono_ns(r.mono_ns);
        let dn = (r.position.lat_deg - truth.lat_deg).to_radians() * 6_371_000.0;
        let de = (r.position.lon_deg - truth.lon_deg).to_radians()
            * 6_371_000.0
            * truth.lat_deg.to_radians().cos();
        assert!(dn.hypot(de) < 0.5, "capture {}", r.seq);
    }
    f.sim.shutdown().await;
}
