//! Saliency: which pixels differ from the prediction more than the face normally does.
//!
//! Per pixel, with `e = |255 (I - I_hat)|` in grey levels and the model's statistics mu, sigma:
//! salient when `(e - mu) / n > t` (one-sided) or `|e - mu| / n > t` (two-sided), where `n` is
//! sigma ([`Normalisation::StdDev`]) or sigma^2 ([`Normalisation::Variance`]).
//!
//! No division per pixel: `t * n` is a per-pixel table in Q8.8 grey levels ([`Thresholds`]),
//! made once per model and setting, so the test is `e - mu > tn` (or `|e - mu| > tn`) in
//! integers. `tn = round(t * n * 256)` saturates at 65535, which no error reaches.
//! `n = 0` gives `tn = 0`: any error different from mu is salient, as a division by 0 would say.

use msr_shared::blob::{
    Merge, Model, Normalisation, Novelty, PoseRegion, Sided, U16Table, MAX_FACE_PIXELS, MAX_FACE_W,
};

/// Novelty settings in force: the model's defaults, or what the host configured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Saliency threshold `t`, in units of the normalisation (finite, > 0).
    pub threshold: f32,
    /// Whether `n` is sigma or sigma^2.
    pub normalisation: Normalisation,
    /// One-sided (`e - mu > tn`) or two-sided (`|e - mu| > tn`) test.
    pub sided: Sided,
    /// Smallest blob, pixels, that counts as a mark.
    pub min_area: u16,
    /// Fragment merge before the area test (the model's; the host cannot change it).
    pub merge: Merge,
}

impl Settings {
    /// The settings stored in the model blob.
    pub fn of(model: &Model) -> Settings {
        Settings::of_novelty(&model.novelty)
    }

    /// The settings for a frame seen with the head at `head`: inside the model's pose region
    /// (`blob::PoseRegion`), the region's threshold and merge; elsewhere these. A threshold the
    /// host configured scales the region's by the same factor (region threshold x configured /
    /// model threshold), so one knob moves both.
    pub fn at(&self, model: &Model, head: [f32; 2]) -> Settings {
        self.in_region(model.region, self.threshold / model.novelty.threshold, head)
    }

    /// The one rule behind [`Settings::at`], for callers that hold a region without a blob (the
    /// host's float engine and calibration): inside `region`, its threshold times `scale` (the
    /// configured threshold over the model's; 1 for the model's own settings) and its merge;
    /// elsewhere (or without a region, or at a non-finite head pose) these.
    pub fn in_region(&self, region: Option<PoseRegion>, scale: f32, head: [f32; 2]) -> Settings {
        match region {
            Some(g) if g.contains(head) => Settings {
                threshold: g.threshold * scale,
                merge: g.merge,
                ..*self
            },
            _ => *self,
        }
    }

    /// The settings a model's novelty block stores.
    pub fn of_novelty(n: &Novelty) -> Settings {
        Settings {
            threshold: n.threshold,
            normalisation: n.normalisation,
            sided: n.sided,
            min_area: n.min_area,
            merge: n.merge,
        }
    }

    /// Finite positive threshold, min area at least 1, a merge valid for it.
    pub fn is_valid(&self) -> bool {
        self.threshold.is_finite()
            && self.threshold > 0.0
            && self.min_area >= 1
            && self.merge.is_valid(self.min_area)
    }
}

/// `t * n` per pixel, Q8.8 grey levels.
pub struct Thresholds {
    tn: [u16; MAX_FACE_PIXELS],
    len: usize,
    /// (model CRC, threshold bits, normalisation) the table was made for.
    key: Option<(u32, u32, Normalisation)>,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self::new()
    }
}

/// One pixel's `t * n` in Q8.8, saturating.
pub fn threshold_q88(sigma_q88: u16, threshold: f32, normalisation: Normalisation) -> u16 {
    let s = sigma_q88 as f32 / 256.0;
    let n = match normalisation {
        Normalisation::StdDev => s,
        Normalisation::Variance => s * s,
    };
    let v = threshold * n * 256.0;
    if v.is_nan() || v < 0.0 {
        0
    } else if v >= 65534.5 {
        u16::MAX
    } else {
        (v + 0.5) as u16
    }
}

