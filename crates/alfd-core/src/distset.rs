//! Setting the autopilot's own distance trigger online (MAV_CMD_DO_SET_CAM_TRIGG_DIST):
//! when to send a new distance. The distance sent is the wished spacing
//! shortened by a margin, so estimator noise within the margin sends nothing.
//! A wish below the distance in force (or on its way) is sent at once, by any
//! amount and whatever the rate limit: the autopilot would otherwise capture
//! too far apart, and each such send lowers the distance by at least the
//! margin, so a falling spacing costs at most one command per estimate. A
//! longer one waits for a hysteresis and the rate limit, so noise does not
//! flood the link; unacknowledged commands are repeated. Pure: time is an
//! argument.

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceSetterParams {
    /// A longer distance is sent only when it exceeds the one in force by this fraction.
    pub hysteresis: f64,
    /// The distance sent is the wish shortened by this fraction (taken within
    /// `[0, 0.5]`; NaN: 0).
    pub margin: f64,
    /// At most one longer distance or repeat per this many seconds (the first
    /// and every shorter one are never held).
    pub min_interval_s: f64,
    /// An unacknowledged command is sent again after this long.
    pub ack_timeout_s: f64,
}

impl Default for DistanceSetterParams {
    fn default() -> Self {
        DistanceSetterParams {
            hysteresis: 0.15,
            // Meant to sit above the spacing's jitter from frame to frame on
            // noisy Z16, so a steady spacing holds one distance: set before
            // any flight was judged with it, and that jitter not measured.
            margin: 0.03,
            min_interval_s: 0.5,
            ack_timeout_s: 1.0,
        }
    }
}

/// Where the autopilot counts a new distance from, which decides whether a
/// command must also take a picture (its param3, "trigger once").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Counting {
    /// From where the command arrives (firmware-sim's generic autopilot; an
    /// autopilot not known): without a picture there, the interval from the
    /// last one would be the way already flown plus the new distance, so
    /// every command triggers once.
    #[default]
    FromCommand,
    /// From the last picture, whatever took it (ArduPilot's `AP_Camera`): a
    /// distance already flown fires at once, so a command needs no picture,
    /// except while none is known in force (the first, or after a reboot:
    /// enabling the trigger counts from there). The wish fed to
    /// [`DistanceSetter::update`] must then be the tightest spacing since the
    /// last picture, which the interval spans.
    FromLastPicture,
}

/// ArduPilot's `AP_Camera::update` runs at 50 Hz: its distance trigger fires
/// at the first update past the distance.
pub const ARDUPILOT_CAMERA_UPDATE_S: f64 = 0.02;

/// PX4's `camera_trigger` runs every 50 ms: its distance trigger fires at the
/// first poll past the distance.
pub const PX4_TRIGGER_POLL_S: f64 = 0.05;

/// The shortest distance asked for: below it every check of the autopilot fires.
pub const DISTANCE_MIN_M: f64 = 0.01;

/// How far past its distance an autopilot checking every `check_period_s` may
/// fire at `speed_mps`: the way flown in one check (0 for an autopilot firing
/// at the point, as firmware-sim's generic one).
pub fn late_m(check_period_s: f64, speed_mps: f64) -> f64 {
    let v = if speed_mps.is_finite() {
        speed_mps.max(0.0)
    } else {
        0.0
    };
    let p = if check_period_s.is_finite() {
        check_period_s.max(0.0)
    } else {
        0.0
    };
    v * p
}

#[derive(Debug, Clone, PartialEq)]
pub struct DistanceSetter {
    params: DistanceSetterParams,
    counting: Counting,
    /// How often the autopilot checks its distance, s (0: at the point).
    check_period_s: f64,
    /// Whether the distance `update` last returned should also trigger once.
    trigger_now: bool,
    /// The distance the autopilot acknowledged.
    in_force_m: Option<f64>,
    /// Sent, not yet acknowledged: (distance, when).
    pending: Option<(f64, f64)>,
    last_sent_s: Option<f64>,
    pub sent: u64,
    /// Of `sent`, those that also triggered once.
    pub sent_with_picture: u64,
    pub acked: u64,
    pub refused: u64,
}

