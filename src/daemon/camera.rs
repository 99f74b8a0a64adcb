//! The MAVLink camera protocol (v2) as alfd answers it, pure: commands in, messages out, time
//! passed in. Owns the image count (newest image index + 1), a ring of the last
//! CAMERA_IMAGE_CAPTURED messages a GCS may re-request, and the capture commands accepted
//! but not yet taken by the coordinator (which schedules them). Every message built here is
//! on the send allow-list (`crate::core::allowlist`).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU16, Ordering};

use crate::core::allowlist::{may_obey, Trust};
use glam::DQuat;
use mavlink::dialects::ardupilotmega::{
    CameraCapFlags, CameraMode, MavBool, MavCmd, MavMessage, MavResult, MavSeverity, StorageStatus,
    StorageType, StorageUsageFlag, CAMERA_CAPTURE_STATUS_DATA, CAMERA_IMAGE_CAPTURED_DATA,
    CAMERA_INFORMATION_DATA, CAMERA_SETTINGS_DATA, COMMAND_ACK_DATA, NAMED_VALUE_FLOAT_DATA,
    STATUSTEXT_DATA, STORAGE_INFORMATION_DATA,
};

/// CAMERA_IMAGE_CAPTURED messages kept for re-requests (about 16 KiB).
pub const CAPTURED_RING: usize = 64;
/// STATUSTEXT text field length (bytes).
pub const STATUSTEXT_CHUNK: usize = 50;
/// At most this many STATUSTEXT messages per text; longer texts end in "…".
pub const STATUSTEXT_MAX_CHUNKS: usize = 4;
/// NAMED_VALUE_FLOAT names: permissible spacing (m) and occlusion degree.
pub const NAME_SPACING: &str = "ALF_SPC";
pub const NAME_OCCLUSION: &str = "ALF_OCC";

const ELLIPSIS: &str = "…";
const MSG_CAMERA_INFORMATION: u32 = 259;
const MSG_CAMERA_SETTINGS: u32 = 260;
const MSG_STORAGE_INFORMATION: u32 = 261;
const MSG_CAMERA_CAPTURE_STATUS: u32 = 262;
const MSG_CAMERA_IMAGE_CAPTURED: u32 = 263;
/// alfd's one storage: the capture directory.
const STORAGE_ID: u8 = 1;

/// What CAMERA_INFORMATION says about the camera. Unknown optics are NaN and unknown
/// resolutions 0, as the message defines.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraInfo {
    /// At most 31 bytes are sent (cut on a char boundary, NUL-terminated).
    pub vendor: String,
    pub model: String,
    /// `(dev << 24) | (patch << 16) | (minor << 8) | major`.
    pub firmware_version: u32,
    pub focal_length_mm: f32,
    pub sensor_size_h_mm: f32,
    pub sensor_size_v_mm: f32,
    pub resolution_h: u16,
    pub resolution_v: u16,
}

impl CameraInfo {
    /// alfd as a still camera of the given image size (0 if unknown), firmware version from
    /// the crate version, optics unknown.
    pub fn for_alfd(resolution_h: u16, resolution_v: u16) -> Self {
        let part = |s: &str| s.parse::<u32>().unwrap_or(0) & 0xff;
        CameraInfo {
            vendor: "alfd".into(),
            model: "light-field trigger".into(),
            firmware_version: part(env!("CARGO_PKG_VERSION_MAJOR"))
                | part(env!("CARGO_PKG_VERSION_MINOR")) << 8
                | part(env!("CARGO_PKG_VERSION_PATCH")) << 16,
            focal_length_mm: f32::NAN,
            sensor_size_h_mm: f32::NAN,
            sensor_size_v_mm: f32::NAN,
            resolution_h,
            resolution_v,
        }
    }
}

impl Default for CameraInfo {
    fn default() -> Self {
        Self::for_alfd(0, 0)
    }
}

/// The capture directory's storage, in MiB (MAVLink's unit). Capacities are ignored by the
/// GCS unless `status` is READY; non-finite values are sent as 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StorageState {
    pub total_mib: f32,
    pub used_mib: f32,
    pub available_mib: f32,
    pub status: StorageStatus,
}

impl StorageState {
    /// A ready storage from byte counts (e.g. `statvfs` of the capture directory).
    pub fn from_bytes(total_bytes: u64, available_bytes: u64) -> Self {
        const MIB: f64 = 1024.0 * 1024.0;
        let available = available_bytes.min(total_bytes);
        let used_mib = ((total_bytes - available) as f64 / MIB) as f32;
        let available_mib = (available as f64 / MIB) as f32;
        // Rounded to f32 apart, the parts could sum past the total (a GCS adds them in
        // double precision): the total is raised to the next f32 that holds them.
        let mut total_mib = (total_bytes as f64 / MIB) as f32;
        while f64::from(used_mib) + f64::from(available_mib) > f64::from(total_mib) {
            total_mib = f32::from_bits(total_mib.to_bits() + 1);
        }
        StorageState {
            total_mib,
            used_mib,
            available_mib,
            status: StorageStatus::STORAGE_STATUS_READY,
        }
    }

    /// A ready storage of which only the free space is known: counted as its total too
    /// (nothing known used), so total ≥ used + available still holds for the GCS.
    pub fn from_free_bytes(available_bytes: u64) -> Self {
        Self::from_bytes(available_bytes, available_bytes)
    }
}

impl Default for StorageState {
    /// Nothing known yet: "does not supply storage status information".
    fn default() -> Self {
        StorageState {
            total_mib: 0.0,
            used_mib: 0.0,
            available_mib: 0.0,
            status: StorageStatus::STORAGE_STATUS_NOT_SUPPORTED,
        }
    }
}

/// Whether alfd's own trigger is running, for CAMERA_CAPTURE_STATUS.image_status.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CaptureActivity {
    pub active: bool,
    /// A nominal interval between captures (s), if there is one; alfd triggers on distance,
    /// so usually `None`.
    pub image_interval_s: Option<f32>,
}

/// A capture command accepted from an allowed system, for the coordinator to schedule
/// (it owns time and the capture numbering; the protocol only validates and answers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CaptureCommand {
    /// IMAGE_START_CAPTURE or DO_DIGICAM_CONTROL: `count` images (0: until stopped),
    /// `interval_s` apart, the first at the next frame.
    Start {
        /// Requester's system and component ids.
        from: (u8, u8),
        /// 0 for a single capture.
        interval_s: f32,
        count: u32,
        /// IMAGE_START_CAPTURE's param4 on a single capture, when the sender numbers them.
        sequence: Option<u32>,
        /// MAV_CMD_IMAGE_START_CAPTURE or MAV_CMD_DO_DIGICAM_CONTROL.
        command: MavCmd,
    },
    /// IMAGE_STOP_CAPTURE: end the running interval capture.
    Stop { from: (u8, u8) },
}

/// One capture as CAMERA_IMAGE_CAPTURED reports it; independent of alfd's capture record.
#[derive(Clone, Debug, PartialEq)]
pub struct Captured {
    /// Autopilot boot clock at the capture's time of validity.
    pub time_boot_ms: u32,
    pub time_unix_us: Option<u64>,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Altitude above mean sea level.
    pub alt_m: f64,
    /// Altitude above the home point (the message's "above ground").
    pub rel_alt_m: f64,
    /// Camera → NED, `[w, x, y, z]`, from [`camera_q_ned`]. Not finite or zero (the attitude
    /// is unknown): sent as `[NaN, 0, 0, 0]`, MAVLink's "quaternion unknown".
    pub q_camera_ned: [f32; 4],
    /// The image file's name, alfd's own (never anything received); sent empty when longer
    /// than 205 bytes or containing NUL rather than cut into a wrong name.
    pub file_name: Option<String>,
    /// 0-based and contiguous over the camera's life: a GCS detects a lost message by a gap
    /// and re-requests it, so a failed capture is reported too (with `success: false`).
    pub image_index: i32,
    /// CAMERA_IMAGE_CAPTURED.capture_result.
    pub success: bool,
}

