//! Shared by the `link_*` tests: firmware-sim on a pty with alfd's link attached, waits on the
//! link's `watch` channels and the simulator's events (never on sleeps), and the error figures
//! against the simulator's truth.
#![allow(dead_code)]

use alfd::core::geo::{Geodetic, LocalFrame};
use alfd::link::{self, LinkConfig, LinkEvent, LinkHandle, LinkHealth};
use firmware_sim::{SimConfig, SimEvent, SimHandle};
use std::time::Duration;
use tokio::sync::{broadcast, mpsc, oneshot};

/// Upper bound on any wait: a test that needs it has failed, it does not pace anything.
pub const GIVE_UP: Duration = Duration::from_secs(60);

pub struct Pair {
    pub sim: SimHandle,
    pub link: LinkHandle,
    pub events: mpsc::Receiver<LinkEvent>,
    pub sim_events: broadcast::Receiver<SimEvent>,
    pub frame: LocalFrame,
    stop: Option<oneshot::Sender<()>>,
    task: Option<tokio::task::JoinHandle<()>>,
}

pub fn sim_config(seed: u64) -> SimConfig {
    let mut c = SimConfig::default();
    c.faults.seed = seed;
    c
}

/// Start the simulator, then the link on its address (home = the survey origin).
pub async fn start(sim_cfg: SimConfig, tweak: impl FnOnce(&mut LinkConfig)) -> Pair {
    let sim = firmware_sim::start(sim_cfg)
        .await
        .expect("simulator starts");
    let sim_events = sim.subscribe();
    let o = sim.origin();
    let home = Geodetic {
        lat_deg: o[0],
        lon_deg: o[1],
        alt_m: o[2],
    };
    let mut cfg = LinkConfig::for_address(sim.address());
    cfg.home = Some(home);
    tweak(&mut cfg);
    let (task, handle, events) = link::new(cfg);
    let (stop, stopped) = oneshot::channel::<()>();
    let task = tokio::spawn(async move {
        task.run(async {
            let _ = stopped.await;
        })
        .await
        .expect("link runs");
    });
    Pair {
        sim,
        link: handle,
        events,
        sim_events,
        frame: LocalFrame::new(home),
        stop: Some(stop),
        task: Some(task),
    }
}

impl Pair {
    pub async fn stop(mut self) {
        let _ = self.stop.take().expect("running").send(());
        self.task
            .take()
            .expect("running")
            .await
            .expect("link task ends cleanly");
        self.sim.shutdown().await;
    }

    /// Wait until the link's health satisfies `pred`; returns that health.
    pub async fn health_until(
        &self,
        what: &str,
        pred: impl FnMut(&LinkHealth) -> bool,
    ) -> LinkHealth {
        let mut rx = self.link.health();
        let got = match tokio::time::timeout(GIVE_UP, rx.wait_for(pred)).await {
            Ok(Ok(h)) => Some(h.clone()),
            _ => None,
        };
        got.unwrap_or_else(|| {
            panic!(
                "gave up waiting for: {what}; health {:?}",
                *self.link.health().borrow()
            )
        })
    }

    /// Wait for a simulator event matching `pred`.
    pub async fn sim_event(
        &mut self,
        what: &str,
        mut pred: impl FnMut(&SimEvent) -> bool,
    ) -> SimEvent {
        let wait = async {
            loop {
                match self.sim_events.recv().await {
                    Ok(e) if pred(&e) => return e,
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => panic!("simulator stopped"),
                }
            }
        };
        tokio::time::timeout(GIVE_UP, wait)
            .await
            .unwrap_or_else(|_| panic!("gave up waiting for: {what}"))
    }

    /// Wait until a position sampled after `mono_ns` has been accepted.
    pub async fn fresh_after(&self, mono_ns: u64) -> u64 {
        let mut rx = self.link.state();
        let f = rx.wait_for(|s| {
            s.as_ref()
                .and_then(|s| s.mono_ns)
                .is_some_and(|t| t > mono_ns)
        });
        let s = tokio::time::timeout(GIVE_UP, f)
            .await
            .expect("fresh pose")
            .expect("link alive");
        s.as_ref().and_then(|s| s.mono_ns).expect("mono")
    }
}

/// Errors of alfd's beliefs at frame instants against the truth.
#[derive(Debug, Default, Clone)]
pub struct Figures {
    pub frames: usize,
    pub unanswered: usize,
    pub pos_err_m: Vec<f64>,
    pub att_err_deg: Vec<f64>,
    pub sync_err_ns: Vec<f64>,
}

pub fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

pub fn max(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |a, b| a.max(b.abs()))
}

impl Figures {
    pub fn summary(&self, label: &str) -> String {
        format!(
            "{label}: {} frames ({} unanswered), position RMS {:.1} mm max {:.1} mm, attitude RMS {:.3} deg, time sync RMS {:.0} us max {:.0} us",
            self.frames,
            self.unanswered,
            rms(&self.pos_err_m) * 1e3,
            max(&self.pos_err_m) * 1e3,
            rms(&self.att_err_deg),
            rms(&self.sync_err_ns) / 1e3,
            max(&self.sync_err_ns) / 1e3,
        )
    }
}

/// Run a 30 fps frame clock for `frames` frames; each frame's pose is asked for `defer` after its
/// instant (so the telemetry around it has arrived: interpolation, not extrapolation).
pub async fn measure(p: &Pair, frames: usize, defer: Duration) -> Figures {
    let mut f = Figures::default();
    let mut clock = tokio::time::interval(Duration::from_nanos(1_000_000_000 / 30));
    let mut queue = std::collections::VecDeque::new();
    let defer_ns = defer.as_nanos() as u64;
    while f.frames < frames {
        clock.tick().await;
        let now = link::mono_ns();
        queue.push_back(now);
        while let Some(&t) = queue.front() {
            if t + defer_ns > now {
                break;
            }
            queue.pop_front();
            f.frames += 1;
            let truth = p.sim.truth_at_mono_ns(t);
            if let Some(boot_ns) = p.link.boot_ns_at_mono_ns(t).await {
                f.sync_err_ns
                    .push(boot_ns as f64 - truth.time_boot_ms * 1e6);
            }
            match p.link.pose_at_mono_ns(t).await {
                Ok(pose) => {
                    let g = Geodetic {
                        lat_deg: truth.lat_deg,
                        lon_deg: truth.lon_deg,
                        alt_m: truth.alt_m,
                    };
                    let tp = glam::DVec3::from_array(p.frame.to_ned(g));
                    f.pos_err_m.push((pose.pos_ned_m - tp).length());
                    let tq = glam::DQuat::from_xyzw(truth.q[1], truth.q[2], truth.q[3], truth.q[0]);
                    let dot = pose.q.dot(tq).abs().min(1.0);
                    f.att_err_deg.push(2.0 * dot.acos().to_degrees());
                }
                Err(_) => f.unanswered += 1,
            }
        }
    }
    f
}
