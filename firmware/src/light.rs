//! The photometric fit: the observed face brought to the prediction's light before the error
//! statistics are applied, and the frames the model cannot explain refused.
//!
//! Per frame, on a grid of sample pixels ([`STEP_X`] x [`STEP_Y`], pixels where the camera clipped
//! left out: they say nothing about the light), a straight line `P = g I + k` is fitted from the observed
//! grey `I` to the predicted face `P` (Q8.8) by least squares, then twice again on the samples
//! whose residual is within 2.5 RMS of the line before ([`TRIM_X4`], at least [`MIN_CUT_Q88`]):
//! a mark, a highlight or the arm cannot pull the last fit (one trimming left a dark mark's
//! pull on the slope at 4 %: its samples sit at the end of the grey range, where they tilt the
//! first line towards themselves). The saliency then compares
//! `v(I) = clamp(g I + k, 0, 255)` (Q8.8, a 256-entry table, [`LightFit::table`]) with the
//! prediction in place of `I << 8`, the error censored where the camera clipped ([`error`]).
//! The identity fit ([`LightFit::IDENTITY`]) is `I << 8`.
//!
//! Where the camera clipped: at 0 and 255, and at the samples' darkest or brightest grey level
//! when a tenth of them sit exactly there (a plateau: [`PLATEAU_SHARE`], [`LightFit::clip`]).
//! A sensor saturates before the ADC's last code often enough (limited-range video stops at 235,
//! a digital gain under 1 after the clip, a frame darkened after it was taken): the 15 published
//! real frames are a quarter white at 255, and at exposure x0.7 that white is a plateau at 178
//! which, taken as grey, made an unmarked frame fire and moved a mark's blob off the mark.
//!
//! The same fit decides whether the frame shows the face in a light the model explains:
//! [`Verdict::NoFace`] when the samples do not follow the prediction (their correlation under
//! [`MIN_CORRELATION`], or no contrast at all: black, white, covered, an empty room);
//! [`Verdict::SceneChanged`] when the fit is out of bounds (gain outside [`GAIN_RANGE`], fewer
//! than [`MIN_INLIER_SHARE`] of the samples explained) or the top and bottom halves of the face
//! disagree by more than [`MAX_HALF_SPLIT`] (a lamp switching while the frame was read out).
//!
//! Everything is integer arithmetic but one correlation test in `f32` (IEEE operations,
//! correctly rounded on both targets): host and `thumbv7em` agree bit for bit.

use msr_shared::blob::{MAX_FACE_H, MAX_FACE_W};

mod arm;
pub use arm::{any_clipped, ramp, sample_levels};

/// Sample grid: every `STEP_X`-th column of every `STEP_Y`-th row, starting half a step in
/// (208 samples of a 75 x 58 face); a face small enough takes every pixel, or every second or
/// third, as long as the samples fit in [`MAX_SAMPLES`].
pub const STEP_X: usize = 6;
/// See [`STEP_X`].
pub const STEP_Y: usize = 5;
/// Most samples a face gives.
pub const MAX_SAMPLES: usize = 256;
const _: () = assert!(MAX_FACE_W.div_ceil(STEP_X) * MAX_FACE_H.div_ceil(STEP_Y) <= MAX_SAMPLES);
const _: () = assert!(254 * 65535 * MAX_SAMPLES as u64 <= u32::MAX as u64);

