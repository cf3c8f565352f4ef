//! Face frames on the host link: chunk sizes, crop position, header, missing chunks, the ack.
use serde::{Deserialize, Serialize};

/// Largest data chunk in a frame or model chunk message.
pub const CHUNK: usize = 224;
/// Smallest face chunk a host may choose.
pub const MIN_CHUNK: usize = 24;
/// Most chunks in one face frame.
pub const MAX_FRAME_CHUNKS: usize = 256;
/// Bytes of a [`ChunkSet`].
pub const BITMAP_BYTES: usize = MAX_FRAME_CHUNKS / 8;
/// Largest face image on the link: the largest grey face and its two chroma planes.
pub const MAX_FRAME_BYTES: usize = crate::blob::MAX_FACE_PIXELS
    + 2 * crate::blob::chroma::blocks(crate::blob::MAX_FACE_H, crate::blob::MAX_FACE_W);
/// A frame id this many or more behind the board's current one is a restarted host, not stale.
pub const STALE_WINDOW: u16 = 64;

/// Steps of [`FrameHeader::crop_sub`] per pixel.
pub const SUB_PER_PX: i8 = 64;
/// Largest [`FrameHeader::crop_sub`] either way: one pixel (the face lies within half a pixel
/// of where it was cut, and that within half a pixel of `crop_x`).
pub const SUB_MAX: i8 = SUB_PER_PX;

/// The sub-pixel part of a crop position `shift` pixels off the whole-pixel one, in
/// [`FrameHeader::crop_sub`]'s steps (rounded, clamped to a pixel; 0 when not finite).
pub fn crop_sub(shift: f32) -> i8 {
    if !shift.is_finite() {
        return 0;
    }
    let v = (shift * SUB_PER_PX as f32).clamp(-(SUB_MAX as f32), SUB_MAX as f32);
    // Round half away from zero (`f32::round` is not in `core`).
    (v + if v >= 0.0 { 0.5 } else { -0.5 }) as i8
}

/// Where a face crop was cut in the full frame: whole pixels and the sub-pixel rest, as the
/// frame header carries them. A `[u16; 2]` is a whole-pixel crop.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CropAt {
    /// `crop_x`, `crop_y`.
    pub px: [u16; 2],
    /// `crop_sub`.
    pub sub: [i8; 2],
}

impl CropAt {
    /// A crop at whole pixels `px`, the face `shift` pixels off them (within a pixel).
    pub fn subpixel(px: [u16; 2], shift: [f32; 2]) -> CropAt {
        CropAt { px, sub: shift.map(crop_sub) }
    }
}

impl From<[u16; 2]> for CropAt {
    fn from(px: [u16; 2]) -> CropAt {
        CropAt { px, sub: [0; 2] }
    }
}

/// Announces a face image; its pixels follow in
/// [`HostToBoard::FrameChunk`](super::HostToBoard::FrameChunk)s.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameHeader {
    /// Frame number chosen by the host; chunks name it.
    pub frame: u16,
    /// Where the face crop sits in the full camera frame (pixels), for full-frame reports and
    /// the reach network's input; the nearest whole pixel when the host cropped at sub-pixel
    /// precision (`blob::CropMode::Subpixel`), so within half a pixel of where it was cut.
    pub crop_x: u16,
    /// See `crop_x`.
    pub crop_y: u16,
    /// Where the face lies relative to `crop_x`, `crop_y`, `[x, y]` in 1/[`SUB_PER_PX`] pixel,
    /// within +-[`SUB_MAX`] (a pixel): the face lies at `crop_x + crop_sub[0] / SUB_PER_PX`,
    /// as the host's template alignment finds it (the crop itself was cut within half a pixel
    /// of `crop_x`). Zero for a whole-pixel crop. The self gate follows the face to a fraction
    /// of a pixel.
    pub crop_sub: [i8; 2],
    /// Crop size; must equal the model's face size.
    pub width: u16,
    /// Crop height in pixels; must equal the model's face height.
    pub height: u16,
    /// Chunk size of this frame, [`MIN_CHUNK`]`..=`[`CHUNK`].
    pub chunk: u16,
    /// CRC-32 (ISO-HDLC, as blobs) of the whole image.
    pub crc32: u32,
    /// The image carries the face's chroma planes after its grey bytes (`Cb` then `Cr`, one
    /// byte a 2 x 2 block: [`crate::blob::chroma`]), for a model with chroma.
    pub colour: bool,
}

impl FrameHeader {
    /// Pixels in the image: its grey bytes.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Bytes of the image: its grey bytes, then its chroma planes when it has them.
    pub fn bytes(&self) -> usize {
        let planes = if self.colour { 2 * crate::blob::chroma::blocks(self.height as usize, self.width as usize) } else { 0 };
        self.pixels() + planes
    }

    /// Chunks the image travels in (0 when `chunk` is 0).
    pub fn chunks(&self) -> usize {
        if self.chunk == 0 {
            return 0;
        }
        self.bytes().div_ceil(self.chunk as usize)
    }

