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
//! before a reach; the section comes last, so [`set_self_gate`] adds or removes it without
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
//! Fragment merge (version 3; bytes 36..40 are zero before): `merge_margin` 0 is the paper's
//! blob stage. Otherwise 8-connected components of at least `merge_fragment` pixels whose
//! boxes, one grown by `merge_margin` pixels on every side, overlap are merged (repeatedly, as
//! OpenMV's `find_blobs(merge=True, margin=N)`) before the `min_area` test; see [`Merge`]. The
//! writer uses version 3 only for a blob that merges.
//!
//! [`Model::parse`] checks all of it (magic, version, lengths, CRC, every shape and the chaining of
//! layers) and borrows the tables from the input bytes, so a blob in flash costs no RAM.

use core::fmt;
use serde::{Deserialize, Serialize};

/// The first 4 bytes of every blob.
pub const MAGIC: [u8; 4] = *b"MSRM";
/// The newest version this build reads and writes (version 1 has no weight order byte,
/// versions 1 and 2 no fragment merge, versions 1 to 3 no sub-pixel crop flag or pose region,
/// versions 1 to 4 no self gate or error pooling).
pub const VERSION: u16 = 5;
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

/// How the prediction error is normalised before the threshold.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Normalisation {
    /// `(e - mu) / sigma`, as the published code.
    StdDev,
    /// `(e - mu) / sigma^2`, as the paper's text.
    Variance,
}

/// How the host cuts the face out of a camera frame with the model's template.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CropMode {
    /// The published code: the best `TM_CCOEFF` window, in whole pixels.
    #[default]
    Pixel,
    /// The best window refined to a fraction of a pixel and resampled, so that the face does
    /// not jump by a whole pixel between neighbouring head poses.
    Subpixel,
}

impl CropMode {
    /// The name used on the command line and in reports: `"pixel"` or `"subpixel"`.
    pub fn name(self) -> &'static str {
        match self {
            CropMode::Pixel => "pixel",
            CropMode::Subpixel => "subpixel",
        }
    }
}

impl fmt::Display for CropMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl core::str::FromStr for CropMode {
    type Err = &'static str;
    fn from_str(s: &str) -> Result<CropMode, &'static str> {
        match s {
            "pixel" => Ok(CropMode::Pixel),
            "subpixel" => Ok(CropMode::Subpixel),
            _ => Err("expected pixel or subpixel"),
        }
    }
}

/// Whether only errors above the mean count, or both directions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Sided {
    /// `(e - mu) / n > t`.
    One,
    /// `|e - mu| / n > t`, as the published code.
    Two,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// What a decoder layer computes (descriptor byte 0).
pub enum LayerKind {
    /// Fully connected over the flattened CHW input (kind 0).
    Dense,
    /// PyTorch `ConvTranspose2d`: out = (in - 1) * stride - 2 * padding + kernel (kind 1).
    ConvTranspose2d,
    /// Nearest-neighbour upsampling by `stride`, then a stride-1 convolution.
    UpConv,
    /// Takes an `output`-sized window at (`crop_top`, `crop_left`) of the input; no weights (kind 3).
    Crop,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The function applied to a layer's output (descriptor byte 1).
pub enum Activation {
    /// No function (0); the only one a Crop layer may have.
    Identity,
    /// Hyperbolic tangent (1).
    Tanh,
    /// Logistic sigmoid (2); the last layer's, so the face comes out as grey/255.
    Sigmoid,
    /// `max(0, x)` (3).
    Relu,
}

/// How a layer's weights are ordered in the blob (see the module notes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightOrder {
    /// PyTorch's order.
    Torch,
    /// Dense only: `[y][x][g][c][BLOCK]` over the output pixels, input blocks and channels.
    Blocked,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The integer type of a layer's weights (descriptor byte 2).
pub enum WeightType {
    /// `i8` weights (code 1).
    I8,
    /// Little-endian `i16` weights (code 2).
    I16,
}

impl WeightType {
    /// Bytes per weight.
    pub const fn size(self) -> usize {
        match self {
            WeightType::I8 => 1,
            WeightType::I16 => 2,
        }
    }
}

/// A channels x height x width shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Channels.
    pub c: u16,
    /// Height, pixels.
    pub h: u16,
    /// Width, pixels.
    pub w: u16,
}