/// The sample grid's steps for a `w` x `h` face: the finest that fits [`MAX_SAMPLES`].
pub fn steps(w: usize, h: usize) -> (usize, usize) {
    for s in 1..=3 {
        if w.div_ceil(s) * h.div_ceil(s) <= MAX_SAMPLES {
            return (s, s);
        }
    }
    (STEP_X, STEP_Y)
}
/// Samples within this many RMS of the fit before (x 4: 10 = 2.5) make the next fit.
pub const TRIM_X4: u64 = 10;
/// The trimming cut is at least this, Q8.8 (4 grey levels): a frame that the first fit
/// explains to the noise keeps its samples.
pub const MIN_CUT_Q88: u64 = 4 * 256;
/// The fitted gain's bounds (the prediction's grey per observed grey).
pub const GAIN_RANGE: [f32; 2] = [0.4, 2.5];
/// Least share of usable samples the second fit keeps, in 1/256 (150/256 = 0.59).
pub const MIN_INLIER_SHARE: u32 = 150;
/// Least correlation between observed and predicted samples (of the kept ones).
pub const MIN_CORRELATION: f32 = 0.6;
/// Largest difference of the halves' mean residuals, as a share of the mean predicted grey,
/// in 1/256 (41/256 = 0.16; at 0.10 one of the 15 published real frames, at its own light, was
/// refused).
pub const MAX_HALF_SPLIT: u32 = 41;
/// The brightest fitted grey level, Q8.8: 255, where the camera the model was calibrated with
/// clipped. A pixel that this frame's light makes brighter than that would have shown 255
/// there; above it, a white face the model predicts at 255 looked brighter than predicted by
/// as much as the gain lifts it (at exposure x0.7 of the published frames, whose white is
/// clipped, 1.5 grey levels: salient where the calibration frames never varied).
pub const V_MAX: u16 = 255 << 8;
/// Least usable samples for a fit.
pub const MIN_SAMPLES: u32 = 16;
/// A plateau ([`LightFit::clip`]): at least one sample in `PLATEAU_SHARE` (and at least
/// [`PLATEAU_SAMPLES`]) at exactly the samples' brightest (darkest) grey level. A smooth
/// highlight or a flat rendered patch puts few there: at most 7 of about 150 in the skin robot's
/// test frames, at exposure x1 and x0.8 alike. The published real frames' white, 37 to 40 of
/// about 144, is a clip, and one that moves marks and fires unmarked frames when taken as grey.
/// A clip smaller than a tenth of the face is left as grey, as before plateaus were looked for.
pub const PLATEAU_SHARE: u32 = 10;
/// See [`PLATEAU_SHARE`].
pub const PLATEAU_SAMPLES: u32 = 4;

/// Whether a frame shows the face in a light the model explains.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// It does: the saliency runs on the fitted frame.
    Face,
    /// The samples do not follow the predicted face (black, white, covered, someone else).
    NoFace,
    /// The light is outside the fit's bounds, or changed while the frame was taken.
    SceneChanged,
}

/// One frame's fit: `v(I) = clamp((gain I + offset + 128) >> 8, 0, V_MAX)`, Q8.8.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LightFit {
    /// Q8.8 of the prediction per observed grey level, x 256 (65536 = unit gain).
    pub gain: i32,
    /// Q8.8 x 256.
    pub offset: i32,
    /// Usable samples (not at a clip level), and how many the second fit kept.
    pub samples: u16,
    /// See [`LightFit::samples`].
    pub inliers: u16,
    /// Correlation of the kept samples with the prediction, x 1000 (0 when undefined).
    pub correlation_milli: i16,
    /// Whether the frame shows the face in a light the model explains.
    pub verdict: Verdict,
    /// The grey levels at which the camera clipped, darkest and brightest: 0 and 255, or a
    /// plateau's level ([`PLATEAU_SHARE`]). A pixel at or past them is censored ([`error`]).
    pub clip: [u8; 2],
}

impl LightFit {
    /// `v(I) = I << 8`: the error as it was before the fit existed.
    pub const IDENTITY: LightFit = LightFit {
        gain: 65536,
        offset: 0,
        samples: 0,
        inliers: 0,
        correlation_milli: 1000,
        verdict: Verdict::Face,
        clip: [0, 255],
    };

    /// The gain as a number (1 = the prediction's light).
    pub fn gain_f32(&self) -> f32 {
        self.gain as f32 / 65536.0
    }

    /// The offset in grey levels.
    pub fn offset_grey(&self) -> f32 {
        self.offset as f32 / 65536.0
    }

    /// `v(i)` for one grey level.
    pub fn value(&self, i: u8) -> u16 {
        let v = (self.gain as i64 * i as i64 + self.offset as i64 + 128) >> 8;
        v.clamp(0, V_MAX as i64) as u16
    }

    /// The fit as the saliency takes it: [`LightFit::table`] and the clip levels.
    pub fn lut(&self, out: &mut Lut) {
        self.table(&mut out.v);
        [out.lo, out.hi] = self.clip;
    }

