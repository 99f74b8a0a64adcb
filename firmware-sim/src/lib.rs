//! firmware-sim: a simulated autopilot for alfd's tests and bench. It flies an analytic survey,
//! streams MAVLink telemetry stamped by its own boot clock over a pty, serial port, UDP or TCP,
//! answers TIMESYNC and camera commands, records the truth, and injects faults on demand.
//! Optionally it forwards MAVLink between that link and a ground station over UDP.

pub mod clock;
pub mod config;
pub mod faults;
pub mod geo;
pub mod pty;
mod sim;
pub mod trajectory;
mod transport;
pub mod trigger;
pub mod truth;

pub use clock::mono_ns;
pub use config::{
    Autopilot, CameraBackend, ConfigError, FaultKind, GcsTimesync, Pattern, SimConfig, Transport,
    Vehicle,
};
pub use faults::Noise;
pub use sim::{start, SimError, SimHandle, SimStats};
pub use truth::Truth;

use std::time::Duration;

/// A fault injected at run time through [`SimHandle::inject`].
#[derive(Clone, Debug, PartialEq)]
pub enum Fault {
    /// Close the link (the pty, the serial port, the socket) and reopen it after `duration`.
    LinkLoss { duration: Duration },
    /// Restart the boot clock; nothing is sent for `silence` (the boot) and stream rates return
    /// to the configured ones.
    Reboot { silence: Duration },
    /// Reported positions jump by `offset_m` (north, east, down) for `duration`; velocities do not.
    GpsGlitch {
        offset_m: [f64; 3],
        duration: Duration,
    },
    /// No telemetry (heartbeats and TIMESYNC replies continue) for `duration`.
    Silence { duration: Duration },
    /// Change the wire's noise from now on.
    Noise(Noise),
}

/// What happened, with the monotonic instant it happened at.
#[derive(Clone, Debug, PartialEq)]
pub enum SimEvent {
    LinkUp {
        mono_ns: u64,
    },
    LinkDown {
        mono_ns: u64,
    },
    Rebooted {
        mono_ns: u64,
    },
    GlitchStart {
        mono_ns: u64,
    },
    GlitchEnd {
        mono_ns: u64,
    },
    SilenceStart {
        mono_ns: u64,
    },
    SilenceEnd {
        mono_ns: u64,
    },
    /// A message arrived (after CRC): who sent it, its id, and the command for COMMAND_LONG/INT.
    Received {
        mono_ns: u64,
        system_id: u8,
        component_id: u8,
        msg_id: u32,
        command: Option<u32>,
    },
    /// A picture was taken (distance trigger or capture command): a CAMERA_TRIGGER went out, or
    /// with the MAVLinkCamV2 backend an IMAGE_START_CAPTURE to the camera and a CAMERA_FEEDBACK,
    /// or with the servo backend the CAMERA_FEEDBACK alone.
    Capture {
        mono_ns: u64,
        seq: u32,
        /// The vehicle at the picture's instant: where a camera's picture is
        /// rendered from (`alfd sim`'s external camera card).
        truth: Truth,
    },
    /// The EKF got its origin: GPS_GLOBAL_ORIGIN and HOME_POSITION went out.
    OriginSet {
        mono_ns: u64,
    },
    Armed {
        mono_ns: u64,
    },
    /// Landed state IN_AIR: the take-off climb is over, the survey starts.
    InAir {
        mono_ns: u64,
    },
}
