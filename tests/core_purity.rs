//! The core stays pure (STYLE.md practice 2): no module under `src/core/` may
//! name tokio, files, sockets, threads or the clock. This test fails the day one does.

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
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/core");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).expect("src/core exists") {
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
