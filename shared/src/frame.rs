//! Framing for both serial links.
//!
//! A frame on the wire is `COBS(version | seq | payload | crc16) 0x00`:
//!
//! | field   | size | meaning                                              |
//! |---------|------|------------------------------------------------------|
//! | version | 1    | [`PROTOCOL_VERSION`]                                  |
//! | seq     | 2    | sender's sequence number, little-endian, wraps        |
//! | payload | 0..=[`MAX_PAYLOAD`] | one postcard-encoded message           |
//! | crc     | 2    | CRC-16/UMTS (poly 0x8005, as Dynamixel 2.0) of all before it, LE |
//!
//! COBS removes every zero byte, so `0x00` always ends a frame and a receiver that joins mid-stream
//! or sees garbage resynchronises at the next zero. [`FrameAccumulator`] does that in bounded memory:
//! a damaged, oversized or foreign frame is counted and dropped whole.
//!
//! This layer does not repeat anything: a frame is delivered once, intact, or not at all.
//! Loss, duplication and reordering of whole frames are left to the messages ([`crate::msg`]
//! says what each side does). The only buffer is the accumulator's `N` bytes
//! ([`MAX_WIRE_FRAME`], 264) per receiving link; a sender encodes into a stack buffer of the same
//! size. Sequence numbers count gaps ([`LinkCounters::seq_gaps`]) for diagnosis only.
//!
//! A frame of another [`PROTOCOL_VERSION`] passes the CRC and is refused as
//! [`FrameError::Version`]: the receiver knows the peer is alive but speaks another protocol.

use core::fmt;
use serde::{Deserialize, Serialize};

/// Bumped whenever a message layout changes incompatibly. Version 2: face frames by selective
/// repeat (`FrameHeader::chunk` and `crc32`, `FramePoll`, `FrameAck`), resumable uploads
/// (`UploadAck`); version 1 sent each frame once and dropped it on any lost chunk. Version 3:
/// the self gate (`Mode::SelfTest`, `BoardToHost::SelfGate`) and
/// head poses on request (`MoveHead`, `HeadAt`, `HeadRefused`, `HeadNotSettled`). Version 4:
/// the crop position's sub-pixel part (`FrameHeader::crop_sub`) and the self gate's hold and
/// level statistics (`GateReport::hold_px`, `level_px`). Version 5: the self gate's return
/// stage (`GateReport::line_px`, `unlike`). Version 6: `crop_sub` says where the face lies
/// (the template aligned to it), up to a whole pixel either way; a version-5 board would refuse
/// such a frame as invalid. Version 7: a face frame may carry its chroma planes after its grey
/// bytes (`FrameHeader::colour`).
pub const PROTOCOL_VERSION: u8 = 7;
/// Largest postcard payload in one frame.
pub const MAX_PAYLOAD: usize = 256;
/// Version byte and sequence number.
pub const HEADER_LEN: usize = 3;
/// The CRC-16 at the end of a frame, little-endian.
pub const CRC_LEN: usize = 2;
/// Largest frame before COBS.
pub const MAX_RAW_FRAME: usize = HEADER_LEN + MAX_PAYLOAD + CRC_LEN;
/// Largest frame on the wire, COBS overhead and the `0x00` delimiter included.
pub const MAX_WIRE_FRAME: usize = MAX_RAW_FRAME + MAX_RAW_FRAME / 254 + 1 + 1;

/// The frame checksum: CRC-16/UMTS, the polynomial Dynamixel 2.0 servos use.
pub const CRC16: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_UMTS);

/// Why a frame was not made or not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The COBS encoding was broken (a length byte pointing past the end).
    Cobs,
    /// Fewer bytes than a header and a CRC.
    TooShort,
    /// The CRC did not match: bits were flipped or bytes lost.
    Crc,
    /// A frame of another protocol version.
    Version(u8),
    /// More bytes than [`MAX_WIRE_FRAME`] before a delimiter.
    Oversized,
    /// The payload is not a valid message of the expected type.
    Message,
    /// The payload is larger than [`MAX_PAYLOAD`] or the output buffer is too small.
    TooLarge,
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::Cobs => f.write_str("broken COBS encoding"),
            FrameError::TooShort => f.write_str("frame shorter than header and CRC"),
            FrameError::Crc => f.write_str("CRC mismatch"),
            FrameError::Version(v) => {
                write!(f, "protocol version {v}, expected {PROTOCOL_VERSION}")
            }
            FrameError::Oversized => write!(f, "frame longer than {MAX_WIRE_FRAME} bytes"),
            FrameError::Message => f.write_str("payload is not a valid message"),
            FrameError::TooLarge => f.write_str("message too large for a frame"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for FrameError {}

/// A checked frame: CRC and version verified, payload not yet parsed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    /// The sender's sequence number (wraps at `u16::MAX`).
    pub seq: u16,
    /// The postcard-encoded message, CRC and header stripped.
    pub payload: &'a [u8],
}

