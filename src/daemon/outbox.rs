//! What the coordinator's [`Action`]s do: messages to the link, captures to the writer's
//! bounded queue (with the backlog that stands in for it while it is full, so the loop never
//! waits on the writer, which waits on the loop), poses looked up in their own tasks; and
//! the clocks and storage the coordinator is handed.

use super::camera::StorageState;
use super::coordinator::{Action, Coordinator, Located, Now};
use super::estimator_task::Counters;
use super::latency::CaptureStamps;
use super::writer::{Space, WriteJob, Written};
use crate::capture::CaptureRecord;
use crate::core::geo::LocalFrame;
use crate::link::unix_us_at;
use crate::link::{self, mono_ns, LinkHandle};
use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::time::Duration;
use tokio::sync::mpsc;

/// Of which the image may take this much; the rest is for the manifest line, the answer
/// and the link.
pub(crate) const IMAGE_BUDGET_NS: u64 = 400_000_000;
/// Captures the coordinator holds while the writer's queue is full (about 1 KiB each);
/// beyond, a capture is reported failed rather than held without bound.
const WRITE_BACKLOG: usize = 1024;
/// How long a capture waits for the telemetry sample after its instant.
const LOCATE_WAIT: Duration = Duration::from_millis(300);

/// Where the coordinator's actions go: the link, and the writer's queue with the backlog
/// that stands in for it while it is full (in order: a capture never overtakes another).
pub struct Outbox {
    pub link: LinkHandle,
    pub located: mpsc::Sender<(u64, Result<Located, String>)>,
    pub writer: Option<mpsc::Sender<WriteJob>>,
    pub backlog: VecDeque<WriteJob>,
}

impl Outbox {
    /// Performs `actions` and whatever they lead to (a located capture is written at once).
    pub async fn perform(&mut self, co: &mut Coordinator, actions: Vec<Action>) {
        let mut todo = VecDeque::from(actions);
        while let Some(a) = todo.pop_front() {
            match a {
                Action::Send(m) => {
                    let _ = self.link.send(*m).await;
                }
                // Not awaited here: the pose may be a telemetry period away.
                Action::Locate { id, mono_ns } => {
                    let (link, tx) = (self.link.clone(), self.located.clone());
                    tokio::spawn(async move {
                        let l = locate(&link, mono_ns).await;
                        // The coordinator bounds the captures it locates at once to the
                        // channel's capacity: this never waits.
                        let _ = tx.send((id, l)).await;
                    });
                }
                Action::Write(record) => {
                    let job = WriteJob {
                        deadline_ns: record.mono_ns + IMAGE_BUDGET_NS,
                        queued_ns: mono_ns(),
                        record,
                    };
                    if let Some(refused) = self.queue(job) {
                        let error = format!(
                            "capture {} not logged: the writer is {refused}",
                            refused.record.seq
                        );
                        let mut r = *refused.record;
                        r.image = None;
                        todo.extend(co.on_capture_written(&r, Err(error), None));
                    }
                }
            }
        }
    }

    /// Queues `job`, or hands it back with why it cannot be.
    fn queue(&mut self, job: WriteJob) -> Option<Refused> {
        let Some(tx) = self.writer.as_ref() else {
            return Some(Refused {
                record: job.record,
                why: "gone",
            });
        };
        if self.backlog.is_empty() {
            match tx.try_send(job) {
                Ok(()) => return None,
                Err(mpsc::error::TrySendError::Closed(j)) => {
                    return Some(Refused {
                        record: j.record,
                        why: "gone",
                    })
                }
                Err(mpsc::error::TrySendError::Full(j)) => self.backlog.push_back(j),
            }
            return None;
        }
        if self.backlog.len() >= WRITE_BACKLOG {
            return Some(Refused {
                record: job.record,
                why: "too far behind",
            });
        }
        self.backlog.push_back(job);
        None
    }
}

struct Refused {
    record: Box<CaptureRecord>,
    why: &'static str,
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.why)
    }
}

/// Room in the writer's queue (a capture from the backlog goes in).
pub async fn reserve(tx: Option<&mpsc::Sender<WriteJob>>) -> Option<mpsc::Permit<'_, WriteJob>> {
    tx?.reserve().await.ok()
}

pub fn written(co: &mut Coordinator, w: Written) -> Vec<Action> {
    // Its CAMERA_IMAGE_CAPTURED goes to the link as the caller performs these actions.
    co.report.latency.record(&CaptureStamps {
        answered_ns: mono_ns(),
        ..w.stamps
    });
    let missing = w.record.image_missing.clone();
    co.on_capture_written(&w.record, w.result, missing.as_deref())
}

pub async fn now(link: &LinkHandle) -> Now {
    let mono = mono_ns();
    Now {
        mono_ns: mono,
        boot_ms: link
            .boot_ns_at_mono_ns(mono)
            .await
            .map_or(0, |ns| (ns / 1_000_000) as u32),
    }
}

/// The vehicle's horizontal speed in the link's latest state.
pub fn ground_speed_mps(link: &LinkHandle) -> Option<f64> {
    link.state()
        .borrow()
        .as_ref()
        .map(|s| s.vel_ned_mps[0].hypot(s.vel_ned_mps[1]))
}

pub async fn tick(
    co: &mut Coordinator,
    link: &LinkHandle,
    space: &Space,
    counters: &Counters,
) -> Vec<Action> {
    let free = space.free_bytes.load(Ordering::Relaxed);
    let total = space.total_bytes.load(Ordering::Relaxed);
    let storage = if total > 0 {
        StorageState::from_bytes(total, free)
    } else {
        StorageState::from_free_bytes(free)
    };
    let speed = ground_speed_mps(link);
    let skipped = counters.skipped_busy.load(Ordering::Relaxed);
    co.on_tick(now(link).await, storage, skipped, speed)
}

pub async fn sleep_until(t: Option<tokio::time::Instant>) {
    match t {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}

/// The pose, clocks and local frame of a capture the coordinator takes itself.
pub async fn locate(link: &LinkHandle, mono_ns: u64) -> Result<Located, String> {
    // A capture taken "now" waits for the telemetry sample after it (at most
    // LOCATE_WAIT): its pose is then interpolated, not extrapolated past the horizon.
    let mut state = link.state();
    let after = |s: &Option<link::VehicleState>| {
        s.as_ref()
            .and_then(|s| s.mono_ns)
            .is_some_and(|t| t >= mono_ns)
    };
    let _ = tokio::time::timeout(LOCATE_WAIT, state.wait_for(after)).await;
    let pose = link
        .pose_at_mono_ns(mono_ns)
        .await
        .map_err(|e| e.to_string())?;
    let home = link
        .state()
        .borrow()
        .as_ref()
        .map(|s| s.home)
        .ok_or("no position from the autopilot yet")?;
    Ok(Located {
        pose,
        boot_us: link.boot_ns_at_mono_ns(mono_ns).await.map(|n| n / 1000),
        unix_us: unix_us_at(mono_ns),
        local: LocalFrame::new(home),
    })
}
