//! The board's pipeline: fixed-point decoder, saliency, blobs, winner, confirmation, reach,
//! motion and the two serial links. `no_std` (unless feature `std`), no heap, bounded memory,
//! no panics on any input.
//!
//! # The API others call
//!
//! **The board** ([`Board`]): a pure function of bytes in and commands out. On a board, a loop
//! calls `board.poll(now_us, &mut host_uart, &mut servo_uart)`; here the two UARTs are byte
//! queues, and the host asks for a ping:
//! ```
//! use embedded_io::{ErrorType, Read, ReadReady, Write};
//! use msr_firmware::{Board, RamStore};
//! use msr_shared::host_port::HostPort;
//! use msr_shared::msg::{BoardToHost, HostToBoard};
//! use std::collections::VecDeque;
//!
//! /// What a UART gives the board: bytes that arrived, and bytes it sent.
//! #[derive(Default)]
//! struct Wire { rx: VecDeque<u8>, tx: Vec<u8> }
//! impl ErrorType for Wire { type Error = core::convert::Infallible; }
//! impl ReadReady for Wire {
//!     fn read_ready(&mut self) -> Result<bool, Self::Error> { Ok(!self.rx.is_empty()) }
//! }
//! impl Read for Wire {
//!     fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
//!         let n = buf.len().min(self.rx.len());
//!         for (b, x) in buf.iter_mut().zip(self.rx.drain(..n)) { *b = x; }
//!         Ok(n)
//!     }
//! }
//! impl Write for Wire {
//!     fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
//!         self.tx.extend_from_slice(buf);
//!         Ok(buf.len())
//!     }
//!     fn flush(&mut self) -> Result<(), Self::Error> { Ok(()) }
//! }
//!
//! // No model yet (a built-in one would be `RamStore::new(Some(BLOB))`), no room for uploads.
//! let mut board = Box::new(Board::new(RamStore::<0>::new(None)));
//! let (mut host, mut servos) = (Wire::default(), Wire::default());
//! let mut pc = HostPort::default();
//! host.rx.extend(pc.encode(&HostToBoard::Ping { nonce: 7 }));
//! board.poll(0, &mut host, &mut servos);
//! assert!(pc.receive(&host.tx).contains(&BoardToHost::Pong { nonce: 7 }));
//! ```
//! `host_uart` and `servo_uart` implement `embedded_io::{Read, Write, ReadReady}`; `poll` never
//! blocks on reads (it takes what `read_ready` says is there), answers the host link
//! (`msr_shared::msg::HostToBoard`), reads servo states, runs the watchdogs and sends servo
//! targets every [`motion::PERIOD_US`]. The model comes from the [`ModelStore`]: built in
//! ([`RamStore::new`]`(Some(bytes))`, 4-byte aligned) or uploaded (`ModelBegin/Chunk/Commit`).
//!
//! **One frame, for host tools** ([`detect`]): crop pixels + crop offset + head angles + model
//! -> winning blob, full-frame centroid, reach angles:
//! ```text
//! let mut ws = Box::new(Workspace::new());
//! let model = msr_shared::blob::Model::parse(&bytes)?;
//! let det = detect(&mut ws, &model, &Settings::of(&model), &crop, [crop_x, crop_y], [yaw, pitch])?;
//! ```
//! The stages are also callable one by one on [`Workspace`] (`decode`, `saliency`, `mask`,
//! `blobs`), and [`blobs::Labeller`] labels any mask (`msr blobs`).
//!
//! **The decoder alone** ([`decoder::Decoder::predict`]): the predicted face for a head pose,
//! Q8.8 grey levels (divide by 65280 for grey/255), for PSNR checks.
//!
//! **Golden vectors** ([`golden::run`]): a fixed set of frames through the pipeline -> a digest,
//! so a host build and a `thumbv7em-none-eabihf` build can be compared bit for bit.
//!
//! # Stages (one module each)
//! [`model`] validates and stages blobs; [`decoder`]; [`saliency`]; [`blobs`]; [`winner`];
//! [`confirm`]; [`reach`]; [`motion`]; [`link`] (framing, reassembly, watchdogs); [`board`];
//! [`light`] (the per-frame photometric fit); [`floor`] (the frame's own floor: sigma widened by
//! what a camera adds beyond the statistics' frames); [`room`] (online self-calibration: what
//! the board learns of the room's light as it runs); [`chroma`] (the marks that only colour
//! shows, for a model with chroma and a frame with its chroma planes).
//!
//! # Memory
//! [`Workspace`] (two `MAX_ACTIVATION_LEN` i16 activation buffers, the threshold table, the
//! labeller; the saliency mask, and the pooled saliency's ring of error rows or the chroma errors behind it, reuse
//! the spare activation buffer) plus the frame buffer and the link buffers make up [`Board`]:
//! 64 480 bytes for faces up to 64 x 96 and their chroma planes, whatever the model
//! (`size_of::<Board<RamStore<0>>>()`, checked by a test against 72 KiB). The model store is
//! separate: a built-in blob stays in flash; uploads need a staging area ([`ModelStore`]).
//!
//! # Behaviour worth knowing
//! - The decoder's input is the HeadYaw/HeadPitch the servos last reported, never the host's.
//! - Confirmation: 3 of the last 5 frames ([`confirm`]); the winner ties go to raster order.
//! - Motion streams 5 targets (the reach joints) every 10 ms once the servos have reported,
//!   starting from where they are; detection pauses while the arm is away from home.
//! - Face watchdog (armed by the first complete frame): 500 ms without one -> `Halted`, the
//!   last posture is held (still streamed), `Error{FaceTimeout}` + `Status`; frames again ->
//!   back home if the arm was up. Servo watchdog: 100 ms without a state -> no more targets,
//!   `Error{ServoTimeout}` + `Status`; states again -> streaming restarts from them, then home.
//! - Frames while the arm is up are counted but not answered.
//!
//! # Exactness and cost (measured with the QEMU benchmark image, mps2-an386, `-icount`)
//! Host (x86_64) and `thumbv7em-none-eabihf` give the same golden digest for the same blob
//! (checked on synthetic default-conv and published-MLP blobs at 58 x 75). Per frame, in
//! emulated instructions, i16 weights: default conv decoder (211 648 MACs) about 207 k (0.98
//! per MAC, target 1.0; 0.85 with 64 hidden units), published MLP (565 784 MACs) about 0.44 M
//! (0.78 per MAC); i8 weights (SXTB16 on top of SMLAD): 1.32 and 1.33 per MAC. SMLAD alone is
//! 0.5 per MAC; the rest is mostly the per-output table step (3 instructions plus packing) and
//! loads. After the decoder (`msr bench --backend qemu`, 58 x 75 = 4 350 pixels), a model with
//! the pooled error and pose cells, what `msr demo` makes (saliency: the photometric fit, then
//! one assembly routine a row, [`saliency::pool`]): saliency about 117 k at a held head pose
//! and 24 k more when the frame changes pose cell (the threshold table made again), blobs
//! 0.5 k on an empty mask and 10-11 k with a mark, reach about 2.5 k: 29.3 per pixel over the
//! bench's four held frames, 31.2 the costliest (marked), 34.9 at a new pose cell; the frame's
//! floor ([`floor`], a model with a spread reference) adds about 50 k a frame and, on a frame
//! whose floor changed, about 180 k for the table made again: the costliest frame of the demo's
//! models about 0.57 M, within the 1.2 M budget (`docs/performance.md`). The paper's per-pixel error (`--pool 0`, measured before the fit):
//! saliency about 74 k, blobs about 26 k: about 23.5 per pixel.
#![cfg_attr(not(any(feature = "std", test)), no_std)]
// Index loops read best in the numeric kernels.
#![allow(clippy::needless_range_loop)]
#![warn(missing_docs)]

pub mod blobs;
pub mod board;
pub mod chroma;
pub mod confirm;
pub mod decoder;
pub mod dynamixel;
pub mod extent;
pub mod floor;
pub mod golden;
pub mod light;
pub mod link;
pub mod model;
pub mod motion;
pub mod pipeline;
pub mod reach;
pub mod room;
pub mod saliency;
pub mod self_gate;
pub mod store;
pub mod winner;

#[cfg(test)]
mod testkit;

pub use board::Board;
pub use model::{ModelStore, RamStore};
pub use pipeline::{detect, detect_colour, DetectError, FaceDetection, Workspace};
pub use saliency::Settings;