/// Camera orientation for CAMERA_IMAGE_CAPTURED.q: the rotation camera → NED, `[w, x, y, z]`.
///
/// Camera frame as in `crate::capture::export`: OpenCV axes (x right in the image, y down,
/// z the optical axis), equal to the vehicle's FRD body frame at camera pitch 0, so a nadir
/// camera's optical axis is body down and the image's x axis body forward. A forward camera
/// pitch φ rotates it about the body's right (y) axis: optical axis (sin φ, 0, cos φ) in body.
/// Body → NED by the autopilot's ZYX Euler angles. `None` if any angle is not finite.
pub fn camera_q_ned(
    roll_rad: f64,
    pitch_rad: f64,
    yaw_rad: f64,
    camera_pitch_rad: f64,
) -> Option<[f32; 4]> {
    if ![roll_rad, pitch_rad, yaw_rad, camera_pitch_rad]
        .iter()
        .all(|a| a.is_finite())
    {
        return None;
    }
    let q = DQuat::from_rotation_z(yaw_rad)
        * DQuat::from_rotation_y(pitch_rad)
        * DQuat::from_rotation_x(roll_rad)
        * DQuat::from_rotation_y(camera_pitch_rad);
    let q = q.normalize();
    Some([q.w as f32, q.x as f32, q.y as f32, q.z as f32])
}

/// alfd's side of the camera protocol. One per camera component; the task that owns the
/// link's command events owns it.
#[derive(Clone, Debug)]
pub struct CameraProtocol {
    info: CameraInfo,
    storage: StorageState,
    activity: CaptureActivity,
    /// Newest image index + 1 (CAMERA_CAPTURE_STATUS.image_count).
    image_count: i32,
    /// The last [`CAPTURED_RING`] captures, oldest first.
    captured: VecDeque<CAMERA_IMAGE_CAPTURED_DATA>,
    /// Capture commands accepted since the coordinator last took them (bounded: a sender
    /// flooding commands faster than the coordinator drains is refused, see `on_command`).
    commands: VecDeque<CaptureCommand>,
    /// The last single-capture sequence number per requester: a retransmitted command
    /// (same number, its ACK lost) is acknowledged again but not taken twice.
    last_sequence: Option<((u8, u8), u32)>,
}

/// Capture commands kept for the coordinator; beyond, TEMPORARILY_REJECTED.
pub const PENDING_COMMANDS: usize = 64;

impl CameraProtocol {
    pub fn new(info: CameraInfo) -> Self {
        CameraProtocol {
            info,
            storage: StorageState::default(),
            activity: CaptureActivity::default(),
            image_count: 0,
            captured: VecDeque::with_capacity(CAPTURED_RING),
            commands: VecDeque::new(),
            last_sequence: None,
        }
    }

    /// The capture commands accepted since the last call, oldest first.
    pub fn take_capture_commands(&mut self) -> Vec<CaptureCommand> {
        self.commands.drain(..).collect()
    }

    pub fn activity(&self) -> CaptureActivity {
        self.activity
    }

    pub fn info(&self) -> &CameraInfo {
        &self.info
    }

    /// Newest image index + 1 (CAMERA_CAPTURE_STATUS.image_count).
    pub fn image_count(&self) -> i32 {
        self.image_count
    }

    /// The last capture's message, if any.
    pub fn last_captured(&self) -> Option<&CAMERA_IMAGE_CAPTURED_DATA> {
        self.captured.back()
    }

    pub fn set_storage(&mut self, s: StorageState) {
        self.storage = s;
    }

    pub fn set_activity(&mut self, a: CaptureActivity) {
        self.activity = a;
    }

