//! The capture log on disk: atomic images, a durable manifest, and what survives a
//! full disk or a crash mid-append.

use std::fs;
use std::path::Path;

use alfd::capture::{
    image_file_name, log_capture, read_manifest, Attitude, CameraIntrinsics, CaptureMode,
    CaptureRecord, CaptureStore, DirStore, FillingStore, ImageFormat, LogError, Occlusion,
    Position, Spacing, StoreError,
};

fn record(seq: u64, with_image: bool) -> CaptureRecord {
    CaptureRecord {
        seq,
        image: with_image.then(|| image_file_name(seq, ImageFormat::Jpeg { quality: 90 })),
        time_boot_us: 60_000_000 + seq * 100_000,
        time_unix_us: Some(1_780_000_000_000_000 + seq * 100_000),
        mono_ns: seq * 100_000_000,
        position: Position {
            lat_deg: 47.0 + seq as f64 * 1e-6,
            lon_deg: 8.0,
            alt_m: 540.0,
            rel_alt_m: 40.0,
            east_m: 0.0,
            north_m: seq as f64 * 0.1,
            up_m: 40.0,
        },
        attitude: Attitude {
            roll_deg: 0.0,
            pitch_deg: 0.0,
            yaw_deg: 0.0,
            camera_pitch_deg: 0.0,
        },
        spacing: Spacing {
            permissible_m: Some(0.12),
            chosen_m: 0.1,
            active_bound: "mmds".into(),
        },
        distance_since_last_m: (seq > 1).then_some(0.1),
        occlusion: Some(Occlusion {
            density_per_m: 0.02,
            degree: 0.002,
        }),
        terms: vec!["mmds".into(), "coverage".into()],
        quality: None,
        closed_loop: None,
        model: "occlusion".into(),
        capture_mode: if with_image {
            CaptureMode::Frame
        } else {
            CaptureMode::AutopilotDistance
        },
        undersampled: false,
        rate_limited: false,
        fallback: false,
        pose_age_ms: 12.5,
        intrinsics: with_image.then_some(CameraIntrinsics {
            width: 64,
            height: 48,
            focal_px: 46.0,
            cx_px: 32.0,
            cy_px: 24.0,
        }),
        requested_by: None,
        image_missing: None,
        picture_after_ms: None,
    }
}

/// Image bytes of capture `seq`, of a size that varies with it.
fn image_bytes(seq: u64) -> Vec<u8> {
    vec![seq as u8; 200 + (seq as usize * 37) % 300]
}

/// The guarantee: every line is a complete record, and every image it names
/// exists with the bytes that were logged for it; no temporary file is left.
fn assert_consistent(dir: &Path, expect_seqs: &[u64]) {
    let m = read_manifest(&dir.join("manifest.jsonl")).unwrap();
    assert_eq!(m.torn_tail_bytes, 0);
    assert!(m.bad_lines.is_empty(), "{:?}", m.bad_lines);
    let seqs: Vec<u64> = m.records.iter().map(|r| r.seq).collect();
    assert_eq!(seqs, expect_seqs);
    for r in &m.records {
        if let Some(name) = &r.image {
            let bytes = fs::read(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(bytes, image_bytes(r.seq), "{name}");
        }
    }
    for e in fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(!name.ends_with(".tmp"), "temporary file left: {name}");
    }
}

#[test]
fn captures_are_logged_image_first_and_read_back() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = DirStore::open(tmp.path().join("flight")).unwrap();
    let mut logged = Vec::new();
    for seq in 1..=5 {
        let with_image = seq != 3;
        let r = record(seq, with_image);
        let img = image_bytes(seq);
        log_capture(&mut store, &r, with_image.then_some(&img[..])).unwrap();
        logged.push(r);
    }
    let dir = store.dir().to_path_buf();
    assert_consistent(&dir, &[1, 2, 3, 4, 5]);
    let m = read_manifest(&store.manifest_path()).unwrap();
    assert_eq!(m.records, logged);
    assert!(!dir.join("IMG_000003.jpg").exists());
    let text = fs::read_to_string(store.manifest_path()).unwrap();
    assert_eq!(text.lines().count(), 5);
    assert!(text.ends_with('\n'));
    assert!(store.free_bytes().is_some_and(|b| b > 0));
}

#[test]
fn images_are_never_replaced_and_exports_are() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = DirStore::open(tmp.path()).unwrap();
    store.write_image("IMG_000001.jpg", b"first").unwrap();
    assert!(matches!(
        store.write_image("IMG_000001.jpg", b"second"),
        Err(StoreError::Exists { .. })
    ));
    assert_eq!(
        fs::read(tmp.path().join("IMG_000001.jpg")).unwrap(),
        b"first"
    );
    store.write_export("geo.txt", b"one").unwrap();
    store.write_export("geo.txt", b"two").unwrap();
    assert_eq!(fs::read(tmp.path().join("geo.txt")).unwrap(), b"two");
    for bad in [
        "../escape.jpg",
        ".hidden",
        "manifest.jsonl",
        "telemetry.tlog",
    ] {
        assert!(
            matches!(
                store.write_export(bad, b"x"),
                Err(StoreError::BadName { .. })
            ),
            "{bad}"
        );
    }
    assert!(matches!(
        store.append_manifest_line("two\nlines"),
        Err(StoreError::BadLine)
    ));
    assert!(!tmp.path().parent().unwrap().join("escape.jpg").exists());
}

