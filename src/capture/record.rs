//! One capture as one manifest line: the typed record, its JSON-lines encoding and
//! decoding, and the image file name derived from the sequence number alone.
//! Pure: no I/O. Non-finite numbers are written as `null` and read back as NaN.

use crate::core::Estimate;
use serde::{Deserialize, Deserializer, Serialize};

/// How the picture was taken (DESIGN §2, capture modes).
/// The same names in the manifest (serde), the config and on the command line (clap).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum CaptureMode {
    /// alfd saved the frame itself; `image` names the file.
    Frame,
    /// alfd commanded an external camera (MAV_CMD_IMAGE_START_CAPTURE / DO_DIGICAM_CONTROL).
    CameraCommand,
    /// The autopilot's own distance trigger fired (CAMERA_TRIGGER feedback).
    AutopilotDistance,
    /// A ground station (or other allowed system) asked for it: IMAGE_START_CAPTURE or
    /// DO_DIGICAM_CONTROL; `requested_by` names the sender. Never a configured mode.
    #[value(skip)]
    Command,
}

/// Where the camera was, geodetic (WGS-84) and local ENU around the home point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Position {
    #[serde(deserialize_with = "nullable_f64")]
    pub lat_deg: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub lon_deg: f64,
    /// Altitude above mean sea level, metres.
    #[serde(deserialize_with = "nullable_f64")]
    pub alt_m: f64,
    /// Altitude above the home point, metres.
    #[serde(deserialize_with = "nullable_f64")]
    pub rel_alt_m: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub east_m: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub north_m: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub up_m: f64,
}

/// Vehicle attitude as the autopilot reports it (NED, ZYX Euler angles, degrees),
/// plus the camera's tilt relative to the vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Attitude {
    #[serde(deserialize_with = "nullable_f64")]
    pub roll_deg: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub pitch_deg: f64,
    /// Heading from true north, clockwise.
    #[serde(deserialize_with = "nullable_f64")]
    pub yaw_deg: f64,
    /// Camera tilt about the vehicle's right axis: 0 = nadir, positive = forward.
    #[serde(deserialize_with = "nullable_f64")]
    pub camera_pitch_deg: f64,
}

/// The spacing decision in force at the capture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spacing {
    /// The permissible spacing from the estimator, or `None` when there was none
    /// (no estimate yet, stale pose: the trigger's fallback spacing held).
    pub permissible_m: Option<f64>,
    /// The spacing the trigger applied (≥ permissible when rate-limited).
    #[serde(deserialize_with = "nullable_f64")]
    pub chosen_m: f64,
    /// Which bound set the permissible spacing (`mmds`, `occlusion`, `coverage`, ...).
    pub active_bound: String,
}

/// Occlusion estimate of the frame the spacing came from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Occlusion {
    /// ρ, occlusion degree per metre of baseline (1/m).
    #[serde(deserialize_with = "nullable_f64")]
    pub density_per_m: f64,
    /// O(b) at the chosen spacing (fraction of the field of view's rays, 0..1).
    #[serde(deserialize_with = "nullable_f64")]
    pub degree: f64,
}

/// The quality targets in force (`[quality]`); a target not in force is `null`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualityTargets {
    /// `lightfield` or `mapping`: where the defaults came from.
    pub profile: String,
    pub parallax_px: Option<f64>,
    pub forward_overlap: Option<f64>,
    pub unseen_fraction_max: f64,
    pub views_per_point_min: u32,
}

/// Each target's value predicted at a spacing from the frame's live depth
/// (`null`: the frame cannot say, e.g. no surface in view).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualityValues {
    pub parallax_px: Option<f64>,
    pub forward_overlap: Option<f64>,
    pub unseen_fraction: Option<f64>,
    pub views_per_point: Option<u32>,
}

/// The largest spacing meeting each target alone, m (`null`: not in force, or
/// nothing in view bounds it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualitySpacingM {
    pub parallax: Option<f64>,
    pub forward_overlap: Option<f64>,
    pub unseen_fraction: Option<f64>,
    pub views_per_point: Option<f64>,
}

