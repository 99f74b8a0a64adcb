//! The capture log's I/O edge: where images, manifest lines, exports and telemetry go.
//! Invariant: a manifest line is appended only after the image it names is durably in
//! place, and a failed append leaves no partial line, so after any failure every
//! line in the manifest is complete JSON and every image it lists exists.

use std::collections::BTreeMap;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};

use super::record::{is_image_name_for, CaptureRecord};
use super::tlog;

/// The manifest's file name in a flight directory.
pub const MANIFEST: &str = "manifest.jsonl";
/// The raw telemetry's file name in a flight directory.
pub const TELEMETRY: &str = "telemetry.tlog";

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    /// No space left (ENOSPC, or the quota, EDQUOT): stop capturing, keep flying.
    #[error("{}: storage full", path.display())]
    Full { path: PathBuf },
    #[error(
        "refusing file name {name:?}: only plain names of [A-Za-z0-9_.-] not starting with '.'"
    )]
    BadName { name: String },
    #[error("{}: already exists; one writer per flight directory, sequence numbers never reused", path.display())]
    Exists { path: PathBuf },
    /// Another process holds the flight directory (a daemon still writing it).
    #[error("{}: in use by another process (one writer per flight directory)", path.display())]
    InUse { path: PathBuf },
    #[error("a manifest line must not contain a newline")]
    BadLine,
}

/// Where a capture log goes. Implementations: [`DirStore`] (a directory on disk),
/// [`MemStore`] (memory, for tests), [`FillingStore`] (fills up after N bytes).
pub trait CaptureStore {
    /// Writes a new image atomically (all or nothing, durable once `Ok`); refuses
    /// to replace an existing one.
    fn write_image(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError>;
    /// Appends `line` and a newline to the manifest, durable once `Ok`; on error
    /// nothing of it remains.
    fn append_manifest_line(&mut self, line: &str) -> Result<(), StoreError>;
    /// Writes (or replaces) an export atomically.
    fn write_export(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError>;
    /// Appends raw bytes to the telemetry log, not synced (see [`Self::sync_telemetry`]);
    /// on error nothing of them remains.
    fn append_telemetry(&mut self, bytes: &[u8]) -> Result<(), StoreError>;
    fn sync_telemetry(&mut self) -> Result<(), StoreError>;
    /// Bytes still available for the log, when known.
    fn free_bytes(&self) -> Option<u64>;
    /// The size of the storage the log is on, when known (STORAGE_INFORMATION's total).
    fn total_bytes(&self) -> Option<u64> {
        None
    }
    /// The manifest as stored (read back for the exports at the end of a run).
    fn manifest_bytes(&self) -> Result<Vec<u8>, StoreError>;
}

/// A store behind a reference or a box is the store itself.
macro_rules! forward_store {
    ($($ty:ty),*) => {$(
        impl<S: CaptureStore + ?Sized> CaptureStore for $ty {
            fn write_image(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
                (**self).write_image(name, bytes)
            }
            fn append_manifest_line(&mut self, line: &str) -> Result<(), StoreError> {
                (**self).append_manifest_line(line)
            }
            fn write_export(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
                (**self).write_export(name, bytes)
            }
            fn append_telemetry(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
                (**self).append_telemetry(bytes)
            }
            fn sync_telemetry(&mut self) -> Result<(), StoreError> {
                (**self).sync_telemetry()
            }
            fn free_bytes(&self) -> Option<u64> {
                (**self).free_bytes()
            }
            fn total_bytes(&self) -> Option<u64> {
                (**self).total_bytes()
            }
            fn manifest_bytes(&self) -> Result<Vec<u8>, StoreError> {
                (**self).manifest_bytes()
            }
        }
    )*};
}

forward_store!(&mut S, Box<S>);

/// Names are ours (derived from sequence numbers or fixed), never received strings;
/// this keeps a bug from writing outside the directory or over a temporary file.
pub fn check_name(name: &str) -> Result<(), StoreError> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(StoreError::BadName { name: name.into() })
    }
}

