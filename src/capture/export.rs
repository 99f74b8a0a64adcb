//! Exports of a flight's manifest for the tools that use the images: OpenDroneMap
//! `geo.txt` and nerfstudio `transforms.json`, with the camera pose maths they
//! share. Encoders are pure; [`write_exports`] writes them through a store, and
//! [`export_flight`] for a flight directory on disk that stopped without them.
//!
//! Frames: the camera (OpenCV axes: x right in the image, y down, z along the
//! optical axis) equals the vehicle's FRD body frame at camera pitch 0 (image
//! columns run forward, rows to the right, see `crate::synth`); a forward camera
//! pitch φ rotates it about the body's right axis. Body → NED by the autopilot's
//! ZYX Euler angles; world = local ENU metres around the home point.

use crate::core::attitude::{body_to_ned, camera_to_body};
use glam::{DMat3, DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};

use super::external::{
    is_external, move_to_exposure, pair, CameraDir, Moved, PairError, Pairing, Trigger,
};
use super::record::{
    is_image_name_for, pictures_after_ms, Attitude, CameraIntrinsics, CaptureMode, CaptureRecord,
};
use super::store::{parse_manifest, CaptureStore, DirStore, Manifest, StoreError, MANIFEST};
use std::collections::BTreeMap;
use std::path::Path;

pub const GEO_TXT: &str = "geo.txt";
pub const TRANSFORMS_JSON: &str = "transforms.json";
/// COLMAP's text model of the flight's own images with their poses (`colmap_text`).
pub const COLMAP_CAMERAS: &str = "cameras.txt";
pub const COLMAP_IMAGES: &str = "images.txt";
pub const COLMAP_POINTS: &str = "points3D.txt";

/// NED → ENU: swap the horizontal axes, flip the vertical one.
pub const NED_TO_ENU: DMat3 = DMat3::from_cols(
    DVec3::new(0.0, 1.0, 0.0),
    DVec3::new(1.0, 0.0, 0.0),
    DVec3::new(0.0, 0.0, -1.0),
);

/// OpenGL camera axes (x right, y up, z back) → OpenCV camera axes: flip y and z.
pub const GL_TO_CV: DMat3 = DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));

/// Rotation of the camera in OpenGL axes → NED.
pub fn camera_gl_to_ned(att: &Attitude) -> DMat3 {
    body_to_ned(
        att.roll_deg.to_radians(),
        att.pitch_deg.to_radians(),
        att.yaw_deg.to_radians(),
    ) * camera_to_body(att.camera_pitch_deg.to_radians())
        * GL_TO_CV
}

/// nerfstudio's `transform_matrix`: camera (OpenGL axes) → world (local ENU, metres).
pub fn camera_to_world_gl(att: &Attitude, enu_m: DVec3) -> DMat4 {
    let r = NED_TO_ENU * camera_gl_to_ned(att);
    DMat4::from_cols(
        r.x_axis.extend(0.0),
        r.y_axis.extend(0.0),
        r.z_axis.extend(0.0),
        DVec4::new(enu_m.x, enu_m.y, enu_m.z, 1.0),
    )
}

/// ODM's image frame (x right, y up = "top of the image", z back) → its body frame
/// (`opendm/photo.py`, `compute_opk`: top of the image points in the flying direction,
/// camera looking down). The matrix is its own inverse.
const ODM_CAMERA_TO_BODY: DMat3 = DMat3::from_cols(
    DVec3::new(0.0, 1.0, 0.0),
    DVec3::new(1.0, 0.0, 0.0),
    DVec3::new(0.0, 0.0, -1.0),
);

/// ZYX Euler angles (yaw, pitch, roll; degrees) of a rotation → NED.
fn zyx_deg(m: DMat3) -> (f64, f64, f64) {
    let pitch = (-m.x_axis.z).clamp(-1.0, 1.0).asin();
    let roll = m.y_axis.z.atan2(m.z_axis.z);
    let yaw = m.x_axis.y.atan2(m.x_axis.x);
    // `+ 0.0` turns −0 into 0, so a level camera prints "0.0000", not "-0.0000".
    (
        yaw.to_degrees() + 0.0,
        pitch.to_degrees() + 0.0,
        roll.to_degrees() + 0.0,
    )
}

