//! Fast paths: multiply-accumulates in pairs (SMLAD on the Cortex-M4).
//!
//! - Dense (i16 weights): a weight row and the input are read as words of two i16; four outputs
//!   share each input word. On the M4 rows of a multiple of four words go to the assembly
//!   (`super::arm`), in pairs when the activation has a table step, else one at a time.
//! - ConvTranspose2d: split by output phase (`ox mod stride`), each output of a phase reads a
//!   fixed set of taps; two horizontally adjacent taps read two adjacent input pixels, i.e. one
//!   word, so a tap pair is one SMLAD with a pre-packed weight pair. Four outputs of a phase
//!   share each weight pair (packed from i8 or i16 weights). Border outputs, whose taps fall
//!   outside the input, take the generic path.
//!
//! [`smlad`] (in `super::arm`) is the instruction on ARM and the same wrapping sum elsewhere:
//! bit-identical.

use super::arm::smlad;
use super::kernels::{Table, Taps, MAX_K};
use super::Activate;
use msr_shared::blob::Layer;

/// `acc + sum_i smlad(w[i], x[i])` over 4-word groups with LDM (Cortex-M4): 8 MACs in 8
/// instructions. `x` and `w` are word-aligned slices of equal length, a multiple of 4.
#[cfg(target_arch = "arm")]
#[inline(always)]
fn dot_ldm(w: &[u32], x: &[u32], acc: i32) -> i32 {
    let n = w.len().min(x.len()) / 4;
    if n == 0 {
        return acc;
    }
    let mut acc = acc;
    if n.is_multiple_of(2) {
        // Two groups per turn of the loop: 16 MACs in 14 instructions.
        // SAFETY: reads n * 4 words from each slice (inside them), writes only the named registers.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldm {xp}!, {{r2, r3, r4, r5}}",
                "ldm {wp}!, {{r8, r10, r12, lr}}",
                "smlad {acc}, r2, r8, {acc}",
                "smlad {acc}, r3, r10, {acc}",
                "smlad {acc}, r4, r12, {acc}",
                "smlad {acc}, r5, lr, {acc}",
                "ldm {xp}!, {{r2, r3, r4, r5}}",
                "ldm {wp}!, {{r8, r10, r12, lr}}",
                "smlad {acc}, r2, r8, {acc}",
                "smlad {acc}, r3, r10, {acc}",
                "smlad {acc}, r4, r12, {acc}",
                "smlad {acc}, r5, lr, {acc}",
                "subs {n}, {n}, #1",
                "bne 2b",
                acc = inout(reg) acc,
                xp = inout(reg) x.as_ptr() => _,
                wp = inout(reg) w.as_ptr() => _,
                n = inout(reg) n / 2 => _,
                out("r2") _, out("r3") _, out("r4") _, out("r5") _,
                out("r8") _, out("r10") _, out("r12") _, out("lr") _,
                options(nostack, readonly),
            );
        }
        return acc;
    }
    // SAFETY: reads n * 4 words from each slice (inside them), writes only the named registers.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldm {xp}!, {{r2, r3, r4, r5}}",
            "ldm {wp}!, {{r8, r10, r12, lr}}",
            "smlad {acc}, r2, r8, {acc}",
            "smlad {acc}, r3, r10, {acc}",
            "smlad {acc}, r4, r12, {acc}",
            "smlad {acc}, r5, lr, {acc}",
            "subs {n}, {n}, #1",
            "bne 2b",
            acc = inout(reg) acc,
            xp = inout(reg) x.as_ptr() => _,
            wp = inout(reg) w.as_ptr() => _,
            n = inout(reg) n => _,
            out("r2") _, out("r3") _, out("r4") _, out("r5") _,
            out("r8") _, out("r10") _, out("r12") _, out("lr") _,
            options(nostack, readonly),
        );
    }
    acc
}

