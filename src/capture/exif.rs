//! EXIF GPS tags for JPEG captures: an APP1 `Exif` segment built by hand (TIFF
//! little-endian: IFD0 → Exif IFD and GPS IFD), a parser for reading it back, and
//! the image encoders (JPEG with the segment, PNG). Pure: bytes in, bytes out.

use super::record::{CaptureRecord, ImageFormat};

/// `Exif\0\0`, the APP1 identifier that precedes the TIFF structure.
pub const EXIF_HEADER: &[u8; 6] = b"Exif\0\0";

const BYTE: u16 = 1;
const ASCII: u16 = 2;
const SHORT: u16 = 3;
const LONG: u16 = 4;
const RATIONAL: u16 = 5;
const UNDEFINED: u16 = 7;

const TAG_MAKE: u16 = 0x010F;
const TAG_MODEL: u16 = 0x0110;
const TAG_X_RESOLUTION: u16 = 0x011A;
const TAG_Y_RESOLUTION: u16 = 0x011B;
const TAG_RESOLUTION_UNIT: u16 = 0x0128;
const TAG_DATE_TIME: u16 = 0x0132;
const TAG_YCBCR_POSITIONING: u16 = 0x0213;
const TAG_EXIF_IFD: u16 = 0x8769;
const TAG_GPS_IFD: u16 = 0x8825;
const TAG_EXIF_VERSION: u16 = 0x9000;
const TAG_DATE_TIME_ORIGINAL: u16 = 0x9003;
const TAG_COMPONENTS_CONFIGURATION: u16 = 0x9101;
const TAG_SUB_SEC_TIME_ORIGINAL: u16 = 0x9291;
const TAG_FLASHPIX_VERSION: u16 = 0xA000;
const TAG_COLOR_SPACE: u16 = 0xA001;
const TAG_PIXEL_X_DIMENSION: u16 = 0xA002;
const TAG_PIXEL_Y_DIMENSION: u16 = 0xA003;
const GPS_VERSION_ID: u16 = 0x0000;
const GPS_LATITUDE_REF: u16 = 0x0001;
const GPS_LATITUDE: u16 = 0x0002;
const GPS_LONGITUDE_REF: u16 = 0x0003;
const GPS_LONGITUDE: u16 = 0x0004;
const GPS_ALTITUDE_REF: u16 = 0x0005;
const GPS_ALTITUDE: u16 = 0x0006;
const GPS_TIME_STAMP: u16 = 0x0007;
const GPS_DATE_STAMP: u16 = 0x001D;

/// What goes into a capture's EXIF.
#[derive(Debug, Clone, PartialEq)]
pub struct ExifGps {
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Above mean sea level, metres.
    pub alt_m: f64,
    /// UNIX time of the capture (UTC), µs; without it no date or time tags are written.
    pub time_unix_us: Option<u64>,
    pub make: String,
    pub model: String,
}

