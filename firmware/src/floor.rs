//! The frame's own floor: how much more its error spreads than the frames the statistics came from.
//!
//! A camera other than the calibration's (defocus, a smear while the head moves, sensor noise,
//! compression, another tone curve or white balance) adds an error of its own to every pixel,
//! which the model's per-pixel statistics never saw: judged by them alone, a webcam's ordinary
//! frame fires. The statistics cannot know the camera; the frame shows it. The rules:
//!
//! 1. The frame's spread `s`: the pooled error `|mean of v(I) - pred|` over the test's own window
//!    at each pixel of every second row of the photometric fit's sample grid
//!    ([`crate::light::steps`], [`ROW_STEP`]: about 100 pixels), and `s = 1.4826 median` of
//!    them (a Gaussian error's standard deviation from its median magnitude). A mark, the arm
//!    or a highlight on fewer than half of the samples does not move a median, so the floor
//!    never rises because of the mark it must keep.
//! 2. The model's reference `s_ref` (blob, [`msr_shared::blob::Novelty::spread_ref`]): the
//!    spread its own statistics' frames show, measured when the statistics were made (0 for an
//!    imported model, whose frames are unknown: then the whole spread counts). A model without
//!    one keeps its statistics alone, as before.
//! 3. The floor `f = sqrt(max(0, s^2 - s_ref^2))`, rounded down to a quarter grey level
//!    ([`FLOOR_STEP`]): the standard deviation of an error, independent of the model's, that
//!    takes the spread from `s_ref` to `s`. A frame like the calibration's gets 0 and the
//!    model's statistics alone.
//! 4. Each pixel's sigma becomes `sqrt(sigma^2 + f^2)` ([`widen`]): independent errors add
//!    their variances, so a pixel the model predicts tightly gets most of the camera's error and
//!    a pixel it predicts loosely little more than it had.
//! 5. A frame whose floor would pass [`MAX_FLOOR`] is not the model's face through a camera
//!    (another robot's face spreads 45 to 75 grey levels against a model; the imperfections
//!    measured, a tone curve of 1.25 the worst, up to 21): its verdict is `NoFace` and it
//!    detects nothing, where widening would have made any face look quiet.
//!
//! Integers but the last step, which takes IEEE single-precision operations (a product, a sum,
//! a square root, each correctly rounded: `vsqrt.f32` on the board, the same result here), so
//! the host and the board agree bit for bit.

use msr_shared::blob::{MAX_FACE_H, MAX_FACE_W, MAX_POOL};

use crate::light::{self, Lut, MAX_SAMPLES};

/// Rule 1 takes every `ROW_STEP`-th row of the fit's sample grid: about 100 windows, which
/// a median needs no more of, at half the cost (a 5 x 5 window is 25 pixels to sum).
pub const ROW_STEP: usize = 2;

/// The floor's step, Q8.8 (a quarter grey level): frames of one camera, whose spreads differ a
/// little from frame to frame, mostly share a floor and so the threshold table made for it
/// ([`crate::saliency::Thresholds`] makes it again when the floor changes).
pub const FLOOR_STEP: u16 = 64;

/// The largest floor a frame may take, Q8.8: 32 grey levels (rule 5).
pub const MAX_FLOOR: u16 = 32 * 256;

/// `1.4826` in Q10: a Gaussian's standard deviation over its median magnitude.
const MAD_Q10: u64 = 1518;

/// Rule 1: the spread of a frame's pooled error, Q8.8 grey levels (0 for an empty face, a width
/// of 0 or past [`MAX_FACE_W`], or a radius past [`MAX_POOL`]). `frame` is grey, `pred` the
/// predicted face in Q8.8, `lut` the frame's fit ([`light::LightFit::lut`]); rows are the
/// shortest input over `w`. The error is [`light::error`] (censored where the camera clipped);
/// the mean over the window (clipped at the face's border) is truncated toward zero, as the
/// test's is. `pool` 0 takes each sample's own error.
pub fn spread(frame: &[u8], pred: &[u16], lut: &Lut, w: usize, pool: u8) -> u16 {
    if w == 0 || w > MAX_FACE_W || pool > MAX_POOL {
        return 0;
    }
    let h = (frame.len().min(pred.len()) / w).min(MAX_FACE_H);
    if h == 0 {
        return 0;
    }
    let (frame, pred) = (&frame[..h * w], &pred[..h * w]);
    let (sx, sy) = light::steps(w, h);
    let r = pool as usize;
    let mut v = [0u16; MAX_SAMPLES];
    let mut n = 0;
    for y in (sy / 2..h).step_by(ROW_STEP * sy) {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in (sx / 2..w).step_by(sx) {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let mut sum = 0i32;
            for row in y0..y1 {
                let (f, p) = (&frame[row * w + x0..row * w + x1], &pred[row * w + x0..row * w + x1]);
                sum += f.iter().zip(p).map(|(&f, &p)| light::error(lut, f, p)).sum::<i32>();
            }
            let k = ((y1 - y0) * (x1 - x0)) as i32;
            if let Some(slot) = v.get_mut(n) {
                *slot = (sum / k).unsigned_abs().min(u16::MAX as u32) as u16;
                n += 1;
            }
        }
    }
    let med = kth(&v[..n], n / 2) as u64;
    ((med * MAD_Q10 + 512) >> 10).min(u16::MAX as u64) as u16
}

