//! An MJPEG camera's frame stored as the camera encoded it: the EXIF segment put in,
//! the standard Huffman tables added where a UVC camera left them out, and nothing
//! decoded or compressed a second time. Decoding and re-encoding a capture cost about
//! 10 ms of CPU each (`docs/daemon-load.md`) and a second generation of JPEG loss; this
//! costs a walk over the frame's marker segments and a copy.
//!
//! Only the structure is checked (start of image, a frame header with a size, a scan,
//! an end of image): a frame that fails is re-encoded from its decoded pixels by the
//! writer instead, so a broken frame is never stored as if it were whole.

/// A frame ready to store, and its size from its frame header (for the EXIF tags).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AsReceived {
    pub bytes: Vec<u8>,
    pub width: u32,
    pub height: u32,
    /// The camera had left out its Huffman tables; the standard ones were added.
    pub tables_added: bool,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JpegError {
    #[error("no start-of-image marker")]
    NoStart,
    #[error("byte {0}: expected a marker")]
    NotMarker(usize),
    #[error("the marker segment at byte {0} runs past the end of the frame")]
    Truncated(usize),
    #[error("end of image before any scan")]
    NoScan,
    #[error("no frame header before the scan")]
    NoFrameHeader,
    #[error("frame header at byte {at}: {reason}")]
    BadFrameHeader { at: usize, reason: &'static str },
    #[error("no end-of-image marker after the scan (a truncated frame)")]
    NoEnd,
    #[error("EXIF segment of {0} bytes is longer than a JPEG segment can hold")]
    ExifTooLong(usize),
}

const SOI: u8 = 0xD8;
const EOI: u8 = 0xD9;
const SOS: u8 = 0xDA;
const DHT: u8 = 0xC4;
const APP0: u8 = 0xE0;
const APP1: u8 = 0xE1;
const EXIF_HEADER: &[u8] = b"Exif\0\0";

/// One marker segment before the scan: where it starts, its marker, and the whole
/// segment (marker, length and payload).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Segment<'a> {
    pub at: usize,
    pub marker: u8,
    pub bytes: &'a [u8],
}

impl<'a> Segment<'a> {
    /// The segment's payload, after its marker and length.
    pub fn payload(&self) -> &'a [u8] {
        &self.bytes[4..]
    }
}

/// The marker segments of a JPEG from after its start-of-image marker up to and
/// including the start-of-scan segment, after which the entropy-coded data begins and
/// the walk ends. Fill bytes and stand-alone markers are stepped over; an end of image
/// before the scan, a byte that is not a marker and a segment running past the end are
/// errors, after which the walk ends. The one walk of marker segments in alfd (the
/// kept frame, the EXIF reader, the decoder's table check, the test cameras).
pub(crate) fn segments(jpeg: &[u8]) -> Segments<'_> {
    Segments {
        jpeg,
        at: if jpeg.starts_with(&[0xFF, SOI]) { 2 } else { 0 },
        started: jpeg.starts_with(&[0xFF, SOI]),
        done: false,
    }
}

pub(crate) struct Segments<'a> {
    jpeg: &'a [u8],
    at: usize,
    started: bool,
    done: bool,
}

impl Segments<'_> {
    /// Where the walk stands: after the last segment given (the scan's data, once the
    /// start-of-scan segment has been given).
    pub fn position(&self) -> usize {
        self.at
    }
}

