//! The reach network: mark centroid in full-frame pixels -> the five reach joint angles.
//!
//! 2-10-5 in f32, sigmoid on both layers, min-max scaling on both sides, as published:
//! `u = (v - in_min) / (in_max - in_min)`, `h = sig(W1 u + b1)`, `o = sig(W2 h + b2)`,
//! `angle = o * (out_max - out_min) + out_min`, in [`REACH_JOINTS`] order. `e^x` is `exp` below:
//! f32 arithmetic only, so host and board compute the same bits. The result is clamped to the
//! joint limits before anything uses it.

use msr_shared::blob::{Reach, REACH_OUT};
use msr_shared::joints::REACH_JOINTS;

#[inline]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// `e^x` within 2 ulp: `x = n ln 2 + r` with `|r| <= ln 2 / 2` (`n` rounded by the 1.5 2^23
/// trick, `ln 2` in two parts so that `n ln 2` is exact), Cephes' degree-6 polynomial for `e^r`,
/// `2^n` put into the exponent. On the Cortex-M4F 30 instructions fewer than `libm::expf`
/// (its special cases and `scalbnf`), and the reach takes 15 a frame. Below -87 it gives 0 and
/// above 88 infinity (the sigmoid is then 1 or 0 to f32 precision either way); NaN stays NaN.
fn exp(x: f32) -> f32 {
    const ROUND: f32 = 12_582_912.0;
    // NaN passes both tests and comes out NaN.
    if x < -87.0 {
        return 0.0;
    }
    if x > 88.0 {
        return f32::INFINITY;
    }
    let t = x * core::f32::consts::LOG2_E + ROUND;
    let n = t.to_bits() as i32 - ROUND.to_bits() as i32;
    let nf = t - ROUND;
    let r = x - nf * 0.693_359_4 - nf * -2.121_944_4e-4;
    let p = ((((1.987_569_2e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    (p * (r * r) + r + 1.0) * f32::from_bits(((n + 127) as u32) << 23)
}

/// The network's raw output for a centroid `[x, y]` (full-frame pixels); `None` if the input
/// or the output is not finite.
pub fn infer(net: &Reach, centroid: [f32; 2]) -> Option<[f32; REACH_OUT]> {
    if !centroid.iter().all(|v| v.is_finite()) {
        return None;
    }
    let u: [f32; 2] =
        core::array::from_fn(|i| (centroid[i] - net.in_min[i]) / (net.in_max[i] - net.in_min[i]));
    // The sums written out term by term, in the order of a loop: the board's code is built for
    // size, which keeps loops rolled (and the reach runs every frame with a blob).
    let h: [f32; 10] = core::array::from_fn(|j| {
        let w = &net.w1[j];
        sigmoid(net.b1[j] + w[0] * u[0] + w[1] * u[1])
    });
    let out: [f32; REACH_OUT] = core::array::from_fn(|k| {
        let w = &net.w2[k];
        let a = net.b2[k]
            + w[0] * h[0]
            + w[1] * h[1]
            + w[2] * h[2]
            + w[3] * h[3]
            + w[4] * h[4]
            + w[5] * h[5]
            + w[6] * h[6]
            + w[7] * h[7]
            + w[8] * h[8]
            + w[9] * h[9];
        sigmoid(a) * (net.out_max[k] - net.out_min[k]) + net.out_min[k]
    });
    out.iter().all(|v| v.is_finite()).then_some(out)
}

/// Clamps each angle into its joint's limits; returns the angles and how many were moved.
/// `None` for NaN (never invent a position).
pub fn clamp(angles: [f32; REACH_OUT]) -> Option<([f32; REACH_OUT], u32)> {
    let mut out = angles;
    let mut moved = 0;
    for (a, j) in out.iter_mut().zip(REACH_JOINTS) {
        let c = j.clamp(*a).ok()?;
        if c != *a {
            moved += 1;
        }
        *a = c;
    }
    Some((out, moved))
}

/// [`infer`] then [`clamp`].
pub fn targets(net: &Reach, centroid: [f32; 2]) -> Option<([f32; REACH_OUT], u32)> {
    clamp(infer(net, centroid)?)
}

#[cfg(test)]
mod tests {
    use super::exp;

    /// Within 2 ulp of e^x on every 97th float of the range it computes, its ends and the edge
    /// of the reduction (`ln 2 / 2`) included; 0, infinity and NaN past them.
    #[test]
    fn exp_is_within_two_ulp() {
        let mut worst = 0f64;
        let (lo, hi) = ((-87.0f32).to_bits(), 88.0f32.to_bits());
        // Every 97th f32 of [-87, 0) and [0, 88].
        let negatives = (0x8000_0000u32..=lo).step_by(97).map(f32::from_bits);
        let positives = (0u32..=hi).step_by(97).map(f32::from_bits);
        for x in negatives
            .chain(positives)
            .chain([-87.0, 88.0, 0.5 * core::f32::consts::LN_2])
        {
            let want = (x as f64).exp();
            let err = ((exp(x) as f64 - want) / want).abs() / f32::EPSILON as f64;
            worst = worst.max(err);
            assert!(err < 2.0, "exp({x}) = {} vs {want}: {err} ulp", exp(x));
        }
        assert!(worst > 0.1, "the test measured nothing: {worst}");
        assert_eq!(exp(-87.01), 0.0);
        assert_eq!(exp(-1e30), 0.0);
        assert_eq!(exp(88.01), f32::INFINITY);
        assert!(exp(f32::NAN).is_nan());
    }
}
