//! Recorded sources: a directory of frames with their times of validity, for
//! replay through the same code paths as a live camera, and the recorder that
//! writes one.
//!
//! Layout: `meta.json` (`width`, `height`, `focal_px`, `cx_px`, `cy_px`,
//! `depth_scale_m`) and `frames.jsonl`, one object per frame: `seq`, `mono_ns`,
//! `depth` (a raw Z16 file name or null) and `color` (an RGB PNG file name, a
//! `.jpg`/`.jpeg` MJPEG camera buffer as it came, or null). File names are relative
//! to the directory and may not leave it.
//!
//! Two replays: [`Recording`] gives the frames once with their recorded times;
//! [`LiveReplay`] paces them in real time, re-stamped and looping, as a stand-in
//! for a live camera. Both read and decode each frame's file when it is due.

use super::{Clock, MonotonicClock};
use super::{ColorImage, DepthSource, FrameSource, RawColor, SourceError, Stamped};
use crate::core::{DepthData, DepthImage, Intrinsics};
use serde::{Deserialize, Serialize};
use std::fs;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordingMeta {
    pub width: usize,
    pub height: usize,
    pub focal_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub depth_scale_m: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameEntry {
    pub seq: u64,
    pub mono_ns: u64,
    pub depth: Option<String>,
    pub color: Option<String>,
}

fn fatal(path: &Path, what: impl std::fmt::Display) -> SourceError {
    SourceError::Fatal(format!("{}: {what}", path.display()))
}

/// A recording opened for replay: depth and colour frames in recorded order.
#[derive(Debug)]
pub struct Recording {
    dir: PathBuf,
    meta: RecordingMeta,
    intrinsics: Intrinsics,
    frames: Vec<FrameEntry>,
    next_depth: usize,
    next_color: usize,
}

impl Recording {
    pub fn open(dir: &Path) -> Result<Recording, SourceError> {
        let meta_path = dir.join("meta.json");
        let text = fs::read_to_string(&meta_path).map_err(|e| fatal(&meta_path, e))?;
        let meta: RecordingMeta = serde_json::from_str(&text).map_err(|e| fatal(&meta_path, e))?;
        let intrinsics = Intrinsics::from_focal_px(
            meta.width,
            meta.height,
            meta.focal_px,
            Some((meta.cx_px, meta.cy_px)),
        )
        .map_err(|e| fatal(&meta_path, e))?;
        if !(meta.depth_scale_m.is_finite() && meta.depth_scale_m > 0.0) {
            return Err(fatal(&meta_path, "depth_scale_m must be positive"));
        }
        let index = dir.join("frames.jsonl");
        let file = fs::File::open(&index).map_err(|e| fatal(&index, e))?;
        let mut frames: Vec<FrameEntry> = Vec::new();
        for (n, line) in BufReader::new(file).lines().enumerate() {
            let line = line.map_err(|e| fatal(&index, e))?;
            if line.trim().is_empty() {
                continue;
            }
            let entry: FrameEntry = serde_json::from_str(&line)
                .map_err(|e| fatal(&index, format!("line {}: {e}", n + 1)))?;
            for name in [&entry.depth, &entry.color].into_iter().flatten() {
                if Path::new(name).components().count() != 1 || name.starts_with('.') {
                    return Err(fatal(
                        &index,
                        format!(
                            "line {}: file name {name:?} must not leave the directory",
                            n + 1
                        ),
                    ));
                }
            }
            if frames
                .last()
                .is_some_and(|last| entry.mono_ns < last.mono_ns)
            {
                return Err(fatal(
                    &index,
                    format!("line {}: mono_ns goes backwards", n + 1),
                ));
            }
            frames.push(entry);
        }
        Ok(Recording {
            dir: dir.to_path_buf(),
            meta,
            intrinsics,
            frames,
            next_depth: 0,
            next_color: 0,
        })
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    pub fn meta(&self) -> &RecordingMeta {
        &self.meta
    }
}

impl Recording {
    /// The next entry at or after `*cursor` that has a file of the kind `pick`
    /// selects, with that file's path; advances the cursor past it.
    fn next_with(
        &self,
        cursor: &mut usize,
        pick: fn(&FrameEntry) -> &Option<String>,
    ) -> Option<(&FrameEntry, PathBuf)> {
        while let Some(entry) = self.frames.get(*cursor) {
            *cursor += 1;
            if let Some(name) = pick(entry) {
                return Some((entry, self.dir.join(name)));
            }
        }
        None
    }

    /// Reads and decodes one depth file; `seq` names the frame in errors.
    fn read_depth(&self, seq: u64, path: &Path) -> Result<DepthImage, SourceError> {
        let bytes =
            fs::read(path).map_err(|e| SourceError::Lost(format!("{}: {e}", path.display())))?;
        crate::depthio::decode_z16(
            &bytes,
            self.meta.width,
            self.meta.height,
            self.meta.depth_scale_m,
        )
        .map_err(|e| SourceError::BadFrame {
            seq,
            reason: format!("{}: {e}", path.display()),
        })
    }

    /// The file as stored (a `.jpg` is an MJPEG camera's frame, anything else a PNG):
    /// decoded only if it is captured.
    fn read_color(&self, seq: u64, path: &Path) -> Result<RawColor, SourceError> {
        let jpeg = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("jpg") || e.eq_ignore_ascii_case("jpeg"));
        fs::read(path)
            .map(|b| {
                if jpeg {
                    RawColor::Mjpeg(b)
                } else {
                    RawColor::Png(b)
                }
            })
            .map_err(|e| SourceError::BadFrame {
                seq,
                reason: format!("{}: {e}", path.display()),
            })
    }
}

impl DepthSource for Recording {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError> {
        let mut cursor = self.next_depth;
        let next = self
            .next_with(&mut cursor, |e| &e.depth)
            .map(|(e, p)| (e.seq, e.mono_ns, p));
        self.next_depth = cursor;
        let Some((seq, mono_ns, path)) = next else {
            return Ok(None);
        };
        let data = self.read_depth(seq, &path)?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

impl FrameSource for Recording {
    fn next_frame(&mut self) -> Result<Option<Stamped<RawColor>>, SourceError> {
        let mut cursor = self.next_color;
        let next = self
            .next_with(&mut cursor, |e| &e.color)
            .map(|(e, p)| (e.seq, e.mono_ns, p));
        self.next_color = cursor;
        let Some((seq, mono_ns, path)) = next else {
            return Ok(None);
        };
        let data = self.read_color(seq, &path)?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

/// A recording replayed as a live camera: each frame falls due at the
/// recording's own offset from its first frame, counted from the first call;
/// it is delivered once the clock reaches that instant and stamped with it
/// (the instant on this clock, not the recorded one: like a V4L2 timestamp,
/// the capture's instant rather than the dequeue's). After the last frame the
/// recording starts again, one mean frame interval later; `seq` counts each
/// stream's frames from 1 across loops. A late caller gets the latest frame
/// due and skips those before it, leaving a gap in `seq`, as a camera drops
/// the frames nobody dequeued.
///
/// Files are read and decoded when due, not cached: that read and decode is
/// what a V4L2 dequeue and copy costs in flight, and 90 decoded 640×480 Z16
/// frames alone would be 55 MB. Depth and colour have one timeline but their
/// own cursors, so one replay can serve both.
#[derive(Debug)]
pub struct LiveReplay<C = MonotonicClock> {
    rec: Recording,
    clock: C,
    /// The recording's length in time, plus one mean frame interval.
    loop_ns: u64,
    /// The clock's instant of the recording's first frame (set at the first call).
    start_ns: Option<u64>,
    depth: Cursor,
    color: Cursor,
}

/// One stream of a live replay: which entries have its kind of file, and
/// how many of its frames have been delivered or skipped.
#[derive(Debug)]
struct Cursor {
    kind: &'static str,
    pick: fn(&FrameEntry) -> &Option<String>,
    /// Indices of the entries that have a file of this kind.
    entries: Vec<usize>,
    next: u64,
}

impl Cursor {
    fn new(
        rec: &Recording,
        kind: &'static str,
        pick: fn(&FrameEntry) -> &Option<String>,
    ) -> Cursor {
        Cursor {
            kind,
            pick,
            entries: (0..rec.frames.len())
                .filter(|&i| pick(&rec.frames[i]).is_some())
                .collect(),
            next: 0,
        }
    }
}

impl Recording {
    /// This recording replayed live on CLOCK_MONOTONIC.
    pub fn live(self) -> Result<LiveReplay, SourceError> {
        LiveReplay::new(self, MonotonicClock)
    }
}

impl<C: Clock> LiveReplay<C> {
    /// Needs at least two frames, with times that advance (else there is
    /// nothing to pace by).
    pub fn new(rec: Recording, clock: C) -> Result<LiveReplay<C>, SourceError> {
        let index = rec.dir.join("frames.jsonl");
        let (Some(first), Some(last)) = (rec.frames.first(), rec.frames.last()) else {
            return Err(fatal(&index, "no frames to replay"));
        };
        let span_ns = last.mono_ns - first.mono_ns;
        if span_ns == 0 {
            return Err(fatal(
                &index,
                "a live replay needs at least two frames with advancing mono_ns",
            ));
        }
        let loop_ns = span_ns + span_ns / (rec.frames.len() as u64 - 1);
        Ok(LiveReplay {
            depth: Cursor::new(&rec, "depth", |e| &e.depth),
            color: Cursor::new(&rec, "colour", |e| &e.color),
            rec,
            clock,
            loop_ns,
            start_ns: None,
        })
    }

    pub fn recording(&self) -> &Recording {
        &self.rec
    }

    /// Waits for the next frame of the depth or the colour stream; returns
    /// its file, the instant it fell due and its live seq.
    fn next_due(&mut self, depth: bool) -> Result<(PathBuf, u64, u64), SourceError> {
        let start = *self.start_ns.get_or_insert_with(|| self.clock.now_ns());
        let cursor = if depth { &self.depth } else { &self.color };
        if cursor.entries.is_empty() {
            let kind = cursor.kind;
            return Err(fatal(&self.rec.dir, format!("no {kind} frames to replay")));
        }
        let k = cursor.entries.len() as u64;
        let t0 = self.rec.frames[0].mono_ns;
        let due = |n: u64| {
            let entry = cursor.entries[(n % k) as usize];
            (
                entry,
                start + (n / k) * self.loop_ns + (self.rec.frames[entry].mono_ns - t0),
            )
        };
        let mut n = cursor.next;
        self.clock.wait_until(due(n).1);
        let now = self.clock.now_ns();
        while due(n + 1).1 <= now {
            n += 1;
        }
        let (entry, t) = due(n);
        // Every entry of the cursor has a file of its kind.
        let name = (cursor.pick)(&self.rec.frames[entry]).as_deref();
        let path = self.rec.dir.join(name.unwrap_or_default());
        let cursor = if depth {
            &mut self.depth
        } else {
            &mut self.color
        };
        cursor.next = n + 1;
        Ok((path, t, n + 1))
    }
}

impl<C: Clock> DepthSource for LiveReplay<C> {
    fn intrinsics(&self) -> Intrinsics {
        self.rec.intrinsics
    }

    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError> {
        let (path, mono_ns, seq) = self.next_due(true)?;
        let data = self.rec.read_depth(seq, &path)?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

impl<C: Clock> FrameSource for LiveReplay<C> {
    fn next_frame(&mut self) -> Result<Option<Stamped<RawColor>>, SourceError> {
        let (path, mono_ns, seq) = self.next_due(false)?;
        let data = self.rec.read_color(seq, &path)?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

/// Writes a recording: frames are appended as they come.
pub struct Recorder {
    dir: PathBuf,
    index: fs::File,
    meta: RecordingMeta,
}

impl Recorder {
    pub fn create(dir: &Path, meta: RecordingMeta) -> std::io::Result<Recorder> {
        fs::create_dir_all(dir)?;
        fs::write(dir.join("meta.json"), serde_json::to_string_pretty(&meta)?)?;
        let index = fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join("frames.jsonl"))?;
        Ok(Recorder {
            dir: dir.to_path_buf(),
            index,
            meta,
        })
    }

    /// Appends one frame; `depth` must be Z16 of the recording's size and scale.
    pub fn push(
        &mut self,
        seq: u64,
        mono_ns: u64,
        depth: Option<&DepthImage>,
        color: Option<&ColorImage>,
    ) -> std::io::Result<()> {
        let mut entry = self.depth_entry(seq, mono_ns, depth)?;
        if let Some(c) = color {
            let name = format!("color_{seq:06}.png");
            let file = fs::File::create(self.dir.join(&name))?;
            let mut enc = png::Encoder::new(
                std::io::BufWriter::new(file),
                c.width as u32,
                c.height as u32,
            );
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.write_header()
                .and_then(|mut w| w.write_image_data(&c.rgb))
                .map_err(std::io::Error::other)?;
            entry.color = Some(name);
        }
        self.append(&entry)
    }

    /// Appends one frame whose colour is an MJPEG camera's buffer, stored as it came
    /// (`color_NNNNNN.jpg`, replayed as MJPEG).
    pub fn push_mjpeg(
        &mut self,
        seq: u64,
        mono_ns: u64,
        depth: Option<&DepthImage>,
        mjpeg: &[u8],
    ) -> std::io::Result<()> {
        let mut entry = self.depth_entry(seq, mono_ns, depth)?;
        let name = format!("color_{seq:06}.jpg");
        fs::write(self.dir.join(&name), mjpeg)?;
        entry.color = Some(name);
        self.append(&entry)
    }

    fn append(&mut self, entry: &FrameEntry) -> std::io::Result<()> {
        writeln!(self.index, "{}", serde_json::to_string(entry)?)?;
        self.index.sync_data()
    }

    /// The frame's index entry with its depth file written.
    fn depth_entry(
        &mut self,
        seq: u64,
        mono_ns: u64,
        depth: Option<&DepthImage>,
    ) -> std::io::Result<FrameEntry> {
        let mut entry = FrameEntry {
            seq,
            mono_ns,
            depth: None,
            color: None,
        };
        if let Some(d) = depth {
            let DepthData::Z16 { data, scale_m } = d.data() else {
                return Err(std::io::Error::other("recordings hold Z16 depth"));
            };
            if d.width() != self.meta.width
                || d.height() != self.meta.height
                || *scale_m != self.meta.depth_scale_m
            {
                return Err(std::io::Error::other(
                    "depth frame does not match the recording's size or scale",
                ));
            }
            let name = format!("depth_{seq:06}.z16");
            fs::write(self.dir.join(&name), crate::depthio::encode_z16(data))?;
            entry.depth = Some(name);
        }
        Ok(entry)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> RecordingMeta {
        RecordingMeta {
            width: 4,
            height: 2,
            focal_px: 3.0,
            cx_px: 2.0,
            cy_px: 1.0,
            depth_scale_m: 0.001,
        }
    }

    #[test]
    fn a_recording_replays_what_was_recorded_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut rec = Recorder::create(dir.path(), meta()).unwrap();
        let depth = |v: u16| {
            DepthImage::new(
                4,
                2,
                DepthData::Z16 {
                    data: vec![v; 8],
                    scale_m: 0.001,
                },
            )
            .unwrap()
        };
        let color = ColorImage {
            width: 2,
            height: 1,
            rgb: vec![1, 2, 3, 4, 5, 6],
        };
        rec.push(1, 100, Some(&depth(1000)), Some(&color)).unwrap();
        rec.push(2, 200, None, Some(&color)).unwrap();
        rec.push(3, 300, Some(&depth(2000)), None).unwrap();
        let mut r = Recording::open(dir.path()).unwrap();
        assert_eq!(r.len(), 3);
        let d1 = r.next_depth().unwrap().unwrap();
        assert_eq!((d1.seq, d1.mono_ns), (1, 100));
        assert_eq!(d1.data, depth(1000));
        let d3 = r.next_depth().unwrap().unwrap();
        assert_eq!((d3.seq, d3.mono_ns, d3.data.clone()), (3, 300, depth(2000)));
        assert!(r.next_depth().unwrap().is_none());
        let c: Vec<u64> = std::iter::from_fn(|| r.next_frame().unwrap())
            .map(|f| f.seq)
            .collect();
        assert_eq!(c, vec![1, 2]);
        assert_eq!(r.intrinsics().focal_px(), 3.0);
    }

    #[test]
    fn bad_recordings_are_named() {
        let dir = tempfile::tempdir().unwrap();
        assert!(
            matches!(Recording::open(dir.path()), Err(SourceError::Fatal(m)) if m.contains("meta.json"))
        );
        fs::write(
            dir.path().join("meta.json"),
            serde_json::to_string(&meta()).unwrap(),
        )
        .unwrap();
        fs::write(
            dir.path().join("frames.jsonl"),
            "{\"seq\":1,\"mono_ns\":5,\"depth\":\"../etc/passwd\",\"color\":null}\n",
        )
        .unwrap();
        let e = Recording::open(dir.path()).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("must not leave"), "{e}");
        fs::write(
            dir.path().join("frames.jsonl"),
            "{\"seq\":1,\"mono_ns\":5,\"depth\":null,\"color\":null}\n{\"seq\":2,\"mono_ns\":4,\"depth\":null,\"color\":null}\n",
        )
        .unwrap();
        assert!(Recording::open(dir.path())
            .unwrap_err()
            .to_string()
            .contains("backwards"));
        // A missing depth file at replay is a lost source, not a panic.
        fs::write(
            dir.path().join("frames.jsonl"),
            "{\"seq\":1,\"mono_ns\":5,\"depth\":\"depth_000001.z16\",\"color\":null}\n",
        )
        .unwrap();
        let mut r = Recording::open(dir.path()).unwrap();
        assert!(matches!(r.next_depth(), Err(SourceError::Lost(_))));
    }

    /// A clock that jumps to whatever instant it is asked to wait for, and
    /// can be pushed ahead by the test (a late consumer).
    #[derive(Debug, Clone, Default)]
    struct Stepped(std::sync::Arc<std::sync::atomic::AtomicU64>);
    impl Clock for Stepped {
        fn now_ns(&self) -> u64 {
            self.0.load(std::sync::atomic::Ordering::SeqCst)
        }
        fn wait_until(&self, t_ns: u64) {
            self.0.fetch_max(t_ns, std::sync::atomic::Ordering::SeqCst);
        }
    }

    const MS: u64 = 1_000_000;

    /// Depth everywhere, colour on the first and last frame; recorded at
    /// 7.0, 7.010 and 7.030 s (irregular), so one loop is 30 + 15 ms.
    fn three_frames(dir: &Path) -> Recording {
        let mut rec = Recorder::create(dir, meta()).unwrap();
        let color = ColorImage {
            width: 1,
            height: 1,
            rgb: vec![9, 8, 7],
        };
        for (seq, t_ms, c) in [(10, 7000, true), (11, 7010, false), (12, 7030, true)] {
            rec.push(
                seq,
                t_ms * MS,
                Some(&depth_of(seq as u16)),
                c.then_some(&color),
            )
            .unwrap();
        }
        Recording::open(dir).unwrap()
    }

    fn depth_of(v: u16) -> DepthImage {
        DepthImage::new(
            4,
            2,
            DepthData::Z16 {
                data: vec![v; 8],
                scale_m: 0.001,
            },
        )
        .unwrap()
    }

    #[test]
    fn a_live_replay_is_paced_restamped_and_loops() {
        let dir = tempfile::tempdir().unwrap();
        let clock = Stepped::default();
        clock.wait_until(500 * MS);
        let mut live = LiveReplay::new(three_frames(dir.path()), clock.clone()).unwrap();
        assert_eq!(live.intrinsics().focal_px(), 3.0);
        let mut got = Vec::new();
        for _ in 0..7 {
            let f = live.next_depth().unwrap().unwrap();
            // Delivered when due: the clock was made to wait for the stamp.
            assert_eq!(clock.now_ns(), f.mono_ns);
            let DepthData::Z16 { data, .. } = f.data.data() else {
                unreachable!()
            };
            got.push((f.seq, (f.mono_ns - 500 * MS) / MS, data[0]));
        }
        assert_eq!(
            got,
            vec![
                (1, 0, 10),
                (2, 10, 11),
                (3, 30, 12),
                (4, 45, 10),
                (5, 55, 11),
                (6, 75, 12),
                (7, 90, 10),
            ]
        );
    }

    #[test]
    fn colour_shares_the_timeline_and_skips_frames_without_colour() {
        let dir = tempfile::tempdir().unwrap();
        let clock = Stepped::default();
        let mut live = LiveReplay::new(three_frames(dir.path()), clock.clone()).unwrap();
        let got: Vec<(u64, u64)> = (0..3)
            .map(|_| live.next_frame().unwrap().unwrap())
            .map(|f| (f.seq, f.mono_ns / MS))
            .collect();
        assert_eq!(got, vec![(1, 0), (2, 30), (3, 45)]);
        // The depth stream has its own cursor on the same timeline: it starts
        // at the first frame, due long ago, and catches up by skipping.
        let d = live.next_depth().unwrap().unwrap();
        assert_eq!((d.seq, d.mono_ns / MS), (4, 45));
    }

    #[test]
    fn a_late_consumer_gets_the_latest_due_frame_and_a_gap_in_seq() {
        let dir = tempfile::tempdir().unwrap();
        let clock = Stepped::default();
        let mut live = LiveReplay::new(three_frames(dir.path()), clock.clone()).unwrap();
        assert_eq!(live.next_depth().unwrap().unwrap().seq, 1);
        // 100 ms pass: frames due at 10, 30, 45, 55, 75 and 90 ms are missed;
        // the one due at 100 ms is delivered.
        clock.wait_until(100 * MS);
        let f = live.next_depth().unwrap().unwrap();
        assert_eq!((f.seq, f.mono_ns / MS), (8, 100));
        let g = live.next_depth().unwrap().unwrap();
        assert_eq!((g.seq, g.mono_ns / MS), (9, 120));
    }

    #[test]
    fn what_cannot_be_replayed_live_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let mut rec = Recorder::create(dir.path(), meta()).unwrap();
        rec.push(1, 5 * MS, Some(&depth_of(1)), None).unwrap();
        let one = Recording::open(dir.path()).unwrap();
        let e = LiveReplay::new(one, Stepped::default()).unwrap_err();
        assert!(e.to_string().contains("advancing mono_ns"), "{e}");
        rec.push(2, 6 * MS, Some(&depth_of(2)), None).unwrap();
        let mut live = Recording::open(dir.path()).unwrap().live().unwrap();
        assert!(
            matches!(live.next_frame(), Err(SourceError::Fatal(m)) if m.contains("no colour frames"))
        );
        // A file gone at replay is a lost source, as from a camera.
        fs::remove_file(dir.path().join("depth_000001.z16")).unwrap();
        assert!(matches!(live.next_depth(), Err(SourceError::Lost(_))));
    }
}
