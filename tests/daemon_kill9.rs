//! `alfd sim` killed with SIGKILL at pseudo-random instants while it captures:
//! what is on disk is always a readable capture log (complete manifest lines, each
//! naming an image that exists and decodes), and reopening the directory (what a
//! restarted daemon does) removes temporary files and cuts torn tails.

use alfd::capture::{parse_manifest, tlog, CaptureRecord, DirStore};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

const RUNS: usize = 24;
/// Two at a time: the machine has two cores, and each run is several threads.
const PARALLEL: usize = 2;
/// Captures are written from about 0.5 s to 9.5 s after spawn (measured on the
/// tower scene at 160×120, 70 m, unloaded); the flight ends at about 13 s.
const KILL_FROM_S: f64 = 1.5;
const KILL_TO_S: f64 = 9.0;
const SEED: u64 = 0x9E37_79B9_7F4A_7C15;

/// Marsaglia's xorshift64: a fixed seed gives the same instants on every run.
struct XorShift(u64);

impl XorShift {
    fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }

    /// Uniform in [0, 1).
    fn next_unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What one killed run left on disk.
#[derive(Debug, Default)]
struct RunStats {
    kill_s: f64,
    lines: usize,
    images: usize,
    /// Complete images on disk that no manifest line names yet (killed between
    /// the image's rename and its manifest line).
    unlisted_images: usize,
    torn_manifest_bytes: usize,
    torn_tlog_bytes: usize,
    tmp_files: usize,
    /// tlog entries stamped earlier than the entry before them.
    tlog_steps_back: usize,
    tlog_max_back_us: u64,
}

fn tmp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') && n.ends_with(".tmp"))
        .collect()
}

/// Decodes a whole JPEG and returns its size; panics with the file name if it is
/// cut short or corrupt.
fn decode_jpeg(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut dec = jpeg_decoder::Decoder::new(&bytes[..]);
    let pixels = dec
        .decode()
        .unwrap_or_else(|e| panic!("{} does not decode: {e}", path.display()));
    let info = dec.info().expect("decoded, so the header was read");
    let (w, h) = (u32::from(info.width), u32::from(info.height));
    assert_eq!(
        pixels.len(),
        w as usize * h as usize * info.pixel_format.pixel_bytes(),
        "{}: every pixel decoded",
        path.display()
    );
    (w, h)
}

/// The image files in `dir` (`IMG_*.jpg`), by name.
fn image_files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("IMG_") && n.ends_with(".jpg"))
        .collect();
    v.sort();
    v
}

/// Checks the records of a manifest: sequence from 1 without gaps; every named
/// image is the one its sequence number gives, exists and decodes at the size
/// of the record's intrinsics. Returns the number of images decoded.
fn check_records(flight: &Path, records: &[CaptureRecord]) -> usize {
    let mut images = 0;
    for (k, r) in records.iter().enumerate() {
        assert_eq!(
            r.seq,
            k as u64 + 1,
            "{}: sequence without gaps",
            flight.display()
        );
        let Some(name) = &r.image else {
            continue;
        };
        assert!(
            alfd::capture::record::is_image_name_for(name, r.seq),
            "capture {} names {name}",
            r.seq
        );
        let path = flight.join(name);
        assert!(
            path.is_file(),
            "capture {}: {} is missing",
            r.seq,
            path.display()
        );
        let (w, h) = decode_jpeg(&path);
        let cam = r
            .intrinsics
            .as_ref()
            .unwrap_or_else(|| panic!("capture {} has an image but no intrinsics", r.seq));
        assert_eq!((w, h), (cam.width, cam.height), "capture {}: {name}", r.seq);
        images += 1;
    }
    images
}

/// The tlog's length kept on reopening, after checking that only a torn last
/// entry can be cut.
fn check_tlog(path: &Path, stats: &mut RunStats) -> usize {
    let Ok(bytes) = std::fs::read(path) else {
        return 0;
    };
    let keep = tlog::complete_prefix_len(&bytes);
    let (entries, err) = tlog::parse(&bytes[..keep]);
    assert!(
        err.is_none(),
        "{}: {err:?} inside the log (not a torn tail)",
        path.display()
    );
    if keep < bytes.len() {
        assert!(
            matches!(tlog::parse(&bytes).1, Some(tlog::TlogError::Truncated { offset }) if offset == keep),
            "{}: cut at {keep} of {}",
            path.display(),
            bytes.len()
        );
    }
    // Reported, not asserted: reception order is not what this test is about.
    for w in entries.windows(2) {
        if w[1].unix_us < w[0].unix_us {
            let back_us = w[0].unix_us - w[1].unix_us;
            println!("{}: tlog time steps back {back_us} µs", path.display());
            stats.tlog_steps_back += 1;
            stats.tlog_max_back_us = stats.tlog_max_back_us.max(back_us);
        }
    }
    bytes.len() - keep
}