impl<'a> Frame<'a> {
    /// Parses the payload as one message; trailing bytes are an error.
    pub fn message<T: Deserialize<'a>>(&self) -> Result<T, FrameError> {
        match postcard::take_from_bytes::<T>(self.payload) {
            Ok((msg, [])) => Ok(msg),
            _ => Err(FrameError::Message),
        }
    }
}

/// Encodes a payload into a wire frame, delimiter included. Returns the bytes written.
pub fn encode_payload(seq: u16, payload: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    if payload.len() > MAX_PAYLOAD {
        return Err(FrameError::TooLarge);
    }
    let mut raw = [0u8; MAX_RAW_FRAME];
    let n = HEADER_LEN + payload.len();
    raw[0] = PROTOCOL_VERSION;
    raw[1..3].copy_from_slice(&seq.to_le_bytes());
    raw[HEADER_LEN..n].copy_from_slice(payload);
    let crc = CRC16.checksum(&raw[..n]);
    raw[n..n + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let raw = &raw[..n + CRC_LEN];
    if out.len() < cobs::max_encoding_length(raw.len()) + 1 {
        return Err(FrameError::TooLarge);
    }
    let len = cobs::encode(raw, out);
    out[len] = 0;
    Ok(len + 1)
}

/// Encodes one message into a wire frame, delimiter included. Returns the bytes written.
pub fn encode_message<T: Serialize>(
    seq: u16,
    msg: &T,
    out: &mut [u8],
) -> Result<usize, FrameError> {
    let mut payload = [0u8; MAX_PAYLOAD];
    let used = postcard::to_slice(msg, &mut payload).map_err(|_| FrameError::TooLarge)?;
    let n = used.len();
    encode_payload(seq, &payload[..n], out)
}

/// Encodes one message into a heap buffer (host side convenience).
#[cfg(feature = "std")]
pub fn encode_message_vec<T: Serialize>(seq: u16, msg: &T) -> Result<Vec<u8>, FrameError> {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let n = encode_message(seq, msg, &mut out)?;
    Ok(out[..n].to_vec())
}

/// Checks one COBS-encoded frame (delimiter stripped), decoding it in place.
pub fn decode_in_place(buf: &mut [u8]) -> Result<Frame<'_>, FrameError> {
    let n = cobs::decode_in_place(buf).map_err(|_| FrameError::Cobs)?;
    let raw = &buf[..n];
    if n < HEADER_LEN + CRC_LEN {
        return Err(FrameError::TooShort);
    }
    let (body, crc) = raw.split_at(n - CRC_LEN);
    if CRC16.checksum(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(FrameError::Crc);
    }
    if body[0] != PROTOCOL_VERSION {
        return Err(FrameError::Version(body[0]));
    }
    Ok(Frame {
        seq: u16::from_le_bytes([body[1], body[2]]),
        payload: &body[HEADER_LEN..],
    })
}

/// What a receiver saw on one link; every dropped frame is counted once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkCounters {
    /// Frames that passed the checks.
    pub frames: u32,
    /// Frames dropped because the CRC did not match (flipped or lost bytes).
    pub crc_errors: u32,
    /// Frames dropped because the COBS encoding was broken.
    pub cobs_errors: u32,
    /// Frames longer than the accumulator's buffer, skipped to the next delimiter.
    pub oversized: u32,
    /// Too short, wrong version or an unparseable message.
    pub malformed: u32,
    /// Frames missing between two good ones, from sequence numbers.
    pub seq_gaps: u32,
}

impl LinkCounters {
    /// Frames dropped and resynchronised past.
    pub fn resyncs(&self) -> u32 {
        self.crc_errors + self.cobs_errors + self.oversized + self.malformed
    }

    /// Counts one error, by kind.
    pub fn count(&mut self, e: FrameError) {
        let c = match e {
            FrameError::Crc => &mut self.crc_errors,
            FrameError::Cobs => &mut self.cobs_errors,
            FrameError::Oversized => &mut self.oversized,
            FrameError::TooShort
            | FrameError::Version(_)
            | FrameError::Message
            | FrameError::TooLarge => &mut self.malformed,
        };
        *c = c.saturating_add(1);
    }
}

