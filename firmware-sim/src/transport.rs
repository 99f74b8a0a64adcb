//! The simulator's side of the wire: one task owns the transport (pty, serial, UDP, TCP or an
//! in-memory stream),
//! writes outgoing frames at their delivery instants, decodes incoming ones, and takes the link
//! down and up again on command (a new pty behind the same symlink; the same port otherwise).
//! The optional ground-station side is a plain UDP socket with no faults and no link loss.

use crate::clock::mono_ns;
use crate::config::Transport;
use crate::pty::{relink, Pty, PtyWriter};
use crate::SimEvent;
use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::{AsyncMavlinkReader, MAVLinkMessageRaw, MavHeader, Message};
use std::io;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, UdpSocket};
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::task::JoinHandle;
use tokio::time::Instant;

pub(crate) struct Outgoing {
    pub at: Instant,
    pub bytes: Vec<u8>,
}

pub(crate) struct Inbound {
    pub mono_ns: u64,
    pub header: MavHeader,
    /// `None` when the CRC holds but the payload does not parse (an enum value this dialect
    /// lacks): such a frame is still forwarded.
    pub msg: Option<MavMessage>,
    /// The frame exactly as it arrived, for forwarding unchanged.
    pub raw: Vec<u8>,
}

pub(crate) enum LinkCtl {
    Down {
        duration: Duration,
        done: oneshot::Sender<u64>,
    },
}

type BoxRead = Box<dyn AsyncRead + Unpin + Send>;

enum Tx {
    Pty(PtyWriter),
    Stream(Box<dyn AsyncWrite + Unpin + Send>),
    Udp(Arc<UdpSocket>, Arc<Mutex<Option<SocketAddr>>>),
}

impl Tx {
    async fn send(&mut self, bytes: &[u8]) -> io::Result<bool> {
        match self {
            Tx::Pty(w) => w.write_frame(bytes).await,
            Tx::Stream(w) => w.write_all(bytes).await.map(|_| true),
            Tx::Udp(s, peer) => {
                let to = *peer.lock().expect("peer lock");
                match to {
                    Some(to) => s.send_to(bytes, to).await.map(|_| true),
                    None => Ok(false),
                }
            }
        }
    }
}

struct Opened {
    tx: Tx,
    rx: BoxRead,
    _pty: Option<Pty>,
}

/// What stays across reopenings: the symlink, the bound address.
struct Endpoint {
    transport: Transport,
    link: Option<PathBuf>,
    bound: Option<SocketAddr>,
    listener: Option<TcpListener>,
    _tmpdir: Option<TempDir>,
    /// The other ends of in-memory streams, one per (re)opening, for whoever plays alfd.
    memory_peers: Option<mpsc::Sender<tokio::io::DuplexStream>>,
}

/// Bytes an in-memory stream buffers each way: about a second of telemetry at 921,600 baud.
const MEMORY_BUFFER: usize = 1 << 17;
/// In-memory streams opened and not yet taken: a reopening beyond this finds its peer
/// dropped (nobody took the last ones; the next reopening offers a fresh one).
const MEMORY_PEERS: usize = 4;

/// A temporary directory removed on drop (for the pty's default symlink).
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn tempdir() -> io::Result<TempDir> {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!(
        "firmware-sim-{}-{n}-{}",
        std::process::id(),
        mono_ns()
    ));
    std::fs::create_dir_all(&dir)?;
    Ok(TempDir(dir))
}

impl Endpoint {
    fn new(transport: Transport) -> io::Result<Self> {
        let mut ep = Endpoint {
            transport,
            link: None,
            bound: None,
            listener: None,
            _tmpdir: None,
            memory_peers: None,
        };
        if let Transport::Pty { link } = &ep.transport {
            ep.link = Some(match link {
                Some(p) => p.clone(),
                None => {
                    let d = tempdir()?;
                    let p = d.0.join("ttyFC");
                    ep._tmpdir = Some(d);
                    p
                }
            });
        }
        Ok(ep)
    }

