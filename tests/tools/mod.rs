//! External programs some tests talk to (Python with pymavlink or pycolmap, exiftool): present,
//! or the test is skipped with a message saying what to install; in CI (`CI` set) a missing one
//! fails the test instead, so CI never passes by skipping.
#![allow(dead_code)]

use std::process::{Command, Stdio};

fn required(present: bool, test: &str, what: &str, install: &str) -> bool {
    if !present {
        if std::env::var_os("CI").is_some() {
            panic!("{test}: CI is set but {what} is missing: {install}");
        }
        eprintln!("SKIPPED {test}: {what} is missing ({install})");
    }
    present
}

/// Whether `python3` can import pymavlink (see the module doc for what happens if not).
pub fn pymavlink(test: &str) -> bool {
    let present = Command::new("python3")
        .args(["-c", "import pymavlink"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    required(
        present,
        test,
        "python3 with pymavlink",
        "pip install pymavlink, or run scripts/setup.sh",
    )
}

/// Whether `python3` can import pycolmap (see the module doc for what happens if not).
pub fn pycolmap(test: &str) -> bool {
    let present = Command::new("python3")
        .args(["-c", "import pycolmap"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    required(
        present,
        test,
        "python3 with pycolmap",
        "pip install pycolmap, or run scripts/setup.sh",
    )
}

/// Whether `exiftool` runs (see the module doc for what happens if not).
pub fn exiftool(test: &str) -> bool {
    let present = Command::new("exiftool")
        .arg("-ver")
        .output()
        .is_ok_and(|o| o.status.success());
    required(
        present,
        test,
        "exiftool",
        "apt-get install libimage-exiftool-perl, or run scripts/setup.sh",
    )
}
