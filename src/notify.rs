//! systemd service notification (the sd_notify protocol) without libsystemd:
//! one datagram per state change to `$NOTIFY_SOCKET`, and the watchdog interval
//! from `$WATCHDOG_USEC`/`$WATCHDOG_PID`. Outside systemd every call is a no-op;
//! a failed send is returned as an error and never panics.
//!
//! The environment is read, not unset (libsystemd's `unset_environment = 0`):
//! alfd spawns no child processes that could inherit it, and changing the
//! environment of a multi-threaded process is unsound.

use std::io;
use std::os::linux::net::SocketAddrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// systemd reads notifications into a buffer of this size (`NOTIFY_BUFFER_MAX`,
/// `PIPE_BUF`) and drops larger ones whole, so a long status is cut to fit.
const MESSAGE_MAX_BYTES: usize = 4096;

/// A failure to deliver a notification to systemd.
#[derive(Debug, thiserror::Error)]
pub enum NotifyError {
    /// `$NOTIFY_SOCKET` names neither a path (`/…`) nor an abstract socket (`@…`).
    #[error(
        "NOTIFY_SOCKET={0:?} is neither an absolute path nor an abstract socket name (@name); \
         systemd sets it itself, so something else in the environment overrode it"
    )]
    UnsupportedAddress(String),
    /// The address is well formed but not usable as a socket address (e.g. too long).
    #[error("notify socket {socket}: invalid address: {source}")]
    Address {
        socket: String,
        #[source]
        source: io::Error,
    },
    /// The datagram socket could not be created.
    #[error("cannot create a datagram socket to notify systemd: {0}")]
    Socket(#[source] io::Error),
    /// systemd's socket refused the message (gone, full, or not permitted).
    #[error("cannot send {message:?} to the systemd notify socket {socket}: {source}")]
    Send {
        socket: String,
        message: String,
        #[source]
        source: io::Error,
    },
}

/// Where notifications go.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Target {
    /// Not started by systemd (or with notification off): every call is a no-op.
    Disabled,
    Path(PathBuf),
    /// The name after the `@`, without the leading NUL of the kernel address.
    Abstract(Vec<u8>),
    /// Set but not understood: reported on every send rather than ignored.
    Unsupported(String),
}

/// Sends service state to systemd (`Type=notify`) and feeds its watchdog.
///
/// Cheap to clone; each call opens a non-blocking socket, so a send never
/// stalls the daemon (a full systemd queue comes back as an error).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Notifier {
    target: Target,
    /// `WATCHDOG_USEC`: systemd restarts the service if not fed within this.
    watchdog_timeout: Option<Duration>,
}

impl Notifier {
    /// The notifier described by this process's environment: `NOTIFY_SOCKET`,
    /// `WATCHDOG_USEC` and `WATCHDOG_PID`. Never fails: outside systemd (or with
    /// values that are not valid UTF-8) it does nothing.
    pub fn from_env() -> Self {
        let var = |name| std::env::var_os(name).and_then(|v| v.into_string().ok());
        let (socket, usec, pid) = (
            var("NOTIFY_SOCKET"),
            var("WATCHDOG_USEC"),
            var("WATCHDOG_PID"),
        );
        parse_env(
            socket.as_deref(),
            usec.as_deref(),
            pid.as_deref(),
            std::process::id(),
        )
    }

    /// A notifier sending to the datagram socket at `path`, with no watchdog.
    pub fn with_socket(path: impl Into<PathBuf>) -> Self {
        Notifier {
            target: Target::Path(path.into()),
            watchdog_timeout: None,
        }
    }

    /// A notifier that does nothing, as outside systemd.
    pub fn disabled() -> Self {
        Notifier {
            target: Target::Disabled,
            watchdog_timeout: None,
        }
    }

    /// The same notifier with the watchdog on, as with `WATCHDOG_USEC=timeout`.
    pub fn with_watchdog(mut self, timeout: Duration) -> Self {
        self.watchdog_timeout = (!timeout.is_zero()).then_some(timeout);
        self
    }

    /// The socket's path when it is a file (not abstract), for messages.
    pub fn socket_path(&self) -> Option<&Path> {
        match &self.target {
            Target::Path(p) => Some(p),
            _ => None,
        }
    }

    /// Whether notifications go anywhere (that is, alfd runs under systemd).
    pub fn is_enabled(&self) -> bool {
        self.target != Target::Disabled
    }

    /// Start-up is finished: systemd marks the unit active (`READY=1`).
    pub fn ready(&self) -> Result<(), NotifyError> {
        self.send("READY=1")
    }

    /// Shutdown has begun (`STOPPING=1`).
    pub fn stopping(&self) -> Result<(), NotifyError> {
        self.send("STOPPING=1")
    }

