//! A ground station's view, with pymavlink: alfd's link, pointed at a UDP port the Python side
//! picked, must show up as a camera component (HEARTBEAT with MAV_TYPE_CAMERA from component
//! 100). Skipped, with a message, only when pymavlink is missing and `CI` is unset.

mod tools;

use alfd::link::{self, LinkConfig};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ground_station_sees_a_camera_component() {
    if !tools::pymavlink("interop_pymavlink") {
        return;
    }
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/python/gcs_sees_camera.py"
    );
    let mut child = Command::new("python3")
        .args([script, "1"])
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
    let mut cfg = LinkConfig::for_address(&format!("udpout:127.0.0.1:{port}"));
    cfg.system_id = 1;
    let (task, _handle, _events) = link::new(cfg);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let running = tokio::spawn(task.run(async {
        let _ = stopped.await;
    }));
    let verdict = tokio::task::spawn_blocking(move || {
        let mut line = String::new();
        out.read_line(&mut line).expect("the verdict line");
        (line, child.wait().expect("python exits"))
    });
    let (line, status) = tokio::time::timeout(Duration::from_secs(60), verdict)
        .await
        .expect("python finished")
        .expect("joined");
    let _ = stop.send(());
    running.await.expect("joined").expect("link ran");
    println!("pymavlink saw: {line}");
    assert!(
        status.success(),
        "pymavlink did not see a camera component: {line}"
    );
}
