//! `alfd export`: a flight directory's exports (`geo.txt`, `transforms.json`) written
//! again from its manifest. The daemon writes them when it stops; a flight cut short
//! (the battery, a SIGKILL, the board's power) has its images and manifest but none.

use super::{bad, emit};
use alfd::capture::export::{Skip, GEO_TXT, TRANSFORMS_JSON};
use alfd::capture::store::MANIFEST;
use alfd::capture::{export_flight, FlightExport, StoreError};
use anyhow::Result;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The flight directory (`capture.dir`'s `flight-NNN`), holding `manifest.jsonl`.
    flight_dir: PathBuf,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let dir = a.flight_dir;
    if !dir.join(MANIFEST).is_file() {
        return Err(bad(format!(
            "{}: no {MANIFEST} here: name a flight directory (flight-NNN)",
            dir.display()
        )));
    }
    let done = export_flight(&dir).map_err(|e| match e {
        StoreError::InUse { .. } => bad(e.to_string()),
        e => anyhow::Error::new(e),
    })?;
    emit(&report(&dir, &done))?;
    Ok(ExitCode::SUCCESS)
}

/// What was found and written, a line each.
pub fn report(dir: &Path, done: &FlightExport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}: {} captures in {MANIFEST}",
        dir.display(),
        done.records
    );
    if done.recovered_bytes > 0 {
        let _ = writeln!(
            s,
            "recovered        {} bytes of a torn last line or telemetry entry cut (a stop mid-write)",
            done.recovered_bytes
        );
    }
    for (line, why) in &done.bad_lines {
        let _ = writeln!(s, "bad line         {MANIFEST}:{line}: {why}");
    }
    let e = &done.exports;
    let _ = writeln!(
        s,
        "{GEO_TXT:<16} {} images{}",
        e.geo_lines,
        skipped(&e.geo_skipped)
    );
    let _ = match e.transform_frames {
        Some(n) => writeln!(
            s,
            "{TRANSFORMS_JSON:<16} {n} frames{}",
            skipped(&e.transforms_skipped)
        ),
        None => writeln!(
            s,
            "{TRANSFORMS_JSON:<16} not written: no capture has an image, a pose and intrinsics{}",
            skipped(&e.transforms_skipped)
        ),
    };
    if !done.missing_images.is_empty() {
        let _ = writeln!(
            s,
            "missing images   {} listed but not in the directory: {}",
            done.missing_images.len(),
            done.missing_images.join(", ")
        );
    }
    s
}

/// `" (3 skipped: no_image 1, no_position 2)"`, or nothing.
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