    /// The address alfd should open.
    fn address(&self) -> String {
        match &self.transport {
            Transport::Pty { .. } => format!(
                "serial:{}:921600",
                self.link.as_ref().expect("pty link").display()
            ),
            Transport::Serial { path, baud } => format!("serial:{}:{baud}", path.display()),
            Transport::Udp { .. } => format!("udpout:{}", self.bound.expect("bound")),
            Transport::Tcp { .. } => format!("tcpout:{}", self.bound.expect("bound")),
            Transport::Memory => "memory".into(),
        }
    }

    /// Make the endpoint reachable (pty and symlink, bound socket, listener, open device).
    async fn prepare(&mut self) -> io::Result<Option<Opened>> {
        match self.transport.clone() {
            Transport::Pty { .. } => {
                let pty = Pty::open()?;
                relink(self.link.as_ref().expect("pty link"), &pty.slave_path)?;
                Ok(Some(Opened {
                    tx: Tx::Pty(pty.writer()),
                    rx: Box::new(pty.reader()),
                    _pty: Some(pty),
                }))
            }
            Transport::Serial { path, baud } => {
                use tokio_serial::SerialPortBuilderExt;
                let port = tokio_serial::new(path.to_string_lossy(), baud).open_native_async()?;
                let (r, w) = tokio::io::split(port);
                Ok(Some(Opened {
                    tx: Tx::Stream(Box::new(w)),
                    rx: Box::new(r),
                    _pty: None,
                }))
            }
            Transport::Udp { bind } => {
                let addr = self.bound.map_or(bind, |a| a.to_string());
                let sock = Arc::new(UdpSocket::bind(&addr).await?);
                self.bound = Some(sock.local_addr()?);
                let peer = Arc::new(Mutex::new(None));
                let (pipe_r, _) = udp_pump(sock.clone(), Some(peer.clone()));
                Ok(Some(Opened {
                    tx: Tx::Udp(sock, peer),
                    rx: Box::new(pipe_r),
                    _pty: None,
                }))
            }
            Transport::Tcp { bind } => {
                let addr = self.bound.map_or(bind, |a| a.to_string());
                let l = TcpListener::bind(&addr).await?;
                self.bound = Some(l.local_addr()?);
                self.listener = Some(l);
                Ok(None)
            }
            Transport::Memory => {
                let (ours, theirs) = tokio::io::duplex(MEMORY_BUFFER);
                if let Some(peers) = &self.memory_peers {
                    // Full or taken away: that end is dropped, and the link reads end-of-file.
                    let _ = peers.try_send(theirs);
                }
                let (r, w) = tokio::io::split(ours);
                Ok(Some(Opened {
                    tx: Tx::Stream(Box::new(w)),
                    rx: Box::new(r),
                    _pty: None,
                }))
            }
        }
    }

    /// The connection, once there is one (TCP waits for a client).
    async fn connect(&mut self, prepared: Option<Opened>) -> io::Result<Opened> {
        if let Some(o) = prepared {
            return Ok(o);
        }
        let l = self.listener.as_ref().expect("tcp listener");
        let (s, _) = l.accept().await?;
        s.set_nodelay(true)?;
        let (r, w) = s.into_split();
        Ok(Opened {
            tx: Tx::Stream(Box::new(w)),
            rx: Box::new(r),
            _pty: None,
        })
    }

    /// Take the endpoint away: for a pty, the symlink goes first, so nobody can open a stale
    /// `/dev/pts/N` that the system may hand to another pty.
    fn close(&mut self) {
        self.listener = None;
        if let Some(link) = &self.link {
            let _ = std::fs::remove_file(link);
        }
    }
}

