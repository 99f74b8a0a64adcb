//! What `alfd export` and a restarted capture writer read back from a flight directory:
//! `manifest.jsonl` (`capture::parse_manifest`, then the exports built from its records),
//! `telemetry.tlog` (`capture::tlog::parse`, `complete_prefix_len`) and EXIF GPS segments
//! (`find_exif_app1`, `parse_exif_gps`). Input: the file's bytes, fed to every reader.
#![no_main]

use alfd::capture::{
    find_exif_app1, geo_txt, parse_exif_gps, parse_manifest, tlog, transforms, CaptureRecord,
};
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();

fuzz_target!(|data: &[u8]| {
    let m = parse_manifest(data);
    let lines = data.iter().filter(|&&b| b == b'\n').count();
    assert_eq!(m.records.len() + m.bad_lines.len(), lines);
    assert!(m.torn_tail_bytes <= data.len());
    for r in &m.records {
        // A record that was read can be written back and read again.
        CaptureRecord::from_json_line(&r.to_json_line()).expect("a read record round-trips");
    }
    let _ = geo_txt(&m.records);
    let _ = transforms(&m.records);

    let (entries, err) = tlog::parse(data);
    let used: usize = entries.iter().map(|e| 8 + e.frame.len()).sum();
    match err {
        None => assert_eq!(used, data.len()),
        Some(_) => assert!(used <= data.len()),
    }
    for e in &entries {
        assert_eq!(tlog::frame_len(e.frame), Some(e.frame.len()));
    }
    assert!(tlog::complete_prefix_len(data) <= data.len());

    if let Some(app1) = find_exif_app1(data) {
        let _ = parse_exif_gps(app1);
    }
    let _ = parse_exif_gps(data);
});
