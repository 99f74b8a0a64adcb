//! An external camera's pictures paired with the captures alfd logged for them.
//!
//! In `camera_command` and `autopilot_distance` flights (and a ground station's
//! `command` captures in them) the camera keeps its pictures on its own card; the
//! manifest has a line per trigger and no image. [`pair`] matches the pictures to
//! those lines (pure): by order when the counts agree and the pictures' times do
//! not contradict it, else by time, with the camera clock's offset found from the
//! data. [`read_camera_dir`] reads the camera's directory and changes nothing in it.

use super::exif::{find_exif_app1, parse_exif_taken, TakenAt};
use super::record::{CaptureMode, CaptureRecord};
use super::store::{io_error, StoreError};
use std::io::Read;
use std::path::{Path, PathBuf};

/// How far a picture's time may sit from its trigger's beyond the time stamp's own
/// step: a camera commanded over MAVLink or by the autopilot's pin exposes tens to
/// a couple of hundred milliseconds after the trigger is logged.
pub const LATENCY_S: f64 = 0.25;

/// Up to this many picture–capture pairs are tried as clock offsets; past it only
/// pairs within [`BAND`] (plus the count difference) of each other in order are.
const ALL_PAIRS_MAX: usize = 4_000_000;
const BAND: usize = 256;

/// How much of a picture file is read for its EXIF: the APP1 segment is at most
/// 64 KiB and comes before the image data.
const HEAD_BYTES: u64 = 256 * 1024;

/// One of the camera's pictures.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraImage {
    pub name: String,
    pub taken: Option<TakenAt>,
}

/// A camera's JPEG pictures, from one folder or several, in the order the camera took
/// them.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraDir {
    /// The folder named (with several, the first).
    pub dir: PathBuf,
    /// Every folder read, in order (one, or a card's several: a camera starts a new
    /// folder every 999 or 9999 pictures).
    pub folders: Vec<PathBuf>,
    /// Names carry their folder (`101MSDCF/DSC00001.JPG`): two folders hold a picture of
    /// the same name. Else each name is the file's own.
    pub qualified: Option<String>,
    pub images: Vec<CameraImage>,
    /// Files that are not JPEG pictures (raw files, videos, sidecars), left alone.
    pub other_files: usize,
    /// JPEGs whose names `geo.txt` cannot carry (a space, a control character).
    pub bad_names: Vec<String>,
    /// Ordered by capture time (every picture has one), else by name.
    pub by_time: bool,
}

/// Whether a line of the manifest is a picture alfd did not take itself: an
/// external camera's, commanded or triggered by the autopilot. A frame alfd meant
/// to save and lost (`image_missing`) is not one.
pub fn is_external(r: &CaptureRecord) -> bool {
    r.image.is_none() && r.image_missing.is_none() && r.capture_mode != CaptureMode::Frame
}

/// A name `geo.txt` (space-separated) can carry.
fn geo_name_ok(name: &str) -> bool {
    !name.is_empty() && !name.chars().any(|c| c.is_whitespace() || c.is_control())
}

/// The JPEG files of `dir` (not its subdirectories), each with the capture time its
/// EXIF holds. Reads the first 256 KiB of each; writes nothing.
pub fn read_camera_dir(dir: &Path) -> Result<CameraDir, StoreError> {
    read_camera_dirs(&[dir.to_owned()])
}

/// The JPEG files of each of `dirs` (not their subdirectories), as one camera's
/// pictures. Each is named by its file name, unless two folders hold the same name:
/// then every name carries its folder's (`101MSDCF/DSC00001.JPG`), and
/// [`CameraDir::qualified`] says which name was shared. Ordered by capture time when
/// every picture has one, else by folder (in the order given), then name.
pub fn read_camera_dirs(dirs: &[PathBuf]) -> Result<CameraDir, StoreError> {
    let mut other_files = 0;
    let mut bad_names = Vec::new();
    // Each picture with the index of its folder in `dirs`.
    let mut keyed: Vec<(usize, CameraImage)> = Vec::new();
    for (k, dir) in dirs.iter().enumerate() {
        let images = read_one_dir(dir, &mut other_files, &mut bad_names)?;
        keyed.extend(images.into_iter().map(|i| (k, i)));
    }
    // Names are unique within a folder: a name found twice is in two folders.
    let qualified = {
        let mut names: Vec<&str> = keyed.iter().map(|(_, i)| i.name.as_str()).collect();
        names.sort_unstable();
        names
            .windows(2)
            .find(|w| w[0] == w[1])
            .map(|w| w[0].to_owned())
    };
    if qualified.is_some() {
        for (k, i) in &mut keyed {
            let folder = dirs[*k]
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default();
            i.name = format!("{folder}/{}", i.name);
        }
        // A folder's name geo.txt cannot carry (a space) leaves its pictures out.
        keyed.retain(|(_, i)| {
            let ok = geo_name_ok(&i.name);
            if !ok {
                bad_names.push(i.name.clone());
            }
            ok
        });
    }
    let by_time = !keyed.is_empty() && keyed.iter().all(|(_, i)| i.taken.is_some());
    if by_time {
        keyed.sort_by(|(ka, a), (kb, b)| {
            let t = |i: &CameraImage| i.taken.map_or(0.0, |t| t.clock_s);
            t(a).total_cmp(&t(b))
                .then_with(|| ka.cmp(kb))
                .then_with(|| a.name.cmp(&b.name))
        });
    } else {
        // Folder by folder, as given, when names decide the order.
        keyed.sort_by(|(ka, a), (kb, b)| ka.cmp(kb).then_with(|| a.name.cmp(&b.name)));
    }
    let images = keyed.into_iter().map(|(_, i)| i).collect();
    bad_names.sort();
    Ok(CameraDir {
        dir: dirs.first().cloned().unwrap_or_default(),
        folders: dirs.to_vec(),
        qualified,
        images,
        other_files,
        bad_names,
        by_time,
    })
}

