//! Threads lent to the core's visibility sweep (`core::visibility::SweepWorkers`).
//! The core names no thread; the daemon's estimator owns these, one scope per
//! frame, so they end with the frame's estimate and nothing outlives a shutdown.

use crate::core::visibility::{LineRun, SweepWorkers};

/// The sweep's runs dealt in turn to `threads` scoped threads, the calling
/// thread one of them. Spawning per frame costs tens of microseconds against a
/// sweep of milliseconds, and leaves no pool to stop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ThreadWorkers {
    threads: usize,
}

impl ThreadWorkers {
    /// At least one thread (the caller's).
    pub fn new(threads: usize) -> ThreadWorkers {
        ThreadWorkers {
            threads: threads.max(1),
        }
    }
}

impl SweepWorkers for ThreadWorkers {
    fn threads(&self) -> usize {
        self.threads
    }

    fn each(&self, runs: &mut [LineRun], job: &(dyn Fn(&mut LineRun) + Sync)) {
        let n = self.threads.min(runs.len());
        if n <= 1 {
            runs.iter_mut().for_each(job);
            return;
        }
        // Dealt in turn rather than in contiguous halves: whichever part of the
        // frame holds the occluders (the costly lines), every thread gets some.
        let mut hands: Vec<Vec<&mut LineRun>> = (0..n).map(|_| Vec::new()).collect();
        for (i, run) in runs.iter_mut().enumerate() {
            hands[i % n].push(run);
        }
        let mut hands = hands.into_iter();
        let own = hands.next().unwrap_or_default();
        std::thread::scope(|s| {
            for hand in hands {
                let spawned = std::thread::Builder::new()
                    .name("alfd-sweep".into())
                    .spawn_scoped(s, move || hand.into_iter().for_each(job));
                if let Err(e) = spawned {
                    // No thread to be had (a resource limit): the core sweeps
                    // the runs no one took on this thread after the scope.
                    tracing::warn!("cannot start a sweep thread, sweeping on fewer: {e}");
                }
            }
            own.into_iter().for_each(job);
        });
    }
}
