//! A small `alfd eval` on a tiny scene: every output is written, the JSON has
//! the documented shape, and the occlusion-aware count is matched at equal
//! captures.

use alfd::eval::{run, EvalOptions};

const SCENE: &str = r#"name = "tiny"
description = "one building, small and coarse"
[survey]
altitude_m = 40.0
speed_mps = 5.0
pitch_deg = 10.0
hfov_deg = 69.0
width = 48
height = 36
start_x_m = -6.0
end_x_m = 6.0
view_step_m = 0.2
[ground]
texture = { colour = [0.4, 0.5, 0.3], contrast = 0.4, cutoff_per_m = 0.5, seed = 1 }
[[box]]
min_m = [-4.0, -4.0, 0.0]
max_m = [4.0, 4.0, 20.0]
texture = { colour = [0.7, 0.7, 0.7], contrast = 0.3, cutoff_per_m = 0.5, seed = 2 }
"#;

#[test]
fn eval_writes_report_json_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("tiny.toml");
    std::fs::write(&scene, SCENE).unwrap();
    let out = dir.path().join("out");
    let opts = EvalOptions {
        scenes_dir: dir.path().to_path_buf(),
        out_dir: out.clone(),
        scenes: vec![scene.display().to_string()],
        quick: false,
        progress: false,
        decimation_table: true,
    };
    let report = run(&opts).unwrap();
    let md = std::fs::read_to_string(report).unwrap();
    assert!(md.contains("| occlusion |") && md.contains("Empirical permissible spacing"));
    for f in [
        "results.json",
        "decimation.md",
        "tiny_spacing.png",
        "tiny_psnr.png",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    let occ = v["tiny"]["occlusion"]["equal"]["lightfield"]["captures"]
        .as_u64()
        .unwrap();
    for method in ["occlusion", "mmds", "sspa", "fixed"] {
        for setting in ["own", "equal"] {
            for renderer in ["lightfield", "warp"] {
                let cell = &v["tiny"][method][setting][renderer];
                assert!(
                    cell["captures"].as_u64().unwrap() >= 2,
                    "{method} {setting}"
                );
                let p = cell["psnr_db"].as_f64().unwrap();
                let s = cell["ssim"].as_f64().unwrap();
                assert!(p > 10.0 && p <= 100.0, "{method} {setting} {renderer}: {p}");
                assert!(s > 0.0 && s <= 1.0, "{method} {setting} {renderer}: {s}");
            }
        }
        let eq = v["tiny"][method]["equal"]["warp"]["captures"]
            .as_u64()
            .unwrap();
        assert!(eq.abs_diff(occ) <= 1, "{method}: {eq} vs {occ}");
    }
}

#[test]
fn unknown_scene_is_an_error() {
    let opts = EvalOptions {
        scenes: vec!["no-such-scene".into()],
        progress: false,
        ..EvalOptions::default()
    };
    assert!(run(&opts).is_err());
}