    /// The 256-entry table of [`LightFit::value`].
    pub fn table(&self, out: &mut [u16; 256]) {
        // Stepping by the gain: exact, the same sums as `value` (no rounding until the shift).
        // In i32 when both ends of the ramp fit (every fit [`fit`] makes: |gain| <= 2^20,
        // |offset| <= 2^28), a quarter of the i64 loop's instructions on the board.
        let (first, last) = (self.offset as i64 + 128, self.offset as i64 + 128 + 255 * self.gain as i64);
        if first.abs() < 1 << 30 && last.abs() < 1 << 30 {
            ramp(out, first as i32, self.gain);
            return;
        }
        let mut acc = first;
        for o in out.iter_mut() {
            *o = (acc >> 8).clamp(0, V_MAX as i64) as u16;
            acc += self.gain as i64;
        }
    }
}

/// `out[i] = clamp((first + i gain) >> 8, 0, V_MAX)`, for `first` and `first + 255 gain` both
/// within `±2^30` (so every step between is too): the i32 loop of [`LightFit::table`], plain.
pub fn ramp_reference(out: &mut [u16; 256], first: i32, gain: i32) {
    let mut acc = first;
    for o in out.iter_mut() {
        *o = (acc >> 8).clamp(0, V_MAX as i32) as u16;
        acc = acc.wrapping_add(gain);
    }
}

/// A frame's fitted grey levels `v` ([`LightFit::table`]) and the levels at which its camera
/// clipped ([`LightFit::clip`]): what every saliency path takes the error from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Lut {
    /// `v(I)`, Q8.8.
    pub v: [u16; 256],
    /// A pixel at or under `lo` was at most as bright as `v(lo)`.
    pub lo: u8,
    /// A pixel at or over `hi` was at least as bright as `v(hi)`.
    pub hi: u8,
}

impl Lut {
    /// `v(I) = I << 8`, clipped at 0 and 255.
    pub const IDENTITY: Lut = Lut { v: IDENTITY_TABLE, lo: 0, hi: 255 };
}

/// The signed error of one pixel, Q8.8: `v(f) - p`, censored where the camera clipped. A pixel
/// at the top clip level (255, or a plateau's) was at least as bright as `v(f)`, so it differs
/// from the prediction only by how far `v(f)` is above it (`max(v(f) - p, 0)`); a pixel at the
/// bottom one only by how far `v(f)` is below (`min(v(f) - p, 0)`). Without this, a brighter
/// exposure (the red robot's bright face clips at x1.2) made every clipped highlight look darker
/// than predicted, and every unmarked frame fired. Every saliency path takes its error from here
/// or from [`censor_row`].
#[inline(always)]
pub fn error(lut: &Lut, f: u8, p: u16) -> i32 {
    let e = lut.v[f as usize] as i32 - p as i32;
    if f >= lut.hi {
        e.max(0)
    } else if f <= lut.lo {
        e.min(0)
    } else {
        e
    }
}

/// For the row routines, which compute `v[f] - p` and nothing else: when `frame`'s row has a
/// clipped pixel, writes to `out` the prediction with which that difference is [`error`]
/// (`min(p, v(f))` at or over the top clip level, `max(p, v(f))` at or under the bottom one)
/// and returns `true`; `false` (and `out` untouched) when nothing in the row is clipped.
#[inline]
pub fn censor_row(frame: &[u8], pred: &[u16], lut: &Lut, out: &mut [u16]) -> bool {
    if !any_clipped(frame, lut) {
        return false;
    }
    for ((o, &f), &p) in out.iter_mut().zip(frame).zip(pred) {
        let v = lut.v[f as usize];
        *o = if f >= lut.hi {
            p.min(v)
        } else if f <= lut.lo {
            p.max(v)
        } else {
            p
        };
    }
    true
}

/// The identity fit's table: `I << 8`.
pub const IDENTITY_TABLE: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = (i as u16) << 8;
        i += 1;
    }
    t
};

/// Least-squares sums over samples (x: observed grey, y: prediction Q8.8).
#[derive(Clone, Copy, Default, Debug, PartialEq)]
struct Sums {
    n: u32,
    x: u32,
    y: u32,
    xx: u32,
    /// At most [`MAX_SAMPLES`] of x y <= 254 x 65535 (0 and 255 are not samples): u32 holds it.
    xy: u32,
    yy: u64,
}

impl Sums {
    /// One sample; `YY`: its square too (only the correlation, at the end, needs it).
    #[inline(always)]
    fn add<const YY: bool>(&mut self, x: u32, y: u32) {
        self.n += 1;
        self.x += x;
        self.y += y;
        self.xx += x * x;
        self.xy += x * y;
        if YY {
            self.yy += y as u64 * y as u64;
        }
    }

