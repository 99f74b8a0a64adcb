//! alfd: occlusion-aware light-field sampling for drone captures.
//! `core` is pure numerics (the `alfd-core` crate in `crates/alfd-core`, re-exported); everything
//! else is the edges (files, devices, links).
//! The simulator, renderer and evaluation are behind the default feature `sim`.

pub mod capture;
pub mod config;
pub use alfd_core as core;
pub mod daemon;
pub mod depthio;
#[cfg(feature = "sim")]
pub mod eval;
pub mod link;
#[cfg(feature = "sim")]
pub mod metrics;
pub mod notify;
#[cfg(feature = "sim")]
pub mod render;
pub mod report;
#[cfg(feature = "sim")]
pub mod scene;
#[cfg(feature = "sim")]
pub mod simreport;
pub mod source;
pub mod synth;
pub mod tradeoff;
pub mod workers;
