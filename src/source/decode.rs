//! Decoding of raw V4L2 buffers, outside the device code so it is tested on
//! recorded buffers on machines without a camera: YUYV 4:2:2, MJPEG (including
//! UVC frames that omit their Huffman tables) and Z16 depth.

use super::ColorImage;
use crate::core::DepthImage;
use crate::depthio::{decode_z16, DepthFileError};
use thiserror::Error;

#[derive(Debug, Error, PartialEq)]
pub enum DecodeError {
    #[error("YUYV {width}x{height} needs {expected} bytes, the buffer has {found}")]
    YuyvSize {
        width: usize,
        height: usize,
        expected: usize,
        found: usize,
    },
    #[error("YUYV width must be even, got {0}")]
    YuyvOddWidth(usize),
    #[error("MJPEG frame does not decode: {0}")]
    Mjpeg(String),
    #[error("Z16 frame: {0}")]
    Z16(String),
}

/// YUYV (YUY2) 4:2:2 to RGB8, BT.601 limited range as UVC cameras send it.
pub fn yuyv_to_rgb(width: usize, height: usize, buf: &[u8]) -> Result<ColorImage, DecodeError> {
    if width % 2 != 0 {
        return Err(DecodeError::YuyvOddWidth(width));
    }
    // Sizes come from the driver: an overflowing product is a size no buffer has.
    let expected = width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(2))
        .unwrap_or(usize::MAX);
    // Drivers may pad the buffer (bytesused > image); never read less.
    if buf.len() < expected || expected == usize::MAX {
        return Err(DecodeError::YuyvSize {
            width,
            height,
            expected,
            found: buf.len(),
        });
    }
    let mut rgb = Vec::with_capacity(width * height * 3);
    for px in buf[..expected].chunks_exact(4) {
        let (y0, u, y1, v) = (px[0], px[1], px[2], px[3]);
        for y in [y0, y1] {
            rgb.extend_from_slice(&ycbcr_to_rgb(y, u, v));
        }
    }
    Ok(ColorImage { width, height, rgb })
}

fn ycbcr_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = (y as f32 - 16.0) * 1.164;
    let d = u as f32 - 128.0;
    let e = v as f32 - 128.0;
    let clamp = |x: f32| x.round().clamp(0.0, 255.0) as u8;
    [
        clamp(c + 1.596 * e),
        clamp(c - 0.392 * d - 0.813 * e),
        clamp(c + 2.017 * d),
    ]
}

/// Largest frame decoded: 8K UHD.
const MJPEG_MAX_PIXELS: usize = 7680 * 4320;
/// Pixels per compressed byte beyond which a frame's header is not believed
/// (a flat 8×8 block costs a few bits; real frames stay far below this).
const MJPEG_MAX_EXPANSION: usize = 2000;
/// Bytes a PNG may expand to per compressed byte before its header is not
/// believed (deflate's limit is about 1032).
const PNG_MAX_EXPANSION: usize = 1100;

/// An MJPEG frame to RGB8. UVC cameras drop the Huffman tables from each
/// frame; the decoder then uses the standard tables (JPEG Annex K), as the UVC
/// MJPEG payload specification says.
pub fn mjpeg_to_rgb(buf: &[u8]) -> Result<ColorImage, DecodeError> {
    // The decoder fills in the standard tables only for frames that say they
    // are AVI1 MJPEG; many UVC cameras omit that marker too, so add it.
    let patched;
    let buf = if buf.len() >= 2 && buf[..2] == [0xFF, 0xD8] && !has_huffman_tables(buf) {
        patched = [
            &buf[..2],
            &[0xFF, 0xE0, 0x00, 0x07, b'A', b'V', b'I', b'1', 0x00][..],
            &buf[2..],
        ]
        .concat();
        &patched[..]
    } else {
        buf
    };
    let mut dec = jpeg_decoder::Decoder::new(buf);
    // The header's size decides the allocation: a corrupted frame claiming
    // 24600×60927 px made the decoder allocate 1.5 GB (found by fuzzing).
    // A frame is refused when it claims more than MJPEG_MAX_PIXELS or more
    // pixels than its compressed bytes could plausibly carry.
    dec.read_info()
        .map_err(|e| DecodeError::Mjpeg(e.to_string()))?;
    if let Some(info) = dec.info() {
        let pixels = info.width as usize * info.height as usize;
        if pixels > MJPEG_MAX_PIXELS || pixels > buf.len().saturating_mul(MJPEG_MAX_EXPANSION) {
            return Err(DecodeError::Mjpeg(format!(
                "header claims {}x{} px from {} bytes",
                info.width,
                info.height,
                buf.len()
            )));
        }
    }
    let pixels = dec
        .decode()
        .map_err(|e| DecodeError::Mjpeg(e.to_string()))?;
    let info = dec
        .info()
        .ok_or_else(|| DecodeError::Mjpeg("no frame header".into()))?;
    let (width, height) = (info.width as usize, info.height as usize);
    let rgb = match info.pixel_format {
        jpeg_decoder::PixelFormat::RGB24 => pixels,
        jpeg_decoder::PixelFormat::L8 => pixels.iter().flat_map(|&l| [l, l, l]).collect(),
        other => {
            return Err(DecodeError::Mjpeg(format!(
                "unsupported pixel format {other:?}"
            )))
        }
    };
    if rgb.len() != width * height * 3 {
        return Err(DecodeError::Mjpeg(format!(
            "{width}x{height} frame decoded to {} bytes",
            rgb.len()
        )));
    }
    Ok(ColorImage { width, height, rgb })
}

