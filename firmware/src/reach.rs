//! The reach network: mark centroid in full-frame pixels -> the five reach joint angles.
//!
//! 2-10-5 in f32, sigmoid on both layers, min-max scaling on both sides, as published:
//! `u = (v - in_min) / (in_max - in_min)`, `h = sig(W1 u + b1)`, `o = sig(W2 h + b2)`,
//! `angle = o * (out_max - out_min) + out_min`, in [`REACH_JOINTS`] order. `expf` is `libm`'s,
//! so host and board compute the same bits. The result is clamped to the joint limits before
//! anything uses it.

use msr_shared::blob::{Reach, REACH_OUT};
use msr_shared::joints::REACH_JOINTS;

#[inline]
fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + libm::expf(-x))
}

/// The network's raw output for a centroid `[x, y]` (full-frame pixels); `None` if the input
/// or the output is not finite.
pub fn infer(net: &Reach, centroid: [f32; 2]) -> Option<[f32; REACH_OUT]> {
    if !centroid.iter().all(|v| v.is_finite()) {
        return None;
    }
    let mut u = [0f32; 2];
    for i in 0..2 {
        u[i] = (centroid[i] - net.in_min[i]) / (net.in_max[i] - net.in_min[i]);
    }
    let mut h = [0f32; 10];
    for (j, hj) in h.iter_mut().enumerate() {
        let mut a = net.b1[j];
        for i in 0..2 {
            a += net.w1[j][i] * u[i];
        }
        *hj = sigmoid(a);
    }
    let mut out = [0f32; REACH_OUT];
    for (k, o) in out.iter_mut().enumerate() {
        let mut a = net.b2[k];
        for (j, hj) in h.iter().enumerate() {
            a += net.w2[k][j] * hj;
        }
        *o = sigmoid(a) * (net.out_max[k] - net.out_min[k]) + net.out_min[k];
    }
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
