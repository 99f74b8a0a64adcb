//! Depth files into depth images (outside the core: this module touches files).
//!
//! Owns the on-disk depth formats: raw little-endian Z16, 16-bit greyscale PNG
//! (Z16 units) and greyscale PFM (metres). It reads them into
//! [`DepthImage`]s and writes them back (used to make test data). Decoders
//! never panic on any input bytes and never allocate more than the input could
//! hold; every error is one line that names the file and what was expected.

use std::fmt;
use std::io::{self, Cursor};
use std::path::Path;

use thiserror::Error;

use crate::core::{DepthData, DepthError, DepthImage};

/// A depth file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DepthFormat {
    /// Raw little-endian `u16` per pixel, row-major, no header; units of `scale_m`.
    Z16,
    /// 16-bit greyscale PNG holding Z16 values.
    Png16,
    /// Greyscale PFM (`Pf`), `f32` metres, rows stored bottom-to-top.
    Pfm,
}

impl DepthFormat {
    /// Every format, in the order of [`DepthFormat::as_str`] listings.
    pub const ALL: [DepthFormat; 3] = [DepthFormat::Z16, DepthFormat::Png16, DepthFormat::Pfm];

    /// `"z16"`, `"png16"` or `"pfm"` (ASCII case-insensitive).
    pub fn parse(s: &str) -> Option<DepthFormat> {
        DepthFormat::ALL
            .into_iter()
            .find(|f| f.as_str().eq_ignore_ascii_case(s))
    }

    /// By extension (case-insensitive): `.z16`/`.raw` → Z16, `.png` → Png16, `.pfm` → Pfm.
    pub fn from_path(path: &Path) -> Option<DepthFormat> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "z16" | "raw" => Some(DepthFormat::Z16),
            "png" => Some(DepthFormat::Png16),
            "pfm" => Some(DepthFormat::Pfm),
            _ => None,
        }
    }

    /// The name accepted by [`DepthFormat::parse`].
    pub fn as_str(self) -> &'static str {
        match self {
            DepthFormat::Z16 => "z16",
            DepthFormat::Png16 => "png16",
            DepthFormat::Pfm => "pfm",
        }
    }

    /// Human name used in error messages.
    fn label(self) -> &'static str {
        match self {
            DepthFormat::Z16 => "Z16",
            DepthFormat::Png16 => "PNG",
            DepthFormat::Pfm => "PFM",
        }
    }
}

impl fmt::Display for DepthFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How to read a depth file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadOptions {
    /// Format; `None` means "from the file extension".
    pub format: Option<DepthFormat>,
    /// Image width: required for Z16, checked against the file for PNG and PFM.
    pub width: Option<usize>,
    /// Image height: required for Z16, checked against the file for PNG and PFM.
    pub height: Option<usize>,
    /// Metres per Z16 unit (Z16 and PNG; PFM is already in metres).
    pub scale_m: f64,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions {
            format: None,
            width: None,
            height: None,
            scale_m: 0.001,
        }
    }
}

/// Why a depth file could not be read, decoded or encoded. Every message is one
/// line naming the file (or "Z16 data", "PNG data", "PFM data" for bare bytes).
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DepthFileError {
    #[error("cannot read {file}: {reason}")]
    Read {
        file: String,
        kind: io::ErrorKind,
        reason: String,
    },
    #[error("cannot write {file}: {reason}")]
    Write {
        file: String,
        kind: io::ErrorKind,
        reason: String,
    },
    #[error(
        "cannot tell the depth format of {file} from its extension; give --format z16, png16 or pfm (or name it .z16/.raw, .png or .pfm)"
    )]
    UnknownFormat { file: String },
    #[error(
        "{file}: raw Z16 depth has no header, so its size must be given with --width/--height"
    )]
    MissingSize { file: String },
    #[error(
        "{file} is truncated: a {width}x{height} {} image needs {expected} bytes of pixel data, found {found}",
        .format.label()
    )]
    Truncated {
        file: String,
        format: DepthFormat,
        width: usize,
        height: usize,
        expected: usize,
        found: usize,
    },
    #[error(
        "{file} is too long: size does not match a {width}x{height} {} image, which needs {expected} bytes of pixel data, found {found}{}",
        .format.label(),
        size_hint(*.format)
    )]
    TooLong {
        file: String,
        format: DepthFormat,
        width: usize,
        height: usize,
        expected: usize,
        found: usize,
    },
    #[error(
        "{file} has an odd byte count ({found}): Z16 stores 2 bytes per pixel, so a {width}x{height} image needs {expected} bytes"
    )]
    OddLength {
        file: String,
        width: usize,
        height: usize,
        expected: usize,
        found: usize,
    },
    #[error(
        "{file}: size {width}x{height} is too large for a {found}-byte {} file",
        .format.label()
    )]
    TooLarge {
        file: String,
        format: DepthFormat,
        width: usize,
        height: usize,
        found: usize,
    },
    #[error(
        "{file}: size mismatch: the {} image is {width}x{height} but {}",
        .format.label(),
        expect_text(*.expected_width, *.expected_height)
    )]
    SizeMismatch {
        file: String,
        format: DepthFormat,
        width: usize,
        height: usize,
        expected_width: Option<usize>,
        expected_height: Option<usize>,
    },
    #[error("{file} is {} {found} PNG; alfd needs a 16-bit greyscale PNG (Z16 units)", article(.found))]
    PngColor { file: String, found: String },
    #[error("{file} is not a readable PNG: {reason}")]
    Png { file: String, reason: String },
    #[error("{file} is a colour PFM (\"PF\"); only greyscale \"Pf\" PFM is supported")]
    PfmColour { file: String },
    #[error(
        "{file} has a bad PFM header: {reason}; expected \"Pf\", width, height and scale separated by whitespace, then one whitespace byte"
    )]
    PfmHeader { file: String, reason: String },
    #[error("{file}: {error}")]
    Image { file: String, error: DepthError },
    #[error("cannot encode {} depth: {reason}", .format.label())]
    Encode { format: DepthFormat, reason: String },
    #[error(
        "cannot write {file} as {format}: it needs {} depth but the image holds {}",
        needed_data(*.format),
        data_name(.data)
    )]
    WrongData {
        file: String,
        format: DepthFormat,
        data: &'static str,
    },
}