impl ExifGps {
    pub fn from_record(r: &CaptureRecord, make: &str, model: &str) -> ExifGps {
        ExifGps {
            lat_deg: r.position.lat_deg,
            lon_deg: r.position.lon_deg,
            alt_m: r.position.alt_m,
            time_unix_us: r.time_unix_us,
            make: make.into(),
            model: model.into(),
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ExifError {
    #[error("no GPS position to tag: lat {lat_deg}, lon {lon_deg}, alt {alt_m} m")]
    BadPosition {
        lat_deg: f64,
        lon_deg: f64,
        alt_m: f64,
    },
    #[error("not an Exif APP1 segment: {0}")]
    Malformed(&'static str),
    #[error("Exif has no GPS {0}")]
    Missing(&'static str),
}

struct Entry {
    tag: u16,
    typ: u16,
    count: u32,
    /// The value, little-endian, unpadded.
    data: Vec<u8>,
}

fn ascii(tag: u16, s: &str) -> Entry {
    let mut data: Vec<u8> = s
        .bytes()
        .filter(|b| (0x20..0x7F).contains(b))
        .take(63)
        .collect();
    data.push(0);
    Entry {
        tag,
        typ: ASCII,
        count: data.len() as u32,
        data,
    }
}

fn rationals(tag: u16, values: &[(u32, u32)]) -> Entry {
    let data = values
        .iter()
        .flat_map(|&(n, d)| n.to_le_bytes().into_iter().chain(d.to_le_bytes()))
        .collect();
    Entry {
        tag,
        typ: RATIONAL,
        count: values.len() as u32,
        data,
    }
}

fn raw(tag: u16, typ: u16, data: &[u8]) -> Entry {
    Entry {
        tag,
        typ,
        count: data.len() as u32,
        data: data.to_vec(),
    }
}

fn short(tag: u16, v: u16) -> Entry {
    Entry {
        tag,
        typ: SHORT,
        count: 1,
        data: v.to_le_bytes().to_vec(),
    }
}

fn long(tag: u16, v: u32) -> Entry {
    Entry {
        tag,
        typ: LONG,
        count: 1,
        data: v.to_le_bytes().to_vec(),
    }
}

/// Bytes an IFD takes: count, entries, next-IFD offset, out-of-line values (even-padded).
fn ifd_len(entries: &[Entry]) -> usize {
    let out_of_line: usize = entries
        .iter()
        .filter(|e| e.data.len() > 4)
        .map(|e| e.data.len().next_multiple_of(2))
        .sum();
    2 + 12 * entries.len() + 4 + out_of_line
}

/// Writes an IFD at `tiff.len()` (offsets count from the TIFF header), its
/// out-of-line values right after it. Entries must be sorted by tag.
fn write_ifd(tiff: &mut Vec<u8>, entries: &[Entry]) {
    debug_assert!(entries.windows(2).all(|w| w[0].tag < w[1].tag));
    let mut data_at = tiff.len() + 2 + 12 * entries.len() + 4;
    let mut data = Vec::new();
    tiff.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for e in entries {
        tiff.extend_from_slice(&e.tag.to_le_bytes());
        tiff.extend_from_slice(&e.typ.to_le_bytes());
        tiff.extend_from_slice(&e.count.to_le_bytes());
        if e.data.len() <= 4 {
            let mut v = [0u8; 4];
            v[..e.data.len()].copy_from_slice(&e.data);
            tiff.extend_from_slice(&v);
        } else {
            tiff.extend_from_slice(&(data_at as u32).to_le_bytes());
            data.extend_from_slice(&e.data);
            if e.data.len() % 2 == 1 {
                data.push(0);
            }
            data_at += e.data.len().next_multiple_of(2);
        }
    }
    tiff.extend_from_slice(&0u32.to_le_bytes());
    tiff.extend_from_slice(&data);
}

/// |deg| as degrees, minutes and seconds rationals, seconds to 1e-6 s (3e-11°).
fn dms(deg: f64) -> [(u32, u32); 3] {
    let micro_arcsec = (deg.abs() * 3_600_000_000.0).round() as u64;
    [
        ((micro_arcsec / 3_600_000_000) as u32, 1),
        ((micro_arcsec / 60_000_000 % 60) as u32, 1),
        ((micro_arcsec % 60_000_000) as u32, 1_000_000),
    ]
}

/// UTC civil date and time of a UNIX time: (year, month, day, hour, minute, millisecond of minute).
fn civil(unix_us: u64) -> (i64, u32, u32, u32, u32, u32) {
    let ms = unix_us / 1000;
    let (days, ms_of_day) = ((ms / 86_400_000) as i64, ms % 86_400_000);
    // Days to civil date: H. Hinnant's algorithm (proleptic Gregorian).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    let (h, rest) = ((ms_of_day / 3_600_000) as u32, ms_of_day % 3_600_000);
    (
        year,
        month,
        day,
        h,
        (rest / 60_000) as u32,
        (rest % 60_000) as u32,
    )
}

/// Days since 1970-01-01 of a civil date (inverse of the above).
fn days_from_civil(y: i64, m: u32, d: u32) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m as i64 + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d as i64 - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The APP1 payload (`Exif\0\0` + TIFF) for a `width` × `height` capture: IFD0
/// (Make, Model, DateTime, resolution), the Exif IFD (ExifVersion, DateTimeOriginal
/// and SubSecTimeOriginal, pixel dimensions, sRGB) and the GPS IFD (version 2.3,
/// latitude, longitude, altitude, UTC time and date stamps). Without a time, no
/// date or time tags.
pub fn exif_app1(g: &ExifGps, width: u32, height: u32) -> Result<Vec<u8>, ExifError> {
    app1(g, width, height, true)
}

/// [`exif_app1`] without the GPS IFD (its position ignored): what a camera with
/// no GPS of its own writes, its capture time from its own clock
/// (`g.time_unix_us`). `alfd sim`'s external camera card is written so.
pub fn exif_app1_without_gps(g: &ExifGps, width: u32, height: u32) -> Vec<u8> {
    app1(g, width, height, false).expect("without a position there is nothing to refuse")
}

fn app1(g: &ExifGps, width: u32, height: u32, with_gps: bool) -> Result<Vec<u8>, ExifError> {
    let ok = g.lat_deg.abs() <= 90.0 && g.lon_deg.abs() <= 180.0 && g.alt_m.is_finite();
    if with_gps && !ok {
        return Err(ExifError::BadPosition {
            lat_deg: g.lat_deg,
            lon_deg: g.lon_deg,
            alt_m: g.alt_m,
        });
    }
    let time = g.time_unix_us.map(civil);
    let stamp = time.map(|(y, mo, d, h, mi, ms)| {
        format!("{y:04}:{mo:02}:{d:02} {h:02}:{mi:02}:{:02}", ms / 1000)
    });

    // Besides GPS, the tags Exif 2.3 requires of a JPEG (so `exiftool -validate` is clean).
    let mut ifd0 = vec![
        ascii(TAG_MAKE, &g.make),
        ascii(TAG_MODEL, &g.model),
        rationals(TAG_X_RESOLUTION, &[(72, 1)]),
        rationals(TAG_Y_RESOLUTION, &[(72, 1)]),
        short(TAG_RESOLUTION_UNIT, 2),
    ];
    if let Some(s) = &stamp {
        ifd0.push(ascii(TAG_DATE_TIME, s));
    }
    ifd0.push(short(TAG_YCBCR_POSITIONING, 1));
    ifd0.push(long(TAG_EXIF_IFD, 0));
    if with_gps {
        ifd0.push(long(TAG_GPS_IFD, 0));
    }

    let mut exif = vec![raw(TAG_EXIF_VERSION, UNDEFINED, b"0232")];
    if let Some(s) = &stamp {
        exif.push(ascii(TAG_DATE_TIME_ORIGINAL, s));
    }
    exif.push(raw(TAG_COMPONENTS_CONFIGURATION, UNDEFINED, &[1, 2, 3, 0]));
    // The milliseconds DateTimeOriginal cannot hold: a reconstruction tool that
    // orders or pairs pictures by time gets the capture's own.
    if let Some((.., ms)) = time {
        exif.push(ascii(
            TAG_SUB_SEC_TIME_ORIGINAL,
            &format!("{:03}", ms % 1000),
        ));
    }
    exif.extend([
        raw(TAG_FLASHPIX_VERSION, UNDEFINED, b"0100"),
        short(TAG_COLOR_SPACE, 1),
        long(TAG_PIXEL_X_DIMENSION, width),
        long(TAG_PIXEL_Y_DIMENSION, height),
    ]);

    // Altitude in millimetres; beyond u32 (4000 km) is no drone's.
    let alt_mm = (g.alt_m.abs() * 1000.0).round().min(u32::MAX as f64) as u32;
    let mut gps = vec![
        raw(GPS_VERSION_ID, BYTE, &[2, 3, 0, 0]),
        ascii(GPS_LATITUDE_REF, if g.lat_deg < 0.0 { "S" } else { "N" }),
        rationals(GPS_LATITUDE, &dms(g.lat_deg)),
        ascii(GPS_LONGITUDE_REF, if g.lon_deg < 0.0 { "W" } else { "E" }),
        rationals(GPS_LONGITUDE, &dms(g.lon_deg)),
        raw(GPS_ALTITUDE_REF, BYTE, &[u8::from(g.alt_m < 0.0)]),
        rationals(GPS_ALTITUDE, &[(alt_mm, 1000)]),
    ];
    if let Some((y, mo, d, h, mi, ms)) = time {
        gps.push(rationals(GPS_TIME_STAMP, &[(h, 1), (mi, 1), (ms, 1000)]));
        gps.push(ascii(GPS_DATE_STAMP, &format!("{y:04}:{mo:02}:{d:02}")));
    }

    let exif_at = 8 + ifd_len(&ifd0);
    let gps_at = exif_at + ifd_len(&exif);
    for e in &mut ifd0 {
        match e.tag {
            TAG_EXIF_IFD => e.data = (exif_at as u32).to_le_bytes().to_vec(),
            TAG_GPS_IFD => e.data = (gps_at as u32).to_le_bytes().to_vec(),
            _ => {}
        }
    }
    let mut tiff = b"II\x2A\x00\x08\x00\x00\x00".to_vec();
    write_ifd(&mut tiff, &ifd0);
    debug_assert_eq!(tiff.len(), exif_at);
    write_ifd(&mut tiff, &exif);
    debug_assert_eq!(tiff.len(), gps_at);
    if with_gps {
        write_ifd(&mut tiff, &gps);
    }

    let mut app1 = EXIF_HEADER.to_vec();
    app1.extend_from_slice(&tiff);
    Ok(app1)
}

/// What [`parse_exif_gps`] reads back.
#[derive(Debug, Clone, PartialEq)]
pub struct ParsedExif {
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f64,
    /// From GPSDateStamp + GPSTimeStamp, when both are present.
    pub gps_time_unix_us: Option<u64>,
    pub make: Option<String>,
    pub model: Option<String>,
    pub date_time_original: Option<String>,
}

/// A TIFF structure of either byte order, bounds-checked.
struct Tiff<'a> {
    b: &'a [u8],
    le: bool,
}

struct Field<'a> {
    typ: u16,
    count: u32,
    value: &'a [u8],
}

impl<'a> Tiff<'a> {
    fn u16(&self, at: usize) -> Option<u16> {
        let s: [u8; 2] = self.b.get(at..at + 2)?.try_into().ok()?;
        Some(if self.le {
            u16::from_le_bytes(s)
        } else {
            u16::from_be_bytes(s)
        })
    }

    fn u32(&self, at: usize) -> Option<u32> {
        let s: [u8; 4] = self.b.get(at..at + 4)?.try_into().ok()?;
        Some(if self.le {
            u32::from_le_bytes(s)
        } else {
            u32::from_be_bytes(s)
        })
    }

    /// The IFD at `at` as (tag → field).
    fn ifd(&self, at: usize) -> Option<Vec<(u16, Field<'a>)>> {
        let n = self.u16(at)? as usize;
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let e = at + 2 + 12 * i;
            let (tag, typ, count) = (self.u16(e)?, self.u16(e + 2)?, self.u32(e + 4)?);
            let size = match typ {
                BYTE | ASCII | UNDEFINED => 1,
                SHORT => 2,
                LONG => 4,
                RATIONAL => 8,
                _ => continue,
            } * count as usize;
            let value = if size <= 4 {
                self.b.get(e + 8..e + 8 + size)?
            } else {
                let off = self.u32(e + 8)? as usize;
                self.b.get(off..off.checked_add(size)?)?
            };
            out.push((tag, Field { typ, count, value }));
        }
        Some(out)
    }

    fn rationals(&self, f: &Field) -> Option<Vec<f64>> {
        if f.typ != RATIONAL {
            return None;
        }
        let t = Tiff {
            b: f.value,
            le: self.le,
        };
        (0..f.count as usize)
            .map(|i| {
                let (n, d) = (t.u32(8 * i)?, t.u32(8 * i + 4)?);
                (d != 0).then(|| n as f64 / d as f64)
            })
            .collect()
    }
}

fn find<'f, 'a>(ifd: &'f [(u16, Field<'a>)], tag: u16) -> Option<&'f Field<'a>> {
    ifd.iter().find(|(t, _)| *t == tag).map(|(_, f)| f)
}