impl<'a> Iterator for Segments<'a> {
    type Item = Result<Segment<'a>, JpegError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let fail = |this: &mut Self, e| {
            this.done = true;
            Some(Err(e))
        };
        if !self.started {
            return fail(self, JpegError::NoStart);
        }
        let jpeg = self.jpeg;
        loop {
            // Fill bytes (0xFF) may precede a marker.
            while jpeg.get(self.at) == Some(&0xFF) && jpeg.get(self.at + 1) == Some(&0xFF) {
                self.at += 1;
            }
            let at = self.at;
            let (Some(&0xFF), Some(&marker)) = (jpeg.get(at), jpeg.get(at + 1)) else {
                let e = if at >= jpeg.len() {
                    JpegError::NoScan
                } else {
                    JpegError::NotMarker(at)
                };
                return fail(self, e);
            };
            match marker {
                EOI => return fail(self, JpegError::NoScan),
                // Stand-alone markers carry no length.
                0x01 | 0xD0..=0xD7 => {
                    self.at += 2;
                    continue;
                }
                _ => {}
            }
            let Some(len) = jpeg
                .get(at + 2..at + 4)
                .map(|l| u16::from_be_bytes([l[0], l[1]]) as usize)
            else {
                return fail(self, JpegError::Truncated(at));
            };
            let end = at + 2 + len;
            if len < 2 || end > jpeg.len() {
                return fail(self, JpegError::Truncated(at));
            }
            self.at = end;
            self.done = marker == SOS;
            return Some(Ok(Segment {
                at,
                marker,
                bytes: &jpeg[at..end],
            }));
        }
    }
}

/// The frame with `exif(width, height)` (an EXIF payload, `Exif\0\0` + TIFF, as
/// [`super::exif_app1`] makes it; `None`: no segment) as its EXIF segment, after any
/// leading APP0 (JFIF, AVI1) and in place of an EXIF segment the camera wrote. Bytes
/// after the end-of-image marker (a driver's padding) are left out.
pub fn as_received(
    jpeg: &[u8],
    exif: impl FnOnce(u32, u32) -> Option<Vec<u8>>,
) -> Result<AsReceived, JpegError> {
    // Segments before the scan, and the scan's own.
    let mut kept: Vec<Segment> = Vec::new();
    let mut scan = None;
    let mut size = None;
    let mut huffman_coded = false;
    let mut has_tables = false;
    for segment in segments(jpeg) {
        let segment = segment?;
        let (at, marker) = (segment.at, segment.marker);
        match marker {
            SOS => {
                scan = Some(segment);
                continue;
            }
            DHT => has_tables = true,
            // Frame headers: SOF0..SOF15 less DHT (C4), JPG (C8) and DAC (CC).
            0xC0..=0xCF if marker != 0xC8 && marker != 0xCC => {
                let p = segment.payload();
                if p.len() < 6 {
                    return Err(JpegError::BadFrameHeader {
                        at,
                        reason: "shorter than its fields",
                    });
                }
                let height = u16::from_be_bytes([p[1], p[2]]) as u32;
                let width = u16::from_be_bytes([p[3], p[4]]) as u32;
                if width == 0 || height == 0 {
                    // Height 0 defers it to a DNL marker after the scan; no camera does.
                    return Err(JpegError::BadFrameHeader {
                        at,
                        reason: "zero width or height",
                    });
                }
                size = Some((width, height));
                // SOF9..SOF15 are arithmetic-coded and need no Huffman tables.
                huffman_coded = marker < 0xC8;
            }
            _ => {}
        }
        kept.push(segment);
    }
    let scan = scan.ok_or(JpegError::NoScan)?;
    let (width, height) = size.ok_or(JpegError::NoFrameHeader)?;
    // The entropy-coded data stuffs every 0xFF with a zero byte or a restart marker, so
    // the first FF D9 after the scan header ends the image.
    let scan_header_end = scan.at + scan.bytes.len();
    let end = jpeg[scan_header_end..]
        .windows(2)
        .position(|w| w == [0xFF, EOI])
        .map(|p| scan_header_end + p + 2)
        .ok_or(JpegError::NoEnd)?;

    let app1_segment = match exif(width, height) {
        None => None,
        Some(p) => {
            let len = u16::try_from(p.len() + 2).map_err(|_| JpegError::ExifTooLong(p.len()))?;
            // Ours replaces the camera's.
            kept.retain(|s| s.marker != APP1 || !s.payload().starts_with(EXIF_HEADER));
            Some([&[0xFF, APP1][..], &len.to_be_bytes(), &p].concat())
        }
    };
    let tables_added = huffman_coded && !has_tables;
    let mut bytes = Vec::with_capacity(end + 512 + app1_segment.as_ref().map_or(0, Vec::len));
    bytes.extend_from_slice(&[0xFF, SOI]);
    let leading_app0 = kept.iter().take_while(|s| s.marker == APP0).count();
    for s in &kept[..leading_app0] {
        bytes.extend_from_slice(s.bytes);
    }
    if let Some(s) = &app1_segment {
        bytes.extend_from_slice(s);
    }
    for s in &kept[leading_app0..] {
        bytes.extend_from_slice(s.bytes);
    }
    if tables_added {
        bytes.extend_from_slice(&standard_tables_segment());
    }
    bytes.extend_from_slice(&jpeg[scan.at..end]);
    Ok(AsReceived {
        bytes,
        width,
        height,
        tables_added,
    })
}

