//! COLMAP as a second judge: `scripts/colmap_judge.py` (pycolmap, CPU) on a 200 m `alfd sim`
//! flight, start-up turn included, must register nearly every capture, reproject well, put the
//! cameras where `transforms.json` says and turn every image as `transforms.json` and
//! `geo.txt` say, after a similarity. Skipped, with a message, only when pycolmap is missing
//! and `CI` is unset.

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

/// `alfd sim --length-m LENGTH` into `tmp`: its flight directory.
fn sim_flight(tmp: &Path, length_m: &str) -> PathBuf {
    let out = tmp.join("sim");
    let sim = Command::new(env!("CARGO_BIN_EXE_alfd"))
        .args(["sim", "--length-m", length_m, "--no-progress", "--out"])
        .arg(&out)
        .output()
        .expect("alfd runs");
    assert!(
        sim.status.success(),
        "alfd sim failed: {}",
        String::from_utf8_lossy(&sim.stderr)
    );
    flight_dir(&out)
}

/// `scripts/NAME FLIGHT --work TMP/colmap --json …`: its figures.
fn script(tmp: &Path, name: &str, flight: &Path) -> Value {
    let json = tmp.join("figures.json");
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(name);
    let run = Command::new("python3")
        .arg(path)
        .arg(flight)
        .arg("--work")
        .arg(tmp.join("colmap"))
        .arg("--json")
        .arg(&json)
        .output()
        .expect("python3 runs");
    println!("{}", String::from_utf8_lossy(&run.stdout));
    assert!(
        run.status.success(),
        "{name} failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(&json).expect("the --json file")).unwrap()
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
    // 200 m of the default scene's line at 100 m (the issue's own flight): about 200 640 x 480
    // captures, two to three minutes of COLMAP on two cores. The first 60 m are open fields,
    // flat ground on which a nadir camera's sideways position and its roll trade against each
    // other in any reconstruction: COLMAP put single centres 0.3-0.9 m off there (0.5-1.5 %
    // of 60 m) while alfd's logged attitude was within 0.002 deg of the picture's. By 200 m
    // the line has crossed the courtyard block, whose relief fixes them: worst 0.20-0.23 m.
    let flight = sim_flight(tmp.path(), "200");
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

    let report = script(tmp.path(), "colmap_judge.py", &flight);

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
    assert!(
        total >= 100,
        "a 200 m flight gives ~200 captures, got {total}"
    );
    assert!(
        10 * registered >= 9 * total,
        "COLMAP registered {registered} of {total} images"
    );
    let reprojection_px = number(&report, &["mean_reprojection_px"]);
    assert!(
        reprojection_px < 1.5,
        "mean reprojection error {reprojection_px:.3} px"
    );
    // Every camera centre within 1 % of the track after the similarity (2 m here), and the
    // median within 0.1 %.
    let (centre_median, centre_max) = (
        number(&report, &["centre_error_fraction", "median"]),
        number(&report, &["centre_error_fraction", "max"]),
    );
    println!(
        "camera centres: median {:.3} %, max {:.3} % of the track",
        100.0 * centre_median,
        100.0 * centre_max
    );
    assert!(
        centre_max < 0.01 && centre_median < 0.001,
        "camera centres off by {:.3} % (median) and {:.3} % (worst) of the track after the similarity",
        100.0 * centre_median,
        100.0 * centre_max
    );
    // The flight starts by turning from the return heading onto the line (firmware-sim's
    // loop): its first captures are the ones whose pictures disagreed with their logged
    // attitude while the synthetic camera rendered pitch only (issue 14).
    let yaws = geo_yaws_deg(&flight);
    assert_eq!(
        yaws.len() as u64,
        total,
        "geo.txt gives every image an attitude"
    );
    let turned = yaws
        .iter()
        .map(|y| angle_between_deg(*y, yaws[yaws.len() - 1]))
        .fold(0.0, f64::max);
    assert!(
        turned > 45.0,
        "the first captures are taken while turning onto the line: yaws {yaws:?}"
    );
    assert_eq!(
        count("geo_images"),
        total,
        "the judge read geo.txt's angles"
    );
    for (what, key) in [
        ("transforms.json", "rotation_error_deg"),
        ("geo.txt", "geo_rotation_error_deg"),
    ] {
        let (median, max) = (
            number(&report, &[key, "median"]),
            number(&report, &[key, "max"]),
        );
        println!("rotation against {what}: median {median:.3} deg, max {max:.3} deg");
        let worst: Vec<String> = report["per_image"]
            .as_array()
            .expect("per_image is a list")
            .iter()
            .filter(|i| i[key].as_f64().is_some_and(|e| e >= 2.0))
            .map(|i| format!("{} {:.1}", i["image"], i[key]))
            .collect();
        assert!(
            max < 2.0,
            "every registered image turned as {what} says, within 2 degrees: {worst:?}"
        );
    }
}

/// ODM's yaw of each line of `geo.txt` that has angles, in order (degrees).
fn geo_yaws_deg(flight: &Path) -> Vec<f64> {
    let geo = std::fs::read_to_string(flight.join("geo.txt")).expect("alfd sim writes geo.txt");
    geo.lines()
        .skip(1)
        .filter_map(|l| l.split_whitespace().nth(4))
        .map(|y| y.parse().expect("a yaw in degrees"))
        .collect()
}

/// The angle between two headings, 0 to 180 degrees.
fn angle_between_deg(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// The flight's own COLMAP model (cameras.txt, images.txt, points3D.txt) is what a
/// reconstruction from known poses starts from: `scripts/colmap_known_poses.py` runs
/// pycolmap's extraction, matching and `triangulate_points` with alfd's poses held fixed on
/// a 60 m `alfd sim` flight over open fields. Poses that disagreed with the pictures would
/// leave few points, far off the ground, and a large reprojection error (with each camera
/// turned half a turn about its axis: 21 points, 1.9 px, median height 57 m).
#[test]
fn colmap_triangulates_a_sim_flight_from_its_own_model() {
    if !tools::pycolmap("colmap_triangulates_a_sim_flight_from_its_own_model") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let flight = sim_flight(tmp.path(), "60");
    let report = script(tmp.path(), "colmap_known_poses.py", &flight);
    let images = report["images"].as_u64().expect("images");
    assert!(
        images >= 40,
        "a 60 m flight gives ~58 captures, got {images}"
    );
    assert_eq!(
        report["images_with_points"].as_u64(),
        Some(images),
        "every image sees a triangulated point"
    );
    let points = report["points3d"].as_u64().expect("points3d");
    assert!(points >= 1000, "{points} points");
    let reprojection_px = number(&report, &["mean_reprojection_px"]);
    assert!(
        reprojection_px < 0.5,
        "mean reprojection error {reprojection_px:.3} px with the poses held"
    );
    // The fields are the ground, z = 0 in the model's ENU metres.
    let median_z = number(&report, &["point_z_m", "median"]);
    assert!(
        median_z.abs() < 0.1,
        "the points' median height {median_z:.3} m"
    );
}