impl DistanceSetter {
    pub fn new(params: DistanceSetterParams) -> Self {
        DistanceSetter {
            params,
            counting: Counting::default(),
            check_period_s: 0.0,
            trigger_now: true,
            in_force_m: None,
            pending: None,
            last_sent_s: None,
            sent: 0,
            sent_with_picture: 0,
            acked: 0,
            refused: 0,
        }
    }

    /// The distance the autopilot has acknowledged.
    pub fn in_force_m(&self) -> Option<f64> {
        self.in_force_m
    }

    /// How the autopilot counts (learnt from its HEARTBEAT).
    pub fn set_counting(&mut self, counting: Counting) {
        self.counting = counting;
    }

    pub fn counting(&self) -> Counting {
        self.counting
    }

    /// How often the autopilot checks its distance (learnt from its
    /// HEARTBEAT: [`ARDUPILOT_CAMERA_UPDATE_S`], [`PX4_TRIGGER_POLL_S`]).
    pub fn set_check_period_s(&mut self, check_period_s: f64) {
        self.check_period_s = check_period_s;
    }

    /// The wish to ask for so that a picture up to one check late (the way
    /// flown at `speed_mps` in [`late_m`]) still meets `wanted_m`; at least
    /// [`DISTANCE_MIN_M`].
    pub fn wish_m(&self, wanted_m: f64, speed_mps: f64) -> f64 {
        (wanted_m - late_m(self.check_period_s, speed_mps)).max(DISTANCE_MIN_M)
    }

    /// The fastest ground speed at which the autopilot's checks still meet
    /// `spacing_m` (the wish stays at or above [`DISTANCE_MIN_M`]); infinite
    /// for an autopilot firing at the point, 0 for a spacing it cannot ask for.
    pub fn speed_max_mps(&self, spacing_m: f64) -> f64 {
        if !(self.check_period_s.is_finite() && self.check_period_s > 0.0) {
            return f64::INFINITY;
        }
        let room_m = spacing_m - DISTANCE_MIN_M;
        if room_m.is_nan() || room_m <= 0.0 {
            return 0.0;
        }
        room_m / self.check_period_s
    }

    /// Whether the distance `update` last returned should also take a picture
    /// (the command's param3).
    pub fn trigger_now(&self) -> bool {
        self.trigger_now
    }

    /// The autopilot lost its distance (it rebooted): the next estimate sends
    /// one at once, as the first.
    pub fn forget(&mut self) {
        self.in_force_m = None;
        self.pending = None;
        self.last_sent_s = None;
    }

    /// Feed the spacing wanted now; returns a distance to send, if one is due.
    pub fn update(&mut self, now_s: f64, wanted_m: f64) -> Option<f64> {
        if !(wanted_m.is_finite() && wanted_m > 0.0 && now_s.is_finite()) {
            return None;
        }
        let margin = if self.params.margin.is_finite() {
            self.params.margin.clamp(0.0, 0.5)
        } else {
            0.0
        };
        let d = wanted_m * (1.0 - margin);
        let reference = self.pending.map(|(d, _)| d).or(self.in_force_m);
        // Below what the autopilot holds (or will): too far apart from now on.
        let shorter = reference.is_none_or(|r| wanted_m < r);
        let longer = reference.is_some_and(|r| d > r * (1.0 + self.params.hysteresis));
        let resend = match self.pending {
            Some((_, at)) => now_s - at >= self.params.ack_timeout_s,
            None => false,
        };
        if !(shorter || longer || resend) {
            return None;
        }
        if !shorter {
            if let Some(last) = self.last_sent_s {
                if now_s - last < self.params.min_interval_s {
                    return None;
                }
            }
        }
        // A resend carries the newest wish, not the stale one.
        let d = if shorter || longer {
            d
        } else {
            self.pending.map_or(d, |(d, _)| d)
        };
        self.trigger_now = match self.counting {
            Counting::FromCommand => true,
            Counting::FromLastPicture => self.in_force_m.is_none(),
        };
        self.pending = Some((d, now_s));
        self.last_sent_s = Some(now_s);
        self.sent += 1;
        self.sent_with_picture += u64::from(self.trigger_now);
        Some(d)
    }