    /// The sums without those of `o`, a part of the samples these sum (exact: every sum of
    /// a part is at most the whole's).
    fn minus(&self, o: &Sums) -> Sums {
        Sums {
            n: self.n - o.n,
            x: self.x - o.x,
            y: self.y - o.y,
            xx: self.xx - o.xx,
            xy: self.xy - o.xy,
            yy: self.yy - o.yy,
        }
    }

    /// The sums without one of their samples.
    #[inline(always)]
    fn remove(&mut self, x: u32, y: u32) {
        let mut one = Sums::default();
        one.add::<true>(x, y);
        *self = self.minus(&one);
    }

    fn plus(&self, o: &Sums) -> Sums {
        Sums {
            n: self.n + o.n,
            x: self.x + o.x,
            y: self.y + o.y,
            xx: self.xx + o.xx,
            xy: self.xy + o.xy,
            yy: self.yy + o.yy,
        }
    }

    /// `n Sxx - Sx^2`, `n Sxy - Sx Sy`, `n Syy - Sy^2`.
    fn centred(&self) -> (i64, i64, i64) {
        let n = self.n as i64;
        let (x, y) = (self.x as i64, self.y as i64);
        (
            n * self.xx as i64 - x * x,
            n * self.xy as i64 - x * y,
            n * self.yy as i64 - y * y,
        )
    }

    /// The line's (gain, offset) in [`LightFit`]'s units, or `None` without contrast: least
    /// squares with the origin (black stays black) as a pseudo-sample of the samples' own
    /// weight, which halves the offset's pull on the gain.
    fn line(&self) -> Option<(i32, i32)> {
        if self.n < 2 {
            return None;
        }
        let anchored = Sums { n: 2 * self.n, ..*self };
        let (dxx, dxy, _) = anchored.centred();
        if dxx <= 0 {
            return None;
        }
        let n = anchored.n;
        // gain = 256 dxy / dxx (rounded to nearest), clamped to 16 x unit.
        let g = div_round(dxy * 256, dxx).clamp(-(1 << 20), 1 << 20);
        // offset = 256 (Sy - slope Sx) / n = (256 Sy - g Sx) / n.
        let k = div_round(256 * self.y as i64 - g * self.x as i64, n as i64).clamp(-(1 << 28), 1 << 28);
        Some((g as i32, k as i32))
    }
}

/// `a / b` rounded to nearest (ties away from zero), `b > 0`.
fn div_round(a: i64, b: i64) -> i64 {
    let q = div_u64(a.unsigned_abs() + b as u64 / 2, b as u64) as i64;
    if a >= 0 { q } else { -q }
}

/// `n / d`, `d > 0`; with the board's 32-bit divide where the operands allow (a 64-bit
/// division is a library loop there: about 400 instructions a line fit went to two of them).
fn div_u64(n: u64, d: u64) -> u64 {
    if d >> 32 != 0 {
        n / d
    } else if n >> 32 == 0 {
        (n as u32 / d as u32) as u64
    } else if n >> 32 < d {
        div_64_32(n, d as u32) as u64
    } else {
        n / d
    }
}

/// `n / d` for `n / d < 2^32` (`n >> 32 < d`): long division in two 16-bit digits on 32-bit
/// divides (Hacker's Delight, `divlu`).
fn div_64_32(n: u64, d: u32) -> u32 {
    let s = d.leading_zeros();
    let d = d << s;
    let (d1, d0) = (d >> 16, d & 0xFFFF);
    // n << s, whose top 32 bits are under d (so under 2^32).
    let (hi, lo) = ((n >> 32) as u32, n as u32);
    let top = if s == 0 { hi } else { (hi << s) | (lo >> (32 - s)) };
    let lo = lo << s;
    let (n1, n0) = (lo >> 16, lo & 0xFFFF);
    // Each digit: estimate from the divisor's top half, then at most two corrections.
    let digit = |top: u32, next: u32| -> (u32, u32) {
        let (mut q, mut r) = (top / d1, top % d1);
        while q >> 16 != 0 || q as u64 * d0 as u64 > ((r as u64) << 16) + next as u64 {
            q -= 1;
            r += d1;
            if r >> 16 != 0 {
                break;
            }
        }
        // The remainder of (top : next) / d, under d.
        (q, (((top as u64) << 16) + next as u64 - q as u64 * d as u64) as u32)
    };
    let (q1, rem) = digit(top, n1);
    let (q0, _) = digit(rem, n0);
    (q1 << 16) | q0
}

