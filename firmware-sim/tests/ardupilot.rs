//! firmware-sim's `autopilot = "ardupilot"` profile, from a camera's side of the pty: positions
//! at lat = lon = 0 until the EKF origin, then GPS_GLOBAL_ORIGIN and HOME_POSITION; the landed
//! state from the ground to the air; the MAVLinkCamV2 backend finding the camera and sending it
//! IMAGE_START_CAPTURE per distance trigger, with CAMERA_FEEDBACK and no CAMERA_TRIGGER; and a
//! ground station answering TIMESYNC.

use firmware_sim::{CameraBackend, SimConfig, SimEvent};
use mavlink::dialects::ardupilotmega::*;
use mavlink::{AsyncMavConnection, MavHeader};
use std::sync::{Arc, Mutex};
use std::time::Duration;

type Conn = Arc<mavlink::AsyncConnection<MavMessage>>;

/// Everything heard, with the monotonic instant it was read.
type Heard = Arc<Mutex<Vec<(u64, MavHeader, MavMessage)>>>;

const CAMERA: MavHeader = MavHeader {
    system_id: 1,
    component_id: 100,
    sequence: 0,
};

fn command(cmd: MavCmd, params: [f32; 4]) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        command: cmd,
        param1: params[0],
        param2: params[1],
        param3: params[2],
        param4: params[3],
        target_system: 1,
        target_component: 1,
        ..Default::default()
    })
}

/// Wait for a simulator event (what the profile's schedule says happened).
async fn event(rx: &mut tokio::sync::broadcast::Receiver<SimEvent>, pick: fn(&SimEvent) -> bool) {
    tokio::time::timeout(Duration::from_secs(40), async {
        loop {
            match rx.recv().await {
                Ok(e) if pick(&e) => return,
                Ok(_) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {}
                Err(e) => panic!("{e}"),
            }
        }
    })
    .await
    .expect("the event came");
}

