//! systemd service notification: READY=1, STATUS=…, WATCHDOG=1 and STOPPING=1
//! sent to `$NOTIFY_SOCKET` by the `sd-notify` crate, and the watchdog interval
//! from `$WATCHDOG_USEC`/`$WATCHDOG_PID`. Outside systemd every call is a no-op;
//! a failed send is returned as an error and never panics.
//!
//! The environment is read, not unset (libsystemd's `unset_environment = 0`):
//! alfd spawns no child processes that could inherit it, and changing the
//! environment of a multi-threaded process is unsound. As with libsystemd's
//! `sd_notify`, a send blocks while systemd's queue is full (it holds megabytes).

use sd_notify::NotifyState;
use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// systemd reads notifications into a buffer of this size (`NOTIFY_BUFFER_MAX`,
/// `PIPE_BUF`) and drops larger ones whole, so a long status is cut to fit.
const MESSAGE_MAX_BYTES: usize = 4096;

/// A failure to deliver a notification to systemd.
#[derive(Debug, thiserror::Error)]
pub enum NotifyError {
    /// `$NOTIFY_SOCKET` is not an absolute path: a relative path, or an abstract
    /// (`@…`) or vsock address, which `sd-notify` does not connect to.
    #[error(
        "NOTIFY_SOCKET={0:?} is not an absolute path to systemd's notify socket \
         (systemd passes services one, e.g. /run/systemd/notify; something else in \
         the environment overrode it)"
    )]
    UnsupportedAddress(String),
    /// systemd's socket refused the message (gone, or not permitted).
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
    /// `$NOTIFY_SOCKET`, which `sd-notify` reads itself when sending.
    Path(PathBuf),
    /// Set but not usable: reported on every send rather than ignored.
    Unsupported(String),
}

