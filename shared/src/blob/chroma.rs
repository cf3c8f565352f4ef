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
pub const SCALE: i32 = 64;
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

/// Block `b`'s grey: the sum of its pixels' grey levels in the `w`-wide `grey`, and how many
/// pixels it has (4, or 2 or 1 at an odd edge of an `h x w` face). The board's colour stage sums
/// in a loop of its own, which its size-optimised build runs faster; every other user calls this.
pub fn block_grey(grey: &[u8], h: usize, w: usize, b: usize) -> (u32, u32) {
    let bw = w.div_ceil(2);
    let (by, bx) = (b / bw, b % bw);
    let (mut sum, mut px) = (0u32, 0u32);
    for y in 2 * by..(2 * by + 2).min(h) {
        for x in 2 * bx..(2 * bx + 2).min(w) {
            sum += grey[y * w + x] as u32;
            px += 1;
        }
    }
    (sum, px)
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

/// The chroma section, borrowed from the blob: its settings and one set of tables per cell of
/// the model's pose grid (or one for every pose).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chroma<'a> {
    /// As [`ChromaCell::threshold`].
    pub threshold: f32,
    /// As [`ChromaCell::spread_ref`].
    pub spread_ref: f32,
    /// Every cell's `u`, `v` and spread tables in turn, each padded to 4.
    pub(super) tables: &'a [u8],
    /// Blocks per table.
    pub(super) n: usize,
    /// Tables' sets: 1, or the pose grid's cells.
    pub(super) cells: usize,
}

impl<'a> Chroma<'a> {
    /// Sets of tables: 1 (every pose) or one per cell of the model's pose grid.
    pub fn cells(&self) -> usize {
        self.cells
    }

    /// Cell `k`'s tables; `None` past the last.
    pub fn cell(&self, k: usize) -> Option<ChromaCell<'a>> {
        if k >= self.cells {
            return None;
        }
        let padded = self.n.div_ceil(4) * 4;
        let at = |i: usize| self.tables.get((3 * k + i) * padded..(3 * k + i) * padded + self.n);
        Some(ChromaCell { threshold: self.threshold, spread_ref: self.spread_ref, mu_u: at(0)?, mu_v: at(1)?, spread: at(2)? })
    }
}

/// One pose cell's chroma tables, with the section's settings: what the board's stage reads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChromaCell<'a> {
    /// A block is salient when its chroma error, less the frame's shift, exceeds this many of
    /// its spreads (finite, `0 < threshold <= MAX_THRESHOLD`).
    pub threshold: f32,
    /// The median over the statistics' frames of each block's squared error over its spread
    /// squared (`0 < spread_ref <= MAX_SPREAD_REF`): a frame whose own median is larger (a
    /// noisier camera, compression) widens every spread by the ratio.
    pub spread_ref: f32,
    /// Mean normalised chroma `u` per block, `i8` each.
    mu_u: &'a [u8],
    /// The same of `v`.
    mu_v: &'a [u8],
    /// Spread per block, in `1 / SPREAD_ONE` units, each at least 1.
    spread: &'a [u8],
}

impl<'a> ChromaCell<'a> {
    /// A cell from its tables (`mu_u`, `mu_v` as `i8` bytes, `spread`), as the parser would
    /// make it; `None` where the parser would refuse it. For a host that calibrates one.
    pub fn from_tables(threshold: f32, spread_ref: f32, mu_u: &'a [u8], mu_v: &'a [u8], spread: &'a [u8]) -> Option<Self> {
        let ok = valid_scalars(threshold, spread_ref)
            && mu_u.len() == spread.len()
            && mu_v.len() == spread.len()
            && !spread.contains(&0);
        ok.then_some(ChromaCell { threshold, spread_ref, mu_u, mu_v, spread })
    }

    /// Block `b`'s mean `[u, v]` and spread; `None` past the table.
    pub fn at(&self, b: usize) -> Option<([i8; 2], u8)> {
        Some(([*self.mu_u.get(b)? as i8, *self.mu_v.get(b)? as i8], *self.spread.get(b)?))
    }

    /// Blocks in the tables.
    pub fn blocks(&self) -> usize {
        self.spread.len()
    }

    /// The three tables, `mu_u` and `mu_v` (`i8` bytes) and `spread`, each [`Self::blocks`]
    /// long: for a loop over every block that reads them without a check each.
    pub fn tables(&self) -> (&'a [u8], &'a [u8], &'a [u8]) {
        (self.mu_u, self.mu_v, self.spread)
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
    /// Per cell (one, or the pose grid's in its order): the mean `[u, v]` per block and the
    /// spread per block (`1 / SPREAD_ONE` units, each at least 1).
    pub cells: Vec<(Vec<[i8; 2]>, Vec<u8>)>,
}

#[cfg(any(feature = "std", test))]
impl ChromaSpec {
    /// Whether the parser would take it for an `h x w` face whose pose grid has `grid_cells`
    /// cells (0 without one).
    pub fn is_valid(&self, h: usize, w: usize, grid_cells: usize) -> bool {
        valid_scalars(self.threshold, self.spread_ref)
            && (self.cells.len() == 1 || (self.cells.len() == grid_cells && grid_cells > 1))
            && self.cells.iter().all(|(mu, s)| mu.len() == blocks(h, w) && s.len() == mu.len() && !s.contains(&0))
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
        // 64 * 40 * 4 / (400 + 32) = 23.7 -> 24; the sign follows the chroma.
        assert_eq!(normalise(168, 400, 4), 24);
        assert_eq!(normalise(88, 400, 4), -24);
        // Halving the light halves chroma and grey alike: nearly the same ratio.
        assert_eq!(normalise(148, 200, 4), 22);
        // Saturated and dark: clamped.
        assert_eq!(normalise(255, 0, 4), 127);
        assert_eq!(normalise(0, 0, 1), -127);
        assert_eq!(blocks(58, 75), 29 * 38);
    }
}
