//! The autopilot's distance trigger (MAV_CMD_DO_SET_CAM_TRIGG_DIST, `CAM_TRIGG_DIST`) as each
//! autopilot counts it: from where is the next picture's distance measured. Pure: positions
//! are the path flown (m), arguments.
//!
//! - `Generic` (what firmware-sim always did): a new distance counts from where the command
//!   arrives; pictures taken by other commands do not move the count.
//! - `ArduPilot` (`AP_Camera_Backend::update`, `take_picture`): the distance counts from the
//!   last picture, whatever took it; a new distance does not restart the count, so one shorter
//!   than the way already flown fires at the next update. With the trigger off the last
//!   picture is forgotten, and enabling it counts from there, with no picture.
//!
//! ArduPilot measures the straight-line distance from the last picture; this counts along the
//! path, the same on a straight lane and longer round a turn.

use crate::config::Autopilot;

#[derive(Clone, Debug, PartialEq)]
pub struct DistanceTrigger {
    autopilot: Autopilot,
    /// The distance in force (`None`: off).
    dist_m: Option<f64>,
    /// Where the count starts.
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
        let restart = match self.autopilot {
            Autopilot::Generic => true,
            Autopilot::ArduPilot => self.dist_m.is_none(),
        };
        if restart {
            self.from_m = here_m;
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
            Autopilot::Generic => {}
            Autopilot::ArduPilot => self.from_m = here_m,
        }
    }

    /// Where the next picture falls on the path (`None`: off). At or behind the vehicle: now.
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
}
