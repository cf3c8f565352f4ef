//! The contract every other crate speaks.
//!
//! - [`joints`]: the 25 Nao joints, their ids, limits and velocity limits, clamping and validation.
//! - [`frame`]: how bytes become messages on either serial link: postcard inside, a header with
//!   protocol version and sequence number, a CRC-16, COBS around it, `0x00` between frames.
//! - [`msg`]: the messages of the host link (host <-> board) and of the servo bus (board <-> servos).
//! - [`dynamixel`]: Dynamixel Protocol 2.0 packets (the servo bus of a real robot) and the
//!   X-series control table.
//! - [`deliver`]: the host's half of face-frame delivery (selective repeat) and the chunk size
//!   for a line.
//! - [`blob`]: the versioned model blob the board runs, with a validating, borrowing parser.
//! - `host_port` (`std`): the PC's side of the host link, the one encoder of face crops and
//!   model uploads.
//!
//! `no_std` and heap-free; the `std` feature adds the blob writer and `std::error::Error` impls.
//!
//! # Example: one message over the wire, and a blob that is refused
//! Any byte stream carries the frames: encode a message, feed the bytes one at a time to an
//! [`frame::FrameAccumulator`], and a checked frame comes out at the delimiter. A damaged byte makes
//! the frame fail its CRC instead.
//! ```
//! use msr_shared::frame::{encode_message, FrameAccumulator, MAX_WIRE_FRAME};
//! use msr_shared::msg::HostToBoard;
//!
//! let mut wire = [0u8; MAX_WIRE_FRAME];
//! let n = encode_message(7, &HostToBoard::Ping { nonce: 42 }, &mut wire).unwrap();
//! assert_eq!(wire[n - 1], 0, "frames end at a 0x00 delimiter");
//!
//! let mut rx: FrameAccumulator<MAX_WIRE_FRAME> = FrameAccumulator::new();
//! let mut frames = 0;
//! for &b in &wire[..n] {
//!     if let Some(frame) = rx.push(b) {
//!         let msg: HostToBoard = frame.unwrap().message().unwrap();
//!         assert_eq!(msg, HostToBoard::Ping { nonce: 42 });
//!         frames += 1;
//!     }
//! }
//! assert_eq!(frames, 1, "one frame, at the delimiter");
//!
//! wire[2] ^= 0x01; // one bit flipped on the line
//! let whole = wire[..n].iter().filter_map(|&b| rx.push(b).map(|f| f.is_ok())).filter(|&ok| ok).count();
//! assert_eq!(whole, 0, "a damaged frame never comes out");
//! assert!(rx.counters().resyncs() >= 1, "it is counted instead");
//!
//! // A model blob is checked before anything in it is used.
//! use msr_shared::blob::{BlobError, Model};
//! assert_eq!(Model::parse(b"MSRM").unwrap_err(), BlobError::Truncated);
//! ```
#![cfg_attr(not(any(feature = "std", test)), no_std)]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod blob;
pub mod deliver;
pub mod dynamixel;
pub mod frame;
pub mod joints;
pub mod msg;
#[cfg(feature = "std")]
pub mod host_port;

pub use joints::{Joint, JointError, JointLimits};