    /// Answer a COMMAND_LONG addressed to us: a COMMAND_ACK to the sender, then the requested
    /// message when the ACK is ACCEPTED and the command asks for one.
    ///
    /// A sender outside `accept_system_ids` (`Trust::Foreign`) is answered the read-only
    /// requests like anyone else; any other command from it is DENIED
    /// (`crate::core::allowlist::may_obey`), never ignored, so its ground station says why.
    ///
    /// Requests (REQUEST_MESSAGE 259–263 and the legacy 521/522/525/527/2002) are served;
    /// SET_CAMERA_MODE accepts image mode only. IMAGE_START_CAPTURE (a single image, a count
    /// or until stopped, at an interval), IMAGE_STOP_CAPTURE and DO_DIGICAM_CONTROL (shoot) are
    /// captures: ACCEPTED and queued as [`CaptureCommand`]s for the coordinator, which takes
    /// them at the next frame (the CAMERA_IMAGE_CAPTURED follows). Parameters the camera cannot
    /// honour (an endless or multi-image capture without an interval, a non-integer count)
    /// are DENIED. STORAGE_FORMAT is DENIED: alfd never erases captures on request. Other
    /// commands: UNSUPPORTED. A command id outside the dialect cannot be named in an ACK, so it
    /// gets nothing (the link cannot decode such a COMMAND_LONG anyway).
    pub fn on_command(
        &mut self,
        cmd: u32,
        params: [f32; 7],
        from_system: u8,
        from_component: u8,
        trust: Trust,
        time_boot_ms: u32,
    ) -> Vec<MavMessage> {
        let Some(command) = mav_cmd(cmd) else {
            return Vec::new();
        };
        let (result, reply) = if may_obey(cmd, trust) {
            match self.capture_command(command, &params, (from_system, from_component)) {
                Some(r) => (r, None),
                None => self.answer(command, &params, time_boot_ms),
            }
        } else {
            denied()
        };
        let mut out = Vec::with_capacity(2);
        out.push(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command,
            result,
            progress: 0,
            result_param2: 0,
            target_system: from_system,
            target_component: from_component,
        }));
        out.extend(reply);
        out
    }

    /// The capture commands' answer (`None`: not a capture command), queueing what is accepted.
    fn capture_command(
        &mut self,
        command: MavCmd,
        p: &[f32; 7],
        from: (u8, u8),
    ) -> Option<MavResult> {
        let start = |interval_s: f32, count: u32, sequence: Option<u32>| CaptureCommand::Start {
            from,
            interval_s,
            count,
            sequence,
            command,
        };
        let queued = match command {
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE => {
                // param2 interval (s), param3 total images (0: until stopped), param4 the
                // sender's sequence number of a single capture (0: none).
                let interval_s = if p[1].is_nan() { 0.0 } else { p[1] };
                let Some(count) = as_index(p[2]) else {
                    return Some(MavResult::MAV_RESULT_DENIED);
                };
                if !(interval_s.is_finite() && interval_s >= 0.0)
                    || (count != 1 && interval_s == 0.0)
                {
                    return Some(MavResult::MAV_RESULT_DENIED);
                }
                let sequence = as_index(p[3]).filter(|s| *s > 0 && count == 1);
                if let Some(seq) = sequence {
                    if self.last_sequence == Some((from, seq)) {
                        // A retransmission: the capture is already taken or queued.
                        return Some(MavResult::MAV_RESULT_ACCEPTED);
                    }
                    self.last_sequence = Some((from, seq));
                }
                start(if count == 1 { 0.0 } else { interval_s }, count, sequence)
            }
            MavCmd::MAV_CMD_IMAGE_STOP_CAPTURE => CaptureCommand::Stop { from },
            // param5 1: shoot; the rest (zoom, focus, session) alfd has no use for.
            MavCmd::MAV_CMD_DO_DIGICAM_CONTROL => {
                if p[4] != 1.0 {
                    return Some(MavResult::MAV_RESULT_DENIED);
                }
                start(0.0, 1, None)
            }
            _ => return None,
        };
        if self.commands.len() >= PENDING_COMMANDS {
            return Some(MavResult::MAV_RESULT_TEMPORARILY_REJECTED);
        }
        self.commands.push_back(queued);
        Some(MavResult::MAV_RESULT_ACCEPTED)
    }

    // The legacy request commands are deprecated in the dialect, yet the protocol's migration
    // notes ask cameras to keep answering them for GCSes that still send them.
    #[allow(deprecated)]
    fn answer(
        &self,
        command: MavCmd,
        p: &[f32; 7],
        now_ms: u32,
    ) -> (MavResult, Option<MavMessage>) {
        use MavCmd::*;
        match command {
            MAV_CMD_REQUEST_MESSAGE => match as_index(p[0]) {
                Some(id) => self.request_message(id, p[1], now_ms),
                None => denied(),
            },
            // Legacy requests: their "0: no action" param is ignored, every GCS sets 1.
            MAV_CMD_REQUEST_CAMERA_INFORMATION => accepted(self.camera_information(now_ms)),
            MAV_CMD_REQUEST_CAMERA_SETTINGS => accepted(self.camera_settings(now_ms)),
            MAV_CMD_REQUEST_STORAGE_INFORMATION => self.storage_request(p[0], now_ms),
            MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS => accepted(self.capture_status(now_ms)),
            MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE => self.resend(p[0]),
            // param1 is the target camera id in newer revisions: param2 holds the mode.
            MAV_CMD_SET_CAMERA_MODE => {
                if p[1] == CameraMode::CAMERA_MODE_IMAGE as u32 as f32 {
                    (MavResult::MAV_RESULT_ACCEPTED, None)
                } else {
                    denied()
                }
            }
            MAV_CMD_STORAGE_FORMAT => denied(),
            _ => (MavResult::MAV_RESULT_UNSUPPORTED, None),
        }
    }

    /// MAV_CMD_REQUEST_MESSAGE: messages alfd does not serve are DENIED (the command is
    /// supported, the parameter is not).
    fn request_message(
        &self,
        msg_id: u32,
        param2: f32,
        now_ms: u32,
    ) -> (MavResult, Option<MavMessage>) {
        match msg_id {
            MSG_CAMERA_INFORMATION => accepted(self.camera_information(now_ms)),
            MSG_CAMERA_SETTINGS => accepted(self.camera_settings(now_ms)),
            MSG_STORAGE_INFORMATION => self.storage_request(param2, now_ms),
            MSG_CAMERA_CAPTURE_STATUS => accepted(self.capture_status(now_ms)),
            MSG_CAMERA_IMAGE_CAPTURED => self.resend(param2),
            _ => denied(),
        }
    }

    /// Storage id 0 (all) or 1 (ours); NaN, the "unused" marker some senders use, as 0.
    fn storage_request(&self, storage_id: f32, now_ms: u32) -> (MavResult, Option<MavMessage>) {
        let ours = storage_id.is_nan() || storage_id == 0.0 || storage_id == STORAGE_ID as f32;
        if ours {
            accepted(self.storage_information(now_ms))
        } else {
            denied()
        }
    }

    /// A kept CAMERA_IMAGE_CAPTURED, unchanged. An index never issued (or not an index) is
    /// DENIED; one issued but no longer kept is FAILED: valid, but it cannot be served.
    fn resend(&self, index: f32) -> (MavResult, Option<MavMessage>) {
        let Some(i) = as_index(index) else {
            return denied();
        };
        if i64::from(i) >= i64::from(self.image_count) {
            return denied();
        }
        match self
            .captured
            .iter()
            .rfind(|c| i64::from(c.image_index) == i64::from(i))
        {
            Some(c) => accepted(MavMessage::CAMERA_IMAGE_CAPTURED(c.clone())),
            None => (MavResult::MAV_RESULT_FAILED, None),
        }
    }

    pub fn camera_information(&self, time_boot_ms: u32) -> MavMessage {
        let i = &self.info;
        MavMessage::CAMERA_INFORMATION(CAMERA_INFORMATION_DATA {
            time_boot_ms,
            firmware_version: i.firmware_version,
            focal_length: i.focal_length_mm,
            sensor_size_h: i.sensor_size_h_mm,
            sensor_size_v: i.sensor_size_v_mm,
            flags: CameraCapFlags::CAMERA_CAP_FLAGS_CAPTURE_IMAGE,
            resolution_h: i.resolution_h,
            resolution_v: i.resolution_v,
            cam_definition_version: 0,
            vendor_name: nul_terminated(&i.vendor),
            model_name: nul_terminated(&i.model),
            lens_id: 0,
            cam_definition_uri: "".into(),
            gimbal_device_id: 0,
            camera_device_id: 0,
        })
    }

    pub fn camera_settings(&self, time_boot_ms: u32) -> MavMessage {
        MavMessage::CAMERA_SETTINGS(CAMERA_SETTINGS_DATA {
            time_boot_ms,
            mode_id: CameraMode::CAMERA_MODE_IMAGE,
            // No zoom or focus control: NaN is the message's "not known".
            zoomLevel: f32::NAN,
            focusLevel: f32::NAN,
            camera_device_id: 0,
        })
    }

    pub fn storage_information(&self, time_boot_ms: u32) -> MavMessage {
        let s = &self.storage;
        MavMessage::STORAGE_INFORMATION(STORAGE_INFORMATION_DATA {
            time_boot_ms,
            total_capacity: finite_or_zero(s.total_mib),
            used_capacity: finite_or_zero(s.used_mib),
            available_capacity: finite_or_zero(s.available_mib),
            read_speed: 0.0,
            write_speed: 0.0,
            storage_id: STORAGE_ID,
            storage_count: 1,
            status: s.status,
            mavtype: StorageType::STORAGE_TYPE_OTHER,
            name: "alfd captures".into(),
            storage_usage: StorageUsageFlag::STORAGE_USAGE_FLAG_SET
                | StorageUsageFlag::STORAGE_USAGE_FLAG_PHOTO,
        })
    }

    pub fn capture_status(&self, time_boot_ms: u32) -> MavMessage {
        let interval_s = self
            .activity
            .image_interval_s
            .filter(|s| s.is_finite() && *s > 0.0);
        // 0 idle, 1 capturing, 2 interval set but idle, 3 interval set and capturing.
        let image_status = match (self.activity.active, interval_s.is_some()) {
            (false, false) => 0,
            (true, false) => 1,
            (false, true) => 2,
            (true, true) => 3,
        };
        let available = if self.storage.status == StorageStatus::STORAGE_STATUS_READY {
            finite_or_zero(self.storage.available_mib)
        } else {
            0.0
        };
        MavMessage::CAMERA_CAPTURE_STATUS(CAMERA_CAPTURE_STATUS_DATA {
            time_boot_ms,
            image_interval: interval_s.unwrap_or(0.0),
            recording_time_ms: 0,
            available_capacity: available,
            image_status,
            video_status: 0,
            image_count: self.image_count,
            camera_device_id: 0,
        })
    }

    /// The CAMERA_IMAGE_CAPTURED for a capture (to broadcast); keeps it for re-requests and
    /// raises the image count to its index + 1. Non-finite positions are sent as 0 and
    /// out-of-range ones saturate (the caller reports only valid positions).
    pub fn image_captured(&mut self, c: &Captured) -> MavMessage {
        let q = unit_quaternion(c.q_camera_ned).unwrap_or([f32::NAN, 0.0, 0.0, 0.0]);
        let file_url = match c.file_name.as_deref() {
            Some(n) if n.len() <= 205 && !n.contains('\0') => n.into(),
            _ => "".into(),
        };
        let data = CAMERA_IMAGE_CAPTURED_DATA {
            time_utc: c.time_unix_us.unwrap_or(0),
            time_boot_ms: c.time_boot_ms,
            // `as` saturates and maps NaN to 0.
            lat: (c.lat_deg * 1e7).round() as i32,
            lon: (c.lon_deg * 1e7).round() as i32,
            alt: (c.alt_m * 1e3).round() as i32,
            relative_alt: (c.rel_alt_m * 1e3).round() as i32,
            q,
            image_index: c.image_index,
            camera_id: 0,
            capture_result: if c.success {
                MavBool::MAV_BOOL_TRUE
            } else {
                MavBool::MAV_BOOL_FALSE
            },
            file_url,
        };
        if c.image_index >= 0 {
            self.image_count = self.image_count.max(c.image_index.saturating_add(1));
        }
        if self.captured.len() == CAPTURED_RING {
            self.captured.pop_front();
        }
        self.captured.push_back(data.clone());
        MavMessage::CAMERA_IMAGE_CAPTURED(data)
    }

    /// `text` as STATUSTEXT: one message (id 0) when it fits 50 bytes, else chunks of at most
    /// 50 bytes cut on char boundaries, sharing a non-zero id, `chunk_seq` 0, 1, …. A chunked
    /// text whose last chunk is full gets an empty closing chunk (receivers end a text at the
    /// first NUL). At most [`STATUSTEXT_MAX_CHUNKS`]; a longer text is cut and ends in "…".
    /// NUL characters in `text` are sent as spaces.
    pub fn statustext(severity: MavSeverity, text: &str) -> Vec<MavMessage> {
        statustext_with(&NEXT_STATUSTEXT_ID, severity, text)
    }

    /// NAMED_VALUE_FLOAT for the permissible spacing (m) and the occlusion degree, skipping a
    /// value that is missing or not finite as an f32 (NaN is never sent).
    pub fn named_values(
        spacing_m: Option<f64>,
        occlusion_degree: Option<f64>,
        time_boot_ms: u32,
    ) -> Vec<MavMessage> {
        [
            (NAME_SPACING, spacing_m),
            (NAME_OCCLUSION, occlusion_degree),
        ]
        .into_iter()
        .filter_map(|(name, v)| Self::named_value(name, v?, time_boot_ms))
        .collect()
    }

    /// One NAMED_VALUE_FLOAT (`name` at most 10 bytes); `None` when `value` is not finite
    /// as an f32.
    pub fn named_value(name: &str, value: f64, time_boot_ms: u32) -> Option<MavMessage> {
        let value = value as f32;
        value.is_finite().then(|| {
            MavMessage::NAMED_VALUE_FLOAT(NAMED_VALUE_FLOAT_DATA {
                time_boot_ms,
                value,
                name: name.into(),
            })
        })
    }
}