impl Shape {
    /// Elements, `c * h * w`.
    pub const fn len(&self) -> usize {
        self.c as usize * self.h as usize * self.w as usize
    }
    /// Whether any dimension is zero.
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Why a blob was refused. [`BlobError::code`] is what the board reports over the link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlobError {
    /// Fewer bytes than the header, or than `total_len` says.
    Truncated,
    /// The first 4 bytes are not [`MAGIC`].
    BadMagic,
    /// A version outside `1..=`[`VERSION`]; holds the version found.
    UnsupportedVersion(u16),
    /// Wrong `header_len`, unknown or version-inappropriate flags, or non-zero reserved bytes.
    BadHeader,
    /// `total_len` disagrees with the bytes given.
    LengthMismatch,
    /// The CRC-32 of bytes 16.. does not match the header's: the blob is corrupt.
    Crc,
    /// Face size zero or over [`MAX_FACE_H`] x [`MAX_FACE_W`].
    FaceSize,
    /// More than [`MAX_LAYERS`] layers.
    TooManyLayers,
    /// A layer descriptor with an unknown kind, activation, type or reserved bits set.
    BadLayer(u8),
    /// A layer's sizes are inconsistent (output size, kernel, weight or bias count).
    LayerShape(u8),
    /// A layer's input is not the previous layer's output.
    Chain(u8),
    /// An intermediate output larger than [`MAX_ACTIVATION_LEN`].
    ActivationTooLarge(u8),
    /// The first layer does not take 2 inputs, or the last does not produce the face.
    ModelShape,
    /// Threshold not finite and positive, unknown normalisation or sidedness, zero min area.
    Novelty,
    /// Non-finite reach weights or scaling, or min >= max.
    Reach,
    /// The template is 0 pixels high or wide, or over [`MAX_TEMPLATE_PIXELS`].
    Template,
    /// Bytes left over after the last section.
    TrailingBytes,
    /// Self-gate parameters out of range.
    SelfGate,
    /// A pose-statistics grid out of range.
    PoseStats,
}

impl BlobError {
    /// A stable number for the wire.
    pub fn code(&self) -> u32 {
        match self {
            BlobError::Truncated => 1,
            BlobError::BadMagic => 2,
            BlobError::UnsupportedVersion(v) => 3 | (*v as u32) << 8,
            BlobError::BadHeader => 4,
            BlobError::LengthMismatch => 5,
            BlobError::Crc => 6,
            BlobError::FaceSize => 7,
            BlobError::TooManyLayers => 8,
            BlobError::BadLayer(i) => 9 | (*i as u32) << 8,
            BlobError::LayerShape(i) => 10 | (*i as u32) << 8,
            BlobError::Chain(i) => 11 | (*i as u32) << 8,
            BlobError::ActivationTooLarge(i) => 12 | (*i as u32) << 8,
            BlobError::ModelShape => 13,
            BlobError::Novelty => 14,
            BlobError::Reach => 15,
            BlobError::Template => 16,
            BlobError::TrailingBytes => 17,
            BlobError::SelfGate => 18,
            BlobError::PoseStats => 19,
        }
    }
}

impl fmt::Display for BlobError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BlobError::Truncated => f.write_str("model blob is truncated"),
            BlobError::BadMagic => f.write_str("not a model blob (bad magic)"),
            BlobError::UnsupportedVersion(v) => {
                write!(f, "model blob version {v}, this build reads 1..={VERSION}")
            }
            BlobError::BadHeader => f.write_str("model blob header is malformed"),
            BlobError::LengthMismatch => f.write_str("model blob length disagrees with its header"),
            BlobError::Crc => f.write_str("model blob CRC mismatch (corrupt)"),
            BlobError::FaceSize => write!(f, "face size must be 1..={MAX_FACE_H} x 1..={MAX_FACE_W}"),
            BlobError::TooManyLayers => write!(f, "more than {MAX_LAYERS} layers"),
            BlobError::BadLayer(i) => write!(f, "layer {i}: unknown kind, activation or type"),
            BlobError::LayerShape(i) => write!(f, "layer {i}: inconsistent sizes"),
            BlobError::Chain(i) => write!(f, "layer {i}: input is not the previous output"),
            BlobError::ActivationTooLarge(i) => {
                write!(f, "layer {i}: output larger than {MAX_ACTIVATION_LEN} elements")
            }
            BlobError::ModelShape => {
                f.write_str("decoder must map 2 head angles to a 1 x face_h x face_w image")
            }
            BlobError::Novelty => f.write_str("novelty parameters out of range"),
            BlobError::Reach => f.write_str("reach network has non-finite values or bad scaling"),
            BlobError::Template => f.write_str("face template is malformed"),
            BlobError::TrailingBytes => f.write_str("bytes left over after the last section"),
            BlobError::SelfGate => f.write_str("self-gate parameters out of range"),
            BlobError::PoseStats => f.write_str("pose-statistics grid out of range"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for BlobError {}

/// Novelty detection parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Novelty {
    /// Saliency threshold, in units of the normalisation (finite, > 0).
    pub threshold: f32,
    /// Whether the error is divided by sigma or sigma^2.
    pub normalisation: Normalisation,
    /// One- or two-sided test.
    pub sided: Sided,
    /// Smallest blob, pixels, that counts as a mark (>= 1).
    pub min_area: u16,
    /// The floor applied to sigma when the statistics were made (grey levels), for reference.
    pub sigma_floor: f32,
    /// Fragment merge before the `min_area` test; [`Merge::OFF`] for the paper's blob stage.
    pub merge: Merge,
    /// Radius of the window the signed error is averaged over before its magnitude is taken
    /// (flag bit 4); 0: per pixel, the paper's error.
    pub pool: u8,
}

/// Merging of nearby components before the minimum-area test (a deviation from the paper, for
/// marks that the saliency breaks up, e.g. along a textured cover). `margin` 0: off.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Merge {
    /// Two boxes merge when one, grown by this many pixels on every side, overlaps the other
    /// (so at most `margin - 1` empty rows or columns lie between them).
    pub margin: u8,
    /// Smallest component (pixels) that takes part; smaller ones are dropped as noise.
    pub fragment: u16,
}

impl Merge {
    /// The paper's blob stage: no merge.
    pub const OFF: Merge = Merge { margin: 0, fragment: 0 };

    /// `margin` > 0.
    pub fn is_on(&self) -> bool {
        self.margin > 0
    }

    /// Off, or a margin up to [`MAX_MERGE_MARGIN`] with `1 <= fragment <= min_area`.
    pub fn is_valid(&self, min_area: u16) -> bool {
        if self.margin == 0 {
            self.fragment == 0
        } else {
            self.margin <= MAX_MERGE_MARGIN && self.fragment >= 1 && self.fragment <= min_area
        }
    }
}