/// The (yaw, pitch, roll) in degrees to write in `geo.txt` so that ODM's
/// `compute_opk` (R = Rz(yaw)·Ry(pitch)·Rx(roll)·ODM_CAMERA_TO_BODY) gives back the
/// true camera orientation. Not the vehicle's angles: ODM assumes the image's top
/// points forward, while alfd's image columns do, so a nadir camera at vehicle
/// yaw ψ is ODM yaw ψ − 90°; the camera pitch is folded in too.
pub fn odm_ypr_deg(att: &Attitude) -> (f64, f64, f64) {
    zyx_deg(camera_gl_to_ned(att) * ODM_CAMERA_TO_BODY)
}

/// Why a record is not in an export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Skip {
    NoImage,
    ImageNameNotFromSeq,
    NoPosition,
    NoAttitude,
    NoIntrinsics,
    /// An external camera's picture: its mounting and lens are not known to alfd, so
    /// it has a position (`geo.txt`) and no camera pose (`transforms.json`).
    ExternalCamera,
}

fn image_of(r: &CaptureRecord) -> Result<&str, Skip> {
    let name = r.image.as_deref().ok_or(Skip::NoImage)?;
    if !is_image_name_for(name, r.seq) {
        return Err(Skip::ImageNameNotFromSeq);
    }
    Ok(name)
}

fn finite(xs: &[f64]) -> bool {
    xs.iter().all(|x| x.is_finite())
}

/// OpenDroneMap `geo.txt`: `EPSG:4326`, then one line per captured image:
/// `image_name lon lat alt_amsl yaw pitch roll` (degrees, metres; angles per
/// [`odm_ypr_deg`], left out when the attitude is unknown). Returns the text and
/// the records left out, by sequence number.
pub fn geo_txt(records: &[CaptureRecord]) -> (String, Vec<(u64, Skip)>) {
    geo_txt_with(records, &External::new())
}

/// An external camera's pictures by the sequence number of the capture each is
/// paired with (`capture::external`).
pub type External = BTreeMap<u64, String>;

/// [`geo_txt`], with the external camera's pictures in `external` on the lines of
/// their captures. Their lines have no angles: the camera's mounting on the
/// vehicle is not known to alfd, and a wrong orientation prior misleads more than none.
pub fn geo_txt_with(records: &[CaptureRecord], external: &External) -> (String, Vec<(u64, Skip)>) {
    let mut out = String::from("EPSG:4326\n");
    let mut skipped = Vec::new();
    for r in records {
        let (name, angles) = match external.get(&r.seq) {
            Some(n) => (n.as_str(), false),
            None => match image_of(r) {
                Ok(n) => (n, true),
                Err(s) => {
                    skipped.push((r.seq, s));
                    continue;
                }
            },
        };
        let p = &r.position;
        if !finite(&[p.lat_deg, p.lon_deg, p.alt_m]) {
            skipped.push((r.seq, Skip::NoPosition));
            continue;
        }
        out += &format!("{name} {:.9} {:.9} {:.3}", p.lon_deg, p.lat_deg, p.alt_m);
        let (yaw, pitch, roll) = odm_ypr_deg(&r.attitude);
        if angles && finite(&[yaw, pitch, roll]) {
            out += &format!(" {yaw:.4} {pitch:.4} {roll:.4}");
        }
        out.push('\n');
    }
    (out, skipped)
}

/// One frame of `transforms.json`. Intrinsics appear per frame only where they
/// differ from the file's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NerfFrame {
    pub file_path: String,
    /// Camera-to-world, rows of the 4×4 matrix, OpenGL camera axes, world = ENU metres.
    pub transform_matrix: [[f64; 4]; 4],
    #[serde(flatten, skip_serializing_if = "Option::is_none", default)]
    pub intrinsics: Option<NerfIntrinsics>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NerfIntrinsics {
    pub fl_x: f64,
    pub fl_y: f64,
    pub cx: f64,
    pub cy: f64,
    pub w: u32,
    pub h: u32,
}