/// The JPEG pictures of one folder, counting the other files and the names geo.txt
/// cannot carry.
fn read_one_dir(
    dir: &Path,
    other_files: &mut usize,
    bad_names: &mut Vec<String>,
) -> Result<Vec<CameraImage>, StoreError> {
    let mut images = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| io_error(dir, e))? {
        let entry = entry.map_err(|e| io_error(dir, e))?;
        let path = entry.path();
        // A link to a picture counts as the picture; a directory is not looked into.
        if !path.is_file() {
            continue;
        }
        let name = entry.file_name().to_string_lossy().into_owned();
        let ext = Path::new(&name)
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        if name.starts_with('.') || !matches!(ext.as_deref(), Some("jpg" | "jpeg")) {
            *other_files += 1;
            continue;
        }
        if entry.file_name().to_str().is_none() || !geo_name_ok(&name) {
            bad_names.push(name);
            continue;
        }
        let mut head = Vec::new();
        std::fs::File::open(&path)
            .and_then(|f| f.take(HEAD_BYTES).read_to_end(&mut head))
            .map_err(|e| io_error(&path, e))?;
        let taken = find_exif_app1(&head).and_then(parse_exif_taken);
        images.push(CameraImage { name, taken });
    }
    Ok(images)
}

/// A capture the camera was to take a picture for, as [`pair`] needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trigger {
    pub seq: u64,
    /// The autopilot's boot clock, s: always there, steady within one boot.
    pub boot_s: f64,
    /// UTC, s, when the flight knew it.
    pub unix_s: Option<f64>,
}

impl Trigger {
    pub fn of(r: &CaptureRecord) -> Trigger {
        Trigger {
            seq: r.seq,
            boot_s: r.time_boot_us as f64 / 1e6,
            unix_s: r.time_unix_us.map(|us| us as f64 / 1e6),
        }
    }
}

/// The longest way between two captures a camera's delay is interpolated over: past it
/// (a pause, a hover, a gap in the log) the vehicle's path is not known to be straight.
pub const DELAY_GAP_MAX_S: f64 = 10.0;

/// What [`move_to_exposure`] did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Moved {
    /// How far each moved capture went (metres), in capture order.
    pub moved_m: Vec<f64>,
    /// Captures left at their trigger's place: no neighbouring capture within
    /// [`DELAY_GAP_MAX_S`] on one clock to tell the way the vehicle went.
    pub left: Vec<u64>,
}

