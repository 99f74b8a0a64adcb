//! Recorded sources: a directory of frames with their times of validity, for
//! replay through the same code paths as a live camera, and the recorder that
//! writes one.
//!
//! Layout: `meta.json` (`width`, `height`, `focal_px`, `cx_px`, `cy_px`,
//! `depth_scale_m`) and `frames.jsonl`, one object per frame: `seq`, `mono_ns`,
//! `depth` (a raw Z16 file name or null) and `color` (an RGB PNG file name or
//! null). File names are relative to the directory and may not leave it.

use super::{ColorImage, DepthSource, FrameSource, SourceError, Stamped};
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
        let bytes =
            fs::read(&path).map_err(|e| SourceError::Lost(format!("{}: {e}", path.display())))?;
        let data = crate::depthio::decode_z16(
            &bytes,
            self.meta.width,
            self.meta.height,
            self.meta.depth_scale_m,
        )
        .map_err(|e| SourceError::BadFrame {
            seq,
            reason: format!("{}: {e}", path.display()),
        })?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

impl FrameSource for Recording {
    fn next_frame(&mut self) -> Result<Option<Stamped<ColorImage>>, SourceError> {
        let mut cursor = self.next_color;
        let next = self
            .next_with(&mut cursor, |e| &e.color)
            .map(|(e, p)| (e.seq, e.mono_ns, p));
        self.next_color = cursor;
        let Some((seq, mono_ns, path)) = next else {
            return Ok(None);
        };
        let data = read_rgb_png(&path).map_err(|reason| SourceError::BadFrame { seq, reason })?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

fn read_rgb_png(path: &Path) -> Result<ColorImage, String> {
    let file = fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut dec = png::Decoder::new(BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec
        .read_info()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| format!("{}: image too large", path.display()))?;
    let mut buf = vec![0; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let (w, h) = (info.width as usize, info.height as usize);
    let rgb = match info.color_type {
        png::ColorType::Rgb => buf[..w * h * 3].to_vec(),
        png::ColorType::Rgba => buf[..w * h * 4]
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        png::ColorType::Grayscale => buf[..w * h].iter().flat_map(|&l| [l, l, l]).collect(),
        other => {
            return Err(format!(
                "{}: unsupported PNG colour type {other:?}",
                path.display()
            ))
        }
    };
    Ok(ColorImage {
        width: w,
        height: h,
        rgb,
    })
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
        writeln!(self.index, "{}", serde_json::to_string(&entry)?)?;
        self.index.sync_data()
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
}