#[test]
fn a_full_disk_at_any_byte_leaves_a_consistent_log() {
    // Fill up after every possible budget over the first few captures: whatever
    // write fails, the manifest holds exactly the captures whose log_capture
    // returned Ok, each complete and with its image in place.
    let per_capture: Vec<u64> = (1..=4)
        .map(|s| image_bytes(s).len() as u64 + record(s, true).to_json_line().len() as u64 + 1)
        .collect();
    let total: u64 = per_capture.iter().sum();
    let tmp = tempfile::tempdir().unwrap();
    let mut fulls = 0;
    let mut all_logged_at = None;
    let mut budgets: Vec<u64> = (0..=total).step_by(47).chain([total - 1, total]).collect();
    budgets.sort_unstable();
    budgets.dedup();
    for capacity in budgets {
        let dir = tmp.path().join(format!("cap{capacity}"));
        let mut store = FillingStore::new(DirStore::open(&dir).unwrap(), capacity);
        let mut ok = Vec::new();
        for seq in 1..=4 {
            let img = image_bytes(seq);
            match log_capture(&mut store, &record(seq, true), Some(&img)) {
                Ok(()) => ok.push(seq),
                Err(LogError::Store(StoreError::Full { .. })) => {
                    fulls += 1;
                    break;
                }
                Err(e) => panic!("capacity {capacity}: {e}"),
            }
        }
        assert!(store.used_bytes() <= capacity);
        if ok.len() == 4 && all_logged_at.is_none() {
            all_logged_at = Some(capacity);
        }
        assert_consistent(&dir, &ok);
        // The log goes on after the disk was full: a reopened store appends cleanly.
        drop(store);
        let mut again = DirStore::open(&dir).unwrap();
        assert_eq!(again.recovered_bytes(), 0);
        let next = ok.len() as u64 + 1;
        let img = image_bytes(next);
        log_capture(&mut again, &record(next, true), Some(&img)).ok();
        // The image of a failed capture may already exist: then the retry is refused
        // (sequence numbers are never reused) and the manifest is still consistent.
        let m = read_manifest(&dir.join("manifest.jsonl")).unwrap();
        let seqs: Vec<u64> = m.records.iter().map(|r| r.seq).collect();
        assert!(seqs == ok || seqs == [&ok[..], &[next]].concat());
        assert_consistent(&dir, &seqs);
    }
    assert!(
        fulls > 0,
        "the budgets never ran out: the test tests nothing"
    );
    assert_eq!(
        all_logged_at,
        Some(total),
        "exactly the sum of the writes fits all four"
    );
}

#[test]
fn reopening_cuts_a_torn_line_and_removes_temporaries() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    {
        let mut store = DirStore::open(dir).unwrap();
        for seq in 1..=2 {
            let img = image_bytes(seq);
            log_capture(&mut store, &record(seq, true), Some(&img)).unwrap();
        }
    }
    // A crash mid-append and mid-image: half a line, a temporary file.
    let line = record(3, true).to_json_line();
    let mut bytes = fs::read(dir.join("manifest.jsonl")).unwrap();
    bytes.extend_from_slice(&line.as_bytes()[..40]);
    fs::write(dir.join("manifest.jsonl"), &bytes).unwrap();
    fs::write(dir.join(".IMG_000003.jpg.tmp"), b"partial").unwrap();

    let m = read_manifest(&dir.join("manifest.jsonl")).unwrap();
    assert_eq!(m.records.len(), 2);
    assert_eq!(m.torn_tail_bytes, 40);

    let mut store = DirStore::open(dir).unwrap();
    assert_eq!(store.recovered_bytes(), 40);
    assert!(!dir.join(".IMG_000003.jpg.tmp").exists());
    let img = image_bytes(3);
    log_capture(&mut store, &record(3, true), Some(&img)).unwrap();
    assert_consistent(dir, &[1, 2, 3]);
}

#[test]
fn the_documented_example_line_is_a_valid_record() {
    let doc = include_str!("../docs/capture-log.md");
    let line = doc
        .lines()
        .find(|l| l.starts_with(r#"{"seq":"#))
        .expect("docs/capture-log.md shows a manifest line");
    let r = CaptureRecord::from_json_line(line).unwrap();
    assert_eq!(
        r.to_json_line(),
        line,
        "the example is in the order alfd writes"
    );
}