impl From<CameraIntrinsics> for NerfIntrinsics {
    fn from(c: CameraIntrinsics) -> Self {
        NerfIntrinsics {
            fl_x: c.focal_px,
            fl_y: c.focal_px,
            cx: c.cx_px,
            cy: c.cy_px,
            w: c.width,
            h: c.height,
        }
    }
}

/// nerfstudio `transforms.json` (pinhole, `OPENCV` with zero distortion).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NerfTransforms {
    pub camera_model: String,
    #[serde(flatten)]
    pub intrinsics: NerfIntrinsics,
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub frames: Vec<NerfFrame>,
}

/// Row-major rows of a glam (column-major) matrix.
pub fn rows(m: &DMat4) -> [[f64; 4]; 4] {
    let t = m.transpose();
    [
        t.x_axis.to_array(),
        t.y_axis.to_array(),
        t.z_axis.to_array(),
        t.w_axis.to_array(),
    ]
}

/// The transforms of the records with an image, a pose and intrinsics; `None`
/// when there is none (nerfstudio needs intrinsics). Also returns the records left out.
pub fn transforms(records: &[CaptureRecord]) -> (Option<NerfTransforms>, Vec<(u64, Skip)>) {
    transforms_with(records, &External::new())
}

/// [`transforms`]; the captures in `external` are skipped as [`Skip::ExternalCamera`].
pub fn transforms_with(
    records: &[CaptureRecord],
    external: &External,
) -> (Option<NerfTransforms>, Vec<(u64, Skip)>) {
    let mut skipped = Vec::new();
    let mut file_intr: Option<NerfIntrinsics> = None;
    let mut frames = Vec::new();
    for r in records {
        let frame = (|| {
            if external.contains_key(&r.seq) {
                return Err(Skip::ExternalCamera);
            }
            let name = image_of(r)?;
            let intr = NerfIntrinsics::from(r.intrinsics.ok_or(Skip::NoIntrinsics)?);
            if !finite(&[intr.fl_x, intr.cx, intr.cy]) || intr.fl_x <= 0.0 {
                return Err(Skip::NoIntrinsics);
            }
            let p = &r.position;
            let m = camera_to_world_gl(&r.attitude, DVec3::new(p.east_m, p.north_m, p.up_m));
            if !m.is_finite() {
                let a = &r.attitude;
                let att_ok = finite(&[a.roll_deg, a.pitch_deg, a.yaw_deg, a.camera_pitch_deg]);
                return Err(if att_ok {
                    Skip::NoPosition
                } else {
                    Skip::NoAttitude
                });
            }
            let file_intr = *file_intr.get_or_insert(intr);
            Ok(NerfFrame {
                file_path: name.to_owned(),
                transform_matrix: rows(&m),
                intrinsics: (intr != file_intr).then_some(intr),
            })
        })();
        match frame {
            Ok(f) => frames.push(f),
            Err(s) => skipped.push((r.seq, s)),
        }
    }
    let t = file_intr.map(|intrinsics| NerfTransforms {
        camera_model: "OPENCV".into(),
        intrinsics,
        k1: 0.0,
        k2: 0.0,
        p1: 0.0,
        p2: 0.0,
        frames,
    });
    (t, skipped)
}

/// A COLMAP text model (`cameras.txt`, `images.txt`, `points3D.txt`): the frames of
/// `transforms.json`, with the same poses and intrinsics, for COLMAP's reconstruction
/// from known poses (`colmap point_triangulator --input_path FLIGHT_DIR`). One PINHOLE
/// camera per distinct intrinsics, numbered from 1 in the order they first appear; an
/// image per frame, numbered from 1 in capture order, its pose world-to-camera (COLMAP
/// and OpenCV axes: x right, y down, z along the optical axis) in the same local ENU
/// metres; no 3-D point (the triangulation makes them). Pixel coordinates are COLMAP's
/// and alfd's alike: the top-left pixel's centre is (0.5, 0.5), so the principal point
/// goes over as it is. Numbers are written in full (Rust's shortest round trip).
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapText {
    pub cameras: String,
    pub images: String,
    pub points: String,
}