    /// One line shown by `systemctl status` (`STATUS=…`); line breaks and other
    /// control characters become spaces, and a long text is cut to fit.
    pub fn status(&self, text: &str) -> Result<(), NotifyError> {
        self.send(&status_message(text))
    }

    /// Feeds the watchdog (`WATCHDOG=1`); call every [`Self::watchdog_interval`].
    pub fn watchdog(&self) -> Result<(), NotifyError> {
        self.send("WATCHDOG=1")
    }

    /// How often to feed the watchdog: half of `WATCHDOG_USEC`, as systemd
    /// recommends. `None` when the watchdog is off for this process.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog_timeout.map(|t| t / 2)
    }

    fn send(&self, message: &str) -> Result<(), NotifyError> {
        let (addr, socket) = match &self.target {
            Target::Disabled => return Ok(()),
            Target::Unsupported(s) => return Err(NotifyError::UnsupportedAddress(s.clone())),
            Target::Path(p) => (SocketAddr::from_pathname(p), p.display().to_string()),
            Target::Abstract(name) => (
                SocketAddr::from_abstract_name(name),
                format!("@{}", String::from_utf8_lossy(name)),
            ),
        };
        let addr = addr.map_err(|source| NotifyError::Address {
            socket: socket.clone(),
            source,
        })?;
        let sock = UnixDatagram::unbound().map_err(NotifyError::Socket)?;
        sock.set_nonblocking(true).map_err(NotifyError::Socket)?;
        // A datagram is sent whole or not at all, so a short count cannot happen.
        sock.send_to_addr(message.as_bytes(), &addr)
            .map(drop)
            .map_err(|source| NotifyError::Send {
                socket,
                message: message.to_owned(),
                source,
            })
    }
}

impl Default for Notifier {
    fn default() -> Self {
        Notifier::disabled()
    }
}

/// The notifier for these environment values, as `sd_notify` and
/// `sd_watchdog_enabled` read them; `my_pid` is this process's id.
///
/// The watchdog is on when `usec` is a positive integer and `pid`, if set, is
/// `my_pid` (systemd sets it so that children do not feed the parent's
/// watchdog). Anything malformed turns the watchdog off rather than failing.
fn parse_env(socket: Option<&str>, usec: Option<&str>, pid: Option<&str>, my_pid: u32) -> Notifier {
    let target = match socket {
        None | Some("") => Target::Disabled,
        Some(s) if s.starts_with('/') => Target::Path(PathBuf::from(s)),
        Some(s) => match s.strip_prefix('@') {
            Some(name) => Target::Abstract(name.as_bytes().to_vec()),
            None => Target::Unsupported(s.to_owned()),
        },
    };
    let for_us = match pid {
        None => true,
        Some(p) => p.parse::<u32>().is_ok_and(|p| p == my_pid),
    };
    let watchdog_timeout = usec
        .and_then(|u| u.parse::<u64>().ok())
        .filter(|&u| u > 0 && for_us)
        .map(Duration::from_micros);
    Notifier {
        target,
        watchdog_timeout,
    }
}

