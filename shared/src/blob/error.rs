//! Why a blob was refused, and the code the board reports for it.

use super::{VERSION, MAX_FACE_H, MAX_FACE_W, MAX_LAYERS, MAX_ACTIVATION_LEN};
use core::fmt;

/// Why a blob was refused. [`BlobError::code`] is what the board reports over the link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlobError {
    /// Fewer bytes than the header, or than `total_len` says.
    Truncated,
    /// The first 4 bytes are not [`MAGIC`](super::MAGIC).
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
    /// The template is 0 pixels high or wide, or over
    /// [`MAX_TEMPLATE_PIXELS`](super::MAX_TEMPLATE_PIXELS).
    Template,
    /// Bytes left over after the last section.
    TrailingBytes,
    /// Self-gate parameters out of range.
    SelfGate,
    /// A pose-statistics grid out of range.
    PoseStats,
    /// Chroma threshold or reference out of range, or a zero spread.
    Chroma,
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
            BlobError::Chroma => 20,
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
            BlobError::Chroma => f.write_str("chroma threshold or reference out of range, or a zero spread"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for BlobError {}