/// Exports may be replaced, so they must not be named like the append-only logs.
fn check_export_name(name: &str) -> Result<(), StoreError> {
    check_name(name)?;
    if name == MANIFEST || name == TELEMETRY {
        return Err(StoreError::BadName { name: name.into() });
    }
    Ok(())
}

fn check_line(line: &str) -> Result<(), StoreError> {
    if line.contains(['\n', '\r']) {
        Err(StoreError::BadLine)
    } else {
        Ok(())
    }
}

/// Maps ENOSPC and EDQUOT to [`StoreError::Full`], the rest to [`StoreError::Io`].
pub fn io_error(path: &Path, source: io::Error) -> StoreError {
    let full = source.kind() == io::ErrorKind::StorageFull
        || matches!(
            rustix::io::Errno::from_io_error(&source),
            Some(rustix::io::Errno::NOSPC | rustix::io::Errno::DQUOT)
        );
    if full {
        StoreError::Full { path: path.into() }
    } else {
        StoreError::Io {
            path: path.into(),
            source,
        }
    }
}

/// A file that is only ever appended to, with the length of its durable content.
trait Tail {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    fn sync_data(&mut self) -> io::Result<()>;
    fn set_len(&mut self, len: u64) -> io::Result<()>;
}

impl Tail for File {
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        Write::write_all(self, bytes)
    }
    fn sync_data(&mut self) -> io::Result<()> {
        File::sync_data(self)
    }
    fn set_len(&mut self, len: u64) -> io::Result<()> {
        File::set_len(self, len)
    }
}

/// Appends `bytes`; on any error truncates back to `*len` so that no partial
/// record stays behind (a short write on ENOSPC would otherwise leave half a line).
fn append_or_roll_back<T: Tail>(
    file: &mut T,
    len: &mut u64,
    bytes: &[u8],
    sync: bool,
) -> io::Result<()> {
    let res = file
        .write_all(bytes)
        .and_then(|()| if sync { file.sync_data() } else { Ok(()) });
    match res {
        Ok(()) => {
            *len += bytes.len() as u64;
            Ok(())
        }
        Err(e) => {
            // Best effort: if even this fails the reader still tolerates a torn tail.
            let _ = file.set_len(*len).and_then(|()| file.sync_data());
            Err(e)
        }
    }
}

/// One flight's directory on disk, held by an exclusive lock (`flock` on the
/// directory) while the store lives: a second writer, or `alfd export` while the
/// daemon writes, is refused instead of removing the temporaries of images in flight.
#[derive(Debug)]
pub struct DirStore {
    dir: PathBuf,
    /// The directory, open for its lock only; the kernel releases it with the
    /// process, so a crashed daemon leaves none behind.
    _lock: File,
    manifest: File,
    manifest_len: u64,
    telemetry: File,
    telemetry_len: u64,
    recovered_bytes: u64,
}