/// Dense with `w` as `[out][in/2]` words and `x` as `in/2` words.
pub(crate) fn dense_pairs<A: Activate>(rq: A, w: &[u32], b: &[i32], x: &[u32], y: &mut [i16]) {
    let np = x.len();
    if np == 0 || w.len() != np * y.len() || b.len() != y.len() {
        return;
    }
    // On the M4, rows of a multiple of 4 words go through LDM + SMLAD: in pairs with the
    // activation in assembly where it has one, else one row at a time.
    #[cfg(target_arch = "arm")]
    if np.is_multiple_of(4) {
        let done = super::arm::dense2(rq, w, b, x, y);
        let rows = w[done * np..].chunks_exact(np);
        for ((row, out), &bias) in rows.zip(y[done..].iter_mut()).zip(&b[done..]) {
            *out = rq.act(dot_ldm(row, x, bias));
        }
        return;
    }
    let mut rows = w.chunks_exact(np);
    let mut o = 0;
    while o + 4 <= y.len() {
        let (Some(r0), Some(r1), Some(r2), Some(r3)) =
            (rows.next(), rows.next(), rows.next(), rows.next())
        else {
            return;
        };
        let (mut a0, mut a1, mut a2, mut a3) = (b[o], b[o + 1], b[o + 2], b[o + 3]);
        for ((((&xi, &w0), &w1), &w2), &w3) in x.iter().zip(r0).zip(r1).zip(r2).zip(r3) {
            a0 = smlad(w0, xi, a0);
            a1 = smlad(w1, xi, a1);
            a2 = smlad(w2, xi, a2);
            a3 = smlad(w3, xi, a3);
        }
        y[o] = rq.act(a0);
        y[o + 1] = rq.act(a1);
        y[o + 2] = rq.act(a2);
        y[o + 3] = rq.act(a3);
        o += 4;
    }
    for (row, (out, &bias)) in rows.zip(y[o..].iter_mut().zip(&b[o..])) {
        let mut a = bias;
        for (&wi, &xi) in row.iter().zip(x) {
            a = smlad(wi, xi, a);
        }
        *out = rq.act(a);
    }
}

/// Packed weight pairs of one output channel and phase: at most this many words on the stack.
const MAX_PACKED: usize = 256;
/// Terms (weight pair, input offset) of one output row of one phase.
const MAX_TERMS: usize = 128;

/// Two adjacent i16 from `p` as one word (low half first). Unaligned loads are fine on v7E-M.
///
/// # Safety
/// `p` and `p + 1` must be inside one slice.
#[inline(always)]
unsafe fn rd(p: *const i16) -> u32 {
    core::ptr::read_unaligned(p as *const u32)
}

