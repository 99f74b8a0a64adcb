//! firmware-sim on its own, seen from a MAVLink peer on its pty: its config errors name the
//! field; it answers commands with COMMAND_ACK, runs a distance trigger like PX4 and records the
//! truth at each trigger; its boot clock restarts on a reboot.

use firmware_sim::{Fault, SimConfig, SimEvent};
use mavlink::dialects::ardupilotmega::*;
use mavlink::{AsyncMavConnection, MavHeader};
use std::time::Duration;

const GIVE_UP: Duration = Duration::from_secs(30);

#[test]
fn config_errors_name_the_field() {
    let cases = [
        ("[survey]\nspeed_mps = -1", "survey.speed_mps"),
        ("[link]\ntransport = \"carrier-pigeon\"", "link.transport"),
        (
            "[faults]\ncorrupt_byte_rate = 2",
            "faults.corrupt_byte_rate",
        ),
        ("[link]\nmavlink_version = 3", "link.mavlink_version"),
        (
            "[[faults.events]]\nat_s = 1\nkind = \"meteor\"",
            "faults.events.kind",
        ),
        (
            "[streams]\nglobal_position_int_hz = 5000",
            "streams.global_position_int_hz",
        ),
        ("[gcs_timesync]\nsystem_id = 1", "gcs_timesync.system_id"),
        ("[gcs_timesync]\noffset_ms = nan", "gcs_timesync.offset_ms"),
    ];
    for (text, field) in cases {
        let e = SimConfig::from_toml(text).unwrap_err().to_string();
        assert!(e.starts_with(field), "{text:?}: {e}");
    }
    let e = SimConfig::from_toml("[survey]\nsped_mps = 3")
        .unwrap_err()
        .to_string();
    assert!(e.contains("sped_mps"), "unknown keys are named: {e}");
    let ok = SimConfig::from_toml(
        "[link]\ntransport = \"udp\"\n[survey]\npattern = \"line\"\n[[faults.events]]\nat_s = 5\nkind = \"reboot\"\n",
    )
    .unwrap();
    assert_eq!(ok.faults.events.len(), 1);
    assert_eq!(ok.gcs_timesync, None);
    let g = SimConfig::from_toml("[gcs_timesync]\noffset_ms = -2.5").unwrap();
    assert_eq!(
        g.gcs_timesync,
        Some(firmware_sim::GcsTimesync {
            system_id: 255,
            component_id: 190,
            offset_ns: -2_500_000,
        })
    );
}

type Conn = mavlink::AsyncConnection<MavMessage>;

async fn peer(address: &str) -> Conn {
    let mut c = mavlink::connect_async::<MavMessage>(address)
        .await
        .expect("open the pty");
    c.set_allow_recv_any_version(true);
    c
}

async fn next(c: &Conn, mut pred: impl FnMut(&MavMessage) -> bool) -> MavMessage {
    tokio::time::timeout(GIVE_UP, async {
        loop {
            if let Ok((_, m)) = c.recv().await {
                if pred(&m) {
                    return m;
                }
            }
        }
    })
    .await
    .expect("message arrived")
}