/// Ids of chunked STATUSTEXTs, one sequence for the process (one MAVLink component), so two
/// tasks reporting at once never share an id. Never 0: 0 means "single chunk".
static NEXT_STATUSTEXT_ID: AtomicU16 = AtomicU16::new(1);

fn take_id(counter: &AtomicU16) -> u16 {
    let next = |id: u16| Some(id.checked_add(1).unwrap_or(1));
    counter
        .fetch_update(Ordering::Relaxed, Ordering::Relaxed, next)
        .unwrap_or_else(|id| id)
}

fn statustext_with(counter: &AtomicU16, severity: MavSeverity, text: &str) -> Vec<MavMessage> {
    let text = text.replace('\0', " ");
    let mut chunks: Vec<String> = split_on_chars(&text, STATUSTEXT_CHUNK)
        .into_iter()
        .map(str::to_owned)
        .collect();
    if chunks.len() <= 1 {
        return vec![statustext_msg(severity, &text, 0, 0)];
    }
    let full_last = chunks.last().is_some_and(|c| c.len() == STATUSTEXT_CHUNK);
    let needed = chunks.len() + usize::from(full_last);
    if needed > STATUSTEXT_MAX_CHUNKS {
        chunks.truncate(STATUSTEXT_MAX_CHUNKS);
        if let Some(last) = chunks.last_mut() {
            // One byte short of full, so the last chunk is NUL-terminated.
            let keep = floor_char_boundary(last, STATUSTEXT_CHUNK - ELLIPSIS.len() - 1);
            last.truncate(keep);
            last.push_str(ELLIPSIS);
        }
    } else if full_last {
        chunks.push(String::new());
    }
    let id = take_id(counter);
    chunks
        .iter()
        .enumerate()
        .map(|(seq, c)| statustext_msg(severity, c, id, seq as u8))
        .collect()
}

/// The dialect's command for a wire id (`None`: not one of the dialect's).
fn mav_cmd(cmd: u32) -> Option<MavCmd> {
    num_traits::FromPrimitive::from_u32(cmd)
}

/// A float parameter that holds a non-negative integer below 2^24 (exact in an f32).
fn as_index(p: f32) -> Option<u32> {
    ((0.0..16_777_216.0).contains(&p) && p.fract() == 0.0).then_some(p as u32)
}

fn accepted(m: MavMessage) -> (MavResult, Option<MavMessage>) {
    (MavResult::MAV_RESULT_ACCEPTED, Some(m))
}

fn denied() -> (MavResult, Option<MavMessage>) {
    (MavResult::MAV_RESULT_DENIED, None)
}

fn finite_or_zero(x: f32) -> f32 {
    if x.is_finite() {
        x
    } else {
        0.0
    }
}

/// `q` normalised (left as is when already unit to f32 precision); `None` if not finite or 0.
fn unit_quaternion(q: [f32; 4]) -> Option<[f32; 4]> {
    let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
    if !n.is_finite() || n < 1e-6 {
        None
    } else if (n - 1.0).abs() < 1e-6 {
        Some(q)
    } else {
        Some(q.map(|c| c / n))
    }
}

/// `s` in a 32-byte name field: at most 31 bytes, cut on a char boundary, NUL-padded.
fn nul_terminated(s: &str) -> [u8; 32] {
    let s = &s[..floor_char_boundary(s, 31)];
    let mut out = [0u8; 32];
    out[..s.len()].copy_from_slice(s.as_bytes());
    out
}

/// The largest char boundary of `s` at or below `max` bytes.
fn floor_char_boundary(s: &str, max: usize) -> usize {
    if s.len() <= max {
        return s.len();
    }
    let mut i = max;
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// `s` in consecutive pieces of at most `max` bytes (`max` ≥ 4), none splitting a char.
fn split_on_chars(s: &str, max: usize) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = s;
    while !rest.is_empty() {
        let cut = floor_char_boundary(rest, max);
        out.push(&rest[..cut]);
        rest = &rest[cut..];
    }
    out
}