/// Sends service state to systemd (`Type=notify`) and feeds its watchdog.
///
/// Cheap to clone; each call sends one datagram.
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

    /// The notify socket's path, for messages.
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
        self.send(NotifyState::Ready)
    }

    /// Shutdown has begun (`STOPPING=1`).
    pub fn stopping(&self) -> Result<(), NotifyError> {
        self.send(NotifyState::Stopping)
    }

    /// One line shown by `systemctl status` (`STATUS=…`); line breaks and other
    /// control characters become spaces, and a long text is cut to fit.
    pub fn status(&self, text: &str) -> Result<(), NotifyError> {
        self.send(NotifyState::Status(&status_text(text)))
    }

    /// Feeds the watchdog (`WATCHDOG=1`); call every [`Self::watchdog_interval`].
    pub fn watchdog(&self) -> Result<(), NotifyError> {
        self.send(NotifyState::Watchdog)
    }

    /// How often to feed the watchdog: half of `WATCHDOG_USEC`, as systemd
    /// recommends. `None` when the watchdog is off for this process.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog_timeout.map(|t| t / 2)
    }

    fn send(&self, state: NotifyState) -> Result<(), NotifyError> {
        match &self.target {
            Target::Disabled => Ok(()),
            Target::Unsupported(s) => Err(NotifyError::UnsupportedAddress(s.clone())),
            Target::Path(p) => sd_notify::notify(std::slice::from_ref(&state)).map_err(|source| {
                NotifyError::Send {
                    socket: p.display().to_string(),
                    message: state.to_string(),
                    source,
                }
            }),
        }
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
/// watchdog). Anything malformed turns the watchdog off rather than failing, as
/// libsystemd does; `sd_notify::watchdog_enabled` would instead ignore a
/// malformed `WATCHDOG_PID`, and report `WATCHDOG_USEC=0` as a zero timeout.
fn parse_env(socket: Option<&str>, usec: Option<&str>, pid: Option<&str>, my_pid: u32) -> Notifier {
    let target = match socket {
        None | Some("") => Target::Disabled,
        Some(s) if s.starts_with('/') => Target::Path(PathBuf::from(s)),
        Some(s) => Target::Unsupported(s.to_owned()),
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

/// The text of `STATUS=text\n` on one line (systemd splits messages at
/// newlines, so a newline would inject another assignment), the whole message
/// within [`MESSAGE_MAX_BYTES`].
fn status_text(text: &str) -> String {
    let room = MESSAGE_MAX_BYTES - "STATUS=\n".len();
    let mut out = String::new();
    for c in text.chars() {
        let c = if c.is_control() { ' ' } else { c };
        if out.len() + c.len_utf8() > room {
            break;
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::net::UnixDatagram;
    use std::process::Command;

    /// Set in the child process that [`child`] runs: what it is to send.
    const CHILD: &str = "ALFD_NOTIFY_TEST_CHILD";

    /// Runs [`in_child_process`] in a new process of this test binary with
    /// `NOTIFY_SOCKET=socket`: `sd-notify` reads the socket from the
    /// environment, and setting it in this multi-threaded process would race
    /// the other tests. Panics, with the child's output, if the child failed.
    fn child(socket: &str, what: &str) {
        let out = Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "notify::tests::in_child_process",
                "--test-threads=1",
            ])
            .env("NOTIFY_SOCKET", socket)
            .env(CHILD, what)
            .output()
            .unwrap();
        assert!(
            out.status.success() && String::from_utf8_lossy(&out.stdout).contains("1 passed"),
            "child {what}: {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }

    /// The child's side of [`child`]; does nothing in the test run itself.
    #[test]
    fn in_child_process() {
        let Ok(what) = std::env::var(CHILD) else {
            return;
        };
        let n = Notifier::from_env();
        assert!(n.is_enabled());
        match what.as_str() {
            "states" => {
                n.ready().unwrap();
                n.watchdog().unwrap();
                n.status("capturing: 12 frames").unwrap();
                n.status("link lost\nREADY=1\r\0x").unwrap();
                n.status(&"x".repeat(10_000)).unwrap();
                n.stopping().unwrap();
            }
            "nobody-listens" => {
                let e = n.ready().unwrap_err();
                assert!(matches!(e, NotifyError::Send { .. }), "{e}");
                assert!(e.to_string().contains("READY=1"), "{e}");
                assert!(n.status("x").is_err() && n.stopping().is_err());
            }
            other => panic!("unknown child {other}"),
        }
    }

    #[test]
    fn each_state_is_one_datagram_and_status_cannot_inject_assignments() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notify");
        let sock = UnixDatagram::bind(&path).unwrap();
        // A guard against hanging if nothing arrives, not a wait for it: the
        // child has sent every datagram before it exits.
        sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        child(path.to_str().unwrap(), "states");
        let mut buf = vec![0u8; 2 * MESSAGE_MAX_BYTES];
        let mut received = || {
            let n = sock.recv(&mut buf).unwrap();
            String::from_utf8(buf[..n].to_vec()).unwrap()
        };
        assert_eq!(received(), "READY=1\n");
        assert_eq!(received(), "WATCHDOG=1\n");
        assert_eq!(received(), "STATUS=capturing: 12 frames\n");
        assert_eq!(received(), "STATUS=link lost READY=1  x\n");
        let long = received();
        assert_eq!(long.len(), MESSAGE_MAX_BYTES);
        assert!(long.starts_with("STATUS=xxx") && long.ends_with("x\n"));
        assert_eq!(received(), "STOPPING=1\n");
    }

    #[test]
    fn send_failures_are_errors_not_panics() {
        let dir = tempfile::tempdir().unwrap();
        child(
            dir.path().join("nobody-listens").to_str().unwrap(),
            "nobody-listens",
        );
        // Too long for a socket address.
        child(&format!("/{}", "x".repeat(200)), "nobody-listens");
        for socket in ["run/notify", "@alfd-notify", "vsock:2:1234"] {
            let n = parse_env(Some(socket), None, None, 1);
            assert!(n.is_enabled());
            let e = n.ready().unwrap_err();
            assert!(matches!(e, NotifyError::UnsupportedAddress(_)), "{e}");
            assert!(e.to_string().contains(socket), "{e}");
        }
    }

    #[test]
    fn long_status_is_cut_on_a_char_boundary() {
        let t = status_text(&"é".repeat(MESSAGE_MAX_BYTES));
        let m = format!("STATUS={t}\n");
        assert!(m.len() <= MESSAGE_MAX_BYTES && m.len() > MESSAGE_MAX_BYTES - 2);
        assert!(t.starts_with('é'));
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
