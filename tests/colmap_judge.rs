//! COLMAP as a second judge: `scripts/colmap_judge.py` (pycolmap, CPU) on a short `alfd sim`
//! flight must register nearly every capture, reproject well and put the cameras where
//! `transforms.json` says, after a similarity. Skipped, with a message, only when pycolmap is
//! missing and `CI` is unset.

mod tools;

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The one `flight-NNN` directory `alfd sim` wrote under `out`.
fn flight_dir(out: &Path) -> PathBuf {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(out)
        .expect("the sim's output directory")
        .map(|e| e.expect("a directory entry").path())
        .filter(|p| {
            p.is_dir()
                && p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("flight-"))
        })
        .collect();
    assert_eq!(dirs.len(), 1, "one flight in {}: {dirs:?}", out.display());
    dirs.pop().unwrap()
}

fn number(report: &Value, path: &[&str]) -> f64 {
    let v = path.iter().fold(report, |v, k| &v[*k]);
    v.as_f64()
        .unwrap_or_else(|| panic!("{} is not a number in the report: {v}", path.join(".")))
}

#[test]
fn colmap_registers_a_short_sim_flight_where_its_transforms_say() {
    if !tools::pycolmap("colmap_judge") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sim");
    // 60 m of the default scene's line at 100 m: about two dozen 640 x 480 captures, so the
    // flight and COLMAP together stay around half a minute of CPU.
    let sim = Command::new(env!("CARGO_BIN_EXE_alfd"))
        .args(["sim", "--length-m", "60", "--no-progress", "--out"])
        .arg(&out)
        .output()
        .expect("alfd runs");
    assert!(
        sim.status.success(),
        "alfd sim failed: {}",
        String::from_utf8_lossy(&sim.stderr)
    );
    let flight = flight_dir(&out);
    let jpegs = std::fs::read_dir(&flight)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "jpg")
        })
        .count();

    let json = tmp.path().join("colmap.json");
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/colmap_judge.py");
    let judge = Command::new("python3")
        .arg(script)
        .arg(&flight)
        .arg("--work")
        .arg(tmp.path().join("colmap"))
        .arg("--json")
        .arg(&json)
        .output()
        .expect("python3 runs");
    println!("{}", String::from_utf8_lossy(&judge.stdout));
    assert!(
        judge.status.success(),
        "colmap_judge.py failed: {}",
        String::from_utf8_lossy(&judge.stderr)
    );
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("the --json file")).unwrap();

    let count = |key: &str| {
        report[key]
            .as_u64()
            .unwrap_or_else(|| panic!("{key} is not a count in the report: {}", report[key]))
    };
    let (total, registered) = (count("images_total"), count("images_registered"));
    assert_eq!(
        total, jpegs as u64,
        "transforms.json names every saved capture"
    );
    assert!(total >= 10, "a 60 m flight gives ~24 captures, got {total}");
    assert!(
        10 * registered >= 9 * total,
        "COLMAP registered {registered} of {total} images"
    );
    let reprojection_px = number(&report, &["mean_reprojection_px"]);
    assert!(
        reprojection_px < 1.5,
        "mean reprojection error {reprojection_px:.3} px"
    );
    let centre = number(&report, &["centre_error_fraction", "median"]);
    assert!(
        centre < 0.01,
        "median camera centre off by {:.2} % of the track after the similarity",
        100.0 * centre
    );
    // Not asserted: the synthetic camera ignores yaw and roll (issue 14), so the first captures
    // of a sim flight, taken while the vehicle turns onto the line, disagree with their logged
    // attitude by up to 180 degrees.
    println!(
        "rotation agreement: median {:.2} deg, max {:.2} deg (not asserted, issue 14)",
        number(&report, &["rotation_error_deg", "median"]),
        number(&report, &["rotation_error_deg", "max"])
    );
}