/// What the quality model decided: the targets, each one's own spacing, and
/// the values predicted at the spacing in force. Which target bound is
/// `spacing.active_bound`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualityRecord {
    pub targets: QualityTargets,
    pub spacing_m: QualitySpacingM,
    pub predicted: QualityValues,
}

impl QualityRecord {
    /// From an estimate of the quality model, with the predictions taken at
    /// `spacing_m` (the trigger's, which the rate limit may hold above the
    /// estimate's own); `None` for other models.
    pub fn from_estimate(e: &Estimate, spacing_m: f64) -> Option<QualityRecord> {
        let q = e.quality?;
        let t = q.targets;
        let p = if e.spacing.chosen_m == Some(spacing_m) {
            q
        } else {
            e.predict_at(spacing_m).unwrap_or(q)
        };
        let s = &e.spacing;
        Some(QualityRecord {
            targets: QualityTargets {
                profile: t.profile.as_str().to_string(),
                parallax_px: t.parallax_px,
                forward_overlap: t.forward_overlap,
                unseen_fraction_max: t.unseen_fraction_max,
                views_per_point_min: t.views_per_point_min,
            },
            spacing_m: QualitySpacingM {
                parallax: s.parallax_m,
                forward_overlap: s.forward_overlap_m,
                unseen_fraction: s.unseen_m,
                views_per_point: s.views_m,
            },
            predicted: QualityValues {
                parallax_px: p.parallax_px,
                forward_overlap: p.forward_overlap,
                unseen_fraction: p.unseen_fraction,
                views_per_point: p.views_per_point,
            },
        })
    }
}

/// The closed loop's measurement against the previous capture at the frame
/// that captured (`[trigger] closed_loop`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClosedLoopRecord {
    /// Distance since the previous capture as the odometer measured it, m.
    pub distance_m: f64,
    /// Disparity span against the previous capture, px (rotation taken out).
    pub parallax_px: Option<f64>,
    /// Unseen fraction of the frame nearest the middle of the interval.
    pub unseen_fraction: f64,
    /// Fraction of this frame's surface inside the previous capture's frame.
    pub in_view_fraction: f64,
    /// The spacing the closed loop allowed (`null`: no target near).
    pub spacing_m: Option<f64>,
    /// `parallax` or `unseen_fraction`, when `spacing_m` is set.
    pub bound: Option<String>,
}

/// Pinhole intrinsics of the captured image (pixels), as the exports need them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraIntrinsics {
    pub width: u32,
    pub height: u32,
    #[serde(deserialize_with = "nullable_f64")]
    pub focal_px: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub cx_px: f64,
    #[serde(deserialize_with = "nullable_f64")]
    pub cy_px: f64,
}

