//! The pure numerical core: depth frames in, permissible sampling spacing out.
//! No async runtime, no files, no devices, no clock: everything here is a plain function
//! or a state machine over its arguments (a test enforces it).

pub mod allowlist;
pub mod attitude;
pub mod backoff;
pub mod closedloop;
pub mod depth;
pub mod distset;
pub mod estimate;
pub mod geo;
pub mod glitch;
pub mod inverse;
pub mod localpos;
pub mod occlusion;
pub mod params;
pub mod plane;
pub mod pose;
pub mod score;
pub mod spacing;
pub mod step;
pub mod timesync;
pub mod trigger;
pub mod visibility;

pub use depth::{DepthData, DepthError, DepthImage, Intrinsics, IntrinsicsError, TrackAxis};
pub use estimate::{
    estimate, Bound, Estimate, EstimateError, Estimator, NoEstimate, QualityPrediction,
    VisibilitySummary,
};
pub use params::{Decimation, EstimatorParams, Model, ParamError, Profile, Quality};

#[cfg(test)]
mod tests;
