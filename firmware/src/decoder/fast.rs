//! Fast paths for i16 weights: multiply-accumulates in pairs (SMLAD on the Cortex-M4).
//!
//! - Dense: a weight row and the input are read as words of two i16; four outputs share each
//!   input word.
//! - ConvTranspose2d: split by output phase (`ox mod stride`), each output of a phase reads a
//!   fixed set of taps; two horizontally adjacent taps read two adjacent input pixels, i.e. one
//!   word, so a tap pair is one SMLAD with a pre-packed weight pair. Four outputs of a phase
//!   share each weight pair. Border outputs, whose taps fall outside the input, take the
//!   generic path.
//!
//! [`smlad`] is the instruction on ARM and the same wrapping sum elsewhere: bit-identical.

use super::kernels::{Table, Taps, MAX_K};
use super::Requant;
use msr_shared::blob::Layer;

/// `acc + a.lo * b.lo + a.hi * b.hi` (signed halves), wrapping.
#[inline(always)]
pub(crate) fn smlad(a: u32, b: u32, acc: i32) -> i32 {
    #[cfg(target_arch = "arm")]
    {
        let r: i32;
        // SAFETY: SMLAD only reads its three registers and writes one (ARMv7E-M DSP).
        unsafe {
            core::arch::asm!("smlad {r}, {a}, {b}, {c}", r = lateout(reg) r, a = in(reg) a, b = in(reg) b,
                c = in(reg) acc, options(pure, nomem, nostack));
        }
        r
    }
    #[cfg(not(target_arch = "arm"))]
    {
        let lo = (a as u16 as i16 as i32) * (b as u16 as i16 as i32);
        let hi = ((a >> 16) as u16 as i16 as i32) * ((b >> 16) as u16 as i16 as i32);
        acc.wrapping_add(lo).wrapping_add(hi)
    }
}

/// Dense with `w` as `[out][in/2]` words and `x` as `in/2` words.
pub(crate) fn dense_pairs(rq: Requant, w: &[u32], b: &[i32], x: &[u32], y: &mut [i16]) {
    let np = x.len();
    if np == 0 || w.len() != np * y.len() || b.len() != y.len() {
        return;
    }
    let mut rows = w.chunks_exact(np);
    let mut o = 0;
    while o + 4 <= y.len() {
        let (Some(r0), Some(r1), Some(r2), Some(r3)) = (rows.next(), rows.next(), rows.next(), rows.next()) else {
            return;
        };
        let (mut a0, mut a1, mut a2, mut a3) = (b[o], b[o + 1], b[o + 2], b[o + 3]);
        for ((((&xi, &w0), &w1), &w2), &w3) in x.iter().zip(r0).zip(r1).zip(r2).zip(r3) {
            a0 = smlad(w0, xi, a0);
            a1 = smlad(w1, xi, a1);
            a2 = smlad(w2, xi, a2);
            a3 = smlad(w3, xi, a3);
        }
        y[o] = rq.apply(a0);
        y[o + 1] = rq.apply(a1);
        y[o + 2] = rq.apply(a2);
        y[o + 3] = rq.apply(a3);
        o += 4;
    }
    for (row, (out, &bias)) in rows.zip(y[o..].iter_mut().zip(&b[o..])) {
        let mut a = bias;
        for (&wi, &xi) in row.iter().zip(x) {
            a = smlad(wi, xi, a);
        }
        *out = rq.apply(a);
    }
}

/// Packed weight pairs of one output channel and phase: at most this many words on the stack.
const MAX_PACKED: usize = 512;

/// Two adjacent i16 of `row` from index `i` as one word (low half first).
#[inline(always)]
fn pair(row: &[i16], i: usize) -> u32 {
    (row[i] as u16 as u32) | ((row[i + 1] as u16 as u32) << 16)
}