fn size_hint(format: DepthFormat) -> &'static str {
    match format {
        DepthFormat::Z16 => " (check --width/--height)",
        _ => "",
    }
}

fn expect_text(w: Option<usize>, h: Option<usize>) -> String {
    match (w, h) {
        (Some(w), Some(h)) => format!("--width/--height say {w}x{h}"),
        (Some(w), None) => format!("--width says {w}"),
        (None, Some(h)) => format!("--height says {h}"),
        (None, None) => "nothing was expected".to_string(),
    }
}

fn article(found: &str) -> &'static str {
    if found.starts_with('8') {
        "an"
    } else {
        "a"
    }
}

fn needed_data(format: DepthFormat) -> &'static str {
    match format {
        DepthFormat::Z16 | DepthFormat::Png16 => "Z16",
        DepthFormat::Pfm => "metre",
    }
}

fn data_name(data: &str) -> String {
    format!("{data} values")
}

/// Upper bound on the deflate expansion ratio (1032:1) with margin: a PNG cannot
/// decode to more than this many bytes per byte of file.
const PNG_MAX_EXPANSION: usize = 1100;

/// Longest PFM header token (width, height or scale) accepted, bytes.
const PFM_MAX_TOKEN: usize = 64;

/// One-line reason from an I/O error, without the "(os error N)" suffix.
fn io_reason(e: &io::Error) -> String {
    let s = e.to_string();
    let s = match s.rfind(" (os error ") {
        Some(i) if s.ends_with(')') => s[..i].to_string(),
        _ => s,
    };
    one_line(&s)
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

fn image_error(file: &str, error: DepthError) -> DepthFileError {
    DepthFileError::Image {
        file: file.to_string(),
        error,
    }
}

/// Reads a depth file. The format comes from `opts.format`, else the extension.
pub fn read_depth(path: &Path, opts: &ReadOptions) -> Result<DepthImage, DepthFileError> {
    let file = path.display().to_string();
    let format = opts
        .format
        .or_else(|| DepthFormat::from_path(path))
        .ok_or_else(|| DepthFileError::UnknownFormat { file: file.clone() })?;
    if format == DepthFormat::Z16 && (opts.width.is_none() || opts.height.is_none()) {
        return Err(DepthFileError::MissingSize { file });
    }
    let bytes = std::fs::read(path).map_err(|e| DepthFileError::Read {
        file: file.clone(),
        kind: e.kind(),
        reason: io_reason(&e),
    })?;
    decode_named(&file, format, &bytes, opts)
}

/// Decodes depth bytes already in memory (e.g. from stdin) as `format`.
/// Errors name the data as "Z16 data", "PNG data" or "PFM data".
pub fn decode_depth(
    bytes: &[u8],
    format: DepthFormat,
    opts: &ReadOptions,
) -> Result<DepthImage, DepthFileError> {
    decode_named(&bare_name(format), format, bytes, opts)
}

fn bare_name(format: DepthFormat) -> String {
    format!("{} data", format.label())
}

fn decode_named(
    file: &str,
    format: DepthFormat,
    bytes: &[u8],
    opts: &ReadOptions,
) -> Result<DepthImage, DepthFileError> {
    match format {
        DepthFormat::Z16 => match (opts.width, opts.height) {
            (Some(w), Some(h)) => z16_named(file, bytes, w, h, opts.scale_m),
            _ => Err(DepthFileError::MissingSize {
                file: file.to_string(),
            }),
        },
        DepthFormat::Png16 => png16_named(file, bytes, opts.scale_m, opts.width, opts.height),
        DepthFormat::Pfm => pfm_named(file, bytes, opts.width, opts.height),
    }
}

/// Decodes raw little-endian Z16 of exactly `width * height * 2` bytes.
pub fn decode_z16(
    bytes: &[u8],
    width: usize,
    height: usize,
    scale_m: f64,
) -> Result<DepthImage, DepthFileError> {
    z16_named(&bare_name(DepthFormat::Z16), bytes, width, height, scale_m)
}

fn z16_named(
    file: &str,
    bytes: &[u8],
    width: usize,
    height: usize,
    scale_m: f64,
) -> Result<DepthImage, DepthFileError> {
    let found = bytes.len();
    if width == 0 || height == 0 {
        return Err(image_error(file, DepthError::Empty { width, height }));
    }
    let expected = width
        .checked_mul(height)
        .and_then(|p| p.checked_mul(2))
        .ok_or_else(|| DepthFileError::TooLarge {
            file: file.to_string(),
            format: DepthFormat::Z16,
            width,
            height,
            found,
        })?;
    if found != expected {
        return Err(if found % 2 == 1 {
            DepthFileError::OddLength {
                file: file.to_string(),
                width,
                height,
                expected,
                found,
            }
        } else if found < expected {
            DepthFileError::Truncated {
                file: file.to_string(),
                format: DepthFormat::Z16,
                width,
                height,
                expected,
                found,
            }
        } else {
            DepthFileError::TooLong {
                file: file.to_string(),
                format: DepthFormat::Z16,
                width,
                height,
                expected,
                found,
            }
        });
    }
    let data = bytes
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    DepthImage::new(width, height, DepthData::Z16 { data, scale_m })
        .map_err(|e| image_error(file, e))
}

/// Decodes a 16-bit greyscale PNG holding Z16 values. `expect` (from
/// `--width/--height`) must match the PNG's own size when given.
pub fn decode_png16(
    bytes: &[u8],
    scale_m: f64,
    expect: Option<(usize, usize)>,
) -> Result<DepthImage, DepthFileError> {
    let (ew, eh) = split_expect(expect);
    png16_named(&bare_name(DepthFormat::Png16), bytes, scale_m, ew, eh)
}

fn split_expect(expect: Option<(usize, usize)>) -> (Option<usize>, Option<usize>) {
    match expect {
        Some((w, h)) => (Some(w), Some(h)),
        None => (None, None),
    }
}

fn check_expect(
    file: &str,
    format: DepthFormat,
    width: usize,
    height: usize,
    expected_width: Option<usize>,
    expected_height: Option<usize>,
) -> Result<(), DepthFileError> {
    let bad = |e: Option<usize>, v: usize| e.is_some_and(|e| e != v);
    if bad(expected_width, width) || bad(expected_height, height) {
        return Err(DepthFileError::SizeMismatch {
            file: file.to_string(),
            format,
            width,
            height,
            expected_width,
            expected_height,
        });
    }
    Ok(())
}

fn colour_name(c: png::ColorType) -> &'static str {
    match c {
        png::ColorType::Grayscale => "greyscale",
        png::ColorType::Rgb => "RGB",
        png::ColorType::Indexed => "palette (indexed colour)",
        png::ColorType::GrayscaleAlpha => "greyscale+alpha",
        png::ColorType::Rgba => "RGBA",
    }
}