/// The typical Huffman tables of ITU-T T.81 Annex K.3, which the UVC MJPEG payload
/// specification says a decoder uses when a frame carries none: per table, its class and
/// id, the number of codes of each length 1..=16, and the symbols in code order.
const STANDARD_TABLES: [(u8, [u8; 16], &[u8]); 4] = [
    // Luminance DC.
    (
        0x00,
        [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0],
        &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11],
    ),
    // Luminance AC.
    (
        0x10,
        [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7D],
        &LUMINANCE_AC,
    ),
    // Chrominance DC.
    (
        0x01,
        [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0],
        &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11],
    ),
    // Chrominance AC.
    (
        0x11,
        [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77],
        &CHROMINANCE_AC,
    ),
];

#[rustfmt::skip]
const LUMINANCE_AC: [u8; 162] = [
    0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61,
    0x07, 0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xA1, 0x08, 0x23, 0x42, 0xB1, 0xC1, 0x15, 0x52,
    0xD1, 0xF0, 0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0A, 0x16, 0x17, 0x18, 0x19, 0x1A, 0x25,
    0x26, 0x27, 0x28, 0x29, 0x2A, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44, 0x45,
    0x46, 0x47, 0x48, 0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63, 0x64,
    0x65, 0x66, 0x67, 0x68, 0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A, 0x83,
    0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99,
    0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4, 0xB5, 0xB6,
    0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA, 0xD2, 0xD3,
    0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE1, 0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7, 0xE8,
    0xE9, 0xEA, 0xF1, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8, 0xF9, 0xFA,
];

#[rustfmt::skip]
const CHROMINANCE_AC: [u8; 162] = [
    0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61,
    0x71, 0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xA1, 0xB1, 0xC1, 0x09, 0x23, 0x33,
    0x52, 0xF0, 0x15, 0x62, 0x72, 0xD1, 0x0A, 0x16, 0x24, 0x34, 0xE1, 0x25, 0xF1, 0x17, 0x18,
    0x19, 0x1A, 0x26, 0x27, 0x28, 0x29, 0x2A, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3A, 0x43, 0x44,
    0x45, 0x46, 0x47, 0x48, 0x49, 0x4A, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5A, 0x63,
    0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6A, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7A,
    0x82, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8A, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97,
    0x98, 0x99, 0x9A, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7, 0xA8, 0xA9, 0xAA, 0xB2, 0xB3, 0xB4,
    0xB5, 0xB6, 0xB7, 0xB8, 0xB9, 0xBA, 0xC2, 0xC3, 0xC4, 0xC5, 0xC6, 0xC7, 0xC8, 0xC9, 0xCA,
    0xD2, 0xD3, 0xD4, 0xD5, 0xD6, 0xD7, 0xD8, 0xD9, 0xDA, 0xE2, 0xE3, 0xE4, 0xE5, 0xE6, 0xE7,
    0xE8, 0xE9, 0xEA, 0xF2, 0xF3, 0xF4, 0xF5, 0xF6, 0xF7, 0xF8, 0xF9, 0xFA,
];

/// One DHT segment holding the four standard tables.
fn standard_tables_segment() -> Vec<u8> {
    let body: usize = STANDARD_TABLES.iter().map(|(_, _, v)| 17 + v.len()).sum();
    let mut s = Vec::with_capacity(4 + body);
    s.extend_from_slice(&[0xFF, DHT]);
    s.extend_from_slice(&((body + 2) as u16).to_be_bytes());
    for (class_id, counts, symbols) in STANDARD_TABLES {
        s.push(class_id);
        s.extend_from_slice(&counts);
        s.extend_from_slice(symbols);
    }
    s
}