fn text(f: &Field) -> Option<String> {
    (f.typ == ASCII).then(|| {
        let end = f
            .value
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(f.value.len());
        String::from_utf8_lossy(&f.value[..end]).into_owned()
    })
}

/// Reads the GPS position (and the tags alfd writes) from an APP1 payload.
pub fn parse_exif_gps(app1: &[u8]) -> Result<ParsedExif, ExifError> {
    use ExifError::{Malformed, Missing};
    let b = app1
        .strip_prefix(EXIF_HEADER)
        .ok_or(Malformed("no Exif header"))?;
    let le = match b.get(..4) {
        Some(b"II\x2A\x00") => true,
        Some(b"MM\x00\x2A") => false,
        _ => return Err(Malformed("no TIFF header")),
    };
    let t = Tiff { b, le };
    let ifd0_at = t.u32(4).ok_or(Malformed("short TIFF header"))? as usize;
    let ifd0 = t.ifd(ifd0_at).ok_or(Malformed("IFD0 out of bounds"))?;
    let pointer = |tag| -> Result<Option<Vec<(u16, Field)>>, ExifError> {
        match find(&ifd0, tag) {
            None => Ok(None),
            Some(f) => {
                let at = Tiff { b: f.value, le }
                    .u32(0)
                    .ok_or(Malformed("bad IFD pointer"))?;
                t.ifd(at as usize)
                    .map(Some)
                    .ok_or(Malformed("sub-IFD out of bounds"))
            }
        }
    };
    let gps = pointer(TAG_GPS_IFD)?.ok_or(Missing("IFD"))?;
    let exif = pointer(TAG_EXIF_IFD)?;

    // A damaged segment can still hold three rationals: an angle beyond its
    // range (found by tests/byte_streams.rs: 181° of longitude) is refused,
    // never returned as a position.
    let angle =
        |value_tag, ref_tag, negative: &str, max_deg: f64, what| -> Result<f64, ExifError> {
            let v = find(&gps, value_tag)
                .and_then(|f| t.rationals(f))
                .filter(|v| v.len() == 3)
                .ok_or(Missing(what))?;
            let r = find(&gps, ref_tag).and_then(text).ok_or(Missing(what))?;
            let deg = v[0] + v[1] / 60.0 + v[2] / 3600.0;
            if !(deg.is_finite() && (0.0..=max_deg).contains(&deg)) {
                return Err(Malformed("GPS angle out of range"));
            }
            Ok(if r == negative { -deg } else { deg })
        };
    let lat_deg = angle(GPS_LATITUDE, GPS_LATITUDE_REF, "S", 90.0, "latitude")?;
    let lon_deg = angle(GPS_LONGITUDE, GPS_LONGITUDE_REF, "W", 180.0, "longitude")?;
    let alt = find(&gps, GPS_ALTITUDE)
        .and_then(|f| t.rationals(f))
        .and_then(|v| v.first().copied())
        .ok_or(Missing("altitude"))?;
    let below = find(&gps, GPS_ALTITUDE_REF).is_some_and(|f| f.value.first() == Some(&1));
    let alt_m = if below { -alt } else { alt };
    if !alt_m.is_finite() {
        return Err(Malformed("GPS altitude not a number"));
    }

    let gps_time_unix_us = (|| {
        let hms = find(&gps, GPS_TIME_STAMP).and_then(|f| t.rationals(f))?;
        let date = find(&gps, GPS_DATE_STAMP).and_then(text)?;
        let mut ymd = date.split(':').map(|s| s.parse::<i64>().ok());
        let (y, m, d) = (ymd.next()??, ymd.next()??, ymd.next()??);
        let days = days_from_civil(y, m as u32, d as u32);
        let secs = hms.first()? * 3600.0 + hms.get(1)? * 60.0 + hms.get(2)?;
        let us = days as f64 * 86_400e6 + (secs * 1e6).round();
        (us >= 0.0).then_some(us as u64)
    })();

    Ok(ParsedExif {
        lat_deg,
        lon_deg,
        alt_m,
        gps_time_unix_us,
        make: find(&ifd0, TAG_MAKE).and_then(text),
        model: find(&ifd0, TAG_MODEL).and_then(text),
        date_time_original: exif
            .as_deref()
            .and_then(|e| find(e, TAG_DATE_TIME_ORIGINAL))
            .and_then(text),
    })
}