fn png16_named(
    file: &str,
    bytes: &[u8],
    scale_m: f64,
    expected_width: Option<usize>,
    expected_height: Option<usize>,
) -> Result<DepthImage, DepthFileError> {
    let png_error = |e: png::DecodingError| DepthFileError::Png {
        file: file.to_string(),
        reason: one_line(&e.to_string()),
    };
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    // No transformation: 16-bit samples stay 16-bit, big-endian in the buffer.
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(png_error)?;
    let (width, height, colour, depth) = {
        let info = reader.info();
        (
            info.width as usize,
            info.height as usize,
            info.color_type,
            info.bit_depth,
        )
    };
    if colour != png::ColorType::Grayscale || depth != png::BitDepth::Sixteen {
        return Err(DepthFileError::PngColor {
            file: file.to_string(),
            found: format!("{}-bit {}", depth as u8, colour_name(colour)),
        });
    }
    check_expect(
        file,
        DepthFormat::Png16,
        width,
        height,
        expected_width,
        expected_height,
    )?;
    let too_large = || DepthFileError::TooLarge {
        file: file.to_string(),
        format: DepthFormat::Png16,
        width,
        height,
        found: bytes.len(),
    };
    let size = reader.output_buffer_size().ok_or_else(too_large)?;
    if size > bytes.len().saturating_mul(PNG_MAX_EXPANSION) {
        return Err(too_large());
    }
    let mut buf = vec![0u8; size];
    let out = reader.next_frame(&mut buf).map_err(png_error)?;
    let (out_w, out_h) = (out.width as usize, out.height as usize);
    if (out_w, out_h) != (width, height) {
        return Err(DepthFileError::Png {
            file: file.to_string(),
            reason: format!("its first frame is {out_w}x{out_h} but the image is {width}x{height}"),
        });
    }
    let pixels = width.checked_mul(height).ok_or_else(too_large)?;
    let raw = pixels
        .checked_mul(2)
        .and_then(|n| buf.get(..n))
        .ok_or_else(too_large)?;
    let data = raw
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    DepthImage::new(width, height, DepthData::Z16 { data, scale_m })
        .map_err(|e| image_error(file, e))
}

/// Decodes a greyscale PFM (`Pf`) into metres, flipping its bottom-to-top rows.
/// `expect` (from `--width/--height`) must match the header when given.
pub fn decode_pfm(
    bytes: &[u8],
    expect: Option<(usize, usize)>,
) -> Result<DepthImage, DepthFileError> {
    let (ew, eh) = split_expect(expect);
    pfm_named(&bare_name(DepthFormat::Pfm), bytes, ew, eh)
}

/// Skips at least one whitespace byte, then returns the next token (up to
/// [`PFM_MAX_TOKEN`] non-whitespace bytes).
fn pfm_token<'a>(bytes: &'a [u8], pos: &mut usize, what: &str) -> Result<&'a [u8], String> {
    let ws_start = *pos;
    while bytes.get(*pos).is_some_and(u8::is_ascii_whitespace) {
        *pos += 1;
    }
    if *pos == ws_start {
        return Err(if *pos >= bytes.len() {
            format!("it ends before the {what}")
        } else {
            format!("no whitespace before the {what}")
        });
    }
    let start = *pos;
    while bytes
        .get(*pos)
        .is_some_and(|b| !b.is_ascii_whitespace() && *pos - start < PFM_MAX_TOKEN)
    {
        *pos += 1;
    }
    let token = bytes.get(start..*pos).unwrap_or_default();
    if token.is_empty() {
        return Err(format!("it ends before the {what}"));
    }
    if bytes.get(*pos).is_some_and(|b| !b.is_ascii_whitespace()) {
        return Err(format!("the {what} is longer than {PFM_MAX_TOKEN} bytes"));
    }
    Ok(token)
}

fn printable(token: &[u8]) -> String {
    String::from_utf8_lossy(token).escape_debug().to_string()
}

fn pfm_dimension(token: &[u8], what: &str) -> Result<usize, String> {
    let text = std::str::from_utf8(token).unwrap_or("");
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return Err(format!(
            "the {what} \"{}\" is not a whole number",
            printable(token)
        ));
    }
    text.parse::<usize>()
        .map_err(|_| format!("the {what} {text} is too large"))
}

fn pfm_named(
    file: &str,
    bytes: &[u8],
    expected_width: Option<usize>,
    expected_height: Option<usize>,
) -> Result<DepthImage, DepthFileError> {
    let header = |reason: String| DepthFileError::PfmHeader {
        file: file.to_string(),
        reason,
    };
    match bytes.get(..2) {
        Some(b"Pf") => {}
        Some(b"PF") => {
            return Err(DepthFileError::PfmColour {
                file: file.to_string(),
            })
        }
        _ => {
            return Err(header(format!(
                "it starts with \"{}\", not \"Pf\"",
                printable(bytes.get(..2).unwrap_or(bytes))
            )))
        }
    }
    let mut pos = 2;
    let width = pfm_token(bytes, &mut pos, "width").and_then(|t| pfm_dimension(t, "width"));
    let width = width.map_err(header)?;
    let height = pfm_token(bytes, &mut pos, "height").and_then(|t| pfm_dimension(t, "height"));
    let height = height.map_err(header)?;
    let scale_token = pfm_token(bytes, &mut pos, "scale").map_err(header)?;
    let scale = std::str::from_utf8(scale_token)
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s != 0.0)
        .ok_or_else(|| {
            header(format!(
                "the scale \"{}\" is not a finite non-zero number (negative = little-endian, positive = big-endian)",
                printable(scale_token)
            ))
        })?;
    // Exactly one whitespace byte separates the header from the pixels.
    if !bytes.get(pos).is_some_and(u8::is_ascii_whitespace) {
        return Err(header(
            "it ends right after the scale, without the whitespace byte before the pixels"
                .to_string(),
        ));
    }
    let data_bytes = bytes.get(pos + 1..).unwrap_or_default();
    if width == 0 || height == 0 {
        return Err(image_error(file, DepthError::Empty { width, height }));
    }
    check_expect(
        file,
        DepthFormat::Pfm,
        width,
        height,
        expected_width,
        expected_height,
    )?;
    let found = data_bytes.len();
    let (row_bytes, expected) = match width
        .checked_mul(4)
        .and_then(|r| r.checked_mul(height).map(|n| (r, n)))
    {
        Some(v) => v,
        None => {
            return Err(DepthFileError::TooLarge {
                file: file.to_string(),
                format: DepthFormat::Pfm,
                width,
                height,
                found: bytes.len(),
            })
        }
    };
    if found != expected {
        let (file, format) = (file.to_string(), DepthFormat::Pfm);
        return Err(if found < expected {
            DepthFileError::Truncated {
                file,
                format,
                width,
                height,
                expected,
                found,
            }
        } else {
            DepthFileError::TooLong {
                file,
                format,
                width,
                height,
                expected,
                found,
            }
        });
    }
    let little = scale < 0.0;
    // Exactly `height` rows of `row_bytes` (> 0): stored bottom-to-top, so reverse.
    let data = data_bytes
        .chunks_exact(row_bytes)
        .rev()
        .flat_map(|row| row.chunks_exact(4))
        .map(|b| {
            let b = [b[0], b[1], b[2], b[3]];
            if little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            }
        })
        .collect();
    DepthImage::new(width, height, DepthData::Metres(data)).map_err(|e| image_error(file, e))
}