/// ConvTranspose2d by output phase with paired taps. Returns false (nothing written) when the
/// layer does not suit it, and the caller takes the generic path.
pub(crate) fn conv_transpose<W: Table, B: Table>(
    l: &Layer,
    rq: Requant,
    w: &W,
    b: &B,
    x: &[i16],
    y: &mut [i16],
) -> bool {
    let (ic_n, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (oc_n, oh, ow) = (l.output.c as usize, l.output.h as usize, l.output.w as usize);
    let (k, s, p) = (l.kernel as usize, l.stride as usize, l.padding as usize);
    if k > MAX_K || s == 0 || k < 2 || x.len() != ic_n * ih * iw || y.len() != oc_n * oh * ow {
        return false;
    }
    // Taps per phase: at most ceil(k / s); pairs of them.
    let nt_max = k.div_ceil(s);
    let np_max = nt_max.div_ceil(2);
    if ic_n * k * np_max > MAX_PACKED || w.len() != ic_n * oc_n * k * k || b.len() != oc_n {
        return false;
    }
    let mut packed = [0u32; MAX_PACKED];
    let mut single = [0i16; MAX_PACKED];
    for oc in 0..oc_n {
        let bias = b.at(oc);
        for px in 0..s.min(ow) {
            // Output ox = s*m + px takes taps kx = kx0 + j*s at input ix = m + c0 - j.
            let kx0 = (px + p) % s;
            let c0 = (px + p) / s;
            let nt = if kx0 < k { (k - kx0).div_ceil(s) } else { 0 };
            let np = nt / 2;
            // Pack (lo: tap j+1 at ix-1, hi: tap j at ix) for every input channel and ky.
            for ic in 0..ic_n {
                for ky in 0..k {
                    let wrow = ((ic * oc_n + oc) * k + ky) * k;
                    for q in 0..np {
                        let hi = w.at(wrow + kx0 + 2 * q * s) as u16 as u32;
                        let lo = w.at(wrow + kx0 + (2 * q + 1) * s) as u16 as u32;
                        packed[(ic * k + ky) * np_max + q] = lo | (hi << 16);
                    }
                    if nt % 2 == 1 {
                        single[ic * k + ky] = w.at(wrow + kx0 + (nt - 1) * s) as i16;
                    }
                }
            }
            // Outputs of this phase: m in 0..m_n; interior when every ix is inside the input.
            let m_n = (ow - px).div_ceil(s);
            let m_lo = (nt.saturating_sub(1)).saturating_sub(c0).min(m_n);
            let m_hi = iw.saturating_sub(c0).min(m_n).max(m_lo);
            for oy in 0..oh {
                let ty = Taps::transpose(oy, k, s, p, ih);
                let out_row = (oc * oh + oy) * ow;
                let edge = |m: usize, y: &mut [i16]| {
                    let ox = s * m + px;
                    let tx = Taps::transpose(ox, k, s, p, iw);
                    let mut acc = bias;
                    for a in 0..ty.n {
                        for c in 0..tx.n {
                            let mut wi = (oc * k + ty.k[a] as usize) * k + tx.k[c] as usize;
                            let mut xi = ty.i[a] as usize * iw + tx.i[c] as usize;
                            for _ in 0..ic_n {
                                acc = acc.wrapping_add(w.at(wi) * x[xi] as i32);
                                wi += oc_n * k * k;
                                xi += ih * iw;
                            }
                        }
                    }
                    y[out_row + ox] = rq.apply(acc);
                };
                for m in (0..m_lo).chain(m_hi..m_n) {
                    edge(m, y);
                }
                let mut m = m_lo;
                while m + 4 <= m_hi {
                    let mut acc = [bias; 4];
                    for ic in 0..ic_n {
                        for a in 0..ty.n {
                            let ky = ty.k[a] as usize;
                            let row = &x[(ic * ih + ty.i[a] as usize) * iw..][..iw];
                            let wp = &packed[(ic * k + ky) * np_max..][..np];
                            for (q, &wv) in wp.iter().enumerate() {
                                // Taps 2q+1 and 2q read ix - 1 and ix, ix = m + c0 - 2q.
                                let base = m + c0 - 2 * q - 1;
                                acc[0] = smlad(wv, pair(row, base), acc[0]);
                                acc[1] = smlad(wv, pair(row, base + 1), acc[1]);
                                acc[2] = smlad(wv, pair(row, base + 2), acc[2]);
                                acc[3] = smlad(wv, pair(row, base + 3), acc[3]);
                            }
                            if nt % 2 == 1 {
                                let ws = single[ic * k + ky] as i32;
                                let base = m + c0 - (nt - 1);
                                for (t, a) in acc.iter_mut().enumerate() {
                                    *a = a.wrapping_add(ws * row[base + t] as i32);
                                }
                            }
                        }
                    }
                    for (t, &a) in acc.iter().enumerate() {
                        y[out_row + s * (m + t) + px] = rq.apply(a);
                    }
                    m += 4;
                }
                while m < m_hi {
                    edge(m, y);
                    m += 1;
                }
            }
        }
    }
    true
}
