//! The two serial links: framing over `embedded_io` byte streams, face-frame reassembly and the
//! watchdogs. The board ([`crate::board`]) uses these; they hold no policy of their own.

use embedded_io::{Read, ReadReady, Write};
use msr_shared::blob::CRC32;
use msr_shared::frame::{encode_message, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::msg::{is_older, ChunkSet, FrameAck, FrameHeader, FrameState, MAX_FRAME_BYTES};
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
    /// A sender starting at sequence number 0; `const`, so it can live in a `static`.
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
    /// Times the period passed without a feed.
    pub trips: u32,
}

impl Watchdog {
    /// A watchdog that trips when `period_us` passes without a feed; unarmed until the first feed.
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

    /// Tripped and not fed since.
    pub fn tripped(&self) -> bool {
        self.tripped
    }

    /// Has anything ever arrived?
    pub fn armed(&self) -> bool {
        self.last_us.is_some()
    }

    /// When the last feed came (board time, microseconds), `None` before the first.
    pub fn last_us(&self) -> Option<u64> {
        self.last_us
    }
}

/// Why a face-frame message was refused; the frame in progress is kept.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AssemblyError {
    /// Size differs from the model's face, larger than the buffer, or a chunk size or count
    /// the protocol does not allow.
    Size,
    /// A chunk whose offset is not a chunk boundary of its frame, or whose length is wrong.
    Chunk,
}

/// What a face-frame message did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// Stored, or a duplicate / stale message ignored; nothing to answer.
    Quiet,
    /// Answer the host with this ack.
    Ack(FrameAck),
    /// The image is whole and passed its CRC-32: answer `Complete` and run the pipeline on
    /// [`Assembly::pixels`].
    Complete(FrameHeader),
}

/// Reassembles one face frame at a time from chunks in any order (selective repeat; the rules
/// are in [`msr_shared::msg`]). Bounded: one image buffer of `MAX_FRAME_BYTES` bytes, one
/// header, one [`ChunkSet`] and the id of the last completed frame.
pub struct Assembly {
    header: Option<FrameHeader>,
    missing: ChunkSet,
    /// The last frame completed, to answer its duplicates and polls.
    done: Option<u16>,
    /// Unfinished frames dropped for a newer one.
    pub superseded: u32,
    /// Chunks and starts that were duplicates or for a frame not in progress.
    pub ignored: u32,
    /// Whole images whose CRC-32 did not match.
    pub crc_errors: u32,
    buf: [u8; MAX_FRAME_BYTES],
}

impl Default for Assembly {
    fn default() -> Self {
        Self::new()
    }
}

impl Assembly {
    /// No frame in progress; `const`, so it can live in a `static`.
    pub const fn new() -> Self {
        Assembly {
            header: None,
            missing: ChunkSet::EMPTY,
            done: None,
            superseded: 0,
            ignored: 0,
            crc_errors: 0,
            buf: [0; MAX_FRAME_BYTES],
        }
    }

    /// Drops any frame in progress and forgets the last one (a new model).
    pub fn clear(&mut self) {
        self.header = None;
        self.done = None;
    }

    /// The frame in progress, if any.
    pub fn current(&self) -> Option<FrameHeader> {
        self.header
    }

    /// Is `frame` the one in progress or done, or older than them?
    fn seen(&self, frame: u16) -> bool {
        let known = |f: u16| f == frame || is_older(frame, f);
        self.header.is_some_and(|h| known(h.frame)) || self.done.is_some_and(known)
    }

    /// `FrameStart`: a newer frame supersedes the one in progress; the same or an older one is
    /// ignored. The image must be `face_w x face_h`.
    pub fn start(&mut self, h: FrameHeader, face_w: u16, face_h: u16) -> Result<(), AssemblyError> {
        if self.seen(h.frame) {
            self.ignored = self.ignored.saturating_add(1);
            return Ok(());
        }
        if h.width != face_w || h.height != face_h || !h.is_valid() || h.bytes() > MAX_FRAME_BYTES {
            return Err(AssemblyError::Size);
        }
        if self.header.is_some() {
            self.superseded = self.superseded.saturating_add(1);
        }
        self.header = Some(h);
        self.missing = ChunkSet::first(h.chunks());
        Ok(())
    }

    /// `FrameChunk`: stores a chunk of the frame in progress.
    pub fn chunk(&mut self, frame: u16, offset: u16, data: &[u8]) -> Result<Progress, AssemblyError> {
        let Some(h) = self.header.filter(|h| h.frame == frame) else {
            self.ignored = self.ignored.saturating_add(1);
            return Ok(Progress::Quiet);
        };
        let chunk = h.chunk as usize;
        let i = offset as usize / chunk;
        let range = h.chunk_range(i);
        if !(offset as usize).is_multiple_of(chunk) || i >= h.chunks() || data.len() != range.len() {
            return Err(AssemblyError::Chunk);
        }
        if !self.missing.remove(i) {
            self.ignored = self.ignored.saturating_add(1);
            return Ok(Progress::Quiet);
        }
        self.buf[range].copy_from_slice(data);
        if self.missing.is_empty() {
            return Ok(self.finish(h, 0));
        }
        if i + 1 == h.chunks() {
            // The end of the first round: tell the host what to send again.
            return Ok(Progress::Ack(self.ack(h.frame, 0)));
        }
        Ok(Progress::Quiet)
    }

    /// `FramePoll`: where the frame stands; starts it if its `FrameStart` was lost.
    pub fn poll(&mut self, h: FrameHeader, round: u8, face_w: u16, face_h: u16) -> Result<FrameAck, AssemblyError> {
        if !self.seen(h.frame) {
            self.start(h, face_w, face_h)?;
        }
        Ok(self.ack(h.frame, round))
    }

    fn ack(&self, frame: u16, round: u8) -> FrameAck {
        let state = match self.header {
            Some(h) if h.frame == frame => FrameState::Missing(self.missing),
            _ if self.done == Some(frame) => FrameState::Complete,
            _ => FrameState::Stale,
        };
        FrameAck { frame, round, state }
    }

    /// All chunks are in: the image must match its CRC-32, else every chunk is asked again.
    fn finish(&mut self, h: FrameHeader, round: u8) -> Progress {
        if CRC32.checksum(&self.buf[..h.bytes()]) == h.crc32 {
            self.header = None;
            self.done = Some(h.frame);
            return Progress::Complete(h);
        }
        self.crc_errors = self.crc_errors.saturating_add(1);
        self.missing = ChunkSet::first(h.chunks());
        Progress::Ack(self.ack(h.frame, round))
    }

    /// The image of the frame just completed: its grey bytes, then its chroma planes when
    /// the header says it has them.
    pub fn pixels(&self, h: &FrameHeader) -> &[u8] {
        &self.buf[..h.bytes().min(MAX_FRAME_BYTES)]
    }
}

#[cfg(test)]
mod tests;