/// The COLMAP text model of `t`'s frames ([`ColmapText`]).
pub fn colmap_text(t: &NerfTransforms) -> ColmapText {
    let mut intrinsics: Vec<NerfIntrinsics> = Vec::new();
    let mut images = String::new();
    for (k, f) in t.frames.iter().enumerate() {
        let intr = f.intrinsics.unwrap_or(t.intrinsics);
        let camera_id = match intrinsics.iter().position(|i| *i == intr) {
            Some(i) => i + 1,
            None => {
                intrinsics.push(intr);
                intrinsics.len()
            }
        };
        let m = f.transform_matrix;
        let c2w_gl = DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        );
        let centre = DVec3::new(m[0][3], m[1][3], m[2][3]);
        let world_to_cam = (c2w_gl * GL_TO_CV).transpose();
        let mut q = glam::DQuat::from_mat3(&world_to_cam).normalize();
        // q and −q are the same rotation: the one with w ≥ 0, so each pose has one text.
        if q.w < 0.0 {
            q = -q;
        }
        let t_cw = -(world_to_cam * centre);
        images.push_str(&format!(
            "{} {} {} {} {} {} {} {} {camera_id} {}\n\n",
            k + 1,
            q.w,
            q.x,
            q.y,
            q.z,
            t_cw.x,
            t_cw.y,
            t_cw.z,
            f.file_path
        ));
    }
    let mut cameras = format!(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: {}\n",
        intrinsics.len()
    );
    for (k, i) in intrinsics.iter().enumerate() {
        cameras.push_str(&format!(
            "{} PINHOLE {} {} {} {} {} {}\n",
            k + 1,
            i.w,
            i.h,
            i.fl_x,
            i.fl_y,
            i.cx,
            i.cy
        ));
    }
    let images = format!(
        "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: {}, mean observations per image: 0\n{images}",
        t.frames.len()
    );
    let points = "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n# Number of points: 0, mean track length: 0\n".to_owned();
    ColmapText {
        cameras,
        images,
        points,
    }
}

/// What [`write_exports`] wrote.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ExportSummary {
    pub geo_lines: usize,
    /// `None` when no record could go into `transforms.json` (then it is not written).
    pub transform_frames: Option<usize>,
    pub geo_skipped: Vec<(u64, Skip)>,
    pub transforms_skipped: Vec<(u64, Skip)>,
}

/// Writes `geo.txt` and (when any frame qualifies) `transforms.json` and the COLMAP
/// model of the same frames ([`colmap_text`]), each file atomically.
pub fn write_exports<S: CaptureStore + ?Sized>(
    store: &mut S,
    records: &[CaptureRecord],
) -> Result<ExportSummary, StoreError> {
    write_exports_with(store, records, &External::new())
}

/// [`write_exports`] with an external camera's pictures ([`geo_txt_with`]).
pub fn write_exports_with<S: CaptureStore + ?Sized>(
    store: &mut S,
    records: &[CaptureRecord],
    external: &External,
) -> Result<ExportSummary, StoreError> {
    let (geo, geo_skipped) = geo_txt_with(records, external);
    store.write_export(GEO_TXT, geo.as_bytes())?;
    let (t, transforms_skipped) = transforms_with(records, external);
    let transform_frames = match t {
        Some(t) => {
            let mut json =
                serde_json::to_string_pretty(&t).expect("finite numbers and strings serialise");
            json.push('\n');
            store.write_export(TRANSFORMS_JSON, json.as_bytes())?;
            let c = colmap_text(&t);
            store.write_export(COLMAP_CAMERAS, c.cameras.as_bytes())?;
            store.write_export(COLMAP_POINTS, c.points.as_bytes())?;
            // The images last: a model is read from its images.
            store.write_export(COLMAP_IMAGES, c.images.as_bytes())?;
            Some(t.frames.len())
        }
        None => None,
    };
    Ok(ExportSummary {
        geo_lines: geo.lines().count() - 1,
        transform_frames,
        geo_skipped,
        transforms_skipped,
    })
}

