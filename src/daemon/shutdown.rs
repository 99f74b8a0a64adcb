//! The daemon's one shutdown: a single `watch` of the run's stage that every loop and thread
//! selects on (or polls, for threads blocked in a device). The order is written once, in
//! `run.rs`: sources, estimator and coordinator stop at `Stopping`; the writer ends when the
//! coordinator closes its queue (every decided capture logged); the link stops last, at
//! `Done`, once the last CAMERA_IMAGE_CAPTURED is sent.

use tokio::sync::watch;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Stage {
    Running,
    /// SIGTERM, the caller's shutdown or a fatal source error: stop taking new work.
    Stopping,
    /// Everything logged and said: the link may go.
    Done,
}

/// What a loop holds to hear the shutdown. Cheap to clone.
#[derive(Clone)]
pub struct Shutdown(watch::Receiver<Stage>);

/// What `run` holds to advance the shutdown.
pub struct ShutdownTrigger(watch::Sender<Stage>);

pub fn channel() -> (ShutdownTrigger, Shutdown) {
    let (tx, rx) = watch::channel(Stage::Running);
    (ShutdownTrigger(tx), Shutdown(rx))
}

impl ShutdownTrigger {
    /// Moves to `stage` (never back).
    pub fn advance(&self, stage: Stage) {
        self.0.send_if_modified(|s| {
            let later = stage > *s;
            if later {
                *s = stage;
            }
            later
        });
    }

    pub fn subscribe(&self) -> Shutdown {
        Shutdown(self.0.subscribe())
    }
}

impl Shutdown {
    /// For threads between two blocking calls.
    pub fn is_stopping(&self) -> bool {
        *self.0.borrow() >= Stage::Stopping
    }

    /// Resolves once the stage is `stage` or later (at once if it already is; also if the
    /// trigger is gone, which only happens when `run` itself is gone).
    pub async fn reached(&mut self, stage: Stage) {
        let _ = self.0.wait_for(|s| *s >= stage).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn stages_only_advance_and_wake_every_holder() {
        let (trigger, mut a) = channel();
        let mut b = trigger.subscribe();
        assert!(!a.is_stopping());
        trigger.advance(Stage::Done);
        trigger.advance(Stage::Stopping);
        a.reached(Stage::Done).await;
        b.reached(Stage::Stopping).await;
        assert!(a.is_stopping() && b.is_stopping());
        assert_eq!(*a.0.borrow(), Stage::Done);
    }
}
