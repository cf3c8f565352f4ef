//! Saliency: which pixels differ from the prediction more than the face normally does.
//!
//! Per pixel, with `e = |255 (I - I_hat)|` in grey levels (`I` brought to the prediction's
//! light by the frame's photometric fit first, [`crate::light`]: the error is `v(I) - pred` in
//! Q8.8, a 256-entry table, `I << 8` without a fit) and the model's statistics mu, sigma:
//! salient when `(e - mu) / n > t` (one-sided) or `|e - mu| / n > t` (two-sided), where `n` is
//! sigma ([`Normalisation::StdDev`]) or sigma^2 ([`Normalisation::Variance`]).
//!
//! No division per pixel: `t * n` is a per-pixel table in Q8.8 grey levels ([`Thresholds`]),
//! made once per model and setting, so the test is `e - mu > tn` (or `|e - mu| > tn`) in
//! integers. `tn = round(t * n * 256)` saturates at 65535, which no error reaches.
//! `n = 0` gives `tn = 0`: any error different from mu is salient, as a division by 0 would say.
//!
//! A pooled model's one-sided test (the default) is in [`pool`]: one assembly routine a row on
//! the board, with `mu + tn` in the table.

use msr_shared::blob::{
    Merge, Model, Normalisation, Novelty, PoseRegion, Sided, U16Table, MAX_FACE_PIXELS, MAX_FACE_W,
    MAX_POOL,
};

pub mod pool;

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

/// `t * n` per pixel, Q8.8 grey levels; for a pooled model's one-sided test, `mu + t * n`
/// ([`pool::Combine`]).
pub struct Thresholds {
    tn: Table,
    len: usize,
    /// (model CRC, threshold bits, normalisation, statistics cell, combined, frame floor) the
    /// table was made for.
    key: Option<(u32, u32, Normalisation, u8, bool, u16)>,
    /// (model CRC, its largest sigma over every cell): found once per model (a pass over all
    /// its statistics, at its first frame), it lets [`pool::combined_table`] skip every
    /// per-pixel range check.
    sigma_max: Option<(u32, u16)>,
}

/// The table's storage, word-aligned for the board's word loads and stores.
#[repr(C, align(4))]
struct Table([u16; MAX_FACE_PIXELS]);

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
    // `as` saturates (NaN and anything below 0 give 0, 65535 and above give 65535): that is
    // the rounding and the saturation wanted, in one conversion and no branches (a new pose
    // cell remakes the whole table). The same value for every input as the explicit checks,
    // `table_matches_the_explicit_checks` tries all sigmas.
    (threshold * n * 256.0 + 0.5) as u16
}

impl Thresholds {
    /// An empty table; the first [`Thresholds::prepare`] fills it.
    pub const fn new() -> Self {
        Thresholds {
            tn: Table([0; MAX_FACE_PIXELS]),
            len: 0,
            key: None,
            sigma_max: None,
        }
    }

    /// Makes the table for `model` and `threshold`/`normalisation` at head pose `head` (the
    /// statistics of its pose cell, [`Model::stats_at`]) with each sigma widened by the frame's
    /// floor `floor` (Q8.8, [`crate::floor`]; 0: the statistics as they are), unless it is
    /// already made. A pooled model's one-sided test gets the combined table (`mu + tn`,
    /// [`pool::Combine`]), any other test `tn` alone ([`threshold_q88`]). Returns true when it
    /// was recomputed: with pose statistics and a floor of 0, once per change of cell; with a
    /// floor, whenever it changes.
    pub fn prepare(&mut self, model: &Model, s: &Settings, head: [f32; 2], floor: u16) -> bool {
        let (mu, sigma, cell) = model.stats_at(head);
        let combined = model.novelty.pool > 0 && s.sided == Sided::One;
        let key = (model.crc32, s.threshold.to_bits(), s.normalisation, cell, combined, floor);
        let n = model.face_pixels().min(MAX_FACE_PIXELS).min(sigma.len()).min(mu.len());
        if self.key == Some(key) && self.len == n {
            return false;
        }
        let sigma_max = if combined { self.sigma_max(model) } else { u16::MAX };
        let out = &mut self.tn.0[..n];
        // Blobs are 4-byte aligned, so the tables are normally u16 slices; else read bytes.
        let aligned = (bytemuck::try_cast_slice::<u8, u16>(sigma.0), bytemuck::try_cast_slice::<u8, u16>(mu.0));
        match (combined, aligned) {
            (true, (Ok(sigma), Ok(mu))) if floor > 0 => {
                pool::widened_table(sigma, mu, &pool::Combine::new(s.threshold, s.normalisation), floor, out)
            }
            _ if floor > 0 => {
                let c = pool::Combine::new(s.threshold, s.normalisation);
                for (i, t) in out.iter_mut().enumerate() {
                    let sigma = crate::floor::widen(sigma.get(i), floor);
                    *t = if combined { c.at(sigma, mu.get(i)) } else { threshold_q88(sigma, s.threshold, s.normalisation) };
                }
            }
            (true, (Ok(sigma), Ok(mu))) => {
                pool::combined_table(sigma, mu, &pool::Combine::new(s.threshold, s.normalisation), sigma_max, out)
            }
            (true, _) => {
                let c = pool::Combine::new(s.threshold, s.normalisation);
                for (i, t) in out.iter_mut().enumerate() {
                    *t = c.at(sigma.get(i), mu.get(i));
                }
            }
            (false, (Ok(sigma), _)) => {
                for (t, &sigma) in out.iter_mut().zip(sigma) {
                    *t = threshold_q88(sigma, s.threshold, s.normalisation);
                }
            }
            (false, _) => {
                for (t, sigma) in out.iter_mut().zip(sigma.iter()) {
                    *t = threshold_q88(sigma, s.threshold, s.normalisation);
                }
            }
        }
        self.len = n;
        self.key = Some(key);
        true
    }

