//! The model blob: everything the board needs to run the mirror test, in one versioned file.
//!
//! All numbers little-endian; every section starts 4-byte aligned (relative to the blob start).
//!
//! ```text
//! header (HEADER_LEN = 40 bytes)
//!   0  magic b"MSRM"          4  version u16        6  header_len u16
//!   8  total_len u32         12  crc32 u32 (CRC-32/ISO-HDLC of bytes 16..total_len)
//!  16  face_h u16            18  face_w u16        20  n_layers u16    22  flags u16 (see below)
//!  24  threshold f32         28  normalisation u8  29  sided u8        30  min_area u16
//!  32  sigma_floor f32       36  merge_margin u8      37  pool u8 (flags bit 4; else 0) 38  merge_fragment u16
//! n_layers x layer:
//!   descriptor (LAYER_DESC_LEN = 32 bytes)
//!     0 kind u8  1 activation u8  2 weight dtype u8  3 weight order u8 (0 PyTorch, 1 blocked)
//!     4 in_c u16  6 in_h u16  8 in_w u16  10 out_c u16  12 out_h u16  14 out_w u16
//!    16 kernel u8  17 stride u8  18 padding u8  19 reserved u8 (0)
//!    20 crop_top u16  22 crop_left u16
//!    24 w_shift i8  25 in_shift i8  26 out_shift i8  27 reserved u8 (0)
//!    28 weight_bytes u32
//!   weights (weight_bytes, padded to 4), then bias (i32 each, count per kind; none for Crop)
//! statistics: mu then sigma, face_h*face_w u16 each, Q8.8 grey levels (padded to 4)
//! reach: 99 f32: w1[10][2] b1[10] w2[5][10] b2[5] in_min[2] in_max[2] out_min[5] out_max[5]
//! pose region (if flags bit 2): centre_yaw f32, centre_pitch f32, radius f32, threshold f32,
//!   merge_margin u8, reserved u8 (0), merge_fragment u16
//! template (if flags bit 0): h u16, w u16, h*w u8 grey (padded to 4)
//! pose statistics (if flags bit 5): bins_yaw u8, bins_pitch u8, reserved u16 (0),
//!   yaw_lo f32, yaw_hi f32, pitch_lo f32, pitch_hi f32, then per bin (bin = pitch index x
//!   bins_yaw + yaw index) mu then sigma, face_h*face_w u16 each, Q8.8 (each padded to 4)
//! frame spread (if flags bit 6): spread_ref f32
//! chroma (if flags bit 7): threshold f32, spread_ref f32, cells u8 (1, or the pose grid's
//!   cells), reserved u8 x 3 (0), then per cell, per 2 x 2 block of the face (blocks =
//!   ceil(face_h / 2) x ceil(face_w / 2)): mu_u i8, then mu_v i8, then spread u8, each table
//!   padded to 4
//! self gate (if flags bit 3): amplitude f32, gain f32, gain_tol f32, rest_tol f32,
//!   latency_ms u16, timeout_ms u16, min_frames u8, layout u8, reserved u8 x2 (0),
//!   then for layout 1: hold_tol f32, level_tol f32; for layout 2: hold_tol f32, level_tol f32,
//!   line_tol f32; for layout 3: hold_tol f32, level_tol f32, line_tol f32, joint_tol f32
//! ```
//!
//! Fixed point: a layer's input is i16 with `in_shift` fraction bits, its weights (i8 or i16) have
//! `w_shift` fraction bits, its bias is i32 in the accumulator's scale (`w_shift + in_shift`
//! fraction bits), and its output is i16 with `out_shift` fraction bits:
//! `out = sat_i16(round(act(acc * 2^-(w_shift+in_shift)) * 2^out_shift))`.
//! The first layer's input is `[HeadYaw, HeadPitch]` in radians; the last layer's output is the
//! predicted face, `1 x face_h x face_w`, grey/255 (so sigmoid output with `out_shift` bits).
//!
//! Weight layouts follow PyTorch: Dense `[out][in]` over the flattened CHW input; ConvTranspose2d
//! `[in_c][out_c][k][k]`; UpConv (nearest upsampling by `stride`, then a stride-1 Conv2d with
//! `padding`) `[out_c][in_c][k][k]`. Bias: Dense one per output element; the convolutions one per
//! output channel.
//!
//! Weight order 1 ([`WeightOrder::Blocked`], version 2; Dense only, inputs a multiple of
//! [`BLOCK`]): the weights of an output `C x H x W` are stored `[y][x][g][c][BLOCK]` for input
//! `BLOCK * g + r`, and the biases `[y][x][c]`: per output pixel, in blocks of 8 inputs, the C
//! channels' rows in turn, the order in which the board's kernel reads them (all channels of a
//! pixel per pass, one load after the other). [`Layer::weight`] and [`Layer::bias`] take PyTorch
//! indices whatever the order. The writer uses it for a Dense of 4 channels feeding a
//! ConvTranspose2d (the conv decoder's big layer) and writes version 1, which older readers
//! take, when no layer uses it.
//!
//! Flags: bit 0, the blob carries the face template; bit 1 (version 4, only with bit 0), the
//! host crops this model's faces at sub-pixel precision ([`CropMode::Subpixel`]). The board
//! never crops: the template and the crop mode tell the host how to make the crops it sends.
//! Bit 2 (version 4): a [`PoseRegion`], novelty settings of their own for head poses near one
//! pose (the observe posture). The writer uses version 4 only for a blob with bit 1 or 2.
//! Bit 3 (version 5): a [`SelfGate`], the test that the face moves with the robot's own head
//! before a reach; it comes last, so the writer's `set_self_gate` adds or removes it without
//! touching the rest, and a blob without it is byte for byte what the writer makes. Its
//! `layout` byte (0 before): 0, one tolerance (`rest_tol`) bounds the rest, hold and level
//! statistics; 1 (what the writer makes), `hold_tol` and `level_tol` of their own follow (each
//! statistic has its own spread in the own image, and one tolerance sized by the largest let a
//! babbling robot through on the others); 2 (what the writer makes for a gate with a
//! `line_tol`), `line_tol` follows too: the probe returns to the resting yaw and the face there
//! must lie on the poses' line within it ([`SelfGate::line_tol`]); 3 (what the writer makes for a
//! gate with a `joint_tol`), `joint_tol` follows `line_tol`: the statistics' squared shares of
//! their tolerances must also sum to at most it ([`SelfGate::joint_tol`]). Any other layout is
//! refused.
//! Bit 4 (version 5): the error is pooled before its statistics and the threshold, `e = |mean
//! of 255 (I - I_hat) over the (2 pool + 1)^2 window|` (clipped at the face's border), with
//! `pool` (1..=[`MAX_POOL`]) in header byte 37; the blob's mu and sigma are of that error.
//! Bit 5 (version 5): [`PoseStats`], the error statistics (mu and sigma) of each cell of a grid
//! over the head pose (`[HeadYaw, HeadPitch]`); the board takes the tables of the cell the
//! reported head pose falls in ([`PoseGrid::bin`]), and the header's tables only for a
//! non-finite pose. Why: the decoder errs more at some poses (the corners of the training
//! poses) than at others, and one sigma for all poses either misses marks at the good poses
//! or fires at the bad ones. The section comes before the self gate's.
//! The writer uses version 5 only for a blob with bit 3, 4 or 5, and a version-5 blob has one
//! of them.
//!
//! Bit 6 (version 6): the spread of the pooled error over the frames the statistics came from
//! ([`Novelty::spread_ref`], grey levels, 0..=255), after the pose statistics and before the
//! self gate. The board widens each pixel's sigma by how much more a frame's own error spreads
//! (the firmware's `floor`): a camera the statistics never saw (noise, blur, compression, another
//! tone curve) pays for itself. The writer uses version 6 only for a blob with bit 6, and a
//! version-6 blob has it.
//!
//! Fragment merge (version 3; bytes 36..40 are zero before): `merge_margin` 0 is the paper's
//! blob stage. Otherwise 8-connected components of at least `merge_fragment` pixels whose
//! boxes, one grown by `merge_margin` pixels on every side, overlap are merged (repeatedly, as
//! OpenMV's `find_blobs(merge=True, margin=N)`) before the `min_area` test; see [`Merge`]. The
//! writer uses version 3 only for a blob that merges.
//!
//! [`Model::parse`] checks all of it (magic, version, lengths, CRC, every shape and the chaining of
//! layers) and borrows the tables from the input bytes, so a blob in flash costs no RAM.

