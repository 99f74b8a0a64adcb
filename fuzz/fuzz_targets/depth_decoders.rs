//! Depth files and raw camera buffers: the depth file decoders (`alfd::depthio`: Z16, 16-bit
//! PNG, PFM) and the V4L2 buffer decoders (`alfd::source::decode`: Z16, YUYV). Every decoder
//! must answer any bytes with an image or a typed error; a decoded image must hold exactly
//! width × height values and survive a round trip through the matching encoder.
//!
//! Input: byte 0 picks the decoder (and its options), bytes 1..5 are width and height
//! (little-endian u16 each) where the decoder takes them from the caller, the rest is the buffer.
#![no_main]

use alfd::core::{DepthData, DepthImage};
use alfd::depthio::{
    decode_depth, decode_pfm, decode_png16, decode_z16, encode_pfm, encode_png16, encode_z16,
    DepthFileError, DepthFormat, ReadOptions,
};
use alfd::source::decode::{yuyv_to_rgb, z16_to_depth};
use alfd::source::ColorImage;
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();

fn check_image(img: &DepthImage) {
    assert!(img.width() > 0 && img.height() > 0);
    let n = img.width().checked_mul(img.height()).expect("pixel count");
    let len = match img.data() {
        DepthData::Z16 { data, .. } => data.len(),
        DepthData::Metres(data) => data.len(),
    };
    assert_eq!(len, n);
}

fn check_colour(c: &ColorImage) {
    assert_eq!(
        Some(c.rgb.len()),
        c.width.checked_mul(c.height).and_then(|p| p.checked_mul(3))
    );
}

fn z16(img: &DepthImage) -> &[u16] {
    match img.data() {
        DepthData::Z16 { data, .. } => data,
        DepthData::Metres(_) => panic!("a Z16 decoder returned metres"),
    }
}

fn metres(img: &DepthImage) -> &[f32] {
    match img.data() {
        DepthData::Metres(data) => data,
        DepthData::Z16 { .. } => panic!("the PFM decoder returned Z16"),
    }
}

/// Errors render as one line (the module's promise) without panicking.
fn check_error(e: &DepthFileError) {
    let s = e.to_string();
    assert!(!s.contains('\n'), "multi-line error: {s:?}");
}

fn png_round_trip(img: &DepthImage) {
    let data = z16(img);
    let bytes = encode_png16(img.width(), img.height(), data).expect("a decoded image encodes");
    let back = decode_png16(&bytes, 0.001, Some((img.width(), img.height()))).expect("re-decodes");
    assert_eq!(z16(&back), data);
}

fn pfm_round_trip(img: &DepthImage) {
    let data = metres(img);
    let bytes = encode_pfm(img.width(), img.height(), data);
    let back = decode_pfm(&bytes, Some((img.width(), img.height()))).expect("re-decodes");
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(metres(&back)), bits(data));
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 5 {
        return;
    }
    let sel = data[0];
    let w = usize::from(u16::from_le_bytes([data[1], data[2]]));
    let h = usize::from(u16::from_le_bytes([data[3], data[4]]));
    let body = &data[5..];
    // Bit 3: a nonsense scale (0), which must be refused, not used.
    let scale_m = if sel & 0x08 != 0 { 0.0 } else { 0.001 };
    // Bit 4: the caller states the size it expects (PNG and PFM check it).
    let expect = (sel & 0x10 != 0).then_some((w, h));
    match sel % 8 {
        0 => match decode_z16(body, w, h, scale_m) {
            Ok(img) => {
                check_image(&img);
                assert_eq!((img.width(), img.height()), (w, h));
                assert_eq!(encode_z16(z16(&img)), body);
            }
            Err(e) => check_error(&e),
        },
        1 => {
            let format = DepthFormat::ALL[usize::from(sel >> 5) % 3];
            let opts = ReadOptions {
                format: Some(format),
                width: expect.map(|(w, _)| w),
                height: expect.map(|(_, h)| h),
                scale_m,
            };
            match decode_depth(body, format, &opts) {
                Ok(img) => check_image(&img),
                Err(e) => check_error(&e),
            }
        }
        2 => match decode_png16(body, scale_m, expect) {
            Ok(img) => {
                check_image(&img);
                png_round_trip(&img);
            }
            Err(e) => check_error(&e),
        },
        3 | 6 => match decode_pfm(&data[1..], expect) {
            Ok(img) => {
                check_image(&img);
                pfm_round_trip(&img);
            }
            Err(e) => check_error(&e),
        },
        4 => {
            if let Ok(img) = z16_to_depth(w, h, body, scale_m) {
                check_image(&img);
                assert_eq!((img.width(), img.height()), (w, h));
            }
        }
        5 => {
            if let Ok(c) = yuyv_to_rgb(w, h, body) {
                check_colour(&c);
            }
        }
        _ => {
            // Sizes as wide as the callers' types allow: V4L2 reports u32, files usize.
            let wide = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
            if body.len() >= 8 {
                let (w, h, buf) = (wide(&body[..4]), wide(&body[4..8]), &body[8..]);
                if let Ok(img) = z16_to_depth(w, h, buf, 0.001) {
                    check_image(&img);
                }
                // Sizes whose byte count overflows: the regression test
                // `yuyv_sizes_that_overflow_are_an_error` (tests/byte_streams.rs) until fixed.
                let fits = w.checked_mul(h).and_then(|p| p.checked_mul(3)).is_some();
                if fits {
                    if let Ok(c) = yuyv_to_rgb(w, h, buf) {
                        check_colour(&c);
                    }
                }
                if let Err(e) = decode_z16(buf, w << 16, h << 16, 0.001) {
                    check_error(&e);
                }
            }
        }
    }
});