/// Moves the captures `seqs` of `records` (capture order) to where the vehicle was
/// `delay_s` after their trigger, when the camera exposes: along the way to the next
/// capture, in proportion to the time (the last one along the way from the one before).
/// Both of a pair's times are read on one clock, UTC when both have it, else the boot
/// clock (the next must be later: an autopilot that rebooted restarts it). Geodetic and
/// local coordinates move alike; attitude is not touched. Pure.
pub fn move_to_exposure(records: &mut [CaptureRecord], seqs: &[u64], delay_s: f64) -> Moved {
    let mut moved = Moved::default();
    let time_between = |a: &CaptureRecord, b: &CaptureRecord| -> Option<f64> {
        let dt = match (a.time_unix_us, b.time_unix_us) {
            (Some(x), Some(y)) => (y as f64 - x as f64) * 1e-6,
            _ => (b.time_boot_us as f64 - a.time_boot_us as f64) * 1e-6,
        };
        (dt > 0.0 && dt <= DELAY_GAP_MAX_S).then_some(dt)
    };
    // A position's seven coordinates, all moved alike.
    let coords = |r: &CaptureRecord| {
        let p = &r.position;
        [
            p.lat_deg,
            p.lon_deg,
            p.alt_m,
            p.rel_alt_m,
            p.east_m,
            p.north_m,
            p.up_m,
        ]
    };
    let finite = |r: &CaptureRecord| coords(r).iter().all(|v| v.is_finite());
    let wanted: std::collections::BTreeSet<u64> = seqs.iter().copied().collect();
    // Every move is read from the places as logged, then made.
    let mut moves = Vec::new();
    for (k, r) in records.iter().enumerate() {
        if !wanted.contains(&r.seq) {
            continue;
        }
        // The segment the exposure lies on: to the next capture, or from the one before.
        let segment = records
            .get(k + 1)
            .filter(|n| finite(n))
            .and_then(|n| Some((r, n, time_between(r, n)?)))
            .or_else(|| {
                let b = records.get(k.checked_sub(1)?).filter(|b| finite(b))?;
                Some((b, r, time_between(b, r)?))
            });
        let Some((a, b, dt)) = segment.filter(|_| finite(r)) else {
            moved.left.push(r.seq);
            continue;
        };
        let (ca, cb) = (coords(a), coords(b));
        let d: [f64; 7] = std::array::from_fn(|i| (cb[i] - ca[i]) * (delay_s / dt));
        moved
            .moved_m
            .push((d[4] * d[4] + d[5] * d[5] + d[6] * d[6]).sqrt());
        moves.push((k, d));
    }
    for (k, d) in moves {
        let p = &mut records[k].position;
        let coords = [
            &mut p.lat_deg,
            &mut p.lon_deg,
            &mut p.alt_m,
            &mut p.rel_alt_m,
            &mut p.east_m,
            &mut p.north_m,
            &mut p.up_m,
        ];
        for (c, d) in coords.into_iter().zip(d) {
            *c += d;
        }
    }
    moved
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairedBy {
    /// The n-th picture with the n-th capture; `checked` when the pictures' times
    /// agreed with the captures' to within the tolerance.
    Order { checked: bool },
    /// Each picture with the capture nearest its time, at the clock offset that
    /// pairs the most.
    Time,
}

/// Which picture goes with which capture.
#[derive(Debug, Clone, PartialEq)]
pub struct Pairing {
    pub by: PairedBy,
    /// (capture sequence number, index into the pictures), in capture order.
    pub pairs: Vec<(u64, usize)>,
    /// The camera's clock minus the captures' (UTC when every capture knew it
    /// and it advances, else the autopilot's boot clock), s, median over the
    /// pairs; `None` when the pictures have no time.
    pub offset_s: Option<f64>,
    /// The camera's clock minus UTC, s (median over the pairs whose capture knew
    /// UTC): its setting's error or its time zone.
    pub camera_ahead_of_utc_s: Option<f64>,
    /// |picture time − offset − capture time| over the pairs: median and worst, s.
    pub residual_s: Option<(f64, f64)>,
    /// The most a pair's residual may be: the time stamp's step plus [`LATENCY_S`].
    pub tolerance_s: f64,
    /// When the pairing is by time and the counts agree: the worst gap between a
    /// picture's time and its capture's had they been paired in order, s.
    pub order_residual_s: Option<f64>,
    /// Pictures paired with no capture (indices), and captures with no picture.
    pub unpaired_images: Vec<usize>,
    pub unpaired_captures: Vec<u64>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PairError {
    #[error(
        "the manifest has no capture by an external camera (every line is a frame alfd saved, or says why its image is missing)"
    )]
    NoCaptures,
    #[error("no JPEG picture there")]
    NoImages,
    #[error(
        "{images} pictures for {captures} captures, and {why}: leave out the pictures this flight's triggers did not take, so that the counts match, and run again"
    )]
    Unpairable {
        images: usize,
        captures: usize,
        why: String,
    },
}

