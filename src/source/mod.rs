//! Frame and depth sources behind two narrow traits, so the flight, the bench
//! and the tests run the same code paths: recorded (replay), V4L2 (feature
//! `v4l2`) and the synthetic renderer (feature `sim`). Every frame carries its
//! time of validity on the companion's monotonic clock, as V4L2 stamps it.
//!
//! Sources are blocking: each runs on its own thread (one task per device),
//! since V4L2 dequeues, file reads and rendering all block.

pub mod decode;
pub mod recorded;
pub mod select;
#[cfg(feature = "sim")]
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
    /// The frame due never came (a stalled camera): skip it; the gap it leaves in the
    /// frame counter counts it.
    #[error("frame {seq} never came")]
    Missed { seq: u64 },
    /// A simulated camera with no pose yet to render from (the bench before the
    /// autopilot's first position): skip it. Nothing is wrong with the frame.
    #[error("frame {seq}: no pose to render it from")]
    Unposed { seq: u64 },
    /// Configuration or setup that will not work: fatal.
    #[error("{0}")]
    Fatal(String),
}

/// A colour frame as the camera delivered it. Decoding is left to the frame
/// that is captured: at 30 fps, decoding every frame cost more than the whole
/// estimator (`docs/daemon-load.md`).
#[derive(Debug, Clone, PartialEq)]
pub enum RawColor {
    Rgb(ColorImage),
    Mjpeg(Vec<u8>),
    Yuyv {
        width: usize,
        height: usize,
        data: Vec<u8>,
    },
    Png(Vec<u8>),
}

impl RawColor {
    pub fn decode(&self) -> Result<ColorImage, String> {
        match self {
            RawColor::Rgb(c) => Ok(c.clone()),
            RawColor::Mjpeg(b) => decode::mjpeg_to_rgb(b).map_err(|e| e.to_string()),
            RawColor::Yuyv {
                width,
                height,
                data,
            } => decode::yuyv_to_rgb(*width, *height, data).map_err(|e| e.to_string()),
            RawColor::Png(b) => decode::png_to_rgb(b),
        }
    }
}

/// A colour camera.
pub trait FrameSource: Send {
    /// The next frame, blocking until it arrives; `None` at the end of a replay.
    fn next_frame(&mut self) -> Result<Option<Stamped<RawColor>>, SourceError>;
}

/// A depth camera.
pub trait DepthSource: Send {
    fn intrinsics(&self) -> Intrinsics;
    /// The next depth frame, blocking until it arrives; `None` at the end.
    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError>;
    /// For a source that paces itself on its [`Clock`]: the instant its next frame is due,
    /// when known. The daemon's depth loop waits for it on the runtime's timer first, so on
    /// simulated time the clock moves there instead of a thread sleeping; `next_depth` then
    /// returns at once. `None` (a device, or the first frame): `next_depth` decides.
    fn due_ns(&self) -> Option<u64> {
        None
    }
}

/// The colour frame for a capture decided at an instant: the nearest a camera
/// delivered, or (synthetic) one rendered at that instant. Called off the
/// trigger path, by the capture writer.
pub trait FrameAt: Send {
    /// The frame as the camera delivered it, not decoded: the writer stores an MJPEG
    /// frame as it came (`capture::jpeg`) and decodes the others itself.
    fn raw_at(&mut self, mono_ns: u64) -> Option<Stamped<RawColor>>;

    /// The frame decoded; `None` also when it does not decode.
    fn frame_at(&mut self, mono_ns: u64) -> Option<Stamped<ColorImage>> {
        let raw = self.raw_at(mono_ns)?;
        let data = match raw.data {
            RawColor::Rgb(c) => c,
            other => other.decode().ok()?,
        };
        Some(Stamped {
            mono_ns: raw.mono_ns,
            seq: raw.seq,
            data,
        })
    }
}