    /// The largest sigma of `model` (its header's table and every pose cell's), kept per model.
    fn sigma_max(&mut self, model: &Model) -> u16 {
        if let Some((crc, max)) = self.sigma_max {
            if crc == model.crc32 {
                return max;
            }
        }
        let largest = |t: U16Table| match bytemuck::try_cast_slice::<u8, u16>(t.0) {
            Ok(v) => v.iter().copied().max().unwrap_or(0),
            Err(_) => t.iter().max().unwrap_or(0),
        };
        let mut max = largest(model.sigma);
        if let Some(p) = &model.pose {
            for (_, sigma) in (0..p.grid.len()).map_while(|b| p.tables(b)) {
                max = max.max(largest(sigma));
            }
        }
        self.sigma_max = Some((model.crc32, max));
        max
    }

    /// Forgets the table, so that the next [`Thresholds::prepare`] recomputes it.
    pub fn invalidate(&mut self) {
        self.key = None;
    }

    /// The table, Q8.8 grey levels per pixel, row-major (empty before `prepare`): `tn`, or
    /// `mu + tn` for a pooled model's one-sided test.
    pub fn table(&self) -> &[u16] {
        &self.tn.0[..self.len]
    }
}

/// Writes `mask[i] = 1` for salient pixels, 0 otherwise, and returns how many are salient.
/// `frame` is grey 0..255, `pred` the predicted face in Q8.8 grey levels, `mu` the model's mean
/// error table; all of `frame.len()` pixels (the shortest input bounds the work).
pub fn saliency(
    frame: &[u8],
    pred: &[u16],
    lut: &crate::light::Lut,
    mu: U16Table,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
) -> u32 {
    // Blobs in memory are 4-byte aligned, so mu is normally a u16 slice; else read bytes.
    match bytemuck::try_cast_slice::<u8, u16>(mu.0) {
        Ok(mu) => run(frame, pred, lut, mu.iter().copied(), tn, sided, mask),
        Err(_) => run(frame, pred, lut, mu.iter(), tn, sided, mask),
    }
}

