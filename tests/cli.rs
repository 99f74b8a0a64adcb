//! `alfd estimate` and `alfd check-config` as a user runs them: on the shipped
//! maps, on hand-made two-level maps (against DESIGN's closed forms, 2 %), and
//! on bad input (one line naming the problem, exit code 2).

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn alfd(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_alfd"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("alfd runs")
}

/// What `alfd args` prints, once it has succeeded.
fn text(args: &[&str]) -> String {
    let out = alfd(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `alfd estimate` on the shipped 160×120 roof map, then `extra`; no field of view.
fn roof_map<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "estimate",
        "--depth",
        "tests/data/roof_160x120.z16",
        "--width",
        "160",
        "--height",
        "120",
    ];
    a.extend_from_slice(extra);
    a
}

/// `alfd estimate` on the shipped 160×120 roof map at 69°, then `extra`.
fn roof_estimate<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = roof_map(&["--hfov-deg", "69"]);
    a.extend_from_slice(extra);
    a
}

fn json(args: &[&str]) -> Value {
    let mut a = args.to_vec();
    a.push("--json");
    let out = alfd(&a);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("valid JSON")
}

fn f(v: &Value, path: &[&str]) -> f64 {
    let mut x = v;
    for k in path {
        x = &x[*k];
    }
    x.as_f64()
        .unwrap_or_else(|| panic!("{path:?} is not a number: {x}"))
}

fn within(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs()
}

/// Runs alfd expecting bad input: exit 2 and exactly one line on stderr
/// containing every word of `expect`.
fn rejects(args: &[&str], expect: &[&str]) {
    let out = alfd(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "args {args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line, got: {err}");
    for w in expect {
        assert!(err.contains(w), "{w:?} missing from: {err}");
    }
    assert!(out.stdout.is_empty());
}