//! Bit 7 (version 7): the face's colour ([`Chroma`]): each 2 x 2 block's normalised chroma
//! and its spread over the statistics' frames, after the frame spread and before the self
//! gate. The board finds a mark whose hue the face does not have even where its grey level
//! matches. The writer adds or removes it with [`set_chroma`]; a blob without it is read and
//! run as a grey model, whatever its version.

/// The first 4 bytes of every blob.
pub const MAGIC: [u8; 4] = *b"MSRM";
/// The newest version this build reads and writes (version 1 has no weight order byte,
/// versions 1 and 2 no fragment merge, versions 1 to 3 no sub-pixel crop flag or pose region,
/// versions 1 to 4 no self gate or error pooling, versions 1 to 5 no frame spread, versions 1
/// to 6 no chroma).
pub const VERSION: u16 = 7;
/// Largest [`Novelty::pool`] radius: a 7 x 7 window.
pub const MAX_POOL: u8 = 3;
/// Largest [`Merge::margin`].
pub const MAX_MERGE_MARGIN: u8 = 16;
/// Inputs per block of the blocked weight order.
pub const BLOCK: usize = 8;
/// Bytes of the header, before the first layer descriptor.
pub const HEADER_LEN: usize = 40;
/// Bytes of one layer descriptor.
pub const LAYER_DESC_LEN: usize = 32;
/// Largest face the board handles.
pub const MAX_FACE_H: usize = 64;
/// Widest face the board handles.
pub const MAX_FACE_W: usize = 96;
/// Pixels of the largest face: the board's face buffer, in bytes.
pub const MAX_FACE_PIXELS: usize = MAX_FACE_H * MAX_FACE_W;
/// Most decoder layers in a blob.
pub const MAX_LAYERS: usize = 16;
/// Largest intermediate activation (elements) of any layer's output.
pub const MAX_ACTIVATION_LEN: usize = 8192;
/// Largest face template (a 320 x 240 frame), pixels.
pub const MAX_TEMPLATE_PIXELS: usize = 240 * 320;
/// Reach network inputs: the mark's full-frame centroid `[x, y]`, pixels.
pub const REACH_IN: usize = 2;
/// Reach network hidden units.
pub const REACH_HIDDEN: usize = 10;
/// Reach network outputs: one angle per [`crate::joints::REACH_JOINTS`] joint, radians.
pub const REACH_OUT: usize = 5;
/// f32 values of the reach section: the [`Reach`] fields in order (99).
pub const REACH_FLOATS: usize = REACH_HIDDEN * REACH_IN
    + REACH_HIDDEN
    + REACH_OUT * REACH_HIDDEN
    + REACH_OUT
    + 2 * REACH_IN
    + 2 * REACH_OUT;
