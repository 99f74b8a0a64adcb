//! A ground station nobody here wrote drives alfd's camera (issue 14): MAVSDK (PyPI `mavsdk`
//! ≥ 4, system 245) behind firmware-sim's ground-station forwarding
//! (`scripts/mavsdk_camera.py`) lists the camera, reads its information and storage, takes
//! photos and follows the capture_info stream while alfd flies the tower line. Every photo
//! succeeds and is a `command` line of the manifest, requested by MAVSDK, at the vehicle;
//! every capture_info is a manifest line. Skipped, with a message, only when mavsdk is
//! missing and `CI` is unset. Figures with `-- --nocapture`.

use alfd::capture::CaptureMode;
use alfd::daemon::sim::{run_sim_with, SimArgs, SimHooks};
use serde_json::Value;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

const PHOTOS: usize = 5;
/// The script's own deadline (s), past the ~12 s flight.
const SCRIPT_DEADLINE_S: &str = "60";

/// A child killed if the test leaves early, so no process outlives it.
struct Reaped(Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            let _ = self.0.kill();
        }
        let _ = self.0.wait();
    }
}

fn mavsdk_present() -> bool {
    let present = Command::new("python3")
        .args([
            "-c",
            "import mavsdk; from mavsdk.plugins.camera import Camera",
        ])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !present {
        if std::env::var_os("CI").is_some() {
            panic!("mavsdk_camera: CI is set but python3 with mavsdk >= 4 is missing: pip install mavsdk, or run scripts/setup.sh");
        }
        eprintln!(
            "SKIPPED mavsdk_camera: python3 with mavsdk >= 4 is missing (pip install mavsdk, or run scripts/setup.sh)"
        );
    }
    present
}

fn f(v: &Value, k: &str) -> f64 {
    v[k].as_f64()
        .unwrap_or_else(|| panic!("{k} not a number in {v}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mavsdk_lists_reads_and_takes_photos_each_a_manifest_line() {
    if !mavsdk_present() {
        return;
    }
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut gcs = Reaped(
        Command::new("python3")
            .arg(repo.join("scripts/mavsdk_camera.py"))
            .args([&PHOTOS.to_string(), SCRIPT_DEADLINE_S])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("python3 runs"),
    );
    let stdin = gcs.0.stdin.take();
    let (tx, lines) = mpsc::channel();
    let stdout = gcs.0.stdout.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let mut stderr = gcs.0.stderr.take().unwrap();
    let stderr = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stderr.read_to_string(&mut s);
        s
    });
    let port: u16 = lines
        .recv_timeout(Duration::from_secs(30))
        .ok()
        .and_then(|l| l.strip_prefix("PORT ").and_then(|p| p.trim().parse().ok()))
        .expect("a PORT line from the MAVSDK station");

    let dir = tempfile::tempdir().unwrap();
    let args = SimArgs {
        out: dir.path().to_path_buf(),
        width: 160,
        height: 120,
        progress: false,
        length_m: Some(100.0),
        seed: 14,
        gcs: Some(format!("udpout:127.0.0.1:{port}")),
        scene: Some(repo.join("tests/data/faults/tower_long.toml")),
        ..SimArgs::default()
    };
    let out = run_sim_with(args, SimHooks::default(), std::future::pending())
        .await
        .expect("the sim runs");
    // The station stops once its stream has been quiet for 2 s; the closed stdin stops it
    // otherwise.
    let result = loop {
        match lines.recv_timeout(Duration::from_secs(10)) {
            Ok(l) if l.starts_with("RESULT ") => break Some(l),
            Ok(_) => continue,
            Err(_) => break None,
        }
    };
    drop(stdin);
    drop(gcs);
    let stderr = stderr.join().unwrap_or_default();
    let result = result.unwrap_or_else(|| panic!("no RESULT from the station; stderr:\n{stderr}"));
    let r: Value = serde_json::from_str(&result["RESULT ".len()..]).expect("RESULT is JSON");
    let context = format!("{r:#}\n--- stderr ---\n{stderr}");

    assert_eq!(r["reason"], "done", "{context}");
    assert_eq!(r["system_id"], 245, "MAVSDK speaks as 245");
    // Listed, with alfd's information.
    let cam = &r["camera_list"][0];
    assert_eq!(cam["component_id"], 100, "{context}");
    assert_eq!(cam["vendor_name"], "alfd", "{context}");
    // Storage totals that add up.
    let st = &r["storage"];
    let (total, used, avail) = (
        f(st, "total_mib"),
        f(st, "used_mib"),
        f(st, "available_mib"),
    );
    assert!(total > 0.0 && total >= used + avail, "{st}");

    // Every photo commanded succeeded and is a `command` line requested by MAVSDK.
    let photos = r["photos"].as_array().unwrap();
    assert_eq!(photos.len(), PHOTOS, "{context}");
    for p in photos {
        assert_eq!(p["result"], "SUCCESS", "{context}");
    }
    let records = &out.report.records;
    let commanded: Vec<_> = records
        .iter()
        .filter(|r| r.capture_mode == CaptureMode::Command)
        .collect();
    assert_eq!(
        commanded.len(),
        PHOTOS,
        "command lines in the manifest; alfd said {:?}; {context}",
        out.report.statustexts
    );
    for (c, truth) in records.iter().zip(&out.truth_at_records) {
        if c.capture_mode != CaptureMode::Command {
            continue;
        }
        assert_eq!(c.requested_by, Some([245, 190]), "{c:?}");
        assert!(c.image.is_some() || c.image_missing.is_some(), "{c:?}");
        // At the vehicle: the simulator's truth at the capture's instant.
        let d = ((c.position.north_m - truth.pos_ned_m[0]).powi(2)
            + (c.position.east_m - truth.pos_ned_m[1]).powi(2))
        .sqrt();
        assert!(d < 0.5, "capture {} {d:.3} m from the vehicle", c.seq);
    }
    // The capture_info stream: increasing indices, each a manifest line at its position.
    let infos = r["capture_infos"].as_array().unwrap();
    assert!(!infos.is_empty(), "{context}");
    let mut last = -1i64;
    let mut matched_commands = 0;
    for i in infos {
        let index = i["index"].as_i64().unwrap();
        assert!(index > last, "indices increase: {context}");
        last = index;
        let rec = records
            .iter()
            .find(|c| c.seq as i64 == index + 1)
            .unwrap_or_else(|| panic!("capture_info {index} has no manifest line"));
        assert_eq!(
            i["success"].as_bool(),
            Some(rec.image.is_some()),
            "{i} {rec:?}"
        );
        assert!(
            (f(i, "lat_deg") - rec.position.lat_deg).abs() < 2e-7,
            "{i} {rec:?}"
        );
        assert!(
            (f(i, "lon_deg") - rec.position.lon_deg).abs() < 2e-7,
            "{i} {rec:?}"
        );
        if rec.capture_mode == CaptureMode::Command {
            matched_commands += 1;
        }
    }
    eprintln!(
        "FIGURE mavsdk: {} photos commanded, {} succeeded, {} command lines in the manifest \
         ({} with images), {} of them in the capture_info stream; {} capture_infos for {} \
         manifest lines; storage {total:.0} MiB total, {used:.0} used, {avail:.0} available",
        photos.len(),
        photos.iter().filter(|p| p["result"] == "SUCCESS").count(),
        commanded.len(),
        commanded.iter().filter(|c| c.image.is_some()).count(),
        matched_commands,
        infos.len(),
        records.len(),
    );
}