async fn command(c: &Conn, cmd: MavCmd, params: [f32; 7]) -> MavResult {
    let msg = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        command: cmd,
        param1: params[0],
        param2: params[1],
        param3: params[2],
        param4: params[3],
        param5: params[4],
        param6: params[5],
        param7: params[6],
        target_system: 1,
        target_component: 1,
        confirmation: 0,
    });
    let h = MavHeader {
        system_id: 1,
        component_id: 100,
        sequence: 0,
    };
    c.send(&h, &msg).await.expect("sent");
    match next(
        c,
        |m| matches!(m, MavMessage::COMMAND_ACK(a) if a.command == cmd),
    )
    .await
    {
        MavMessage::COMMAND_ACK(a) => a.result,
        _ => unreachable!(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_distance_trigger_and_truth() {
    let dir = std::env::temp_dir().join(format!("fsim-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let truth = dir.join("truth.jsonl");
    let mut cfg =
        SimConfig::from_toml("[survey]\npattern = \"line\"\nlength_m = 2000\nwind_m = 0\n")
            .unwrap();
    cfg.truth_path = Some(truth.clone());
    let sim = firmware_sim::start(cfg).await.unwrap();
    let mut events = sim.subscribe();
    let c = peer(sim.address()).await;
    next(&c, |m| matches!(m, MavMessage::HEARTBEAT(_))).await;

    let ok = MavResult::MAV_RESULT_ACCEPTED;
    assert_eq!(
        command(
            &c,
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            [33.0, 20_000.0, 0., 0., 0., 0., 0.]
        )
        .await,
        ok
    );
    assert_eq!(
        command(
            &c,
            MavCmd::MAV_CMD_REQUEST_MESSAGE,
            [2.0, 0., 0., 0., 0., 0., 0.]
        )
        .await,
        ok
    );
    next(&c, |m| matches!(m, MavMessage::SYSTEM_TIME(_))).await;
    assert_eq!(
        command(
            &c,
            MavCmd::MAV_CMD_IMAGE_START_CAPTURE,
            [0., 0., 1., 0., 0., 0., 0.]
        )
        .await,
        ok
    );
    assert_eq!(
        command(
            &c,
            MavCmd::MAV_CMD_DO_DIGICAM_CONTROL,
            [0., 0., 0., 0., 1., 0., 0.]
        )
        .await,
        ok
    );
    assert_eq!(
        command(&c, MavCmd::MAV_CMD_NAV_TAKEOFF, [0.; 7]).await,
        MavResult::MAV_RESULT_UNSUPPORTED
    );
    assert_eq!(
        command(
            &c,
            MavCmd::MAV_CMD_DO_SET_CAM_TRIGG_DIST,
            [5.0, 0., 0., 0., 0., 0., 0.]
        )
        .await,
        ok
    );
    let mut triggers = 0;
    while triggers < 6 {
        match tokio::time::timeout(GIVE_UP, events.recv())
            .await
            .expect("event")
        {
            Ok(SimEvent::Capture { .. }) => triggers += 1,
            _ => continue,
        }
    }
    sim.shutdown().await;

    let lines: Vec<serde_json::Value> = std::fs::read_to_string(&truth)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let captures = lines.iter().filter(|l| l["event"] == "capture").count();
    assert_eq!(captures, 2, "{lines:?}");
    let trig: Vec<&serde_json::Value> = lines.iter().filter(|l| l["event"] == "trigger").collect();
    assert!(trig.len() >= 4);
    for w in trig.windows(2) {
        let d: f64 = (0..3)
            .map(|k| {
                w[1]["pos_ned_m"][k].as_f64().unwrap() - w[0]["pos_ned_m"][k].as_f64().unwrap()
            })
            .map(|x| x * x)
            .sum::<f64>()
            .sqrt();
        assert!(
            (d - 5.0).abs() < 1e-3,
            "triggers 5 m apart on a straight line: {d}"
        );
        assert!(w[1]["mono_ns"].as_u64() > w[0]["mono_ns"].as_u64());
        assert!(w[1]["time_boot_ms"].as_f64() > w[0]["time_boot_ms"].as_f64());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reboot_restarts_the_boot_clock_and_timesync_answers() {
    let sim = firmware_sim::start(SimConfig::default()).await.unwrap();
    let c = peer(sim.address()).await;
    let before = match next(
        &c,
        |m| matches!(m, MavMessage::GLOBAL_POSITION_INT(p) if p.time_boot_ms > 500),
    )
    .await
    {
        MavMessage::GLOBAL_POSITION_INT(p) => p.time_boot_ms,
        _ => unreachable!(),
    };
    let at = sim
        .inject(Fault::Reboot {
            silence: Duration::ZERO,
        })
        .await
        .unwrap();
    let after = match next(
        &c,
        |m| matches!(m, MavMessage::GLOBAL_POSITION_INT(p) if p.time_boot_ms < before),
    )
    .await
    {
        MavMessage::GLOBAL_POSITION_INT(p) => p.time_boot_ms,
        _ => unreachable!(),
    };
    assert!(after < 1_000, "{after}");
    let truth = sim.truth_at_mono_ns(at + 250_000_000);
    assert!(
        (truth.time_boot_ms - 250.0).abs() < 1.0,
        "{}",
        truth.time_boot_ms
    );
    let h = MavHeader {
        system_id: 1,
        component_id: 100,
        sequence: 0,
    };
    let ts = MavMessage::TIMESYNC(TIMESYNC_DATA {
        tc1: 0,
        ts1: 12345,
        target_system: 1,
        target_component: 1,
    });
    c.send(&h, &ts).await.unwrap();
    let reply = next(
        &c,
        |m| matches!(m, MavMessage::TIMESYNC(t) if t.ts1 == 12345),
    )
    .await;
    let MavMessage::TIMESYNC(t) = reply else {
        unreachable!()
    };
    assert!(t.tc1 > 0 && (t.tc1 as f64) < 60e9);
    sim.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scheduled_faults_fire_from_the_config() {
    let cfg = SimConfig::from_toml(
        "[[faults.events]]\nat_s = 0.3\nkind = \"silence\"\nduration_s = 0.2\n\
         [[faults.events]]\nat_s = 0.6\nkind = \"link_loss\"\nduration_s = 0.2\n",
    )
    .unwrap();
    let sim = firmware_sim::start(cfg).await.unwrap();
    let mut events = sim.subscribe();
    let mut seen = Vec::new();
    while seen.len() < 5 {
        let e = tokio::time::timeout(GIVE_UP, events.recv())
            .await
            .expect("event")
            .unwrap();
        match e {
            SimEvent::SilenceStart { .. } => seen.push("silence"),
            SimEvent::SilenceEnd { .. } => seen.push("silence end"),
            SimEvent::LinkDown { .. } => seen.push("down"),
            SimEvent::LinkUp { .. } => seen.push("up"),
            SimEvent::Rebooted { .. } => seen.push("reboot"),
            _ => {}
        }
        if seen.last() == Some(&"up") {
            break;
        }
    }
    assert_eq!(seen, ["silence", "silence end", "down", "up"]);
    sim.shutdown().await;
}