/// Q8.8 residual of one sample against a line.
#[inline(always)]
fn residual(x: u32, y: u32, g: i32, k: i32) -> i32 {
    y as i32 - ((g * x as i32 + k + 128) >> 8)
}

/// The samples a pass keeps: those within `cut2` (squared Q8.8) of the line `(g, k)`; their
/// sums and squared residuals. What [`trim`] gives, the plain way (for its test).
#[cfg(test)]
fn kept(xs: &[u8], ys: &[u16], g: i32, k: i32, cut2: u32) -> (Sums, u64) {
    let (mut s, mut sse) = (Sums::default(), 0u64);
    for (&x, &y) in xs.iter().zip(ys) {
        let r = residual(x as u32, y as u32, g, k).unsigned_abs().min(65535);
        let r2 = r * r;
        if r2 <= cut2 {
            s.add::<false>(x as u32, y as u32);
            sse += r2 as u64;
        }
    }
    (s, sse)
}

/// The squared residuals of every sample against the line `(g, k)`, summed, each residual's
/// magnitude (at most 65535) in `rs`, for [`trim`], and the sum of the squared predictions
/// (what `Sums::add::<true>` adds beyond the gather's sums).
fn sse(xs: &[u8], ys: &[u16], g: i32, k: i32, rs: &mut [u16]) -> (u64, u64) {
    let (mut sse, mut yy) = (0u64, 0u64);
    for ((&x, &y), r_out) in xs.iter().zip(ys).zip(rs.iter_mut()) {
        let r = residual(x as u32, y as u32, g, k).unsigned_abs().min(65535);
        *r_out = r as u16;
        sse += (r * r) as u64;
        yy += y as u64 * y as u64;
    }
    (sse, yy)
}

/// `floor(sqrt(cut2))`, or `u32::MAX` once `cut2 >= 65535^2`: a residual magnitude `r` at
/// most 65535 has `r^2 <= cut2` exactly when `r <= root_cut(cut2)`.
fn root_cut(cut2: u32) -> u32 {
    if cut2 >= 65535 * 65535 { u32::MAX } else { isqrt(cut2) }
}

/// The samples within `cut2` (squared Q8.8) of the line [`sse`] measured `rs` against: their
/// sums and squared residuals, as `all` (the sums of every sample) and `sse` (the sum of every
/// `rs^2`) without the samples past the cut. The same sums added up sample by sample
/// (`kept`, kept for the test) took 32 instructions a sample on the board; the cut rejects a
/// few samples at most, so taking them out costs about 7 a sample.
#[inline(always)]
fn trim(all: Sums, sse: u64, xs: &[u8], ys: &[u16], rs: &[u16], cut2: u32) -> (Sums, u64) {
    let cut = root_cut(cut2);
    let (mut s, mut sse) = (all, sse);
    for ((&x, &y), &r) in xs.iter().zip(ys).zip(rs) {
        if r as u32 > cut {
            s.remove(x as u32, y as u32);
            sse -= r as u64 * r as u64;
        }
    }
    (s, sse)
}

/// The samples within `cut2` of the line `(g, k)`, as `kept_sums` (kept for the test) takes
/// them (with their squares), from `sums`, the sums of every one of `xs` and `ys`: those past
/// the cut taken out (14 instructions a sample on the board where adding up the kept ones
/// took 27).
#[inline(always)]
fn trim_again(sums: Sums, xs: &[u8], ys: &[u16], g: i32, k: i32, cut2: u32) -> Sums {
    let cut = root_cut(cut2);
    let mut s = sums;
    for (&x, &y) in xs.iter().zip(ys) {
        if residual(x as u32, y as u32, g, k).unsigned_abs() > cut {
            s.remove(x as u32, y as u32);
        }
    }
    s
}

/// The samples within `cut2` of the line `(g, k)`, as [`kept`] takes them, with their squares
/// (for the correlation) and without the squared residuals: `min(r, 65535)^2 <= cut2` is
/// `r <= root_cut(cut2)`. What [`trim_again`] gives, the plain way (for its test).
#[cfg(test)]
fn kept_sums(xs: &[u8], ys: &[u16], g: i32, k: i32, cut2: u32) -> Sums {
    let cut = root_cut(cut2);
    let mut s = Sums::default();
    for (&x, &y) in xs.iter().zip(ys) {
        if residual(x as u32, y as u32, g, k).unsigned_abs() <= cut {
            s.add::<true>(x as u32, y as u32);
        }
    }
    s
}