/// Raw little-endian Z16 bytes, no header.
pub fn encode_z16(data: &[u16]) -> Vec<u8> {
    data.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A 16-bit greyscale PNG of `width * height` Z16 values, row-major.
pub fn encode_png16(width: usize, height: usize, data: &[u16]) -> Result<Vec<u8>, DepthFileError> {
    let encode_error = |reason: String| DepthFileError::Encode {
        format: DepthFormat::Png16,
        reason,
    };
    if width == 0 || height == 0 {
        return Err(encode_error(format!(
            "image size {width}x{height} is empty; it needs at least 1x1 pixels"
        )));
    }
    if width.checked_mul(height) != Some(data.len()) {
        return Err(encode_error(format!(
            "a {width}x{height} image needs {width}x{height} values, got {}",
            data.len()
        )));
    }
    let (w, h) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) => (w, h),
        _ => {
            return Err(encode_error(format!(
                "image size {width}x{height} does not fit a PNG"
            )))
        }
    };
    let png_error = |e: png::EncodingError| encode_error(one_line(&e.to_string()));
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, w, h);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Sixteen);
    let mut writer = encoder.write_header().map_err(png_error)?;
    let samples: Vec<u8> = data.iter().flat_map(|v| v.to_be_bytes()).collect();
    writer.write_image_data(&samples).map_err(png_error)?;
    writer.finish().map_err(png_error)?;
    Ok(out)
}

/// A little-endian greyscale PFM of `width * height` metre values given
/// top-to-bottom (written bottom-to-top, as PFM stores them).
///
/// # Panics
/// If `data_m.len() != width * height` (a caller bug; it cannot be encoded).
pub fn encode_pfm(width: usize, height: usize, data_m: &[f32]) -> Vec<u8> {
    assert!(
        width.checked_mul(height) == Some(data_m.len()),
        "encode_pfm: a {width}x{height} image needs {width}x{height} values, got {}",
        data_m.len()
    );
    let mut out = format!("Pf\n{width} {height}\n-1.0\n").into_bytes();
    out.reserve(data_m.len() * 4);
    if width > 0 {
        for row in data_m.chunks_exact(width).rev() {
            out.extend(row.iter().flat_map(|v| v.to_le_bytes()));
        }
    }
    out
}

