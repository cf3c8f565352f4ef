//! Colour: the blocks whose chroma the face does not have ([`msr_shared::blob::chroma`]).
//!
//! The rules, in order:
//! 1. Each 2 x 2 block's normalised chroma ([`chroma::normalise`]) less the model's mean for
//!    that block is its error `e = (e_u, e_v)`.
//! 2. The frame's line, per axis, is taken out of every block's error: `e = a + g mu` fitted
//!    by least squares over the blocks within [`TRIM`] of the median error. A white balance or
//!    a tinted light moves every block alike (`a`); a tone curve scales each block's chroma
//!    ratio (`g`: a curve of exponent 0.8 makes the ratios about 0.8 times); a mark moves only
//!    a few blocks, and far.
//! 3. Each block's `q = |e|^2 / spread^2`; the median of `q` over the face against the model's
//!    [`Chroma::spread_ref`] says how much more this camera's chroma spreads than the
//!    statistics' frames did (noise, compression). Every spread is widened by that ratio, never
//!    narrowed.
//! 4. A block is salient when `q > threshold^2 x widening`; its pixels join the grey stage's
//!    mask as salient, so a mark that grey sees and one that only colour sees make one blob.
//!
//! The tables are those of the frame's head-pose cell (`Model::chroma_at`), as the grey
//! statistics are. Integer arithmetic only: `q` in sixteenths ([`Q_ONE`]), the widening in 256ths, so the host,
//! the board and QEMU agree to the bit.
use msr_shared::blob::chroma::{self, SPREAD_ONE};
use msr_shared::blob::ChromaCell as Chroma;

/// `q`'s unit: `q = 16` is an error of one spread.
pub const Q_ONE: u32 = 16;
/// The widening's unit (1.0).
pub const WIDEN_ONE: u32 = 256;

/// What one frame's chroma gave.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Frame {
    /// Rule 2: the shift taken out, `[u, v]` normalised chroma units.
    pub shift: [i16; 2],
    /// Rule 2: the slope taken out with it, `[u, v]` in 256ths of the model's chroma.
    pub gain: [i16; 2],
    /// Rule 3: the median `q` over the face (at most [`MAX_MEDIAN_Q`]), in [`Q_ONE`]ths.
    pub median_q: u16,
    /// Rule 3: how much the spreads were widened (squared), in [`WIDEN_ONE`]ths, at least 1.0.
    pub widen: u32,
    /// Rule 4: salient blocks.
    pub blocks: u16,
}