#[test]
fn shipped_roof_map_matches_the_closed_forms() {
    let v = json(&roof_estimate(&["--model", "occlusion"]));
    assert_eq!(v["status"], "ok");
    // f = 80/tan(34.5°); roof at 20 m, ground at 40 m: Δw = 0.025 1/m.
    let focal = 80.0 / 34.5f64.to_radians().tan();
    assert!(within(
        f(&v, &["spacing_m", "mmds"]),
        2.0 / (focal * 0.025),
        0.02
    ));
    // The 12 m wide roof seen from 20 m spans |y/f| <= 0.3: rows r with
    // |r + 0.5 - 60| <= 0.3·f, each crossing two edges of contrast 0.025.
    let rows = (0..120)
        .filter(|r| ((*r as f64 + 0.5 - 60.0) / focal).abs() <= 0.3)
        .count();
    assert_eq!(rows, 70);
    let d = rows as f64 * 2.0 * 0.025 / 120.0;
    let occ = 0.01 * 160.0 / (focal * d);
    assert!(
        within(f(&v, &["spacing_m", "occlusion"]), occ, 0.02),
        "{}",
        v["spacing_m"]
    );
    assert_eq!(v["active_bound"], "occlusion");
    assert_eq!(v["occlusion"]["boundaries"], 140);
    assert!(within(f(&v, &["occlusion", "degree"]), 0.01, 1e-9));
    let terms: Vec<&str> = v["terms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap())
        .collect();
    assert_eq!(terms, ["mmds", "occlusion", "coverage", "score"]);
}

#[test]
fn every_shipped_map_answers_with_the_documented_schema() {
    for args in [
        vec![
            "estimate",
            "--depth",
            "tests/data/buildings_320x240.png",
            "--hfov-deg",
            "69",
            "--pitch-deg",
            "20",
            "--sspa",
        ],
        vec![
            "estimate",
            "--depth",
            "tests/data/street_64x48.pfm",
            "--hfov-deg",
            "90",
            "--pitch-deg",
            "60",
        ],
        roof_estimate(&["--decimation", "auto"]),
    ] {
        let v = json(&args);
        assert_eq!(v["status"], "ok", "{args:?}");
        for key in [
            "status",
            "reason",
            "valid_fraction",
            "far_below_fraction",
            "far_end_unbounded",
            "inv_depth_per_m",
            "occlusion",
            "spacing_m",
            "active_bound",
            "terms",
            "best_pitch_deg",
            "elapsed_us",
        ] {
            assert!(v.get(key).is_some(), "{key} missing for {args:?}");
        }
        for key in ["mmds", "sspa", "occlusion", "coverage", "chosen"] {
            let x = &v["spacing_m"][key];
            assert!(
                x.is_null() || x.as_f64().is_some_and(|s| s.is_finite() && s > 0.0),
                "{key}: {x}"
            );
        }
        let chosen = f(&v, &["spacing_m", "chosen"]);
        assert!(chosen > 0.0);
    }
}

#[test]
fn human_summary_names_the_chosen_spacing_and_its_bound() {
    let out = alfd(&roof_estimate(&[]));
    assert!(out.status.success());
    let s = String::from_utf8_lossy(&out.stdout);
    // The default, the quality model: the targets, each one's spacing, the
    // prediction at the chosen spacing. The roof's 20 m of relief binds the
    // 2 px parallax at 2/(f·Δw) = 0.687 m.
    for want in [
        "targets        lightfield profile: parallax 2 px",
        "spacing  parallax        0.687 m      predicted at chosen: 2.00 px",
        "chosen         0.687 m (quality model, bound: parallax)",
        "terms          parallax, visibility, views, mmds, coverage",
    ] {
        assert!(s.contains(want), "{want:?} missing from:\n{s}");
    }
    let out = alfd(&roof_estimate(&["--model", "occlusion"]));
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(
        s.contains("chosen") && s.contains("bound: occlusion"),
        "{s}"
    );
    assert!(!s.contains("targets are not met"), "{s}");
    // A 1° lens: the 2 px parallax allows millimetres, the default floor
    // (spacing_min_m 0.05 m) holds the spacing above it, and says the targets break.
    let out = alfd(&[
        "estimate",
        "--depth",
        "tests/data/buildings_320x240.png",
        "--hfov-deg",
        "1",
    ]);
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(
        s.contains("chosen         0.050 m (quality model, bound: config_min)"),
        "{s}"
    );
    assert!(
        s.contains("longer than the permissible 3.491e-3 m: sampling.spacing_min_m holds it, so the targets are not met"),
        "{s}"
    );
}

/// The mapping profile and targets set one by one: the bound follows, and a
/// target out of range is refused naming the flag's field.
#[test]
fn quality_targets_from_the_command_line() {
    let v = json(&roof_estimate(&["--profile", "mapping"]));
    assert_eq!(v["active_bound"], "forward_overlap");
    assert_eq!(v["quality"]["targets"]["profile"], "mapping");
    assert_eq!(v["quality"]["targets"]["views_per_point_min"], 3);
    assert!(within(
        f(&v, &["quality", "predicted", "forward_overlap"]),
        0.8,
        1e-9
    ));
    let v = json(&roof_estimate(&[
        "--parallax-px",
        "off",
        "--forward-overlap",
        "0.5",
    ]));
    assert!(v["quality"]["targets"]["parallax_px"].is_null());
    assert!(within(
        f(&v, &["quality", "targets", "forward_overlap"]),
        0.5,
        1e-12
    ));
    let out = alfd(&roof_estimate(&["--unseen-fraction-max", "2"]));
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("quality.unseen_fraction_max"), "{err}");
    // "off" takes the two other targets out of force as it does the first two
    // (the help and configs/estimator.toml say so): 1 for both.
    let v = json(&roof_estimate(&[
        "--unseen-fraction-max",
        "off",
        "--views-per-point-min",
        "off",
    ]));
    assert_eq!(v["quality"]["targets"]["unseen_fraction_max"], 1.0);
    assert_eq!(v["quality"]["targets"]["views_per_point_min"], 1);
    // A target out of force bounds nothing: the unseen term is not among the
    // terms used although the roof occludes, and the text says which rows are
    // off and which were left out by the frame.
    let terms: Vec<&str> = v["terms"]
        .as_array()
        .expect("terms")
        .iter()
        .filter_map(|t| t.as_str())
        .collect();
    assert!(
        !terms.contains(&"visibility") && terms.contains(&"views"),
        "{terms:?}"
    );
    let s = text(&roof_estimate(&["--unseen-fraction-max", "off"]));
    assert!(
        s.contains("forward overlap off, unseen off, views >= 2"),
        "{s}"
    );
    assert!(
        s.contains("spacing  unseen_fraction off (not in force)\n"),
        "{s}"
    );
    let s = text(&roof_estimate(&["--depth-scale-m", "1e30"]));
    // Depth far beyond any camera: a float's digits are not printed as a
    // measurement, and a count that saturates is not given as a count.
    assert!(s.contains("depth range    2.000e34 m to 4.000e34 m"), "{s}");
    assert!(s.contains("predicted at chosen: unbounded"), "{s}");
    let s = text(&roof_estimate(&[]));
    assert!(
        s.contains("spacing  forward_overlap off (not in force)\n"),
        "{s}"
    );
    // A stride that leaves the frame one sample: the spacing rests on it, and
    // the text says so with the coarsest stride that keeps 200 (160/9 × 120/9).
    let s = text(&roof_estimate(&["--decimation", "256"]));
    assert!(
        s.contains("1 sample of the frame at decimation 256, fewer than the 200 its 0.5 % percentile needs")
            && s.contains("(decimation 9 at most for this frame)"),
        "{s}"
    );
    assert!(!text(&roof_estimate(&["--decimation", "9"])).contains("percentile needs"));
    let out = alfd(&roof_estimate(&["--views-per-point-min", "two"]));
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--views-per-point-min two: a whole number"),
        "{err}"
    );
}