impl Thresholds {
    /// An empty table; the first [`Thresholds::prepare`] fills it.
    pub const fn new() -> Self {
        Thresholds {
            tn: [0; MAX_FACE_PIXELS],
            len: 0,
            key: None,
        }
    }

    /// Makes the table for `model` and `threshold`/`normalisation`, unless it is already made.
    /// Returns true when it was recomputed.
    pub fn prepare(&mut self, model: &Model, s: &Settings) -> bool {
        let key = (model.crc32, s.threshold.to_bits(), s.normalisation);
        let n = model
            .face_pixels()
            .min(MAX_FACE_PIXELS)
            .min(model.sigma.len());
        if self.key == Some(key) && self.len == n {
            return false;
        }
        for (t, sigma) in self.tn[..n].iter_mut().zip(model.sigma.iter()) {
            *t = threshold_q88(sigma, s.threshold, s.normalisation);
        }
        self.len = n;
        self.key = Some(key);
        true
    }

    /// Forgets the table, so that the next [`Thresholds::prepare`] recomputes it.
    pub fn invalidate(&mut self) {
        self.key = None;
    }

    /// The `tn` table, Q8.8 grey levels per pixel, row-major (empty before `prepare`).
    pub fn table(&self) -> &[u16] {
        &self.tn[..self.len]
    }
}

/// Writes `mask[i] = 1` for salient pixels, 0 otherwise, and returns how many are salient.
/// `frame` is grey 0..255, `pred` the predicted face in Q8.8 grey levels, `mu` the model's mean
/// error table; all of `frame.len()` pixels (the shortest input bounds the work).
pub fn saliency(
    frame: &[u8],
    pred: &[u16],
    mu: U16Table,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
) -> u32 {
    // Blobs in memory are 4-byte aligned, so mu is normally a u16 slice; else read bytes.
    match bytemuck::try_cast_slice::<u8, u16>(mu.0) {
        Ok(mu) => run(frame, pred, mu.iter().copied(), tn, sided, mask),
        Err(_) => run(frame, pred, mu.iter(), tn, sided, mask),
    }
}

/// [`saliency`] on the pooled error (the blob's flag bit 4): `e = |mean of (I << 8) - pred over
/// the (2 pool + 1)^2 window, clipped at the border|`, Q8.8, the mean truncated toward zero.
/// `w` is the face's width; the rows are `frame.len() / w`. Running column sums (one row in,
/// one out per row) and a running window sum along the row: a few additions per pixel whatever
/// the radius, no buffer but the column sums, and no division: `floor(|s| / n) > k` is tested
/// as `|s| >= (k + 1) n`. Slices are taken with `get`, so nothing here can panic.
#[allow(clippy::too_many_arguments)]
pub fn pooled(
    frame: &[u8],
    pred: &[u16],
    mu: U16Table,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
    w: usize,
    pool: u8,
) -> u32 {
    match bytemuck::try_cast_slice::<u8, u16>(mu.0) {
        Ok(mu) => pooled_run(frame, pred, mu, tn, sided, mask, w, pool as usize),
        Err(_) => 0,
    }
}