/// One capture: one line of `manifest.jsonl` (schema in docs/capture-log.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureRecord {
    /// Capture sequence number, from 1, increasing by one per capture.
    pub seq: u64,
    /// Image file name in the flight directory (`IMG_000123.jpg`), derived from
    /// `seq` only; `None` when an external camera or the autopilot took the picture.
    pub image: Option<String>,
    /// Autopilot boot clock at the time of validity, microseconds.
    pub time_boot_us: u64,
    /// UNIX time at the time of validity, microseconds; `None` while unknown.
    pub time_unix_us: Option<u64>,
    /// Companion monotonic clock (CLOCK_MONOTONIC) at the frame's time of validity, ns.
    pub mono_ns: u64,
    pub position: Position,
    pub attitude: Attitude,
    pub spacing: Spacing,
    /// Distance travelled since the previous capture (m); `None` for the first.
    pub distance_since_last_m: Option<f64>,
    /// `None` when the occlusion term was not computed for this capture.
    pub occlusion: Option<Occlusion>,
    /// Terms the estimator computed (`parallax`, `visibility`, `views`, `mmds`, ...).
    pub terms: Vec<String>,
    /// The quality model's targets, per-target spacings and predictions at
    /// `spacing.chosen_m`; `None` for the other models or without an estimate.
    pub quality: Option<QualityRecord>,
    /// The closed loop's measurement (`None`: off, or the first capture).
    pub closed_loop: Option<ClosedLoopRecord>,
    /// Sampling model in force (`occlusion`, `mmds`, `sspa`, `fixed`).
    pub model: String,
    pub capture_mode: CaptureMode,
    /// The rate limit held the spacing above the permissible one.
    pub undersampled: bool,
    /// The capture came at the rate limit rather than at the spacing.
    pub rate_limited: bool,
    /// The fallback spacing was used (no fresh estimate).
    pub fallback: bool,
    /// Age of the newest pose sample at the time of validity (ms; extrapolation horizon).
    #[serde(deserialize_with = "nullable_f64")]
    pub pose_age_ms: f64,
    /// `None` when alfd does not know the camera (autopilot-triggered captures).
    pub intrinsics: Option<CameraIntrinsics>,
    /// `[system_id, component_id]` of the sender of the command that asked for the capture
    /// (`command` captures, and the autopilot's IMAGE_START_CAPTURE in `autopilot_distance`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub requested_by: Option<[u8; 2]>,
    /// Why a capture that was to save a frame names no image (no frame in time, the
    /// writer behind, encoding failed); the ground station got a failed
    /// CAMERA_IMAGE_CAPTURED for it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image_missing: Option<String>,
    /// `camera_command`: how long after the capture was decided the autopilot reported taking
    /// its picture (CAMERA_TRIGGER, CAMERA_FEEDBACK), ms; the line's times and pose are then
    /// the picture's. Absent: another mode, or no report came (the decision's instant).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub picture_after_ms: Option<f64>,
}

/// Image encodings of saved frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    Png,
    /// Baseline JPEG, quality 1..=100.
    Jpeg {
        quality: u8,
    },
}

impl ImageFormat {
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Jpeg { .. } => "jpg",
        }
    }
}

/// The `picture_after_ms` of the records that have one (the `camera_command` captures the
/// autopilot's report placed), in increasing order.
pub fn pictures_after_ms(records: &[CaptureRecord]) -> Vec<f64> {
    let mut after: Vec<f64> = records.iter().filter_map(|r| r.picture_after_ms).collect();
    after.sort_by(f64::total_cmp);
    after
}

/// The file name of capture `seq`: `IMG_000123.jpg` (six digits at least).
pub fn image_file_name(seq: u64, format: ImageFormat) -> String {
    format!("IMG_{seq:06}.{}", format.extension())
}

/// Whether `name` is one that [`image_file_name`] makes for `seq`: the guard that
/// keeps a corrupt or hand-edited manifest from steering writes or exports.
pub fn is_image_name_for(name: &str, seq: u64) -> bool {
    [ImageFormat::Png, ImageFormat::Jpeg { quality: 0 }]
        .iter()
        .any(|&f| name == image_file_name(seq, f))
}

impl CaptureRecord {
    /// One JSON object on one line, without the trailing newline. JSON has no NaN or
    /// infinity: non-finite numbers are written as `null` (serde_json's behaviour,
    /// pinned by a test) and read back as NaN by [`CaptureRecord::from_json_line`]
    /// (or as `None` where the field is optional).
    pub fn to_json_line(&self) -> String {
        // Serialising plain structs of numbers, strings and bools cannot fail, and
        // serde_json escapes control characters, so the line holds no raw newline.
        serde_json::to_string(self).expect("a CaptureRecord always serialises")
    }

    pub fn from_json_line(line: &str) -> Result<CaptureRecord, serde_json::Error> {
        serde_json::from_str(line)
    }
}