fn write_two_level_z16(
    dir: &Path,
    w: usize,
    h: usize,
    split: usize,
    near_mm: u16,
    far_mm: u16,
) -> PathBuf {
    let mut bytes = Vec::new();
    for _ in 0..h {
        for i in 0..w {
            let z = if i < split { near_mm } else { far_mm };
            bytes.extend_from_slice(&z.to_le_bytes());
        }
    }
    let p = dir.join("two_level.z16");
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn hand_made_two_level_maps_match_design_within_two_percent() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("tight.toml");
    // O_max small enough that one edge per row binds.
    std::fs::write(
        &config,
        "[sampling]\nmodel = \"occlusion\"\nocclusion_max = 0.001\nspacing_min_m = 0.001\n",
    )
    .unwrap();
    for (w, h, split, near, far, fov, pitch) in [
        (
            640usize, 48usize, 300usize, 15_000u16, 45_000u16, 69.0f64, 0.0f64,
        ),
        (320, 20, 100, 8_000, 30_000, 40.0, 30.0),
        (1280, 8, 900, 2_500, 3_000, 100.0, -45.0),
    ] {
        let path = write_two_level_z16(dir.path(), w, h, split, near, far);
        let ws = w.to_string();
        let hs = h.to_string();
        let fovs = fov.to_string();
        let pitchs = pitch.to_string();
        let v = json(&[
            "estimate",
            "--depth",
            path.to_str().unwrap(),
            "--width",
            &ws,
            "--height",
            &hs,
            "--hfov-deg",
            &fovs,
            "--pitch-deg",
            &pitchs,
            "--config",
            config.to_str().unwrap(),
        ]);
        let focal = (w as f64 / 2.0) / (fov / 2.0).to_radians().tan();
        let c = pitch.to_radians().cos();
        let dw = 1000.0 / near as f64 - 1000.0 / far as f64;
        // MMDS 2/(f·cos φ·Δw); occlusion O_max·2v_m/(f·cos φ·D) with D = Δw (one edge a row).
        assert!(
            within(f(&v, &["spacing_m", "mmds"]), 2.0 / (focal * c * dw), 0.02),
            "{v}"
        );
        let occ = (0.001 * w as f64 / (focal * c * dw)).min(2.0 / (focal * c * dw));
        assert!(within(f(&v, &["spacing_m", "occlusion"]), occ, 0.02), "{v}");
    }
}

#[test]
fn bad_input_gets_one_line_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.z16");
    std::fs::write(&short, vec![0u8; 100]).unwrap();
    let s = short.to_str().unwrap();
    rejects(
        &[
            "estimate",
            "--depth",
            s,
            "--width",
            "160",
            "--height",
            "120",
            "--hfov-deg",
            "69",
        ],
        &["truncated", "short.z16"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "tests/data/roof_160x120.z16",
            "--width",
            "100",
            "--height",
            "100",
            "--hfov-deg",
            "69",
        ],
        &["size does not match"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "tests/data/buildings_320x240.png",
            "--width",
            "100",
            "--hfov-deg",
            "69",
        ],
        &["size mismatch"],
    );
    let rgb = dir.path().join("rgb.png");
    {
        let file = std::fs::File::create(&rgb).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), 2, 2);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .unwrap()
            .write_image_data(&[0u8; 12])
            .unwrap();
    }
    rejects(
        &[
            "estimate",
            "--depth",
            rgb.to_str().unwrap(),
            "--hfov-deg",
            "69",
        ],
        &["16-bit greyscale", "rgb.png"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "no/such/depth.png",
            "--hfov-deg",
            "69",
        ],
        &["cannot read", "no/such/depth.png"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "tests/data/street_64x48.pfm",
            "--hfov-deg",
            "175",
        ],
        &["--hfov-deg", "between 1 and 170"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "tests/data/street_64x48.pfm",
            "--hfov-deg",
            "0.5",
        ],
        &["--hfov-deg"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "tests/data/roof_160x120.z16",
            "--hfov-deg",
            "69",
        ],
        &["--width/--height"],
    );
    rejects(
        &[
            "estimate",
            "--depth",
            "tests/data/street_64x48.pfm",
            "--hfov-deg",
            "69",
            "--model",
            "best",
        ],
        &["--model"],
    );
}

