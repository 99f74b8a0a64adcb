//! The core stays pure (STYLE.md practice 2). It is its own crate, `crates/alfd-core`,
//! so the compiler refuses what its manifest does not list: the manifest must list glam
//! and thiserror only. Its modules must not name tokio, files, sockets, threads or the
//! clock from std either. This test fails the day either happens.

use std::path::Path;

const FORBIDDEN: &[&str] = &[
    "tokio",
    "std::fs",
    "std::net",
    "std::thread",
    "std::time",
    "std::io",
    "std::process",
    "std::env",
    "File::",
    "Instant",
    "SystemTime",
];

#[test]
fn core_modules_name_no_io_no_runtime_and_no_clock() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/alfd-core/src");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).expect("crates/alfd-core/src exists") {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "rs") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        for (n, line) in text.lines().enumerate() {
            for word in FORBIDDEN {
                assert!(
                    !line.contains(word),
                    "{}:{}: the core must not name `{word}`: {line}",
                    path.display(),
                    n + 1
                );
            }
        }
        checked += 1;
    }
    assert!(
        checked >= 8,
        "expected the core's modules, found {checked} files"
    );
}

/// The crate's dependencies, as its manifest lists them: glam and thiserror, nothing else
/// (dev-dependencies are the tests' own).
#[test]
fn the_core_crate_depends_on_glam_and_thiserror_only() {
    let manifest = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/alfd-core/Cargo.toml"),
    )
    .expect("the core's manifest");
    let mut section = String::new();
    let mut deps = Vec::new();
    for line in manifest.lines().map(str::trim) {
        if line.starts_with('[') {
            section = line.to_string();
        } else if section == "[dependencies]" && !line.is_empty() && !line.starts_with('#') {
            let name = line.split(['=', '.']).next().unwrap_or("").trim();
            deps.push(name.to_string());
        } else if section.starts_with("[dependencies.") || section.starts_with("[target.") {
            panic!("the core's manifest has {section}: dependencies belong in [dependencies]");
        }
    }
    deps.sort();
    assert_eq!(deps, ["glam", "thiserror"], "the core's dependencies");
    // The main crate names the core through its manifest, not its source tree.
    let lib = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs"))
        .expect("src/lib.rs");
    assert!(
        lib.contains("pub use alfd_core as core;"),
        "alfd::core is the core crate"
    );
    assert!(
        !Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("src/core")
            .exists(),
        "src/core/ is gone: the core lives in crates/alfd-core"
    );
}
