//! The daemon: the tasks that feed the pipeline (link, sources, writer) and the
//! pipeline itself. `step` is pure and owns the per-frame decision; `camera`
//! is the pure MAVLink camera protocol; the tasks at the edges own the devices.

pub mod camera;
pub mod devices;
pub mod run;
pub mod sim;
pub mod step;