/// Novelty settings that replace the model's own for head poses near `centre`: a threshold and
/// merge calibrated at the pose where the robot looks for marks (its observe posture), while
/// the model's own settings hold for every other pose. `threshold` is in the model's
/// normalisation, like [`Novelty::threshold`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseRegion {
    /// `[HeadYaw, HeadPitch]`, radians.
    pub centre: [f32; 2],
    /// Radians, in the (yaw, pitch) plane.
    pub radius: f32,
    /// Threshold used inside the region, in the model's normalisation (finite, > 0).
    pub threshold: f32,
    /// Fragment merge used inside the region.
    pub merge: Merge,
}

impl PoseRegion {
    /// Whether `head` lies within `radius` of the centre (not for non-finite angles).
    pub fn contains(&self, head: [f32; 2]) -> bool {
        let (dy, dp) = (head[0] - self.centre[0], head[1] - self.centre[1]);
        dy * dy + dp * dp <= self.radius * self.radius
    }

    /// Finite centre, `0 < radius <= MAX_REGION_RADIUS`, finite positive threshold, a merge valid
    /// for `min_area`.
    pub fn is_valid(&self, min_area: u16) -> bool {
        self.centre.iter().all(|a| a.is_finite())
            && self.radius > 0.0
            && self.radius <= MAX_REGION_RADIUS
            && self.threshold.is_finite()
            && self.threshold > 0.0
            && self.merge.is_valid(min_area)
    }
}

/// A grid over the head pose, `bins[0]` cells of yaw from `lo[0]` to `hi[0]` by `bins[1]` of
/// pitch from `lo[1]` to `hi[1]` (radians); a pose outside it counts to the nearest cell.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseGrid {
    /// Cells along yaw and pitch (each `1..=MAX_POSE_BINS`, at least 2 in all).
    pub bins: [u8; 2],
    /// Lower edges, `[yaw, pitch]`, radians.
    pub lo: [f32; 2],
    /// Upper edges, radians (`> lo`).
    pub hi: [f32; 2],
}

impl PoseGrid {
    /// Cells in all.
    pub fn len(&self) -> usize {
        self.bins[0] as usize * self.bins[1] as usize
    }

    /// Whether the grid has no cell (never for a valid one).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cell of `head` (`pitch index x bins[0] + yaw index`), clamped to the grid; `None`
    /// for a non-finite angle. The one rule for the board and the host (f32 throughout).
    pub fn bin(&self, head: [f32; 2]) -> Option<usize> {
        let mut idx = [0usize; 2];
        for a in 0..2 {
            if !head[a].is_finite() {
                return None;
            }
            let n = self.bins[a].max(1);
            let f = (head[a] - self.lo[a]) / (self.hi[a] - self.lo[a]) * n as f32;
            // `as` saturates (negative and NaN to 0); the min clamps the top.
            idx[a] = (f as usize).min(n as usize - 1);
        }
        Some(idx[1] * self.bins[0] as usize + idx[0])
    }

    /// Cells `1..=MAX_POSE_BINS` per angle and at least 2 in all, finite edges within
    /// `MAX_POSE_ANGLE`, `lo < hi`.
    pub fn is_valid(&self) -> bool {
        self.bins.iter().all(|&b| (1..=MAX_POSE_BINS).contains(&b))
            && self.len() >= 2
            && (0..2).all(|a| {
                self.lo[a].is_finite()
                    && self.hi[a].is_finite()
                    && self.lo[a] < self.hi[a]
                    && self.lo[a].abs() <= MAX_POSE_ANGLE
                    && self.hi[a].abs() <= MAX_POSE_ANGLE
            })
    }
}

/// Error statistics per cell of a [`PoseGrid`] (flag bit 5), borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseStats<'a> {
    /// The grid.
    pub grid: PoseGrid,
    /// Every cell's mu then sigma table in turn, each `stride` bytes.
    tables: &'a [u8],
    /// Bytes of one table with its padding.
    stride: usize,
    /// Bytes of one table's values (2 per pixel).
    len: usize,
}

impl<'a> PoseStats<'a> {
    /// Cell `bin`'s (mu, sigma) tables, Q8.8 grey levels; `None` past the grid.
    pub fn tables(&self, bin: usize) -> Option<(U16Table<'a>, U16Table<'a>)> {
        let at = |k: usize| {
            let start = k.checked_mul(self.stride)?;
            self.tables.get(start..start.checked_add(self.len)?).map(U16Table)
        };
        Some((at(2 * bin)?, at(2 * bin + 1)?))
    }
}

/// The self gate: before a reach, the board turns its head by `+amplitude` then `-amplitude`
/// (yaw, from where it is) and checks that the face's crop offset follows with the gain the
/// robot's own mirror image has (`firmware::self_gate`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SelfGate {
    /// Probe yaw offset, radians.
    pub amplitude: f32,
    /// Expected crop-offset x change per radian of head yaw (pixels/rad, signed).
    pub gain: f32,
    /// Largest relative error of the measured gain: `|measured / gain - 1|`.
    pub gain_tol: f32,
    /// Largest distance (pixels) of the resting face from the probe's line.
    pub rest_tol: f32,
    /// Largest x range (pixels) of the face while the head holds (at rest, at each pose).
    pub hold_tol: f32,
    /// Largest vertical move (pixels) of the face at a probe pose from its rest.
    pub level_tol: f32,
    /// With a return stage (layout 2): the probe ends back at the resting yaw the encoder
    /// reported, the poses' exact midpoint, and the face there must lie this close (pixels) to
    /// the poses' line. `None` (layouts 0 and 1): two stages, as before.
    pub line_tol: Option<f32>,
    /// With a return stage (layout 3): the most `sum((statistic / tolerance)^2)` over the gain
    /// (`|ratio - 1|` over `gain_tol`), rest, hold, level and line may reach. Each tolerance alone
    /// bounds one statistic (a box); the own image comes near one of them at a time, a stranger
    /// that gets inside the box by luck near several (`firmware::self_gate::joint`). `None`
    /// (layouts 0 to 2): the box alone.
    pub joint_tol: Option<f32>,
    /// The robot's own latency from a head pose to a frame showing it on the board, ms.
    pub latency_ms: u16,
    /// A probe not decided within this is undecided (no reach), ms.
    pub timeout_ms: u16,
    /// Frames needed at each probe pose.
    pub min_frames: u8,
}