/// [`saliency`] on the pooled error (the blob's flag bit 4), with `mu` and `tn` apart, for the
/// two-sided test (the one-sided one, the default, is [`pool::pooled_one_sided`]): `e = |mean
/// of v(I) - pred over the (2 pool + 1)^2 window, clipped at the border|`, Q8.8, the mean
/// truncated toward zero. `w` is the face's width; the rows are `frame.len() / w`. Row by row,
/// in two passes that each keep few values live: `vertical` brings the running column sums to
/// the row's window (one row in, one out), then `horizontal` slides the window sum along the
/// row and tests each pixel. No division: `floor(|s| / n) > k` is tested as `|s| >= (k + 1) n`.
/// A mu table that is not 2-byte aligned is read a row at a time into a buffer (blobs are
/// 4-aligned, so only a caller's odd slice takes that path). A radius above [`MAX_POOL`] (which
/// no blob carries) or a width of 0 or past [`MAX_FACE_W`] finds nothing. Slices are taken
/// with `get`, so nothing here can panic.
#[allow(clippy::too_many_arguments)]
pub fn pooled(
    frame: &[u8],
    pred: &[u16],
    lut: &crate::light::Lut,
    mu: U16Table,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
    w: usize,
    pool: u8,
) -> u32 {
    if w == 0 || w > MAX_FACE_W || pool > MAX_POOL {
        return 0;
    }
    let n = frame.len().min(pred.len()).min(tn.len()).min(mask.len()).min(mu.len());
    let (h, r) = (n / w, pool as usize);
    let aligned = bytemuck::try_cast_slice::<u8, u16>(mu.0).ok();
    let mut buf = [0u16; MAX_FACE_W];
    let row = |y: usize| match (frame.get(y * w..y * w + w), pred.get(y * w..y * w + w)) {
        (Some(f), Some(p)) if y < h => Some((f, p)),
        _ => None,
    };
    // Column sums, with PAD zero columns either side: the window slides over them unclipped.
    let mut cols = [0i32; MAX_FACE_W + 2 * PAD];
    let Some(c) = cols.get_mut(PAD..PAD + w) else { return 0 };
    for y in 0..r.min(h) {
        vertical(c, row(y), None, lut);
    }
    let mut count = 0u32;
    for y in 0..h {
        let gone = if y > r { row(y - r - 1) } else { None };
        if let Some(c) = cols.get_mut(PAD..PAD + w) {
            vertical(c, row(y + r), gone, lut);
        }
        let rows = ((y + r).min(h - 1) + 1 - y.saturating_sub(r)) as u32;
        let mu_row: &[u16] = match aligned {
            Some(m) => m.get(y * w..y * w + w).unwrap_or(&[]),
            None => {
                for (x, b) in buf[..w].iter_mut().enumerate() {
                    *b = mu.get(y * w + x);
                }
                &buf[..w]
            }
        };
        let (Some(m_row), Some(tn_row)) = (mask.get_mut(y * w..y * w + w), tn.get(y * w..y * w + w)) else {
            break;
        };
        if mu_row.len() != w {
            break;
        }
        count += horizontal(&cols, mu_row, tn_row, m_row, r, rows, sided);
    }
    count
}

/// Zero columns on either side of the column sums in [`pooled`]: one more than the largest
/// radius, so that the column leaving the window at `x = 0` is one of them.
const PAD: usize = MAX_POOL as usize + 1;

/// Adds the error of row `add` to the column sums and takes that of row `sub` off. Out of
/// line, so that it keeps its own registers.
#[inline(never)]
fn vertical(c: &mut [i32], add: Option<(&[u8], &[u16])>, sub: Option<(&[u8], &[u16])>, lut: &crate::light::Lut) {
    let err = |f: u8, p: u16| err(lut, f, p);
    match (add, sub) {
        (Some((a, b)), Some((e, g))) => {
            for ((((c, &a), &b), &e), &g) in c.iter_mut().zip(a).zip(b).zip(e).zip(g) {
                *c += err(a, b) - err(e, g);
            }
        }
        (Some((a, b)), None) => {
            for ((c, &a), &b) in c.iter_mut().zip(a).zip(b) {
                *c += err(a, b);
            }
        }
        (None, Some((e, g))) => {
            for ((c, &e), &g) in c.iter_mut().zip(e).zip(g) {
                *c -= err(e, g);
            }
        }
        (None, None) => {}
    }
}