/// `STATUS=text` on one line (systemd splits messages at newlines, so a newline
/// would inject another assignment), within [`MESSAGE_MAX_BYTES`].
fn status_message(text: &str) -> String {
    let mut message = String::from("STATUS=");
    for c in text.chars() {
        let c = if c.is_control() { ' ' } else { c };
        if message.len() + c.len_utf8() > MESSAGE_MAX_BYTES {
            break;
        }
        message.push(c);
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU32, Ordering};

    /// A socket standing in for systemd's, bound in a fresh directory.
    fn listener() -> (tempfile::TempDir, PathBuf, UnixDatagram) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notify");
        let sock = UnixDatagram::bind(&path).unwrap();
        // A guard against hanging if nothing arrives, not a wait for it: the
        // datagram is queued before `send` returns.
        sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        (dir, path, sock)
    }

    fn received(sock: &UnixDatagram) -> String {
        let mut buf = vec![0u8; 2 * MESSAGE_MAX_BYTES];
        let n = sock.recv(&mut buf).unwrap();
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    #[test]
    fn each_state_is_one_datagram() {
        let (_dir, path, sock) = listener();
        let n = Notifier::with_socket(&path);
        assert!(n.is_enabled());
        n.ready().unwrap();
        assert_eq!(received(&sock), "READY=1");
        n.watchdog().unwrap();
        assert_eq!(received(&sock), "WATCHDOG=1");
        n.status("capturing: 12 frames").unwrap();
        assert_eq!(received(&sock), "STATUS=capturing: 12 frames");
        n.stopping().unwrap();
        assert_eq!(received(&sock), "STOPPING=1");
    }

    #[test]
    fn status_cannot_inject_assignments() {
        let (_dir, path, sock) = listener();
        Notifier::with_socket(&path)
            .status("link lost\nREADY=1\r\0x")
            .unwrap();
        assert_eq!(received(&sock), "STATUS=link lost READY=1  x");
    }

    #[test]
    fn long_status_is_cut_on_a_char_boundary() {
        let m = status_message(&"é".repeat(MESSAGE_MAX_BYTES));
        assert!(m.len() <= MESSAGE_MAX_BYTES && m.len() > MESSAGE_MAX_BYTES - 2);
        assert!(m.starts_with("STATUS=é"));
        let (_dir, path, sock) = listener();
        Notifier::with_socket(&path)
            .status(&"x".repeat(10_000))
            .unwrap();
        assert_eq!(received(&sock).len(), MESSAGE_MAX_BYTES);
    }

    #[test]
    fn abstract_socket_from_env() {
        static SEQ: AtomicU32 = AtomicU32::new(0);
        let name = format!(
            "alfd-notify-test-{}-{}",
            std::process::id(),
            SEQ.fetch_add(1, Ordering::Relaxed)
        );
        let sock =
            UnixDatagram::bind_addr(&SocketAddr::from_abstract_name(&name).unwrap()).unwrap();
        sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let n = parse_env(Some(&format!("@{name}")), None, None, 1);
        n.ready().unwrap();
        assert_eq!(received(&sock), "READY=1");
    }

    #[test]
    fn outside_systemd_nothing_is_sent() {
        for socket in [None, Some("")] {
            let n = parse_env(socket, Some("5000000"), None, 1);
            assert!(!n.is_enabled());
            n.ready().unwrap();
            n.status("x").unwrap();
            n.watchdog().unwrap();
            n.stopping().unwrap();
        }
        assert!(!Notifier::default().is_enabled());
    }

    #[test]
    fn send_failures_are_errors_not_panics() {
        let dir = tempfile::tempdir().unwrap();
        let gone = Notifier::with_socket(dir.path().join("nobody-listens"));
        assert!(matches!(gone.ready(), Err(NotifyError::Send { .. })));
        let relative = parse_env(Some("run/notify"), None, None, 1);
        assert!(relative.is_enabled());
        let e = relative.ready().unwrap_err();
        assert!(matches!(e, NotifyError::UnsupportedAddress(_)));
        assert!(e.to_string().contains("run/notify"));
        let too_long = Notifier::with_socket(format!("/{}", "x".repeat(200)));
        assert!(matches!(too_long.ready(), Err(NotifyError::Address { .. })));
    }

    #[test]
    fn watchdog_interval_is_half_the_timeout() {
        let n = parse_env(Some("/run/systemd/notify"), Some("5000000"), None, 42);
        assert_eq!(n.watchdog_interval(), Some(Duration::from_millis(2500)));
        let n = parse_env(Some("/run/systemd/notify"), Some("5000000"), Some("42"), 42);
        assert_eq!(n.watchdog_interval(), Some(Duration::from_millis(2500)));
        assert_eq!(n.socket_path(), Some(Path::new("/run/systemd/notify")));
        // 1 µs still gives a non-zero period (a zero one makes timers panic).
        let n = parse_env(None, Some("1"), None, 42);
        assert_eq!(n.watchdog_interval(), Some(Duration::from_nanos(500)));
    }

    #[test]
    fn watchdog_for_another_process_is_off() {
        let n = parse_env(Some("/run/systemd/notify"), Some("5000000"), Some("41"), 42);
        assert_eq!(n.watchdog_interval(), None);
    }

    #[test]
    fn malformed_watchdog_values_turn_it_off() {
        for (usec, pid) in [
            (None, None),
            (Some(""), None),
            (Some("0"), None),
            (Some("-5000000"), None),
            (Some("5s"), None),
            (Some("5000000.0"), None),
            (Some("99999999999999999999999"), None),
            (Some("5000000"), Some("")),
            (Some("5000000"), Some("forty-two")),
            (Some("5000000"), Some("-42")),
        ] {
            let n = parse_env(Some("/run/systemd/notify"), usec, pid, 42);
            assert_eq!(n.watchdog_interval(), None, "usec {usec:?} pid {pid:?}");
        }
    }

    #[test]
    fn with_watchdog_matches_the_environment() {
        let n = Notifier::disabled().with_watchdog(Duration::from_secs(5));
        assert_eq!(n.watchdog_interval(), Some(Duration::from_millis(2500)));
        assert_eq!(
            Notifier::disabled()
                .with_watchdog(Duration::ZERO)
                .watchdog_interval(),
            None
        );
    }
}
