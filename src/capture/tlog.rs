//! `telemetry.tlog`, the ground stations' telemetry log: each entry is the UNIX time
//! in microseconds (8 bytes, big-endian) followed by one MAVLink frame exactly as
//! received. Encoding and parsing are pure; [`TlogWriter`] appends through a store.

use super::store::{CaptureStore, StoreError};

const STX_V1: u8 = 0xFE;
const STX_V2: u8 = 0xFD;
const SIGNATURE_LEN: usize = 13;
/// MAVLink 2 incompatibility flags: signed, and the 32-bit system id extension
/// rust-mavlink reads (three more header bytes).
const IFLAG_SIGNED: u8 = 0x01;
const IFLAG_SYSID32: u8 = 0x02;
const SYSID32_EXTRA: usize = 3;
/// Timestamp + the longest frame (signed MAVLink 2, 32-bit system id, 255-byte payload).
const MAX_ENTRY_LEN: usize = 8 + 12 + SYSID32_EXTRA + 255 + SIGNATURE_LEN;

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum TlogError {
    #[error("{len} bytes are not one complete MAVLink v1/v2 frame")]
    NotAFrame { len: usize },
    #[error("tlog truncated at byte {offset}")]
    Truncated { offset: usize },
    #[error("no MAVLink start byte at byte {offset} (found {found:#04x})")]
    BadStart { offset: usize, found: u8 },
}

/// Length of the MAVLink frame that starts `bytes`, from its header alone (v1:
/// 8 + payload; v2: 12 + payload, + 13 when signed, + 3 with a 32-bit system
/// id); `None` if it does not start with a start byte or the header is incomplete.
pub fn frame_len(bytes: &[u8]) -> Option<usize> {
    match *bytes {
        [STX_V1, len, ..] => Some(8 + len as usize),
        [STX_V2, len, incompat, ..] => Some(
            12 + len as usize
                + if incompat & IFLAG_SIGNED != 0 {
                    SIGNATURE_LEN
                } else {
                    0
                }
                + if incompat & IFLAG_SYSID32 != 0 {
                    SYSID32_EXTRA
                } else {
                    0
                },
        ),
        _ => None,
    }
}

/// Appends one entry to `out`.
pub fn encode_entry(unix_us: u64, frame: &[u8], out: &mut Vec<u8>) {
    out.extend_from_slice(&unix_us.to_be_bytes());
    out.extend_from_slice(frame);
}

/// One tlog entry, borrowing its frame from the parsed bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TlogEntry<'a> {
    pub unix_us: u64,
    pub frame: &'a [u8],
}

/// Splits `bytes` into the entries it holds, plus the error at the first byte that
/// does not begin a complete entry (`None` when the whole input was read).
pub fn parse(bytes: &[u8]) -> (Vec<TlogEntry<'_>>, Option<TlogError>) {
    let mut entries = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        match entry_at(bytes, at) {
            Ok((entry, next)) => {
                entries.push(entry);
                at = next;
            }
            Err(e) => return (entries, Some(e)),
        }
    }
    (entries, None)
}

/// How much of a tlog to keep before appending: all of it, less a last entry cut
/// short by an interrupted append. Bytes that do not parse elsewhere are kept (not
/// ours to destroy), and the new entries go after them.
pub fn complete_prefix_len(bytes: &[u8]) -> usize {
    match parse(bytes).1 {
        // Shorter than the longest entry: a cut append, not a garbled length byte.
        Some(TlogError::Truncated { offset }) if bytes.len() - offset < MAX_ENTRY_LEN => offset,
        _ => bytes.len(),
    }
}

fn entry_at(bytes: &[u8], at: usize) -> Result<(TlogEntry<'_>, usize), TlogError> {
    let rest = &bytes[at..];
    if rest.len() < 8 + 3 {
        return Err(TlogError::Truncated { offset: at });
    }
    let unix_us = u64::from_be_bytes(rest[..8].try_into().expect("8 bytes"));
    let frame = &rest[8..];
    let len = frame_len(frame).ok_or(TlogError::BadStart {
        offset: at + 8,
        found: frame[0],
    })?;
    if frame.len() < len {
        return Err(TlogError::Truncated { offset: at });
    }
    Ok((
        TlogEntry {
            unix_us,
            frame: &frame[..len],
        },
        at + 8 + len,
    ))
}