impl SelfGate {
    /// Every field finite and in range.
    pub fn is_valid(&self) -> bool {
        self.amplitude > 0.0
            && self.amplitude <= MAX_GATE_AMPLITUDE
            && self.gain.is_finite()
            && self.gain.abs() >= 1.0
            && self.gain.abs() <= 10_000.0
            && self.gain_tol > 0.0
            && self.gain_tol < 1.0
            && [self.rest_tol, self.hold_tol, self.level_tol, self.line_tol.unwrap_or(1.0)].iter().all(|t| *t > 0.0 && *t <= 64.0)
            && self.joint_tol.is_none_or(|j| self.line_tol.is_some() && j > 0.0 && j <= 64.0)
            && (1..=1000).contains(&self.latency_ms)
            && (100..=MAX_GATE_TIMEOUT_MS).contains(&self.timeout_ms)
            && (1..=MAX_GATE_FRAMES).contains(&self.min_frames)
    }
}

/// One decoder layer, its tables borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Layer<'a> {
    /// What the layer computes.
    pub kind: LayerKind,
    /// Applied to the output before requantising.
    pub activation: Activation,
    /// `i8` or `i16` weights.
    pub weight_type: WeightType,
    /// Order of the stored weights (see the module notes); [`Layer::weight`] hides it.
    pub order: WeightOrder,
    /// Input shape; the previous layer's output.
    pub input: Shape,
    /// Output shape.
    pub output: Shape,
    /// Kernel size (square), convolutions only.
    pub kernel: u8,
    /// Convolution stride, or the upsampling factor of an UpConv.
    pub stride: u8,
    /// PyTorch-style padding of the convolution.
    pub padding: u8,
    /// First input row a Crop layer keeps.
    pub crop_top: u16,
    /// First input column a Crop layer keeps.
    pub crop_left: u16,
    /// Fraction bits of the weights.
    pub w_shift: i8,
    /// Fraction bits of the i16 input.
    pub in_shift: i8,
    /// Fraction bits of the i16 output.
    pub out_shift: i8,
    /// Raw little-endian weights; see [`Layer::weight`].
    pub weights: &'a [u8],
    /// Raw little-endian i32 biases; see [`Layer::bias`].
    pub bias: &'a [u8],
}

impl<'a> Layer<'a> {
    /// Number of weights.
    pub fn weight_count(&self) -> usize {
        self.weights.len() / self.weight_type.size()
    }

    /// Weight `i` (PyTorch index) as an integer. Panics if out of range, like slice indexing.
    #[inline]
    pub fn weight(&self, i: usize) -> i32 {
        let i = self.stored_index(i);
        match self.weight_type {
            WeightType::I8 => self.weights[i] as i8 as i32,
            WeightType::I16 => {
                i16::from_le_bytes([self.weights[2 * i], self.weights[2 * i + 1]]) as i32
            }
        }
    }

    /// Where weight `i` (PyTorch index) is stored in [`Layer::weights`].
    #[inline]
    pub fn stored_index(&self, i: usize) -> usize {
        match self.order {
            WeightOrder::Torch => i,
            WeightOrder::Blocked => {
                let n_in = self.input.len();
                let (c_n, hw) = (self.output.c as usize, self.output.h as usize * self.output.w as usize);
                let (o, j) = (i / n_in, i % n_in);
                let (c, px) = (o / hw, o % hw);
                ((px * (n_in / BLOCK) + j / BLOCK) * c_n + c) * BLOCK + j % BLOCK
            }
        }
    }

    /// The raw tables ([`Layer::weights_i16`], [`Layer::weights_i8`]) are in PyTorch order.
    pub fn torch_order(&self) -> bool {
        self.order == WeightOrder::Torch
    }

    /// Number of biases (per output element for Dense, per output channel for convolutions).
    pub fn bias_count(&self) -> usize {
        self.bias.len() / 4
    }

    /// Bias `i` (PyTorch index).
    #[inline]
    pub fn bias(&self, i: usize) -> i32 {
        let i = match self.order {
            WeightOrder::Torch => i,
            WeightOrder::Blocked => {
                let hw = self.output.h as usize * self.output.w as usize;
                (i % hw) * self.output.c as usize + i / hw
            }
        };
        let b = &self.bias[4 * i..4 * i + 4];
        i32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// The i16 weights as a slice, when the blob sits 2-byte aligned in memory, in the stored
    /// order (see [`Layer::torch_order`]).
    #[cfg(target_endian = "little")]
    pub fn weights_i16(&self) -> Option<&'a [i16]> {
        match self.weight_type {
            WeightType::I16 => bytemuck::try_cast_slice(self.weights).ok(),
            WeightType::I8 => None,
        }
    }