/// When a camera says it took a picture: EXIF DateTimeOriginal (the camera's own
/// clock, no time zone) with SubSecTimeOriginal's fraction when given.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TakenAt {
    /// Seconds since 1970-01-01 00:00:00 of the camera's clock, read as if it were UTC.
    pub clock_s: f64,
    /// The stamp's step: 1 s without SubSecTimeOriginal, 10^-digits with it.
    pub resolution_s: f64,
}

/// The capture time an APP1 payload's Exif IFD holds (DateTimeOriginal, and
/// SubSecTimeOriginal); `None` when it has none or it is not a date. An external
/// camera's pictures are paired with alfd's captures by it (`capture::external`).
pub fn parse_exif_taken(app1: &[u8]) -> Option<TakenAt> {
    let b = app1.strip_prefix(EXIF_HEADER)?;
    let le = match b.get(..4)? {
        b"II\x2A\x00" => true,
        b"MM\x00\x2A" => false,
        _ => return None,
    };
    let t = Tiff { b, le };
    let ifd0 = t.ifd(t.u32(4)? as usize)?;
    let at = Tiff {
        b: find(&ifd0, TAG_EXIF_IFD)?.value,
        le,
    }
    .u32(0)?;
    let exif = t.ifd(at as usize)?;
    let stamp = find(&exif, TAG_DATE_TIME_ORIGINAL).and_then(text)?;
    // "YYYY:MM:DD HH:MM:SS"; a camera that never had its clock set writes blanks
    // or zeros, which is no time.
    let (date, time) = stamp.trim().split_once(' ')?;
    let num = |s: &str| s.trim().parse::<u32>().ok();
    let mut d = date.split(':').map(num);
    let (y, mo, day) = (d.next()??, d.next()??, d.next()??);
    let mut h = time.split(':').map(num);
    let (hh, mm, ss) = (h.next()??, h.next()??, h.next()??);
    if !(1..=12).contains(&mo) || !(1..=31).contains(&day) || hh > 23 || mm > 59 || ss > 60 {
        return None;
    }
    let mut clock_s =
        days_from_civil(y as i64, mo, day) as f64 * 86_400.0 + f64::from(hh * 3600 + mm * 60 + ss);
    let mut resolution_s = 1.0;
    let sub = find(&exif, TAG_SUB_SEC_TIME_ORIGINAL).and_then(text);
    if let Some(digits) = sub
        .as_deref()
        .map(str::trim)
        .filter(|s| (1..=9).contains(&s.len()) && s.bytes().all(|c| c.is_ascii_digit()))
    {
        // "SubSecTimeOriginal" is the fraction's digits: "5" is 0.5 s, "05" 0.05 s.
        resolution_s = 10f64.powi(-(digits.len() as i32));
        clock_s += digits.parse::<u32>().ok()? as f64 * resolution_s;
    }
    Some(TakenAt {
        clock_s,
        resolution_s,
    })
}

