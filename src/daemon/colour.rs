//! A streaming colour camera's side of the daemon: its thread, which keeps the camera's
//! last frames in a ring until the run stops, and the ring as the writer sees it, waiting
//! briefly for the frame of an instant the camera has not delivered yet.

use super::loops::spawn_thread;
use super::shutdown::Shutdown;
use crate::source::{FrameAt, FrameRing, FrameSource, RawColor, SourceError, Stamped};
use std::time::Duration;

/// How long the writer waits for the frame of a capture's instant to arrive.
pub const FRAME_WAIT: Duration = Duration::from_millis(200);

/// Frames a streaming camera's ring keeps: every frame of the last image budget (a
/// capture's image may be made up to then), and two more for the tolerance either side.
/// Eight frames (267 ms at 30 fps, 133 ms at 60) were fewer than a capture waiting for its
/// pose (up to one telemetry period) and the writer's queue can take.
pub(crate) fn ring_frames(fps: f64) -> usize {
    (fps * super::outbox::IMAGE_BUDGET_NS as f64 * 1e-9).ceil() as usize + 2
}

/// A streaming camera's thread, feeding a ring of its last frames until the run stops.
pub(crate) fn stream_thread(
    mut s: Box<dyn FrameSource>,
    frames: usize,
    tolerance_ns: u64,
    stop: Shutdown,
) -> (WaitingRing, std::thread::JoinHandle<()>) {
    let ring = FrameRing::new(frames, tolerance_ns);
    let feed = ring.clone();
    let h = spawn_thread("alfd-camera", move || {
        while !stop.is_stopping() {
            match s.next_frame() {
                Ok(Some(f)) => feed.push(f),
                Ok(None) => return,
                Err(SourceError::Fatal(e)) => {
                    tracing::error!("camera: {e}");
                    return;
                }
                Err(e) => tracing::warn!("camera: {e}"),
            }
        }
    });
    (WaitingRing(ring), h)
}

/// The ring as the writer reads it: the frame of an instant, waited for up to
/// [`FRAME_WAIT`] (woken by each new frame).
pub(crate) struct WaitingRing(FrameRing);

impl FrameAt for WaitingRing {
    fn raw_at(&mut self, mono: u64) -> Option<Stamped<RawColor>> {
        self.0.raw_at_within(mono, FRAME_WAIT)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::outbox::IMAGE_BUDGET_NS;
    use crate::source::ColorImage;

    /// The ring still holds the frame of a capture's instant when the writer starts its
    /// image, however late within the budget, at any frame rate.
    #[test]
    fn the_colour_ring_spans_the_image_budget_at_any_frame_rate() {
        for fps in [1.0, 6.0, 15.0, 30.0, 60.0, 90.0] {
            let n = ring_frames(fps);
            let span_ns = (n - 1) as f64 / fps * 1e9;
            assert!(
                span_ns >= IMAGE_BUDGET_NS as f64,
                "{n} frames at {fps} fps span {span_ns} ns"
            );
        }
        assert_eq!(ring_frames(30.0), 14);
    }

    fn grey(mono_ns: u64, seq: u64) -> Stamped<RawColor> {
        Stamped {
            mono_ns,
            seq,
            data: RawColor::Rgb(ColorImage {
                width: 2,
                height: 1,
                rgb: vec![seq as u8; 6],
            }),
        }
    }

    /// A reader asking for an instant the camera has not delivered yet gets the frame
    /// another thread pushes (whether before or during its wait: no sleep decides the
    /// outcome), one for an instant already seen gets it at once, and one whose frame
    /// never comes gets none when its wait is over.
    #[test]
    fn a_waiting_reader_gets_the_frame_pushed_after_it_asked() {
        let ring = FrameRing::new(4, 5_000_000);
        let mut reader = WaitingRing(ring.clone());
        ring.push(grey(100_000_000, 1));
        let asked = std::sync::Arc::new(std::sync::Barrier::new(2));
        let (a, feed) = (asked.clone(), ring.clone());
        let camera = std::thread::spawn(move || {
            a.wait();
            feed.push(grey(200_000_000, 2));
        });
        asked.wait();
        let f = ring
            .raw_at_within(201_000_000, Duration::from_secs(30))
            .expect("the frame pushed while waiting");
        assert_eq!((f.seq, f.mono_ns), (2, 200_000_000));
        camera.join().unwrap();
        // Nearest within the tolerance, at once, for an instant already seen.
        assert_eq!(reader.frame_at(99_000_000).map(|f| f.seq), Some(1));
        // None within the tolerance and none to come.
        assert!(ring
            .raw_at_within(150_000_000, Duration::from_millis(1))
            .is_none());
    }
}