const FLAG_TEMPLATE: u16 = 1;
const FLAG_SUBPIXEL: u16 = 2;
const FLAG_REGION: u16 = 4;
const FLAG_SELF_GATE: u16 = 8;
/// Bytes of the self-gate section as the writer makes it without a return stage (layout 1).
pub const SELF_GATE_LEN: usize = 32;
/// Bytes of the self-gate section with a return stage (layout 2, [`SelfGate::line_tol`]).
pub const SELF_GATE_LEN_V2: usize = 36;
/// Bytes of the self-gate section with a joint bound (layout 3, [`SelfGate::joint_tol`]).
pub const SELF_GATE_LEN_V3: usize = 40;
/// Bytes of a layout-0 self-gate section (one tolerance for the rest, hold and level).
pub const SELF_GATE_LEN_V0: usize = 24;
/// Largest [`SelfGate::amplitude`], radians (about 5.7 degrees: within the training poses).
pub const MAX_GATE_AMPLITUDE: f32 = 0.1;
/// Longest [`SelfGate::timeout_ms`].
pub const MAX_GATE_TIMEOUT_MS: u16 = 3000;
/// Most [`SelfGate::min_frames`].
pub const MAX_GATE_FRAMES: u8 = 8;
const FLAG_POOL: u16 = 16;
const FLAG_POSE: u16 = 32;
const FLAG_SPREAD: u16 = 64;
const FLAG_CHROMA: u16 = 128;
/// Largest [`Novelty::spread_ref`], grey levels.
pub const MAX_SPREAD_REF: f32 = 255.0;
/// Most cells of a [`PoseGrid`] along one angle.
pub const MAX_POSE_BINS: u8 = 4;
/// Bytes of the pose-statistics section before its tables.
pub const POSE_HEADER_LEN: usize = 20;
/// Largest `|lo|`, `|hi|` of a [`PoseGrid`], radians (beyond every head joint's range).
pub const MAX_POSE_ANGLE: f32 = 3.2;
/// Largest [`PoseRegion::radius`], radians.
pub const MAX_REGION_RADIUS: f32 = 0.5;

/// CRC of the blob body: CRC-32/ISO-HDLC (the zlib one).
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

pub mod chroma;
mod error;
mod model;
mod settings;
mod view;

pub use chroma::{Chroma, ChromaCell};
#[cfg(any(feature = "std", test))]
pub use chroma::ChromaSpec;
pub use error::BlobError;
pub use model::Model;
pub use settings::{Merge, Normalisation, Novelty, PoseGrid, PoseRegion, PoseStats, SelfGate, Sided};
pub use view::{
    Activation, CropMode, Layer, LayerKind, Reach, Shape, Template, U16Table, WeightOrder,
    WeightType,
};

#[cfg(any(feature = "std", test))]
pub use writer::*;

#[cfg(any(feature = "std", test))]
mod writer;

#[cfg(test)]
mod tests;