/// Datagrams from `sock` as a byte stream for the frame decoder; with `peer`, replies follow
/// the last sender.
fn udp_pump(
    sock: Arc<UdpSocket>,
    peer: Option<Arc<Mutex<Option<SocketAddr>>>>,
) -> (tokio::io::DuplexStream, JoinHandle<()>) {
    let (mut pipe_w, pipe_r) = tokio::io::duplex(1 << 16);
    let task = tokio::spawn(async move {
        let mut buf = vec![0u8; 65_536];
        while let Ok((n, from)) = sock.recv_from(&mut buf).await {
            if let Some(p) = &peer {
                *p.lock().expect("peer lock") = Some(from);
            }
            if pipe_w.write_all(&buf[..n]).await.is_err() {
                break;
            }
        }
    });
    (pipe_r, task)
}

fn spawn_reader(rx: BoxRead, inbound: mpsc::Sender<Inbound>) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut reader = AsyncMavlinkReader::new(rx);
        loop {
            // Raw first (CRC checked against the common dialect), so the bytes can be forwarded.
            let Ok(raw) = reader.read_any_raw_message::<MavMessage>().await else {
                return;
            };
            let bytes = match &raw {
                MAVLinkMessageRaw::V1(f) => f.raw_bytes().to_vec(),
                MAVLinkMessageRaw::V2(f) => f.raw_bytes().to_vec(),
            };
            let m = Inbound {
                mono_ns: mono_ns(),
                header: MavHeader {
                    system_id: raw.system_id(),
                    component_id: raw.component_id(),
                    sequence: raw.sequence(),
                },
                msg: MavMessage::parse(raw.version(), raw.message_id(), raw.payload()).ok(),
                raw: bytes,
            };
            if inbound.send(m).await.is_err() {
                return;
            }
        }
    })
}

/// The ground-station port: a UDP socket sending to the station's address (`udpout:`, the
/// station listens) and decoding whatever datagrams come back. The engine sends with
/// `try_send_to` (UDP never waits long); the tasks stop when this is dropped.
pub(crate) struct GcsLink {
    sock: Arc<UdpSocket>,
    to: SocketAddr,
    pub inbound: mpsc::Receiver<Inbound>,
    pump: JoinHandle<()>,
    reader: JoinHandle<()>,
}

impl GcsLink {
    /// `address` is `udpout:HOST:PORT` (checked by the config).
    pub(crate) async fn open(address: &str) -> io::Result<GcsLink> {
        let host_port = address.strip_prefix("udpout:").unwrap_or(address);
        let to = tokio::net::lookup_host(host_port)
            .await?
            .next()
            .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, "no address"))?;
        let local: SocketAddr = match to {
            SocketAddr::V4(a) if a.ip().is_loopback() => (*a.ip(), 0).into(),
            SocketAddr::V4(_) => ([0, 0, 0, 0], 0).into(),
            SocketAddr::V6(_) => (std::net::Ipv6Addr::UNSPECIFIED, 0).into(),
        };
        let sock = Arc::new(UdpSocket::bind(local).await?);
        let (pipe_r, pump) = udp_pump(sock.clone(), None);
        let (in_tx, inbound) = mpsc::channel(512);
        let reader = spawn_reader(Box::new(pipe_r), in_tx);
        Ok(GcsLink {
            sock,
            to,
            inbound,
            pump,
            reader,
        })
    }

    /// Send one frame now; false if it could not go (nobody listening is not an error for UDP).
    pub(crate) fn send(&self, bytes: &[u8]) -> bool {
        self.sock.try_send_to(bytes, self.to).is_ok()
    }
}

impl Drop for GcsLink {
    fn drop(&mut self) {
        self.pump.abort();
        self.reader.abort();
    }
}

pub(crate) struct LinkIo {
    pub out: mpsc::Sender<Outgoing>,
    pub inbound: mpsc::Receiver<Inbound>,
    pub ctl: mpsc::Sender<LinkCtl>,
    pub address: String,
    pub link_path: Option<PathBuf>,
    pub task: JoinHandle<()>,
    /// The in-memory streams' other ends ([`Transport::Memory`]).
    pub memory_peers: Option<mpsc::Receiver<tokio::io::DuplexStream>>,
}