    /// The i8 weights as a slice, in the stored order.
    pub fn weights_i8(&self) -> Option<&'a [i8]> {
        match self.weight_type {
            WeightType::I8 => Some(bytemuck::cast_slice(self.weights)),
            WeightType::I16 => None,
        }
    }

    /// The biases as a slice, when the blob sits 4-byte aligned in memory, in the stored order.
    #[cfg(target_endian = "little")]
    pub fn bias_i32(&self) -> Option<&'a [i32]> {
        bytemuck::try_cast_slice(self.bias).ok()
    }

    /// Multiply-accumulates of one inference of this layer.
    pub fn macs(&self) -> u64 {
        let k2 = self.kernel as u64 * self.kernel as u64;
        match self.kind {
            LayerKind::Dense => self.input.len() as u64 * self.output.len() as u64,
            LayerKind::ConvTranspose2d => self.input.len() as u64 * self.output.c as u64 * k2,
            LayerKind::UpConv => self.output.len() as u64 * self.input.c as u64 * k2,
            LayerKind::Crop => 0,
        }
    }
}

/// A table of u16 values borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct U16Table<'a>(pub &'a [u8]);

impl<'a> U16Table<'a> {
    /// Number of values.
    pub fn len(&self) -> usize {
        self.0.len() / 2
    }
    /// Whether the table holds no values.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    #[inline]
    /// Value `i`. Panics if out of range, like slice indexing.
    pub fn get(&self, i: usize) -> u16 {
        u16::from_le_bytes([self.0[2 * i], self.0[2 * i + 1]])
    }
    /// The values in order.
    pub fn iter(&self) -> impl Iterator<Item = u16> + 'a {
        self.0.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]]))
    }
}

/// The reach network 2-10-5 (sigmoid, sigmoid) with min-max scaling on both sides. Copied out of
/// the blob: it is small and the firmware runs it in f32.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// Hidden layer weights, `[hidden][input]`.
    pub w1: [[f32; REACH_IN]; REACH_HIDDEN],
    /// Hidden layer biases.
    pub b1: [f32; REACH_HIDDEN],
    /// Output layer weights, `[output][hidden]`.
    pub w2: [[f32; REACH_HIDDEN]; REACH_OUT],
    /// Output layer biases.
    pub b2: [f32; REACH_OUT],
    /// Input value mapped to 0: `u = (v - in_min) / (in_max - in_min)`; pixels.
    pub in_min: [f32; REACH_IN],
    /// Input value mapped to 1; pixels. Each `in_min < in_max`.
    pub in_max: [f32; REACH_IN],
    /// Joint angle for output 0: `angle = o * (out_max - out_min) + out_min`; radians.
    pub out_min: [f32; REACH_OUT],
    /// Joint angle for output 1, radians. Each `out_min < out_max`.
    pub out_max: [f32; REACH_OUT],
}

impl Reach {
    fn to_floats(self) -> [f32; REACH_FLOATS] {
        let mut v = [0f32; REACH_FLOATS];
        let mut i = 0;
        let mut put = |x: f32| {
            v[i] = x;
            i += 1;
        };
        self.w1.iter().flatten().for_each(|&x| put(x));
        self.b1.iter().for_each(|&x| put(x));
        self.w2.iter().flatten().for_each(|&x| put(x));
        self.b2.iter().for_each(|&x| put(x));
        self.in_min.iter().for_each(|&x| put(x));
        self.in_max.iter().for_each(|&x| put(x));
        self.out_min.iter().for_each(|&x| put(x));
        self.out_max.iter().for_each(|&x| put(x));
        v
    }

    fn from_floats(v: &[f32; REACH_FLOATS]) -> Reach {
        let mut it = v.iter().copied();
        let mut next = || it.next().unwrap_or(0.0);
        let mut r = Reach {
            w1: [[0.0; REACH_IN]; REACH_HIDDEN],
            b1: [0.0; REACH_HIDDEN],
            w2: [[0.0; REACH_HIDDEN]; REACH_OUT],
            b2: [0.0; REACH_OUT],
            in_min: [0.0; REACH_IN],
            in_max: [0.0; REACH_IN],
            out_min: [0.0; REACH_OUT],
            out_max: [0.0; REACH_OUT],
        };
        r.w1.iter_mut().flatten().for_each(|x| *x = next());
        r.b1.iter_mut().for_each(|x| *x = next());
        r.w2.iter_mut().flatten().for_each(|x| *x = next());
        r.b2.iter_mut().for_each(|x| *x = next());
        r.in_min.iter_mut().for_each(|x| *x = next());
        r.in_max.iter_mut().for_each(|x| *x = next());
        r.out_min.iter_mut().for_each(|x| *x = next());
        r.out_max.iter_mut().for_each(|x| *x = next());
        r
    }

    fn is_valid(&self) -> bool {
        let v = self.to_floats();
        v.iter().all(|x| x.is_finite())
            && self.in_min.iter().zip(&self.in_max).all(|(a, b)| a < b)
            && self.out_min.iter().zip(&self.out_max).all(|(a, b)| a < b)
    }
}

/// The face template the host crops with, borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Template<'a> {
    /// Template height, pixels.
    pub h: u16,
    /// Template width, pixels.
    pub w: u16,
    /// `h * w` grey bytes, row-major.
    pub pixels: &'a [u8],
    /// How the host crops with it (flag bit 1).
    pub crop: CropMode,
}

