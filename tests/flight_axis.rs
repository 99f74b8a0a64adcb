//! The estimator scans along the direction of flight projected into the image
//! (issue 14): a vehicle flying sideways (heading east, flying north) over the
//! same ground gets the spacing it gets flying forwards, because the pipeline
//! scans the image's rows then instead of its columns.

use alfd::capture::CaptureMode;
use alfd::core::attitude::flight_axis;
use alfd::core::geo::{Geodetic, LocalFrame};
use alfd::core::pose::Pose;
use alfd::core::trigger::TriggerParams;
use alfd::core::{DepthData, DepthImage, EstimatorParams, Intrinsics, Profile, Quality, TrackAxis};
use alfd::daemon::step::{FrameInput, Pipeline, StepOutcome, StepParams};
use alfd::render::render_depth;
use alfd::scene::Scene;
use alfd::source::synthetic::CameraPose;
use glam::{DMat3, DQuat, DVec3, EulerRot};
use std::path::Path;

/// The mapping profile's views per point alone (parallax and overlap out of
/// the way): the bound that depends on the direction the lines run.
fn pipeline() -> Pipeline {
    let est = EstimatorParams {
        score: None,
        quality: Quality {
            parallax_px: None,
            forward_overlap: Some(0.0),
            ..Profile::Mapping.targets()
        },
        overlap_min: 0.0,
        ..EstimatorParams::default()
    };
    let params = StepParams {
        camera_mount_pitch_rad: 0.0,
        frame_period_s: 1.0 / 30.0,
        capture_mode: CaptureMode::Frame,
        image_format: None,
        image_intrinsics: None,
    };
    let home = Geodetic {
        lat_deg: 47.0,
        lon_deg: 8.0,
        alt_m: 400.0,
    };
    Pipeline::new(est, TriggerParams::default(), params, LocalFrame::new(home))
}

/// The spacing the pipeline chooses at `north_m` along the canyon's survey
/// line, flying north at 5 m/s with heading `yaw_rad`.
fn spacing_at(p: &mut Pipeline, s: &Scene, north_m: f64, yaw_rad: f64) -> Option<f64> {
    let intr = Intrinsics::from_hfov_deg(96, 96, 69.0, None).unwrap();
    let alt = s.survey.altitude_m;
    let cam =
        CameraPose::on_vehicle([north_m, s.survey.y_m, alt], [0.0, 0.0, yaw_rad], 0.0).camera(intr);
    let depth = render_depth(s, &cam);
    let img = DepthImage::new(96, 96, DepthData::Metres(depth)).unwrap();
    let pose = Pose {
        time_ns: 0,
        pos_ned_m: DVec3::new(north_m, -s.survey.y_m, -alt),
        vel_ned_mps: DVec3::new(5.0, 0.0, 0.0),
        q: DQuat::from_euler(EulerRot::ZYX, yaw_rad, 0.0, 0.0),
        extrapolated_ns: 0,
    };
    let out = p.on_frame(FrameInput {
        mono_ns: (north_m * 1e8) as u64 + 1,
        depth: Some(&img),
        intrinsics: &intr,
        pose: Ok(pose),
        boot_us: Some(0),
        unix_us: None,
    });
    let e = match out {
        StepOutcome::Wait { estimate } | StepOutcome::Capture { estimate, .. } => estimate,
        StepOutcome::Suspended { reason } => panic!("suspended: {reason}"),
    };
    assert_eq!(e.active_bound.map(|b| b.as_str()), Some("views_per_point"));
    e.spacing.chosen_m
}

#[test]
fn sideways_flight_scans_the_image_rows_and_keeps_the_spacing() {
    let s = Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/canyon.toml")).unwrap();
    let (mut forwards, mut sideways) = (pipeline(), pipeline());
    let mut compared = 0;
    for k in 0..8 {
        let north_m = s.survey.start_x_m + 4.0 * k as f64;
        let f = spacing_at(&mut forwards, &s, north_m, 0.0).expect("forwards: a spacing");
        let g = spacing_at(&mut sideways, &s, north_m, 90f64.to_radians())
            .expect("sideways: a spacing");
        // The sideways picture is the forwards one turned a quarter: the same
        // samples, up to rounding in the renderer's rays.
        assert!(
            (f - g).abs() <= 1e-3 * f,
            "north {north_m}: forwards {f} m, sideways {g} m"
        );
        compared += 1;
    }
    assert_eq!(compared, 8);
}

#[test]
fn the_axis_follows_the_velocity_in_the_image() {
    let nadir = DMat3::IDENTITY;
    let v = |n: f64, e: f64| DVec3::new(n, e, 0.0);
    assert_eq!(
        flight_axis(&nadir, v(5.0, 0.0), TrackAxis::Columns).0,
        TrackAxis::Rows
    );
    assert_eq!(
        flight_axis(&nadir, v(-5.0, 0.0), TrackAxis::Columns).0,
        TrackAxis::Rows
    );
    assert_eq!(
        flight_axis(&nadir, v(0.0, 5.0), TrackAxis::Rows).0,
        TrackAxis::Columns
    );
    // Crabbing 30°: still nearer the columns' direction.
    assert_eq!(
        flight_axis(&nadir, v(5.0, 2.9), TrackAxis::Columns).0,
        TrackAxis::Rows
    );
    // Hovering: the configured axis.
    assert_eq!(
        flight_axis(&nadir, v(0.1, 0.2), TrackAxis::Columns).0,
        TrackAxis::Columns
    );
    // A camera tilted 20° forward: tilt 20° along the rows' lines, 0 across.
    let tilted = DMat3::from_rotation_y(20f64.to_radians());
    let (a, t) = flight_axis(&tilted, v(5.0, 0.0), TrackAxis::Rows);
    assert_eq!(a, TrackAxis::Rows);
    assert!((t - 20f64.to_radians()).abs() < 1e-12, "{t}");
    let (a, t) = flight_axis(&tilted, v(0.0, 5.0), TrackAxis::Rows);
    assert_eq!(a, TrackAxis::Columns);
    assert!(t.abs() < 1e-12, "{t}");
    // Looking at the horizon along the axis: 90°, which the estimator refuses.
    let level = DMat3::from_rotation_y(90f64.to_radians());
    let (_, t) = flight_axis(&level, v(5.0, 0.0), TrackAxis::Rows);
    assert!((t - 90f64.to_radians()).abs() < 1e-9, "{t}");
}
