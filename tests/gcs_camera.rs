//! A ground station sees alfd's captures as they happen: `alfd sim` flies the
//! tower line against firmware-sim, which forwards MAVLink to a pymavlink
//! ground station (`tests/python/gcs_camera.py`). The station must get the
//! camera's information and storage on request, every capture as
//! CAMERA_IMAGE_CAPTURED and the spacing as a named value, and what it saw must
//! be what alfd wrote in the flight's manifest. Skipped, with a message, only
//! when pymavlink is missing and `CI` is unset.

mod tools;

use serde_json::Value;
use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// The whole exchange, start to finish; the flight itself takes about 10 s.
const DEADLINE: Duration = Duration::from_secs(120);
/// The station's own deadline (seconds), inside ours so it reports what it saw.
const GCS_DEADLINE_S: &str = "90";
const MIN_IMAGES: usize = 3;
const MAV_CMD_REQUEST_MESSAGE: u64 = 512;
const MAV_RESULT_ACCEPTED: u64 = 0;
const CAMERA_COMPONENT: u64 = 100;

/// A child that is killed if the test leaves early (a failed assertion, a
/// timeout), so no process outlives it.
struct Reaped(Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

impl Reaped {
    /// Waits until `until`; `None` if the child is still running then.
    fn wait_until(&mut self, until: Instant) -> Option<ExitStatus> {
        loop {
            if let Some(status) = self.0.try_wait().expect("try_wait") {
                return Some(status);
            }
            if Instant::now() >= until {
                return None;
            }
            thread::sleep(Duration::from_millis(50));
        }
    }

    fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Every line of `r`, sent as it arrives.
fn lines_of(r: impl Read + Send + 'static) -> Receiver<String> {
    let (tx, rx) = mpsc::channel();
    thread::spawn(move || {
        for line in BufReader::new(r).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// All of `r`, as text, once it closes.
fn all_of(mut r: impl Read + Send + 'static) -> JoinHandle<String> {
    thread::spawn(move || {
        let mut s = String::new();
        let _ = r.read_to_string(&mut s);
        s
    })
}

fn u(v: &Value, field: &str) -> u64 {
    v[field]
        .as_u64()
        .unwrap_or_else(|| panic!("{field} is not an unsigned integer in {v}"))
}

fn i(v: &Value, field: &str) -> i64 {
    v[field]
        .as_i64()
        .unwrap_or_else(|| panic!("{field} is not an integer in {v}"))
}

fn f(v: &Value, field: &str) -> f64 {
    v[field]
        .as_f64()
        .unwrap_or_else(|| panic!("{field} is not a number in {v}"))
}

fn s<'a>(v: &'a Value, field: &str) -> &'a str {
    v[field]
        .as_str()
        .unwrap_or_else(|| panic!("{field} is not a string in {v}"))
}

#[test]
fn a_ground_station_sees_the_captures_as_they_happen() {
    if !tools::pymavlink("gcs_camera") {
        return;
    }
    let started = Instant::now();
    let until = started + DEADLINE;
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out_dir = tempfile::tempdir().unwrap();

    // The ground station first: it picks the port, and stops when its stdin closes.
    let mut gcs = Reaped(
        Command::new("python3")
            .arg(repo.join("tests/python/gcs_camera.py"))
            .args(["1", &MIN_IMAGES.to_string(), GCS_DEADLINE_S])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("python3 runs"),
    );
    let mut gcs_stdin: Option<ChildStdin> = gcs.0.stdin.take();
    let gcs_lines = lines_of(gcs.0.stdout.take().unwrap());
    let gcs_stderr = all_of(gcs.0.stderr.take().unwrap());
    let port: u16 = match gcs_lines.recv_timeout(Duration::from_secs(30)) {
        Ok(line) => line
            .strip_prefix("PORT ")
            .and_then(|p| p.trim().parse().ok())
            .unwrap_or_else(|| panic!("expected `PORT <n>`, got {line:?}")),
        Err(e) => {
            gcs.kill();
            panic!(
                "no PORT line from the ground station ({e}); its stderr:\n{}",
                gcs_stderr.join().unwrap()
            );
        }
    };

    let mut alfd = Reaped(
        Command::new(env!("CARGO_BIN_EXE_alfd"))
            .args(["--log-level", "warn", "sim", "--real-time", "--gcs"])
            .arg(format!("udpout:127.0.0.1:{port}"))
            .arg("--scene")
            .arg(repo.join("tests/data/tower.toml"))
            .args(["--width", "160", "--height", "120", "--no-progress"])
            .arg("--out")
            .arg(out_dir.path())
            .args(["--length-m", "70"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("alfd runs"),
    );
    let alfd_stdout = all_of(alfd.0.stdout.take().unwrap());
    let alfd_stderr = all_of(alfd.0.stderr.take().unwrap());

    // Both run to the end, within the deadline. The station normally finishes
    // first; if alfd finishes first, the station gets a few seconds to drain
    // what is still in its socket, then its stdin closes and it reports.
    let alfd_status = alfd.wait_until(until);
    if alfd_status.is_none() {
        alfd.kill();
    }
    let grace = (Instant::now() + Duration::from_secs(5)).min(until);
    let mut gcs_status = gcs.wait_until(grace);
    if gcs_status.is_none() {
        drop(gcs_stdin.take());
        gcs_status = gcs.wait_until(Instant::now() + Duration::from_secs(5));
        if gcs_status.is_none() {
            gcs.kill();
        }
    }
    drop(gcs_stdin);
    let elapsed = started.elapsed();
    let alfd_stdout = alfd_stdout.join().unwrap();
    let alfd_stderr = alfd_stderr.join().unwrap();
    let gcs_stderr = gcs_stderr.join().unwrap();
    let result_line = loop {
        match gcs_lines.recv_timeout(Duration::from_secs(1)) {
            Ok(line) if line.starts_with("RESULT ") => break Some(line),
            Ok(_) => continue,
            Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => break None,
        }
    };
    let context = format!(
        "after {elapsed:.1?}\nalfd: {alfd_status:?}\n--- alfd stderr ---\n{alfd_stderr}\n--- alfd stdout ---\n{alfd_stdout}\n\
         ground station: {gcs_status:?}\n--- its stderr ---\n{gcs_stderr}\n--- its result ---\n{}",
        result_line.as_deref().unwrap_or("(none)")
    );
    println!("{context}");

    let status =
        alfd_status.unwrap_or_else(|| panic!("alfd sim did not finish in time\n{context}"));
    assert!(status.success(), "alfd sim failed\n{context}");
    let result_line = result_line.unwrap_or_else(|| panic!("no RESULT line\n{context}"));
    let r: Value = serde_json::from_str(result_line.strip_prefix("RESULT ").unwrap())
        .unwrap_or_else(|e| panic!("RESULT is not JSON ({e})\n{context}"));
    assert_eq!(r["ok"], Value::Bool(true), "{context}");
    assert_eq!(r["reason"], "done", "{context}");
    assert!(
        gcs_status.is_some_and(|s| s.success()),
        "the ground station did not exit 0\n{context}"
    );
    assert_eq!(r["camera_seen"], Value::Bool(true), "{context}");

    // Both informations, from the camera, describing what alfd was told to fly.
    let info = &r["camera_information"];
    assert!(info.is_object(), "no CAMERA_INFORMATION\n{context}");
    assert_eq!(u(info, "component"), CAMERA_COMPONENT);
    assert_eq!(s(info, "vendor_name"), "alfd");
    assert_eq!(
        (u(info, "resolution_h"), u(info, "resolution_v")),
        (160, 120)
    );
    let storage = &r["storage_information"];
    assert!(storage.is_object(), "no STORAGE_INFORMATION\n{context}");
    assert_eq!(u(storage, "component"), CAMERA_COMPONENT);

    // Every request was acknowledged by the camera, and accepted: at least one
    // per message asked for.
    let acks = r["acks"].as_array().expect("acks");
    let request_acks: Vec<&Value> = acks
        .iter()
        .filter(|a| u(a, "command") == MAV_CMD_REQUEST_MESSAGE)
        .collect();
    assert!(request_acks.len() >= 2, "{acks:?}");
    for a in &request_acks {
        assert_eq!(u(a, "component"), CAMERA_COMPONENT, "{a}");
        assert_eq!(u(a, "result"), MAV_RESULT_ACCEPTED, "{a}");
    }

    // The spacing the estimator chose, as it went.
    let spc = &r["named_values"]["ALF_SPC"];
    assert!(
        spc.is_object() && u(spc, "count") >= 1,
        "no ALF_SPC\n{context}"
    );
    let spacing = f(spc, "last");
    assert!(spacing.is_finite() && spacing > 0.0, "ALF_SPC {spacing}");

    // The captures, in order from the first, each where the vehicle was.
    let images = r["images"].as_array().expect("images");
    assert!(images.len() >= MIN_IMAGES, "{context}");
    for (k, img) in images.iter().enumerate() {
        assert_eq!(u(img, "component"), CAMERA_COMPONENT, "{img}");
        assert_eq!(u(img, "image_index"), k as u64, "indices run from 0: {img}");
        assert_eq!(u(img, "capture_result"), 1, "{img}");
        assert!(i(img, "lat") != 0 && i(img, "lon") != 0, "{img}");
        let url = s(img, "file_url");
        let digits = url
            .strip_prefix("IMG_")
            .and_then(|rest| rest.strip_suffix(".jpg"))
            .unwrap_or_else(|| panic!("file_url {url:?} is not IMG_nnnnnn.jpg"));
        assert!(
            digits.len() == 6 && digits.bytes().all(|b| b.is_ascii_digit()),
            "file_url {url:?}"
        );
    }

    // What the station saw is what alfd logged: the same image under seq =
    // index + 1, at the same place and autopilot time.
    let flight = out_dir.path().join("flight-001");
    let manifest = std::fs::read_to_string(flight.join("manifest.jsonl"))
        .unwrap_or_else(|e| panic!("{}: {e}\n{context}", flight.display()));
    let records: HashMap<u64, Value> = manifest
        .lines()
        .map(|l| {
            let v: Value = serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}"));
            (u(&v, "seq"), v)
        })
        .collect();
    assert!(records.len() >= images.len(), "{} records", records.len());
    for img in images {
        let seq = u(img, "image_index") + 1;
        let rec = records
            .get(&seq)
            .unwrap_or_else(|| panic!("no manifest record with seq {seq} for {img}"));
        let name = s(rec, "image");
        assert_eq!(s(img, "file_url"), name, "seq {seq}");
        assert!(flight.join(name).is_file(), "{name} is not in the flight");
        let pos = &rec["position"];
        let lat_e7 = f(pos, "lat_deg") * 1e7;
        let lon_e7 = f(pos, "lon_deg") * 1e7;
        assert!(
            (i(img, "lat") as f64 - lat_e7).abs() <= 2.0
                && (i(img, "lon") as f64 - lon_e7).abs() <= 2.0,
            "seq {seq}: GCS {img} vs manifest {pos}"
        );
        let boot_ms = f(rec, "time_boot_us") / 1000.0;
        assert!(
            (u(img, "time_boot_ms") as f64 - boot_ms).abs() <= 1.0,
            "seq {seq}: GCS time_boot_ms {} vs manifest {boot_ms} ms",
            u(img, "time_boot_ms")
        );
    }
    println!(
        "gcs_camera: {} captures seen live ({} logged), ALF_SPC {spacing:.2} m, in {elapsed:.1?}",
        images.len(),
        records.len()
    );
}