/// One row of the mask from the column sums `cols` (the face's `w` columns between [`PAD`]
/// zero columns either side; `w` = `out.len()`): the window sum slides along the row, a column
/// in and one out, and each pixel is tested against its window's size (`rows` times the
/// columns inside the face). Returns the salient pixels.
#[inline(never)]
fn horizontal(cols: &[i32], mu: &[u16], tn: &[u16], out: &mut [u8], r: usize, rows: u32, sided: Sided) -> u32 {
    let w = out.len();
    let col = |j: usize| cols.get(j).copied().unwrap_or(0);
    // The window of x = -1: padded columns PAD - 1 - r ..= PAD - 1 + r.
    let mut sum: i32 = mid(cols, PAD - 1 - r, PAD + r).iter().sum();
    let mut count = 0u32;
    // The borders, one pixel at a time with the clipped window's size.
    let edge = |x: usize, sum: &mut i32, count: &mut u32, out: &mut [u8]| {
        *sum += col(PAD + x + r) - col(PAD + x - r - 1);
        let k = rows * ((x + r).min(w - 1) + 1 - x.saturating_sub(r)) as u32;
        if let (Some(o), Some(&m), Some(&t)) = (out.get_mut(x), mu.get(x), tn.get(x)) {
            *o = test(sum.unsigned_abs(), k, m, t, sided);
            *count += *o as u32;
        }
    };
    let lo = r.min(w);
    for x in 0..lo {
        edge(x, &mut sum, &mut count, out);
    }
    let hi = w.saturating_sub(r).max(lo);
    // The inside: the whole window, k fixed; column x + r comes in, x - r - 1 goes out.
    if hi > lo {
        let k = rows * (2 * r + 1) as u32;
        let ins = mid(cols, PAD + lo + r, PAD + hi + r).iter().zip(mid(cols, PAD + lo - r - 1, PAD + hi - r - 1));
        let thr = mid(mu, lo, hi).iter().zip(mid(tn, lo, hi));
        let outs = out.get_mut(lo..hi).unwrap_or(&mut []);
        let mut inner = 0u32;
        // The board takes pool::pooled_one_sided for the one-sided test; this loop serves the
        // two-sided one and callers with mu and tn apart, so one loop for both.
        for (((&a, &b), (&m, &t)), o) in ins.zip(thr).zip(outs) {
            sum += a - b;
            let s = test(sum.unsigned_abs(), k, m, t, sided);
            *o = s;
            inner += s as u32;
        }
        count += inner;
    }
    for x in hi..w {
        edge(x, &mut sum, &mut count, out);
    }
    count
}

/// `s[a..b]`, or nothing.
#[inline(always)]
fn mid<T>(s: &[T], a: usize, b: usize) -> &[T] {
    s.get(a..b).unwrap_or(&[])
}

/// The signed error of one pixel, Q8.8 grey levels: the fitted frame `v(f)` minus the
/// prediction, censored where clipped ([`crate::light::error`]).
#[inline(always)]
fn err(lut: &crate::light::Lut, f: u8, p: u16) -> i32 {
    crate::light::error(lut, f, p)
}

/// Whether `floor(a / k)` (the pooled error) is salient against `mu` and `t` (Q8.8), in u32:
/// `a <= 49 x 65280` and `(mu + t + 1) x 49 < 2^23`.
#[inline(always)]
fn test(a: u32, k: u32, m: u16, t: u16, sided: Sided) -> u8 {
    // floor(a / k) - mu > t  <=>  a >= (mu + t + 1) k
    let above = a >= (m as u32 + t as u32 + 1) * k;
    match sided {
        Sided::One => above as u8,
        // |floor(a / k) - mu| > t: above mu + t, or below mu - t.
        Sided::Two => (above || (m > t && a < (m as u32 - t as u32) * k)) as u8,
    }
}

