//! What alfd may put on the flight controller's link (camera, status and time messages, and
//! COMMAND_LONG only for telemetry-rate and camera commands), refused here in one place; and whom
//! it obeys: read-only camera requests from any system, every other command only from accepted ones.

/// Message ids alfd may send (MAVLink common dialect).
pub const ALLOWED_MESSAGES: &[(u32, &str)] = &[
    (0, "HEARTBEAT"),
    (2, "SYSTEM_TIME"),
    (76, "COMMAND_LONG"),
    (77, "COMMAND_ACK"),
    (111, "TIMESYNC"),
    (112, "CAMERA_TRIGGER"),
    (251, "NAMED_VALUE_FLOAT"),
    (253, "STATUSTEXT"),
    (259, "CAMERA_INFORMATION"),
    (260, "CAMERA_SETTINGS"),
    (261, "STORAGE_INFORMATION"),
    (262, "CAMERA_CAPTURE_STATUS"),
    (263, "CAMERA_IMAGE_CAPTURED"),
];

/// Commands alfd may send inside COMMAND_LONG.
pub const ALLOWED_COMMANDS: &[(u32, &str)] = &[
    (203, "MAV_CMD_DO_DIGICAM_CONTROL"),
    (206, "MAV_CMD_DO_SET_CAM_TRIGG_DIST"),
    (511, "MAV_CMD_SET_MESSAGE_INTERVAL"),
    (512, "MAV_CMD_REQUEST_MESSAGE"),
    (2000, "MAV_CMD_IMAGE_START_CAPTURE"),
    (2001, "MAV_CMD_IMAGE_STOP_CAPTURE"),
];

/// COMMAND_LONG's message id.
pub const COMMAND_LONG_ID: u32 = 76;

/// Commands that only ask the camera for a message and change nothing: answered whoever
/// asks, so a ground station outside `accept_system_ids` (MAVSDK speaks as system 245) can
/// still discover the camera and read its state.
pub const READ_ONLY_COMMANDS: &[(u32, &str)] = &[
    (512, "MAV_CMD_REQUEST_MESSAGE"),
    (521, "MAV_CMD_REQUEST_CAMERA_INFORMATION"),
    (522, "MAV_CMD_REQUEST_CAMERA_SETTINGS"),
    (525, "MAV_CMD_REQUEST_STORAGE_INFORMATION"),
    (527, "MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS"),
    (2002, "MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE"),
];

/// Who sent a received command, as far as obeying it goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Trust {
    /// A system in `accept_system_ids`.
    Accepted,
    /// Any other system on the link.
    Foreign,
}

/// Whether a command received from `from` may be acted on. A foreign system gets only the
/// read-only requests; anything else from it is to be refused (COMMAND_ACK DENIED, not
/// silence, so the sender knows).
pub fn may_obey(command: u32, from: Trust) -> bool {
    from == Trust::Accepted || READ_ONLY_COMMANDS.iter().any(|(id, _)| *id == command)
}

/// Why a message may not be sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The message id is not on the allow-list.
    Message(u32),
    /// A COMMAND_LONG carrying a command that is not on the allow-list.
    Command(u32),
}

/// `Ok` if a message with id `msg_id` (and, for COMMAND_LONG, `command`) may be sent.
pub fn may_send(msg_id: u32, command: Option<u32>) -> Result<(), Refusal> {
    if !ALLOWED_MESSAGES.iter().any(|(id, _)| *id == msg_id) {
        return Err(Refusal::Message(msg_id));
    }
    if msg_id == COMMAND_LONG_ID {
        let cmd = command.unwrap_or(u32::MAX);
        if !ALLOWED_COMMANDS.iter().any(|(id, _)| *id == cmd) {
            return Err(Refusal::Command(cmd));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flight_control_is_refused() {
        // SET_POSITION_TARGET_LOCAL_NED, MANUAL_CONTROL, COMMAND_INT, SET_MODE, MISSION_ITEM_INT.
        for id in [84, 69, 75, 11, 73] {
            assert_eq!(may_send(id, None), Err(Refusal::Message(id)));
        }
        // ARM/DISARM, NAV_LAND, DO_SET_MODE, NAV_TAKEOFF inside COMMAND_LONG.
        for cmd in [400, 21, 176, 22] {
            assert_eq!(may_send(76, Some(cmd)), Err(Refusal::Command(cmd)));
        }
        assert_eq!(may_send(76, None), Err(Refusal::Command(u32::MAX)));
        assert_eq!(may_send(76, Some(511)), Ok(()));
        assert_eq!(may_send(0, None), Ok(()));
    }

    #[test]
    fn foreign_systems_get_requests_only() {
        for (cmd, name) in READ_ONLY_COMMANDS {
            assert!(may_obey(*cmd, Trust::Foreign), "{name}");
            assert!(may_obey(*cmd, Trust::Accepted), "{name}");
        }
        // Captures, mode, storage format, trigger distance, digicam, message rates, arming,
        // and an id outside the dialect: accepted systems only.
        for cmd in [2000, 2001, 530, 526, 206, 203, 511, 400, 65_000, u32::MAX] {
            assert!(!may_obey(cmd, Trust::Foreign), "{cmd}");
            assert!(may_obey(cmd, Trust::Accepted), "{cmd}");
        }
    }

    #[test]
    fn camera_protocol_messages_are_allowed() {
        // What `daemon::camera` sends (its own test drives the protocol through every
        // path): COMMAND_ACK, NAMED_VALUE_FLOAT, STATUSTEXT, CAMERA_INFORMATION,
        // CAMERA_SETTINGS, STORAGE_INFORMATION, CAMERA_CAPTURE_STATUS, CAMERA_IMAGE_CAPTURED.
        for id in [77, 251, 253, 259, 260, 261, 262, 263] {
            assert_eq!(may_send(id, None), Ok(()), "{id}");
        }
    }
}