/// Rules 1 to 3 for an `h x w` face: `grey` its bytes, `planes` its `Cb` then `Cr` block
/// planes. Fills `e` (one entry a block, at least [`chroma::blocks`]) with each block's error
/// less the frame's shift. `None` when the sizes disagree with each other or the model.
pub fn errors(c: &Chroma, grey: &[u8], planes: &[u8], h: usize, w: usize, e: &mut [[i16; 2]]) -> Option<Frame> {
    let n = chroma::blocks(h, w);
    if grey.len() != h * w || planes.len() != 2 * n || e.len() < n || c.blocks() != n || n == 0 {
        return None;
    }
    let (bh, bw) = (h.div_ceil(2), w.div_ceil(2));
    let (mu_u, mu_v, spread) = c.tables();
    let (mu_u, mu_v, spread, e) = (&mu_u[..n], &mu_v[..n], &spread[..n], &mut e[..n]);
    let mut hist = [[0u16; 256]; 2];
    // Index loops, not iterator chains: the board's image is built for size, where those cost
    // several times as much.
    for by in 0..bh {
        let y0 = 2 * by;
        let two_rows = y0 + 1 < h;
        let r0 = &grey[y0 * w..y0 * w + w];
        let r1 = if two_rows { &grey[(y0 + 1) * w..(y0 + 2) * w] } else { r0 };
        for bx in 0..bw {
            let x0 = 2 * bx;
            let two_cols = x0 + 1 < w;
            let (mut sum, mut px) = (r0[x0] as u32, 1u32);
            if two_cols {
                sum += r0[x0 + 1] as u32;
                px += 1;
            }
            if two_rows {
                sum += r1[x0] as u32;
                px += 1;
                if two_cols {
                    sum += r1[x0 + 1] as u32;
                    px += 1;
                }
            }
            let b = by * bw + bx;
            let u = chroma::normalise(planes[b], sum, px) as i16 - mu_u[b] as i8 as i16;
            let v = chroma::normalise(planes[n + b], sum, px) as i16 - mu_v[b] as i8 as i16;
            e[b] = [u, v];
            hist[0][(u.clamp(-128, 127) + 128) as usize] += 1;
            hist[1][(v.clamp(-128, 127) + 128) as usize] += 1;
        }
    }
    let mid = [median(&hist[0], n) as i32 - 128, median(&hist[1], n) as i32 - 128];
    // Rule 2's line, per axis, over the blocks near the median (a mark lies far from it). In
    // 32 bits: |mu| <= 128 and |e| <= 255 over at most 1 536 blocks.
    let mut sums = [[0i32; 5]; 2];
    for b in 0..n {
        let mu = [mu_u[b] as i8 as i32, mu_v[b] as i8 as i32];
        let eb = e[b];
        for k in 0..2 {
            let (x, y) = (mu[k], eb[k] as i32);
            if (y - mid[k]).abs() <= TRIM {
                let t = &mut sums[k];
                t[0] += 1;
                t[1] += x;
                t[2] += y;
                t[3] += x * x;
                t[4] += x * y;
            }
        }
    }
    let line = [line_of(&sums[0], mid[0]), line_of(&sums[1], mid[1])];
    let mut qs = [0u16; 256];
    let ([au, gu], [av, gv]) = (line[0].into(), line[1].into());
    for b in 0..n {
        let eb = [
            e[b][0] - ((au + gu * mu_u[b] as i8 as i32 + 128) >> 8) as i16,
            e[b][1] - ((av + gv * mu_v[b] as i8 as i32 + 128) >> 8) as i16,
        ];
        e[b] = eb;
        qs[q_bin(q16(eb, spread[b]))] += 1;
    }
    let shift = [((line[0].0 + 128) >> 8) as i16, ((line[1].0 + 128) >> 8) as i16];
    let gain = [line[0].1 as i16, line[1].1 as i16];
    let median_q = q_of_bin(median(&qs, n));
    let reference = ((c.spread_ref * Q_ONE as f32) as u32).clamp(1, 255);
    let widen = (median_q as u32 * WIDEN_ONE / reference).max(WIDEN_ONE);
    Some(Frame { shift, gain, median_q, widen, blocks: 0 })
}

/// Rule 2's fit of the errors on the model's chroma, `e = a + g mu`, from the sums
/// `[n, sum mu, sum e, sum mu^2, sum mu e]` of the blocks within [`TRIM`] of the median `m`:
/// `(a, g)` in 256ths. A face whose model chroma spreads less than [`MIN_SPREAD2`] (a grey
/// face) has no slope to fit, and a fit outside [`MAX_SLOPE`] is no camera's: those take the
/// median as the shift alone.
fn line_of(t: &[i32; 5], m: i32) -> (i32, i32) {
    let [n, sx, sy, sxx, sxy] = t.map(|v| v as i64);
    let det = n * sxx - sx * sx;
    if n < 2 || det < MIN_SPREAD2 * n * n {
        return (m * 256, 0);
    }
    let g = (n * sxy - sx * sy) * 256 / det;
    if g.abs() > MAX_SLOPE as i64 {
        return (m * 256, 0);
    }
    let a = (sy * 256 - g * sx) / n;
    (a as i32, g as i32)
}

/// Rule 2: blocks whose error lies further than this from the median (normalised chroma
/// units, each axis) are left out of the fit.
pub const TRIM: i32 = 24;
/// Rule 2: the least variance of the model's chroma over the fitted blocks (units squared)
/// for a slope to be fitted.
pub const MIN_SPREAD2: i64 = 4;
/// Rule 2: the largest slope, in 256ths (a chroma at most halved or one and a half times).
pub const MAX_SLOPE: i32 = 128;

