//! Property tests of the link's pure parts: the local projection against geodesic distances
//! (Vincenty's inverse formula, itself checked against his published example), the TIMESYNC
//! filter, the pose buffer, the glitch gate and the reconnect backoff. Cases per property:
//! `ALFD_PROPTEST_CASES` (default 100000; the heavier TIMESYNC properties run a tenth of it).

use alfd::core::backoff::reconnect_delay_ms;
use alfd::core::geo::{Geodetic, LocalFrame, WGS84_A_M, WGS84_F};
use alfd::core::glitch::{GlitchConfig, GlitchGate, Verdict};
use alfd::core::pose::{AttitudeSample, PoseBuffer, PoseBufferConfig, PositionSample};
use alfd::core::timesync::{TimeCheck, TimeSync, TimeSyncConfig};
use glam::{DQuat, DVec3};
use proptest::prelude::*;

fn cases(divisor: u32) -> ProptestConfig {
    let n: u32 = std::env::var("ALFD_PROPTEST_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    ProptestConfig {
        cases: (n / divisor).max(1),
        ..ProptestConfig::default()
    }
}

/// Geodesic distance on the WGS-84 ellipsoid (Vincenty 1975, inverse), metres.
fn vincenty_m(lat1: f64, lon1: f64, lat2: f64, lon2: f64) -> f64 {
    let (a, f) = (WGS84_A_M, WGS84_F);
    let b = a * (1.0 - f);
    let l = (lon2 - lon1).to_radians();
    let u1 = ((1.0 - f) * lat1.to_radians().tan()).atan();
    let u2 = ((1.0 - f) * lat2.to_radians().tan()).atan();
    let (su1, cu1, su2, cu2) = (u1.sin(), u1.cos(), u2.sin(), u2.cos());
    let mut lambda = l;
    let (mut ss, mut cs, mut sigma, mut ca2, mut c2sm);
    loop {
        let (sl, cl) = (lambda.sin(), lambda.cos());
        ss = ((cu2 * sl).powi(2) + (cu1 * su2 - su1 * cu2 * cl).powi(2)).sqrt();
        if ss == 0.0 {
            return 0.0;
        }
        cs = su1 * su2 + cu1 * cu2 * cl;
        sigma = ss.atan2(cs);
        let sa = cu1 * cu2 * sl / ss;
        ca2 = 1.0 - sa * sa;
        c2sm = if ca2 != 0.0 {
            cs - 2.0 * su1 * su2 / ca2
        } else {
            0.0
        };
        let c = f / 16.0 * ca2 * (4.0 + f * (4.0 - 3.0 * ca2));
        let prev = lambda;
        lambda = l
            + (1.0 - c) * f * sa * (sigma + c * ss * (c2sm + c * cs * (-1.0 + 2.0 * c2sm * c2sm)));
        if (lambda - prev).abs() < 1e-13 {
            break;
        }
    }
    let u2b = ca2 * (a * a - b * b) / (b * b);
    let ka = 1.0 + u2b / 16384.0 * (4096.0 + u2b * (-768.0 + u2b * (320.0 - 175.0 * u2b)));
    let kb = u2b / 1024.0 * (256.0 + u2b * (-128.0 + u2b * (74.0 - 47.0 * u2b)));
    let ds = kb
        * ss
        * (c2sm
            + kb / 4.0
                * (cs * (-1.0 + 2.0 * c2sm * c2sm)
                    - kb / 6.0 * c2sm * (-3.0 + 4.0 * ss * ss) * (-3.0 + 4.0 * c2sm * c2sm)));
    b * ka * (sigma - ds)
}

fn dms(d: f64, m: f64, s: f64) -> f64 {
    d.signum() * (d.abs() + m / 60.0 + s / 3600.0)
}

#[test]
fn vincenty_matches_his_published_example() {
    // Flinders Peak to Buninyong: 54 972.271 m (Vincenty 1975; GRS80 and WGS-84 agree here to
    // well under a millimetre).
    let d = vincenty_m(
        dms(-37.0, 57.0, 3.72030),
        dms(144.0, 25.0, 29.52440),
        dms(-37.0, 39.0, 10.15610),
        dms(143.0, 55.0, 35.38390),
    );
    assert!((d - 54_972.271).abs() < 2e-3, "{d}");
}

