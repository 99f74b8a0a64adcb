//! `systemd/alfd.service`: systemd's own analysers must accept it and rate its
//! exposure at most [`EXPOSURE_MAX`]; the directives alfd relies on are present.
//! Needs `systemd-analyze` (Debian package `systemd`): skipped without it,
//! except under CI where its absence is a failure.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// `systemd-analyze security` scores 0 (locked down) to 10 (unprotected); its
/// "OK" band ends at 4.9. 2.5 leaves room for a drop-in opening the network.
const EXPOSURE_MAX: f64 = 2.5;

/// Where the unit installs `alfd` (its ExecStart and ExecStartPre).
const INSTALLED_BINARY: &str = "/usr/local/bin/alfd";

fn unit_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd/alfd.service")
}

fn unit_text() -> String {
    std::fs::read_to_string(unit_path()).expect("systemd/alfd.service is readable")
}

/// `systemd-analyze` on `PATH`; `None` (after saying so) when absent outside CI.
fn systemd_analyze() -> Option<PathBuf> {
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|dir| dir.join("systemd-analyze"))
            .find(|p| p.is_file())
    });
    if found.is_none() {
        assert!(
            std::env::var_os("CI").is_none(),
            "systemd-analyze not found on PATH; CI must install the Debian package `systemd`"
        );
        eprintln!("SKIPPED: systemd-analyze not found on PATH (Debian package `systemd`)");
    }
    found
}

fn run(cmd: &mut Command) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{}{}",
        out.status,
        text(&out.stdout),
        text(&out.stderr)
    );
    out
}

/// The figure in `→ Overall exposure level for alfd.service: 1.3 OK 🙂`.
fn overall_exposure(report: &str) -> Option<f64> {
    let line = report
        .lines()
        .find(|l| l.contains("Overall exposure level for"))?;
    let (_, rest) = line.split_once(".service:")?;
    rest.split_whitespace().next()?.parse().ok()
}

#[test]
fn exposure_is_at_most_the_bound() {
    let Some(analyze) = systemd_analyze() else {
        return;
    };
    let out = run(Command::new(analyze)
        .args(["security", "--offline=yes", "--no-pager"])
        .arg(unit_path()));
    let report = String::from_utf8_lossy(&out.stdout);
    let exposure = overall_exposure(&report)
        .unwrap_or_else(|| panic!("no overall exposure in the report:\n{report}"));
    assert!(
        exposure <= EXPOSURE_MAX,
        "alfd.service exposure {exposure} > {EXPOSURE_MAX}; the ✗ lines say what opened up:\n{report}"
    );
}

/// `verify` checks every ExecStart* binary exists and is executable, and alfd is
/// not installed here, so it runs on a copy whose commands point at the alfd
/// that cargo built for this test: only the paths differ from the shipped unit.
/// It exits 0 on unknown keys and bad values (it warns and ignores them), so
/// any output at all is a failure too.
#[test]
fn verify_accepts_the_unit() {
    let Some(analyze) = systemd_analyze() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // The copy keeps the name: verify derives the unit's name from the file.
    let copy = dir.path().join("alfd.service");
    let text = unit_text().replace(INSTALLED_BINARY, env!("CARGO_BIN_EXE_alfd"));
    std::fs::write(&copy, text).unwrap();
    // Dependencies (basic.target, …) come from the host; their problems are not ours.
    let out = run(Command::new(analyze)
        .args(["verify", "--recursive-errors=no", "--man=no"])
        .arg(&copy));
    let said =
        String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
    assert!(
        said.trim().is_empty(),
        "systemd-analyze verify warned:\n{said}"
    );
}

/// A directive, its value, as the last assignment in the unit (systemd's rule
/// for single-valued settings); comments are not assignments.
fn directive<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.starts_with('#') && !l.starts_with(';'))
        .filter_map(|l| l.split_once('='))
        .filter(|(k, _)| k.trim() == key)
        .map(|(_, v)| v.trim())
        .next_back()
}

#[test]
fn unit_has_what_alfd_relies_on() {
    let text = unit_text();
    let d = |key| directive(&text, key).unwrap_or_else(|| panic!("alfd.service has no {key}="));
    // alfd run sends READY=1 and WATCHDOG=1 (src/notify.rs).
    assert_eq!(d("Type"), "notify");
    assert_eq!(d("NotifyAccess"), "main");
    assert_eq!(d("WatchdogSec"), "5");
    assert_eq!(
        d("ExecStartPre"),
        format!("{INSTALLED_BINARY} check-config /etc/alfd/alfd.toml")
    );
    assert_eq!(
        d("ExecStart"),
        format!("{INSTALLED_BINARY} run --config /etc/alfd/alfd.toml")
    );
    assert_eq!(d("Restart"), "on-failure");
    // The capture directory of configs/rpi-realsense.toml is /var/lib/alfd/….
    assert_eq!(d("StateDirectory"), "alfd");
    assert_eq!(d("DevicePolicy"), "closed");
}

#[test]
fn exposure_line_parses() {
    let report = "✗ UMask=   Files created by service are group-readable by default  0.1\n\n\
                  → Overall exposure level for alfd.service: 1.3 OK 🙂\n";
    assert_eq!(overall_exposure(report), Some(1.3));
    assert_eq!(overall_exposure("nothing here"), None);
    let text = "# Type=simple\n[Service]\nType=notify\nRestart=no\nRestart=on-failure\n";
    assert_eq!(directive(text, "Type"), Some("notify"));
    assert_eq!(directive(text, "Restart"), Some("on-failure"));
    assert_eq!(directive(text, "WatchdogSec"), None);
}
