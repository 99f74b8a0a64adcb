//! The flight build (`--no-default-features`, issue 15) links neither the
//! simulated autopilot, the plots, the progress bars nor the renderer's thread
//! pool: `cargo tree` of that build must not list them, while the default
//! build (`alfd sim`, `alfd eval`) still does. `.ci/run` also lints the lean
//! build, so a module the lean build cannot compile fails there.

use std::collections::BTreeSet;
use std::process::Command;

/// The crates only `alfd sim`, `alfd eval` and the synthetic sources use.
const SIM_ONLY: [&str; 5] = ["firmware-sim", "plotters", "indicatif", "rayon", "ab_glyph"];

/// The names of the crates in alfd's normal (non-dev, non-build) dependency tree.
fn normal_deps(features: &[&str]) -> BTreeSet<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "tree",
            "--offline",
            "--locked",
            "-p",
            "alfd",
            "-e",
            "normal",
        ])
        .args(["--prefix", "none", "--format", "{p}"])
        .args(features)
        .arg("--manifest-path")
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml"))
        .output()
        .expect("running cargo tree");
    assert!(
        out.status.success(),
        "cargo tree {features:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_owned)
        .collect()
}

#[test]
fn the_flight_build_links_no_simulator_plots_or_progress_bars() {
    let lean = normal_deps(&["--no-default-features"]);
    let full = normal_deps(&[]);
    // What the flight needs is there: the tree was read, not empty.
    for needed in ["alfd", "mavlink", "tokio", "jpeg-encoder", "png"] {
        assert!(lean.contains(needed), "{needed} missing from {lean:?}");
    }
    let linked: Vec<_> = SIM_ONLY.iter().filter(|c| lean.contains(**c)).collect();
    assert!(
        linked.is_empty(),
        "the --no-default-features build links {linked:?}"
    );
    // The default build keeps `alfd sim` and `alfd eval`, so it has them all.
    let missing: Vec<_> = SIM_ONLY.iter().filter(|c| !full.contains(**c)).collect();
    assert!(missing.is_empty(), "the default build lacks {missing:?}");
    eprintln!(
        "FIGURE lean build {} crates, default {} ({} only in the default build)",
        lean.len(),
        full.len(),
        full.difference(&lean).count()
    );
}
