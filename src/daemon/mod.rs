//! The daemon: the tasks that feed the pipeline (link, sources, writer) and the
//! pipeline itself. `step` is pure and owns the per-frame decision; `camera`
//! is the pure MAVLink camera protocol; `coordinator` the pure state machine
//! between them; the tasks at the edges own the devices; `run` wires them.

pub mod camera;
#[cfg(feature = "sim")]
pub mod camera_card;
pub(crate) mod colour;
pub mod coordinator;
pub mod devices;
pub mod estimator_task;
pub mod latency;
mod loops;
pub mod outbox;
pub mod report;
pub mod run;
mod serve;
pub mod shutdown;
#[cfg(feature = "sim")]
pub mod sim;
pub mod step;
pub mod writer;
