//! What `alfd export` and a restarted capture writer read back from a flight directory:
//! `manifest.jsonl` (`capture::parse_manifest`, then the exports built from its records),
//! `telemetry.tlog` (`capture::tlog::parse`, `complete_prefix_len`) and EXIF GPS segments
//! (`find_exif_app1`, `parse_exif_gps`, and the capture time `parse_exif_taken` pairs an
//! external camera's pictures by). Input: the file's bytes, fed to every reader.
#![no_main]

use alfd::capture::exif::parse_exif_taken;
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
    // Every record is a line of geo.txt or a stated skip; the same for transforms.json.
    let (geo, skipped) = geo_txt(&m.records);
    assert_eq!(geo.lines().count() - 1 + skipped.len(), m.records.len());
    let (nerf, skipped) = transforms(&m.records);
    assert_eq!(
        nerf.map_or(0, |t| t.frames.len()) + skipped.len(),
        m.records.len()
    );

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

    // A position read back is a position: on the globe, finite height.
    for g in [
        find_exif_app1(data).map(parse_exif_gps),
        Some(parse_exif_gps(data)),
    ]
    .into_iter()
    .flatten()
    .flatten()
    {
        assert!(
            g.lat_deg.abs() <= 90.0 && g.lon_deg.abs() <= 180.0 && g.alt_m.is_finite(),
            "{g:?}"
        );
    }
    // A capture time read back is a time: finite, its step a power of ten up to 1 s.
    for t in [
        find_exif_app1(data).and_then(parse_exif_taken),
        parse_exif_taken(data),
    ]
    .into_iter()
    .flatten()
    {
        assert!(
            t.clock_s.is_finite() && t.resolution_s > 0.0 && t.resolution_s <= 1.0,
            "{t:?}"
        );
    }
});