/// What [`export_flight`] found and wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightExport {
    pub records: usize,
    /// Bytes of a torn manifest line or telemetry entry cut (a stop mid-write).
    pub recovered_bytes: u64,
    /// Complete manifest lines that are not a record: (1-based line, error).
    pub bad_lines: Vec<(usize, String)>,
    pub exports: ExportSummary,
    /// Images the manifest lists that are not in the directory (left out of the
    /// exports, skipped as `no_image`).
    pub missing_images: Vec<String>,
    /// Captures an external camera took (`capture::external::is_external`): their
    /// pictures are on the camera's card, not here.
    pub external_captures: usize,
    /// `camera_command` captures, and of them those placed where the autopilot reported
    /// their picture (`picture_after_ms`), with the median time from decision to picture.
    pub commanded: usize,
    pub commanded_reported: usize,
    pub picture_after_median_ms: Option<f64>,
}

/// Why [`export_flight_with_camera`] wrote nothing.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("{}: {source}", dir.display())]
    Pair {
        dir: std::path::PathBuf,
        source: PairError,
    },
}

/// A flight directory's exports written from its manifest's complete lines, as
/// the daemon writes them at its stop: for a flight cut short (power lost, a
/// SIGKILL) that has its images and manifest and none. The directory is opened as
/// a restarted daemon opens it ([`DirStore::open`]: a torn tail cut, temporaries
/// removed, `InUse` while another process holds it); a path without a manifest is
/// an error, not made a flight directory.
pub fn export_flight(dir: &Path) -> Result<FlightExport, StoreError> {
    let (mut store, m) = open_flight(dir)?;
    write_flight(&mut store, dir, m, &External::new())
}

/// [`export_flight`], with an external camera's pictures (read from its card by
/// [`read_camera_dir`](super::external::read_camera_dir)) paired with the captures
/// it took and named on their `geo.txt` lines. Nothing is written when they
/// cannot be paired.
///
/// With `delay_s`, each paired picture is placed where the vehicle was that long after
/// its trigger ([`move_to_exposure`]).
pub fn export_flight_with_camera(
    dir: &Path,
    camera: &CameraDir,
    delay_s: Option<f64>,
) -> Result<(FlightExport, Pairing, Option<Moved>), ExportError> {
    let (mut store, mut m) = open_flight(dir)?;
    let triggers: Vec<Trigger> = m
        .records
        .iter()
        .filter(|r| is_external(r))
        .map(Trigger::of)
        .collect();
    let pairing = pair(&triggers, &camera.images).map_err(|source| ExportError::Pair {
        dir: camera.dir.clone(),
        source,
    })?;
    let external: External = pairing
        .pairs
        .iter()
        .map(|&(seq, i)| (seq, camera.images[i].name.clone()))
        .collect();
    // Only the exports see the moved places: the manifest keeps the triggers'.
    let moved = delay_s.map(|d| {
        let seqs: Vec<u64> = pairing.pairs.iter().map(|&(seq, _)| seq).collect();
        move_to_exposure(&mut m.records, &seqs, d)
    });
    Ok((write_flight(&mut store, dir, m, &external)?, pairing, moved))
}

fn open_flight(dir: &Path) -> Result<(DirStore, Manifest), StoreError> {
    let manifest = dir.join(MANIFEST);
    if !manifest.is_file() {
        return Err(StoreError::Io {
            path: manifest,
            source: std::io::ErrorKind::NotFound.into(),
        });
    }
    let store = DirStore::open(dir)?;
    let m = parse_manifest(&store.manifest_bytes()?);
    Ok((store, m))
}

