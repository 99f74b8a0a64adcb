//! Compressed colour frames: MJPEG buffers from UVC cameras (`mjpeg_to_rgb`, including frames
//! without Huffman tables) and the PNG frames of recorded sessions (`png_to_rgb`). A frame
//! decodes to width × height × 3 bytes or is refused; it never panics or allocates by a size
//! field it has not checked (the allocation cap in `alfd_fuzz`).
//!
//! Input: bit 7 of byte 0 picks PNG (set) or MJPEG; the rest is the frame.
#![no_main]

use alfd::source::decode::{mjpeg_to_rgb, png_to_rgb};
use alfd::source::ColorImage;
use libfuzzer_sys::fuzz_target;

alfd_fuzz::cap_allocations!();

fn check(c: &ColorImage) {
    assert_eq!(
        Some(c.rgb.len()),
        c.width.checked_mul(c.height).and_then(|p| p.checked_mul(3))
    );
}

fuzz_target!(|data: &[u8]| {
    let Some((&sel, frame)) = data.split_first() else {
        return;
    };
    if sel & 0x80 != 0 {
        if let Ok(c) = png_to_rgb(frame) {
            check(&c);
        }
    } else {
        if let Ok(c) = mjpeg_to_rgb(frame) {
            check(&c);
        }
    }
});