/// The payload of the first APP1 `Exif` segment of a JPEG (header included).
pub fn find_exif_app1(jpeg: &[u8]) -> Option<&[u8]> {
    super::jpeg::segments(jpeg)
        .map_while(Result::ok)
        .take_while(|s| s.marker != 0xDA)
        .find(|s| s.marker == 0xE1 && s.payload().starts_with(EXIF_HEADER))
        .map(|s| s.payload())
}

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("image of {width}×{height} px: {reason}")]
    Size {
        width: u32,
        height: u32,
        reason: &'static str,
    },
    #[error("JPEG quality {0} outside 1..=100")]
    Quality(u8),
    #[error("JPEG encoder: {0}")]
    Jpeg(#[from] jpeg_encoder::EncodingError),
    #[error("PNG encoder: {0}")]
    Png(#[from] png::EncodingError),
}

fn check_rgb(rgb: &[u8], width: u32, height: u32) -> Result<(), ImageError> {
    let size = |reason| ImageError::Size {
        width,
        height,
        reason,
    };
    if width == 0 || height == 0 {
        return Err(size("empty"));
    }
    if rgb.len() as u64 != 3 * width as u64 * height as u64 {
        return Err(size("RGB8 buffer length is not 3 × width × height"));
    }
    Ok(())
}

/// Baseline JPEG (4:2:0) of an RGB8 image, with `app1` (from [`exif_app1`]) inserted.
pub fn encode_jpeg(
    rgb: &[u8],
    width: u32,
    height: u32,
    quality: u8,
    app1: Option<Vec<u8>>,
) -> Result<Vec<u8>, ImageError> {
    check_rgb(rgb, width, height)?;
    if !(1..=100).contains(&quality) {
        return Err(ImageError::Quality(quality));
    }
    let (w, h) = match (u16::try_from(width), u16::try_from(height)) {
        (Ok(w), Ok(h)) => (w, h),
        _ => {
            return Err(ImageError::Size {
                width,
                height,
                reason: "JPEG is limited to 65535 px a side",
            })
        }
    };
    let mut out = Vec::with_capacity(rgb.len() / 8);
    let mut enc = jpeg_encoder::Encoder::new(&mut out, quality);
    if let Some(app1) = app1 {
        enc.add_app_segment(1, app1)?;
    }
    enc.encode(rgb, w, h, jpeg_encoder::ColorType::Rgb)?;
    Ok(out)
}

/// PNG (8-bit RGB) of an RGB8 image; PNG carries no EXIF here, the manifest and
/// `geo.txt` give its position.
pub fn encode_png(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, ImageError> {
    check_rgb(rgb, width, height)?;
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header()?;
    w.write_image_data(rgb)?;
    w.finish()?;
    Ok(out)
}

/// Encodes a captured RGB8 frame. A JPEG carries the EXIF GPS of `gps` when given
/// and valid; an invalid position leaves the image untagged rather than lost.
/// Returns the bytes and whether GPS tags were written.
pub fn encode_capture(
    rgb: &[u8],
    width: u32,
    height: u32,
    format: ImageFormat,
    gps: Option<&ExifGps>,
) -> Result<(Vec<u8>, bool), ImageError> {
    match format {
        ImageFormat::Png => Ok((encode_png(rgb, width, height)?, false)),
        ImageFormat::Jpeg { quality } => {
            let app1 = gps.and_then(|g| exif_app1(g, width, height).ok());
            let tagged = app1.is_some();
            Ok((encode_jpeg(rgb, width, height, quality, app1)?, tagged))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn zurich() -> ExifGps {
        ExifGps {
            lat_deg: 47.397_742_123,
            lon_deg: 8.545_594_987,
            alt_m: 528.125,
            time_unix_us: Some(1_780_123_456_789_000),
            make: "alfd".into(),
            model: "synthetic 64x48".into(),
        }
    }

    #[test]
    fn civil_dates_are_right_at_known_instants() {
        assert_eq!(civil(0), (1970, 1, 1, 0, 0, 0));
        // 2000-02-29T23:59:59.999Z = 951868799.999 s.
        assert_eq!(civil(951_868_799_999_000), (2000, 2, 29, 23, 59, 59_999));
        // 2026-11-22T16:00:00Z = 1795363200 s.
        assert_eq!(civil(1_795_363_200_000_000), (2026, 11, 22, 16, 0, 0));
        for days in [0, 59, 60, 11_016, 20_779, 40_000] {
            let (y, m, d, ..) = civil(days as u64 * 86_400_000_000);
            assert_eq!(days_from_civil(y, m, d), days);
        }
    }

    #[test]
    fn dms_rationals_keep_a_micro_arcsecond() {
        assert_eq!(dms(-33.5), [(33, 1), (30, 1), (0, 1_000_000)]);
        // 59.9999999999 s rounds up into the next minute, never to "60 s".
        let d = dms(10.0 + 59.0 / 60.0 + 59.999_999_999_9 / 3600.0);
        assert_eq!(d, [(11, 1), (0, 1), (0, 1_000_000)]);
    }

    #[test]
    fn app1_reads_back_in_every_hemisphere() {
        for (lat, lon, alt) in [
            (47.397_742_123, 8.545_594_987, 528.125),
            (-33.856_784, 151.215_297, 12.0),
            (-0.000_001, -179.999_999, -27.5),
            (90.0, 180.0, 0.0),
        ] {
            let g = ExifGps {
                lat_deg: lat,
                lon_deg: lon,
                alt_m: alt,
                ..zurich()
            };
            let app1 = exif_app1(&g, 64, 48).unwrap();
            let p = parse_exif_gps(&app1).unwrap();
            assert!((p.lat_deg - lat).abs() < 1e-9, "{} vs {lat}", p.lat_deg);
            assert!((p.lon_deg - lon).abs() < 1e-9, "{} vs {lon}", p.lon_deg);
            assert!((p.alt_m - alt).abs() < 1e-3, "{} vs {alt}", p.alt_m);
        }
    }

    #[test]
    fn app1_carries_time_make_and_model() {
        let app1 = exif_app1(&zurich(), 64, 48).unwrap();
        assert!(app1.len() < 65_533);
        let p = parse_exif_gps(&app1).unwrap();
        assert_eq!(p.gps_time_unix_us, Some(1_780_123_456_789_000));
        assert_eq!(p.make.as_deref(), Some("alfd"));
        assert_eq!(p.model.as_deref(), Some("synthetic 64x48"));
        // 1780123456 s = 2026-05-30T06:44:16Z.
        assert_eq!(p.date_time_original.as_deref(), Some("2026:05:30 06:44:16"));

        let untimed = exif_app1(
            &ExifGps {
                time_unix_us: None,
                ..zurich()
            },
            64,
            48,
        )
        .unwrap();
        let p = parse_exif_gps(&untimed).unwrap();
        assert_eq!((p.gps_time_unix_us, p.date_time_original), (None, None));
    }

    #[test]
    fn no_position_no_tags() {
        for (lat, alt) in [(f64::NAN, 0.0), (91.0, 0.0), (10.0, f64::INFINITY)] {
            let g = ExifGps {
                lat_deg: lat,
                alt_m: alt,
                ..zurich()
            };
            assert!(matches!(
                exif_app1(&g, 64, 48),
                Err(ExifError::BadPosition { .. })
            ));
        }
    }

    #[test]
    fn parser_refuses_garbage_without_panicking() {
        let app1 = exif_app1(&zurich(), 64, 48).unwrap();
        let full = parse_exif_gps(&app1).unwrap();
        // A cut segment is refused, or (cut after everything read) read whole: never a
        // different answer.
        for n in 0..app1.len() {
            if let Ok(p) = parse_exif_gps(&app1[..n]) {
                assert_eq!(p, full, "prefix of {n} bytes");
            }
        }
        assert!(parse_exif_gps(&app1[..app1.len() / 2]).is_err());
        assert!(parse_exif_gps(b"Exif\0\0MM\0\x2A\0\0\0\x08\0\0").is_err());
        assert!(parse_exif_gps(b"JFIF").is_err());
    }

    #[test]
    fn jpeg_holds_the_segment_and_checks_its_input() {
        let (w, h) = (16u32, 8u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        let app1 = exif_app1(&zurich(), 64, 48).unwrap();
        let jpeg = encode_jpeg(&rgb, w, h, 85, Some(app1.clone())).unwrap();
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8]);
        assert_eq!(&jpeg[jpeg.len() - 2..], &[0xFF, 0xD9]);
        assert_eq!(find_exif_app1(&jpeg), Some(&app1[..]));
        assert!(find_exif_app1(&encode_jpeg(&rgb, w, h, 85, None).unwrap()).is_none());
        assert!(matches!(
            encode_jpeg(&rgb, w, h, 0, None),
            Err(ImageError::Quality(0))
        ));
        assert!(encode_jpeg(&rgb[1..], w, h, 80, None).is_err());
        let png = encode_png(&rgb, w, h).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    }

    #[test]
    fn captures_are_tagged_when_they_can_be_and_saved_when_not() {
        let rgb = vec![128u8; 8 * 8 * 3];
        let jpeg = ImageFormat::Jpeg { quality: 90 };
        let (bytes, tagged) = encode_capture(&rgb, 8, 8, jpeg, Some(&zurich())).unwrap();
        assert!(tagged && find_exif_app1(&bytes).is_some());
        let lost = ExifGps {
            lat_deg: f64::NAN,
            ..zurich()
        };
        let (bytes, tagged) = encode_capture(&rgb, 8, 8, jpeg, Some(&lost)).unwrap();
        assert!(!tagged && find_exif_app1(&bytes).is_none());
        assert_eq!(&bytes[..2], &[0xFF, 0xD8]);
        let (png, tagged) = encode_capture(&rgb, 8, 8, ImageFormat::Png, Some(&zurich())).unwrap();
        assert!(!tagged && png.starts_with(b"\x89PNG"));
    }
}