    /// The autopilot's answer to the last command sent.
    pub fn on_ack(&mut self, accepted: bool) {
        let Some((d, _)) = self.pending.take() else {
            return;
        };
        if accepted {
            self.in_force_m = Some(d);
            self.acked += 1;
        } else {
            self.refused += 1;
        }
    }
}

/// Frames kept to split at a picture that is heard of late: a second at 30 fps.
const RECENT_FRAMES: usize = 32;

/// How far a picture's instant may be off the frames' clock: TIMESYNC's fit, and for a
/// CAMERA_FEEDBACK its GPS stamp mapped through SYSTEM_TIME's millisecond. A frame this
/// close before a picture may as well be after it, and is counted in the interval the
/// picture opens as well as the one it closes: from a millimetre or two away it sees what
/// the picture's neighbourhood needs (a frame 55 µs before a CAMERA_FEEDBACK's mapped
/// instant, left out of the new interval, let its distance run 1.09× past that frame's
/// spacing in `alfd sim --autopilot ardupilot --mode autopilot_distance`).
pub const PICTURE_SLACK_NS: u64 = 2_000_000;

/// The tightest spacing over the frames since the autopilot's last picture,
/// by the frames' own times: the picture is heard of after some frames taken
/// after it were estimated (the link's latency), and those belong to the new
/// interval; so do the frames within [`PICTURE_SLACK_NS`] before it. Pure: times
/// are arguments.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SinceLastPicture {
    /// The newest frames' (time, spacing, the tightest since the last picture
    /// up to this frame), oldest first, at most `RECENT_FRAMES`.
    recent: std::collections::VecDeque<(u64, f64, Option<f64>)>,
    picture_ns: Option<u64>,
    tightest_m: Option<f64>,
}

impl SinceLastPicture {
    /// A frame taken at `mono_ns` wants `spacing_m`.
    pub fn on_spacing(&mut self, mono_ns: u64, spacing_m: f64) {
        if !(spacing_m.is_finite() && spacing_m > 0.0) {
            return;
        }
        if self.recent.len() == RECENT_FRAMES {
            self.recent.pop_front();
        }
        // A frame from before the last picture, estimated after it was heard
        // of, belongs to the interval already closed: not counted (unless it
        // is within the slack of it).
        let counts = self
            .picture_ns
            .is_none_or(|p| mono_ns.saturating_add(PICTURE_SLACK_NS) >= p);
        if counts {
            self.tightest_m = Some(self.tightest_m.map_or(spacing_m, |t| t.min(spacing_m)));
        }
        let run = if counts { self.tightest_m } else { None };
        self.recent.push_back((mono_ns, spacing_m, run));
    }

    /// The autopilot took a picture at `mono_ns`: returns the tightest spacing
    /// of the interval it closes (the frames from the last picture up to this
    /// one; `None`: no frame in it). An older picture than the last is ignored
    /// (`None`).
    pub fn on_picture(&mut self, mono_ns: u64) -> Option<f64> {
        if self.picture_ns.is_some_and(|p| mono_ns <= p) {
            return None;
        }
        // The closing interval's frames end with the newest frame before the
        // picture; its running tightest is theirs (frames come in time order).
        // Without one kept, no frame was heard of after the last picture and
        // before this one, or it came before that picture.
        let closing = match self.recent.iter().rev().find(|(t, _, _)| *t < mono_ns) {
            Some(&(t, _, run)) if self.picture_ns.is_none_or(|p| t >= p) => run,
            _ => None,
        };
        self.picture_ns = Some(mono_ns);
        let mut run: Option<f64> = None;
        let opens_from = mono_ns.saturating_sub(PICTURE_SLACK_NS);
        for e in self.recent.iter_mut().filter(|e| e.0 >= opens_from) {
            run = Some(run.map_or(e.1, |r: f64| r.min(e.1)));
            e.2 = run;
        }
        self.tightest_m = run;
        closing
    }