    /// Chunk size in range, at most [`MAX_FRAME_CHUNKS`] chunks, a non-empty image, the
    /// sub-pixel part within a pixel.
    pub fn is_valid(&self) -> bool {
        (MIN_CHUNK..=CHUNK).contains(&(self.chunk as usize))
            && self.pixels() > 0
            && self.chunks() <= MAX_FRAME_CHUNKS
            && self.crop_sub.iter().all(|s| s.unsigned_abs() <= SUB_MAX as u8)
    }

    /// Where the face crop sits in the full frame, `[x, y]` pixels, sub-pixel part included.
    pub fn position(&self) -> [f32; 2] {
        [
            self.crop_x as f32 + self.crop_sub[0] as f32 / SUB_PER_PX as f32,
            self.crop_y as f32 + self.crop_sub[1] as f32 / SUB_PER_PX as f32,
        ]
    }

    /// Where chunk `i` lies in the image.
    pub fn chunk_range(&self, i: usize) -> core::ops::Range<usize> {
        let start = i * self.chunk as usize;
        start.min(self.bytes())..(start + self.chunk as usize).min(self.bytes())
    }

    /// Is `frame` older than this header's frame by less than [`STALE_WINDOW`]?
    pub fn is_stale(&self, frame: u16) -> bool {
        is_older(frame, self.frame)
    }
}

/// Is frame id `a` behind `b` by 1 to [`STALE_WINDOW`]` - 1` (wrapping)?
pub fn is_older(a: u16, b: u16) -> bool {
    let back = b.wrapping_sub(a);
    back != 0 && back < STALE_WINDOW
}

/// One bit per chunk of a face frame, [`MAX_FRAME_CHUNKS`] of them. On the wire: the bitmap up
/// to its last non-zero byte, with a length (an ack is short when few chunks are missing, and a
/// short ack is less likely to be hit on a noisy line).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(into = "Trimmed", from = "Trimmed")]
pub struct ChunkSet([u8; BITMAP_BYTES]);

type Trimmed = heapless::Vec<u8, BITMAP_BYTES>;

impl From<ChunkSet> for Trimmed {
    fn from(s: ChunkSet) -> Trimmed {
        let used = s.0.iter().rposition(|b| *b != 0).map_or(0, |i| i + 1);
        Trimmed::from_slice(&s.0[..used]).unwrap_or_default()
    }
}

impl From<Trimmed> for ChunkSet {
    fn from(v: Trimmed) -> ChunkSet {
        let mut s = ChunkSet::EMPTY;
        s.0[..v.len()].copy_from_slice(&v);
        s
    }
}

impl ChunkSet {
    /// No chunks.
    pub const EMPTY: ChunkSet = ChunkSet([0; BITMAP_BYTES]);

    /// Chunks `0..n`.
    pub fn first(n: usize) -> ChunkSet {
        let mut s = ChunkSet::EMPTY;
        for i in 0..n.min(MAX_FRAME_CHUNKS) {
            s.insert(i);
        }
        s
    }

    /// Whether chunk `i` is a member (false for `i` >= [`MAX_FRAME_CHUNKS`]).
    pub fn contains(&self, i: usize) -> bool {
        i < MAX_FRAME_CHUNKS && self.0[i / 8] & (1 << (i % 8)) != 0
    }

    /// Adds chunk `i`; ignored for `i` >= [`MAX_FRAME_CHUNKS`].
    pub fn insert(&mut self, i: usize) {
        if i < MAX_FRAME_CHUNKS {
            self.0[i / 8] |= 1 << (i % 8);
        }
    }

    /// Removes `i`; returns whether it was there.
    pub fn remove(&mut self, i: usize) -> bool {
        let had = self.contains(i);
        if had {
            self.0[i / 8] &= !(1 << (i % 8));
        }
        had
    }

    /// Number of members.
    pub fn len(&self) -> usize {
        self.0.iter().map(|b| b.count_ones() as usize).sum()
    }

    /// No members.
    pub fn is_empty(&self) -> bool {
        self.0.iter().all(|b| *b == 0)
    }

    /// The smallest member.
    pub fn first_member(&self) -> Option<usize> {
        let (byte, b) = self.0.iter().enumerate().find(|(_, b)| **b != 0)?;
        Some(byte * 8 + b.trailing_zeros() as usize)
    }

    /// The members in increasing order.
    pub fn iter(&self) -> impl Iterator<Item = usize> + '_ {
        (0..MAX_FRAME_CHUNKS).filter(|i| self.contains(*i))
    }

    /// The bitmap, bit `i % 8` of byte `i / 8` for chunk `i`.
    pub fn bytes(&self) -> &[u8; BITMAP_BYTES] {
        &self.0
    }
}

/// Where a face frame stands on the board.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FrameState {
    /// All chunks arrived and the image passed its CRC-32; the pipeline ran on it once.
    Complete,
    /// In progress: these chunks are missing.
    Missing(ChunkSet),
    /// An older frame than the one in progress: it will never be processed.
    Stale,
}

/// The board's answer about one face frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameAck {
    /// The face frame's id, as in its [`FrameHeader`].
    pub frame: u16,
    /// The `FramePoll` round answered; 0 for acks the last chunk or completion triggered.
    pub round: u8,
    /// Complete, stale, or the chunks still missing.
    pub state: FrameState,
}