/// Writes `image` to `path` as `format`. Z16 images go to Z16 or PNG (the
/// scale is not stored: read them back with the same `scale_m`); metre images go to PFM.
pub fn write_depth(
    path: &Path,
    format: DepthFormat,
    image: &DepthImage,
) -> Result<(), DepthFileError> {
    let file = path.display().to_string();
    let (w, h) = (image.width(), image.height());
    let bytes = match (format, image.data()) {
        (DepthFormat::Z16, DepthData::Z16 { data, .. }) => encode_z16(data),
        (DepthFormat::Png16, DepthData::Z16 { data, .. }) => encode_png16(w, h, data)?,
        (DepthFormat::Pfm, DepthData::Metres(data)) => encode_pfm(w, h, data),
        (_, data) => {
            return Err(DepthFileError::WrongData {
                file,
                format,
                data: match data {
                    DepthData::Z16 { .. } => "Z16",
                    DepthData::Metres(_) => "metre",
                },
            })
        }
    };
    std::fs::write(path, bytes).map_err(|e| DepthFileError::Write {
        file,
        kind: e.kind(),
        reason: io_reason(&e),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn z16_of(img: &DepthImage) -> (&[u16], f64) {
        match img.data() {
            DepthData::Z16 { data, scale_m } => (data, *scale_m),
            other => panic!("expected Z16 data, got {other:?}"),
        }
    }

    fn metres_of(img: &DepthImage) -> &[f32] {
        match img.data() {
            DepthData::Metres(d) => d,
            other => panic!("expected metre data, got {other:?}"),
        }
    }

    /// The message is one line and contains every `needle`.
    fn assert_msg(err: &DepthFileError, needles: &[&str]) {
        let msg = err.to_string();
        assert!(!msg.contains('\n'), "multi-line message: {msg:?}");
        for n in needles {
            assert!(msg.contains(n), "{msg:?} does not contain {n:?}");
        }
    }

    fn write_tmp(dir: &tempfile::TempDir, name: &str, bytes: &[u8]) -> PathBuf {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    fn sized(w: usize, h: usize) -> ReadOptions {
        ReadOptions {
            width: Some(w),
            height: Some(h),
            ..ReadOptions::default()
        }
    }

    /// A PNG of any colour type and depth from raw (already packed) samples.
    fn png_raw(
        w: u32,
        h: u32,
        colour: png::ColorType,
        depth: png::BitDepth,
        samples: &[u8],
    ) -> Vec<u8> {
        let mut out = Vec::new();
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(colour);
        enc.set_depth(depth);
        if colour == png::ColorType::Indexed {
            enc.set_palette(vec![0u8, 0, 0, 255, 255, 255]);
        }
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(samples).unwrap();
        wr.finish().unwrap();
        out
    }

    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = 0xffff_ffffu32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xedb8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    // Asymmetric 3x2 images: every pixel distinct, rows and columns distinguishable.
    const Z16_3X2: [u16; 6] = [0, 1, 0x0102, 1000, 0xfffe, u16::MAX];

    #[test]
    fn read_options_default_scale_is_one_millimetre() {
        let o = ReadOptions::default();
        assert_eq!(o.scale_m, 0.001);
        assert_eq!((o.format, o.width, o.height), (None, None, None));
    }

    #[test]
    fn format_names_round_trip() {
        for f in DepthFormat::ALL {
            assert_eq!(DepthFormat::parse(f.as_str()), Some(f));
            assert_eq!(f.to_string(), f.as_str());
        }
        assert_eq!(DepthFormat::parse("z16"), Some(DepthFormat::Z16));
        assert_eq!(DepthFormat::parse("png16"), Some(DepthFormat::Png16));
        assert_eq!(DepthFormat::parse("pfm"), Some(DepthFormat::Pfm));
        assert_eq!(DepthFormat::parse("PFM"), Some(DepthFormat::Pfm));
        assert_eq!(DepthFormat::parse("png"), None);
        assert_eq!(DepthFormat::parse(""), None);
        assert_eq!(DepthFormat::parse("exr"), None);
    }

    #[test]
    fn format_from_extension() {
        let f = |p: &str| DepthFormat::from_path(Path::new(p));
        assert_eq!(f("a/depth.z16"), Some(DepthFormat::Z16));
        assert_eq!(f("depth.raw"), Some(DepthFormat::Z16));
        assert_eq!(f("depth.RAW"), Some(DepthFormat::Z16));
        assert_eq!(f("depth.Z16"), Some(DepthFormat::Z16));
        assert_eq!(f("depth.png"), Some(DepthFormat::Png16));
        assert_eq!(f("depth.PNG"), Some(DepthFormat::Png16));
        assert_eq!(f("depth.pfm"), Some(DepthFormat::Pfm));
        assert_eq!(f("depth.PfM"), Some(DepthFormat::Pfm));
        assert_eq!(f("depth"), None);
        assert_eq!(f("depth.bin"), None);
        assert_eq!(f(".png"), None); // a hidden file with no extension
        assert_eq!(f("depth.png.gz"), None);
    }

    #[test]
    fn z16_round_trip_through_file() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode_z16(&Z16_3X2);
        assert_eq!(bytes.len(), 12);
        assert_eq!(&bytes[4..6], &[0x02, 0x01], "little-endian");
        for name in ["d.z16", "d.raw"] {
            let path = write_tmp(&dir, name, &bytes);
            let opts = ReadOptions {
                scale_m: 0.00025,
                ..sized(3, 2)
            };
            let img = read_depth(&path, &opts).unwrap();
            assert_eq!((img.width(), img.height()), (3, 2));
            assert_eq!(z16_of(&img), (&Z16_3X2[..], 0.00025));
        }
        // Explicit format overrides an unknown extension.
        let path = write_tmp(&dir, "d.bin", &bytes);
        let opts = ReadOptions {
            format: Some(DepthFormat::Z16),
            ..sized(2, 3)
        };
        let img = read_depth(&path, &opts).unwrap();
        assert_eq!((img.width(), img.height()), (2, 3));
        assert_eq!(z16_of(&img).0, &Z16_3X2[..]);
    }

    #[test]
    fn z16_one_by_one() {
        let img = decode_z16(&encode_z16(&[4242]), 1, 1, 0.001).unwrap();
        assert_eq!((img.width(), img.height()), (1, 1));
        assert_eq!(z16_of(&img).0, &[4242]);
    }

    #[test]
    fn z16_needs_width_and_height() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_tmp(&dir, "d.z16", &[0; 4]);
        for opts in [
            ReadOptions::default(),
            ReadOptions {
                width: Some(2),
                ..ReadOptions::default()
            },
            ReadOptions {
                height: Some(1),
                ..ReadOptions::default()
            },
        ] {
            let e = read_depth(&path, &opts).unwrap_err();
            assert!(matches!(e, DepthFileError::MissingSize { .. }), "{e:?}");
            assert_msg(&e, &["d.z16", "--width/--height", "no header"]);
        }
        let e = decode_depth(&[0; 4], DepthFormat::Z16, &ReadOptions::default()).unwrap_err();
        assert!(matches!(e, DepthFileError::MissingSize { .. }), "{e:?}");
    }

    #[test]
    fn z16_truncated() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_tmp(&dir, "short.z16", &[0; 10]);
        let e = read_depth(&path, &sized(3, 2)).unwrap_err();
        assert_eq!(
            e,
            DepthFileError::Truncated {
                file: path.display().to_string(),
                format: DepthFormat::Z16,
                width: 3,
                height: 2,
                expected: 12,
                found: 10
            }
        );
        assert_msg(
            &e,
            &["short.z16", "truncated", "3x2", "12 bytes", "found 10"],
        );
        let e = decode_z16(&[], 3, 2, 0.001).unwrap_err();
        assert!(
            matches!(e, DepthFileError::Truncated { found: 0, .. }),
            "{e:?}"
        );
        assert_msg(&e, &["Z16 data", "truncated"]);
    }

    #[test]
    fn z16_too_long() {
        let e = decode_z16(&[0; 14], 3, 2, 0.001).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::TooLong {
                    expected: 12,
                    found: 14,
                    ..
                }
            ),
            "{e:?}"
        );
        assert_msg(
            &e,
            &[
                "too long",
                "size does not match",
                "3x2",
                "12",
                "14",
                "--width/--height",
            ],
        );
    }

    #[test]
    fn z16_odd_byte_count() {
        for len in [11, 13, 1] {
            let e = decode_z16(&vec![0; len], 3, 2, 0.001).unwrap_err();
            assert!(matches!(e, DepthFileError::OddLength { .. }), "{e:?}");
            assert_msg(&e, &["odd byte count", &format!("({len})"), "12 bytes"]);
        }
    }

    #[test]
    fn z16_bad_sizes_and_scale() {
        let e = decode_z16(&[], 0, 5, 0.001).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::Image {
                    error: DepthError::Empty { .. },
                    ..
                }
            ),
            "{e:?}"
        );
        assert_msg(&e, &["empty", "0x5"]);
        let e = decode_z16(&[0; 4], usize::MAX, 2, 0.001).unwrap_err();
        assert!(matches!(e, DepthFileError::TooLarge { .. }), "{e:?}");
        assert_msg(&e, &["too large", "4-byte"]);
        let e = decode_z16(&[0; 4], 2, 1, -1.0).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::Image {
                    error: DepthError::BadScale(_),
                    ..
                }
            ),
            "{e:?}"
        );
        assert_msg(&e, &["Z16 data", "scale"]);
    }

    #[test]
    fn png16_round_trip_through_file() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode_png16(3, 2, &Z16_3X2).unwrap();
        for name in ["d.png", "D.PNG"] {
            let path = write_tmp(&dir, name, &bytes);
            let img = read_depth(&path, &ReadOptions::default()).unwrap();
            assert_eq!((img.width(), img.height()), (3, 2));
            assert_eq!(z16_of(&img), (&Z16_3X2[..], 0.001));
            // Matching --width/--height are accepted.
            let img = read_depth(&path, &sized(3, 2)).unwrap();
            assert_eq!(z16_of(&img).0, &Z16_3X2[..]);
        }
    }

    #[test]
    fn png16_samples_are_big_endian() {
        // Written by the png crate directly, not by our encoder.
        let bytes = png_raw(
            2,
            1,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &[0x01, 0x02, 0xff, 0x00],
        );
        let img = decode_png16(&bytes, 0.002, None).unwrap();
        assert_eq!(z16_of(&img), (&[0x0102, 0xff00][..], 0.002));
    }

    #[test]
    fn png16_one_by_one() {
        let img = decode_png16(&encode_png16(1, 1, &[7]).unwrap(), 0.001, Some((1, 1))).unwrap();
        assert_eq!((img.width(), img.height()), (1, 1));
        assert_eq!(z16_of(&img).0, &[7]);
    }

    #[test]
    fn png_wrong_colour_types() {
        use png::{BitDepth as B, ColorType as C};
        let dir = tempfile::tempdir().unwrap();
        let cases: [(C, B, &[u8], &str); 6] = [
            (C::Rgb, B::Eight, &[1, 2, 3], "is an 8-bit RGB PNG"),
            (C::Grayscale, B::Eight, &[1], "is an 8-bit greyscale PNG"),
            (
                C::Indexed,
                B::Eight,
                &[1],
                "is an 8-bit palette (indexed colour) PNG",
            ),
            (
                C::GrayscaleAlpha,
                B::Sixteen,
                &[0, 1, 0, 2],
                "is a 16-bit greyscale+alpha PNG",
            ),
            (C::Rgba, B::Sixteen, &[0; 8], "is a 16-bit RGBA PNG"),
            (C::Grayscale, B::One, &[0x80], "is a 1-bit greyscale PNG"),
        ];
        for (colour, depth, samples, found) in cases {
            let path = write_tmp(&dir, "depth.png", &png_raw(1, 1, colour, depth, samples));
            let e = read_depth(&path, &ReadOptions::default()).unwrap_err();
            assert!(matches!(e, DepthFileError::PngColor { .. }), "{e:?}");
            assert_msg(
                &e,
                &[
                    &format!("depth.png {found}"),
                    "; alfd needs a 16-bit greyscale PNG (Z16 units)",
                ],
            );
        }
        let e =
            decode_png16(&png_raw(1, 1, C::Rgb, B::Eight, &[1, 2, 3]), 0.001, None).unwrap_err();
        assert_eq!(
            e.to_string(),
            "PNG data is an 8-bit RGB PNG; alfd needs a 16-bit greyscale PNG (Z16 units)"
        );
    }

    #[test]
    fn png16_size_mismatch() {
        let bytes = encode_png16(3, 2, &Z16_3X2).unwrap();
        let e = decode_png16(&bytes, 0.001, Some((2, 3))).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::SizeMismatch {
                    width: 3,
                    height: 2,
                    expected_width: Some(2),
                    expected_height: Some(3),
                    ..
                }
            ),
            "{e:?}"
        );
        assert_msg(&e, &["size mismatch", "3x2", "--width/--height say 2x3"]);
        // Only one of --width/--height given: that one is still checked.
        let dir = tempfile::tempdir().unwrap();
        let path = write_tmp(&dir, "d.png", &bytes);
        let opts = ReadOptions {
            height: Some(5),
            ..ReadOptions::default()
        };
        let e = read_depth(&path, &opts).unwrap_err();
        assert!(matches!(e, DepthFileError::SizeMismatch { .. }), "{e:?}");
        assert_msg(&e, &["d.png", "size mismatch", "--height says 5"]);
        let opts = ReadOptions {
            width: Some(3),
            ..ReadOptions::default()
        };
        assert!(read_depth(&path, &opts).is_ok());
    }

    #[test]
    fn png_corrupt_or_not_png() {
        let e = decode_png16(b"Pf\n1 1\n-1\n\0\0\0\0", 0.001, None).unwrap_err();
        assert!(matches!(e, DepthFileError::Png { .. }), "{e:?}");
        assert_msg(&e, &["PNG data is not a readable PNG"]);
        let bytes = encode_png16(3, 2, &Z16_3X2).unwrap();
        let e = decode_png16(&bytes[..bytes.len() - 20], 0.001, None).unwrap_err();
        assert!(matches!(e, DepthFileError::Png { .. }), "{e:?}");
        assert_msg(&e, &["not a readable PNG"]);
        let e = decode_png16(&[], 0.001, None).unwrap_err();
        assert!(matches!(e, DepthFileError::Png { .. }), "{e:?}");
    }

    #[test]
    fn png_header_claiming_a_huge_image_is_refused_before_allocating() {
        let mut bytes = encode_png16(1, 1, &[0]).unwrap();
        assert_eq!(&bytes[12..16], b"IHDR");
        bytes[16..20].copy_from_slice(&1_000_000u32.to_be_bytes());
        bytes[20..24].copy_from_slice(&1_000_000u32.to_be_bytes());
        let crc = crc32(&bytes[12..29]);
        bytes[29..33].copy_from_slice(&crc.to_be_bytes());
        let e = decode_png16(&bytes, 0.001, None).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::TooLarge {
                    width: 1_000_000,
                    height: 1_000_000,
                    ..
                }
            ),
            "{e:?}"
        );
        assert_msg(&e, &["too large", "1000000x1000000"]);
    }

    #[test]
    fn png16_rejects_bad_encode_arguments() {
        for (w, h, n) in [(0, 1, 0), (3, 2, 5), (2, 0, 0), (usize::MAX, 2, 1)] {
            let e = encode_png16(w, h, &vec![0; n]).unwrap_err();
            assert!(matches!(e, DepthFileError::Encode { .. }), "{e:?}");
            assert_msg(&e, &["cannot encode PNG depth"]);
        }
    }

    const METRES_3X2: [f32; 6] = [1.0, 2.5, f32::INFINITY, f32::NAN, -1.0, 0.0];

    fn assert_metres_eq(got: &[f32], want: &[f32]) {
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(want) {
            assert_eq!(g.to_bits(), w.to_bits(), "got {got:?}, want {want:?}");
        }
    }

    #[test]
    fn pfm_round_trip_through_file() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode_pfm(3, 2, &METRES_3X2);
        for name in ["d.pfm", "d.PFM"] {
            let path = write_tmp(&dir, name, &bytes);
            let img = read_depth(&path, &ReadOptions::default()).unwrap();
            assert_eq!((img.width(), img.height()), (3, 2));
            let m = metres_of(&img);
            assert_metres_eq(m, &METRES_3X2);
            assert!(m[2].is_infinite() && m[3].is_nan());
            assert!(read_depth(&path, &sized(3, 2)).is_ok());
        }
    }

    #[test]
    fn pfm_rows_are_stored_bottom_to_top() {
        let bytes = encode_pfm(3, 2, &METRES_3X2);
        let header = b"Pf\n3 2\n-1.0\n";
        assert_eq!(&bytes[..header.len()], header);
        let stored: Vec<f32> = bytes[header.len()..]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        // File order: bottom row first.
        assert_metres_eq(&stored, &[f32::NAN, -1.0, 0.0, 1.0, 2.5, f32::INFINITY]);

        // A hand-made big-endian file (positive scale), 2 wide and 3 high, other whitespace.
        let mut be = b"Pf \t2\r\n3   0.5\n".to_vec();
        for v in [5.0f32, 6.0, 3.0, 4.0, 1.0, 2.0] {
            be.extend(v.to_be_bytes());
        }
        let img = decode_pfm(&be, Some((2, 3))).unwrap();
        assert_eq!((img.width(), img.height()), (2, 3));
        assert_metres_eq(metres_of(&img), &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    }

    #[test]
    fn pfm_one_by_one() {
        for v in [0.75f32, f32::INFINITY] {
            let img = decode_pfm(&encode_pfm(1, 1, &[v]), None).unwrap();
            assert_eq!((img.width(), img.height()), (1, 1));
            assert_metres_eq(metres_of(&img), &[v]);
        }
        // The single whitespace byte may itself look like part of the data.
        let mut b = b"Pf\n1 1\n-1\n".to_vec();
        b.extend(f32::from_le_bytes([b' ', b' ', b'\n', b'A']).to_le_bytes());
        let img = decode_pfm(&b, None).unwrap();
        assert_eq!(metres_of(&img)[0].to_le_bytes(), [b' ', b' ', b'\n', b'A']);
    }

    #[test]
    fn pfm_colour_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = b"PF\n1 1\n-1.0\n".to_vec();
        bytes.extend([0u8; 12]);
        let path = write_tmp(&dir, "rgb.pfm", &bytes);
        let e = read_depth(&path, &ReadOptions::default()).unwrap_err();
        assert!(matches!(e, DepthFileError::PfmColour { .. }), "{e:?}");
        assert_msg(&e, &["rgb.pfm", "colour", "only greyscale \"Pf\""]);
    }

    #[test]
    fn pfm_bad_headers() {
        let cases: [(&[u8], &str); 13] = [
            (b"", "starts with \"\""),
            (b"P", "starts with \"P\""),
            (b"P5\n1 1\n255\n\0", "not \"Pf\""),
            (b"Pf", "ends before the width"),
            (b"Pf1 1\n-1\n\0\0\0\0", "no whitespace before the width"),
            (b"Pf\nx 1\n-1\n\0\0\0\0", "width \"x\" is not a whole number"),
            (b"Pf\n-1 1\n-1\n\0\0\0\0", "width \"-1\" is not a whole number"),
            (b"Pf\n1\n", "ends before the height"),
            (b"Pf\n1 1.5\n-1\n\0\0\0\0", "height \"1.5\" is not a whole number"),
            (b"Pf\n1 1\n0\n\0\0\0\0", "scale \"0\" is not a finite non-zero number"),
            (b"Pf\n1 1\nnan\n\0\0\0\0", "scale \"nan\""),
            (b"Pf\n1 1\n-1", "without the whitespace byte"),
            (b"Pf\n1 1\n-1.00000000000000000000000000000000000000000000000000000000000000000000\n", "longer than 64 bytes"),
        ];
        for (bytes, reason) in cases {
            let e = decode_pfm(bytes, None).unwrap_err();
            assert!(
                matches!(e, DepthFileError::PfmHeader { .. }),
                "{bytes:?}: {e:?}"
            );
            assert_msg(
                &e,
                &["PFM data has a bad PFM header", reason, "expected \"Pf\""],
            );
        }
        let e = decode_pfm(b"Pf\n99999999999999999999999 1\n-1\n", None).unwrap_err();
        assert!(matches!(e, DepthFileError::PfmHeader { .. }), "{e:?}");
        assert_msg(&e, &["width 99999999999999999999999 is too large"]);
    }

    #[test]
    fn pfm_zero_size() {
        for (w, h) in [(0, 1), (1, 0), (0, 0)] {
            let e = decode_pfm(format!("Pf\n{w} {h}\n-1\n").as_bytes(), None).unwrap_err();
            assert!(
                matches!(
                    e,
                    DepthFileError::Image {
                        error: DepthError::Empty { .. },
                        ..
                    }
                ),
                "{e:?}"
            );
            assert_msg(&e, &["empty", &format!("{w}x{h}")]);
        }
    }

    #[test]
    fn pfm_absurd_sizes_do_not_allocate() {
        // width*height*4 overflows.
        let max = usize::MAX;
        let e = decode_pfm(format!("Pf\n{max} 2\n-1\n\0\0\0\0").as_bytes(), None).unwrap_err();
        assert!(matches!(e, DepthFileError::TooLarge { .. }), "{e:?}");
        assert_msg(&e, &["too large", "PFM file"]);
        // Representable but far more than the file holds: truncated, nothing allocated.
        let e = decode_pfm(b"Pf\n4000000000 4000000\n-1\n\0\0\0\0", None).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::Truncated {
                    found: 4,
                    width: 4_000_000_000,
                    ..
                }
            ),
            "{e:?}"
        );
    }

    #[test]
    fn pfm_truncated_and_too_long() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode_pfm(3, 2, &METRES_3X2);
        let path = write_tmp(&dir, "cut.pfm", &bytes[..bytes.len() - 3]);
        let e = read_depth(&path, &ReadOptions::default()).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::Truncated {
                    format: DepthFormat::Pfm,
                    expected: 24,
                    found: 21,
                    ..
                }
            ),
            "{e:?}"
        );
        assert_msg(
            &e,
            &["cut.pfm is truncated", "3x2 PFM", "24 bytes", "found 21"],
        );

        let mut long = bytes.clone();
        long.push(b'\n');
        let e = decode_pfm(&long, None).unwrap_err();
        assert!(
            matches!(e, DepthFileError::TooLong { found: 25, .. }),
            "{e:?}"
        );
        assert_msg(&e, &["too long", "size does not match", "24 bytes"]);
    }

    #[test]
    fn pfm_size_mismatch() {
        let bytes = encode_pfm(3, 2, &METRES_3X2);
        let e = decode_pfm(&bytes, Some((3, 3))).unwrap_err();
        assert!(matches!(e, DepthFileError::SizeMismatch { .. }), "{e:?}");
        assert_msg(&e, &["size mismatch", "PFM image is 3x2", "say 3x3"]);
    }

    #[test]
    fn read_missing_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nope.png");
        let e = read_depth(&path, &ReadOptions::default()).unwrap_err();
        assert!(
            matches!(
                e,
                DepthFileError::Read {
                    kind: io::ErrorKind::NotFound,
                    ..
                }
            ),
            "{e:?}"
        );
        if cfg!(unix) {
            assert_eq!(
                e.to_string(),
                format!("cannot read {}: No such file or directory", path.display())
            );
        }
    }

    #[test]
    fn read_unknown_extension_asks_for_format() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_tmp(&dir, "depth.bin", &encode_pfm(1, 1, &[1.0]));
        let e = read_depth(&path, &ReadOptions::default()).unwrap_err();
        assert!(matches!(e, DepthFileError::UnknownFormat { .. }), "{e:?}");
        assert_msg(&e, &["depth.bin", "--format"]);
        let opts = ReadOptions {
            format: Some(DepthFormat::Pfm),
            ..ReadOptions::default()
        };
        assert_metres_eq(metres_of(&read_depth(&path, &opts).unwrap()), &[1.0]);
        // An explicit format wins over the extension.
        let path = write_tmp(&dir, "depth.png", &encode_pfm(1, 1, &[1.0]));
        assert!(read_depth(&path, &opts).is_ok());
    }

    #[test]
    fn write_depth_round_trips_and_refuses_wrong_data() {
        let dir = tempfile::tempdir().unwrap();
        let z = DepthImage::new(
            3,
            2,
            DepthData::Z16 {
                data: Z16_3X2.to_vec(),
                scale_m: 0.001,
            },
        )
        .unwrap();
        let m = DepthImage::new(3, 2, DepthData::Metres(METRES_3X2.to_vec())).unwrap();
        for (name, format, img) in [
            ("a.z16", DepthFormat::Z16, &z),
            ("a.png", DepthFormat::Png16, &z),
            ("a.pfm", DepthFormat::Pfm, &m),
        ] {
            let path = dir.path().join(name);
            write_depth(&path, format, img).unwrap();
            let back = read_depth(&path, &sized(3, 2)).unwrap();
            match (img.data(), back.data()) {
                (DepthData::Metres(a), DepthData::Metres(b)) => assert_metres_eq(b, a),
                (a, b) => assert_eq!(a, b),
            }
        }
        let e = write_depth(&dir.path().join("b.pfm"), DepthFormat::Pfm, &z).unwrap_err();
        assert!(matches!(e, DepthFileError::WrongData { .. }), "{e:?}");
        assert_msg(&e, &["b.pfm", "needs metre depth", "holds Z16 values"]);
        let e = write_depth(&dir.path().join("b.png"), DepthFormat::Png16, &m).unwrap_err();
        assert_msg(&e, &["needs Z16 depth", "holds metre values"]);
        let e = write_depth(&dir.path().join("no/such/dir.z16"), DepthFormat::Z16, &z).unwrap_err();
        assert!(matches!(e, DepthFileError::Write { .. }), "{e:?}");
        assert_msg(&e, &["cannot write", "dir.z16"]);
    }

    /// Every prefix and many single-byte corruptions of valid files decode to
    /// an image or a one-line error, never a panic.
    #[test]
    fn corrupt_inputs_never_panic() {
        let png = encode_png16(3, 2, &Z16_3X2).unwrap();
        let pfm = encode_pfm(3, 2, &METRES_3X2);
        let z16 = encode_z16(&Z16_3X2);
        let opts = ReadOptions {
            width: Some(3),
            height: Some(2),
            ..ReadOptions::default()
        };
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for (format, good) in [
            (DepthFormat::Png16, &png),
            (DepthFormat::Pfm, &pfm),
            (DepthFormat::Z16, &z16),
        ] {
            let mut inputs: Vec<Vec<u8>> = (0..good.len()).map(|n| good[..n].to_vec()).collect();
            for _ in 0..300 {
                let mut b = good.clone();
                let i = (next() as usize) % b.len();
                b[i] = next() as u8;
                inputs.push(b);
            }
            for b in &inputs {
                for o in [opts, ReadOptions::default()] {
                    if let Err(e) = decode_depth(b, format, &o) {
                        assert!(!e.to_string().contains('\n'), "{e}");
                    }
                }
            }
        }
    }
}
