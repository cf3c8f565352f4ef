//! A pseudo-terminal pair, so that host code using `serialport` opens the sim exactly as it
//! would open a board: `serialport::new(pty.path(), 921_600).open()`.
//!
//! The sim keeps the master side; [`PtyBridge::pump`] moves bytes between it and a
//! [`LinkEnd`] each tick, so a world run with `WorldConfig::pace = Some(1.0)` (real time) can
//! put the PTY on its host link.
use crate::link::LinkEnd;
use serialport::{SerialPort, TTYPort};
use std::io::{Read, Write};

/// Both sides of a PTY. The slave stays open (unlocked, so host code can still open it
/// exclusively) so that the master never sees a hung-up line between host connections.
pub struct Pty {
    master: TTYPort,
    _slave: TTYPort,
    path: String,
}

impl Pty {
    /// Opens a new pseudo-terminal.
    pub fn open() -> anyhow::Result<Pty> {
        let (mut master, slave) = TTYPort::pair()?;
        let path = slave.name().ok_or_else(|| anyhow::anyhow!("the PTY has no path"))?;
        master.set_timeout(std::time::Duration::from_millis(0))?;
        Ok(Pty { master, _slave: slave, path })
    }

    /// The device path host code opens, e.g. `/dev/pts/3`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The sim's side.
    pub fn master(&mut self) -> &mut TTYPort {
        &mut self.master
    }

    /// Bytes waiting on the sim's side, without blocking.
    pub fn read_available(&mut self) -> std::io::Result<Vec<u8>> {
        let n = self.master.bytes_to_read().map_err(std::io::Error::from)? as usize;
        let mut buf = vec![0u8; n];
        if n > 0 {
            self.master.read_exact(&mut buf)?;
        }
        Ok(buf)
    }

    /// Writes all of `bytes` to the pseudo-terminal.
    pub fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.master.write_all(bytes)?;
        self.master.flush()
    }
}

/// Copies between a PTY and a simulated link end.
pub struct PtyBridge {
    /// The pseudo-terminal.
    pub pty: Pty,
    /// Bytes carried from the pseudo-terminal to the link.
    pub to_link: u64,
    /// Bytes carried from the link to the pseudo-terminal.
    pub to_pty: u64,
}

impl PtyBridge {
    /// A bridge over `pty` with zero counts.
    pub fn new(pty: Pty) -> PtyBridge {
        PtyBridge { pty, to_link: 0, to_pty: 0 }
    }

    /// Moves what the PTY peer wrote onto the link (at the end's time) and what arrived on the
    /// link out to the PTY peer.
    pub fn pump(&mut self, end: &mut LinkEnd) -> std::io::Result<()> {
        let inbound = self.pty.read_available()?;
        if !inbound.is_empty() {
            self.to_link += inbound.len() as u64;
            end.send(&inbound);
        }
        let outbound = end.receive();
        if !outbound.is_empty() {
            self.to_pty += outbound.len() as u64;
            self.pty.write_all(&outbound)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
