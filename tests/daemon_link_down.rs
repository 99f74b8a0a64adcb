//! `alfd run` whose autopilot cannot be reached says so, and stops cleanly on a SIGTERM
//! that comes while it is still starting. A wrong serial device in `mavlink.address` used
//! to leave only "triggers suspended: no position from the autopilot yet", the reason (the
//! device is missing) thrown away; a SIGTERM before the daemon's loop first listened for
//! it killed the process by the signal's default action.

mod tools;

use std::path::Path;
use std::process::{Child, ExitStatus};
use std::sync::mpsc;
use std::time::Duration;

/// `alfd run` (JSON log) on the tower config against a serial device that does not
/// exist, its stderr's lines sent to the receiver as they come.
fn start(dir: &Path) -> (Child, mpsc::Receiver<String>, String) {
    let address = format!("serial:{}:921600", dir.join("no-such-tty").display());
    start_at(dir, address)
}

/// [`start`] against `address`.
fn start_at(dir: &Path, address: String) -> (Child, mpsc::Receiver<String>, String) {
    let config = dir.join("alfd.toml");
    std::fs::write(
        &config,
        tools::synthetic_tower_config(&address, &dir.join("captures"), "frame"),
    )
    .unwrap();
    let (child, rx) = tools::alfd_run_lines(&config, &[]);
    (child, rx, address)
}

/// Lines until `done` holds of them. The bound only keeps a broken build from hanging
/// the suite: every line awaited comes within milliseconds of the start.
fn read_until(
    child: &mut Child,
    rx: &mpsc::Receiver<String>,
    done: impl Fn(&[String]) -> bool,
) -> Vec<String> {
    let mut seen = Vec::new();
    while !done(&seen) {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(l) => seen.push(l),
            Err(_) => {
                child.kill().ok();
                panic!("not within 60 s; the log so far: {seen:#?}");
            }
        }
    }
    seen
}

fn sigterm_and_wait(child: &mut Child) -> ExitStatus {
    // SAFETY: signalling our own child by its pid.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    child.wait().unwrap()
}

fn message(line: &str) -> (String, String) {
    let v: serde_json::Value = serde_json::from_str(line).unwrap();
    (
        v["level"].as_str().unwrap_or_default().to_string(),
        v["fields"]["message"]
            .as_str()
            .unwrap_or_default()
            .to_string(),
    )
}

#[test]
fn a_link_that_cannot_connect_is_warned_of_with_its_reason() {
    let tmp = tempfile::tempdir().unwrap();
    let (mut child, rx, address) = start(tmp.path());
    let seen = read_until(&mut child, &rx, |s| {
        s.iter().any(|l| l.contains("cannot connect"))
    });
    let status = sigterm_and_wait(&mut child);
    let (level, text) = message(seen.last().unwrap());
    assert_eq!(level, "WARN", "{text}");
    assert!(text.contains(&address), "{text}");
    assert!(text.contains("No such file or directory"), "{text}");
    assert!(status.success(), "alfd run after SIGTERM: {status}");
}

#[test]
fn a_sigterm_while_starting_is_a_clean_stop() {
    let tmp = tempfile::tempdir().unwrap();
    let (mut child, rx, _) = start(tmp.path());
    // The first line: the daemon has opened its devices and not yet started its loops.
    let first = read_until(&mut child, &rx, |s| !s.is_empty());
    assert!(message(&first[0]).1.contains("captures go to"), "{first:?}");
    let status = sigterm_and_wait(&mut child);
    let rest: Vec<String> = rx.iter().collect();
    assert!(
        status.success(),
        "alfd run after SIGTERM: {status}; log: {rest:#?}"
    );
    assert!(
        rest.iter()
            .any(|l| message(l).1.starts_with("stopped: 0 captures")),
        "no stop report: {rest:#?}"
    );
}

/// A peer that accepts and hangs up at once makes the link close and reconnect
/// every few milliseconds: that is said at most every 10 s with the count, not once
/// per close (it filled the log at a line every 6 ms).
#[test]
fn a_flapping_link_is_not_said_at_every_close() {
    let tmp = tempfile::tempdir().unwrap();
    let server = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = server.local_addr().unwrap().port();
    let (mut child, rx, _) = start_at(tmp.path(), format!("tcpout:127.0.0.1:{port}"));
    // Twenty connections accepted and dropped: twenty closes, in well under 10 s
    // (each reconnection waits at most 500 ms).
    for _ in 0..20 {
        let (conn, _) = server.accept().unwrap();
        drop(conn);
    }
    let status = sigterm_and_wait(&mut child);
    let log: Vec<String> = rx.iter().collect();
    assert!(status.success(), "alfd run after SIGTERM: {status}");
    let closed = log
        .iter()
        .filter(|l| message(l).1.contains("closed"))
        .count();
    assert!(
        (1..=2).contains(&closed),
        "{closed} close warnings over twenty closes: {log:#?}"
    );
}