/// Rule 2: the model's reference, Q8.8 grey levels (rounded; [`None`] for a model without
/// one, whose frames keep the statistics alone).
pub fn reference(model: &msr_shared::blob::Model) -> Option<u16> {
    model.novelty.spread_ref.map(reference_q88)
}

/// A reference in grey levels as the board holds it, Q8.8 (rounded, saturating).
pub fn reference_q88(spread_ref: f32) -> u16 {
    // `as` saturates, and NaN gives 0.
    (spread_ref * 256.0 + 0.5) as u16
}

/// Rule 3: the floor of a frame of spread `s` for a model whose reference is `s_ref`, Q8.8
/// grey levels: `sqrt(s^2 - s_ref^2)` rounded down to a [`FLOOR_STEP`], 0 where `s <= s_ref`.
pub fn floor(s: u16, s_ref: u16) -> u16 {
    if s <= s_ref {
        return 0;
    }
    let d = (s as u64 * s as u64 - s_ref as u64 * s_ref as u64).min(u32::MAX as u64) as u32;
    (light::isqrt(d).min(u16::MAX as u32) as u16) & !(FLOOR_STEP - 1)
}

/// Rule 4: `sigma` (Q8.8) widened by the floor `f` (Q8.8): `sqrt(sigma^2 + f^2)` rounded to
/// the nearest, saturating; `sigma` itself when `f` is 0.
#[inline]
pub fn widen(sigma: u16, f: u16) -> u16 {
    if f == 0 {
        return sigma;
    }
    widen_sq(sigma, f as f32 * f as f32)
}

/// [`widen`] with `f^2` (as `f as f32 * f as f32`) made once for a whole table.
#[inline]
pub fn widen_sq(sigma: u16, ff: f32) -> u16 {
    let s = sigma as f32;
    // `as` saturates: the rounding and the saturation in one conversion.
    (sqrt(s * s + ff) + 0.5) as u16
}

/// IEEE single-precision square root, correctly rounded.
#[inline]
fn sqrt(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        // SAFETY: the routine below reads s0 and writes s0, as the hard-float ABI passes and
        // returns an f32; it touches nothing else.
        unsafe { msr_sqrtf(x) }
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

// One `VSQRT.F32` (14 cycles on the M4F's FPU). Core has no `f32::sqrt` without std, and
// libm's is a software root of about a hundred instructions.
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
core::arch::global_asm!(
    ".section .text.msr_sqrtf,\"ax\",%progbits",
    ".global msr_sqrtf",
    ".type msr_sqrtf,%function",
    ".p2align 1",
    ".thumb_func",
    // The Cortex-M4F's FPU, which the hard-float target assumes (the assembler is not told).
    ".fpu fpv4-sp-d16",
    "msr_sqrtf:",
    "vsqrt.f32 s0, s0",
    "bx lr",
);

#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
extern "C" {
    fn msr_sqrtf(x: f32) -> f32;
}

/// The `k`-th smallest of `v` (0-based; 0 for an empty slice, the largest for `k` past the end):
/// two counting passes, one over each byte, so no sort and no allocation.
pub fn kth(v: &[u16], k: usize) -> u16 {
    if v.is_empty() {
        return 0;
    }
    let k = k.min(v.len() - 1);
    let mut count = [0u16; 256];
    for &x in v {
        count[(x >> 8) as usize] += 1;
    }
    let (hi, below) = bucket(&count, k);
    count = [0; 256];
    for &x in v.iter().filter(|&&x| (x >> 8) as usize == hi) {
        count[(x & 0xFF) as usize] += 1;
    }
    let (lo, _) = bucket(&count, k - below);
    ((hi << 8) | lo) as u16
}

/// The bucket that holds the `k`-th smallest, and how many lie in the buckets before it.
fn bucket(count: &[u16; 256], k: usize) -> (usize, usize) {
    let mut below = 0;
    for (b, &c) in count.iter().enumerate() {
        if below + c as usize > k {
            return (b, below);
        }
        below += c as usize;
    }
    (255, below)
}

#[cfg(test)]
mod tests;