/// `floor(sqrt(n))`, exactly: two bits of the root a step, 16 steps at most (core's
/// `u32::isqrt` took 700 bytes more of the board's code).
pub(crate) fn isqrt(n: u32) -> u32 {
    let (mut rem, mut root, mut bit) = (n, 0u32, 1u32 << 30);
    while bit > n {
        bit >>= 2;
    }
    while bit != 0 {
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root
}

#[cfg(test)]
/// The bisection [`isqrt`] replaced, for its test.
fn isqrt_bisection(n: u32) -> u32 {
    // lo^2 <= n < hi^2
    let (mut lo, mut hi) = (0u64, 1u64 << 16);
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if mid * mid <= n as u64 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo as u32
}

/// The squared cut ([`TRIM_X4`] times the RMS, at least [`MIN_CUT_Q88`]) for a sum of squared
/// residuals `sse` over `n` samples, saturating.
fn cut_of(sse: u64, n: u32) -> u32 {
    let c = div_u64(sse.saturating_mul(TRIM_X4 * TRIM_X4), 16 * n.max(1) as u64);
    c.max(MIN_CUT_Q88 * MIN_CUT_Q88).min(u32::MAX as u64) as u32
}

/// Fits the light of `frame` (grey, `w` wide) to `pred` (Q8.8, same size) and judges it:
/// a least-squares line on every usable sample, then twice on the samples within the cut of
/// the line before (the cut from those samples' residuals), the last time with the top and
/// bottom halves of the face apart. Faces smaller than the sample grid needs, or without
/// enough usable samples, are [`Verdict::NoFace`].
pub fn fit(frame: &[u8], pred: &[u16], w: usize) -> LightFit {
    let mut xs = [0u8; MAX_SAMPLES];
    let mut ys = [0u16; MAX_SAMPLES];
    let no_face = LightFit { verdict: Verdict::NoFace, correlation_milli: 0, ..LightFit::IDENTITY };
    if w == 0 || w > MAX_FACE_W {
        return no_face;
    }
    let h = (frame.len().min(pred.len()) / w).min(MAX_FACE_H);
    let (mut n, mut half, [mut top, bottom]) = gather(frame, pred, w, h, &mut xs, &mut ys);
    let mut all = top.plus(&bottom);
    // A plateau at the samples' extreme is where the camera clipped: those samples leave too.
    let clip = clip_levels(&mut xs, n);
    if clip != [0, 255] {
        let (mut m, mut kept_half) = (0, None);
        all = Sums::default();
        for j in 0..n {
            if j == half {
                (kept_half, top) = (Some(m), all);
            }
            let x = xs[j];
            if x > clip[0] && x < clip[1] {
                (xs[m], ys[m]) = (x, ys[j]);
                all.add::<false>(x as u32, ys[j] as u32);
                m += 1;
            }
        }
        if kept_half.is_none() {
            top = all;
        }
        (n, half) = (m, kept_half.unwrap_or(m));
    }
    let samples = n as u16;
    let no_face = LightFit { samples, clip, ..no_face };
    if (n as u32) < MIN_SAMPLES {
        return no_face;
    }
    let (xs, ys) = (&xs[..n], &ys[..n]);
    let Some((g0, k0)) = all.line() else { return no_face };
    // With the residuals, the squares of the predictions (for the correlation), each half's
    // apart: the halves' sums start as `top` and `all - top`, and each trimming takes its few
    // rejected samples out of them again.
    let mut rs = [0u16; MAX_SAMPLES];
    let (rs_top, rs_bottom) = rs.split_at_mut(half);
    let (sse_top, yy_top) = sse(&xs[..half], &ys[..half], g0, k0, rs_top);
    let (sse_bottom, yy_bottom) = sse(&xs[half..], &ys[half..], g0, k0, rs_bottom);
    let sse0 = sse_top + sse_bottom;
    (top.yy, all.yy) = (yy_top, yy_top + yy_bottom);
    let (s1, sse1) = trim(all, sse0, xs, ys, &rs[..n], cut_of(sse0, n as u32));
    let Some((g1, k1)) = s1.line() else { return no_face };
    let cut2 = cut_of(sse1, s1.n);
    let halves = [
        trim_again(top, &xs[..half], &ys[..half], g1, k1, cut2),
        trim_again(all.minus(&top), &xs[half..], &ys[half..], g1, k1, cut2),
    ];
    let kept = halves[0].plus(&halves[1]);
    let Some((gain, offset)) = kept.line() else { return no_face };
    let (dxx, dxy, dyy) = kept.centred();
    let corr = if dxx > 0 && dyy > 0 {
        let (a, b, c) = (dxy as f32, dxx as f32, dyy as f32);
        // libm on both targets: the same bits as the board.
        a / libm::sqrtf(b * c)
    } else {
        0.0
    };
    let mut out = LightFit {
        gain,
        offset,
        samples,
        inliers: kept.n as u16,
        correlation_milli: (corr * 1000.0) as i16,
        verdict: Verdict::Face,
        clip,
    };
    let gf = out.gain_f32();
    out.verdict = if !(corr >= MIN_CORRELATION) {
        Verdict::NoFace
    } else if !(GAIN_RANGE[0]..=GAIN_RANGE[1]).contains(&gf)
        || kept.n * 256 < MIN_INLIER_SHARE * n as u32
        || (halves_split(&halves, gain, offset) > MAX_HALF_SPLIT as i64
            && median_split(xs, ys, half, (g1, k1, cut2), (gain, offset), &kept) > MAX_HALF_SPLIT as i64)
    {
        Verdict::SceneChanged
    } else {
        Verdict::Face
    };
    out
}

/// The usable samples of the grid (neither 0 nor 255) into `xs` (grey) and `ys` (prediction),
/// with the sums of the top half's rows (those above `h / 2`) and of the bottom half's apart
/// (without the squares of the predictions: [`sse`] adds them). Returns the samples, the
/// first of the bottom half's and the two sums.
fn gather(frame: &[u8], pred: &[u16], w: usize, h: usize, xs: &mut [u8; MAX_SAMPLES], ys: &mut [u16; MAX_SAMPLES]) -> (usize, usize, [Sums; 2]) {
    let (step_x, step_y) = steps(w, h);
    // The first grid row at or under h / 2.
    let first = step_y / 2;
    let split = (first + (h / 2).saturating_sub(first).div_ceil(step_y) * step_y).min(h);
    let (half, top) = gather_rows(frame, pred, w, (first, split), (step_x, step_y), xs, ys, 0);
    let (n, bottom) = gather_rows(frame, pred, w, (split, h), (step_x, step_y), xs, ys, half);
    (n, half, [top, bottom])
}

/// The grid's rows `rows.0, rows.0 + step_y, ..` under `rows.1` into `xs` and `ys` from
/// sample `from`: how many samples `xs` holds after them, and their sums. A function of its
/// own, with its sums in locals: inside [`fit`] they lived on the stack (29 instructions a
/// sample; 21 here).
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn gather_rows(frame: &[u8], pred: &[u16], w: usize, rows: (usize, usize), (step_x, step_y): (usize, usize), xs: &mut [u8; MAX_SAMPLES], ys: &mut [u16; MAX_SAMPLES], from: usize) -> (usize, Sums) {
    let mut n = from;
    let (mut sx, mut sy, mut sxx, mut sxy) = (0u32, 0u32, 0u32, 0u32);
    let mut y = rows.0;
    while y < rows.1 {
        let (Some(fr), Some(pr)) = (frame.get(y * w..y * w + w), pred.get(y * w..y * w + w)) else { break };
        let mut x = step_x / 2;
        while x < w {
            let i = fr[x];
            if i != 0 && i != 255 && n < MAX_SAMPLES {
                let p = pr[x];
                xs[n] = i;
                ys[n] = p;
                let (i, p) = (i as u32, p as u32);
                sx += i;
                sy += p;
                sxx += i * i;
                sxy += i * p;
                n += 1;
            }
            x += step_x;
        }
        y += step_y;
    }
    (n, Sums { n: (n - from) as u32, x: sx, y: sy, xx: sxx, xy: sxy, yy: 0 })
}

/// The clip levels of the `n` samples in `xs` (none at 0 or 255): their darkest and brightest
/// grey level where a plateau sits ([`PLATEAU_SHARE`]), else 0 and 255. May write up to 3 bytes
/// past `n` (the board's routine reads whole words).
fn clip_levels(xs: &mut [u8; MAX_SAMPLES], n: usize) -> [u8; 2] {
    let [bottom, top, at_bottom, at_top] = sample_levels(xs, n);
    let least = PLATEAU_SAMPLES.max(n as u32 / PLATEAU_SHARE);
    [
        if at_bottom as u32 >= least { bottom as u8 } else { 0 },
        if at_top as u32 >= least { top as u8 } else { 255 },
    ]
}

/// The darkest and brightest of `xs`, and how many sit at each: `[bottom, top, at bottom, at
/// top]`; `[255, 0, 0, 0]` when empty. Plain Rust, what the board's routine must give.
pub fn sample_levels_reference(xs: &[u8]) -> [u16; 4] {
    let (mut bottom, mut top) = (255u8, 0u8);
    for &x in xs {
        bottom = bottom.min(x);
        top = top.max(x);
    }
    let (mut at_bottom, mut at_top) = (0u16, 0u16);
    for &x in xs {
        at_bottom += (x == bottom) as u16;
        at_top += (x == top) as u16;
    }
    [bottom as u16, top as u16, at_bottom, at_top]
}

/// How far apart the halves' median residuals under the line `(g, k)` are, of the samples
/// [`trim_again`] keeps (within `cut2` of the line `(g1, k1)`), in 1/256 of the kept samples'
/// mean predicted grey. Asked only of a frame whose halves' means are apart: a lamp that
/// switched moves every residual of its half, median and mean alike, while a large mark moves
/// the mean of its half only (the green mark of one published frame, a quarter of the usable
/// samples of its half once the white face clips at exposure x1.1, took the mean past the bound).
fn median_split(xs: &[u8], ys: &[u16], half: usize, (g1, k1, cut2): (i32, i32, u32), (g, k): (i32, i32), kept: &Sums) -> i64 {
    let cut = root_cut(cut2);
    // Insertion sort as the samples come (at most MAX_SAMPLES, only on this rare path): the
    // residuals in Q8.8, clamped to i16 (128 grey levels either side is enough for a median).
    let median = |xs: &[u8], ys: &[u16]| -> Option<i32> {
        let mut r = [0i16; MAX_SAMPLES];
        let mut m = 0usize;
        for (&x, &y) in xs.iter().zip(ys) {
            if m == MAX_SAMPLES || residual(x as u32, y as u32, g1, k1).unsigned_abs() > cut {
                continue;
            }
            let v = residual(x as u32, y as u32, g, k).clamp(i16::MIN as i32, i16::MAX as i32) as i16;
            let mut j = m;
            while j > 0 && r[j - 1] > v {
                r[j] = r[j - 1];
                j -= 1;
            }
            r[j] = v;
            m += 1;
        }
        (m > 0).then(|| r[m / 2] as i32)
    };
    let half = half.min(xs.len()).min(ys.len());
    let (Some(top), Some(bottom)) = (median(&xs[..half], &ys[..half]), median(&xs[half..], &ys[half..])) else {
        return 0;
    };
    if kept.n == 0 || kept.y == 0 {
        return 0;
    }
    let mean_y = div_round(kept.y as i64, kept.n as i64).max(1);
    div_u64((top - bottom).unsigned_abs() as u64 * 256, mean_y as u64) as i64
}

/// How far apart the halves' mean residuals under the fit are, in 1/256 of the mean predicted
/// grey: what a lamp switching between the top and the bottom rows leaves.
fn halves_split(h: &[Sums; 2], g: i32, k: i32) -> i64 {
    // Mean residual of a half, Q8.8 x 256: (256 Sy - g Sx - k n) / n.
    let mean_r = |s: &Sums| {
        if s.n == 0 {
            return 0;
        }
        div_round(256 * s.y as i64 - g as i64 * s.x as i64 - k as i64 * s.n as i64, s.n as i64)
    };
    let all = h[0].plus(&h[1]);
    if all.n == 0 || h[0].n == 0 || h[1].n == 0 || all.y == 0 {
        return 0;
    }
    let mean_y = div_round(256 * all.y as i64, all.n as i64).max(1);
    div_u64((mean_r(&h[0]) - mean_r(&h[1])).unsigned_abs() * 256, mean_y as u64) as i64
}

#[cfg(test)]
mod tests;
