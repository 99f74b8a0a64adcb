//! What the link talks through: a rust-mavlink connection (serial, UDP, TCP), or an in-memory
//! byte stream to firmware-sim in the same process. The second is for `alfd sim` on simulated
//! time: the runtime's paused clock jumps ahead whenever every task waits, and bytes in a
//! kernel pty or socket would be in flight, unseen, while it jumped. A stream in memory wakes
//! its reader the moment it is written, so the simulation repeats exactly.

use mavlink::dialects::ardupilotmega::MavMessage;
use mavlink::error::{MessageReadError, MessageWriteError};
use mavlink::{
    AsyncConnection, AsyncMavConnection, AsyncMavlinkReader, MAVLinkMessageRaw, MavHeader,
    MavlinkVersion,
};
use tokio::io::{DuplexStream, ReadHalf, WriteHalf};
use tokio::sync::Mutex;

/// One connection's wire.
pub(crate) enum Wire {
    Mav(AsyncConnection<MavMessage>),
    Memory(MemoryWire),
}

/// An in-memory stream: frames of either version read, frames written in `version` with
/// the link's own sequence numbers (rust-mavlink's connections number theirs likewise).
pub(crate) struct MemoryWire {
    reader: Mutex<AsyncMavlinkReader<ReadHalf<DuplexStream>>>,
    writer: Mutex<(WriteHalf<DuplexStream>, u8)>,
    version: MavlinkVersion,
}

impl MemoryWire {
    pub(crate) fn new(stream: DuplexStream, version: MavlinkVersion) -> Self {
        let (r, w) = tokio::io::split(stream);
        MemoryWire {
            reader: Mutex::new(AsyncMavlinkReader::new(r)),
            writer: Mutex::new((w, 0)),
            version,
        }
    }
}

impl Wire {
    pub(crate) async fn recv_raw(&self) -> Result<MAVLinkMessageRaw, MessageReadError> {
        match self {
            Wire::Mav(c) => c.recv_raw().await,
            Wire::Memory(m) => {
                m.reader
                    .lock()
                    .await
                    .read_any_raw_message::<MavMessage>()
                    .await
            }
        }
    }

    pub(crate) async fn send(
        &self,
        header: &MavHeader,
        msg: &MavMessage,
    ) -> Result<usize, MessageWriteError> {
        match self {
            Wire::Mav(c) => c.send(header, msg).await,
            Wire::Memory(m) => {
                let mut w = m.writer.lock().await;
                let header = MavHeader {
                    sequence: w.1,
                    ..*header
                };
                w.1 = w.1.wrapping_add(1);
                mavlink::write_versioned_msg_async(&mut w.0, m.version, header, msg).await
            }
        }
    }
}