/// Spawns `alfd sim` in a fresh directory, kills it `kill_s` after spawn, and
/// checks what it left.
fn killed_run(bin: &Path, scene: &Path, kill_s: f64) -> RunStats {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let stderr = std::fs::File::create(tmp.path().join("stderr.txt")).unwrap();
    let spawned = Instant::now();
    let mut child = Command::new(bin)
        // In real time, over a pty: the kill must land in a flight under way (on simulated
        // time the short flight is over within a second or two).
        .args(["sim", "--real-time", "--scene"])
        .arg(scene)
        .args(["--width", "160", "--height", "120", "--no-progress"])
        .args(["--log-level", "warn", "--length-m", "70", "--out"])
        .arg(&out)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .expect("alfd starts");
    std::thread::sleep(
        (spawned + Duration::from_secs_f64(kill_s)).saturating_duration_since(Instant::now()),
    );
    let early = child.try_wait().unwrap();
    let pid = libc::pid_t::try_from(child.id()).unwrap();
    // SAFETY: kill(2) with a pid we spawned and have not reaped (try_wait saw it running).
    let rc = if early.is_none() {
        unsafe { libc::kill(pid, libc::SIGKILL) }
    } else {
        0
    };
    assert_eq!(rc, 0, "kill: {}", std::io::Error::last_os_error());
    let status = child.wait().unwrap();
    let log = std::fs::read_to_string(tmp.path().join("stderr.txt")).unwrap_or_default();
    assert_eq!(
        status.signal(),
        Some(libc::SIGKILL),
        "alfd was to be killed at {kill_s:.2} s, but ended with {status}; stderr:\n{log}"
    );

    let mut stats = RunStats {
        kill_s,
        ..RunStats::default()
    };
    let flight = out.join("flight-001");
    if !flight.is_dir() {
        return stats; // killed before the flight directory existed
    }
    stats.tmp_files = tmp_files(&flight).len();

    // As the kill left it.
    let manifest = std::fs::read(flight.join("manifest.jsonl")).unwrap_or_default();
    let m = parse_manifest(&manifest);
    assert!(
        m.bad_lines.is_empty(),
        "{}: {:?}",
        flight.display(),
        m.bad_lines
    );
    let complete = manifest.len() - m.torn_tail_bytes;
    for line in manifest[..complete].split_inclusive(|&c| c == b'\n') {
        let line = std::str::from_utf8(&line[..line.len() - 1]).unwrap();
        CaptureRecord::from_json_line(line).unwrap_or_else(|e| panic!("{e}: {line}"));
    }
    stats.lines = m.records.len();
    stats.torn_manifest_bytes = m.torn_tail_bytes;
    stats.images = check_records(&flight, &m.records);
    // Images are renamed into place whole, so any on disk decodes, listed or not.
    for name in image_files(&flight) {
        let listed = m.records.iter().any(|r| r.image.as_deref() == Some(&name));
        if !listed {
            decode_jpeg(&flight.join(&name));
            stats.unlisted_images += 1;
        }
    }
    stats.torn_tlog_bytes = check_tlog(&flight.join("telemetry.tlog"), &mut stats);

    // As a restarted daemon finds it.
    let store = DirStore::open(&flight).expect("the flight directory reopens");
    assert_eq!(
        store.recovered_bytes(),
        (stats.torn_manifest_bytes + stats.torn_tlog_bytes) as u64,
        "{}: reopening cuts exactly the torn tails",
        flight.display()
    );
    drop(store);
    assert_eq!(
        tmp_files(&flight),
        Vec::<String>::new(),
        "reopening removes .tmp files"
    );
    let again = parse_manifest(&std::fs::read(flight.join("manifest.jsonl")).unwrap());
    assert_eq!(again.torn_tail_bytes, 0);
    assert!(again.bad_lines.is_empty());
    assert_eq!(
        again.records, m.records,
        "reopening keeps every complete line"
    );
    check_records(&flight, &again.records);
    assert_eq!(
        check_tlog(&flight.join("telemetry.tlog"), &mut RunStats::default()),
        0
    );
    stats
}

#[test]
fn kill9_at_random_instants_leaves_a_readable_capture_log() {
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_alfd"));
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/tower.toml");
    let mut rng = XorShift(SEED);
    let instants: Vec<f64> = (0..RUNS)
        .map(|_| KILL_FROM_S + (KILL_TO_S - KILL_FROM_S) * rng.next_unit())
        .collect();

    let started = Instant::now();
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<(usize, RunStats)>> = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..PARALLEL {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&kill_s) = instants.get(i) else {
                    break;
                };
                let st = killed_run(&bin, &scene, kill_s);
                println!(
                    "run {i:2}: killed at {:5.2} s: {:2} lines, {:2} images (+{} unlisted), \
                     torn manifest {:3} B, torn tlog {:3} B, {} tmp files",
                    st.kill_s,
                    st.lines,
                    st.images,
                    st.unlisted_images,
                    st.torn_manifest_bytes,
                    st.torn_tlog_bytes,
                    st.tmp_files
                );
                results.lock().unwrap().push((i, st));
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|(i, _)| *i);
    assert_eq!(results.len(), RUNS);

    let sum = |f: fn(&RunStats) -> usize| results.iter().map(|(_, s)| f(s)).sum::<usize>();
    let count = |f: fn(&RunStats) -> bool| results.iter().filter(|(_, s)| f(s)).count();
    let with_records = count(|s| s.lines > 0);
    println!(
        "total: {RUNS} runs killed in {:.1} s; {} with records; {} lines checked, {} images \
         decoded (+{} unlisted); torn manifest tails {}, torn tlog tails {}, runs with tmp \
         files {} ({} files); tlog steps back in time {} (largest {} µs)",
        started.elapsed().as_secs_f64(),
        with_records,
        sum(|s| s.lines),
        sum(|s| s.images),
        sum(|s| s.unlisted_images),
        count(|s| s.torn_manifest_bytes > 0),
        count(|s| s.torn_tlog_bytes > 0),
        count(|s| s.tmp_files > 0),
        sum(|s| s.tmp_files),
        sum(|s| s.tlog_steps_back),
        results
            .iter()
            .map(|(_, s)| s.tlog_max_back_us)
            .max()
            .unwrap_or(0),
    );
    assert!(
        with_records * 4 >= RUNS * 3,
        "only {with_records} of {RUNS} runs had written a capture when killed: \
         the test would pass without checking anything"
    );
}
