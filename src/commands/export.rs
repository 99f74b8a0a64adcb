//! `alfd export`: a flight directory's exports (`geo.txt`, `transforms.json`) written
//! again from its manifest. The daemon writes them when it stops; a flight cut short
//! (the battery, a SIGKILL, the board's power) has its images and manifest but none.
//! With `--images`, an external camera's pictures (its card) are paired with the
//! captures it took and named in `geo.txt`.

use super::{bad, emit};
use alfd::capture::export::{
    Skip, COLMAP_CAMERAS, COLMAP_IMAGES, COLMAP_POINTS, GEO_TXT, TRANSFORMS_JSON,
};
use alfd::capture::external::{
    read_camera_dirs, CameraDir, Moved, PairedBy, Pairing, DELAY_GAP_MAX_S,
};
use alfd::capture::store::MANIFEST;
use alfd::capture::{
    export_flight, export_flight_with_camera, ExportError, FlightExport, StoreError,
};
use anyhow::Result;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The flight directory (`capture.dir`'s `flight-NNN`), holding `manifest.jsonl`.
    flight_dir: PathBuf,
    /// An external camera's pictures (its card's folder of JPEGs): each is paired
    /// with the capture that triggered it (`camera_command`, `autopilot_distance`)
    /// and named on that capture's `geo.txt` line. Given again for a flight the
    /// camera spread over several folders; a card's DCIM (or the card's mount point
    /// holding it) reads every folder in it that holds pictures. The folders are
    /// only read.
    #[arg(long, value_name = "DIR")]
    images: Vec<PathBuf>,
    /// The external camera's delay from trigger to exposure, seconds (its shutter
    /// lag; 0 to 2): each paired picture's geo.txt line is placed where the vehicle
    /// was then, along the way to the next capture, instead of at the trigger.
    /// Without it, at the trigger: the pictures' times cannot tell the delay from
    /// the camera clock's error.
    #[arg(
        long,
        value_name = "SECONDS",
        requires = "images",
        allow_negative_numbers = true
    )]
    camera_delay_s: Option<f64>,
}

pub fn run(a: Args) -> Result<ExitCode> {
    let dir = a.flight_dir;
    if !dir.join(MANIFEST).is_file() {
        return Err(bad(format!(
            "{}: no {MANIFEST} here: name a flight directory (flight-NNN)",
            dir.display()
        )));
    }
    let in_use = |e: StoreError| match e {
        StoreError::InUse { .. } => bad(e.to_string()),
        e => anyhow::Error::new(e),
    };
    if let Some(d) = a.camera_delay_s {
        if !(d.is_finite() && (0.0..=2.0).contains(&d)) {
            return Err(bad(format!(
                "--camera-delay-s {d}: a camera's delay from trigger to exposure is 0 to 2 s"
            )));
        }
    }
    if a.images.is_empty() {
        let done = export_flight(&dir).map_err(in_use)?;
        emit(&report(&dir, &done, true))?;
        return Ok(ExitCode::SUCCESS);
    }
    let mut seen = std::collections::HashSet::new();
    for images in &a.images {
        if !images.is_dir() {
            return Err(bad(format!(
                "--images {}: not a directory: name the folder of the camera's pictures",
                images.display()
            )));
        }
        let real = images
            .canonicalize()
            .map_err(|e| bad(format!("--images {}: {e}", images.display())))?;
        if !seen.insert(real) {
            return Err(bad(format!(
                "--images {}: given twice (each folder of the camera's pictures once)",
                images.display()
            )));
        }
    }
    let mut folders = a.images.clone();
    let mut root = None;
    if let [one] = folders.as_slice() {
        // A card's root (DCIM) holds folders of pictures, not pictures: all of them,
        // in the order of their names (100MSDCF, 101MSDCF: the camera's own order).
        // A card's mount point holds DCIM (beside MISC, PRIVATE): its folders, when none
        // of the mount point's own holds pictures.
        if !has_jpeg(one) {
            let with_pictures = |dir: &Path| {
                let mut inside: Vec<PathBuf> = std::fs::read_dir(dir)
                    .into_iter()
                    .flatten()
                    .flatten()
                    .map(|e| e.path())
                    .filter(|p| p.is_dir() && has_jpeg(p))
                    .collect();
                inside.sort();
                inside
            };
            let mut inside = with_pictures(one);
            if inside.is_empty() {
                if let Some(dcim) = dcim_in(one) {
                    inside = with_pictures(&dcim);
                }
            }
            if !inside.is_empty() {
                root = Some(one.clone());
                folders = inside;
            }
        }
    }
    let mut camera = read_camera_dirs(&folders)?;
    // A refusal names the folder the operator named.
    if let Some(root) = root {
        camera.dir = root;
    }
    if camera.images.is_empty() {
        let named: Vec<String> = a.images.iter().map(|p| p.display().to_string()).collect();
        let mut msg = format!("--images {}: no JPEG picture there", named.join(", "));
        if !camera.bad_names.is_empty() {
            let _ = write!(
                msg,
                " whose name geo.txt can carry: rename the {} with a space or a control character",
                camera.bad_names.len()
            );
        }
        return Err(bad(msg));
    }
    let (done, pairing, moved) = export_flight_with_camera(&dir, &camera, a.camera_delay_s)
        .map_err(|e| match e {
            ExportError::Store(e) => in_use(e),
            e @ ExportError::Pair { .. } => bad(format!("--images {e}")),
        })?;
    let mut s = report(&dir, &done, false);
    s += &camera_report(&camera, &pairing);
    if done.commanded > 0 {
        let when = done.picture_after_median_ms.map_or(String::new(), |ms| {
            format!(" ({ms:.0} ms after alfd decided them, median)")
        });
        s += &format!(
            "placed           {} of {} commanded captures where the autopilot reported their picture{when}, the rest where alfd decided them; --camera-delay-s is the camera's lag after that\n",
            done.commanded_reported, done.commanded
        );
    }
    if let (Some(d), Some(m)) = (a.camera_delay_s, moved) {
        s += &delay_report(d, &m);
    }
    emit(&s)?;
    Ok(ExitCode::SUCCESS)
}