#[test]
fn no_estimate_is_reported_not_guessed() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("empty.z16");
    std::fs::write(&p, vec![0u8; 2 * 8 * 6]).unwrap();
    let v = json(&[
        "estimate",
        "--depth",
        p.to_str().unwrap(),
        "--width",
        "8",
        "--height",
        "6",
        "--hfov-deg",
        "60",
    ]);
    assert_eq!(v["status"], "no_estimate");
    assert_eq!(v["reason"], "too_few_valid_pixels");
    let text = v["reason_text"].as_str().unwrap();
    assert!(
        text.starts_with("0 % of the depth valid, 20 % needed"),
        "{text}"
    );
    assert!(v["spacing_m"]["chosen"].is_null());
    let v = json(&[
        "estimate",
        "--depth",
        "tests/data/street_64x48.pfm",
        "--hfov-deg",
        "90",
        "--pitch-deg",
        "89.5",
    ]);
    assert_eq!(v["reason"], "pitch_near_horizontal");
    // In words, with the pitch and the key that limits it (was the code only).
    let text = v["reason_text"].as_str().unwrap();
    assert!(
        text.starts_with("pitch 89.5 deg is beyond estimator.pitch_max_deg"),
        "{text}"
    );
}

#[test]
fn check_config_accepts_the_shipped_configs_and_names_bad_fields() {
    for entry in std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs")).unwrap() {
        let p = entry.unwrap().path();
        let out = alfd(&["check-config", p.to_str().unwrap()]);
        assert!(
            out.status.success(),
            "{}: {}",
            p.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // What the daemon would do, defaults included, a line a section.
    let said = text(&["check-config", "configs/rpi-realsense.toml"]);
    for want in [
        "link           serial:/dev/ttyAMA0:921600 as system 1 component 100",
        "depth          V4L2 the device of serial 012345678901, card \"RealSense\" (Z16), 640x480 at 30 fps, 87 deg wide, 0.001 m per unit",
        "camera         V4L2 the device of serial 012345678901 (YUYV), 640x480 at 30 fps, 69 deg wide",
        "targets        lightfield profile: parallax 2 px, forward overlap off, unseen <= 0.002, views >= 2",
        "decimation     2",
        "trigger        at most 10 captures a second; 1 m without an estimate; closed loop off",
        "capture        frames saved by alfd, into /var/lib/alfd/flights",
    ] {
        assert!(said.contains(want), "{want:?} not in\n{said}");
    }
    let estimator_only = text(&["check-config", "configs/estimator.toml"]);
    assert!(!estimator_only.contains("link "), "{estimator_only}");
    assert!(
        estimator_only.contains("model          quality"),
        "{estimator_only}"
    );
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[sampling]\nocclusion_max = 3.0\n").unwrap();
    rejects(
        &["check-config", bad.to_str().unwrap()],
        &["sampling.occlusion_max"],
    );
    std::fs::write(&bad, "[estimator]\ndecimaton = 2\n").unwrap();
    rejects(
        &["check-config", bad.to_str().unwrap()],
        &["decimaton", "line 2"],
    );
    // A scene that is not there is caught by check-config, not at take-off.
    std::fs::write(&bad, "[sim]\nscene = \"no-such-scene.toml\"\n").unwrap();
    rejects(
        &["check-config", bad.to_str().unwrap()],
        &["sim.scene", "no-such-scene.toml"],
    );
}

/// What a flight on simulated time cannot do is refused before anything is written, naming
/// the flag that makes it possible.
#[test]
fn sim_refuses_what_simulated_time_cannot_do() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let out_s = out.to_str().unwrap();
    rejects(
        &["sim", "--pose", "telemetry", "--out", out_s],
        &["--pose telemetry", "--real-time"],
    );
    rejects(
        &["sim", "--gcs", "udpout:127.0.0.1:9", "--out", out_s],
        &["--gcs", "--real-time"],
    );
    // A scene or config that cannot be read or parsed, or a line longer than the
    // scene's, is refused before the flight's directory is made (each left an
    // empty one behind).
    rejects(
        &["sim", "--scene", "no/such/scene.toml", "--out", out_s],
        &["--scene no/such/scene.toml", "No such file"],
    );
    rejects(
        &["sim", "--scene", "Cargo.toml", "--out", out_s],
        &["Cargo.toml"],
    );
    rejects(
        &["sim", "--config", "no/such/alfd.toml", "--out", out_s],
        &["no/such/alfd.toml"],
    );
    rejects(
        &[
            "sim",
            "--scene",
            "tests/data/tower.toml",
            "--length-m",
            "71",
            "--out",
            out_s,
        ],
        &["--length-m 71", "70 m"],
    );
    assert!(!out.exists(), "a refused run wrote {}", out.display());
}