#[test]
fn the_profile_sets_its_behaviours_and_explicit_keys_win() {
    let ap = SimConfig::from_toml("autopilot = \"ardupilot\"").unwrap();
    assert_eq!(ap.camera, CameraBackend::MavlinkCamV2);
    assert!(ap.vehicle.origin_delay > Duration::ZERO && ap.vehicle.ground > Duration::ZERO);
    assert!(ap.streams.extended_sys_state > 0.0);
    assert_eq!(ap.gcs_timesync.map(|g| g.system_id), Some(255));
    // The same through the builder `--autopilot ardupilot` uses.
    let built = SimConfig::default().ardupilot();
    assert_eq!(built.vehicle, ap.vehicle);
    assert_eq!(built.camera, ap.camera);
    let mixed = SimConfig::from_toml(
        "autopilot = \"ardupilot\"\n[camera]\nbackend = \"trigger\"\n[vehicle]\nground_s = 0\n",
    )
    .unwrap();
    assert_eq!(mixed.camera, CameraBackend::Trigger);
    assert_eq!(mixed.vehicle.ground, Duration::ZERO);
    for name in ["servo", "relay"] {
        let c = SimConfig::from_toml(&format!(
            "autopilot = \"ardupilot\"\n[camera]\nbackend = \"{name}\"\n"
        ))
        .unwrap();
        assert_eq!(c.camera, CameraBackend::Servo);
    }
    let generic = SimConfig::default();
    assert_eq!(generic.camera, CameraBackend::Trigger);
    assert_eq!(generic.camera_delay, Duration::ZERO);
    let late = SimConfig::from_toml("[camera]\ndelay_ms = 80\nrefuse_first = 2\n").unwrap();
    assert_eq!(late.camera_delay, Duration::from_millis(80));
    assert_eq!(
        (generic.camera_refuse_first, late.camera_refuse_first),
        (0, 2)
    );
    assert_eq!(generic.vehicle.origin_delay, Duration::ZERO);
    for (text, field) in [
        ("autopilot = \"px5\"", "autopilot"),
        ("[camera]\nbackend = \"film\"", "camera.backend"),
        ("[camera]\ndelay_ms = -1", "camera.delay_ms"),
        ("[camera]\ndelay_ms = 2500", "camera.delay_ms"),
        ("[camera]\nrefuse_first = 1001", "camera.refuse_first"),
        ("[vehicle]\nclimb_mps = 0", "vehicle.climb_mps"),
        (
            "[vehicle]\norigin_delay_s = 9\nground_s = 10",
            "vehicle.origin_delay_s",
        ),
    ] {
        let e = SimConfig::from_toml(text).unwrap_err().to_string();
        assert!(e.starts_with(field), "{text:?}: {e}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ardupilot_origin_landed_state_and_mavlink_camera() {
    let cfg = SimConfig::from_toml(
        "autopilot = \"ardupilot\"\n\
         [vehicle]\norigin_delay_s = 2\nground_s = 4\nclimb_mps = 10\n\
         [survey]\npattern = \"line\"\nlength_m = 2000\naltitude_m = 20\nwind_m = 0\n",
    )
    .unwrap();
    let origin = [
        cfg.survey.origin_lat_deg,
        cfg.survey.origin_lon_deg,
        cfg.survey.origin_alt_m,
    ];
    let sim = firmware_sim::start(cfg).await.unwrap();
    let mut events = sim.subscribe();
    let mut c = mavlink::connect_async::<MavMessage>(sim.address())
        .await
        .unwrap();
    c.set_allow_recv_any_version(true);
    let c: Conn = Arc::new(c);
    let heard: Heard = Arc::default();
    // The camera: a HEARTBEAT every second, CAMERA_INFORMATION when asked.
    let camera = {
        let (c, heard) = (c.clone(), heard.clone());
        tokio::spawn(async move {
            let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                mavtype: MavType::MAV_TYPE_CAMERA,
                autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                ..Default::default()
            });
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                tokio::select! {
                    _ = tick.tick() => { c.send(&CAMERA, &hb).await.unwrap(); }
                    r = c.recv() => {
                        let Ok((h, m)) = r else { continue };
                        if let MavMessage::COMMAND_LONG(cmd) = &m {
                            if cmd.command == MavCmd::MAV_CMD_REQUEST_MESSAGE && cmd.param1 == 259.0 {
                                let info = MavMessage::CAMERA_INFORMATION(CAMERA_INFORMATION_DATA {
                                    flags: CameraCapFlags::CAMERA_CAP_FLAGS_CAPTURE_IMAGE,
                                    ..Default::default()
                                });
                                c.send(&CAMERA, &info).await.unwrap();
                            }
                        }
                        heard.lock().unwrap().push((firmware_sim::mono_ns(), h, m));
                    }
                }
            }
        })
    };
    // Before the origin: asking for home is accepted, and answered with nothing.
    tokio::time::sleep(Duration::from_millis(500)).await;
    c.send(
        &CAMERA,
        &command(MavCmd::MAV_CMD_REQUEST_MESSAGE, [242.0, 0.0, 0.0, 0.0]),
    )
    .await
    .unwrap();
    event(&mut events, |e| matches!(e, SimEvent::OriginSet { .. })).await;
    let origin_at = firmware_sim::mono_ns();
    event(&mut events, |e| matches!(e, SimEvent::InAir { .. })).await;
    // The camera is looked for from 10 s after boot; once its information is read, a distance
    // trigger takes pictures through it.
    tokio::time::timeout(Duration::from_secs(20), async {
        loop {
            let asked = heard
                .lock()
                .unwrap()
                .iter()
                .any(|(_, _, m)| matches!(m, MavMessage::COMMAND_LONG(c) if c.param1 == 259.0));
            if asked {
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await
    .expect("MAVLinkCamV2 asked for CAMERA_INFORMATION");
    tokio::time::sleep(Duration::from_millis(300)).await;
    c.send(
        &CAMERA,
        &command(MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST, [10.0, 0.0, 0.0, 0.0]),
    )
    .await
    .unwrap();
    for _ in 0..3 {
        event(&mut events, |e| matches!(e, SimEvent::Capture { .. })).await;
    }
    // The ground station behind the autopilot answers TIMESYNC too.
    c.send(
        &CAMERA,
        &MavMessage::TIMESYNC(TIMESYNC_DATA {
            tc1: 0,
            ts1: 42,
            target_system: 1,
            target_component: 1,
        }),
    )
    .await
    .unwrap();
    tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let answered = heard
                .lock()
                .unwrap()
                .iter()
                .filter(|(_, _, m)| matches!(m, MavMessage::TIMESYNC(t) if t.ts1 == 42))
                .count();
            if answered >= 2 {
                return;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("TIMESYNC answered");
    camera.abort();
    sim.shutdown().await;
    let heard = heard.lock().unwrap().clone();
    let before: Vec<&MavMessage> = heard
        .iter()
        .filter(|(t, _, _)| *t < origin_at - 100_000_000)
        .map(|(_, _, m)| m)
        .collect();
    let after = |pick: fn(&MavMessage) -> bool| {
        heard
            .iter()
            .filter(|(t, _, _)| *t > origin_at + 100_000_000)
            .map(|(_, _, m)| m)
            .filter(move |m| pick(m))
    };

    // (a) Zeros before the origin, no fix at first, and no home or origin message.
    let zeros = before
        .iter()
        .filter(|m| matches!(m, MavMessage::GLOBAL_POSITION_INT(p) if p.lat == 0 && p.lon == 0))
        .count();
    assert!(zeros >= 10, "{zeros} zero positions before the origin");
    assert!(!before
        .iter()
        .any(|m| matches!(m, MavMessage::GLOBAL_POSITION_INT(p) if p.lat != 0 || p.lon != 0)));
    assert!(before.iter().any(|m| matches!(m, MavMessage::GPS_RAW_INT(g)
        if g.fix_type == GpsFixType::GPS_FIX_TYPE_NO_FIX)));
    assert!(!before.iter().any(|m| matches!(
        m,
        MavMessage::HOME_POSITION(_) | MavMessage::GPS_GLOBAL_ORIGIN(_)
    )));
    assert!(before.iter().any(|m| matches!(m, MavMessage::COMMAND_ACK(a)
        if a.command == MavCmd::MAV_CMD_REQUEST_MESSAGE
            && a.result == MavResult::MAV_RESULT_ACCEPTED)));
    // Then the origin, home (again at arming), and real positions.
    let o = heard
        .iter()
        .find_map(|(_, _, m)| match m {
            MavMessage::GPS_GLOBAL_ORIGIN(o) => Some(o.clone()),
            _ => None,
        })
        .expect("GPS_GLOBAL_ORIGIN");
    assert_eq!(o.latitude, (origin[0] * 1e7).round() as i32);
    assert_eq!(o.longitude, (origin[1] * 1e7).round() as i32);
    assert_eq!(o.altitude, (origin[2] * 1e3).round() as i32);
    let homes = heard
        .iter()
        .filter(|(_, _, m)| matches!(m, MavMessage::HOME_POSITION(h) if h.latitude != 0))
        .count();
    assert_eq!(homes, 2, "home when the origin is set, and again at arming");
    assert!(after(|m| matches!(m, MavMessage::GLOBAL_POSITION_INT(p) if p.lat == 0)).count() == 0);

    // (c) Landed state: on the ground, taking off, in the air, in that order; armed on the way.
    let states: Vec<MavLandedState> = heard
        .iter()
        .filter_map(|(_, _, m)| match m {
            MavMessage::EXTENDED_SYS_STATE(e) => Some(e.landed_state),
            _ => None,
        })
        .collect();
    let mut phases = states.clone();
    phases.dedup();
    assert_eq!(
        phases,
        [
            MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            MavLandedState::MAV_LANDED_STATE_TAKEOFF,
            MavLandedState::MAV_LANDED_STATE_IN_AIR
        ],
        "{states:?}"
    );
    let armed: Vec<bool> = heard
        .iter()
        .filter_map(|(_, h, m)| match m {
            MavMessage::HEARTBEAT(hb) if h.component_id == 1 => Some(
                hb.base_mode
                    .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
            ),
            _ => None,
        })
        .collect();
    assert_eq!(armed.first(), Some(&false));
    assert_eq!(armed.last(), Some(&true));

    // (b) The distance trigger through the camera: IMAGE_START_CAPTURE to it, one image each,
    // numbered on, each with its CAMERA_FEEDBACK; never a CAMERA_TRIGGER.
    let starts: Vec<COMMAND_LONG_DATA> = heard
        .iter()
        .filter_map(|(_, _, m)| match m {
            MavMessage::COMMAND_LONG(c) if c.command == MavCmd::MAV_CMD_IMAGE_START_CAPTURE => {
                Some(c.clone())
            }
            _ => None,
        })
        .collect();
    assert!(starts.len() >= 3, "{starts:?}");
    for (k, s) in starts.iter().enumerate() {
        assert_eq!((s.target_system, s.target_component), (1, 100));
        assert_eq!(s.param3, 1.0);
        assert_eq!(s.param4, k as f32 + 1.0);
    }
    let feedback: Vec<CAMERA_FEEDBACK_DATA> = heard
        .iter()
        .filter_map(|(_, _, m)| match m {
            MavMessage::CAMERA_FEEDBACK(f) => Some(f.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(feedback.len(), starts.len());
    let unix_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_micros() as u64;
    for (k, f) in feedback.iter().enumerate() {
        assert_eq!(f.img_idx as usize, k + 1);
        assert!(f.lat != 0 && f.lng != 0);
        assert!((f.alt_rel - 20.0).abs() < 1.0, "{}", f.alt_rel);
        // GPS time (UNIX epoch), not boot time.
        assert!(unix_us - f.time_usec < 60_000_000, "{}", f.time_usec);
    }
    assert!(!heard
        .iter()
        .any(|(_, _, m)| matches!(m, MavMessage::CAMERA_TRIGGER(_))));

    // (d) TIMESYNC answered by the ground station (its own clock) as well as the autopilot.
    let answers: Vec<u32> = heard
        .iter()
        .filter_map(|(_, h, m)| match m {
            MavMessage::TIMESYNC(t) if t.ts1 == 42 && t.tc1 != 0 => Some(h.system_id),
            _ => None,
        })
        .collect();
    assert!(
        answers.contains(&255) && answers.contains(&1),
        "{answers:?}"
    );
}
