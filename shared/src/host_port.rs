//! The PC's side of the host link (`std` only): messages out as wire frames, wire bytes in as
//! board messages. Every host-link talker (the `msr` command, the sim's camera, the tests) uses
//! this one encoder, so a face crop or a model upload has one wire form.
//!
//! ```
//! use msr_shared::host_port::HostPort;
//! use msr_shared::msg::HostToBoard;
//! use msr_shared::frame::{FrameAccumulator, MAX_WIRE_FRAME};
//!
//! let mut port = HostPort::default();
//! let grey = vec![128u8; 75 * 58];
//! let wire = port.encode_face([120, 80], [75, 58], &grey).unwrap();
//! // A FrameStart, then chunks of at most CHUNK bytes, each its own frame.
//! let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
//! let mut got = Vec::new();
//! for b in wire {
//!     if let Some(Ok(f)) = acc.push(b) {
//!         match f.message::<HostToBoard>().unwrap() {
//!             HostToBoard::FrameStart(h) => assert_eq!((h.crop_x, h.width), (120, 75)),
//!             HostToBoard::FrameChunk { data, .. } => got.extend_from_slice(data),
//!             m => panic!("{m:?}"),
//!         }
//!     }
//! }
//! assert_eq!(got, grey);
//! ```
use crate::blob::CRC32;
use crate::frame::{
    encode_message_vec, FrameAccumulator, FrameError, LinkCounters, Sequencer, MAX_WIRE_FRAME, PROTOCOL_VERSION,
};
use crate::msg::{BoardToHost, HostToBoard, CHUNK};

/// A face crop that the frame messages cannot carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaceError {
    /// Origin or size beyond `u16`, or more pixels than a frame's `u16` offsets reach.
    /// `origin` (the crop's top-left) and `size` (width, height) as given, in camera pixels.
    #[allow(missing_docs)]
    TooLarge { origin: [u32; 2], size: [u32; 2] },
    /// `grey` does not hold `width * height` pixels.
    /// `expected` is `width * height`, `got` the length of `grey`.
    #[allow(missing_docs)]
    Length { expected: usize, got: usize },
}

impl core::fmt::Display for FaceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FaceError::TooLarge { origin, size } => {
                write!(f, "a {}x{} crop at {origin:?} does not fit the frame messages", size[0], size[1])
            }
            FaceError::Length { expected, got } => write!(f, "face crop has {got} pixels, expected {expected}"),
        }
    }
}

impl std::error::Error for FaceError {}

/// The PC's side of the host link: frames out, reports in.
pub struct HostPort {
    seq: Sequencer,
    rx: Box<FrameAccumulator<MAX_WIRE_FRAME>>,
    frame_id: u16,
    /// The protocol version of a board that speaks another one, once one of its frames came.
    foreign: Option<u8>,
}

impl Default for HostPort {
    fn default() -> Self {
        HostPort { seq: Sequencer::default(), rx: Box::new(FrameAccumulator::new()), frame_id: 0, foreign: None }
    }
}

/// A board that speaks another host-link protocol version (older or newer firmware), which
/// would not understand this host either.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VersionMismatch {
    /// The board's version.
    pub board: u8,
}

impl core::fmt::Display for VersionMismatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "the board speaks host-link protocol version {}, this host version {}: \
             flash firmware and msr of the same release",
            self.board, PROTOCOL_VERSION
        )
    }
}

impl std::error::Error for VersionMismatch {}

impl HostPort {
    /// The wire bytes of one message.
    pub fn encode(&mut self, msg: &HostToBoard) -> Vec<u8> {
        encode_message_vec(self.seq.next(), msg).expect("host messages fit a frame")
    }

    /// The wire bytes of a face crop under the next frame id: `FrameStart` and its chunks.
    /// `origin` is the crop's top-left in the camera frame, `size` its width and height.
    pub fn encode_face(&mut self, origin: [u32; 2], size: [u32; 2], grey: &[u8]) -> Result<Vec<u8>, FaceError> {
        let id = self.frame_id.wrapping_add(1);
        let out = self.encode_frame(id, origin, size, grey)?;
        self.frame_id = id;
        Ok(out)
    }

    /// As [`HostPort::encode_face`], under the frame id `frame`.
    pub fn encode_frame(&mut self, frame: u16, origin: [u32; 2], size: [u32; 2], grey: &[u8]) -> Result<Vec<u8>, FaceError> {
        let fits = |v: u32| u16::try_from(v).is_ok();
        let pixels = size[0] as usize * size[1] as usize;
        if !origin.iter().chain(&size).all(|&v| fits(v)) || pixels > u16::MAX as usize + 1 {
            return Err(FaceError::TooLarge { origin, size });
        }
        if grey.len() != pixels {
            return Err(FaceError::Length { expected: pixels, got: grey.len() });
        }
        // Sent once, for a clean line; a lossy line needs `crate::deliver::FaceLink`, which
        // repeats what the board missed.
        let h = crate::deliver::face_header(
            frame,
            [origin[0] as u16, origin[1] as u16],
            [size[0] as u16, size[1] as u16],
            CHUNK as u16,
            grey,
        );
        let mut out = self.encode(&HostToBoard::FrameStart(h));
        for (i, data) in grey.chunks(h.chunk as usize).enumerate() {
            let offset = (i * h.chunk as usize) as u16;
            out.extend(self.encode(&HostToBoard::FrameChunk { frame, offset, data }));
        }
        Ok(out)
    }

