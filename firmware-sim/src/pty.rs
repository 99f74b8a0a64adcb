//! A pseudo-terminal pair in raw mode. The simulator owns the master (non-blocking, in tokio)
//! and keeps its own slave descriptor open so the master never reads EIO while nobody is
//! attached; a stable symlink points at the current slave path, replaced atomically on reopen.

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{ready, Context, Poll};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, ReadBuf};

pub struct Pty {
    master: Arc<AsyncFd<OwnedFd>>,
    _slave: OwnedFd,
    pub slave_path: PathBuf,
}

fn cvt(r: libc::c_int) -> io::Result<libc::c_int> {
    if r < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(r)
    }
}

impl Pty {
    /// Open a raw pty pair.
    pub fn open() -> io::Result<Pty> {
        let (mut m, mut s): (RawFd, RawFd) = (-1, -1);
        let mut name = [0 as libc::c_char; 128];
        // SAFETY: openpty writes two descriptors and a NUL-terminated name into buffers we own
        // (128 bytes is above the kernel's pts name length); termios and winsize may be null.
        cvt(unsafe {
            libc::openpty(
                &mut m,
                &mut s,
                name.as_mut_ptr(),
                std::ptr::null(),
                std::ptr::null(),
            )
        })?;
        // SAFETY: both descriptors were just returned by openpty and are owned by nobody else.
        let (master, slave) = unsafe { (OwnedFd::from_raw_fd(m), OwnedFd::from_raw_fd(s)) };
        // SAFETY: `name` is NUL-terminated by openpty.
        let slave_path = unsafe { std::ffi::CStr::from_ptr(name.as_ptr()) }
            .to_string_lossy()
            .into_owned();
        for fd in [master.as_raw_fd(), slave.as_raw_fd()] {
            let mut t = std::mem::MaybeUninit::<libc::termios>::uninit();
            // SAFETY: tcgetattr fills the termios on success, checked before assume_init.
            cvt(unsafe { libc::tcgetattr(fd, t.as_mut_ptr()) })?;
            let mut t = unsafe { t.assume_init() };
            // SAFETY: cfmakeraw only edits the struct; tcsetattr reads it.
            unsafe { libc::cfmakeraw(&mut t) };
            cvt(unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) })?;
        }
        // SAFETY: plain fcntl flag update on a descriptor we own.
        let flags = cvt(unsafe { libc::fcntl(master.as_raw_fd(), libc::F_GETFL) })?;
        cvt(unsafe { libc::fcntl(master.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK) })?;
        // SAFETY: the master descriptor is valid, non-blocking, and owned by the AsyncFd until dropped.
        let master = unsafe { AsyncFd::register(master)? };
        Ok(Pty {
            master: Arc::new(master),
            _slave: slave,
            slave_path: slave_path.into(),
        })
    }

    pub fn reader(&self) -> PtyReader {
        PtyReader(self.master.clone())
    }

    pub fn writer(&self) -> PtyWriter {
        PtyWriter(self.master.clone())
    }
}

/// Point `link` at `target`, atomically (a new symlink renamed over the old one).
pub fn relink(link: &Path, target: &Path) -> io::Result<()> {
    let tmp = link.with_extension(format!("tmp{}", std::process::id()));
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(target, &tmp)?;
    std::fs::rename(&tmp, link)
}

pub struct PtyReader(Arc<AsyncFd<OwnedFd>>);

impl AsyncRead for PtyReader {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.0.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let res = guard.try_io(|fd| {
                // SAFETY: reads at most `unfilled.len()` bytes into memory we borrow mutably.
                let n = unsafe {
                    libc::read(fd.as_raw_fd(), unfilled.as_mut_ptr().cast(), unfilled.len())
                };
                if n < 0 {
                    Err(io::Error::last_os_error())
                } else {
                    Ok(n as usize)
                }
            });
            match res {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

pub struct PtyWriter(Arc<AsyncFd<OwnedFd>>);

impl PtyWriter {
    /// Write one whole frame, or nothing when the pty's buffer is full (nobody reading): like a
    /// UART, bytes nobody takes are lost. Returns whether the frame went out.
    pub async fn write_frame(&self, bytes: &[u8]) -> io::Result<bool> {
        let mut off = 0;
        while off < bytes.len() {
            let mut guard = self.0.writable().await?;
            let res = guard.try_io(|fd| {
                let rest = &bytes[off..];
                // SAFETY: writes from a slice we borrow.
                let n = unsafe { libc::write(fd.as_raw_fd(), rest.as_ptr().cast(), rest.len()) };
                if n < 0 {
                    Err(io::Error::last_os_error())
                } else {
                    Ok(n as usize)
                }
            });
            match res {
                Ok(Ok(n)) => off += n,
                Ok(Err(e)) => return Err(e),
                Err(_would_block) if off == 0 => return Ok(false),
                Err(_would_block) => continue,
            }
        }
        Ok(true)
    }
}