fn statustext_msg(severity: MavSeverity, chunk: &str, id: u16, chunk_seq: u8) -> MavMessage {
    MavMessage::STATUSTEXT(STATUSTEXT_DATA {
        severity,
        text: chunk.into(),
        id,
        chunk_seq,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::allowlist::may_send;
    use mavlink::{MavHeader, MavlinkReader, MavlinkVersion, Message};
    use proptest::prelude::*;

    const GCS: (u8, u8) = (255, 190);

    #[test]
    fn wire_ids_become_the_dialects_commands_or_nothing() {
        assert_eq!(mav_cmd(2000), Some(MavCmd::MAV_CMD_IMAGE_START_CAPTURE));
        assert_eq!(mav_cmd(203), Some(MavCmd::MAV_CMD_DO_DIGICAM_CONTROL));
        assert_eq!(mav_cmd(12_345), None, "not a command of the dialect");
        assert_eq!(mav_cmd(70_000 + 2000), None, "beyond the wire's 16 bits");
    }

    fn proto() -> CameraProtocol {
        CameraProtocol::new(CameraInfo {
            focal_length_mm: 1.93,
            sensor_size_h_mm: 3.8,
            sensor_size_v_mm: 2.9,
            ..CameraInfo::for_alfd(1280, 720)
        })
    }

    fn cmd(p: &mut CameraProtocol, c: u32, params: [f32; 7]) -> Vec<MavMessage> {
        p.on_command(c, params, GCS.0, GCS.1, Trust::Accepted, 5_000)
    }

    fn request(p: &mut CameraProtocol, msg: f32, param2: f32) -> Vec<MavMessage> {
        cmd(p, 512, [msg, param2, 0.0, 0.0, 0.0, 0.0, 0.0])
    }

    /// The ACK's command and result, after checking it goes back to the sender.
    fn ack(m: &MavMessage) -> (MavCmd, MavResult) {
        match m {
            MavMessage::COMMAND_ACK(a) => {
                assert_eq!((a.target_system, a.target_component), GCS);
                (a.command, a.result)
            }
            other => panic!("not an ACK: {other:?}"),
        }
    }

    /// Serialises as MAVLink 2, decodes back to the same bytes, and is allowed out.
    fn wire(m: &MavMessage) -> Vec<u8> {
        let h = MavHeader {
            system_id: 1,
            component_id: 100,
            sequence: 7,
        };
        let mut buf = Vec::new();
        let n = mavlink::write_v2_msg(&mut buf, h, m).expect("serialises");
        assert_eq!(n, buf.len());
        let (h2, back) = MavlinkReader::new(&buf[..])
            .read_message::<MavMessage>(MavlinkVersion::V2)
            .expect("decodes");
        assert_eq!(h2, h);
        let mut again = Vec::new();
        mavlink::write_v2_msg(&mut again, h, &back).unwrap();
        assert_eq!(again, buf, "{}", m.message_name());
        assert_eq!(
            may_send(m.message_id(), None),
            Ok(()),
            "{}",
            m.message_name()
        );
        buf
    }

    fn capture(i: u32) -> Captured {
        Captured {
            time_boot_ms: 100_000 + i * 250,
            time_unix_us: Some(1_780_000_000_000_000 + u64::from(i) * 250_000),
            lat_deg: 47.397_742_1,
            lon_deg: -8.545_594,
            alt_m: 528.25,
            rel_alt_m: 40.0,
            q_camera_ned: camera_q_ned(0.0, 0.0, 0.0, 0.0).unwrap(),
            file_name: Some(format!("IMG_{i:06}.jpg")),
            image_index: i as i32,
            success: true,
        }
    }

    fn captured_index(m: &MavMessage) -> i32 {
        match m {
            MavMessage::CAMERA_IMAGE_CAPTURED(c) => c.image_index,
            other => panic!("not CAMERA_IMAGE_CAPTURED: {other:?}"),
        }
    }

    #[test]
    #[allow(deprecated)] // the legacy request commands
    fn camera_information_by_request_message_and_legacy_command() {
        let mut p = proto();
        for out in [request(&mut p, 259.0, 0.0), cmd(&mut p, 521, [1.0; 7])] {
            assert_eq!(out.len(), 2);
            let (c, r) = ack(&out[0]);
            assert!(matches!(
                c,
                MavCmd::MAV_CMD_REQUEST_MESSAGE | MavCmd::MAV_CMD_REQUEST_CAMERA_INFORMATION
            ));
            assert_eq!(r, MavResult::MAV_RESULT_ACCEPTED);
            let MavMessage::CAMERA_INFORMATION(i) = &out[1] else {
                panic!("{:?}", out[1]);
            };
            assert_eq!(i.time_boot_ms, 5_000);
            assert_eq!(&i.vendor_name[..5], b"alfd\0");
            assert_eq!(&i.model_name[..20], b"light-field trigger\0");
            assert_eq!(i.flags, CameraCapFlags::CAMERA_CAP_FLAGS_CAPTURE_IMAGE);
            assert_eq!((i.resolution_h, i.resolution_v), (1280, 720));
            assert_eq!(i.focal_length, 1.93);
            assert_eq!(i.camera_device_id, 0);
            assert_eq!(i.firmware_version & 0xff, 0); // crate 0.1.0: major 0
            assert_eq!((i.firmware_version >> 8) & 0xff, 1);
            for m in &out {
                wire(m);
            }
        }
        // The ACK names the command it answers.
        assert_eq!(
            ack(&cmd(&mut p, 521, [1.0; 7])[0]).0,
            MavCmd::MAV_CMD_REQUEST_CAMERA_INFORMATION
        );
    }

    #[test]
    fn long_names_are_cut_on_a_char_boundary_and_terminated() {
        let n = nul_terminated(&"é".repeat(20)); // 40 bytes
        assert_eq!(&n[..30], "é".repeat(15).as_bytes());
        assert_eq!(&n[30..], &[0, 0]);
    }

    #[test]
    fn settings_storage_and_capture_status_are_served() {
        let mut p = proto();
        let out = request(&mut p, 260.0, 0.0);
        assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_ACCEPTED);
        let MavMessage::CAMERA_SETTINGS(s) = &out[1] else {
            panic!()
        };
        assert_eq!(s.mode_id, CameraMode::CAMERA_MODE_IMAGE);
        wire(&out[1]);
        assert!(matches!(
            cmd(&mut p, 522, [1.0; 7])[1],
            MavMessage::CAMERA_SETTINGS(_)
        ));

        // Storage: not supported until set, then ready with the figures given.
        let MavMessage::STORAGE_INFORMATION(s) = &request(&mut p, 261.0, 0.0)[1] else {
            panic!()
        };
        assert_eq!(s.status, StorageStatus::STORAGE_STATUS_NOT_SUPPORTED);
        p.set_storage(StorageState::from_bytes(64 << 30, 16 << 30));
        for out in [request(&mut p, 261.0, 1.0), cmd(&mut p, 525, [0.0; 7])] {
            assert_eq!(out.len(), 2);
            assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_ACCEPTED);
            let MavMessage::STORAGE_INFORMATION(s) = &out[1] else {
                panic!("{:?}", out[1])
            };
            assert_eq!(s.status, StorageStatus::STORAGE_STATUS_READY);
            assert_eq!(
                (s.total_capacity, s.used_capacity, s.available_capacity),
                (65536.0, 49152.0, 16384.0)
            );
            assert_eq!((s.storage_id, s.storage_count), (1, 1));
            assert_eq!(s.name.to_str().unwrap(), "alfd captures");
            wire(&out[1]);
        }
        // A second storage does not exist.
        let out = request(&mut p, 261.0, 2.0);
        assert_eq!(out.len(), 1);
        assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_DENIED);

        // Capture status follows the captures, the storage and the activity.
        p.image_captured(&capture(0));
        p.image_captured(&capture(1));
        p.set_activity(CaptureActivity {
            active: true,
            image_interval_s: None,
        });
        for out in [request(&mut p, 262.0, 0.0), cmd(&mut p, 527, [1.0; 7])] {
            assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_ACCEPTED);
            let MavMessage::CAMERA_CAPTURE_STATUS(c) = &out[1] else {
                panic!()
            };
            assert_eq!(c.image_count, 2);
            assert_eq!(c.image_status, 1);
            assert_eq!(c.available_capacity, 16384.0);
            assert_eq!(c.time_boot_ms, 5_000);
            wire(&out[1]);
        }
        p.set_activity(CaptureActivity {
            active: false,
            image_interval_s: Some(2.0),
        });
        let MavMessage::CAMERA_CAPTURE_STATUS(c) = &request(&mut p, 262.0, 0.0)[1] else {
            panic!()
        };
        assert_eq!((c.image_status, c.image_interval), (2, 2.0));
    }

    #[test]
    fn image_index_counts_from_zero_and_the_ring_answers_re_requests() {
        let mut p = proto();
        // Nothing captured: index 0 was never issued.
        assert_eq!(
            ack(&request(&mut p, 263.0, 0.0)[0]).1,
            MavResult::MAV_RESULT_DENIED
        );
        for i in 0..70 {
            let m = p.image_captured(&capture(i));
            assert_eq!(captured_index(&m), i as i32);
            wire(&m);
        }
        assert_eq!(p.image_count(), 70);
        assert_eq!(p.last_captured().unwrap().image_index, 69);
        let MavMessage::CAMERA_CAPTURE_STATUS(st) = &request(&mut p, 262.0, 0.0)[1] else {
            panic!()
        };
        assert_eq!(st.image_count, 70); // newest index + 1

        // Kept (70 − 64 = 6 ..= 69): the original message, unchanged.
        for (i, legacy) in [(6u32, false), (40, true), (69, false)] {
            let out = if legacy {
                cmd(&mut p, 2002, [i as f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            } else {
                request(&mut p, 263.0, i as f32)
            };
            assert_eq!(out.len(), 2);
            assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_ACCEPTED);
            let MavMessage::CAMERA_IMAGE_CAPTURED(c) = &out[1] else {
                panic!()
            };
            assert_eq!(c.image_index, i as i32);
            assert_eq!(c.time_boot_ms, 100_000 + i * 250);
            assert_eq!(c.file_url.to_str().unwrap(), format!("IMG_{i:06}.jpg"));
        }
        // Issued but evicted: FAILED, and no message.
        let out = request(&mut p, 263.0, 5.0);
        assert_eq!(out.len(), 1);
        assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_FAILED);
        // Never issued, or not an index: DENIED.
        for bad in [70.0, 1e9, -1.0, 3.5, f32::NAN, f32::INFINITY] {
            let out = request(&mut p, 263.0, bad);
            assert_eq!(out.len(), 1, "{bad}");
            assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_DENIED, "{bad}");
        }
    }

    #[test]
    fn image_captured_fields() {
        let mut p = proto();
        let mut c = capture(3);
        c.q_camera_ned = camera_q_ned(0.0, 0.0, std::f64::consts::FRAC_PI_2, 0.0).unwrap();
        let MavMessage::CAMERA_IMAGE_CAPTURED(m) = p.image_captured(&c) else {
            panic!()
        };
        assert_eq!(m.time_boot_ms, 100_750);
        assert_eq!(m.time_utc, 1_780_000_000_750_000);
        assert_eq!((m.lat, m.lon), (473_977_421, -85_455_940));
        assert_eq!((m.alt, m.relative_alt), (528_250, 40_000));
        assert_eq!(m.q, c.q_camera_ned);
        assert_eq!(m.image_index, 3);
        assert_eq!(p.image_count(), 4);
        assert_eq!(m.capture_result, MavBool::MAV_BOOL_TRUE);
        assert_eq!(m.camera_id, 0);
        assert_eq!(m.file_url.to_str().unwrap(), "IMG_000003.jpg");

        // Unknowns: time 0, position 0, quaternion [NaN, 0, 0, 0], file name empty.
        let bad = Captured {
            time_unix_us: None,
            lat_deg: f64::NAN,
            lon_deg: f64::INFINITY,
            alt_m: f64::NAN,
            rel_alt_m: -1e300,
            q_camera_ned: [0.0; 4],
            file_name: Some("x".repeat(206)),
            ..capture(4)
        };
        let msg = p.image_captured(&bad);
        let MavMessage::CAMERA_IMAGE_CAPTURED(m) = &msg else {
            panic!()
        };
        assert_eq!(m.time_utc, 0);
        assert_eq!(
            (m.lat, m.lon, m.alt, m.relative_alt),
            (0, i32::MAX, 0, i32::MIN)
        );
        assert!(m.q[0].is_nan() && m.q[1..] == [0.0; 3]);
        assert_eq!(m.file_url.to_str().unwrap(), "");
        assert_eq!(m.image_index, 4);
        wire(&msg);
        let MavMessage::CAMERA_IMAGE_CAPTURED(m) = p.image_captured(&Captured {
            q_camera_ned: [f32::NAN; 4],
            success: false,
            file_name: None,
            ..capture(6)
        }) else {
            panic!()
        };
        assert!(m.q[0].is_nan() && m.q[1..] == [0.0; 3]);
        assert_eq!(m.capture_result, MavBool::MAV_BOOL_FALSE);
        assert_eq!(m.file_url.to_str().unwrap(), "");
        assert_eq!(p.image_count(), 7);
        // A non-unit quaternion is normalised.
        let MavMessage::CAMERA_IMAGE_CAPTURED(m) = p.image_captured(&Captured {
            q_camera_ned: [2.0, 0.0, 0.0, 0.0],
            ..capture(7)
        }) else {
            panic!()
        };
        assert_eq!(m.q, [1.0, 0.0, 0.0, 0.0]);
        // 205 bytes exactly fits (no terminator needed in a full field).
        let m = p.image_captured(&Captured {
            file_name: Some("y".repeat(205)),
            ..capture(8)
        });
        let MavMessage::CAMERA_IMAGE_CAPTURED(m) = &m else {
            panic!()
        };
        assert_eq!(m.file_url.to_str().unwrap().len(), 205);
    }

    #[test]
    fn mode_capture_and_unknown_commands() {
        let mut p = proto();
        let one = |out: Vec<MavMessage>| {
            assert_eq!(out.len(), 1);
            wire(&out[0]);
            ack(&out[0])
        };
        let r = one(cmd(
            &mut p,
            530,
            [0.0, 0.0, f32::NAN, f32::NAN, 0.0, 0.0, f32::NAN],
        ));
        assert_eq!(
            r,
            (
                MavCmd::MAV_CMD_SET_CAMERA_MODE,
                MavResult::MAV_RESULT_ACCEPTED
            )
        );
        for mode in [1.0, 2.0, f32::NAN] {
            let r = one(cmd(&mut p, 530, [0.0, mode, 0.0, 0.0, 0.0, 0.0, 0.0]));
            assert_eq!(r.1, MavResult::MAV_RESULT_DENIED);
        }
        // Storage format never; a capture of no images, or endless without an interval, no.
        for (c, params) in [
            (526, [0.0; 7]),
            (2000, [0.0; 7]),
            (2000, [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0]),
            (2000, [0.0, 1.0, 2.5, 0.0, 0.0, 0.0, 0.0]),
            (2000, [0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            (203, [0.0; 7]),
        ] {
            assert_eq!(
                one(cmd(&mut p, c, params)).1,
                MavResult::MAV_RESULT_DENIED,
                "{c} {params:?}"
            );
        }
        assert!(p.take_capture_commands().is_empty());
        // Video, zoom, arming: not ours.
        for c in [2500, 531, 400] {
            assert_eq!(
                one(cmd(&mut p, c, [0.0; 7])).1,
                MavResult::MAV_RESULT_UNSUPPORTED
            );
        }
        // REQUEST_MESSAGE for something a camera does not send (AUTOPILOT_VERSION).
        assert_eq!(
            one(request(&mut p, 148.0, 0.0)).1,
            MavResult::MAV_RESULT_DENIED
        );
        // Not in the dialect: nothing can name it.
        assert!(cmd(&mut p, 65_000, [0.0; 7]).is_empty());
        assert!(cmd(&mut p, u32::MAX, [0.0; 7]).is_empty());
        // Nothing above changed the image count.
        assert_eq!(p.image_count(), 0);
    }

    #[test]
    fn capture_commands_are_accepted_and_queued() {
        use CaptureCommand::*;
        let mut p = proto();
        let acked = |out: Vec<MavMessage>| {
            assert_eq!(out.len(), 1, "{out:?}");
            wire(&out[0]);
            ack(&out[0]).1
        };
        let start = MavCmd::MAV_CMD_IMAGE_START_CAPTURE;
        // MAVSDK's take_photo: one image, its sequence number in param4.
        let single = [0.0, 0.0, 1.0, 7.0, f32::NAN, f32::NAN, f32::NAN];
        assert_eq!(
            acked(cmd(&mut p, 2000, single)),
            MavResult::MAV_RESULT_ACCEPTED
        );
        // Retransmitted (its ACK lost): acknowledged again, not taken twice.
        assert_eq!(
            acked(cmd(&mut p, 2000, single)),
            MavResult::MAV_RESULT_ACCEPTED
        );
        // Five at 0.5 s; endless at 2 s; a stop; a digicam shot.
        let five = [0.0, 0.5, 5.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(
            acked(cmd(&mut p, 2000, five)),
            MavResult::MAV_RESULT_ACCEPTED
        );
        let endless = [0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(
            acked(cmd(&mut p, 2000, endless)),
            MavResult::MAV_RESULT_ACCEPTED
        );
        assert_eq!(
            acked(cmd(&mut p, 2001, [0.0; 7])),
            MavResult::MAV_RESULT_ACCEPTED
        );
        let shoot = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
        assert_eq!(
            acked(cmd(&mut p, 203, shoot)),
            MavResult::MAV_RESULT_ACCEPTED
        );
        assert_eq!(
            p.take_capture_commands(),
            [
                Start {
                    from: GCS,
                    interval_s: 0.0,
                    count: 1,
                    sequence: Some(7),
                    command: start
                },
                Start {
                    from: GCS,
                    interval_s: 0.5,
                    count: 5,
                    sequence: None,
                    command: start
                },
                Start {
                    from: GCS,
                    interval_s: 2.0,
                    count: 0,
                    sequence: None,
                    command: start
                },
                Stop { from: GCS },
                Start {
                    from: GCS,
                    interval_s: 0.0,
                    count: 1,
                    sequence: None,
                    command: MavCmd::MAV_CMD_DO_DIGICAM_CONTROL
                },
            ]
        );
        assert!(p.take_capture_commands().is_empty());
        // The next sequence number is a new capture; a flood beyond the queue is refused.
        let next = [0.0, 0.0, 1.0, 8.0, 0.0, 0.0, 0.0];
        assert_eq!(
            acked(cmd(&mut p, 2000, next)),
            MavResult::MAV_RESULT_ACCEPTED
        );
        for _ in 1..PENDING_COMMANDS {
            assert_eq!(
                acked(cmd(&mut p, 203, shoot)),
                MavResult::MAV_RESULT_ACCEPTED
            );
        }
        assert_eq!(
            acked(cmd(&mut p, 203, shoot)),
            MavResult::MAV_RESULT_TEMPORARILY_REJECTED
        );
        assert_eq!(p.take_capture_commands().len(), PENDING_COMMANDS);
        // The protocol counts images only when they are reported captured.
        assert_eq!(p.image_count(), 0);
    }

    #[test]
    fn storage_totals_are_consistent() {
        for (total, free) in [
            (64u64 << 30, 16u64 << 30),
            (75_000_000_000, 75_000_000_000),
            (10, 20),
            // Parts that, each rounded to f32, summed past an f32 total in double precision
            // (MAVSDK read such a storage of this machine's disk).
            (269_841_714_938, 35_630_780_113),
        ] {
            for s in [
                StorageState::from_bytes(total, free),
                StorageState::from_free_bytes(free),
            ] {
                let parts = f64::from(s.used_mib) + f64::from(s.available_mib);
                assert!(f64::from(s.total_mib) >= parts, "{s:?}");
                assert!(s.total_mib > 0.0 && s.available_mib > 0.0, "{s:?}");
            }
        }
        // What MAVSDK saw: 75 GB free, and a total of 0.
        let s = StorageState::from_free_bytes(75_000_000_000);
        assert!((s.total_mib - 71_525.57).abs() < 0.1, "{s:?}");
    }

    #[test]
    fn foreign_systems_read_but_do_not_command() {
        let mut p = proto();
        p.image_captured(&capture(0));
        let foreign = |p: &mut CameraProtocol, c: u32, params: [f32; 7]| {
            p.on_command(c, params, GCS.0, GCS.1, Trust::Foreign, 5_000)
        };
        // Every read-only request gets what an accepted system gets: the same ACK, to the
        // foreign sender, and the same message.
        let mut requests: Vec<(u32, [f32; 7])> = [259.0, 260.0, 261.0, 262.0]
            .map(|m| (512, [m, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
            .to_vec();
        requests.push((512, [263.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
        for c in [521, 522, 525, 527, 2002] {
            requests.push((c, [0.0; 7]));
        }
        for (c, params) in requests {
            let theirs = foreign(&mut p, c, params);
            assert_eq!(theirs.len(), 2, "{c} {params:?}");
            assert_eq!(ack(&theirs[0]).1, MavResult::MAV_RESULT_ACCEPTED);
            // Compared on the wire: CAMERA_SETTINGS carries NaN, never equal to itself.
            let bytes = |out: &[MavMessage]| out.iter().map(wire).collect::<Vec<_>>();
            assert_eq!(
                bytes(&theirs),
                bytes(&cmd(&mut p, c, params)),
                "{c} {params:?}"
            );
        }
        // Commands that change something are DENIED, with an ACK: captures, mode (even
        // image mode, which an accepted system gets), storage format, trigger distance,
        // digicam; and what the camera would call UNSUPPORTED (video, arming).
        let image_mode = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(
            ack(&cmd(&mut p, 530, image_mode)[0]).1,
            MavResult::MAV_RESULT_ACCEPTED
        );
        for c in [530, 2000, 2001, 526, 206, 203, 2500, 400] {
            let out = foreign(&mut p, c, image_mode);
            assert_eq!(out.len(), 1, "{c}");
            assert_eq!(ack(&out[0]).1, MavResult::MAV_RESULT_DENIED, "{c}");
            assert_eq!(ack(&out[0]).0 as u32, c);
            wire(&out[0]);
        }
        // A command outside the dialect still cannot be named in an ACK.
        assert!(foreign(&mut p, 65_000, [0.0; 7]).is_empty());
        assert_eq!(p.image_count(), 1);
    }

    #[test]
    fn nan_params_get_a_clean_ack() {
        let mut p = proto();
        for c in [512, 521, 522, 525, 527, 530, 2000, 2001, 2002, 526, 511] {
            for params in [[f32::NAN; 7], [f32::INFINITY; 7], [-f32::MAX; 7]] {
                let out = cmd(&mut p, c, params);
                assert!(!out.is_empty() && out.len() <= 2, "{c}");
                let (ac, r) = ack(&out[0]);
                assert_eq!(ac as u32, c);
                if out.len() == 2 {
                    assert_eq!(r, MavResult::MAV_RESULT_ACCEPTED);
                } else if c != 2001 {
                    // Stopping is always accepted; nothing else is with such params.
                    assert_ne!(r, MavResult::MAV_RESULT_ACCEPTED, "{c}");
                }
                for m in &out {
                    wire(m);
                }
            }
        }
    }

    proptest! {
        #[test]
        fn any_command_and_params_answer_with_one_ack(
            c in prop_oneof![0u32..3000, any::<u32>()],
            bits in prop::array::uniform7(any::<u32>()),
        ) {
            let mut p = proto();
            p.image_captured(&capture(0));
            let trust = if c % 2 == 0 { Trust::Accepted } else { Trust::Foreign };
            let out = p.on_command(c, bits.map(f32::from_bits), 1, 2, trust, 0);
            if let Some(first) = out.first() {
                let MavMessage::COMMAND_ACK(a) = first else { panic!("{first:?}") };
                prop_assert_eq!(a.command as u32, c);
                prop_assert!(out.len() <= 2);
                prop_assert!(out[1..].iter().all(|m| !matches!(m, MavMessage::COMMAND_ACK(_))));
            } else {
                prop_assert!(mav_cmd(c).is_none());
            }
        }
    }

    fn texts(out: &[MavMessage]) -> Vec<(String, u16, u8)> {
        out.iter()
            .map(|m| match m {
                MavMessage::STATUSTEXT(s) => {
                    wire(m);
                    assert_eq!(s.severity, MavSeverity::MAV_SEVERITY_WARNING);
                    let t = s.text.to_str().expect("each chunk is valid UTF-8");
                    (t.to_owned(), s.id, s.chunk_seq)
                }
                other => panic!("{other:?}"),
            })
            .collect()
    }

    fn join(t: &[(String, u16, u8)]) -> String {
        t.iter().map(|(s, ..)| s.as_str()).collect()
    }

    #[test]
    fn statustext_chunks() {
        let w = MavSeverity::MAV_SEVERITY_WARNING;

        let fifty = "a".repeat(50);
        let t = texts(&CameraProtocol::statustext(w, &fifty));
        assert_eq!(t, vec![(fifty, 0, 0)]);

        let long: String = (0..120)
            .map(|i| char::from(b'a' + (i % 26) as u8))
            .collect();
        let t = texts(&CameraProtocol::statustext(w, &long));
        assert_eq!(t.len(), 3);
        let id = t[0].1;
        assert_ne!(id, 0);
        assert!(t.iter().all(|c| c.1 == id));
        assert_eq!(t.iter().map(|c| c.2).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(join(&t), long);
        assert_eq!(t[2].0.len(), 20);

        // The next text gets a new id.
        let t2 = texts(&CameraProtocol::statustext(w, &long));
        assert_ne!(t2[0].1, id);
        assert_ne!(t2[0].1, 0);

        // A full last chunk is closed by an empty one.
        let hundred = "b".repeat(100);
        let t = texts(&CameraProtocol::statustext(w, &hundred));
        assert_eq!(t.iter().map(|c| c.0.len()).collect::<Vec<_>>(), [50, 50, 0]);
        assert_eq!(join(&t), hundred);

        // Two-byte chars at an odd offset: no chunk splits one.
        let accents = format!("a{}", "é".repeat(60));
        let t = texts(&CameraProtocol::statustext(w, &accents));
        assert_eq!(t[0].0.len(), 49);
        assert_eq!(join(&t), accents);
    }

    #[test]
    fn statustext_beyond_four_chunks_is_cut_with_an_ellipsis() {
        let w = MavSeverity::MAV_SEVERITY_WARNING;
        for text in ["c".repeat(500), "c".repeat(200), "€".repeat(100)] {
            let t = texts(&CameraProtocol::statustext(w, &text));
            assert_eq!(t.len(), STATUSTEXT_MAX_CHUNKS, "{}", text.len());
            let joined = join(&t);
            assert!(joined.ends_with(ELLIPSIS));
            let body = joined.strip_suffix(ELLIPSIS).unwrap();
            assert!(text.starts_with(body) && body.len() > 140);
            // The last chunk is short of full, so receivers see it end.
            assert!(t[3].0.len() < STATUSTEXT_CHUNK);
        }
        // 199 bytes fit four chunks, the last one short of full: nothing cut.
        let t = texts(&CameraProtocol::statustext(w, &"d".repeat(199)));
        assert_eq!(t.len(), 4);
        assert_eq!(join(&t), "d".repeat(199));
    }

    #[test]
    fn statustext_ids_wrap_past_zero() {
        let w = MavSeverity::MAV_SEVERITY_WARNING;
        let counter = AtomicU16::new(u16::MAX);
        let long = "e".repeat(60);
        let a = texts(&statustext_with(&counter, w, &long));
        let b = texts(&statustext_with(&counter, w, &long));
        assert_eq!((a[0].1, b[0].1), (u16::MAX, 1));
        // A single chunk takes no id.
        assert_eq!(texts(&statustext_with(&counter, w, "short"))[0].1, 0);
        assert_eq!(texts(&statustext_with(&counter, w, &long))[0].1, 2);
        // NUL inside a text would end it early at the receiver.
        let c = texts(&CameraProtocol::statustext(w, "a\0b"));
        assert_eq!(c[0].0, "a b");
    }

    #[test]
    fn named_values_skip_missing_and_non_finite() {
        let out = CameraProtocol::named_values(Some(3.25), Some(0.4), 9_000);
        assert_eq!(out.len(), 2);
        let got: Vec<(String, f32, u32)> = out
            .iter()
            .map(|m| {
                wire(m);
                let MavMessage::NAMED_VALUE_FLOAT(n) = m else {
                    panic!()
                };
                assert_eq!(n.name.len(), 10);
                (n.name.to_str().unwrap().to_owned(), n.value, n.time_boot_ms)
            })
            .collect();
        assert_eq!(
            got,
            [
                ("ALF_SPC".to_owned(), 3.25, 9_000),
                ("ALF_OCC".to_owned(), 0.4, 9_000)
            ]
        );
        for (s, o) in [
            (Some(f64::NAN), Some(0.4)),
            (None, Some(0.4)),
            (Some(1e300), Some(0.4)), // finite as f64, infinite as f32
        ] {
            let out = CameraProtocol::named_values(s, o, 0);
            assert_eq!(out.len(), 1);
            let MavMessage::NAMED_VALUE_FLOAT(n) = &out[0] else {
                panic!()
            };
            assert_eq!(n.name.to_str().unwrap(), "ALF_OCC");
        }
        assert!(CameraProtocol::named_values(None, Some(f64::INFINITY), 0).is_empty());
    }

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6)
    }

    /// Rotates `v` by `[w, x, y, z]` with the textbook formula, independent of glam.
    fn rotate(q: [f32; 4], v: [f64; 3]) -> [f64; 3] {
        let [w, x, y, z] = q.map(f64::from);
        let u = [x, y, z];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let t = cross(u, v).map(|c| 2.0 * c);
        let ut = cross(u, t);
        [0, 1, 2].map(|i| v[i] + w * t[i] + ut[i])
    }

    #[test]
    fn nadir_camera_at_level_flight_looks_down() {
        for yaw_deg in [0.0f64, 90.0, -135.0] {
            let q = camera_q_ned(0.0, 0.0, yaw_deg.to_radians(), 0.0).unwrap();
            assert!(
                close(rotate(q, [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0]),
                "{yaw_deg}"
            );
        }
        // At yaw 0 the image's x axis is body forward = north.
        let q = camera_q_ned(0.0, 0.0, 0.0, 0.0).unwrap();
        assert!(close(rotate(q, [1.0, 0.0, 0.0]), [1.0, 0.0, 0.0]));
        assert_eq!(q, [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn camera_pitch_tilts_the_optical_axis_forward() {
        let s3 = 3f64.sqrt() / 2.0;
        // Heading north, camera 30° forward of nadir: (sin 30°, 0, cos 30°).
        let q = camera_q_ned(0.0, 0.0, 0.0, 30f64.to_radians()).unwrap();
        assert!(close(rotate(q, [0.0, 0.0, 1.0]), [0.5, 0.0, s3]));
        // Heading east: forward is east.
        let q = camera_q_ned(0.0, 0.0, 90f64.to_radians(), 30f64.to_radians()).unwrap();
        assert!(close(rotate(q, [0.0, 0.0, 1.0]), [0.0, 0.5, s3]));
        // Nose down 30° with the camera 30° back: nadir again.
        let q = camera_q_ned(0.0, (-30f64).to_radians(), 0.0, 30f64.to_radians()).unwrap();
        assert!(close(rotate(q, [0.0, 0.0, 1.0]), [0.0, 0.0, 1.0]));
        assert_eq!(camera_q_ned(f64::NAN, 0.0, 0.0, 0.0), None);
    }

    proptest! {
        #[test]
        fn quaternion_matches_the_capture_exports(
            roll in -60.0f64..60.0, pitch in -60.0f64..60.0, yaw in -180.0f64..180.0,
            cam in -10.0f64..90.0,
        ) {
            use crate::core::attitude::{body_to_ned, camera_to_body};
            let (r, p, y, c) =
                (roll.to_radians(), pitch.to_radians(), yaw.to_radians(), cam.to_radians());
            let m = body_to_ned(r, p, y) * camera_to_body(c);
            let q = camera_q_ned(r, p, y, c).unwrap();
            for (axis, col) in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
                .into_iter()
                .zip([m.x_axis, m.y_axis, m.z_axis])
            {
                prop_assert!(close(rotate(q, axis), col.to_array()));
            }
        }
    }

    #[test]
    fn every_message_the_protocol_produces_is_allowed() {
        let mut p = proto();
        let mut all = Vec::new();
        all.push(p.image_captured(&capture(0)));
        for c in [512u32, 521, 522, 525, 527, 530, 2000, 2002, 9999] {
            for m in [259.0, 260.0, 261.0, 262.0, 263.0, 0.0] {
                all.extend(cmd(&mut p, c, [m, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
            }
        }
        all.extend(CameraProtocol::statustext(
            MavSeverity::MAV_SEVERITY_INFO,
            &"f".repeat(300),
        ));
        all.extend(CameraProtocol::named_values(Some(1.0), Some(2.0), 0));
        let mut ids: Vec<u32> = all.iter().map(|m| m.message_id()).collect();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids, [77, 251, 253, 259, 260, 261, 262, 263]);
        for m in &all {
            wire(m);
        }
    }
}
