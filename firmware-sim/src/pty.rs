//! A pseudo-terminal pair in raw mode. The simulator owns the master (non-blocking, in tokio)
//! and keeps its own slave descriptor open so the master never reads EIO while nobody is
//! attached; a stable symlink points at the current slave path, replaced atomically on reopen.

use std::io;
use std::os::fd::OwnedFd;
use std::os::unix::ffi::OsStrExt;
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

impl Pty {
    /// Open a raw pty pair.
    pub fn open() -> io::Result<Pty> {
        use rustix::pty::{grantpt, openpt, ptsname, unlockpt, OpenptFlags};
        let master = openpt(OpenptFlags::RDWR | OpenptFlags::NOCTTY | OpenptFlags::CLOEXEC)?;
        grantpt(&master)?;
        unlockpt(&master)?;
        let slave_path = PathBuf::from(std::ffi::OsStr::from_bytes(
            ptsname(&master, Vec::new())?.as_bytes(),
        ));
        let slave: OwnedFd = rustix::fs::open(
            &slave_path,
            rustix::fs::OFlags::RDWR | rustix::fs::OFlags::NOCTTY | rustix::fs::OFlags::CLOEXEC,
            rustix::fs::Mode::empty(),
        )?;
        for fd in [&master, &slave] {
            let mut t = rustix::termios::tcgetattr(fd)?;
            t.make_raw();
            rustix::termios::tcsetattr(fd, rustix::termios::OptionalActions::Now, &t)?;
        }
        let flags = rustix::fs::fcntl_getfl(&master)?;
        rustix::fs::fcntl_setfl(&master, flags | rustix::fs::OFlags::NONBLOCK)?;
        // SAFETY: the master descriptor is valid, non-blocking, and owned by the AsyncFd until dropped.
        let master = unsafe { AsyncFd::register(master)? };
        Ok(Pty {
            master: Arc::new(master),
            _slave: slave,
            slave_path,
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
            let res = guard.try_io(|fd| Ok(rustix::io::read(fd.get_ref(), &mut *unfilled)?));
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
            let res = guard.try_io(|fd| Ok(rustix::io::write(fd.get_ref(), &bytes[off..])?));
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