/// The card's `DCIM` folder (any case, as DCF names it) when `dir` is a card's
/// mount point holding it.
fn dcim_in(dir: &Path) -> Option<PathBuf> {
    std::fs::read_dir(dir)
        .ok()?
        .flatten()
        .map(|e| e.path())
        .find(|p| {
            p.file_name()
                .is_some_and(|n| n.eq_ignore_ascii_case("DCIM"))
                && p.is_dir()
        })
}

/// Whether a folder holds a file named as a JPEG (its listing only: a card's
/// folders hold thousands).
fn has_jpeg(dir: &Path) -> bool {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .any(|e| {
            let name = e.file_name().to_string_lossy().to_ascii_lowercase();
            name.ends_with(".jpg") || name.ends_with(".jpeg")
        })
}

/// `1 picture`, `2 pictures`.
fn count(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// Up to ten names, then how many more.
fn some(names: &[&str]) -> String {
    let mut s = names
        .iter()
        .take(10)
        .copied()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > 10 {
        let _ = write!(s, " and {} more", names.len() - 10);
    }
    s
}

/// What was found on the camera's card and how it was paired, a line each.
pub fn camera_report(camera: &CameraDir, p: &Pairing) -> String {
    let mut s = String::new();
    let order = if camera.by_time {
        "in the order of their EXIF capture times"
    } else {
        "in the order of their names (not every picture has an EXIF capture time)"
    };
    let place = match camera.folders.as_slice() {
        [one] => one.display().to_string(),
        several => format!(
            "{} folders ({})",
            several.len(),
            several
                .iter()
                .map(|f| f.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let _ = writeln!(
        s,
        "camera           {} JPEG pictures in {place}, {order}",
        camera.images.len(),
    );
    if let Some(shared) = &camera.qualified {
        let _ = writeln!(
            s,
            "names            with their folder ({shared} is in two of them): give the reconstruction the folders' parent as its image folder"
        );
    }
    if camera.other_files > 0 {
        let _ = writeln!(
            s,
            "left alone       {} (raw, video, sidecars: not JPEG)",
            count(camera.other_files, "other file")
        );
    }
    if !camera.bad_names.is_empty() {
        let names: Vec<&str> = camera.bad_names.iter().map(String::as_str).collect();
        let _ = writeln!(
            s,
            "left out         {} whose names geo.txt cannot carry (a space or a control character): {}",
            count(names.len(), "picture"),
            some(&names)
        );
    }
    let how = match p.by {
        PairedBy::Order { checked: true } => "in order, and their times agree".to_owned(),
        PairedBy::Order { checked: false } => {
            "in order, unchecked: the pictures have no capture time".to_owned()
        }
        PairedBy::Time => match p.order_residual_s {
            Some(worst) => format!(
                "by time: in order, a picture would be {worst:.1} s from its capture's time"
            ),
            None => "by time: the counts differ".to_owned(),
        },
    };
    let _ = writeln!(
        s,
        "paired           {} of {} captures {how}",
        p.pairs.len(),
        p.pairs.len() + p.unpaired_captures.len()
    );
    if let Some((median, worst)) = p.residual_s {
        let _ = writeln!(
            s,
            "time residual    median {median:.3} s, worst {worst:.3} s (at most {:.2} s: the time stamps' step and the camera's delay)",
            p.tolerance_s
        );
    }
    if let Some(ahead) = p.camera_ahead_of_utc_s {
        let _ = writeln!(s, "camera clock     {}", clock(ahead));
    }
    if !p.unpaired_images.is_empty() {
        let names: Vec<&str> = p
            .unpaired_images
            .iter()
            .map(|&i| camera.images[i].name.as_str())
            .collect();
        let _ = writeln!(
            s,
            "not paired       {} no capture triggered (left out): {}",
            count(names.len(), "picture"),
            some(&names)
        );
    }
    if !p.unpaired_captures.is_empty() {
        let seqs: Vec<String> = p.unpaired_captures.iter().map(u64::to_string).collect();
        let seqs: Vec<&str> = seqs.iter().map(String::as_str).collect();
        let _ = writeln!(
            s,
            "no picture       {} the camera has no picture for: seq {}",
            count(seqs.len(), "capture"),
            some(&seqs)
        );
    }
    let _ = writeln!(
        s,
        "note             the camera's pictures keep their names and stay where they are; their geo.txt lines give positions and no angles (alfd does not know how the camera is mounted), and transforms.json has none of them (nor its lens)"
    );
    s
}

/// Where the camera's delay moved its pictures, a line (two with captures left).
fn delay_report(delay_s: f64, m: &Moved) -> String {
    let mut s = String::new();
    let mut d = m.moved_m.clone();
    d.sort_by(f64::total_cmp);
    let moved = match d.as_slice() {
        [] => "none moved".to_owned(),
        d => format!(
            "{} moved to the exposure along the way flown (median {:.2} m, worst {:.2} m)",
            count(d.len(), "picture"),
            d[d.len() / 2],
            d[d.len() - 1]
        ),
    };
    let _ = writeln!(s, "camera delay     {delay_s:.3} s: {moved}");
    if !m.left.is_empty() {
        let seqs: Vec<String> = m.left.iter().map(u64::to_string).collect();
        let seqs: Vec<&str> = seqs.iter().map(String::as_str).collect();
        let _ = writeln!(
            s,
            "left at trigger  {} with no capture within {DELAY_GAP_MAX_S} s before or after to tell the way: seq {}",
            count(seqs.len(), "picture"),
            some(&seqs)
        );
    }
    s
}

/// The camera's clock against UTC, in words.
fn clock(ahead_s: f64) -> String {
    if ahead_s.abs() < 1.0 {
        return format!("within a second of UTC ({ahead_s:+.2} s)");
    }
    let word = if ahead_s > 0.0 { "ahead of" } else { "behind" };
    let a = ahead_s.abs();
    let (h, rest) = ((a / 3600.0).floor(), a % 3600.0);
    let (m, sec) = ((rest / 60.0).floor(), rest % 60.0);
    let text = if h > 0.0 {
        format!("{h} h {m} min {sec:.1} s")
    } else if m > 0.0 {
        format!("{m} min {sec:.1} s")
    } else {
        format!("{sec:.2} s")
    };
    format!("{text} {word} UTC (its setting, or its time zone)")
}

/// What was found and written, a line each; `hint_images` says how to pair an
/// external camera's pictures when the flight has some.
pub fn report(dir: &Path, done: &FlightExport, hint_images: bool) -> String {
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
            "{TRANSFORMS_JSON:<16} {n} frames{}\nCOLMAP model     {COLMAP_CAMERAS}, {COLMAP_IMAGES}, {COLMAP_POINTS}: the same {n} images and poses (colmap point_triangulator --input_path {})",
            skipped(&e.transforms_skipped),
            dir.display()
        ),
        None => writeln!(
            s,
            "{TRANSFORMS_JSON:<16} not written: no capture has an image, a pose and intrinsics{}",
            skipped(&e.transforms_skipped)
        ),
    };
    if hint_images
        && done.external_captures > 0
        && e.geo_skipped.iter().any(|(_, w)| *w == Skip::NoImage)
    {
        let _ = writeln!(
            s,
            "external camera  {} captures were taken by an external camera: pair its pictures with `alfd export {} --images DIR`",
            done.external_captures,
            dir.display()
        );
    }
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
