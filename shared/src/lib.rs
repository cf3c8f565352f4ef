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
#![cfg_attr(not(any(feature = "std", test)), no_std)]
#![forbid(unsafe_code)]

pub mod blob;
pub mod deliver;
pub mod dynamixel;
pub mod frame;
pub mod joints;
pub mod msg;
#[cfg(feature = "std")]
pub mod host_port;

pub use joints::{Joint, JointError, JointLimits};
