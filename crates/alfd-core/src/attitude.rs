//! The camera's attitude geometry: body (FRD) to NED from the autopilot's Euler angles, the
//! camera mount's tilt, and the image axis nearest the direction of flight. Pure; the
//! exports (`capture::export`), the synthetic camera and the daemon's step share it.

use crate::depth::TrackAxis;
use glam::{DMat3, DVec3};

/// Vehicle body (FRD) → NED, from the autopilot's roll, pitch, yaw (ZYX, radians).
pub fn body_to_ned(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> DMat3 {
    DMat3::from_rotation_z(yaw_rad)
        * DMat3::from_rotation_y(pitch_rad)
        * DMat3::from_rotation_x(roll_rad)
}

/// OpenCV camera → body (FRD): a rotation by the camera pitch about the body's
/// right (y) axis, so the optical axis is (sin φ, 0, cos φ) and the image's x axis
/// (cos φ, 0, −sin φ).
pub fn camera_to_body(camera_pitch_rad: f64) -> DMat3 {
    DMat3::from_rotation_y(camera_pitch_rad)
}

/// Below this horizontal speed the direction of flight is noise: the
/// configured scan axis holds.
pub const FLIGHT_AXIS_SPEED_MIN_MPS: f64 = 0.5;

/// The image axis nearest the direction of flight (image columns run along
/// `Rows`' lines, image rows along `Columns`'), and the camera's tilt along
/// it: the angle of the optical axis from the vertical in the vertical plane of
/// that axis, positive towards the axis. Below
/// [`FLIGHT_AXIS_SPEED_MIN_MPS`], `fixed` holds. Pure.
pub fn flight_axis(cam_to_ned: &DMat3, vel_ned_mps: DVec3, fixed: TrackAxis) -> (TrackAxis, f64) {
    let horizontal = |v: DVec3| DVec3::new(v.x, v.y, 0.0);
    let v = horizontal(vel_ned_mps);
    // NaN speeds (never from the pose buffer, which refuses them) hold too.
    let moving = v.length() >= FLIGHT_AXIS_SPEED_MIN_MPS;
    let axis = if !moving {
        fixed
    } else if horizontal(cam_to_ned.x_axis).dot(v).abs()
        >= horizontal(cam_to_ned.y_axis).dot(v).abs()
    {
        TrackAxis::Rows
    } else {
        TrackAxis::Columns
    };
    let image_axis = match axis {
        TrackAxis::Rows => cam_to_ned.x_axis,
        TrackAxis::Columns => cam_to_ned.y_axis,
    };
    let a = horizontal(image_axis);
    let z = cam_to_ned.z_axis;
    let tilt = if a.length() < 1e-12 {
        // The image axis is vertical: the camera looks along the horizon.
        std::f64::consts::FRAC_PI_2
    } else {
        z.dot(a / a.length()).atan2(z.z)
    };
    (axis, tilt)
}