/// `null` (what a non-finite number became on write) reads back as NaN.
fn nullable_f64<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn sample(seq: u64) -> CaptureRecord {
        CaptureRecord {
            seq,
            image: Some(image_file_name(seq, ImageFormat::Jpeg { quality: 90 })),
            time_boot_us: 120_000_000 + seq * 250_000,
            time_unix_us: Some(1_780_000_000_000_000 + seq * 250_000),
            mono_ns: 5_000_000_000 + seq * 250_000_000,
            position: Position {
                lat_deg: 47.397_742 + seq as f64 * 1e-5,
                lon_deg: 8.545_594,
                alt_m: 488.0 + 40.0,
                rel_alt_m: 40.0,
                east_m: 0.0,
                north_m: seq as f64 * 1.1,
                up_m: 40.0,
            },
            attitude: Attitude {
                roll_deg: 1.5,
                pitch_deg: -2.0,
                yaw_deg: 0.5,
                camera_pitch_deg: 0.0,
            },
            spacing: Spacing {
                permissible_m: Some(1.2),
                chosen_m: 1.2,
                active_bound: "occlusion".into(),
            },
            distance_since_last_m: (seq > 1).then_some(1.1),
            occlusion: Some(Occlusion {
                density_per_m: 0.008,
                degree: 0.0096,
            }),
            terms: vec!["mmds".into(), "occlusion".into(), "coverage".into()],
            quality: None,
            closed_loop: None,
            model: "occlusion".into(),
            capture_mode: CaptureMode::Frame,
            undersampled: false,
            rate_limited: false,
            fallback: false,
            pose_age_ms: 42.0,
            intrinsics: Some(CameraIntrinsics {
                width: 64,
                height: 48,
                focal_px: 46.5,
                cx_px: 32.0,
                cy_px: 24.0,
            }),
            requested_by: None,
            image_missing: None,
            picture_after_ms: None,
        }
    }

    #[test]
    fn round_trips_through_one_line() {
        let r = sample(7);
        let line = r.to_json_line();
        assert!(!line.contains('\n'));
        assert!(line.contains(r#""image":"IMG_000007.jpg""#), "{line}");
        assert!(line.contains(r#""capture_mode":"frame""#), "{line}");
        assert_eq!(CaptureRecord::from_json_line(&line).unwrap(), r);
    }

    #[test]
    fn non_finite_numbers_become_null_and_read_back_as_nan_or_none() {
        let mut r = sample(2);
        r.position.alt_m = f64::NAN;
        r.pose_age_ms = f64::INFINITY;
        r.distance_since_last_m = Some(f64::NEG_INFINITY);
        r.model = "line\nbreak".into();
        let line = r.to_json_line();
        assert!(!line.contains('\n'), "{line}");
        assert!(!line.contains("NaN") && !line.contains("inf"), "{line}");
        assert!(line.contains(r#""alt_m":null"#), "{line}");
        assert!(line.contains(r#""pose_age_ms":null"#), "{line}");
        let back = CaptureRecord::from_json_line(&line).unwrap();
        assert!(back.position.alt_m.is_nan());
        assert!(back.pose_age_ms.is_nan());
        assert_eq!(back.distance_since_last_m, None);
        assert_eq!(back.model, "line\nbreak");
    }

    #[test]
    fn unknown_fields_are_refused() {
        let line = sample(1).to_json_line();
        let extra = line.replacen('{', r#"{"surprise":1,"#, 1);
        assert!(CaptureRecord::from_json_line(&extra).is_err());
        let nested = line.replacen(r#""roll_deg""#, r#""yaw_rate":0,"roll_deg""#, 1);
        assert!(CaptureRecord::from_json_line(&nested).is_err());
    }

    #[test]
    fn image_names_come_from_the_sequence_number() {
        assert_eq!(image_file_name(123, ImageFormat::Png), "IMG_000123.png");
        assert_eq!(
            image_file_name(1_234_567, ImageFormat::Jpeg { quality: 80 }),
            "IMG_1234567.jpg"
        );
        assert!(is_image_name_for("IMG_000123.jpg", 123));
        assert!(!is_image_name_for("IMG_000124.jpg", 123));
        assert!(!is_image_name_for("../IMG_000123.jpg", 123));
    }
}