    /// The tightest spacing since the last picture (`None`: no frame since).
    pub fn tightest_m(&self) -> Option<f64> {
        self.tightest_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setter() -> DistanceSetter {
        DistanceSetter::new(DistanceSetterParams::default())
    }

    /// The distance sent for a wish: 3 % shorter.
    fn sent(wanted_m: f64) -> Option<f64> {
        Some(wanted_m * 0.97)
    }

    #[test]
    fn the_first_distance_goes_at_once_and_holds_once_acknowledged() {
        let mut s = setter();
        assert_eq!(s.update(0.0, 5.0), sent(5.0));
        s.on_ack(true);
        assert_eq!(s.in_force_m(), sent(5.0));
        // Noise within the margin and the hysteresis sends nothing.
        for (k, d) in [5.2, 4.9, 5.6, 5.05].into_iter().enumerate() {
            assert_eq!(s.update(1.0 + k as f64, d), None, "{d}");
        }
        assert_eq!(s.sent, 1);
    }

    #[test]
    fn shorter_is_sent_by_any_amount_longer_only_past_the_hysteresis() {
        let mut s = setter();
        s.update(0.0, 5.0);
        s.on_ack(true);
        // 4.85 m in force: a wish 0.1 % below it is sent (no dead band past
        // the promise).
        assert_eq!(s.update(1.0, 4.845), sent(4.845));
        s.on_ack(true);
        assert_eq!(s.update(2.0, 5.5), None, "within the hysteresis");
        assert_eq!(s.update(3.0, 5.8), sent(5.8));
    }

    #[test]
    fn a_falling_spacing_is_followed_at_every_estimate_whatever_the_rate_limit() {
        let mut s = setter();
        s.update(0.0, 1.0);
        s.on_ack(true);
        // 30 estimates a second, the spacing falling 2 % each, no ack yet for
        // most: each wish below the last distance sent goes out.
        let mut wish = 1.0;
        let mut sends = 0;
        for k in 1..=30 {
            wish *= 0.98;
            let t = k as f64 / 30.0;
            if let Some(d) = s.update(t, wish) {
                assert_eq!(d, wish * 0.97);
                sends += 1;
            }
            // Every wish at or above what the autopilot is asked to hold.
            let asked = s.pending.map(|p| p.0).or(s.in_force_m()).unwrap();
            assert!(asked <= wish, "{asked} asked for a wish of {wish}");
        }
        // Each send lowers the distance by the margin: not one per estimate.
        assert!((10..=16).contains(&sends), "{sends} sends");
    }

    #[test]
    fn the_rate_limit_holds_longer_distances_then_the_newest_wish_goes() {
        let mut s = setter();
        s.update(0.0, 2.0);
        s.on_ack(true);
        assert_eq!(s.update(0.1, 3.0), None, "0.1 s after the last send");
        assert_eq!(s.update(0.3, 4.0), None);
        assert_eq!(s.update(0.6, 3.5), sent(3.5));
    }

    #[test]
    fn an_unacknowledged_command_is_repeated_and_a_refusal_keeps_the_old_distance() {
        let mut s = setter();
        assert_eq!(s.update(0.0, 5.0), sent(5.0));
        assert_eq!(s.update(0.5, 5.0), None, "waiting for the ack");
        assert_eq!(s.update(1.0, 5.0), sent(5.0), "resent after the timeout");
        s.on_ack(false);
        assert_eq!(s.in_force_m(), None);
        assert_eq!(s.refused, 1);
        assert_eq!(s.update(2.0, 5.0), sent(5.0));
    }

    #[test]
    fn bad_wishes_send_nothing() {
        let mut s = setter();
        for d in [f64::NAN, f64::INFINITY, 0.0, -1.0] {
            assert_eq!(s.update(0.0, d), None);
        }
        assert_eq!(s.update(f64::NAN, 3.0), None);
    }

    #[test]
    fn a_command_triggers_once_unless_the_autopilot_counts_from_its_last_picture() {
        // Counting from the command: every distance sent takes a picture.
        let mut s = setter();
        s.update(0.0, 5.0);
        assert!(s.trigger_now());
        s.on_ack(true);
        s.update(1.0, 4.0);
        assert!(s.trigger_now());
        // Counting from the last picture: only until a distance is known in
        // force (a lost first command is resent with its picture too).
        let mut s = setter();
        s.set_counting(Counting::FromLastPicture);
        assert_eq!(s.update(0.0, 5.0), sent(5.0));
        assert!(s.trigger_now());
        assert_eq!(s.update(1.0, 5.0), sent(5.0), "resent");
        assert!(s.trigger_now());
        s.on_ack(true);
        assert_eq!(s.update(2.0, 4.0), sent(4.0));
        assert!(!s.trigger_now());
        s.on_ack(true);
        assert_eq!(s.update(3.0, 6.0), sent(6.0));
        assert!(!s.trigger_now());
    }

    #[test]
    fn after_a_reboot_the_distance_is_sent_again_at_once() {
        let mut s = setter();
        s.set_counting(Counting::FromLastPicture);
        s.update(0.0, 5.0);
        s.on_ack(true);
        s.update(0.2, 4.0);
        s.on_ack(true);
        // A steady wish sends nothing while the autopilot holds it.
        assert_eq!(s.update(0.3, 4.0), None);
        // Rebooted: it holds nothing. The same wish goes out at once (within
        // the rate limit of the last send), with a picture, as the first did.
        s.forget();
        assert_eq!(s.in_force_m(), None);
        assert_eq!(s.update(0.4, 4.0), sent(4.0));
        assert!(s.trigger_now());
    }

    #[test]
    fn the_tightest_since_a_picture_counts_the_frames_after_it_heard_of_late() {
        const MS: u64 = 1_000_000;
        let mut w = SinceLastPicture::default();
        for (t, sp) in [(100, 2.0), (133, 0.7), (166, 3.0), (200, 5.0)] {
            w.on_spacing(t * MS, sp);
        }
        assert_eq!(w.tightest_m(), Some(0.7));
        // A picture at 150 heard of after the frames at 166 and 200: they are its interval's.
        // The interval it closes: the frames before it (0.7 m the tightest).
        assert_eq!(w.on_picture(150 * MS), Some(0.7));
        assert_eq!(w.tightest_m(), Some(3.0));
        // A late frame from before the picture does not count.
        w.on_spacing(140 * MS, 0.1);
        assert_eq!(w.tightest_m(), Some(3.0));
        w.on_spacing(233 * MS, 2.5);
        assert_eq!(w.tightest_m(), Some(2.5));
        // An older picture heard of later changes nothing.
        assert_eq!(w.on_picture(120 * MS), None);
        assert_eq!(w.tightest_m(), Some(2.5));
        // A picture after every frame: nothing since it yet; bad spacings are ignored.
        // It closes 166 … 233 (not the late 140).
        assert_eq!(w.on_picture(300 * MS), Some(2.5));
        assert_eq!(w.tightest_m(), None);
        w.on_spacing(310 * MS, f64::NAN);
        assert_eq!(w.tightest_m(), None);
        // Only the newest frames are kept.
        for k in 0..100u64 {
            w.on_spacing((400 + k) * MS, 1.0 + k as f64);
        }
        // No valid frame between 300 and 400 (310 was NaN).
        assert_eq!(w.on_picture(400 * MS), None);
        assert_eq!(w.tightest_m(), Some(1.0 + (100 - RECENT_FRAMES) as f64));
    }

    /// A frame within the slack before a picture counts in both intervals: the closing
    /// one (by its time) and the one the picture opens (its instant may be off by that
    /// much); one further before counts in the closing one only.
    #[test]
    fn a_frame_within_the_slack_of_a_picture_counts_on_both_sides() {
        const MS: u64 = 1_000_000;
        let mut w = SinceLastPicture::default();
        w.on_spacing(1000 * MS, 4.0);
        w.on_spacing(1033 * MS, 0.5);
        w.on_spacing(1066 * MS, 3.0);
        // The picture 1 ms after the 0.5 m frame: it closes 4.0 and 0.5, and opens with
        // 0.5 and 3.0.
        assert_eq!(w.on_picture(1034 * MS), Some(0.5));
        assert_eq!(w.tightest_m(), Some(0.5));
        // The picture 3 ms after a 0.2 m frame: closed, not carried over.
        w.on_spacing(1100 * MS, 0.2);
        assert_eq!(w.on_picture(1103 * MS), Some(0.2));
        assert_eq!(w.tightest_m(), None);
        // A frame heard of late, 1 ms before the last picture, counts in its interval.
        w.on_spacing(1102 * MS, 0.9);
        assert_eq!(w.tightest_m(), Some(0.9));
        w.on_spacing(1090 * MS, 0.1);
        assert_eq!(w.tightest_m(), Some(0.9));
    }

    #[test]
    fn an_autopilot_checking_at_50_hz_is_asked_for_its_lateness_less() {
        let mut s = DistanceSetter::new(DistanceSetterParams::default());
        // Firing at the point: asked for the spacing itself, at any speed.
        assert_eq!(s.wish_m(1.0, 10.0), 1.0);
        assert_eq!(s.speed_max_mps(0.3), f64::INFINITY);
        s.set_check_period_s(ARDUPILOT_CAMERA_UPDATE_S);
        assert!((late_m(ARDUPILOT_CAMERA_UPDATE_S, 10.0) - 0.2).abs() < 1e-12);
        assert!((s.wish_m(1.0, 10.0) - 0.8).abs() < 1e-12);
        // Beyond what it can meet: every update fires.
        assert_eq!(s.wish_m(0.1, 10.0), DISTANCE_MIN_M);
        for v in [f64::NAN, -3.0, f64::NEG_INFINITY] {
            assert_eq!(late_m(ARDUPILOT_CAMERA_UPDATE_S, v), 0.0);
        }
        for p in [f64::NAN, -1.0, f64::INFINITY] {
            assert_eq!(late_m(p, 10.0), 0.0);
        }
    }

    #[test]
    fn a_polling_autopilot_meets_a_spacing_only_below_a_speed() {
        let mut s = DistanceSetter::new(DistanceSetterParams::default());
        s.set_check_period_s(PX4_TRIGGER_POLL_S);
        // 0.3 m with a 50 ms poll: up to 5.8 m/s; at 10 m/s a poll is 0.5 m
        // and every poll fires (the wish at its floor).
        let v_max = s.speed_max_mps(0.3);
        assert!((v_max - 5.8).abs() < 1e-9, "{v_max}");
        assert!((s.wish_m(0.3, v_max) - DISTANCE_MIN_M).abs() < 1e-12);
        assert_eq!(s.wish_m(0.3, 10.0), DISTANCE_MIN_M);
        assert!((s.wish_m(0.3, 4.0) - 0.1).abs() < 1e-12);
        for bad in [0.0, DISTANCE_MIN_M, -1.0, f64::NAN] {
            assert_eq!(s.speed_max_mps(bad), 0.0, "{bad}");
        }
        assert_eq!(s.speed_max_mps(f64::INFINITY), f64::INFINITY);
    }
}
