//! `alfd export`: a flight directory's exports (`geo.txt`, `transforms.json`) written
//! again from its manifest. The daemon writes them when it stops; a flight cut short
//! (the battery, a SIGKILL, the board's power) has its images and manifest but none.

use super::{bad, emit};
use alfd::capture::export::{Skip, GEO_TXT, TRANSFORMS_JSON};
use alfd::capture::store::MANIFEST;
use alfd::capture::{parse_manifest, write_exports, CaptureStore, DirStore, StoreError};
use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The flight directory (`capture.dir`'s `flight-NNN`), holding `manifest.jsonl`.
    flight_dir: PathBuf,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let dir = a.flight_dir;
    // Opening the store creates a directory: a mistyped path must not become one.
    if !dir.join(MANIFEST).is_file() {
        return Err(bad(format!(
            "{}: no {MANIFEST} here: name a flight directory (flight-NNN)",
            dir.display()
        )));
    }
    // Opening cuts a torn last line and removes temporaries, as a restarted daemon
    // does; the lock refuses a directory a daemon is still writing.
    let mut store = DirStore::open(&dir).map_err(|e| match e {
        StoreError::InUse { .. } => bad(e.to_string()),
        e => anyhow::Error::new(e),
    })?;
    let bytes = store
        .manifest_bytes()
        .with_context(|| format!("{}: reading {MANIFEST}", dir.display()))?;
    let m = parse_manifest(&bytes);
    let summary = write_exports(&mut store, &m.records)
        .with_context(|| format!("{}: writing the exports", dir.display()))?;

    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: {} captures in {MANIFEST}",
        dir.display(),
        m.records.len()
    );
    if store.recovered_bytes() > 0 {
        let _ = writeln!(
            s,
            "recovered        {} bytes of a torn last line or telemetry entry cut (a stop mid-write)",
            store.recovered_bytes()
        );
    }
    for (line, why) in &m.bad_lines {
        let _ = writeln!(s, "bad line         {MANIFEST}:{line}: {why}");
    }
    let _ = writeln!(
        s,
        "{GEO_TXT:<16} {} images{}",
        summary.geo_lines,
        skipped(&summary.geo_skipped)
    );
    match summary.transform_frames {
        Some(n) => {
            let _ = writeln!(
                s,
                "{TRANSFORMS_JSON:<16} {n} frames{}",
                skipped(&summary.transforms_skipped)
            );
        }
        None => {
            let _ = writeln!(
                s,
                "{TRANSFORMS_JSON:<16} not written: no capture has an image, a pose and intrinsics{}",
                skipped(&summary.transforms_skipped)
            );
        }
    }
    // The manifest lists an image only once it is in place; one missing since is
    // worth knowing before a reconstruction fails on it.
    let missing: Vec<&str> = m
        .records
        .iter()
        .filter_map(|r| r.image.as_deref())
        .filter(|name| !dir.join(name).is_file())
        .collect();
    if !missing.is_empty() {
        let _ = writeln!(
            s,
            "missing images   {} listed but not in the directory: {}",
            missing.len(),
            missing.join(", ")
        );
    }
    emit(&s)?;
    Ok(ExitCode::SUCCESS)
}

/// `" (3 skipped: no_position 2, no_image 1)"`, or nothing.
fn skipped(list: &[(u64, Skip)]) -> String {
    if list.is_empty() {
        return String::new();
    }
    let mut by: BTreeMap<String, usize> = BTreeMap::new();
    for (_, why) in list {
        let name = serde_json::to_value(why)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_else(|| format!("{why:?}"));
        *by.entry(name).or_default() += 1;
    }
    let parts: Vec<String> = by.iter().map(|(k, n)| format!("{k} {n}")).collect();
    format!(" ({} skipped: {})", list.len(), parts.join(", "))
}
