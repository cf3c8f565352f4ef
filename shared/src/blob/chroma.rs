//! The face's colour (flag bit 7): what colour each 2 x 2 block of the face should have.
//!
//! A camera gives colour as two chroma planes beside the grey (YCbCr, as a webcam's YUV 4:2:0
//! or MJPEG frames carry it). A mark whose grey level matches the face's but whose hue does
//! not is invisible to the grey error and plain in chroma. Chroma scales with the light, so the
//! board divides it by the block's grey level ([`normalise`]): the ratio stays the same when the
//! light dims, and a white balance moves it the same way across the whole face (the board takes
//! that shift out per frame).
//!
//! Link: after the `face_h x face_w` grey bytes come the block's `Cb` plane then its `Cr`
//! plane, [`blocks`] bytes each (block `(i, j)` covers face rows `2i, 2i + 1` and columns
//! `2j, 2j + 1`, one row or column at an odd edge): BT.601 full-range chroma, 128 neutral, the
//! mean over the block's pixels.

/// Units of the normalised chroma per unit ratio `(C - 128) / grey`.
pub const SCALE: i32 = 32;
/// Grey level added to the block's before the division: the darkest blocks' chroma is mostly
/// the camera's noise, and the offset keeps their ratio from growing without bound.
pub const DARK: i32 = 8;
/// [`Chroma::spread`]'s unit: sixteenths of a normalised chroma unit.
pub const SPREAD_ONE: u8 = 16;
/// Largest [`Chroma::threshold`], in spreads.
pub const MAX_THRESHOLD: f32 = 64.0;
/// Largest [`Chroma::spread_ref`].
pub const MAX_SPREAD_REF: f32 = 255.0 / 16.0;

/// Chroma blocks of an `h x w` face: `ceil(h / 2) x ceil(w / 2)`.
pub const fn blocks(h: usize, w: usize) -> usize {
    h.div_ceil(2) * w.div_ceil(2)
}

/// The normalised chroma of one block: `round(SCALE (c - 128) n / (grey_sum + DARK n))`
/// clamped to `-127..=127`, for a block of `n` pixels whose grey levels sum to `grey_sum`.
pub fn normalise(c: u8, grey_sum: u32, n: u32) -> i8 {
    let num = SCALE * (c as i32 - 128) * n as i32;
    let den = grey_sum as i32 + DARK * n as i32;
    if den <= 0 {
        return 0;
    }
    // Rounded half away from zero.
    let q = (2 * num.abs() + den) / (2 * den);
    (if num < 0 { -q } else { q }).clamp(-127, 127) as i8
}

/// The chroma section, borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chroma<'a> {
    /// A block is salient when its chroma error, less the frame's shift, exceeds this many of
    /// its spreads (finite, `0 < threshold <= MAX_THRESHOLD`).
    pub threshold: f32,
    /// The median over the statistics' frames of each block's squared error over its spread
    /// squared (`0 < spread_ref <= MAX_SPREAD_REF`): a frame whose own median is larger (a
    /// noisier camera, compression) widens every spread by the ratio.
    pub spread_ref: f32,
    /// Mean normalised chroma `u` per block, `i8` each.
    pub(super) mu_u: &'a [u8],
    /// The same of `v`.
    pub(super) mu_v: &'a [u8],
    /// Spread per block, in `1 / SPREAD_ONE` units, each at least 1.
    pub(super) spread: &'a [u8],
}

impl Chroma<'_> {
    /// Block `b`'s mean `[u, v]` and spread; `None` past the table.
    pub fn at(&self, b: usize) -> Option<([i8; 2], u8)> {
        Some((
            [*self.mu_u.get(b)? as i8, *self.mu_v.get(b)? as i8],
            *self.spread.get(b)?,
        ))
    }

    /// Blocks in the tables.
    pub fn blocks(&self) -> usize {
        self.spread.len()
    }
}

/// A chroma section to write (`set_chroma`).
#[cfg(any(feature = "std", test))]
#[derive(Clone, Debug, PartialEq)]
pub struct ChromaSpec {
    /// As [`Chroma::threshold`].
    pub threshold: f32,
    /// As [`Chroma::spread_ref`].
    pub spread_ref: f32,
    /// Mean `[u, v]` per block.
    pub mu: Vec<[i8; 2]>,
    /// Spread per block, `1 / SPREAD_ONE` units, each at least 1.
    pub spread: Vec<u8>,
}

#[cfg(any(feature = "std", test))]
impl ChromaSpec {
    /// Whether the parser would take it for an `h x w` face.
    pub fn is_valid(&self, h: usize, w: usize) -> bool {
        valid_scalars(self.threshold, self.spread_ref)
            && self.mu.len() == blocks(h, w)
            && self.spread.len() == self.mu.len()
            && self.spread.iter().all(|&s| s > 0)
    }
}

pub(super) fn valid_scalars(threshold: f32, spread_ref: f32) -> bool {
    threshold.is_finite()
        && threshold > 0.0
        && threshold <= MAX_THRESHOLD
        && spread_ref.is_finite()
        && spread_ref > 0.0
        && spread_ref <= MAX_SPREAD_REF
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalise_is_the_rounded_ratio() {
        // Neutral chroma is 0 at any grey.
        assert_eq!(normalise(128, 400, 4), 0);
        // 32 * 40 * 4 / (400 + 32) = 11.85 -> 12; the sign follows the chroma.
        assert_eq!(normalise(168, 400, 4), 12);
        assert_eq!(normalise(88, 400, 4), -12);
        // Halving the light halves chroma and grey alike: nearly the same ratio.
        assert_eq!(normalise(148, 200, 4), 11);
        // Saturated and dark: clamped.
        assert_eq!(normalise(255, 0, 4), 127);
        assert_eq!(normalise(0, 0, 1), -127);
        assert_eq!(blocks(58, 75), 29 * 38);
    }
}