/// Whether a DHT segment comes before the first scan (walking the marker
/// segments from SOI; a malformed walk answers true and leaves it to the decoder).
fn has_huffman_tables(jpeg: &[u8]) -> bool {
    for segment in crate::capture::jpeg::segments(jpeg) {
        match segment.map(|s| s.marker) {
            Ok(0xC4) | Err(_) => return true,
            Ok(0xDA) => return false,
            Ok(_) => {}
        }
    }
    true
}

/// A Z16 buffer (little-endian u16, `scale_m` metres per unit). Padding beyond
/// the image (`bytesused` larger than `width·height·2`) is ignored.
pub fn z16_to_depth(
    width: usize,
    height: usize,
    buf: &[u8],
    scale_m: f64,
) -> Result<DepthImage, DecodeError> {
    let n = width.checked_mul(height).and_then(|p| p.checked_mul(2));
    let bytes = match n {
        Some(n) if buf.len() >= n => &buf[..n],
        _ => buf,
    };
    decode_z16(bytes, width, height, scale_m)
        .map_err(|e: DepthFileError| DecodeError::Z16(e.to_string()))
}

/// A PNG (RGB, RGBA or grey, 8 or 16 bit) into RGB8.
pub fn png_to_rgb(bytes: &[u8]) -> Result<ColorImage, String> {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec.read_info().map_err(|e| e.to_string())?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| "image too large".to_string())?;
    // The header decides the allocation: no more than the data can inflate to.
    if size > bytes.len().saturating_mul(PNG_MAX_EXPANSION) {
        return Err(format!(
            "header claims {size} bytes of pixels from a {}-byte file",
            bytes.len()
        ));
    }
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    let (w, h) = (info.width as usize, info.height as usize);
    let rgb = match info.color_type {
        png::ColorType::Rgb => buf[..w * h * 3].to_vec(),
        png::ColorType::Rgba => buf[..w * h * 4]
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        png::ColorType::Grayscale => buf[..w * h].iter().flat_map(|&l| [l, l, l]).collect(),
        other => return Err(format!("unsupported PNG colour type {other:?}")),
    };
    Ok(ColorImage {
        width: w,
        height: h,
        rgb,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_known_values() {
        // Y=16,U=V=128 is black; Y=235 white; Y=81,U=90,V=240 is (limited) red.
        let buf = [16, 128, 235, 128, 81, 90, 81, 240];
        let img = yuyv_to_rgb(4, 1, &buf).unwrap();
        assert_eq!(&img.rgb[0..3], &[0, 0, 0]);
        assert_eq!(&img.rgb[3..6], &[255, 255, 255]);
        let red = &img.rgb[6..9];
        assert!(red[0] > 240 && red[1] < 10 && red[2] < 10, "{red:?}");
        assert_eq!(
            yuyv_to_rgb(4, 2, &buf),
            Err(DecodeError::YuyvSize {
                width: 4,
                height: 2,
                expected: 16,
                found: 8
            })
        );
        assert_eq!(yuyv_to_rgb(3, 1, &buf), Err(DecodeError::YuyvOddWidth(3)));
    }

    #[test]
    fn z16_ignores_driver_padding_and_rejects_short_buffers() {
        let mut buf = vec![0u8; 2 * 4 * 2 + 16];
        buf[0..2].copy_from_slice(&1234u16.to_le_bytes());
        let d = z16_to_depth(4, 2, &buf, 0.001).unwrap();
        assert_eq!(d.width(), 4);
        assert!(matches!(
            z16_to_depth(4, 2, &buf[..10], 0.001),
            Err(DecodeError::Z16(_))
        ));
    }

    /// Removes every DHT (define Huffman table) segment, as UVC cameras send MJPEG.
    fn strip_huffman_tables(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut i = 2;
        while i + 4 <= jpeg.len() && jpeg[i] == 0xFF {
            let marker = jpeg[i + 1];
            if marker == 0xDA {
                break; // start of scan: entropy-coded data follows
            }
            let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
            if marker != 0xC4 {
                out.extend_from_slice(&jpeg[i..i + 2 + len]);
            }
            i += 2 + len;
        }
        out.extend_from_slice(&jpeg[i..]);
        out
    }

    #[test]
    fn mjpeg_without_huffman_tables_decodes_like_the_full_jpeg() {
        let (w, h) = (64u16, 48u16);
        let rgb: Vec<u8> = (0..w as usize * h as usize)
            .flat_map(|k| {
                let (x, y) = (k % w as usize, k / w as usize);
                [(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8]
            })
            .collect();
        let mut full = Vec::new();
        jpeg_encoder::Encoder::new(&mut full, 90)
            .encode(&rgb, w, h, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        let stripped = strip_huffman_tables(&full);
        assert!(
            stripped.len() < full.len(),
            "the encoder wrote no DHT to strip"
        );
        assert!(!stripped.windows(2).any(|m| m == [0xFF, 0xC4]));
        let a = mjpeg_to_rgb(&full).unwrap();
        let b = mjpeg_to_rgb(&stripped).unwrap();
        assert_eq!((b.width, b.height), (64, 48));
        // The standard tables are the ones the encoder used: identical pixels.
        assert_eq!(a.rgb, b.rgb);
        // And close to the source image (quality 90 on a smooth ramp).
        let mse: f64 = a
            .rgb
            .iter()
            .zip(&rgb)
            .map(|(&p, &q)| (p as f64 - q as f64).powi(2))
            .sum::<f64>()
            / rgb.len() as f64;
        assert!(mse < 10.0, "mse {mse}");
    }

    #[test]
    fn garbage_mjpeg_is_an_error_not_a_panic() {
        assert!(mjpeg_to_rgb(&[0xFF, 0xD8, 0xFF, 0x00, 1, 2, 3]).is_err());
        assert!(mjpeg_to_rgb(&[]).is_err());
    }
}