/// Pairs `images` (in the order taken) with `triggers` (in capture order).
pub fn pair(triggers: &[Trigger], images: &[CameraImage]) -> Result<Pairing, PairError> {
    let (n, m) = (images.len(), triggers.len());
    if m == 0 {
        return Err(PairError::NoCaptures);
    }
    if n == 0 {
        return Err(PairError::NoImages);
    }
    let times: Option<Vec<f64>> = images.iter().map(|i| i.taken.map(|t| t.clock_s)).collect();
    let step_s = images
        .iter()
        .filter_map(|i| i.taken.map(|t| t.resolution_s))
        .fold(0.0, f64::max);
    let tolerance_s = step_s + LATENCY_S;
    let unpairable = |why: String| PairError::Unpairable {
        images: n,
        captures: m,
        why,
    };

    // The captures' times on UTC when every one has it and it advances: an
    // autopilot rebooted in flight starts its boot clock again, UTC goes on.
    // Else on the boot clock.
    let utc: Option<Vec<f64>> = triggers.iter().map(|c| c.unix_s).collect();
    let clock: Vec<f64> = match utc.filter(|u| u.windows(2).all(|w| w[1] > w[0])) {
        Some(u) => u,
        None => triggers.iter().map(|c| c.boot_s).collect(),
    };

    let mut order_disagrees = None;
    if n == m {
        let pairs: Vec<(usize, usize)> = (0..n).map(|k| (k, k)).collect();
        let Some(t) = &times else {
            return Ok(finish(
                PairedBy::Order { checked: false },
                triggers,
                &clock,
                None,
                &pairs,
                tolerance_s,
                n,
            ));
        };
        let p = finish(
            PairedBy::Order { checked: true },
            triggers,
            &clock,
            Some(t),
            &pairs,
            tolerance_s,
            n,
        );
        match p.residual_s {
            Some((_, worst)) if worst <= tolerance_s => return Ok(p),
            Some((_, worst)) => order_disagrees = Some(worst),
            None => {}
        }
    }

    let Some(t) = times else {
        return Err(unpairable(
            "the pictures carry no capture time (EXIF DateTimeOriginal) to pair them by".into(),
        ));
    };
    let boot = &clock;
    if let Some(w) = boot.windows(2).position(|w| w[1] <= w[0]) {
        return Err(unpairable(format!(
            "the autopilot's clock does not advance from capture {} to {} (a reboot in flight, before UTC was known?), so their times cannot be compared with the pictures'",
            triggers[w].seq,
            triggers[w + 1].seq
        )));
    }
    let closest_s = boot
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min);
    let by_order = match order_disagrees {
        Some(worst) => format!(
            "paired in order, a picture's time is {worst:.2} s from its capture's (more than {tolerance_s:.2} s); "
        ),
        None => String::new(),
    };
    if closest_s <= 2.0 * tolerance_s {
        return Err(unpairable(format!(
            "{by_order}the captures come {closest_s:.2} s apart at the closest, too close to tell apart by the pictures' times (stamped in steps of {step_s} s, {LATENCY_S} s allowed for the camera's delay)"
        )));
    }

    // Every picture–capture pair proposes an offset; the offsets of true pairs
    // agree, so the densest window of width 2·tolerance holds the camera's.
    let band = if n * m <= ALL_PAIRS_MAX {
        usize::MAX
    } else {
        n.abs_diff(m) + BAND
    };
    let mut offsets = Vec::new();
    for (i, ti) in t.iter().enumerate() {
        let lo = i.saturating_sub(band);
        let hi = i.saturating_add(band).saturating_add(1).min(m);
        offsets.extend(boot[lo.min(m)..hi].iter().map(|b| ti - b));
    }
    offsets.sort_by(f64::total_cmp);
    let width = 2.0 * tolerance_s;
    let mut windows: Vec<(usize, f64)> = Vec::with_capacity(offsets.len());
    let mut end = 0;
    for (a, &start) in offsets.iter().enumerate() {
        while end < offsets.len() && offsets[end] <= start + width {
            end += 1;
        }
        windows.push((end - a, offsets[(a + end - 1) / 2]));
    }
    windows.sort_by(|x, y| y.0.cmp(&x.0).then(x.1.total_cmp(&y.1)));
    // The densest few distinct offsets, each refined to its pairs' median and
    // paired one to one.
    let mut tried: Vec<Candidate> = Vec::new();
    for &(_, c) in &windows {
        if tried.len() == 6 {
            break;
        }
        if tried.iter().any(|x| (x.offset_s - c).abs() <= width) {
            continue;
        }
        let first = greedy(&t, boot, c, tolerance_s);
        let refined = c + median(first.iter().map(|&(i, j)| t[i] - c - boot[j]).collect());
        let pairs = greedy(&t, boot, refined, tolerance_s);
        let spread: f64 = pairs
            .iter()
            .map(|&(i, j)| (t[i] - refined - boot[j]).abs())
            .sum();
        if tried.iter().any(|x| (x.offset_s - refined).abs() <= width) {
            continue;
        }
        tried.push(Candidate {
            offset_s: refined,
            spread_s: spread,
            pairs,
        });
    }
    tried.sort_by(|x, y| {
        (y.pairs.len().cmp(&x.pairs.len())).then(x.spread_s.total_cmp(&y.spread_s))
    });
    let Some(best) = tried.first() else {
        return Err(unpairable("no clock offset pairs any of them".into()));
    };
    // A pairing by time is taken only when it stands out: most of the pictures
    // paired, and at least twice as many as at any other offset (chance pairs a
    // few at many offsets; evenly spaced captures pair almost as many one picture
    // along). A wrong pairing puts every picture in the wrong place, silently.
    let need = n.min(m).div_ceil(2).max(3);
    if best.pairs.len() < need {
        return Err(unpairable(format!(
            "{by_order}no one clock offset pairs more than {} of them by time (at {:.2} s): are these this flight's pictures?",
            best.pairs.len(),
            best.offset_s
        )));
    }
    if let Some(second) = tried
        .get(1)
        .filter(|s| 2 * s.pairs.len() > best.pairs.len())
    {
        return Err(unpairable(format!(
            "{by_order}clock offsets {:.2} s and {:.2} s pair {} and {} of them: too close a call to tell by time which picture is whose",
            best.offset_s,
            second.offset_s,
            best.pairs.len(),
            second.pairs.len()
        )));
    }
    let mut p = finish(
        PairedBy::Time,
        triggers,
        &clock,
        Some(&t),
        &best.pairs,
        tolerance_s,
        n,
    );
    p.order_residual_s = order_disagrees;
    Ok(p)
}