/// `alfd tradeoff` refuses what it cannot measure, naming the flag, before
/// it renders or times anything: a frame too large to allocate (it aborted
/// the process), none timed (`--repeats 0` printed "median of 0 runs" over
/// times it had taken once), and angles that only a --depth map would have
/// read (they were never checked without one).
#[test]
fn tradeoff_refuses_what_it_cannot_measure_by_name() {
    rejects(
        &["tradeoff", "--width", "100000", "--height", "100000"],
        &["--width 100000", "--height 100000", "4096"],
    );
    rejects(&["tradeoff", "--width", "8"], &["--width 8", "16×12"]);
    rejects(&["tradeoff", "--repeats", "0"], &["--repeats 0"]);
    rejects(&["tradeoff", "--hfov-deg", "200"], &["--hfov-deg", "170"]);
    rejects(&["tradeoff", "--hfov-deg", "-5"], &["--hfov-deg", "-5"]);
    rejects(&["tradeoff", "--pitch-deg", "NaN"], &["--pitch-deg NaN"]);
    // A raw Z16 map: the reader's answer sent the user to --width/--height, which
    // here size the reference scenes and cannot describe the map.
    rejects(
        &["tradeoff", "--depth", "tests/data/roof_160x120.z16"],
        &["--depth", "roof_160x120.z16", "16-bit PNG or a PFM"],
    );
    rejects(
        &["tradeoff", "--repeats", "5000"],
        &["--repeats 5000", "1 to 1000"],
    );
    // A map past the estimator's pitch has no estimate at any level: its
    // column read 0 % error everywhere.
    rejects(
        &[
            "tradeoff",
            "--depth",
            "tests/data/buildings_320x240.png",
            "--pitch-deg",
            "85",
        ],
        &[
            "--depth tests/data/buildings_320x240.png: no estimate at full resolution",
            "pitch 85.0 deg is beyond estimator.pitch_max_deg",
        ],
    );
}

/// `alfd tradeoff --depth` reads a map at the scale `alfd estimate` would: a
/// daemon config's camera (0.01 m per unit), a flag over it, and says which.
#[test]
fn tradeoff_reads_a_depth_map_at_the_cameras_scale() {
    let run = |extra: &[&str]| {
        let mut args = vec![
            "tradeoff",
            "--width",
            "16",
            "--height",
            "12",
            "--repeats",
            "1",
            "--depth",
            "tests/data/buildings_320x240.png",
        ];
        args.extend_from_slice(extra);
        text(&args)
    };
    let header = |out: &str| {
        out.lines()
            .find(|l| l.contains("reference frames"))
            .map(str::to_owned)
    };
    let from_config = run(&["--config", "configs/sim.toml"]);
    assert!(
        header(&from_config)
            .is_some_and(|h| h.contains("buildings_320x240.png (320x240, 0.01 m per unit)")),
        "{from_config}"
    );
    let flag = run(&["--config", "configs/sim.toml", "--depth-scale-m", "0.002"]);
    assert!(
        header(&flag).is_some_and(|h| h.contains("(320x240, 0.002 m per unit)")),
        "{flag}"
    );
    let default = run(&[]);
    assert!(
        header(&default).is_some_and(|h| h.contains("(320x240, 0.001 m per unit)")),
        "{default}"
    );
    rejects(
        &["tradeoff", "--depth-scale-m", "0"],
        &["--depth-scale-m 0: must be a positive number"],
    );
}

