//! The daemon: the tasks that feed the pipeline (link, sources, writer) and the
//! pipeline itself. `step` is pure and owns the per-frame decision; the tasks
//! at the edges own the devices.

pub mod step;
