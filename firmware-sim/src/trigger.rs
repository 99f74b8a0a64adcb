//! The autopilot's distance trigger (MAV_CMD_DO_SET_CAM_TRIGG_DIST, `CAM_TRIGG_DIST`) as each
//! autopilot counts it: from where is the next picture's distance measured. Pure: positions
//! are the path flown (m), arguments.
//!
//! - `Generic` (what firmware-sim always did): a new distance counts from where the command
//!   arrives; pictures taken by other commands do not move the count.
//! - `Px4` (`camera_trigger`'s `Run`, `update_distance`): a new distance forgets the count; the
//!   next check shoots once and counts from there (with or without "trigger once": one picture
//!   either way). Pictures taken by other commands do not move the count.
//! - `ArduPilot` (`AP_Camera_Backend::update`, `take_picture`): the distance counts from the
//!   last picture, whatever took it; a new distance does not restart the count, so one shorter
//!   than the way already flown fires at the next update. With the trigger off the last
//!   picture is forgotten, and enabling it counts from there, with no picture.
//!
//! Each checks on its own clock ([`check_period_ns`]): the picture is taken at the first check
//! at or past the point, and the count goes on from there.
//!
//! ArduPilot and PX4 measure the straight-line distance from the last picture; this counts along
//! the path, the same on a straight lane and longer round a turn.

use crate::config::Autopilot;

/// How often the autopilot checks its distance trigger (`None`: firmware-sim's generic
/// autopilot, at the point itself). ArduPilot: `AP_Camera::update` at 50 Hz; PX4:
/// `camera_trigger` polls every 50 ms (it also handles commands then: not modelled, the
/// command's picture is taken at the first check after it).
pub fn check_period_ns(autopilot: Autopilot) -> Option<u64> {
    match autopilot {
        Autopilot::Generic => None,
        Autopilot::Px4 => Some(50_000_000),
        Autopilot::ArduPilot => Some(20_000_000),
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct DistanceTrigger {
    autopilot: Autopilot,
    /// The distance in force (`None`: off).
    dist_m: Option<f64>,
    /// Where the count starts (−∞: at once, PX4's shot for a new distance).
    from_m: f64,
}

impl DistanceTrigger {
    pub fn new(autopilot: Autopilot) -> Self {
        DistanceTrigger {
            autopilot,
            dist_m: None,
            from_m: 0.0,
        }
    }

    /// A DO_SET_CAM_TRIGG_DIST received at `here_m`: `dist_m` ≤ 0 (or NaN) turns it off.
    pub fn set(&mut self, dist_m: f64, here_m: f64) {
        if dist_m.is_nan() || dist_m <= 0.0 {
            self.dist_m = None;
            return;
        }
        match self.autopilot {
            Autopilot::Generic => self.from_m = here_m,
            Autopilot::Px4 => self.from_m = f64::NEG_INFINITY,
            Autopilot::ArduPilot if self.dist_m.is_none() => self.from_m = here_m,
            Autopilot::ArduPilot => {}
        }
        self.dist_m = Some(dist_m);
    }

    /// Off (a reboot: the distance was never saved).
    pub fn off(&mut self) {
        self.dist_m = None;
    }

    pub fn is_on(&self) -> bool {
        self.dist_m.is_some()
    }

    /// The trigger itself fired at `here_m`.
    pub fn fired(&mut self, here_m: f64) {
        self.from_m = here_m;
    }

    /// A picture taken by something else (a capture command, the command's "trigger once").
    pub fn other_picture(&mut self, here_m: f64) {
        match self.autopilot {
            Autopilot::Generic | Autopilot::Px4 => {}
            Autopilot::ArduPilot => self.from_m = here_m,
        }
    }

    /// Whether a distance command's "trigger once" (param3) takes a picture of its own: PX4's
    /// new distance shoots once whatever param3 says ([`DistanceTrigger::set`]), never twice.
    pub fn command_shoots_once(&self) -> bool {
        self.autopilot != Autopilot::Px4
    }

    /// Where the next picture falls on the path (`None`: off). At or behind the vehicle (−∞
    /// included): at the next check.
    pub fn next_m(&self) -> Option<f64> {
        self.dist_m.map(|d| self.from_m + d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generic_counts_a_new_distance_from_the_command() {
        let mut t = DistanceTrigger::new(Autopilot::Generic);
        assert_eq!(t.next_m(), None);
        t.set(5.0, 10.0);
        assert_eq!(t.next_m(), Some(15.0));
        t.fired(15.0);
        assert_eq!(t.next_m(), Some(20.0));
        // Shorter, 3 m after the last trigger: counted from here, 1 m later than from the
        // last picture.
        t.set(1.0, 18.0);
        assert_eq!(t.next_m(), Some(19.0));
        // Capture commands do not move the count.
        t.other_picture(18.5);
        assert_eq!(t.next_m(), Some(19.0));
        t.set(0.0, 19.0);
        assert_eq!(t.next_m(), None);
    }

    #[test]
    fn ardupilot_counts_from_the_last_picture_whatever_took_it() {
        let mut t = DistanceTrigger::new(Autopilot::ArduPilot);
        // Enabled at 10 m: counted from there, no picture.
        t.set(5.0, 10.0);
        assert_eq!(t.next_m(), Some(15.0));
        t.fired(15.0);
        // A shorter distance 3 m on: from the last picture, so it falls behind the
        // vehicle (16 m < 18 m) and fires at once.
        t.set(1.0, 18.0);
        assert_eq!(t.next_m(), Some(16.0));
        t.fired(18.0);
        assert_eq!(t.next_m(), Some(19.0));
        // A longer one does not restart the count either.
        t.set(4.0, 18.5);
        assert_eq!(t.next_m(), Some(22.0));
        // A capture command's picture does.
        t.other_picture(20.0);
        assert_eq!(t.next_m(), Some(24.0));
        // Off forgets the last picture; on again counts from the command.
        t.set(0.0, 21.0);
        assert_eq!(t.next_m(), None);
        t.set(4.0, 30.0);
        assert_eq!(t.next_m(), Some(34.0));
        t.off();
        assert!(!t.is_on());
        t.set(f64::NAN, 31.0);
        assert_eq!(t.next_m(), None);
    }

    #[test]
    fn px4_shoots_once_for_a_new_distance_and_counts_from_that_picture() {
        let mut t = DistanceTrigger::new(Autopilot::Px4);
        assert!(!t.command_shoots_once());
        // A new distance: a picture at the next check, wherever the last one was.
        t.set(5.0, 10.0);
        assert_eq!(t.next_m(), Some(f64::NEG_INFINITY));
        t.fired(10.4);
        assert_eq!(t.next_m(), Some(15.4));
        t.fired(15.5);
        // A longer distance restarts too (not counted from 15.5 m).
        t.set(8.0, 17.0);
        assert_eq!(t.next_m(), Some(f64::NEG_INFINITY));
        t.fired(17.2);
        assert_eq!(t.next_m(), Some(25.2));
        // Capture commands do not move the count.
        t.other_picture(20.0);
        assert_eq!(t.next_m(), Some(25.2));
        t.set(-1.0, 21.0);
        assert_eq!(t.next_m(), None);
        assert_eq!(check_period_ns(Autopilot::Px4), Some(50_000_000));
    }
}