proptest! {
    #![proptest_config(cases(10))]

    /// Horizontal distance in the local frame equals the geodesic distance up to the tangent
    /// plane's own shortening, R·sin(d/R) ≈ d − d³/6R²: 0.03 mm at 2 km, 0.3 mm at 4 km.
    #[test]
    fn projection_matches_geodesic_distances(
        lat in -80.0f64..80.0, lon in -180.0f64..180.0,
        north in -5000.0f64..5000.0, east in -5000.0f64..5000.0,
    ) {
        let home = Geodetic { lat_deg: lat, lon_deg: lon, alt_m: 0.0 };
        let frame = LocalFrame::new(home);
        // A point on the ellipsoid (height 0) about (north, east) from home.
        let mut p = frame.to_geodetic([north, east, 0.0]);
        p.alt_m = 0.0;
        let ned = frame.to_ned(p);
        let geodesic = vincenty_m(lat, lon, p.lat_deg, p.lon_deg);
        let shortening = geodesic.powi(3) / (6.0 * WGS84_A_M * WGS84_A_M);
        let horizontal = ned[0].hypot(ned[1]);
        prop_assert!((horizontal + shortening - geodesic).abs() < 1e-4 + 0.05 * shortening,
            "{horizontal} + {shortening} vs {geodesic}");
        prop_assert!(horizontal <= geodesic + 1e-4);
    }

    /// The backoff never shrinks, never passes the cap, starts at the initial delay.
    #[test]
    fn backoff_is_monotone_and_capped(attempt in 0u32..100, initial in 0u64..10_000, extra in 0u64..100_000) {
        let max = initial + extra;
        let (a, b) = (reconnect_delay_ms(attempt, initial, max), reconnect_delay_ms(attempt + 1, initial, max));
        prop_assert!(a <= b && b <= max);
        prop_assert_eq!(reconnect_delay_ms(0, initial, max), initial);
    }

    /// Linear motion is interpolated exactly; slerp turns by the fraction of the angle.
    #[test]
    fn pose_buffer_interpolates_exactly(
        v in prop::array::uniform3(-20.0f64..20.0), gaps in prop::collection::vec(1u64..300, 3..40),
        u in 0.0f64..1.0, angle in 0.0f64..3.0,
    ) {
        let mut b = PoseBuffer::new(PoseBufferConfig { horizon_ns: 0, keep_ns: u64::MAX / 4, max_samples: 100 });
        let vel = DVec3::from_array(v);
        let mut t = 1_000_000_000u64;
        let times: Vec<u64> = gaps.iter().map(|g| { t += g * 1_000_000; t }).collect();
        for (k, &t) in times.iter().enumerate() {
            let pos = vel * (t as f64 * 1e-9);
            b.push_position(PositionSample { time_ns: t, pos_ned_m: pos, vel_ned_mps: vel }).unwrap();
            let q = DQuat::from_rotation_z(angle * k as f64);
            b.push_attitude(AttitudeSample { time_ns: t, q, rates_rps: DVec3::ZERO }).unwrap();
        }
        let (t0, t1) = (times[0], times[1]);
        let tq = t0 + ((t1 - t0) as f64 * u) as u64;
        let p = b.at(tq).unwrap();
        prop_assert!((p.pos_ned_m - vel * (tq as f64 * 1e-9)).length() < 1e-6);
        let frac = (tq - t0) as f64 / (t1 - t0) as f64;
        let expect = DQuat::from_rotation_z(angle * frac);
        prop_assert!(p.q.angle_between(expect) < 1e-6);
        prop_assert!(b.at(*times.last().unwrap() + 1).is_err(), "horizon 0: nothing past the newest");
    }

    /// Constant acceleration (up to 5 m/s² each way, samples up to 300 ms apart) is followed
    /// exactly between samples (the cubic through positions and velocities) and past the newest
    /// (the last two velocities' acceleration), where a chord or the velocity alone would be
    /// off by `a·Δt²/8` and `a·τ²/2`.
    #[test]
    fn pose_buffer_follows_constant_acceleration(
        v in prop::array::uniform3(-20.0f64..20.0), a in prop::array::uniform3(-5.0f64..5.0),
        gaps in prop::collection::vec(1u64..300, 3..40), u in 0.0f64..1.0, ahead_ms in 0u64..200,
    ) {
        let mut b = PoseBuffer::new(PoseBufferConfig { horizon_ns: 200_000_000, keep_ns: u64::MAX / 4, max_samples: 100 });
        let (vel, acc) = (DVec3::from_array(v), DVec3::from_array(a));
        let at = |t: u64| {
            let s = (t - 1_000_000_000) as f64 * 1e-9;
            (vel * s + 0.5 * acc * s * s, vel + acc * s)
        };
        let mut t = 1_000_000_000u64;
        let times: Vec<u64> = gaps.iter().map(|g| { t += g * 1_000_000; t }).collect();
        for &t in &times {
            let (pos, v) = at(t);
            b.push_position(PositionSample { time_ns: t, pos_ned_m: pos, vel_ned_mps: v }).unwrap();
            b.push_attitude(AttitudeSample { time_ns: t, q: DQuat::IDENTITY, rates_rps: DVec3::ZERO }).unwrap();
        }
        let k = times.len() / 2;
        let (t0, t1) = (times[k - 1], times[k]);
        let tq = t0 + ((t1 - t0) as f64 * u) as u64;
        let p = b.at(tq).unwrap();
        prop_assert!((p.pos_ned_m - at(tq).0).length() < 1e-6, "{} {}", p.pos_ned_m, at(tq).0);
        prop_assert!((p.vel_ned_mps - at(tq).1).length() < 1e-6);
        let te = times.last().unwrap() + ahead_ms * 1_000_000;
        let p = b.at(te).unwrap();
        prop_assert!((p.pos_ned_m - at(te).0).length() < 1e-6, "{} {}", p.pos_ned_m, at(te).0);
        prop_assert!((p.vel_ned_mps - at(te).1).length() < 1e-6);
    }

    /// A track within tolerance is never flagged; a jump beyond it always is, and is not followed.
    #[test]
    fn glitch_gate_flags_jumps_only(
        v in prop::array::uniform2(-15.0f64..15.0), noise in prop::collection::vec(-0.5f64..0.5, 30),
        jump in prop::array::uniform2(-100.0f64..100.0),
    ) {
        let mut g = GlitchGate::new(GlitchConfig::default());
        let vel = DVec3::new(v[0], v[1], 0.0);
        for (k, n) in noise.iter().enumerate() {
            let t = k as u64 * 100_000_000;
            let pos = vel * (k as f64 * 0.1) + DVec3::new(*n, -n, 0.0);
            prop_assert_eq!(g.check(t, pos, vel), Verdict::Accept);
        }
        let j = DVec3::new(jump[0], jump[1], 0.0);
        let pos = vel * 3.0 + j;
        let flagged = matches!(g.check(3_000_000_000, pos, vel), Verdict::Glitch { .. });
        // Tolerance 2 m + 0.5·6·0.1² m, plus up to 0.7 m of the track's own noise.
        if j.length() < 1.2 {
            prop_assert!(!flagged);
        }
        if j.length() > 2.8 {
            prop_assert!(flagged);
            // A persistent jump stays rejected (never silently followed) until re-anchoring.
            for k in 31..120u64 {
                let v = g.check(k * 100_000_000, vel * (k as f64 * 0.1) + j, vel);
                prop_assert!(matches!(v, Verdict::Glitch { .. }), "sample {k}: {v:?}");
            }
        }
    }
}