/// Appends received frames to the store's telemetry log and syncs it whenever
/// `sync_interval_us` of log time has passed since the last sync (time is the
/// entries' own, so replay and tests are deterministic). Call [`TlogWriter::sync`]
/// at shutdown.
#[derive(Debug)]
pub struct TlogWriter<S> {
    store: S,
    sync_interval_us: u64,
    last_sync_us: Option<u64>,
    unsynced: bool,
    buf: Vec<u8>,
}

#[derive(Debug, thiserror::Error)]
pub enum TlogWriteError {
    #[error(transparent)]
    Frame(#[from] TlogError),
    #[error(transparent)]
    Store(#[from] StoreError),
}

impl<S: CaptureStore> TlogWriter<S> {
    pub fn new(store: S, sync_interval_us: u64) -> Self {
        TlogWriter {
            store,
            sync_interval_us,
            last_sync_us: None,
            unsynced: false,
            buf: Vec::with_capacity(8 + 280),
        }
    }

    /// Logs one frame received at `unix_us`. A frame that is not exactly one
    /// complete MAVLink frame is refused: it would make the rest of the log unreadable.
    pub fn write(&mut self, unix_us: u64, frame: &[u8]) -> Result<(), TlogWriteError> {
        if frame_len(frame) != Some(frame.len()) {
            return Err(TlogError::NotAFrame { len: frame.len() }.into());
        }
        self.buf.clear();
        encode_entry(unix_us, frame, &mut self.buf);
        self.store.append_telemetry(&self.buf)?;
        self.unsynced = true;
        let last = *self.last_sync_us.get_or_insert(unix_us);
        if unix_us.saturating_sub(last) >= self.sync_interval_us {
            self.sync_at(unix_us)?;
        }
        Ok(())
    }

    /// Makes everything written so far durable.
    pub fn sync(&mut self) -> Result<(), StoreError> {
        if self.unsynced {
            self.store.sync_telemetry()?;
            self.unsynced = false;
        }
        Ok(())
    }

    fn sync_at(&mut self, unix_us: u64) -> Result<(), StoreError> {
        self.sync()?;
        self.last_sync_us = Some(unix_us);
        Ok(())
    }

    pub fn store_mut(&mut self) -> &mut S {
        &mut self.store
    }

    pub fn store(&self) -> &S {
        &self.store
    }

    pub fn into_inner(self) -> S {
        self.store
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lengths_from_headers() {
        assert_eq!(frame_len(&[0xFE, 9, 0]), Some(17));
        assert_eq!(frame_len(&[0xFD, 9, 0]), Some(21));
        assert_eq!(frame_len(&[0xFD, 9, 1]), Some(34));
        assert_eq!(frame_len(&[0xFD, 9]), None);
        assert_eq!(frame_len(&[0x55, 9, 0]), None);
    }

    #[test]
    fn entries_round_trip_and_a_torn_tail_is_reported() {
        let v1 = [&[0xFE, 2][..], &[0; 4], &[7, 8], &[0xAA, 0xBB]].concat();
        let v2 = [&[0xFD, 1, 0][..], &[0; 7], &[9], &[0xCC, 0xDD]].concat();
        let mut bytes = Vec::new();
        encode_entry(1_700_000_000_000_001, &v1, &mut bytes);
        encode_entry(1_700_000_000_100_000, &v2, &mut bytes);
        assert_eq!(&bytes[..8], &1_700_000_000_000_001u64.to_be_bytes());
        let whole = bytes.len();
        encode_entry(1_700_000_000_200_000, &v2, &mut bytes);
        bytes.truncate(bytes.len() - 3);
        let (entries, err) = parse(&bytes);
        assert_eq!(
            entries,
            [
                TlogEntry {
                    unix_us: 1_700_000_000_000_001,
                    frame: &v1
                },
                TlogEntry {
                    unix_us: 1_700_000_000_100_000,
                    frame: &v2
                }
            ]
        );
        assert_eq!(err, Some(TlogError::Truncated { offset: whole }));
        assert_eq!(complete_prefix_len(&bytes), whole);
        let mut garbled = bytes[..whole].to_vec();
        garbled[8] = 0x00;
        assert_eq!(complete_prefix_len(&garbled), whole, "not ours to cut");
    }
}
