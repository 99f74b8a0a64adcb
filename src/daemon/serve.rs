//! The coordinator's loop: every event (a decided capture, an estimate, a link event, a
//! written capture, a located pose, room in the writer's queue, the clock) goes to the pure
//! [`Coordinator`], and what it decides is performed through the [`Outbox`]. Then the
//! coordinator's steps of the shutdown, which [`super::run::run`] calls in their order.

use super::coordinator::{Coordinator, EstimatorView, Located};
use super::estimator_task::{Counters, Decided};
use super::outbox::{ground_speed_mps, now, reserve, sleep_until, tick, written, Outbox};
use super::shutdown::{Shutdown, Stage};
use super::writer::{Space, Written};
use crate::link::{LinkEvent, LinkHandle};
use crate::notify::Notifier;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};

/// At the stop, how long the reports of pictures commanded just before it are read.
pub const PICTURE_STOP_WAIT: Duration = Duration::from_millis(250);

/// The coordinator and every queue into it.
pub(super) struct Loop {
    pub co: Coordinator,
    pub out: Outbox,
    pub link: LinkHandle,
    pub link_events: mpsc::Receiver<LinkEvent>,
    pub decided: mpsc::Receiver<Decided>,
    pub views: watch::Receiver<Option<EstimatorView>>,
    pub written: mpsc::Receiver<Written>,
    pub located: mpsc::Receiver<(u64, Result<Located, String>)>,
    pub space: Arc<Space>,
    pub counters: Arc<Counters>,
}

impl Loop {
    /// Performs what the coordinator says it is ready to do (the camera's first messages).
    pub async fn start(&mut self) {
        let ready = self.co.ready();
        self.out.perform(&mut self.co, ready).await;
    }

    /// Until the run's one cancellation (the stage reaching `Stopping`) or the depth source
    /// ends; the source's error, if it failed.
    pub async fn serve(&mut self, mut stop: Shutdown, notifier: &Notifier) -> Option<String> {
        let pet = notifier
            .watchdog_interval()
            .unwrap_or(Duration::from_secs(3600));
        let mut watchdog = tokio::time::interval(pet);
        let mut second = tokio::time::interval(Duration::from_secs(1));
        second.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            let due = self.co.next_due_ns().map(crate::link::clock::instant_at);
            let co = &mut self.co;
            let (link, space, counters) = (&self.link, &self.space, &self.counters);
            let actions = tokio::select! {
                biased;
                _ = stop.reached(Stage::Stopping) => return None,
                d = self.decided.recv() => match d {
                    None => return None,
                    Some(Decided::SourceFailed(e)) => return Some(e),
                    Some(Decided::Capture(r)) => co.on_decided(*r),
                },
                Ok(()) = self.views.changed() => {
                    let v = self.views.borrow_and_update().clone();
                    match v {
                        Some(v) => {
                            co.set_ground_speed(ground_speed_mps(link));
                            co.on_estimate(v, now(link).await)
                        }
                        None => Vec::new(),
                    }
                }
                Some(ev) = self.link_events.recv() => co.on_link_event(ev, now(link).await),
                Some(w) = self.written.recv() => written(co, w),
                Some((id, l)) = self.located.recv() => co.on_located(id, l),
                Some(permit) = reserve(self.out.writer.as_ref()), if !self.out.backlog.is_empty() => {
                    if let Some(job) = self.out.backlog.pop_front() {
                        permit.send(job);
                    }
                    Vec::new()
                }
                _ = second.tick() => tick(co, link, space, counters).await,
                _ = sleep_until(due), if due.is_some() => tick(co, link, space, counters).await,
                _ = watchdog.tick() => { let _ = notifier.watchdog(); Vec::new() }
            };
            self.out.perform(&mut self.co, actions).await;
        }
    }

    /// Logs the captures the estimator decided before it stopped, for at most `within`.
    pub async fn take_decided(&mut self, within: Duration) {
        let deadline = tokio::time::Instant::now() + within;
        while let Ok(Some(d)) = tokio::time::timeout_at(deadline, self.decided.recv()).await {
            if let Decided::Capture(r) = d {
                let a = self.co.on_decided(*r);
                self.out.perform(&mut self.co, a).await;
            }
        }
    }

    /// Hands the backlog and the captures still waiting for their pose (each within
    /// `LOCATE_WAIT`) or their picture's report to the writer, taking the writer's answers
    /// meanwhile (it waits on them). A picture commanded just before the stop is reported
    /// within the camera's delay, and the link stops last: its report is read for up to
    /// [`PICTURE_STOP_WAIT`], then no capture waits for one.
    pub async fn hand_over(&mut self) {
        let deadline = tokio::time::Instant::now() + PICTURE_STOP_WAIT;
        let mut reading = true;
        while !self.out.backlog.is_empty() || self.co.locating() > 0 {
            let co = &mut self.co;
            let link = &self.link;
            let awaiting = reading && co.awaiting_pictures() > 0;
            let actions = tokio::select! {
                biased;
                Some(permit) = reserve(self.out.writer.as_ref()), if !self.out.backlog.is_empty() => {
                    if let Some(job) = self.out.backlog.pop_front() {
                        permit.send(job);
                    }
                    Vec::new()
                }
                Some(w) = self.written.recv() => written(co, w),
                Some((id, l)) = self.located.recv(), if co.locating() > 0 => co.on_located(id, l),
                Some(ev) = self.link_events.recv(), if awaiting => match ev {
                    // Only the pictures' reports: the daemon takes nothing new now.
                    LinkEvent::CameraTrigger { .. } | LinkEvent::CameraFeedback { .. } => {
                        co.on_link_event(ev, now(link).await)
                    }
                    _ => Vec::new(),
                },
                _ = tokio::time::sleep_until(deadline), if awaiting => {
                    reading = false;
                    co.stop_awaiting_pictures()
                }
                else => break,
            };
            self.out.perform(&mut self.co, actions).await;
        }
    }

    /// Closes the writer's queue (it then writes the tlog and the exports and ends) and says
    /// every capture it answers for.
    pub async fn close_writer(&mut self) {
        self.out.writer = None;
        while let Some(w) = self.written.recv().await {
            let a = written(&mut self.co, w);
            self.out.perform(&mut self.co, a).await;
        }
    }
}