/// The TIMESYNC filter on simulated time, under what `link_faults`'s
/// `time_sync_under_10_ms_jitter` puts on a pty: firmware-sim delays each frame it sends by
/// 0–10 ms (uniform, its `faults.jitter`) and delivers in order (a frame waits for the one
/// before it), telemetry goes out every 20 ms besides the answers, the request takes 0.1 ms,
/// the autopilot's clock runs 20 ppm fast (its default drift), exchanges at the link's
/// default 10 Hz. Sampled every 10 ms over a minute after 5 s, the estimate's RMS error stays
/// under 1 ms (issue 5's target), the same on every run; over the pty the error is printed,
/// not asserted (the wall clock is not a test's).
#[test]
fn timesync_rms_under_1_ms_with_10_ms_jitter_on_simulated_time() {
    let mut ts = TimeSync::new(TimeSyncConfig::default());
    let boot_at: u64 = 3_600_000_000_000;
    let remote_at = |local: u64| ((local - boot_at) as f64 * (1.0 + 20e-6)) as u64;
    // SplitMix64: a fixed, seeded sequence of delays.
    let mut state = 26u64;
    let mut unit = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)) as f64 / u64::MAX as f64
    };
    const MS: u64 = 1_000_000;
    let start = boot_at + 2_000 * MS;
    let (mut sq, mut n, mut worst) = (0.0f64, 0u32, 0.0f64);
    let (mut last_delivery, mut next_telemetry) = (0u64, start + 7 * MS);
    let mut delivered = |sent_ns: u64, last: &mut u64| {
        *last = (*last).max(sent_ns + (unit() * 10.0 * MS as f64) as u64);
        *last
    };
    for k in 0..650u64 {
        let sent = start + k * 100 * MS;
        let answered = sent + MS / 10;
        while next_telemetry < answered {
            delivered(next_telemetry, &mut last_delivery);
            next_telemetry += 20 * MS;
        }
        let received = delivered(answered, &mut last_delivery);
        ts.on_exchange(sent, remote_at(answered), received);
        if k < 50 {
            continue;
        }
        for j in 0..10 {
            let t = received + j * 10 * MS;
            let err = ts.local_to_remote(t).expect("synced") as f64 - remote_at(t) as f64;
            sq += err * err;
            worst = worst.max(err.abs());
            n += 1;
        }
    }
    let rms_ms = (sq / n as f64).sqrt() / 1e6;
    println!("FIGURE TIMESYNC on simulated time, 10 ms jitter: RMS {rms_ms:.3} ms, worst {:.3} ms over {n} samples", worst / 1e6);
    assert!(rms_ms < 1.0, "RMS {rms_ms} ms");
}