/// A validated model blob.
#[derive(Clone, Debug, PartialEq)]
pub struct Model<'a> {
    /// Face crop height the model expects, pixels (`1..=MAX_FACE_H`).
    pub face_h: u16,
    /// Face crop width the model expects, pixels (`1..=MAX_FACE_W`).
    pub face_w: u16,
    /// Threshold, normalisation and blob settings.
    pub novelty: Novelty,
    /// The decoder, head angles in, predicted face out.
    pub layers: heapless::Vec<Layer<'a>, MAX_LAYERS>,
    /// Mean prediction error per pixel, Q8.8 grey levels, row-major.
    pub mu: U16Table<'a>,
    /// Its standard deviation per pixel, Q8.8 grey levels, row-major.
    pub sigma: U16Table<'a>,
    /// The reach network, mark centroid to joint angles.
    pub reach: Reach,
    /// Settings of their own near one head pose (flag bit 2).
    pub region: Option<PoseRegion>,
    /// The face template the host crops with (flag bit 0).
    pub template: Option<Template<'a>>,
    /// The self gate (flag bit 3); `None`: confirmed marks are reached at once, as the paper.
    pub self_gate: Option<SelfGate>,
    /// Error statistics per head-pose cell (flag bit 5); `None`: [`Model::mu`] and
    /// [`Model::sigma`] at every pose.
    pub pose: Option<PoseStats<'a>>,
    /// The CRC-32 from the header: the model's identity.
    pub crc32: u32,
    /// Where the self-gate section starts (its length depends on its layout).
    gate_at: usize,
}

/// Bounds-checked little-endian reads; every failure is [`BlobError::Truncated`].
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], BlobError> {
        let end = self.pos.checked_add(n).ok_or(BlobError::Truncated)?;
        let s = self.buf.get(self.pos..end).ok_or(BlobError::Truncated)?;
        self.pos = end;
        Ok(s)
    }
    /// Takes `n` bytes and skips padding to the next multiple of 4.
    fn take_padded(&mut self, n: usize) -> Result<&'a [u8], BlobError> {
        let s = self.take(n)?;
        let pad = (4 - n % 4) % 4;
        self.take(pad)?;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, BlobError> {
        Ok(self.take(1)?[0])
    }
    fn i8(&mut self) -> Result<i8, BlobError> {
        Ok(self.u8()? as i8)
    }
    fn u16(&mut self) -> Result<u16, BlobError> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, BlobError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn f32(&mut self) -> Result<f32, BlobError> {
        Ok(f32::from_bits(self.u32()?))
    }
}

fn checked_mul(a: usize, b: usize, e: BlobError) -> Result<usize, BlobError> {
    a.checked_mul(b).ok_or(e)
}