/// Collects bytes into frames in a fixed buffer of `N` bytes (use [`MAX_WIRE_FRAME`]).
///
/// Feed it every received byte with [`push`](Self::push). It never panics and never returns a
/// partial frame: a frame longer than `N` is skipped up to the next delimiter and reported once as
/// [`FrameError::Oversized`].
pub struct FrameAccumulator<const N: usize> {
    buf: [u8; N],
    len: usize,
    overflowed: bool,
    last_seq: Option<u16>,
    counters: LinkCounters,
}

impl<const N: usize> Default for FrameAccumulator<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameAccumulator<N> {
    /// An empty accumulator with zeroed counters; `const`, so it can live in a `static`.
    pub const fn new() -> Self {
        FrameAccumulator {
            buf: [0; N],
            len: 0,
            overflowed: false,
            last_seq: None,
            counters: LinkCounters {
                frames: 0,
                crc_errors: 0,
                cobs_errors: 0,
                oversized: 0,
                malformed: 0,
                seq_gaps: 0,
            },
        }
    }

    /// What this link has received and dropped so far.
    pub fn counters(&self) -> &LinkCounters {
        &self.counters
    }

    /// Counts a frame that was checked here but whose message the caller could not use.
    pub fn count_malformed(&mut self) {
        self.counters.count(FrameError::Message);
    }

    /// Forgets a partial frame, e.g. after a link disconnect.
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Takes one byte. At a delimiter, returns the finished frame or why it was dropped;
    /// empty frames (back-to-back delimiters) are ignored.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame<'_>, FrameError>> {
        if byte != 0 {
            if self.len < N {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflowed = true;
            }
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.overflowed, false) {
            self.counters.count(FrameError::Oversized);
            return Some(Err(FrameError::Oversized));
        }
        if len == 0 {
            return None;
        }
        match decode_in_place(&mut self.buf[..len]) {
            Ok(frame) => {
                self.counters.frames = self.counters.frames.saturating_add(1);
                if let Some(prev) = self.last_seq {
                    let gap = frame.seq.wrapping_sub(prev).wrapping_sub(1);
                    // A huge gap is a restarted sender, not 60000 lost frames.
                    if gap != 0 && gap < 1024 {
                        self.counters.seq_gaps = self.counters.seq_gaps.saturating_add(gap as u32);
                    }
                }
                self.last_seq = Some(frame.seq);
                Some(Ok(frame))
            }
            Err(e) => {
                self.counters.count(e);
                Some(Err(e))
            }
        }
    }
}

/// Hands out increasing sequence numbers for one sending side.
#[derive(Clone, Copy, Debug, Default)]
pub struct Sequencer(u16);