impl DirStore {
    /// Opens (creating it if needed) a flight directory. Left-over temporary files
    /// of an interrupted write are removed, and a torn last manifest line or tlog
    /// entry (a crash mid-append) is cut off, so new appends start on a boundary.
    pub fn open(dir: impl Into<PathBuf>) -> Result<DirStore, StoreError> {
        let dir = dir.into();
        fs::create_dir_all(&dir).map_err(|e| io_error(&dir, e))?;
        let lock = File::open(&dir).map_err(|e| io_error(&dir, e))?;
        match rustix::fs::flock(&lock, rustix::fs::FlockOperation::NonBlockingLockExclusive) {
            Ok(()) => {}
            Err(rustix::io::Errno::WOULDBLOCK) => return Err(StoreError::InUse { path: dir }),
            // A filesystem without locks still takes captures: the lock is a guard
            // against a second writer, not a condition of writing; but the
            // operator hears that the guard is off.
            Err(e) => tracing::warn!(
                "{}: the filesystem takes no lock ({e}): a second alfd, or alfd export, on this flight would not be refused",
                dir.display()
            ),
        }
        let entries = fs::read_dir(&dir).map_err(|e| io_error(&dir, e))?;
        for entry in entries {
            let entry = entry.map_err(|e| io_error(&dir, e))?;
            let name = entry.file_name();
            let name = name.to_string_lossy();
            if name.starts_with('.') && name.ends_with(".tmp") {
                let p = entry.path();
                fs::remove_file(&p).map_err(|e| io_error(&p, e))?;
            }
        }
        let (manifest, manifest_len, cut_m) = open_tail(&dir.join(MANIFEST), |b| {
            b.iter().rposition(|&c| c == b'\n').map_or(0, |i| i + 1)
        })?;
        let (telemetry, telemetry_len, cut_t) =
            open_tail(&dir.join(TELEMETRY), tlog::complete_prefix_len)?;
        sync_dir(&dir)?;
        Ok(DirStore {
            dir,
            _lock: lock,
            manifest,
            manifest_len,
            telemetry,
            telemetry_len,
            recovered_bytes: cut_m + cut_t,
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn manifest_path(&self) -> PathBuf {
        self.dir.join(MANIFEST)
    }

    /// Bytes of torn tails cut off when the directory was opened (0 after a clean stop).
    pub fn recovered_bytes(&self) -> u64 {
        self.recovered_bytes
    }

    fn write_atomic(&self, name: &str, bytes: &[u8], replace: bool) -> Result<(), StoreError> {
        check_name(name)?;
        let path = self.dir.join(name);
        if !replace && path.exists() {
            return Err(StoreError::Exists { path });
        }
        let tmp = self.dir.join(format!(".{name}.tmp"));
        let written = File::create(&tmp).and_then(|mut f| {
            Write::write_all(&mut f, bytes)?;
            f.sync_all()
        });
        if let Err(e) = written {
            let _ = fs::remove_file(&tmp);
            return Err(io_error(&tmp, e));
        }
        fs::rename(&tmp, &path).map_err(|e| {
            let _ = fs::remove_file(&tmp);
            io_error(&path, e)
        })?;
        sync_dir(&self.dir)
    }
}

/// Opens an append-only file, cutting it to `keep(content)` bytes.
fn open_tail(path: &Path, keep: impl Fn(&[u8]) -> usize) -> Result<(File, u64, u64), StoreError> {
    let mut file = OpenOptions::new()
        .create(true)
        .append(true)
        .read(true)
        .open(path)
        .map_err(|e| io_error(path, e))?;
    let mut content = Vec::new();
    file.read_to_end(&mut content)
        .map_err(|e| io_error(path, e))?;
    let keep = keep(&content) as u64;
    let cut = content.len() as u64 - keep;
    if cut > 0 {
        file.set_len(keep)
            .and_then(|()| file.sync_data())
            .map_err(|e| io_error(path, e))?;
    }
    Ok((file, keep, cut))
}

fn sync_dir(dir: &Path) -> Result<(), StoreError> {
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| io_error(dir, e))
}

impl CaptureStore for DirStore {
    fn write_image(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.write_atomic(name, bytes, false)
    }

    fn append_manifest_line(&mut self, line: &str) -> Result<(), StoreError> {
        check_line(line)?;
        let mut buf = Vec::with_capacity(line.len() + 1);
        buf.extend_from_slice(line.as_bytes());
        buf.push(b'\n');
        append_or_roll_back(&mut self.manifest, &mut self.manifest_len, &buf, true)
            .map_err(|e| io_error(&self.dir.join(MANIFEST), e))
    }

    fn write_export(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        check_export_name(name)?;
        self.write_atomic(name, bytes, true)
    }

    fn append_telemetry(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        append_or_roll_back(&mut self.telemetry, &mut self.telemetry_len, bytes, false)
            .map_err(|e| io_error(&self.dir.join(TELEMETRY), e))
    }

    fn sync_telemetry(&mut self) -> Result<(), StoreError> {
        self.telemetry
            .sync_data()
            .map_err(|e| io_error(&self.dir.join(TELEMETRY), e))
    }

    fn free_bytes(&self) -> Option<u64> {
        let s = rustix::fs::statvfs(&self.dir).ok()?;
        Some(s.f_bavail.saturating_mul(s.f_frsize))
    }
    fn total_bytes(&self) -> Option<u64> {
        let s = rustix::fs::statvfs(&self.dir).ok()?;
        Some(s.f_blocks.saturating_mul(s.f_frsize))
    }
    fn manifest_bytes(&self) -> Result<Vec<u8>, StoreError> {
        let p = self.manifest_path();
        fs::read(&p).map_err(|e| io_error(&p, e))
    }
}

/// A capture log in memory, for tests of the code that writes one.
#[derive(Debug, Default, Clone)]
pub struct MemStore {
    pub images: BTreeMap<String, Vec<u8>>,
    pub exports: BTreeMap<String, Vec<u8>>,
    pub manifest: Vec<u8>,
    pub telemetry: Vec<u8>,
    /// Length of `telemetry` at the last sync.
    pub telemetry_synced: usize,
    pub telemetry_syncs: usize,
}

impl CaptureStore for MemStore {
    fn write_image(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        check_name(name)?;
        if self.images.contains_key(name) {
            return Err(StoreError::Exists { path: name.into() });
        }
        self.images.insert(name.into(), bytes.to_vec());
        Ok(())
    }

    fn append_manifest_line(&mut self, line: &str) -> Result<(), StoreError> {
        check_line(line)?;
        self.manifest.extend_from_slice(line.as_bytes());
        self.manifest.push(b'\n');
        Ok(())
    }

    fn write_export(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        check_export_name(name)?;
        self.exports.insert(name.into(), bytes.to_vec());
        Ok(())
    }

    fn append_telemetry(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        self.telemetry.extend_from_slice(bytes);
        Ok(())
    }

    fn sync_telemetry(&mut self) -> Result<(), StoreError> {
        self.telemetry_synced = self.telemetry.len();
        self.telemetry_syncs += 1;
        Ok(())
    }

    fn free_bytes(&self) -> Option<u64> {
        None
    }
    fn manifest_bytes(&self) -> Result<Vec<u8>, StoreError> {
        Ok(self.manifest.clone())
    }
}

/// Wraps a store and fails with [`StoreError::Full`] once `capacity` bytes have been
/// written through it, as a filling disk does: the write that does not fit leaves
/// nothing behind (what [`DirStore`] guarantees by renaming and rolling back).
#[derive(Debug)]
pub struct FillingStore<S> {
    pub inner: S,
    capacity: u64,
    used: u64,
}

impl<S: CaptureStore> FillingStore<S> {
    pub fn new(inner: S, capacity_bytes: u64) -> Self {
        FillingStore {
            inner,
            capacity: capacity_bytes,
            used: 0,
        }
    }

    pub fn used_bytes(&self) -> u64 {
        self.used
    }

    /// Runs `write` if `n` more bytes fit; bytes of a write the inner store refused
    /// are not counted.
    fn within(
        &mut self,
        name: &str,
        n: usize,
        write: impl FnOnce(&mut S) -> Result<(), StoreError>,
    ) -> Result<(), StoreError> {
        let n = n as u64;
        if self.used + n > self.capacity {
            return Err(StoreError::Full { path: name.into() });
        }
        write(&mut self.inner)?;
        self.used += n;
        Ok(())
    }
}

impl<S: CaptureStore> CaptureStore for FillingStore<S> {
    fn write_image(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.within(name, bytes.len(), |s| s.write_image(name, bytes))
    }
    fn append_manifest_line(&mut self, line: &str) -> Result<(), StoreError> {
        self.within(MANIFEST, line.len() + 1, |s| s.append_manifest_line(line))
    }
    fn write_export(&mut self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.within(name, bytes.len(), |s| s.write_export(name, bytes))
    }
    fn append_telemetry(&mut self, bytes: &[u8]) -> Result<(), StoreError> {
        self.within(TELEMETRY, bytes.len(), |s| s.append_telemetry(bytes))
    }
    fn sync_telemetry(&mut self) -> Result<(), StoreError> {
        self.inner.sync_telemetry()
    }
    fn free_bytes(&self) -> Option<u64> {
        let left = self.capacity - self.used;
        Some(self.inner.free_bytes().map_or(left, |f| f.min(left)))
    }
    fn total_bytes(&self) -> Option<u64> {
        Some(self.capacity)
    }
    fn manifest_bytes(&self) -> Result<Vec<u8>, StoreError> {
        self.inner.manifest_bytes()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error(transparent)]
    Store(#[from] StoreError),
    /// A bug in the caller, not a storage condition: the record and the bytes disagree.
    #[error("capture {seq}: {what}")]
    Mismatch { seq: u64, what: &'static str },
}

/// Logs one capture: the image first (atomically), then its manifest line. If
/// either fails the capture is not in the manifest; an image without a line may
/// remain (harmless: the manifest is the index).
pub fn log_capture<S: CaptureStore + ?Sized>(
    store: &mut S,
    record: &CaptureRecord,
    image: Option<&[u8]>,
) -> Result<(), LogError> {
    let seq = record.seq;
    match (&record.image, image) {
        (Some(name), Some(bytes)) => {
            if !is_image_name_for(name, seq) {
                return Err(LogError::Mismatch {
                    seq,
                    what: "image name not derived from the sequence number",
                });
            }
            store.write_image(name, bytes)?;
        }
        (None, None) => {}
        (Some(_), None) => {
            return Err(LogError::Mismatch {
                seq,
                what: "record names an image but no bytes were given",
            })
        }
        (None, Some(_)) => {
            return Err(LogError::Mismatch {
                seq,
                what: "image bytes given for a record without an image name",
            })
        }
    }
    store.append_manifest_line(&record.to_json_line())?;
    Ok(())
}

/// What a manifest held, and what in it could not be read.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Manifest {
    pub records: Vec<CaptureRecord>,
    /// Bytes after the last newline: a line torn by a crash mid-append (0 normally).
    pub torn_tail_bytes: usize,
    /// Complete lines that are not a valid record: (1-based line number, error).
    pub bad_lines: Vec<(usize, String)>,
}

/// Parses manifest content; never fails: a torn last line and bad lines are reported.
pub fn parse_manifest(bytes: &[u8]) -> Manifest {
    let complete = bytes.iter().rposition(|&c| c == b'\n').map_or(0, |i| i + 1);
    let mut m = Manifest {
        torn_tail_bytes: bytes.len() - complete,
        ..Manifest::default()
    };
    for (i, line) in bytes[..complete]
        .split_inclusive(|&c| c == b'\n')
        .enumerate()
    {
        let line = &line[..line.len() - 1];
        let parsed = std::str::from_utf8(line)
            .map_err(|e| e.to_string())
            .and_then(|s| CaptureRecord::from_json_line(s).map_err(|e| e.to_string()));
        match parsed {
            Ok(r) => m.records.push(r),
            Err(e) => m.bad_lines.push((i + 1, e)),
        }
    }
    m
}

/// Reads a manifest file; fails only when the file cannot be read.
pub fn read_manifest(path: &Path) -> Result<Manifest, StoreError> {
    let bytes = fs::read(path).map_err(|e| io_error(path, e))?;
    Ok(parse_manifest(&bytes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::record::tests::sample;

    /// A tail that accepts `room` bytes, then fails like a full disk (after a short write).
    struct ShortDisk {
        data: Vec<u8>,
        room: usize,
    }

    impl Tail for ShortDisk {
        fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
            let n = bytes.len().min(self.room.saturating_sub(self.data.len()));
            self.data.extend_from_slice(&bytes[..n]);
            if n < bytes.len() {
                return Err(io::Error::from(io::ErrorKind::StorageFull));
            }
            Ok(())
        }
        fn sync_data(&mut self) -> io::Result<()> {
            Ok(())
        }
        fn set_len(&mut self, len: u64) -> io::Result<()> {
            self.data.truncate(len as usize);
            Ok(())
        }
    }

    #[test]
    fn a_short_write_is_rolled_back_to_the_last_complete_line() {
        let mut disk = ShortDisk {
            data: Vec::new(),
            room: 30,
        };
        let mut len = 0;
        append_or_roll_back(&mut disk, &mut len, b"first line\n", true).unwrap();
        let e = append_or_roll_back(&mut disk, &mut len, b"second line is too long\n", true)
            .unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::StorageFull);
        assert_eq!(disk.data, b"first line\n");
        assert_eq!(len, 11);
        assert!(matches!(
            io_error(Path::new("m"), e),
            StoreError::Full { .. }
        ));
    }

    #[test]
    fn enospc_and_edquot_map_to_full_other_errors_to_io() {
        for errno in [rustix::io::Errno::NOSPC, rustix::io::Errno::DQUOT] {
            let e = io::Error::from_raw_os_error(errno.raw_os_error());
            assert!(matches!(
                io_error(Path::new("x"), e),
                StoreError::Full { .. }
            ));
        }
        let e = io::Error::from_raw_os_error(rustix::io::Errno::ACCESS.raw_os_error());
        assert!(matches!(io_error(Path::new("x"), e), StoreError::Io { .. }));
    }

    #[test]
    fn names_outside_the_plain_set_are_refused() {
        for bad in ["", ".hidden", "../x", "a/b", "a b", "x\n", "é.jpg"] {
            assert!(check_name(bad).is_err(), "{bad:?}");
        }
        check_name("IMG_000001.jpg").unwrap();
        check_name("transforms.json").unwrap();
    }

    #[test]
    fn filling_store_refuses_what_does_not_fit_and_keeps_nothing_of_it() {
        let mut s = FillingStore::new(MemStore::default(), 10);
        s.write_image("IMG_000001.png", b"123456").unwrap();
        assert!(matches!(
            s.write_image("IMG_000002.png", b"12345"),
            Err(StoreError::Full { .. })
        ));
        // A write the inner store refuses costs nothing.
        assert!(matches!(
            s.write_image("IMG_000001.png", b"1"),
            Err(StoreError::Exists { .. })
        ));
        assert_eq!((s.used_bytes(), s.free_bytes()), (6, Some(4)));
        assert!(matches!(
            s.append_manifest_line("1234"),
            Err(StoreError::Full { .. })
        ));
        s.append_manifest_line("123").unwrap();
        assert_eq!(s.inner.manifest, b"123\n");
        assert_eq!(s.inner.images.len(), 1);
        assert!(matches!(
            s.write_export(MANIFEST, b""),
            Err(StoreError::BadName { .. })
        ));
    }

    #[test]
    fn parse_reports_a_torn_tail_and_bad_lines_without_failing() {
        let mut bytes = Vec::new();
        for seq in 1..=3 {
            bytes.extend_from_slice(sample(seq).to_json_line().as_bytes());
            bytes.push(b'\n');
        }
        bytes.extend_from_slice(b"{\"not\":\"a record\"}\n");
        let whole = sample(4).to_json_line();
        bytes.extend_from_slice(&whole.as_bytes()[..whole.len() / 2]);
        let m = parse_manifest(&bytes);
        assert_eq!(
            m.records.iter().map(|r| r.seq).collect::<Vec<_>>(),
            [1, 2, 3]
        );
        assert_eq!(m.torn_tail_bytes, whole.len() / 2);
        assert_eq!(m.bad_lines.len(), 1);
        assert_eq!(m.bad_lines[0].0, 4);
        assert_eq!(parse_manifest(b""), Manifest::default());
    }

    #[test]
    fn log_capture_refuses_records_and_bytes_that_disagree() {
        let mut s = MemStore::default();
        let mut r = sample(5);
        assert!(matches!(
            log_capture(&mut s, &r, None),
            Err(LogError::Mismatch { .. })
        ));
        r.image = Some("IMG_000006.jpg".into());
        assert!(matches!(
            log_capture(&mut s, &r, Some(b"x")),
            Err(LogError::Mismatch { .. })
        ));
        r.image = None;
        assert!(log_capture(&mut s, &r, Some(b"x")).is_err());
        log_capture(&mut s, &r, None).unwrap();
        assert!(s.images.is_empty());
        assert_eq!(parse_manifest(&s.manifest).records, [r]);
    }
}