#[inline(always)]
fn run(
    frame: &[u8],
    pred: &[u16],
    lut: &crate::light::Lut,
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
                let e = err(lut, i, p).abs();
                let s = (e - m as i32 > t as i32) as u8;
                *out = s;
                count += s as u32;
            }
        }
        Sided::Two => {
            for ((((&i, &p), m), &t), out) in px {
                let e = err(lut, i, p).abs();
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

    /// The bound the board's table routine relies on is the largest sigma of the header's table
    /// and of every pose cell, found again for another model.
    #[test]
    fn the_largest_sigma_spans_every_cell() {
        use msr_shared::blob::PoseGrid;
        let mut spec = crate::testkit::conv_spec(5, false);
        let n = spec.mu.len();
        let mut far = vec![300u16; n];
        far[n - 1] = 9000;
        let cells = vec![(vec![256u16; n], vec![128u16; n]), (vec![256u16; n], far)];
        spec.pose = Some((PoseGrid { bins: [2, 1], lo: [-0.1, -0.1], hi: [0.1, 0.1] }, cells));
        let bytes = spec.to_bytes().unwrap();
        let m = Model::parse(&bytes).unwrap();
        let mut t = Box::new(Thresholds::new());
        assert_eq!(t.sigma_max(&m), 9000);
        let header_max = m.sigma.iter().max().unwrap();
        assert!(header_max < 9000);
        spec.pose = None;
        let bytes = spec.to_bytes().unwrap();
        let plain = Model::parse(&bytes).unwrap();
        assert_eq!(t.sigma_max(&plain), header_max);
    }

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

    /// The branch-free rounding gives what the checks written out give, for every sigma and
    /// thresholds from tiny to overflowing.
    #[test]
    fn table_matches_the_explicit_checks() {
        fn explicit(sigma_q88: u16, threshold: f32, normalisation: Normalisation) -> u16 {
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
        let thresholds = [4.59f32, 1.0, 0.5, 2.7, 3.3, 6.0, 9.9, 1e-3, 1e-30, f32::MIN_POSITIVE, 1e-45, 255.9, 1e5, 1e30, f32::MAX];
        for t in thresholds {
            for norm in [Normalisation::StdDev, Normalisation::Variance] {
                for sigma in 0..=u16::MAX {
                    assert_eq!(threshold_q88(sigma, t, norm), explicit(sigma, t, norm), "sigma {sigma} t {t} {norm:?}");
                }
            }
        }
    }

    /// The pooled mask against the window mean written out plainly, on faces of 7 x 9 (every
    /// radius: borders only, and a few inner pixels), 11 x 20 and 3 x 2 (narrower than the
    /// window), one- and two-sided, with the mu table aligned and not.
    #[test]
    fn pooled_matches_the_plain_window_mean() {
        for (w, h) in [(9usize, 7usize), (20, 11), (2, 3)] {
            pooled_case(w, h);
        }
    }

    fn pooled_case(w: usize, h: usize) {
        let n = w * h;
        let frame: Vec<u8> = (0..n).map(|i| ((i * 37) % 251) as u8).collect();
        let pred: Vec<u16> = (0..n).map(|i| (((i * 91) % 200) as u16) << 8 | (i as u16 * 13 % 256)).collect();
        let mu: Vec<u16> = (0..n).map(|i| (i as u16 % 5) * 300).collect();
        let mu_bytes: Vec<u8> = mu.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut shifted = vec![0u8];
        shifted.extend_from_slice(&mu_bytes);
        let tn: Vec<u16> = (0..n).map(|i| (i as u16 % 7) * 500).collect();
        for pool in 0..=3u8 {
            let r = pool as i64;
            for sided in [Sided::One, Sided::Two] {
                let mut mask = vec![7u8; n];
                let count = pooled(&frame, &pred, &crate::light::Lut::IDENTITY, U16Table(&mu_bytes), &tn, sided, &mut mask, w, pool);
                // An unaligned mu table gives the same mask.
                let mut odd = vec![7u8; n];
                pooled(&frame, &pred, &crate::light::Lut::IDENTITY, U16Table(&shifted[1..]), &tn, sided, &mut odd, w, pool);
                assert_eq!(odd, mask, "unaligned mu, pool {pool} {sided:?} {w}x{h}");
                let mut want = vec![0u8; n];
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
                assert_eq!(mask, want, "pool {pool} {sided:?} {w}x{h}");
                assert_eq!(count as usize, want.iter().filter(|&&m| m == 1).count());
                if pool == 0 {
                    // Radius 0 is the per-pixel saliency.
                    let mut plain = vec![0u8; n];
                    saliency(&frame, &pred, &crate::light::Lut::IDENTITY, U16Table(&mu_bytes), &tn, sided, &mut plain);
                    assert_eq!(mask, plain);
                }
            }
        }
        // A width past the board's limit or of zero finds nothing and writes nothing.
        let mut mask = vec![7u8; n];
        assert_eq!(pooled(&frame, &pred, &crate::light::Lut::IDENTITY, U16Table(&mu_bytes), &tn, Sided::One, &mut mask, 0, 2), 0);
        assert_eq!(pooled(&frame, &pred, &crate::light::Lut::IDENTITY, U16Table(&mu_bytes), &tn, Sided::One, &mut mask, MAX_FACE_W + 1, 2), 0);
        assert_eq!(mask, vec![7u8; n]);
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
            &crate::light::Lut::IDENTITY,
            U16Table(&mu_bytes),
            &tn,
            Sided::One,
            &mut mask,
        );
        assert_eq!((n, mask), (1, [1, 0, 0]));
        let n = saliency(
            &frame,
            &pred,
            &crate::light::Lut::IDENTITY,
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
            &crate::light::Lut::IDENTITY,
            U16Table(&shifted[1..]),
            &tn,
            Sided::Two,
            &mut mask,
        );
        assert_eq!((n, mask), (2, [1, 1, 0]));
    }
}
