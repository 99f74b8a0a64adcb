//! Where the daemon's device loops (depth, estimator, writer) run. In flight each has its
//! own named thread driving its future, so a blocking camera read, an estimate or a slow
//! write holds only that thread. On simulated time ([`crate::link::simulated`]) they are
//! tasks on the caller's current-thread runtime: the runtime's paused clock moves only when
//! every task waits, so a render or an estimate takes no simulated time and a run repeats
//! exactly. The loops are the same code either way.

use std::future::Future;

/// A running loop, to be joined when the run stops.
pub(crate) enum Running<T> {
    Thread(std::thread::JoinHandle<T>),
    Task(tokio::task::JoinHandle<T>),
}

impl<T: Send + 'static> Running<T> {
    /// Its result, once it ends; `None` if it panicked.
    pub(crate) async fn join(self) -> Option<T> {
        match self {
            Running::Thread(h) => tokio::task::spawn_blocking(move || h.join().ok())
                .await
                .ok()
                .flatten(),
            Running::Task(h) => h.await.ok(),
        }
    }
}

/// Starts a named thread (the daemon's threads are named in `top` and in panics).
pub(crate) fn spawn_thread<T: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::thread::JoinHandle<T> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .expect("a thread starts")
}

/// Runs `fut` on its own thread named `name` (driven by the runtime `rt`, for its timers and
/// channels), or as a task of `rt` on simulated time.
pub(crate) fn spawn_loop<T: Send + 'static>(
    name: &str,
    rt: &tokio::runtime::Handle,
    fut: impl Future<Output = T> + Send + 'static,
) -> Running<T> {
    if crate::link::simulated() {
        Running::Task(rt.spawn(fut))
    } else {
        let rt = rt.clone();
        Running::Thread(spawn_thread(name, move || rt.block_on(fut)))
    }
}
