//! An MJPEG camera through the whole daemon: `alfd run` against firmware-sim over a
//! pty, both cameras a live replay of a recording whose colour frames are MJPEG buffers
//! without Huffman tables (as many UVC cameras send them), the streaming colour path
//! (`Frames::Stream`, the camera's ring, the writer) as in flight. With
//! `keep_camera_jpeg` (the default) every image is the camera's own scan, byte for byte,
//! with the standard tables and alfd's EXIF added; with it off, every image is
//! re-encoded. Either way each image decodes, its EXIF places it where the manifest does, and
//! the manifest gives it the colour camera's intrinsics (60° here), not the depth camera's
//! (69°).

mod tools;

use alfd::capture::{find_exif_app1, parse_exif_gps, read_manifest};
use alfd::core::Intrinsics;
use alfd::render::{render, Camera, RenderOptions, SensorModel};
use alfd::scene::Scene;
use alfd::source::recorded::{Recorder, RecordingMeta};
use alfd::source::ColorImage;
use std::collections::HashSet;
use std::path::Path;
use std::time::{Duration, Instant};

const W: usize = 160;
const H: usize = 120;
const FRAMES: usize = 30;
/// The colour camera's field of view: narrower than the depth camera's 69°, as on a D435.
const COLOUR_HFOV_DEG: f64 = 60.0;

/// The bytes from the scan's start to the end of the image: what an encoder wrote.
fn scan(jpeg: &[u8]) -> &[u8] {
    let sos = jpeg
        .windows(2)
        .position(|w| w == [0xFF, 0xDA])
        .expect("a scan");
    &jpeg[sos..]
}

fn has_tables(jpeg: &[u8]) -> bool {
    jpeg[..jpeg.len() - scan(jpeg).len()]
        .windows(2)
        .any(|w| w == [0xFF, 0xC4])
}

/// A second of the tower scene, 30 fps, 0.333 m apart at 60 m: Z16 depth and MJPEG
/// colour without tables. Returns the colour frames' scans.
fn record(dir: &Path) -> HashSet<Vec<u8>> {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/tower.toml"
    ))
    .unwrap();
    let scene = Scene::parse(&text, "tower").unwrap();
    let intr = Intrinsics::from_hfov_deg(W, H, 69.0, None).unwrap();
    let (cx_px, cy_px) = intr.principal_px();
    let meta = RecordingMeta {
        width: W,
        height: H,
        focal_px: intr.focal_px(),
        cx_px,
        cy_px,
        depth_scale_m: 0.01,
    };
    let sensor = SensorModel {
        scale_m: 0.01,
        max_range_m: 300.0,
        ..SensorModel::default()
    };
    let mut rec = Recorder::create(dir, meta).unwrap();
    let mut scans = HashSet::new();
    let colour_intr = Intrinsics::from_hfov_deg(W, H, COLOUR_HFOV_DEG, None).unwrap();
    for i in 0..FRAMES {
        let at = |intrinsics| Camera {
            position_m: [-5.0 + i as f64 / 3.0, 0.0, 60.0],
            roll_rad: 0.0,
            pitch_rad: 0.0,
            yaw_rad: 0.0,
            intrinsics,
        };
        let frame = render(&scene, &at(intr), &RenderOptions { supersample: 1 });
        let colour = ColorImage {
            width: W,
            height: H,
            rgb: render(&scene, &at(colour_intr), &RenderOptions { supersample: 1 }).rgb8(),
        };
        let jpeg = alfd::capture::encode_jpeg(&colour.rgb, W as u32, H as u32, 85, None).unwrap();
        let uvc = alfd::capture::jpeg::without_huffman_tables(&jpeg);
        assert!(!has_tables(&uvc));
        scans.insert(scan(&uvc).to_vec());
        let t = 1_000_000_000 + i as u64 * 33_333_333;
        rec.push_mjpeg(i as u64 + 1, t, Some(&frame.z16(&sensor)), &uvc)
            .unwrap();
    }
    scans
}

fn config(address: &str, recording: &Path, captures: &Path, keep: bool) -> String {
    format!(
        r#"[mavlink]
address = "{address}"
[camera]
source = "recorded"
dir = {recording:?}
replay = "live"
width = {W}
height = {H}
fps = 30.0
hfov_deg = {COLOUR_HFOV_DEG}
[depth]
source = "recorded"
dir = {recording:?}
replay = "live"
width = {W}
height = {H}
fps = 30.0
hfov_deg = 69.0
scale_m = 0.01
[trigger]
fallback_spacing_m = 1.0
[capture]
dir = {captures:?}
mode = "frame"
image_format = "jpeg"
keep_camera_jpeg = {keep}
"#
    )
}

