//! The two serial links: framing over `embedded_io` byte streams, face-frame reassembly and the
//! watchdogs. The board ([`crate::board`]) uses these; they hold no policy of their own.

use embedded_io::{Read, ReadReady, Write};
use msr_shared::blob::MAX_FACE_PIXELS;
use msr_shared::frame::{encode_message, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::msg::FrameHeader;
use serde::Serialize;

/// Face watchdog: no complete face frame for this long -> hold still and report.
pub const FACE_TIMEOUT_US: u64 = 500_000;
/// Servo watchdog: no servo state for this long -> stop streaming and report.
pub const SERVO_TIMEOUT_US: u64 = 100_000;
/// Bytes read from one link per read call.
pub const READ_CHUNK: usize = 64;

/// Receiving side of one link.
pub type Rx = FrameAccumulator<MAX_WIRE_FRAME>;

/// Sending side of one link: sequence numbers and write failures.
#[derive(Debug, Default)]
pub struct Tx {
    seq: u16,
    /// Messages that could not be encoded or written.
    pub failures: u32,
}

impl Tx {
    pub const fn new() -> Self {
        Tx {
            seq: 0,
            failures: 0,
        }
    }

    /// Frames and writes one message; a failure is counted, never fatal.
    pub fn send<W: Write, T: Serialize>(&mut self, io: &mut W, msg: &T) -> bool {
        let mut wire = [0u8; MAX_WIRE_FRAME];
        let seq = self.seq;
        self.seq = seq.wrapping_add(1);
        let ok = match encode_message(seq, msg, &mut wire) {
            Ok(n) => io.write_all(&wire[..n]).is_ok(),
            Err(_) => false,
        };
        if !ok {
            self.failures = self.failures.saturating_add(1);
        }
        ok
    }
}

/// Reads what has arrived, without blocking: 0 when nothing is ready or on an error.
pub fn read_ready<R: Read + ReadReady>(io: &mut R, buf: &mut [u8]) -> usize {
    match io.read_ready() {
        Ok(true) => io.read(buf).unwrap_or(0),
        _ => 0,
    }
}

/// A watchdog over "something arrived recently".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Watchdog {
    period_us: u64,
    last_us: Option<u64>,
    tripped: bool,
    pub trips: u32,
}

impl Watchdog {
    pub const fn new(period_us: u64) -> Self {
        Watchdog {
            period_us,
            last_us: None,
            tripped: false,
            trips: 0,
        }
    }

    /// Something arrived. Returns true when this ends a trip.
    pub fn feed(&mut self, now_us: u64) -> bool {
        self.last_us = Some(now_us);
        core::mem::replace(&mut self.tripped, false)
    }

    /// Returns true once, when the period passes without a feed. Armed by the first feed.
    pub fn check(&mut self, now_us: u64) -> bool {
        match self.last_us {
            Some(t) if !self.tripped && now_us.saturating_sub(t) >= self.period_us => {
                self.tripped = true;
                self.trips = self.trips.saturating_add(1);
                true
            }
            _ => false,
        }
    }

    pub fn tripped(&self) -> bool {
        self.tripped
    }

    /// Has anything ever arrived?
    pub fn armed(&self) -> bool {
        self.last_us.is_some()
    }

    pub fn last_us(&self) -> Option<u64> {
        self.last_us
    }
}

/// Why a frame chunk was refused; the frame in progress is dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AssemblyError {
    /// Size differs from the model's face, or larger than the buffer.
    Size,
    /// A chunk for no frame or another frame, out of order, or past the end.
    Chunk,
}

/// Collects a face image from its chunks.
pub struct Assembly {
    header: Option<FrameHeader>,
    received: usize,
    buf: [u8; MAX_FACE_PIXELS],
}

impl Default for Assembly {
    fn default() -> Self {
        Self::new()
    }
}

impl Assembly {
    pub const fn new() -> Self {
        Assembly {
            header: None,
            received: 0,
            buf: [0; MAX_FACE_PIXELS],
        }
    }

    /// Drops any frame in progress.
    pub fn clear(&mut self) {
        self.header = None;
        self.received = 0;
    }

    /// `FrameStart`: the image must be `face_w x face_h`.
    pub fn start(&mut self, h: FrameHeader, face_w: u16, face_h: u16) -> Result<(), AssemblyError> {
        self.clear();
        let n = h.width as usize * h.height as usize;
        if h.width != face_w || h.height != face_h || n == 0 || n > MAX_FACE_PIXELS {
            return Err(AssemblyError::Size);
        }
        self.header = Some(h);
        Ok(())
    }

    /// `FrameChunk`: in order, no gaps. Returns the header once the image is complete.
    pub fn chunk(
        &mut self,
        frame: u16,
        offset: u16,
        data: &[u8],
    ) -> Result<Option<FrameHeader>, AssemblyError> {
        let Some(h) = self.header else {
            return Err(AssemblyError::Chunk);
        };
        let n = h.width as usize * h.height as usize;
        let end = offset as usize + data.len();
        if frame != h.frame || offset as usize != self.received || end > n {
            self.clear();
            return Err(AssemblyError::Chunk);
        }
        self.buf[offset as usize..end].copy_from_slice(data);
        self.received = end;
        if end == n {
            self.header = None;
            self.received = 0;
            return Ok(Some(h));
        }
        Ok(None)
    }

    /// The pixels of the frame just completed.
    pub fn pixels(&self, h: &FrameHeader) -> &[u8] {
        let n = (h.width as usize * h.height as usize).min(MAX_FACE_PIXELS);
        &self.buf[..n]
    }
}