impl Sequencer {
    #[allow(clippy::should_implement_trait)] // never ends, so not an Iterator
    /// The next sequence number: 0, 1, 2, … wrapping after `u16::MAX`.
    pub fn next(&mut self) -> u16 {
        let s = self.0;
        self.0 = self.0.wrapping_add(1);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Acc = FrameAccumulator<MAX_WIRE_FRAME>;

    fn feed(acc: &mut Acc, bytes: &[u8]) -> Vec<Result<(u16, Vec<u8>), FrameError>> {
        let mut out = Vec::new();
        for &b in bytes {
            if let Some(r) = acc.push(b) {
                out.push(r.map(|f| (f.seq, f.payload.to_vec())));
            }
        }
        out
    }

    fn wire(seq: u16, payload: &[u8]) -> Vec<u8> {
        let mut out = [0u8; MAX_WIRE_FRAME];
        let n = encode_payload(seq, payload, &mut out).unwrap();
        out[..n].to_vec()
    }

    #[test]
    fn literal_frame() {
        // version 7, seq 0x0102, payload [0x00, 0x2A]; CRC-16/UMTS of 07 02 01 00 2A.
        let crc = CRC16.checksum(&[7, 2, 1, 0, 0x2A]).to_le_bytes();
        let bytes = wire(0x0102, &[0x00, 0x2A]);
        let mut expect = vec![0x04, 0x07, 0x02, 0x01, 0x04, 0x2A];
        expect.extend_from_slice(&crc);
        expect.push(0x00);
        // COBS: the zero inside the payload splits the frame into two runs.
        assert!(!crc.contains(&0), "the literal below assumes a CRC without zero bytes");
        assert_eq!(bytes, expect);
        let mut acc = Acc::new();
        assert_eq!(feed(&mut acc, &bytes), vec![Ok((0x0102, vec![0x00, 0x2A]))]);
    }

    #[test]
    fn crc_is_umts() {
        // The catalogue check value of CRC-16/UMTS.
        assert_eq!(CRC16.checksum(b"123456789"), 0xFEE8);
    }

    #[test]
    fn every_single_bit_flip_is_caught() {
        let good = wire(7, b"mirror");
        for i in 0..good.len() - 1 {
            for bit in 0..8 {
                let mut bad = good.clone();
                bad[i] ^= 1 << bit;
                let mut acc = Acc::new();
                let got = feed(&mut acc, &bad);
                assert!(
                    got.iter().all(|r| r.is_err()),
                    "flip {i}:{bit} accepted: {got:?}"
                );
                // The next good frame still comes through.
                assert_eq!(feed(&mut acc, &good), vec![Ok((7, b"mirror".to_vec()))]);
            }
        }
    }

    #[test]
    fn truncated_frames_are_dropped() {
        let good = wire(1, b"hello");
        for cut in 1..good.len() - 1 {
            let mut bytes = good[..cut].to_vec();
            bytes.push(0);
            let mut acc = Acc::new();
            let got = feed(&mut acc, &bytes);
            assert!(got.iter().all(|r| r.is_err()), "cut {cut}: {got:?}");
            assert_eq!(acc.counters().frames, 0);
        }
    }

    #[test]
    fn garbage_then_resync() {
        let mut acc = Acc::new();
        let mut bytes = vec![0x55, 0x13, 0xff, 0x00];
        bytes.extend(wire(3, b"abc"));
        let got = feed(&mut acc, &bytes);
        assert_eq!(got.last(), Some(&Ok((3, b"abc".to_vec()))));
        assert_eq!(acc.counters().frames, 1);
        assert_eq!(acc.counters().resyncs(), 1);
    }

    #[test]
    fn oversized_is_counted_once_and_skipped() {
        let mut acc = Acc::new();
        let mut bytes = vec![0x11; MAX_WIRE_FRAME * 3];
        bytes.push(0);
        bytes.extend(wire(9, b"ok"));
        let got = feed(&mut acc, &bytes);
        assert_eq!(got, vec![Err(FrameError::Oversized), Ok((9, b"ok".to_vec()))]);
        assert_eq!(acc.counters().oversized, 1);
    }

    #[test]
    fn wrong_version_is_refused() {
        // A version-1 frame (the protocol before selective repeat): seq 0, payload AA.
        let mut raw = vec![1u8, 0, 0, 0xAA];
        let crc = CRC16.checksum(&raw).to_le_bytes();
        raw.extend_from_slice(&crc);
        let mut enc = vec![0u8; 16];
        let n = cobs::encode(&raw, &mut enc);
        enc.truncate(n);
        enc.push(0);
        let mut acc = Acc::new();
        assert_eq!(feed(&mut acc, &enc), vec![Err(FrameError::Version(1))]);
        assert_eq!(acc.counters().malformed, 1);
    }

    #[test]
    fn sequence_gaps_are_counted() {
        let mut acc = Acc::new();
        for seq in [1u16, 2, 5, 6] {
            feed(&mut acc, &wire(seq, b"x"));
        }
        assert_eq!(acc.counters().seq_gaps, 2);
    }

    #[test]
    fn largest_payload_fits_and_one_more_does_not() {
        let p = [0u8; MAX_PAYLOAD];
        let bytes = wire(0, &p);
        assert!(bytes.len() <= MAX_WIRE_FRAME);
        let mut acc = Acc::new();
        assert_eq!(feed(&mut acc, &bytes), vec![Ok((0, p.to_vec()))]);
        let mut out = [0u8; MAX_WIRE_FRAME];
        assert_eq!(
            encode_payload(0, &[0u8; MAX_PAYLOAD + 1], &mut out),
            Err(FrameError::TooLarge)
        );
        assert_eq!(
            encode_payload(0, &p, &mut out[..10]),
            Err(FrameError::TooLarge)
        );
    }

    mod props {
        use super::*;
        use proptest::prelude::*;

        proptest! {
            #[test]
            fn round_trip(seq: u16, payload in proptest::collection::vec(any::<u8>(), 0..=MAX_PAYLOAD)) {
                let mut acc = Acc::new();
                prop_assert_eq!(feed(&mut acc, &wire(seq, &payload)), vec![Ok((seq, payload))]);
            }

            #[test]
            fn noise_never_panics_and_frames_after_it_survive(
                noise in proptest::collection::vec(any::<u8>(), 0..2000),
                payload in proptest::collection::vec(any::<u8>(), 0..64),
            ) {
                let mut acc = Acc::new();
                feed(&mut acc, &noise);
                let mut bytes = vec![0u8];
                bytes.extend(wire(42, &payload));
                let got = feed(&mut acc, &bytes);
                prop_assert_eq!(got.last().cloned(), Some(Ok((42, payload))));
            }
        }
    }
}