/// A depth frame dumped from the daemon's camera, estimated with the daemon's
/// config, is read as the daemon reads it: configs/sim.toml's camera gives 0.01 m
/// per unit (the default 0.001 put every depth ten times too near, silently) and
/// its field of view; a flag still overrides, and without either the field of
/// view is asked for by name.
#[test]
fn estimate_reads_the_depth_camera_of_a_daemon_config() {
    let with = |extra: &[&str]| text(&roof_map(extra));
    let s = with(&["--config", "configs/sim.toml"]);
    assert!(s.contains("depth range    200.0 m to 400.0 m"), "{s}");
    assert!(
        s.contains("from config    hfov 69 deg, 0.01 m per unit ([depth] of configs/sim.toml)"),
        "{s}"
    );
    let s = with(&[
        "--config",
        "configs/sim.toml",
        "--depth-scale-m",
        "0.001",
        "--hfov-deg",
        "69",
    ]);
    assert!(s.contains("depth range    20.000 m to 40.000 m"), "{s}");
    assert!(!s.contains("from config"), "{s}");
    // The JSON echoes the scale it read the map at, so a result file stands alone.
    assert_eq!(
        json(&roof_map(&["--config", "configs/sim.toml"]))["input"]["depth_scale_m"],
        0.01
    );
    // An estimator config has no camera: the flag is needed.
    rejects(
        &roof_map(&["--config", "configs/estimator.toml"]),
        &["--hfov-deg", "field of view is needed"],
    );
}

/// `alfd sim` refuses by flag what it cannot fly, before any directory is made:
/// `--config` with an estimator config (no `[mavlink]`: it validated, and the
/// daemon stopped for want of a link, "config: no [mavlink] section: the daemon
/// needs a link", no file named, after making an empty flight directory), and an
/// `--out` that is a file.
#[test]
fn sim_refuses_by_flag_before_making_a_flight() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    rejects(
        &[
            "sim",
            "--config",
            "configs/estimator.toml",
            "--out",
            out.to_str().unwrap(),
        ],
        &[
            "--config configs/estimator.toml: no [mavlink] section",
            "configs/sim.toml",
        ],
    );
    assert!(!out.exists(), "a flight directory was made");
    // A flag a given config sets is named with the key that sets it, and bad
    // targets by what was given, before any directory is made.
    let o = out.to_str().unwrap();
    rejects(
        &[
            "sim",
            "--config",
            "configs/sim.toml",
            "--fps",
            "15",
            "--out",
            o,
        ],
        &["--fps: with --config configs/sim.toml, this is the config's [depth] fps"],
    );
    rejects(
        &[
            "sim",
            "--config",
            "configs/sim.toml",
            "--unseen-fraction-max",
            "7",
            "--out",
            o,
        ],
        &[
            "the quality targets given over configs/sim.toml: quality.unseen_fraction_max",
            "got 7",
        ],
    );
    rejects(
        &["sim", "--parallax-px", "-1", "--out", o],
        &["the quality targets given: quality.parallax_px", "got -1"],
    );
    assert!(!out.exists(), "a flight directory was made");
    // An --out that is a file, or under one, is named by its flag.
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"").unwrap();
    rejects(
        &["sim", "--out", file.to_str().unwrap()],
        &["--out", "a-file: a file, not a directory"],
    );
    let under = file.join("x");
    rejects(
        &["sim", "--out", under.to_str().unwrap()],
        &["--out", "a-file/x: Not a directory"],
    );
}

/// `alfd eval` refuses, before its first scene, what would fail only after
/// minutes of evaluation: an output path that is a file ("writing file: File
/// exists" came after the scenes loaded), a scene directory that is not there,
/// and `--colmap` with no judge script (every COLMAP result an error at the end).
#[test]
fn eval_refuses_what_would_fail_after_minutes() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"").unwrap();
    rejects(
        &["eval", "--scene", "roof", "--out", file.to_str().unwrap()],
        &["--out", "a-file", "not a directory"],
    );
    let out = dir.path().join("eval");
    let nowhere = dir.path().join("no-scenes");
    rejects(
        &[
            "eval",
            "--scenes-dir",
            nowhere.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &["--scenes-dir", "no-scenes", "no such directory"],
    );
    let script = dir.path().join("no-judge.py");
    rejects(
        &[
            "eval",
            "--scene",
            "roof",
            "--colmap",
            "--colmap-script",
            script.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &["--colmap-script", "no-judge.py", "no such file"],
    );
    assert!(!out.exists(), "a refused eval wrote {}", out.display());
}