#[allow(clippy::too_many_arguments)]
fn pooled_run(
    frame: &[u8],
    pred: &[u16],
    mu: &[u16],
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
    w: usize,
    r: usize,
) -> u32 {
    if w == 0 || w > MAX_FACE_W {
        return 0;
    }
    let n = frame.len().min(pred.len()).min(tn.len()).min(mask.len()).min(mu.len());
    let h = n / w;
    // Columns past `w` stay 0, so the window sum may read them.
    let mut col = [0i32; MAX_FACE_W + 8];
    let add_row = |col: &mut [i32], y: usize, add: bool| {
        if let (Some(f), Some(p)) = (frame.get(y * w..y * w + w), pred.get(y * w..y * w + w)) {
            let rs = col.iter_mut().zip(f).zip(p);
            if add {
                rs.for_each(|((c, &f), &p)| *c += ((f as i32) << 8) - p as i32);
            } else {
                rs.for_each(|((c, &f), &p)| *c -= ((f as i32) << 8) - p as i32);
            }
        }
    };
    for y in 0..r.min(h) {
        add_row(&mut col, y, true);
    }
    // Window widths along a row.
    let mut cols = [0u8; MAX_FACE_W];
    for (x, c) in cols.iter_mut().enumerate().take(w) {
        *c = ((x + r).min(w - 1) + 1 - x.saturating_sub(r)) as u8;
    }
    let mut count = 0u32;
    for y in 0..h {
        if y + r < h {
            add_row(&mut col, y + r, true);
        }
        if y > r {
            add_row(&mut col, y - r - 1, false);
        }
        let rows = ((y + r).min(h - 1) + 1 - y.saturating_sub(r)) as u32;
        let (Some(m_row), Some(mu_row), Some(tn_row)) = (
            mask.get_mut(y * w..y * w + w),
            mu.get(y * w..y * w + w),
            tn.get(y * w..y * w + w),
        ) else {
            break;
        };
        let mut sum: i32 = col.iter().take(r).sum();
        let px = m_row.iter_mut().zip(mu_row).zip(tn_row).zip(&cols);
        // In u32: |sum| <= 49 x 65280 and (mu + t + 1) x 49 < 2^23.
        let mut step = |x: usize| {
            sum += col.get(x + r).copied().unwrap_or(0);
            if x > r {
                sum -= col.get(x - r - 1).copied().unwrap_or(0);
            }
            sum.unsigned_abs()
        };
        match sided {
            Sided::One => {
                for (x, (((out, &m), &t), &c)) in px.enumerate() {
                    let (a, k) = (step(x), rows * c as u32);
                    // floor(a / k) - mu > t  <=>  a >= (mu + t + 1) k
                    let s = (a >= (m as u32 + t as u32 + 1) * k) as u8;
                    *out = s;
                    count += s as u32;
                }
            }
            Sided::Two => {
                for (x, (((out, &m), &t), &c)) in px.enumerate() {
                    let (a, k) = (step(x), rows * c as u32);
                    // |floor(a / k) - mu| > t: above mu + t, or below mu - t.
                    let above = a >= (m as u32 + t as u32 + 1) * k;
                    let below = m > t && a < (m as u32 - t as u32) * k;
                    let s = (above || below) as u8;
                    *out = s;
                    count += s as u32;
                }
            }
        }
    }
    count
}