proptest! {
    #![proptest_config(cases(100))]

    /// With one-way delays up to `jitter`, the estimate is within `jitter` (plus the drift's
    /// share) of the truth, whatever the offset and drift.
    #[test]
    fn timesync_error_is_bounded_by_the_delays(
        offset_s in 0.0f64..1e5, drift_ppm in -100.0f64..100.0, jitter_us in 0u64..20_000,
        delays in prop::collection::vec((0.0f64..1.0, 0.0f64..1.0), 120),
    ) {
        let mut ts = TimeSync::new(TimeSyncConfig::default());
        let boot_at = (offset_s * 1e9) as u64;
        let drift = drift_ppm * 1e-6;
        let remote_at = |local: u64| ((local - boot_at) as f64 * (1.0 + drift)) as u64;
        let mut local = boot_at + 1_000_000_000;
        for (a, b) in &delays {
            let (d_out, d_back) = ((a * jitter_us as f64 * 1e3) as u64, (b * jitter_us as f64 * 1e3) as u64);
            let remote = remote_at(local + d_out);
            ts.on_exchange(local, remote, local + d_out + d_back);
            local += 250_000_000;
        }
        prop_assert!(ts.is_synced());
        let probe = local;
        let est = ts.local_to_remote(probe).unwrap() as f64;
        let err = (est - remote_at(probe) as f64).abs();
        prop_assert!(err <= jitter_us as f64 * 1e3 + 100_000.0, "error {err} ns with jitter {jitter_us} us");
    }

    /// Single corrupted timestamps (anywhere, backwards or forwards) never reset the filter;
    /// a real restart, seen on consecutive messages, always does.
    #[test]
    fn only_a_confirmed_restart_resets(bad in prop::collection::vec((any::<u32>(), 2usize..6), 1..10)) {
        let mut ts = TimeSync::new(TimeSyncConfig::default());
        let mut local = 10_000_000_000u64;
        let mut remote = 3_600_000_000_000u64;
        for (value, every) in &bad {
            for k in 0..*every {
                local += 20_000_000;
                remote += 20_000_000;
                prop_assert_eq!(ts.check_remote_time(remote, local), TimeCheck::Plausible);
                if k == 0 {
                    let corrupt = *value as u64 * 1_000_000;
                    let far = corrupt + 1_000_000_000 < remote || corrupt > remote + 400_000_000;
                    let got = ts.check_remote_time(corrupt, local);
                    prop_assert!(got != TimeCheck::Rebooted);
                    if far { prop_assert_eq!(got, TimeCheck::Implausible); }
                }
            }
        }
        prop_assert_eq!(ts.resets(), 0);
        let mut rebooted = false;
        for k in 0..3u64 {
            rebooted |= ts.check_remote_time(k * 20_000_000, local + k * 20_000_000) == TimeCheck::Rebooted;
        }
        prop_assert!(rebooted);
    }
}