    /// The wire bytes of a model upload: begin (length and CRC-32), chunks, commit.
    pub fn encode_upload(&mut self, blob: &[u8]) -> Vec<u8> {
        let mut out = self.encode(&HostToBoard::ModelBegin { len: blob.len() as u32, crc32: CRC32.checksum(blob) });
        out.extend(self.encode_upload_from(blob, 0));
        out
    }

    /// The rest of an upload from byte `from` (where the board's `UploadAck` said it stands):
    /// chunks, commit.
    pub fn encode_upload_from(&mut self, blob: &[u8], from: usize) -> Vec<u8> {
        let from = from.min(blob.len());
        let mut out = Vec::new();
        for (i, data) in blob[from..].chunks(CHUNK).enumerate() {
            out.extend(self.encode(&HostToBoard::ModelChunk { offset: (from + i * CHUNK) as u32, data }));
        }
        out.extend(self.encode(&HostToBoard::ModelCommit));
        out
    }

    /// Parses what arrived; damaged frames are counted by the accumulator and skipped.
    pub fn receive(&mut self, bytes: &[u8]) -> Vec<BoardToHost> {
        let mut out = Vec::new();
        for &b in bytes {
            match self.rx.push(b) {
                Some(Ok(f)) => match f.message::<BoardToHost>() {
                    Ok(m) => out.push(m),
                    Err(_) => self.rx.count_malformed(),
                },
                Some(Err(FrameError::Version(v))) => self.foreign = Some(v),
                _ => {}
            }
        }
        out
    }

    /// Fails once a frame of another protocol version came.
    pub fn check_version(&self) -> Result<(), VersionMismatch> {
        self.foreign.map_or(Ok(()), |board| Err(VersionMismatch { board }))
    }

    /// What the receiving side counted so far.
    pub fn counters(&self) -> &LinkCounters {
        self.rx.counters()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_board_of_another_protocol_version_is_a_clear_error() {
        // A version-1 board's Pong { nonce: 5 }: version 1, seq 0, payload 00 05, CRC-16/UMTS.
        let raw = [1u8, 0, 0, 0, 5];
        let crc = crate::frame::CRC16.checksum(&raw).to_le_bytes();
        assert!(!crc.contains(&0), "the literal assumes a CRC without zero bytes");
        // COBS of 01 00 00 00 05 c0 c1: runs [01] [] [] [05 c0 c1], then the delimiter.
        let wire = [0x02, 0x01, 0x01, 0x01, 0x04, 0x05, crc[0], crc[1], 0x00];
        let mut port = HostPort::default();
        assert!(port.check_version().is_ok());
        assert!(port.receive(&wire).is_empty());
        let e = port.check_version().unwrap_err().to_string();
        assert!(e.contains("version 1, this host version 7"), "{e}");
        // The same message from a board of this version is taken.
        let mut port = HostPort::default();
        let good = encode_message_vec(0, &BoardToHost::Pong { nonce: 5 }).unwrap();
        assert_eq!(port.receive(&good), vec![BoardToHost::Pong { nonce: 5 }]);
        assert!(port.check_version().is_ok());
    }


    #[test]
    fn crops_the_messages_cannot_carry_are_errors() {
        let mut p = HostPort::default();
        assert!(matches!(p.encode_face([0, 0], [300, 300], &[0; 90_000]), Err(FaceError::TooLarge { .. })));
        assert!(matches!(p.encode_face([70_000, 0], [75, 58], &[0; 75 * 58]), Err(FaceError::TooLarge { .. })));
        assert_eq!(p.encode_face([0, 0], [4, 2], &[0; 7]), Err(FaceError::Length { expected: 8, got: 7 }));
        // A refused crop does not use up a frame id.
        let wire = p.encode_face([0, 0], [2, 2], &[1, 2, 3, 4]).unwrap();
        let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
        let mut frames = Vec::new();
        for &b in &wire {
            if let Some(f) = acc.push(b) {
                match f.unwrap().message::<HostToBoard>().unwrap() {
                    HostToBoard::FrameStart(h) => frames.push(h.frame),
                    HostToBoard::FrameChunk { frame, .. } => frames.push(frame),
                    m => panic!("{m:?}"),
                }
            }
        }
        assert_eq!(frames, [1, 1]);
    }
}