#[inline(always)]
fn run(
    frame: &[u8],
    pred: &[u16],
    mu: impl Iterator<Item = u16>,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
) -> u32 {
    let mut count = 0u32;
    let px = frame.iter().zip(pred).zip(mu).zip(tn).zip(mask.iter_mut());
    match sided {
        Sided::One => {
            for ((((&i, &p), m), &t), out) in px {
                let e = (((i as i32) << 8) - p as i32).abs();
                let s = (e - m as i32 > t as i32) as u8;
                *out = s;
                count += s as u32;
            }
        }
        Sided::Two => {
            for ((((&i, &p), m), &t), out) in px {
                let e = (((i as i32) << 8) - p as i32).abs();
                let s = ((e - m as i32).abs() > t as i32) as u8;
                *out = s;
                count += s as u32;
            }
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threshold_table_values() {
        // sigma 2.0 grey, t 4.59: StdDev -> 9.18 grey = 2350.08 -> 2350.
        assert_eq!(threshold_q88(512, 4.59, Normalisation::StdDev), 2350);
        // Variance: 4.59 * 4 = 18.36 grey -> 4700.16 -> 4700.
        assert_eq!(threshold_q88(512, 4.59, Normalisation::Variance), 4700);
        assert_eq!(threshold_q88(0, 4.59, Normalisation::StdDev), 0);
        assert_eq!(
            threshold_q88(u16::MAX, 1e30, Normalisation::Variance),
            u16::MAX
        );
    }

    /// The pooled mask against the window mean written out plainly, on a 7 x 9 face with
    /// every radius, one- and two-sided.
    #[test]
    fn pooled_matches_the_plain_window_mean() {
        let (w, h) = (9usize, 7usize);
        let frame: [u8; 63] = core::array::from_fn(|i| ((i * 37) % 251) as u8);
        let pred: [u16; 63] = core::array::from_fn(|i| (((i * 91) % 200) as u16) << 8 | (i as u16 * 13 % 256));
        let mu: [u16; 63] = core::array::from_fn(|i| (i as u16 % 5) * 300);
        let mu_bytes: Vec<u8> = mu.iter().flat_map(|v| v.to_le_bytes()).collect();
        let tn: [u16; 63] = core::array::from_fn(|i| (i as u16 % 7) * 500);
        for pool in 0..=3u8 {
            let r = pool as i64;
            for sided in [Sided::One, Sided::Two] {
                let mut mask = [7u8; 63];
                let n = pooled(&frame, &pred, U16Table(&mu_bytes), &tn, sided, &mut mask, w, pool);
                let mut want = [0u8; 63];
                for y in 0..h as i64 {
                    for x in 0..w as i64 {
                        let (mut s, mut c) = (0i64, 0i64);
                        for yy in (y - r).max(0)..=(y + r).min(h as i64 - 1) {
                            for xx in (x - r).max(0)..=(x + r).min(w as i64 - 1) {
                                let i = (yy * w as i64 + xx) as usize;
                                s += ((frame[i] as i64) << 8) - pred[i] as i64;
                                c += 1;
                            }
                        }
                        let i = (y * w as i64 + x) as usize;
                        let d = (s / c).abs() - mu[i] as i64;
                        let d = if sided == Sided::Two { d.abs() } else { d };
                        want[i] = (d > tn[i] as i64) as u8;
                    }
                }
                assert_eq!(mask, want, "pool {pool} {sided:?}");
                assert_eq!(n as usize, want.iter().filter(|&&m| m == 1).count());
                if pool == 0 {
                    // Radius 0 is the per-pixel saliency.
                    let mut plain = [0u8; 63];
                    saliency(&frame, &pred, U16Table(&mu_bytes), &tn, sided, &mut plain);
                    assert_eq!(mask, plain);
                }
            }
        }
        // A width past the board's limit or of zero finds nothing and writes nothing.
        let mut mask = [7u8; 63];
        assert_eq!(pooled(&frame, &pred, U16Table(&mu_bytes), &tn, Sided::One, &mut mask, 0, 2), 0);
        assert_eq!(mask, [7u8; 63]);
    }

    #[test]
    fn one_and_two_sided() {
        // Pixel 0: error 10 grey above mu 2 (t*n = 4): salient both ways.
        // Pixel 1: error 0, mu 8: e - mu = -8: salient two-sided only.
        // Pixel 2: error 3, mu 2: below t*n: never.
        let frame = [110u8, 50, 53];
        let pred = [100 * 256, 50 * 256, 50 * 256];
        let mu_bytes: Vec<u8> = [2u16 * 256, 8 * 256, 2 * 256]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let tn = [4 * 256u16; 3];
        let mut mask = [9u8; 3];
        let n = saliency(
            &frame,
            &pred,
            U16Table(&mu_bytes),
            &tn,
            Sided::One,
            &mut mask,
        );
        assert_eq!((n, mask), (1, [1, 0, 0]));
        let n = saliency(
            &frame,
            &pred,
            U16Table(&mu_bytes),
            &tn,
            Sided::Two,
            &mut mask,
        );
        assert_eq!((n, mask), (2, [1, 1, 0]));
        // Unaligned mu bytes take the other path and agree.
        let mut shifted = vec![0u8];
        shifted.extend_from_slice(&mu_bytes);
        let n = saliency(
            &frame,
            &pred,
            U16Table(&shifted[1..]),
            &tn,
            Sided::Two,
            &mut mask,
        );
        assert_eq!((n, mask), (2, [1, 1, 0]));
    }
}