/// A clock offset tried, with the pairs it gives and their residuals' sum.
struct Candidate {
    offset_s: f64,
    spread_s: f64,
    pairs: Vec<(usize, usize)>,
}

/// Pictures at clock offset `offset` paired one to one, in order, each with the
/// capture within `tol` of it (the nearer picture when two are).
fn greedy(t: &[f64], boot: &[f64], offset: f64, tol: f64) -> Vec<(usize, usize)> {
    let (mut i, mut j) = (0, 0);
    let mut pairs = Vec::new();
    while i < t.len() && j < boot.len() {
        let r = t[i] - offset - boot[j];
        if r.abs() <= tol {
            let next_nearer = t
                .get(i + 1)
                .is_some_and(|tn| (tn - offset - boot[j]).abs() < r.abs());
            if next_nearer {
                i += 1;
                continue;
            }
            pairs.push((i, j));
            i += 1;
            j += 1;
        } else if r < 0.0 {
            i += 1;
        } else {
            j += 1;
        }
    }
    pairs
}

fn median(mut xs: Vec<f64>) -> f64 {
    if xs.is_empty() {
        return 0.0;
    }
    xs.sort_by(f64::total_cmp);
    let k = xs.len() / 2;
    if xs.len() % 2 == 1 {
        xs[k]
    } else {
        0.5 * (xs[k - 1] + xs[k])
    }
}