/// Open the endpoint and start the task that owns it.
pub(crate) async fn start(
    transport: Transport,
    events: broadcast::Sender<SimEvent>,
) -> io::Result<LinkIo> {
    let mut ep = Endpoint::new(transport)?;
    let memory_peers = matches!(ep.transport, Transport::Memory).then(|| {
        let (tx, rx) = mpsc::channel(MEMORY_PEERS);
        ep.memory_peers = Some(tx);
        rx
    });
    let first = ep.prepare().await?;
    let address = ep.address();
    let link_path = ep.link.clone();
    let (out_tx, out_rx) = mpsc::channel(512);
    let (in_tx, in_rx) = mpsc::channel(512);
    let (ctl_tx, ctl_rx) = mpsc::channel(8);
    let _ = events.send(SimEvent::LinkUp { mono_ns: mono_ns() });
    let task = tokio::spawn(run(ep, first, out_rx, in_tx, ctl_rx, events));
    Ok(LinkIo {
        out: out_tx,
        inbound: in_rx,
        ctl: ctl_tx,
        address,
        link_path,
        task,
        memory_peers,
    })
}

async fn run(
    mut ep: Endpoint,
    mut prepared: Option<Opened>,
    mut out: mpsc::Receiver<Outgoing>,
    inbound: mpsc::Sender<Inbound>,
    mut ctl: mpsc::Receiver<LinkCtl>,
    events: broadcast::Sender<SimEvent>,
) {
    loop {
        // Wait for a connection, discarding what is sent meanwhile (nobody is listening).
        let conn = {
            let connect = ep.connect(prepared.take());
            tokio::pin!(connect);
            loop {
                tokio::select! {
                    biased;
                    c = &mut connect => break c,
                    o = out.recv() => if o.is_none() { return },
                    c = ctl.recv() => match c {
                        None => return,
                        Some(LinkCtl::Down { done, .. }) => { let _ = done.send(mono_ns()); }
                    },
                }
            }
        };
        let Ok(Opened { mut tx, rx, _pty }) = conn else {
            tokio::time::sleep(Duration::from_millis(100)).await;
            prepared = ep.prepare().await.ok().flatten();
            continue;
        };
        let mut reader = spawn_reader(rx, inbound.clone());
        let mut reader_done = false;
        let down = loop {
            tokio::select! {
                biased;
                o = out.recv() => {
                    let Some(o) = o else { reader.abort(); return };
                    // Only sleep for a real delay: tokio's timer rounds up to the next
                    // millisecond, which would bias every reply by half a millisecond.
                    if o.at > Instant::now() {
                        tokio::time::sleep_until(o.at).await;
                    }
                    if tx.send(&o.bytes).await.is_err() { break None; }
                }
                c = ctl.recv() => match c {
                    None => { reader.abort(); return }
                    Some(LinkCtl::Down { duration, done }) => break Some((duration, done)),
                },
                _ = &mut reader => {
                    reader_done = true;
                    break None;
                }
            }
        };
        if !reader_done {
            reader.abort();
            let _ = reader.await;
        }
        ep.close();
        drop((tx, _pty));
        if let Some((duration, done)) = down {
            let t = mono_ns();
            let _ = events.send(SimEvent::LinkDown { mono_ns: t });
            let _ = done.send(t);
            let until = Instant::now() + duration;
            loop {
                tokio::select! {
                    biased;
                    _ = tokio::time::sleep_until(until) => break,
                    o = out.recv() => if o.is_none() { return },
                }
            }
        }
        loop {
            match ep.prepare().await {
                Ok(p) => {
                    prepared = p;
                    break;
                }
                Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        }
        let _ = events.send(SimEvent::LinkUp { mono_ns: mono_ns() });
    }
}
