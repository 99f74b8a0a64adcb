//! Live V4L2 cameras (feature `v4l2`): Z16 depth and MJPEG/YUYV colour, e.g. an
//! Intel RealSense. Buffers are decoded by `decode`, tested on recorded buffers;
//! this file only owns the device: finding it, streaming, and telling a lost
//! device (reopen) from a bad frame (skip).

use super::decode::z16_to_depth;
use super::select::{DeviceInfo, DeviceSelector};
use super::{DepthSource, FrameSource, RawColor, SourceError, Stamped};
use crate::core::{DepthImage, Intrinsics};
use std::path::{Path, PathBuf};
use v4l::buffer::Type;
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

/// Every /dev/video* node with what identifies it.
pub fn scan() -> Vec<DeviceInfo> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir("/sys/class/video4linux") else {
        return out;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let path = PathBuf::from("/dev").join(&name);
        let Ok(dev) = Device::with_path(&path) else {
            continue;
        };
        let Ok(caps) = dev.query_caps() else { continue };
        let formats = dev
            .enum_formats()
            .map(|f| {
                f.iter()
                    .filter_map(|d| d.fourcc.str().ok().map(str::to_string))
                    .collect()
            })
            .unwrap_or_default();
        // The USB serial sits on the USB device, a few levels above the interface.
        let serial = ["device/../serial", "device/../../serial"]
            .iter()
            .find_map(|rel| std::fs::read_to_string(e.path().join(rel)).ok())
            .map(|s| s.trim().to_string());
        out.push(DeviceInfo {
            path,
            serial,
            bus: caps.bus,
            card: caps.card,
            formats,
        });
    }
    out
}

fn lost(path: &Path, e: impl std::fmt::Display) -> SourceError {
    SourceError::Lost(format!("{}: {e}", path.display()))
}

struct Streaming {
    path: PathBuf,
    stream: Stream<'static>,
}

fn open(
    sel: &DeviceSelector,
    fourcc: &str,
    width: usize,
    height: usize,
    fps: u32,
) -> Result<Streaming, SourceError> {
    let devices = scan();
    let info = sel.pick(&devices, fourcc).ok_or_else(|| {
        SourceError::Lost(format!(
            "no V4L2 device matches {sel:?} with format {fourcc:?}"
        ))
    })?;
    let dev = Device::with_path(&info.path).map_err(|e| lost(&info.path, e))?;
    let mut fmt = dev.format().map_err(|e| lost(&info.path, e))?;
    fmt.width = width as u32;
    fmt.height = height as u32;
    let code: [u8; 4] = fourcc
        .as_bytes()
        .try_into()
        .map_err(|_| SourceError::Fatal(format!("bad FourCC {fourcc:?}")))?;
    fmt.fourcc = FourCC::new(&code);
    let got = dev.set_format(&fmt).map_err(|e| lost(&info.path, e))?;
    if got.width as usize != width || got.height as usize != height || got.fourcc != fmt.fourcc {
        return Err(SourceError::Fatal(format!(
            "{} gives {}x{} {} where {width}x{height} {fourcc} was asked",
            info.path.display(),
            got.width,
            got.height,
            got.fourcc
        )));
    }
    if fps > 0 {
        let params = v4l::video::capture::Parameters::with_fps(fps);
        dev.set_params(&params).map_err(|e| lost(&info.path, e))?;
    }
    let mut stream =
        Stream::with_buffers(&dev, Type::VideoCapture, 4).map_err(|e| lost(&info.path, e))?;
    // A dequeue that never returns would hang the task: bound it.
    stream.set_timeout(std::time::Duration::from_secs(2));
    Ok(Streaming {
        path: info.path.clone(),
        stream,
    })
}

impl Streaming {
    /// The next buffer: bytes in use, kernel timestamp (ns) and sequence.
    fn next(&mut self) -> Result<(Vec<u8>, u64, u64), SourceError> {
        let (buf, meta) = self.stream.next().map_err(|e| lost(&self.path, e))?;
        let used = (meta.bytesused as usize).min(buf.len());
        // Drivers stamp buffers with CLOCK_MONOTONIC (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC).
        let ns = meta.timestamp.sec as u64 * 1_000_000_000 + meta.timestamp.usec as u64 * 1_000;
        Ok((buf[..used].to_vec(), ns, meta.sequence as u64))
    }
}

/// A stream that reopens itself: on an error the device is dropped, and the
/// next call finds it again by what identifies it, wherever it re-enumerated.
struct Reopening {
    sel: DeviceSelector,
    fourcc: &'static str,
    width: usize,
    height: usize,
    fps: u32,
    s: Option<Streaming>,
}

impl Reopening {
    fn open(
        sel: DeviceSelector,
        fourcc: &'static str,
        width: usize,
        height: usize,
        fps: u32,
    ) -> Result<Self, SourceError> {
        let s = open(&sel, fourcc, width, height, fps)?;
        Ok(Reopening {
            sel,
            fourcc,
            width,
            height,
            fps,
            s: Some(s),
        })
    }

    fn next(&mut self) -> Result<(Vec<u8>, u64, u64), SourceError> {
        let s = match &mut self.s {
            Some(s) => s,
            None => self.s.insert(open(
                &self.sel,
                self.fourcc,
                self.width,
                self.height,
                self.fps,
            )?),
        };
        s.next().inspect_err(|_| self.s = None)
    }
}

/// Z16 depth from a V4L2 device.
pub struct V4l2Depth {
    stream: Reopening,
    intrinsics: Intrinsics,
    scale_m: f64,
}

impl V4l2Depth {
    pub fn open(
        sel: DeviceSelector,
        intrinsics: Intrinsics,
        scale_m: f64,
        fps: u32,
    ) -> Result<Self, SourceError> {
        let stream = Reopening::open(sel, "Z16 ", intrinsics.width(), intrinsics.height(), fps)?;
        Ok(V4l2Depth {
            stream,
            intrinsics,
            scale_m,
        })
    }
}

impl DepthSource for V4l2Depth {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn next_depth(&mut self) -> Result<Option<Stamped<DepthImage>>, SourceError> {
        let (buf, mono_ns, seq) = self.stream.next()?;
        let (w, h) = (self.stream.width, self.stream.height);
        let data = z16_to_depth(w, h, &buf, self.scale_m).map_err(|e| SourceError::BadFrame {
            seq,
            reason: e.to_string(),
        })?;
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}

/// Colour from a V4L2 device, MJPEG or YUYV.
pub struct V4l2Color {
    stream: Reopening,
}

impl V4l2Color {
    pub fn open(
        sel: DeviceSelector,
        mjpeg: bool,
        width: usize,
        height: usize,
        fps: u32,
    ) -> Result<Self, SourceError> {
        let fourcc = if mjpeg { "MJPG" } else { "YUYV" };
        Ok(V4l2Color {
            stream: Reopening::open(sel, fourcc, width, height, fps)?,
        })
    }
}

impl FrameSource for V4l2Color {
    fn next_frame(&mut self) -> Result<Option<Stamped<RawColor>>, SourceError> {
        let (buf, mono_ns, seq) = self.stream.next()?;
        // Kept as delivered: only a captured frame is decoded.
        let data = if self.stream.fourcc == "MJPG" {
            RawColor::Mjpeg(buf.to_vec())
        } else {
            RawColor::Yuyv {
                width: self.stream.width,
                height: self.stream.height,
                data: buf.to_vec(),
            }
        };
        Ok(Some(Stamped { mono_ns, seq, data }))
    }
}