/// A well-formed frame with its Huffman tables (DHT segments) taken out, as many UVC
/// cameras send it: for tests and benches that stand in for such a camera. Segments
/// are walked up to the scan; the scan and what follows are kept as they are.
pub fn without_huffman_tables(jpeg: &[u8]) -> Vec<u8> {
    let mut out = jpeg[..2.min(jpeg.len())].to_vec();
    let mut walk = segments(jpeg);
    let mut rest = 2.min(jpeg.len());
    while let Some(Ok(segment)) = walk.next() {
        if segment.marker == SOS {
            break;
        }
        if segment.marker != DHT {
            out.extend_from_slice(segment.bytes);
        }
        rest = walk.position();
    }
    out.extend_from_slice(&jpeg[rest..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::{exif_app1, find_exif_app1, parse_exif_gps, ExifGps};
    use crate::source::decode::mjpeg_to_rgb;

    /// A textured frame through the JPEG encoder (which writes its tables).
    fn camera_frame(width: u16, height: u16) -> Vec<u8> {
        let rgb: Vec<u8> = (0..width as usize * height as usize)
            .flat_map(|i| {
                let (x, y) = (i % width as usize, i / width as usize);
                [
                    (x * 7 % 256) as u8,
                    (y * 5 % 256) as u8,
                    ((x ^ y) % 256) as u8,
                ]
            })
            .collect();
        let mut out = Vec::new();
        jpeg_encoder::Encoder::new(&mut out, 80)
            .encode(&rgb, width, height, jpeg_encoder::ColorType::Rgb)
            .unwrap();
        out
    }

    fn gps() -> ExifGps {
        ExifGps {
            lat_deg: 47.397_742,
            lon_deg: 8.545_594,
            alt_m: 528.1,
            time_unix_us: Some(1_780_123_456_789_000),
            make: "alfd".into(),
            model: "uvc 96x64".into(),
        }
    }

    #[test]
    fn the_stored_frame_decodes_to_the_cameras_pixels_and_carries_the_exif() {
        let frame = camera_frame(96, 64);
        let app1 = exif_app1(&gps(), 96, 64).unwrap();
        let stored = as_received(&frame, |w, h| {
            assert_eq!((w, h), (96, 64), "the size from the frame header");
            Some(app1.clone())
        })
        .unwrap();
        assert_eq!(
            (stored.width, stored.height, stored.tables_added),
            (96, 64, false)
        );
        assert_eq!(mjpeg_to_rgb(&stored.bytes), mjpeg_to_rgb(&frame));
        let exif = parse_exif_gps(find_exif_app1(&stored.bytes).expect("an EXIF segment")).unwrap();
        assert!((exif.lat_deg - 47.397_742).abs() < 1e-6, "{exif:?}");
        // Nothing but the EXIF segment was added.
        assert_eq!(stored.bytes.len(), frame.len() + 4 + app1.len());
    }

    #[test]
    fn a_frame_without_tables_gets_the_standard_ones_and_the_same_pixels() {
        let frame = camera_frame(64, 48);
        let uvc = without_huffman_tables(&frame);
        assert!(
            uvc.len() < frame.len(),
            "the encoder wrote tables to take out"
        );
        let stored = as_received(&uvc, |_, _| None).unwrap();
        assert!(stored.tables_added);
        // The decoder substitutes Annex K's tables for a frame that has none; a frame
        // with our tables written in must decode to the same pixels, and so must the
        // original (whose encoder wrote the same standard tables).
        let want = mjpeg_to_rgb(&frame).unwrap();
        assert_eq!(mjpeg_to_rgb(&uvc).unwrap(), want);
        assert_eq!(mjpeg_to_rgb(&stored.bytes).unwrap(), want);
        // A decoder that knows nothing of MJPEG finds the tables in the file.
        let mut dec = jpeg_decoder::Decoder::new(&stored.bytes[..]);
        assert_eq!(dec.decode().unwrap(), want.rgb);
    }

    #[test]
    fn padding_after_the_end_is_dropped_and_a_cameras_exif_replaced() {
        let frame = camera_frame(32, 32);
        let theirs = exif_app1(
            &ExifGps {
                lat_deg: -10.0,
                ..gps()
            },
            32,
            32,
        )
        .unwrap();
        let mut with_theirs = frame[..2].to_vec();
        with_theirs.extend_from_slice(&[0xFF, APP1]);
        with_theirs.extend_from_slice(&((theirs.len() + 2) as u16).to_be_bytes());
        with_theirs.extend_from_slice(&theirs);
        with_theirs.extend_from_slice(&frame[2..]);
        with_theirs.extend_from_slice(&[0; 100]);
        let ours = exif_app1(&gps(), 32, 32).unwrap();
        let stored = as_received(&with_theirs, |_, _| Some(ours.clone())).unwrap();
        assert!(stored.bytes.ends_with(&[0xFF, EOI]));
        assert_eq!(stored.bytes.len(), frame.len() + 4 + ours.len());
        let exif = parse_exif_gps(find_exif_app1(&stored.bytes).unwrap()).unwrap();
        assert!(exif.lat_deg > 0.0, "ours, not the camera's: {exif:?}");
    }

    #[test]
    fn broken_frames_are_refused_naming_what_is_wrong() {
        let frame = camera_frame(32, 16);
        assert_eq!(as_received(b"", |_, _| None), Err(JpegError::NoStart));
        assert_eq!(
            as_received(&frame[2..], |_, _| None),
            Err(JpegError::NoStart)
        );
        // Cut inside the scan: no end of image.
        assert_eq!(
            as_received(&frame[..frame.len() - 10], |_, _| None),
            Err(JpegError::NoEnd)
        );
        // Cut inside the headers.
        assert!(matches!(
            as_received(&frame[..30], |_, _| None),
            Err(JpegError::Truncated(_) | JpegError::NoScan)
        ));
        // A zero height in the frame header.
        let mut zero = frame.clone();
        let sof = zero.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
        zero[sof + 5] = 0;
        zero[sof + 6] = 0;
        assert!(matches!(
            as_received(&zero, |_, _| None),
            Err(JpegError::BadFrameHeader { .. })
        ));
        // Garbage where a marker should be.
        let mut garbage = frame.clone();
        garbage[2] = 0x12;
        assert_eq!(
            as_received(&garbage, |_, _| None),
            Err(JpegError::NotMarker(2))
        );
        // An EXIF payload no segment can hold.
        assert_eq!(
            as_received(&frame, |_, _| Some(vec![0; 70_000])),
            Err(JpegError::ExifTooLong(70_000))
        );
    }

    /// The walk gives each segment up to and including the scan's, steps over fill bytes
    /// and stand-alone markers, and ends after its first error.
    #[test]
    fn the_segment_walk_stops_at_the_scan_or_its_first_error() {
        let frame = camera_frame(16, 8);
        let markers: Vec<u8> = segments(&frame).map(|s| s.unwrap().marker).collect();
        assert_eq!(markers.last(), Some(&SOS));
        assert!(
            markers.contains(&DHT) && markers.contains(&0xC0),
            "{markers:X?}"
        );
        let mut walk = segments(&frame);
        let sos = walk.by_ref().map(Result::unwrap).last().unwrap();
        assert_eq!(walk.position(), sos.at + sos.bytes.len());

        // Fill bytes and a stand-alone marker before the first segment.
        let padded = [&frame[..2], &[0xFF, 0xFF, 0xFF, 0x01], &frame[2..]].concat();
        let again: Vec<u8> = segments(&padded).map(|s| s.unwrap().marker).collect();
        assert_eq!(again, markers);

        fn errors(b: &[u8]) -> Vec<Result<Segment<'_>, JpegError>> {
            segments(b).collect()
        }
        assert_eq!(errors(b"no"), vec![Err(JpegError::NoStart)]);
        assert_eq!(
            errors(&[0xFF, SOI, 0x12]),
            vec![Err(JpegError::NotMarker(2))]
        );
        assert_eq!(
            errors(&[0xFF, SOI, 0xFF, EOI]),
            vec![Err(JpegError::NoScan)]
        );
        assert_eq!(
            errors(&[0xFF, SOI, 0xFF, APP0, 0x00, 0x10, 1]),
            vec![Err(JpegError::Truncated(2))]
        );
    }
}
