//! Frame and depth sources behind two narrow traits, so the flight, the bench
//! and the tests run the same code paths: recorded (replay), V4L2 (feature
//! `v4l2`) and, in a later part, the synthetic renderer. Every frame carries its
//! time of validity on the companion's monotonic clock, as V4L2 stamps it.
//!
//! Sources are blocking: each runs on its own thread (one task per device),
//! since V4L2 dequeues, file reads and rendering all block.

pub mod decode;
pub mod recorded;
pub mod select;
pub mod synthetic;
#[cfg(feature = "v4l2")]
pub mod v4l2;

use crate::core::{DepthImage, Intrinsics};
use thiserror::Error;

/// A sample with its time of validity.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamped<T> {
    /// Companion monotonic clock (CLOCK_MONOTONIC), nanoseconds.
    pub mono_ns: u64,
    /// The source's own frame counter (gaps mean dropped frames).
    pub seq: u64,
    pub data: T,
}

/// An RGB8 image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorImage {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
}

#[derive(Debug, Error)]
pub enum SourceError {
    /// The device or directory is gone (unplugged, re-enumerated): reopen.
    #[error("source lost: {0}")]
    Lost(String),
    /// One frame could not be decoded: skip it.
    #[error("bad frame {seq}: {reason}")]
    BadFrame { seq: u64, reason: String },
    /// Configuration or setup that will not work: fatal.
    #[error("{0}")]
    Fatal(String),
}

/// A colour camera.
pub trait FrameSource: Send {
    /// The next frame, blocking until it arrives; `None` at the end of a replay.
    fn next_frame(&mut self) -> Result<Option<Stamped<ColorImage>>, SourceError>;
}

/// A depth camera.
pub trait DepthSource: Send {
    fn intrinsics(&self) -> Intrinsics;
    /// The next depth frame, blocking until it arrives; `None` at the end.
    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError>;
}