/// The last few frames of a streaming camera, fed by its thread; `frame_at`
/// picks the nearest one within `tolerance_ns`. Full: the oldest frame goes.
#[derive(Clone)]
pub struct FrameRing {
    inner: std::sync::Arc<RingInner>,
    capacity: usize,
    tolerance_ns: u64,
}

#[derive(Default)]
struct RingInner {
    frames: std::sync::Mutex<std::collections::VecDeque<Stamped<RawColor>>>,
    /// Told of every new frame, for a reader waiting on an instant not yet seen.
    pushed: std::sync::Condvar,
}

impl FrameRing {
    pub fn new(capacity: usize, tolerance_ns: u64) -> Self {
        FrameRing {
            inner: Default::default(),
            capacity: capacity.max(1),
            tolerance_ns,
        }
    }

    pub fn push(&self, f: Stamped<RawColor>) {
        let mut q = self.inner.frames.lock().unwrap_or_else(|p| p.into_inner());
        while q.len() >= self.capacity {
            q.pop_front();
        }
        q.push_back(f);
        drop(q);
        self.inner.pushed.notify_all();
    }

    /// The frame nearest `mono_ns` within the tolerance, as delivered, waiting up to
    /// `wait` for one to arrive (the colour frame of a depth instant may come a little
    /// later); woken by each new frame, not polling. Decoding is left to the caller,
    /// outside the lock, and only for the frame that is captured.
    pub fn raw_at_within(
        &self,
        mono_ns: u64,
        wait: std::time::Duration,
    ) -> Option<Stamped<RawColor>> {
        let deadline = std::time::Instant::now() + wait;
        let mut q = self.inner.frames.lock().unwrap_or_else(|p| p.into_inner());
        loop {
            if let Some(f) = self.nearest(&q, mono_ns) {
                return Some(f);
            }
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return None;
            }
            q = self
                .inner
                .pushed
                .wait_timeout(q, left)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }

    fn nearest(
        &self,
        q: &std::collections::VecDeque<Stamped<RawColor>>,
        mono_ns: u64,
    ) -> Option<Stamped<RawColor>> {
        q.iter()
            .min_by_key(|f| f.mono_ns.abs_diff(mono_ns))
            .filter(|f| f.mono_ns.abs_diff(mono_ns) <= self.tolerance_ns)
            .cloned()
    }
}

impl FrameAt for FrameRing {
    fn raw_at(&mut self, mono_ns: u64) -> Option<Stamped<RawColor>> {
        self.raw_at_within(mono_ns, std::time::Duration::ZERO)
    }
}

/// Time for a source that paces itself: the monotonic clock in flight, a
/// stepped clock in tests.
pub trait Clock: Send {
    fn now_ns(&self) -> u64;
    /// Returns once `now_ns() >= t_ns`.
    fn wait_until(&self, t_ns: u64);
}

/// CLOCK_MONOTONIC, sleeping the thread.
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        crate::link::mono_ns()
    }
    fn wait_until(&self, t_ns: u64) {
        let now = self.now_ns();
        if t_ns > now {
            std::thread::sleep(std::time::Duration::from_nanos(t_ns - now));
        }
    }
}

#[cfg(test)]
mod ring_tests {
    use super::*;

    fn frame(mono_ns: u64) -> Stamped<RawColor> {
        Stamped {
            mono_ns,
            seq: mono_ns,
            data: RawColor::Rgb(ColorImage {
                width: 1,
                height: 1,
                rgb: vec![0; 3],
            }),
        }
    }

    #[test]
    fn the_nearest_frame_within_tolerance_or_none() {
        let mut r = FrameRing::new(3, 20);
        for t in [100, 133, 166, 200] {
            r.push(frame(t));
        }
        // 100 was pushed out by capacity 3.
        assert_eq!(r.frame_at(140).map(|f| f.mono_ns), Some(133));
        assert_eq!(r.frame_at(190).map(|f| f.mono_ns), Some(200));
        assert_eq!(r.frame_at(100), None);
        assert_eq!(r.frame_at(260), None);
    }
}