fn write_flight(
    store: &mut DirStore,
    dir: &Path,
    m: Manifest,
    external: &External,
) -> Result<FlightExport, StoreError> {
    // The manifest lists an image only once it is in place; one missing since (a
    // card copied in part) is named, and left out of the exports as a capture
    // without an image: a reconstruction tool stops at a file it cannot open.
    let mut missing_images = Vec::new();
    let present: Vec<CaptureRecord> = m
        .records
        .iter()
        .cloned()
        .map(|mut r| {
            if let Some(name) = r.image.take_if(|name| !dir.join(name).is_file()) {
                missing_images.push(name);
            }
            r
        })
        .collect();
    let exports = write_exports_with(store, &present, external)?;
    let after = pictures_after_ms(&m.records);
    Ok(FlightExport {
        records: m.records.len(),
        recovered_bytes: store.recovered_bytes(),
        bad_lines: m.bad_lines,
        exports,
        missing_images,
        external_captures: m.records.iter().filter(|r| is_external(r)).count(),
        commanded: m
            .records
            .iter()
            .filter(|r| r.capture_mode == CaptureMode::CameraCommand)
            .count(),
        commanded_reported: after.len(),
        picture_after_median_ms: after.get(after.len() / 2).copied(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn att(roll: f64, pitch: f64, yaw: f64, cam: f64) -> Attitude {
        Attitude {
            roll_deg: roll,
            pitch_deg: pitch,
            yaw_deg: yaw,
            camera_pitch_deg: cam,
        }
    }

    fn assert_mat3(got: DMat3, want: [[f64; 3]; 3]) {
        let t = got.transpose();
        let got_rows = [
            t.x_axis.to_array(),
            t.y_axis.to_array(),
            t.z_axis.to_array(),
        ];
        for (g, w) in got_rows.iter().zip(&want) {
            for (a, b) in g.iter().zip(w) {
                assert!((a - b).abs() < 1e-12, "got {got_rows:?}, want {want:?}");
            }
        }
    }

    fn rot(m: &DMat4) -> DMat3 {
        DMat3::from_mat4(*m)
    }

    #[test]
    fn nadir_at_yaw_0_looks_down_with_image_right_to_north() {
        // Vehicle level, heading north, camera at nadir. OpenCV camera = FRD body:
        // CV x = forward = north, CV y = right = east, CV z = down.
        // GL x = CV x = north = ENU (0,1,0); GL y = −CV y = west = (−1,0,0);
        // GL z = −CV z = up = (0,0,1). Columns → rows:
        // [[0, −1, 0], [1, 0, 0], [0, 0, 1]].
        let m = camera_to_world_gl(&att(0.0, 0.0, 0.0, 0.0), DVec3::new(3.0, 4.0, 40.0));
        assert_mat3(
            rot(&m),
            [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        );
        // The camera looks along its −z: world down.
        let look = rot(&m) * DVec3::NEG_Z;
        assert!((look - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-12);
        assert_eq!(rows(&m)[0][3], 3.0);
        assert_eq!(rows(&m)[1][3], 4.0);
        assert_eq!(rows(&m)[2][3], 40.0);
        assert_eq!(rows(&m)[3], [0.0, 0.0, 0.0, 1.0]);
    }

    /// The COLMAP model projects every world point where `transforms.json` does: a nadir
    /// frame (by hand: the point below at the principal point, a metre north of it
    /// f/40 px to the right) and a tilted, rolled one with other intrinsics (its own camera).
    #[test]
    fn the_colmap_model_projects_as_transforms_json_does() {
        let intr = NerfIntrinsics {
            fl_x: 465.0,
            fl_y: 465.0,
            cx: 320.0,
            cy: 240.0,
            w: 640,
            h: 480,
        };
        let other = NerfIntrinsics {
            fl_x: 600.5,
            cx: 300.25,
            ..intr
        };
        let poses = [
            (att(0.0, 0.0, 0.0, 0.0), DVec3::new(10.0, -5.0, 40.0), None),
            (
                att(7.0, -4.0, 123.0, 30.0),
                DVec3::new(-3.0, 8.0, 55.0),
                Some(other),
            ),
        ];
        let t = NerfTransforms {
            camera_model: "OPENCV".into(),
            intrinsics: intr,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            frames: poses
                .iter()
                .enumerate()
                .map(|(k, (a, c, i))| NerfFrame {
                    file_path: format!("IMG_{:06}.jpg", k + 1),
                    transform_matrix: rows(&camera_to_world_gl(a, *c)),
                    intrinsics: *i,
                })
                .collect(),
        };
        let c = colmap_text(&t);
        let cams: Vec<Vec<f64>> = c
            .cameras
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| l.split(' ').skip(2).map(|x| x.parse().unwrap()).collect())
            .collect();
        assert_eq!(
            cams,
            [
                vec![640.0, 480.0, 465.0, 465.0, 320.0, 240.0],
                vec![640.0, 480.0, 600.5, 465.0, 300.25, 240.0]
            ]
        );
        let images: Vec<&str> = c.images.lines().filter(|l| !l.starts_with('#')).collect();
        // Two lines an image, the second (its 2-D points) empty.
        assert_eq!(images.len(), 4);
        assert!(images[1].is_empty() && images[3].is_empty());
        assert!(c.points.lines().all(|l| l.starts_with('#')));
        let colmap = |k: usize, x: DVec3| {
            let f: Vec<&str> = images[2 * k].split(' ').collect();
            assert_eq!(f[0], (k + 1).to_string());
            assert_eq!(f[9], format!("IMG_{:06}.jpg", k + 1));
            let n: Vec<f64> = f[1..8].iter().map(|x| x.parse().unwrap()).collect();
            let q = glam::DQuat::from_xyzw(n[1], n[2], n[3], n[0]);
            assert!(q.w >= 0.0 && (q.length() - 1.0).abs() < 1e-12);
            let xc = q * x + DVec3::new(n[4], n[5], n[6]);
            let cam = &cams[f[8].parse::<usize>().unwrap() - 1];
            (cam[2] * xc.x / xc.z + cam[4], cam[3] * xc.y / xc.z + cam[5])
        };
        let gl = |k: usize, x: DVec3| {
            let (a, c, i) = &poses[k];
            let i = i.unwrap_or(intr);
            let p = camera_to_world_gl(a, *c).inverse().transform_point3(x);
            (i.cx + i.fl_x * p.x / -p.z, i.cy - i.fl_y * p.y / -p.z)
        };
        let below = colmap(0, DVec3::new(10.0, -5.0, 0.0));
        assert!((below.0 - 320.0).abs() < 1e-9 && (below.1 - 240.0).abs() < 1e-9);
        let north = colmap(0, DVec3::new(10.0, -4.0, 0.0));
        assert!((north.0 - (320.0 + 465.0 / 40.0)).abs() < 1e-9 && (north.1 - 240.0).abs() < 1e-9);
        for k in 0..2 {
            for x in [
                DVec3::new(10.0, -5.0, 0.0),
                DVec3::new(14.0, 2.0, 3.5),
                DVec3::new(-6.0, 30.0, 10.0),
            ] {
                let (a, b) = (colmap(k, x), gl(k, x));
                assert!(
                    (a.0 - b.0).abs() < 1e-7 && (a.1 - b.1).abs() < 1e-7,
                    "frame {k}, {x}: {a:?} {b:?}"
                );
            }
        }
    }

    #[test]
    fn nadir_at_yaw_90_is_the_identity_rotation() {
        // Heading east: forward = east, right = south. GL x = east = (1,0,0);
        // GL y = −right = north = (0,1,0); GL z = up = (0,0,1): the identity.
        let m = camera_to_world_gl(&att(0.0, 0.0, 90.0, 0.0), DVec3::ZERO);
        assert_mat3(rot(&m), [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    }

    #[test]
    fn camera_pitch_30_tilts_the_view_forward() {
        // Heading north, camera pitched 30° forward. In FRD: optical axis CV z =
        // (sin30, 0, cos30) = (½, 0, √3/2); CV x = (cos30, 0, −sin30) = (√3/2, 0, −½);
        // CV y = (0,1,0). NED → ENU (e, n, u) = (y, x, −z):
        // GL x = CV x → (0, √3/2, ½); GL y = −CV y → (−1, 0, 0);
        // GL z = −CV z = (−½, 0, −√3/2) in FRD → (0, −½, √3/2).
        let s3 = 3f64.sqrt() / 2.0;
        let m = camera_to_world_gl(&att(0.0, 0.0, 0.0, 30.0), DVec3::ZERO);
        assert_mat3(rot(&m), [[0.0, -1.0, 0.0], [s3, 0.0, -0.5], [0.5, 0.0, s3]]);
        // It looks forward (north) and down, 30° off the vertical.
        let look = rot(&m) * DVec3::NEG_Z;
        assert!((look - DVec3::new(0.0, 0.5, -s3)).length() < 1e-12);
    }

    #[test]
    fn rolling_right_turns_the_nadir_view_to_the_left() {
        // Right wing down by 90° at yaw 0: Rx(90°) maps the body's down axis (0,0,1)
        // to (0, −sin 90°, cos 90°) = (0, −1, 0) in NED, i.e. west: the belly, and
        // the nadir camera with it, faces the left of the track.
        let m = camera_to_world_gl(&att(90.0, 0.0, 0.0, 0.0), DVec3::ZERO);
        let look = rot(&m) * DVec3::NEG_Z;
        assert!(
            (look - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-12,
            "{look}"
        );
    }

    #[test]
    fn odm_angles_for_a_nadir_camera_are_yaw_minus_90() {
        // At yaw 0 the image's top (−CV y) points west: ODM's "forward" is west.
        let (y, p, r) = odm_ypr_deg(&att(0.0, 0.0, 0.0, 0.0));
        assert!((y + 90.0).abs() < 1e-9 && p.abs() < 1e-9 && r.abs() < 1e-9);
        let (y, ..) = odm_ypr_deg(&att(0.0, 0.0, 135.0, 0.0));
        assert!((y - 45.0).abs() < 1e-9, "{y}");
    }

    proptest! {
        #[test]
        fn transforms_are_rigid(
            roll in -60.0f64..60.0, pitch in -60.0f64..60.0, yaw in -180.0f64..180.0,
            cam in -10.0f64..90.0,
            e in -1e3f64..1e3, n in -1e3f64..1e3, u in -10.0f64..200.0,
        ) {
            let m = camera_to_world_gl(&att(roll, pitch, yaw, cam), DVec3::new(e, n, u));
            let r = rot(&m);
            let rtr = r.transpose() * r;
            prop_assert!(rtr.abs_diff_eq(DMat3::IDENTITY, 1e-12), "{rtr}");
            prop_assert!((r.determinant() - 1.0).abs() < 1e-12);
            prop_assert_eq!(m.w_axis, DVec4::new(e, n, u, 1.0));
        }

        #[test]
        fn vehicle_pitch_adds_to_camera_pitch(pitch in -80.0f64..80.0, yaw in -180.0f64..180.0) {
            // Nose up by θ turns the belly forward by θ (Ry(θ)·(0,0,1) = (sin θ, 0, cos θ)),
            // as a forward camera pitch does: a camera pitched by −θ looks straight down.
            let m = camera_to_world_gl(&att(0.0, pitch, yaw, -pitch), DVec3::ZERO);
            let look = rot(&m) * DVec3::NEG_Z;
            prop_assert!((look - DVec3::NEG_Z).length() < 1e-12, "{}", look);
        }

        #[test]
        fn odm_angles_rebuild_the_camera_rotation(
            roll in -60.0f64..60.0, pitch in -60.0f64..60.0, yaw in -180.0f64..180.0,
            cam in 0.0f64..60.0,
        ) {
            let a = att(roll, pitch, yaw, cam);
            let (y, p, r) = odm_ypr_deg(&a);
            // ODM's cnb · cbb, as compute_opk builds it.
            let odm = body_to_ned(r.to_radians(), p.to_radians(), y.to_radians()) * ODM_CAMERA_TO_BODY;
            prop_assert!(odm.abs_diff_eq(camera_gl_to_ned(&a), 1e-9));
        }
    }
}