impl<'a> Model<'a> {
    /// Validates a blob and borrows its tables. Nothing in `bytes` is trusted.
    pub fn parse(bytes: &'a [u8]) -> Result<Model<'a>, BlobError> {
        Self::parse_inner(bytes, true)
    }

    /// [`Model::parse`] without the CRC pass, for a blob that `parse` accepted before and that
    /// has not changed since: the board re-borrows its running model for every frame, and the
    /// CRC of a large blob would cost more than the rest of the frame. Every other check runs.
    pub fn parse_trusted(bytes: &'a [u8]) -> Result<Model<'a>, BlobError> {
        Self::parse_inner(bytes, false)
    }

    fn parse_inner(bytes: &'a [u8], check_crc: bool) -> Result<Model<'a>, BlobError> {
        if bytes.len() < HEADER_LEN {
            return Err(BlobError::Truncated);
        }
        let mut r = Reader { buf: bytes, pos: 0 };
        if r.take(4)? != MAGIC {
            return Err(BlobError::BadMagic);
        }
        let version = r.u16()?;
        if !(1..=VERSION).contains(&version) {
            return Err(BlobError::UnsupportedVersion(version));
        }
        if r.u16()? as usize != HEADER_LEN {
            return Err(BlobError::BadHeader);
        }
        let total = r.u32()? as usize;
        if total > bytes.len() {
            return Err(BlobError::Truncated);
        }
        if total != bytes.len() {
            return Err(BlobError::LengthMismatch);
        }
        let crc = r.u32()?;
        if check_crc && CRC32.checksum(&bytes[16..]) != crc {
            return Err(BlobError::Crc);
        }
        let face_h = r.u16()?;
        let face_w = r.u16()?;
        if face_h == 0 || face_w == 0 || face_h as usize > MAX_FACE_H || face_w as usize > MAX_FACE_W
        {
            return Err(BlobError::FaceSize);
        }
        let n_layers = r.u16()? as usize;
        if n_layers == 0 || n_layers > MAX_LAYERS {
            return Err(BlobError::TooManyLayers);
        }
        let flags = r.u16()?;
        if flags & !(FLAG_TEMPLATE | FLAG_SUBPIXEL | FLAG_REGION | FLAG_SELF_GATE | FLAG_POOL | FLAG_POSE) != 0
            || (flags & FLAG_SUBPIXEL != 0 && (version < 4 || flags & FLAG_TEMPLATE == 0))
            || (flags & FLAG_REGION != 0 && version < 4)
            || (flags & (FLAG_SELF_GATE | FLAG_POOL | FLAG_POSE) != 0) != (version >= 5)
        {
            return Err(BlobError::BadHeader);
        }
        let threshold = r.f32()?;
        let normalisation = match r.u8()? {
            0 => Normalisation::StdDev,
            1 => Normalisation::Variance,
            _ => return Err(BlobError::Novelty),
        };
        let sided = match r.u8()? {
            0 => Sided::One,
            1 => Sided::Two,
            _ => return Err(BlobError::Novelty),
        };
        let min_area = r.u16()?;
        let sigma_floor = r.f32()?;
        if !(threshold.is_finite() && threshold > 0.0)
            || min_area == 0
            || !(sigma_floor.is_finite() && sigma_floor >= 0.0)
        {
            return Err(BlobError::Novelty);
        }
        let merge_margin = r.u8()?;
        let pool = r.u8()?;
        let merge = Merge { margin: merge_margin, fragment: r.u16()? };
        if (flags & FLAG_POOL == 0 && pool != 0) || (version < 3 && merge != Merge::OFF) {
            return Err(BlobError::BadHeader);
        }
        if flags & FLAG_POOL != 0 && !(1..=MAX_POOL).contains(&pool) {
            return Err(BlobError::Novelty);
        }
        if !merge.is_valid(min_area) {
            return Err(BlobError::Novelty);
        }

        let mut layers = heapless::Vec::new();
        let mut prev = Shape { c: 2, h: 1, w: 1 };
        for i in 0..n_layers {
            let layer = parse_layer(&mut r, i as u8)?;
            if version < 2 && layer.order != WeightOrder::Torch {
                return Err(BlobError::BadLayer(i as u8));
            }
            if i == 0 {
                if layer.input.len() != 2 || layer.kind != LayerKind::Dense {
                    return Err(BlobError::ModelShape);
                }
            } else if layer.input != prev
                && !(layer.kind == LayerKind::Dense && layer.input.len() == prev.len())
            {
                return Err(BlobError::Chain(i as u8));
            }
            let last = i + 1 == n_layers;
            if !last && layer.output.len() > MAX_ACTIVATION_LEN {
                return Err(BlobError::ActivationTooLarge(i as u8));
            }
            prev = layer.output;
            // Cannot fail: n_layers <= MAX_LAYERS was checked.
            let _ = layers.push(layer);
        }
        if prev != (Shape { c: 1, h: face_h, w: face_w }) {
            return Err(BlobError::ModelShape);
        }

        let pixels = face_h as usize * face_w as usize;
        let mu = U16Table(r.take_padded(2 * pixels)?);
        let sigma = U16Table(r.take_padded(2 * pixels)?);

        let mut floats = [0f32; REACH_FLOATS];
        for f in floats.iter_mut() {
            *f = r.f32()?;
        }
        let reach = Reach::from_floats(&floats);
        if !reach.is_valid() {
            return Err(BlobError::Reach);
        }
        let region = if flags & FLAG_REGION != 0 {
            let centre = [r.f32()?, r.f32()?];
            let (radius, threshold) = (r.f32()?, r.f32()?);
            let margin = r.u8()?;
            if r.u8()? != 0 {
                return Err(BlobError::BadHeader);
            }
            let merge = Merge { margin, fragment: r.u16()? };
            let region = PoseRegion { centre, radius, threshold, merge };
            if !region.is_valid(min_area) {
                return Err(BlobError::Novelty);
            }
            Some(region)
        } else {
            None
        };

        let template = if flags & FLAG_TEMPLATE != 0 {
            let h = r.u16()?;
            let w = r.u16()?;
            let n = h as usize * w as usize;
            if h == 0 || w == 0 || n > MAX_TEMPLATE_PIXELS {
                return Err(BlobError::Template);
            }
            let crop = if flags & FLAG_SUBPIXEL != 0 {
                CropMode::Subpixel
            } else {
                CropMode::Pixel
            };
            Some(Template { h, w, pixels: r.take_padded(n)?, crop })
        } else {
            None
        };
        let pose = if flags & FLAG_POSE != 0 {
            let bins = [r.u8()?, r.u8()?];
            if r.u16()? != 0 {
                return Err(BlobError::BadHeader);
            }
            let (yaw_lo, yaw_hi, pitch_lo, pitch_hi) = (r.f32()?, r.f32()?, r.f32()?, r.f32()?);
            let grid = PoseGrid { bins, lo: [yaw_lo, pitch_lo], hi: [yaw_hi, pitch_hi] };
            if !grid.is_valid() {
                return Err(BlobError::PoseStats);
            }
            let len = 2 * pixels;
            let stride = len + (4 - len % 4) % 4;
            // At most 2 x 16 tables of MAX_FACE_PIXELS: no overflow.
            let tables = r.take(2 * grid.len() * stride)?;
            Some(PoseStats { grid, tables, stride, len })
        } else {
            None
        };
        let gate_at = r.pos;
        let self_gate = if flags & FLAG_SELF_GATE != 0 {
            let (amplitude, gain, gain_tol, rest_tol) = (r.f32()?, r.f32()?, r.f32()?, r.f32()?);
            let (latency_ms, timeout_ms, min_frames) = (r.u16()?, r.u16()?, r.u8()?);
            let layout = r.u8()?;
            if r.take(2)? != [0; 2] {
                return Err(BlobError::BadHeader);
            }
            let (hold_tol, level_tol, line_tol, joint_tol) = match layout {
                0 => (rest_tol, rest_tol, None, None),
                1 => (r.f32()?, r.f32()?, None, None),
                2 => (r.f32()?, r.f32()?, Some(r.f32()?), None),
                3 => (r.f32()?, r.f32()?, Some(r.f32()?), Some(r.f32()?)),
                _ => return Err(BlobError::BadHeader),
            };
            let g = SelfGate { amplitude, gain, gain_tol, rest_tol, hold_tol, level_tol, line_tol, joint_tol, latency_ms, timeout_ms, min_frames };
            if !g.is_valid() {
                return Err(BlobError::SelfGate);
            }
            Some(g)
        } else {
            None
        };
        if r.pos != bytes.len() {
            return Err(BlobError::TrailingBytes);
        }
        Ok(Model {
            face_h,
            face_w,
            novelty: Novelty { threshold, normalisation, sided, min_area, sigma_floor, merge, pool },
            layers,
            mu,
            sigma,
            reach,
            region,
            template,
            self_gate,
            pose,
            crc32: crc,
            gate_at,
        })
    }

    /// Pixels of a face crop, `face_h * face_w`.
    pub fn face_pixels(&self) -> usize {
        self.face_h as usize * self.face_w as usize
    }

    /// The (mu, sigma) tables for a face seen with the head at `head`, and which they are: 0
    /// for the header's tables (no pose statistics, or a non-finite pose), `1 + cell` for a
    /// cell's of [`Model::pose`].
    pub fn stats_at(&self, head: [f32; 2]) -> (U16Table<'a>, U16Table<'a>, u8) {
        if let Some(p) = &self.pose {
            if let Some((bin, (mu, sigma))) = p.grid.bin(head).and_then(|b| Some((b, p.tables(b)?))) {
                return (mu, sigma, 1 + bin as u8);
            }
        }
        (self.mu, self.sigma, 0)
    }

    /// Multiply-accumulates of one decoder inference.
    pub fn decoder_macs(&self) -> u64 {
        self.layers.iter().map(|l| l.macs()).sum()
    }
}

fn parse_layer<'a>(r: &mut Reader<'a>, i: u8) -> Result<Layer<'a>, BlobError> {
    let bad = BlobError::BadLayer(i);
    let shape_err = BlobError::LayerShape(i);
    let kind = match r.u8()? {
        0 => LayerKind::Dense,
        1 => LayerKind::ConvTranspose2d,
        2 => LayerKind::UpConv,
        3 => LayerKind::Crop,
        _ => return Err(bad),
    };
    let activation = match r.u8()? {
        0 => Activation::Identity,
        1 => Activation::Tanh,
        2 => Activation::Sigmoid,
        3 => Activation::Relu,
        _ => return Err(bad),
    };
    let weight_type = match r.u8()? {
        1 => WeightType::I8,
        2 => WeightType::I16,
        _ => return Err(bad),
    };
    let order = match r.u8()? {
        0 => WeightOrder::Torch,
        1 => WeightOrder::Blocked,
        _ => return Err(bad),
    };
    let input = Shape { c: r.u16()?, h: r.u16()?, w: r.u16()? };
    let output = Shape { c: r.u16()?, h: r.u16()?, w: r.u16()? };
    let kernel = r.u8()?;
    let stride = r.u8()?;
    let padding = r.u8()?;
    if r.u8()? != 0 {
        return Err(bad);
    }
    let crop_top = r.u16()?;
    let crop_left = r.u16()?;
    let w_shift = r.i8()?;
    let in_shift = r.i8()?;
    let out_shift = r.i8()?;
    if r.u8()? != 0 {
        return Err(bad);
    }
    // Shifts outside 0..=31 would make the fixed-point arithmetic overflow or lose everything.
    if !(0..=31).contains(&w_shift) || !(0..=31).contains(&in_shift) || !(0..=31).contains(&out_shift)
    {
        return Err(bad);
    }
    let weight_bytes = r.u32()? as usize;
    if input.is_empty() || output.is_empty() {
        return Err(shape_err);
    }
    if order == WeightOrder::Blocked && (kind != LayerKind::Dense || !input.len().is_multiple_of(BLOCK))
    {
        return Err(bad);
    }
    let (k, s, p) = (kernel as usize, stride as usize, padding as usize);
    let (weights, bias) = match kind {
        LayerKind::Dense => (
            checked_mul(input.len(), output.len(), shape_err)?,
            output.len(),
        ),
        LayerKind::ConvTranspose2d => {
            if input.c == 0 || k == 0 || s == 0 {
                return Err(shape_err);
            }
            // (in - 1) * s - 2p + k, without going negative.
            let want = |n: u16| ((n as usize - 1) * s + k).checked_sub(2 * p);
            if want(input.h) != Some(output.h as usize) || want(input.w) != Some(output.w as usize)
            {
                return Err(shape_err);
            }
            (input.c as usize * output.c as usize * k * k, output.c as usize)
        }
        LayerKind::UpConv => {
            if k == 0 || s == 0 {
                return Err(shape_err);
            }
            // in * s + 2p - k + 1.
            let want = |n: u16| (n as usize * s + 2 * p + 1).checked_sub(k);
            if want(input.h) != Some(output.h as usize) || want(input.w) != Some(output.w as usize)
            {
                return Err(shape_err);
            }
            (input.c as usize * output.c as usize * k * k, output.c as usize)
        }
        LayerKind::Crop => {
            if input.c != output.c
                || crop_top as usize + output.h as usize > input.h as usize
                || crop_left as usize + output.w as usize > input.w as usize
                || activation != Activation::Identity
            {
                return Err(shape_err);
            }
            (0, 0)
        }
    };
    if checked_mul(weights, weight_type.size(), shape_err)? != weight_bytes {
        return Err(shape_err);
    }
    let weights = r.take_padded(weight_bytes)?;
    let bias = r.take(4 * bias)?;
    Ok(Layer {
        kind,
        activation,
        weight_type,
        order,
        input,
        output,
        kernel,
        stride,
        padding,
        crop_top,
        crop_left,
        w_shift,
        in_shift,
        out_shift,
        weights,
        bias,
    })
}

#[cfg(any(feature = "std", test))]
pub use writer::*;

#[cfg(any(feature = "std", test))]
mod writer;

#[cfg(test)]
mod tests;