/// The pairing from (picture index, trigger index) pairs, with its figures.
fn finish(
    by: PairedBy,
    triggers: &[Trigger],
    clock: &[f64],
    times: Option<&Vec<f64>>,
    pairs: &[(usize, usize)],
    tolerance_s: f64,
    n_images: usize,
) -> Pairing {
    let (offset_s, camera_ahead_of_utc_s, residual_s) = match times {
        Some(t) if !pairs.is_empty() => {
            let offset = median(pairs.iter().map(|&(i, j)| t[i] - clock[j]).collect());
            let res: Vec<f64> = pairs
                .iter()
                .map(|&(i, j)| (t[i] - offset - clock[j]).abs())
                .collect();
            let worst = res.iter().copied().fold(0.0, f64::max);
            let utc: Vec<f64> = pairs
                .iter()
                .filter_map(|&(i, j)| triggers[j].unix_s.map(|u| t[i] - u))
                .collect();
            let utc = (!utc.is_empty()).then(|| median(utc));
            (Some(offset), utc, Some((median(res), worst)))
        }
        _ => (None, None, None),
    };
    let mut image_paired = vec![false; n_images];
    let mut trigger_paired = vec![false; triggers.len()];
    for &(i, j) in pairs {
        image_paired[i] = true;
        trigger_paired[j] = true;
    }
    Pairing {
        by,
        pairs: pairs.iter().map(|&(i, j)| (triggers[j].seq, i)).collect(),
        offset_s,
        camera_ahead_of_utc_s,
        residual_s,
        tolerance_s,
        order_residual_s: None,
        unpaired_images: (0..n_images).filter(|&i| !image_paired[i]).collect(),
        unpaired_captures: triggers
            .iter()
            .zip(&trigger_paired)
            .filter(|(_, &p)| !p)
            .map(|(c, _)| c.seq)
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn image(k: usize, clock_s: Option<f64>, resolution_s: f64) -> CameraImage {
        CameraImage {
            name: format!("DSC{k:05}.JPG"),
            taken: clock_s.map(|clock_s| TakenAt {
                clock_s,
                resolution_s,
            }),
        }
    }

    /// Several folders are one camera's: without times, folder by folder as given,
    /// then by name; a name two folders share makes every name carry its folder, and
    /// a folder's name geo.txt cannot carry then leaves its pictures out.
    #[test]
    fn folders_read_as_one_camera() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = |name: &str, files: &[&str]| {
            let d = tmp.path().join(name);
            std::fs::create_dir(&d).unwrap();
            for f in files {
                std::fs::write(d.join(f), b"not a real JPEG: no EXIF time").unwrap();
            }
            d
        };
        let names = |c: &CameraDir| c.images.iter().map(|i| i.name.clone()).collect::<Vec<_>>();
        let a = dir("100CANON", &["IMG_9998.JPG", "IMG_9999.JPG", "notes.txt"]);
        let b = dir("101CANON", &["IMG_0001.JPG", "IMG_0002.JPG"]);
        let c = read_camera_dirs(&[a.clone(), b.clone()]).unwrap();
        assert!(!c.by_time && c.qualified.is_none());
        assert_eq!(
            names(&c),
            [
                "IMG_9998.JPG",
                "IMG_9999.JPG",
                "IMG_0001.JPG",
                "IMG_0002.JPG"
            ]
        );
        assert_eq!((c.other_files, c.folders.len()), (1, 2));
        let d = dir("102 CANON", &["IMG_0001.JPG"]);
        let c = read_camera_dirs(&[a, b, d]).unwrap();
        assert_eq!(c.qualified.as_deref(), Some("IMG_0001.JPG"));
        assert_eq!(
            names(&c),
            [
                "100CANON/IMG_9998.JPG",
                "100CANON/IMG_9999.JPG",
                "101CANON/IMG_0001.JPG",
                "101CANON/IMG_0002.JPG"
            ]
        );
        assert_eq!(c.bad_names, ["102 CANON/IMG_0001.JPG"]);
    }

    /// A picture moves by the delay's share of the way to the next capture (the last:
    /// of the way from the one before), on UTC or, without it, the boot clock; one with
    /// no neighbour on one clock within 10 s stays at its trigger, as do the captures
    /// not asked for.
    #[test]
    fn a_camera_delay_moves_a_picture_along_the_way_flown() {
        use crate::capture::record::tests::sample;
        // 1.1 m north every 0.25 s: 4.4 m/s.
        let mut records: Vec<CaptureRecord> = (1..=6).map(sample).collect();
        // Capture 4 on the boot clock alone, 20 s later (a hover), and 5 after a reboot.
        records[3].time_unix_us = None;
        records[3].time_boot_us += 20_000_000;
        records[4].time_unix_us = None;
        records[4].time_boot_us = 1_000_000;
        let before = records.clone();
        let m = move_to_exposure(&mut records, &[1, 2, 4, 5, 6], 0.05);
        let north = |r: &CaptureRecord| r.position.north_m;
        // 0.05 s of 0.25 s: a fifth of 1.1 m.
        for k in [0, 1] {
            assert!((north(&records[k]) - north(&before[k]) - 0.22).abs() < 1e-12);
            let dlat = records[k].position.lat_deg - before[k].position.lat_deg;
            assert!((dlat - 0.2e-5).abs() < 1e-13);
        }
        assert_eq!(records[2], before[2], "not asked for");
        // 4: 20 s after 3 on the boot clock, and 5 before it (a reboot): no way known.
        // 5: the boot clock back at 1 s, 120 s before 6's; 4's is later than its own.
        // 6: the last, 120 s after 5 on the boot clock (5 has no UTC).
        assert_eq!(m.left, [4, 5, 6]);
        assert_eq!(m.moved_m.len(), 2);
        assert!(m.moved_m.iter().all(|d| (d - 0.22).abs() < 1e-12));
        // The last, from the one before, when they share a clock.
        let mut two: Vec<CaptureRecord> = (1..=2).map(sample).collect();
        let m = move_to_exposure(&mut two, &[2], 0.125);
        assert_eq!(m.left, Vec::<u64>::new());
        assert!((north(&two[1]) - 2.2 - 0.55).abs() < 1e-12);
        // A neighbour with no position tells nothing.
        let mut two: Vec<CaptureRecord> = (1..=2).map(sample).collect();
        two[1].position.east_m = f64::NAN;
        assert_eq!(move_to_exposure(&mut two, &[1], 0.1).left, [1]);
    }

    /// Triggers at the given boot times, seq from 1, UTC 1.78e9 s ahead of boot.
    fn triggers(boot_s: &[f64]) -> Vec<Trigger> {
        boot_s
            .iter()
            .enumerate()
            .map(|(k, &b)| Trigger {
                seq: k as u64 + 1,
                boot_s: b,
                unix_s: Some(1.78e9 + b),
            })
            .collect()
    }

    /// Uneven intervals, as an adaptive spacing gives: 1.3–3.7 s.
    fn uneven(m: usize) -> Vec<f64> {
        let mut t = 100.0;
        (0..m)
            .map(|k| {
                t += 1.3 + ((k * 7919) % 25) as f64 / 10.0;
                t
            })
            .collect()
    }

    #[test]
    fn equal_counts_pair_in_order_and_the_times_check_it() {
        let boot = uneven(20);
        let trig = triggers(&boot);
        // The camera's clock is set to local time, an hour ahead of UTC, and
        // stamps whole seconds (a picture's second is the one it began in).
        let imgs: Vec<_> = boot
            .iter()
            .enumerate()
            .map(|(k, b)| image(k, Some((1.78e9 + b + 3600.0 + 0.1).floor()), 1.0))
            .collect();
        let p = pair(&trig, &imgs).unwrap();
        assert_eq!(p.by, PairedBy::Order { checked: true });
        assert_eq!(
            p.pairs,
            (0..20).map(|k| (k as u64 + 1, k)).collect::<Vec<_>>()
        );
        let ahead = p.camera_ahead_of_utc_s.unwrap();
        assert!((ahead - 3600.0).abs() < 1.0, "{ahead}");
        assert!(p.unpaired_images.is_empty() && p.unpaired_captures.is_empty());

        // Without times, equal counts still pair in order, unchecked.
        let untimed: Vec<_> = (0..20).map(|k| image(k, None, 1.0)).collect();
        let p = pair(&trig, &untimed).unwrap();
        assert_eq!(p.by, PairedBy::Order { checked: false });
        assert_eq!(p.pairs.len(), 20);
        assert_eq!(p.residual_s, None);
    }

    #[test]
    fn a_test_shot_and_a_missed_trigger_are_found_by_time() {
        let boot = uneven(30);
        let trig = triggers(&boot);
        // A picture on the ground 5 minutes before the first capture; the camera
        // missed capture 12. Equal counts, but in order every picture from the
        // first to the 11th would take the wrong capture.
        let mut imgs = vec![image(0, Some(1.78e9 + boot[0] - 300.0 + 42.0), 0.01)];
        for (k, b) in boot.iter().enumerate() {
            if k != 11 {
                imgs.push(image(k + 1, Some(1.78e9 + b + 42.0 + 0.08), 0.01));
            }
        }
        let p = pair(&trig, &imgs).unwrap();
        assert_eq!(p.by, PairedBy::Time);
        assert_eq!(p.unpaired_images, vec![0]);
        assert_eq!(p.unpaired_captures, vec![12]);
        assert_eq!(p.pairs.len(), 29);
        for &(seq, i) in &p.pairs {
            assert_eq!(imgs[i].name, format!("DSC{seq:05}.JPG"));
        }
        assert!((p.camera_ahead_of_utc_s.unwrap() - 42.08).abs() < 1e-6);
    }

    /// An autopilot rebooted in flight starts its boot clock again; the
    /// captures' UTC goes on, and the pictures pair by it. Before UTC is known
    /// (a capture without it) the boot clock's step back is refused by name.
    #[test]
    fn an_autopilot_rebooted_in_flight_pairs_by_utc() {
        let utc = uneven(20);
        let mut trig = triggers(&utc);
        for (k, t) in trig.iter_mut().enumerate() {
            t.unix_s = Some(1.78e9 + utc[k]);
            // Rebooted after capture 10: its boot clock restarts at 5 s.
            t.boot_s = if k < 10 {
                utc[k]
            } else {
                utc[k] - utc[10] + 5.0
            };
        }
        // The camera missed capture 3: the counts differ, so time decides.
        let imgs: Vec<_> = (0..20)
            .filter(|&k| k != 2)
            .map(|k| image(k, Some(1.78e9 + utc[k] + 60.0), 0.01))
            .collect();
        let p = pair(&trig, &imgs).unwrap();
        assert_eq!(p.by, PairedBy::Time);
        assert_eq!(p.pairs.len(), 19);
        assert_eq!(p.unpaired_captures, vec![3]);
        assert!((p.offset_s.unwrap() - 60.0).abs() < 1e-6);
        trig[0].unix_s = None;
        let e = pair(&trig, &imgs).unwrap_err().to_string();
        assert!(e.contains("does not advance from capture 10 to 11"), "{e}");
    }

    #[test]
    fn what_cannot_be_told_apart_is_refused_with_the_reason() {
        // Counts differ and the pictures have no time.
        let trig = triggers(&uneven(5));
        let untimed: Vec<_> = (0..4).map(|k| image(k, None, 1.0)).collect();
        let e = pair(&trig, &untimed).unwrap_err().to_string();
        assert!(
            e.contains("4 pictures for 5 captures") && e.contains("no capture time"),
            "{e}"
        );

        // Captures 1 s apart, stamped in whole seconds.
        let boot: Vec<f64> = (0..6).map(|k| 100.0 + k as f64).collect();
        let imgs: Vec<_> = boot[1..]
            .iter()
            .enumerate()
            .map(|(k, b)| image(k, Some(*b), 1.0))
            .collect();
        let e = pair(&triggers(&boot), &imgs).unwrap_err().to_string();
        assert!(e.contains("1.00 s apart at the closest"), "{e}");

        // Captures exactly every 3 s, one picture short: every shift pairs as many.
        let boot: Vec<f64> = (0..8).map(|k| 100.0 + 3.0 * k as f64).collect();
        let imgs: Vec<_> = boot[1..]
            .iter()
            .enumerate()
            .map(|(k, b)| image(k, Some(*b + 7.0), 0.01))
            .collect();
        let e = pair(&triggers(&boot), &imgs).unwrap_err().to_string();
        assert!(e.contains("pair 7 and 7 of them: too close a call"), "{e}");

        // Pictures of another flight: no offset pairs half of them.
        let boot = uneven(10);
        let other = uneven(25);
        let imgs: Vec<_> = other[15..]
            .iter()
            .enumerate()
            .map(|(k, b)| image(k, Some(b * 1.37), 0.01))
            .collect();
        let e = pair(&triggers(&boot), &imgs[..9]).unwrap_err().to_string();
        assert!(e.starts_with("9 pictures for 10 captures, and "), "{e}");
        // Pictures far closer together than the captures: at any offset only a few pair.
        let burst: Vec<_> = (0..9)
            .map(|k| image(k, Some(500.0 + 0.7 * k as f64), 0.01))
            .collect();
        let e = pair(&triggers(&boot), &burst).unwrap_err().to_string();
        assert!(e.contains("are these this flight's pictures"), "{e}");

        assert_eq!(pair(&[], &imgs), Err(PairError::NoCaptures));
        assert_eq!(pair(&triggers(&boot), &[]), Err(PairError::NoImages));
    }

    /// A flight's pictures with some missed triggers and some shots before it: the
    /// pictures (times at `offset` with a delay of up to 0.2 s, stamped to 0.01 s)
    /// and the true pairs.
    fn flight(
        gaps: &[f64],
        offset: f64,
        lag: &[f64],
        missed: &[bool],
        extra_before: usize,
    ) -> (Vec<Trigger>, Vec<CameraImage>, Vec<(u64, usize)>) {
        let mut b = 50.0;
        let boot: Vec<f64> = gaps
            .iter()
            .map(|g| {
                b += g;
                b
            })
            .collect();
        let mut imgs = Vec::new();
        let mut truth = Vec::new();
        for e in 0..extra_before {
            let t = boot[0] + offset - 600.0 + e as f64;
            imgs.push(image(imgs.len(), Some(t), 0.01));
        }
        for (k, b) in boot.iter().enumerate() {
            if !missed[k] {
                truth.push((k as u64 + 1, imgs.len()));
                let t = ((b + offset + lag[k]) * 100.0).floor() / 100.0;
                imgs.push(image(imgs.len(), Some(t), 0.01));
            }
        }
        (triggers(&boot), imgs, truth)
    }

    proptest! {
        /// Whatever pictures are missing or extra, at whatever clock offset and
        /// however evenly the captures come, a pairing is the true one or none:
        /// never a wrong one.
        #[test]
        fn a_pairing_by_time_is_the_true_one_or_none(
            gaps in proptest::collection::vec(1.2f64..6.0, 12..80),
            offset in -1e5f64..1e5,
            lag in proptest::collection::vec(0.0f64..0.2, 80),
            missed in proptest::collection::vec(any::<bool>(), 80),
            extra_before in 0usize..3,
        ) {
            // At most a quarter missed.
            let missed: Vec<bool> = (0..80).map(|k| missed[k] && k % 4 == 0).collect();
            let (trig, imgs, truth) = flight(&gaps, offset, &lag, &missed, extra_before);
            match pair(&trig, &imgs) {
                Ok(p) => {
                    prop_assert_eq!(&p.pairs, &truth);
                    prop_assert!(p.residual_s.unwrap().1 <= p.tolerance_s);
                }
                Err(e) => prop_assert!(matches!(e, PairError::Unpairable { .. }), "{e}"),
            }
        }
    }

    /// And it is not refused as a rule: of 500 flights of 12 to 80 captures 1.2 to
    /// 6 s apart (uniform), each with up to a quarter of its triggers missed and up
    /// to two shots before it, at least 90 % pair, every one truly.
    #[test]
    fn most_flights_with_missed_triggers_and_extra_shots_pair_by_time() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut unit = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut paired = 0;
        for _ in 0..500 {
            let m = 12 + (unit() * 69.0) as usize;
            let gaps: Vec<f64> = (0..m).map(|_| 1.2 + 4.8 * unit()).collect();
            let lag: Vec<f64> = (0..m).map(|_| 0.2 * unit()).collect();
            let missed: Vec<bool> = (0..m).map(|k| k % 4 == 0 && unit() < 0.5).collect();
            let extra = (unit() * 3.0) as usize;
            let offset = 2e5 * (unit() - 0.5);
            let (trig, imgs, truth) = flight(&gaps, offset, &lag, &missed, extra);
            if let Ok(p) = pair(&trig, &imgs) {
                assert_eq!(p.pairs, truth);
                paired += 1;
            }
        }
        assert!(paired >= 450, "{paired} of 500 paired");
    }
}