/// Flies until `want` captures are logged, stops the daemon by SIGTERM, and checks every
/// image against the camera's frames. Returns the images and the count the daemon's
/// last log line gives of those stored as the camera encoded them.
async fn fly(keep: bool, want: usize) -> (usize, u64) {
    let dir = tempfile::tempdir().unwrap();
    let recording = dir.path().join("recording");
    let scans = record(&recording);
    let sim = firmware_sim::start(tools::line_sim(dir.path()))
        .await
        .unwrap();
    let captures = dir.path().join("captures");
    let config_path = dir.path().join("alfd.toml");
    std::fs::write(
        &config_path,
        config(sim.address(), &recording, &captures, keep),
    )
    .unwrap();
    let (mut child, log) = tools::alfd_run(&config_path, &[]);
    let manifest = captures.join("flight-001").join("manifest.jsonl");
    let deadline = Instant::now() + Duration::from_secs(90);
    while std::fs::read_to_string(&manifest).map_or(0, |t| t.lines().count()) < want {
        assert!(
            Instant::now() < deadline,
            "fewer than {want} captures within 90 s"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // SAFETY: kill sends a signal to the child we started, by its id.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let status = tokio::task::spawn_blocking(move || child.wait())
        .await
        .unwrap()
        .unwrap();
    assert!(status.success(), "exit status {status}");
    let lines = log.join().unwrap();
    let stopped = lines
        .iter()
        .find(|l| l.contains("stopped:"))
        .unwrap_or_else(|| panic!("no final line in {lines:?}"));
    let as_received: u64 = stopped
        .split(" images as the camera encoded them")
        .next()
        .and_then(|s| s.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count of images kept in {stopped}"));

    let flight = captures.join("flight-001");
    let m = read_manifest(&manifest).unwrap();
    assert!(m.records.len() >= want && m.bad_lines.is_empty());
    let mut images = 0;
    for r in &m.records {
        let name = match (&r.image, &r.image_missing) {
            (Some(name), None) => name,
            // A storage stall on a shared disk may put the writer behind its deadline;
            // nothing else takes an image away.
            (None, Some(why)) if why.starts_with("writer behind") => continue,
            other => panic!("capture {}: {other:?}", r.seq),
        };
        // The manifest describes the colour camera that took the image, not the depth camera.
        let ci = r.intrinsics.as_ref().expect("intrinsics of a saved image");
        let focal = (W as f64 / 2.0) / (COLOUR_HFOV_DEG / 2.0).to_radians().tan();
        assert_eq!((ci.width, ci.height), (W as u32, H as u32));
        assert!(
            (ci.focal_px - focal).abs() < 1e-6,
            "{name}: focal {} px",
            ci.focal_px
        );
        let bytes = std::fs::read(flight.join(name)).unwrap();
        let decoded = jpeg_decoder::Decoder::new(&bytes[..]).decode();
        assert_eq!(decoded.map(|p| p.len()).ok(), Some(W * H * 3), "{name}");
        assert!(has_tables(&bytes), "{name}: a file any decoder reads");
        let exif = parse_exif_gps(find_exif_app1(&bytes).expect("EXIF")).unwrap();
        assert!((exif.lat_deg - r.position.lat_deg).abs() < 1e-7, "{name}");
        assert!((exif.lon_deg - r.position.lon_deg).abs() < 1e-7, "{name}");
        assert_eq!(
            scans.contains(scan(&bytes)),
            keep,
            "{name}: the camera's scan kept = {keep}"
        );
        images += 1;
    }
    eprintln!(
        "FIGURE keep_camera_jpeg = {keep}: {} captures, {images} images, {as_received} as the camera encoded them",
        m.records.len()
    );
    sim.shutdown().await;
    (images, as_received)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_mjpeg_cameras_frames_are_stored_as_it_encoded_them() {
    let (images, as_received) = fly(true, 8).await;
    assert!(images >= 4, "{images} images");
    assert_eq!(as_received, images as u64);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_keep_camera_jpeg_off_every_frame_is_re_encoded() {
    let (images, as_received) = fly(false, 8).await;
    assert!(images >= 4, "{images} images");
    assert_eq!(as_received, 0);
}