/// The histogram bin of `q`: sixteenths below 128, then steps of 16 up to [`MAX_MEDIAN_Q`].
fn q_bin(q: u32) -> usize {
    if q < 128 {
        q as usize
    } else {
        128 + ((q - 128) / 16).min(127) as usize
    }
}

/// The least `q` of a bin.
fn q_of_bin(bin: usize) -> u16 {
    if bin < 128 {
        bin as u16
    } else {
        128 + 16 * (bin as u16 - 128)
    }
}

/// The largest median `q` rule 3 tells apart (135 spreads squared); a frame beyond it is
/// widened as if at it.
pub const MAX_MEDIAN_Q: u16 = 128 + 16 * 127;

/// Rule 3's `q` of one block's error (after the shift) with spread `s`, in [`Q_ONE`]ths.
pub fn q16(e: [i16; 2], s: u8) -> u32 {
    let r = (e[0] as i32 * e[0] as i32 + e[1] as i32 * e[1] as i32) as u32;
    let s = s.max(1) as u32;
    // r <= 2 x 382^2 < 2^19: no overflow in 32 bits.
    (r * Q_ONE * (SPREAD_ONE as u32 * SPREAD_ONE as u32)) / (s * s)
}

/// Rule 4's test of one block: `q > threshold^2 x widen`, exactly, in 64 bits.
pub fn salient(c: &Chroma, f: &Frame, e: [i16; 2], s: u8) -> bool {
    over(limit(c, f), e, s)
}

/// Rule 4's bound for a frame, `threshold^2 x widen` in the units [`over`] compares with: made
/// once a frame (a float to integer conversion is a library call on the board).
fn limit(c: &Chroma, f: &Frame) -> u64 {
    (c.threshold * c.threshold * Q_ONE as f32) as u64 * f.widen as u64
}

/// Whether a block's error `e` with spread `s` is over the frame's `limit`.
#[inline(always)]
fn over(limit: u64, e: [i16; 2], s: u8) -> bool {
    let r = (e[0] as i32 * e[0] as i32 + e[1] as i32 * e[1] as i32) as u64;
    let s = s.max(1) as u64;
    r * (SPREAD_ONE as u64 * SPREAD_ONE as u64 * Q_ONE as u64 * WIDEN_ONE as u64) > limit * s * s
}

/// Rule 4: sets the pixels of every salient block to 1 in the `w`-wide `mask` and counts the
/// pixels that were 0 (in `rows` too, per row, when the mask's rows are counted). Returns the
/// frame with its salient blocks, and the pixels added.
pub fn mark(c: &Chroma, f: Frame, e: &[[i16; 2]], h: usize, w: usize, mask: &mut [u8], mut rows: Option<&mut [u16]>) -> (Frame, u32) {
    let (bh, bw) = (h.div_ceil(2), w.div_ceil(2));
    let (mut added, mut blocks) = (0u32, 0u16);
    if mask.len() < h * w || e.len() < bh * bw {
        return (f, 0);
    }
    let limit = limit(c, &f);
    let (_, _, spread) = c.tables();
    if spread.len() < bh * bw {
        return (f, 0);
    }
    for by in 0..bh {
        for bx in 0..bw {
            let b = by * bw + bx;
            if !over(limit, e[b], spread[b]) {
                continue;
            }
            blocks += 1;
            for y in 2 * by..(2 * by + 2).min(h) {
                for x in 2 * bx..(2 * bx + 2).min(w) {
                    let m = &mut mask[y * w + x];
                    if *m == 0 {
                        added += 1;
                        if let Some(r) = rows.as_deref_mut().and_then(|r| r.get_mut(y)) {
                            *r += 1;
                        }
                    }
                    *m = 1;
                }
            }
        }
    }
    (Frame { blocks, ..f }, added)
}

/// The lower median of `n` values counted in `hist`: the bin holding value `(n - 1) / 2`.
fn median(hist: &[u16; 256], n: usize) -> usize {
    let mut seen = 0usize;
    for (i, &k) in hist.iter().enumerate() {
        seen += k as usize;
        if seen > (n - 1) / 2 {
            return i;
        }
    }
    255
}

#[cfg(test)]
mod tests;