/// ConvTranspose2d by output phase with paired taps. Returns false (nothing written) when the
/// layer does not suit it, and the caller takes the generic path. Not inlined: its 2.5 KB of
/// tables would add to the caller's frame (stack peak).
#[inline(never)]
pub(crate) fn conv_transpose<W: Table, B: Table, A: Activate>(
    l: &Layer,
    rq: A,
    w: &W,
    b: &B,
    x: &[i16],
    y: &mut [i16],
) -> bool {
    let (ic_n, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (oc_n, oh, ow) = (
        l.output.c as usize,
        l.output.h as usize,
        l.output.w as usize,
    );
    let (k, s, p) = (l.kernel as usize, l.stride as usize, l.padding as usize);
    if k > MAX_K || s == 0 || k < 2 || x.len() != ic_n * ih * iw || y.len() != oc_n * oh * ow {
        return false;
    }
    // Taps per phase: at most ceil(k / s), in pairs (an odd one pairs with a zero weight).
    let np_max = k.div_ceil(s).div_ceil(2);
    let ty_max = k.div_ceil(s);
    if ic_n * k * np_max > MAX_PACKED
        || ic_n * ty_max * np_max > MAX_TERMS
        || w.len() != ic_n * oc_n * k * k
        || b.len() != oc_n
    {
        return false;
    }
    let mut packed = [0u32; MAX_PACKED];
    let mut wt = [0u32; MAX_TERMS];
    let mut offs = [0i32; MAX_TERMS];
    let mut rows = [0i32; MAX_TERMS];
    for oc in 0..oc_n {
        let bias = b.at(oc);
        for px in 0..s.min(ow) {
            // Output ox = s*m + px takes taps kx = kx0 + j*s at input ix = m + c0 - j.
            let kx0 = (px + p) % s;
            let c0 = (px + p) / s;
            let nt = if kx0 < k { (k - kx0).div_ceil(s) } else { 0 };
            let np = nt.div_ceil(2);
            // Pair q: (lo: tap 2q+1 at ix-1, hi: tap 2q at ix); an odd last tap has lo = 0.
            for ic in 0..ic_n {
                for ky in 0..k {
                    let wrow = ((ic * oc_n + oc) * k + ky) * k;
                    for q in 0..np {
                        let hi = w.at(wrow + kx0 + 2 * q * s) as u16 as u32;
                        let lo = if 2 * q + 1 < nt {
                            w.at(wrow + kx0 + (2 * q + 1) * s) as u16 as u32
                        } else {
                            0
                        };
                        packed[(ic * k + ky) * np_max + q] = lo | (hi << 16);
                    }
                }
            }
            // Outputs of this phase: m in 0..m_n; interior when every pair read is inside the
            // row: lowest read m + c0 - 2*np + 1 >= 0, highest m + c0 < iw.
            let m_n = (ow - px).div_ceil(s);
            let m_lo = (2 * np).saturating_sub(1).saturating_sub(c0).min(m_n);
            let m_hi = iw.saturating_sub(c0).min(m_n).max(m_lo);
            // Rows by phase: consecutive rows of one phase use the same taps one input row
            // further down, so their terms only shift (rebuilt when the taps change).
            let mut n = 0;
            let mut prev: Option<(usize, u8, u16)> = None;
            for oy in (0..s).flat_map(|py| (py..oh).step_by(s)) {
                let ty = Taps::transpose(oy, k, s, p, ih);
                let out_row = (oc * oh + oy) * ow;
                // Same count and same first tap: the same contiguous run of taps.
                let same = prev.filter(|&(pn, pk, _)| pn == ty.n && pk == ty.k[0] && ty.n > 0);
                prev = Some((ty.n, ty.k[0], ty.i[0]));
                if let Some((_, _, pi)) = same {
                    let d = (ty.i[0] as i32 - pi as i32) * iw as i32;
                    for t in 0..n {
                        offs[t] += d;
                        rows[t] += d;
                    }
                } else {
                    // This row's terms: weight pair and where its input pair starts (minus m).
                    n = 0;
                    for ic in 0..ic_n {
                        for a in 0..ty.n {
                            let ky = ty.k[a] as usize;
                            let row = ((ic * ih + ty.i[a] as usize) * iw) as i32;
                            for q in 0..np {
                                wt[n] = packed[(ic * k + ky) * np_max + q];
                                offs[n] = row + c0 as i32 - 2 * q as i32 - 1;
                                rows[n] = row;
                                n += 1;
                            }
                        }
                    }
                }
                // Border outputs: the same terms, reading zero outside the row.
                let edge = |m: usize, y: &mut [i16]| {
                    let mut acc = bias;
                    for t in 0..n {
                        let col = (offs[t] - rows[t]) as isize + m as isize;
                        let at = |c: isize| -> u32 {
                            if c >= 0 && (c as usize) < iw {
                                x[(rows[t] as isize + c) as usize] as u16 as u32
                            } else {
                                0
                            }
                        };
                        acc = smlad(wt[t], at(col) | (at(col + 1) << 16), acc);
                    }
                    y[out_row + s * m + px] = rq.act(acc);
                };
                for m in (0..m_lo).chain(m_hi..m_n) {
                    edge(m, y);
                }
                let terms = wt[..n].iter().zip(&offs[..n]);
                let xp = x.as_ptr();
                // Blocks of four; a last partial block is redone as the four ending at m_hi
                // (the overlap is written twice with the same values).
                let mut m = m_lo;
                let mut last = false;
                while m + 4 <= m_hi || (!last && m < m_hi && m_hi >= m_lo + 4) {
                    if m + 4 > m_hi {
                        m = m_hi - 4;
                        last = true;
                    }
                    let (mut a0, mut a1, mut a2, mut a3) = (bias, bias, bias, bias);
                    for (&wv, &off) in terms.clone() {
                        // SAFETY: m_lo <= m and m + 3 < m_hi keep every pair read, from
                        // off + m to off + m + 4, inside row `row` of `x` (see m_lo, m_hi).
                        unsafe {
                            let q = xp.offset(off as isize + m as isize);
                            a0 = smlad(wv, rd(q), a0);
                            a1 = smlad(wv, rd(q.add(1)), a1);
                            a2 = smlad(wv, rd(q.add(2)), a2);
                            a3 = smlad(wv, rd(q.add(3)), a3);
                        }
                    }
                    let o = out_row + s * m + px;
                    y[o] = rq.act(a0);
                    y[o + s] = rq.act(a1);
                    y[o + 2 * s] = rq.act(a2);
                    y[o + 3 * s] = rq.act(a3);
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
