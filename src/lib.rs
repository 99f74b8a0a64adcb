//! alfd: occlusion-aware light-field sampling for drone captures.
//! `core` is pure numerics; everything else is the edges (files, devices, links).

pub mod capture;
pub mod config;
pub mod core;
pub mod daemon;
pub mod depthio;
pub mod eval;
pub mod link;
pub mod metrics;
pub mod notify;
pub mod render;
pub mod report;
pub mod scene;
pub mod simreport;
pub mod source;
pub mod synth;
pub mod tradeoff;
