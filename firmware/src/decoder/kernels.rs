//! The layer loops. Generic over how weights are read (aligned i16 or i8 slices, or raw bytes),
//! so one portable definition serves every blob; the Cortex-M4 fast path lives in `arm`.
//!
//! Sums are wrapping i32 in any order: addition modulo 2^32 is associative, so the SMLAD path and
//! this one give the same bits.

use super::Requant;
use msr_shared::blob::{Layer, LayerKind, BLOCK};

pub(crate) trait Table {
    fn len(&self) -> usize;
    fn at(&self, i: usize) -> i32;
}

impl Table for &[i16] {
    #[inline(always)]
    fn len(&self) -> usize {
        <[i16]>::len(self)
    }
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self[i] as i32
    }
}

impl Table for &[i8] {
    #[inline(always)]
    fn len(&self) -> usize {
        <[i8]>::len(self)
    }
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self[i] as i32
    }
}

impl Table for &[i32] {
    #[inline(always)]
    fn len(&self) -> usize {
        <[i32]>::len(self)
    }
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self[i]
    }
}

/// i8 or i16 weights behind one type, for kernels that read weights only to pack them (one
/// instantiation for both).
#[derive(Clone, Copy)]
pub(crate) enum AnyWeights<'a> {
    I8(&'a [i8]),
    I16(&'a [i16]),
}

impl<'a> AnyWeights<'a> {
    /// The layer's aligned weight table, if it has one.
    pub(crate) fn of(l: &Layer<'a>) -> Option<Self> {
        match l.weights_i16() {
            Some(w) => Some(AnyWeights::I16(w)),
            None => l.weights_i8().map(AnyWeights::I8),
        }
    }
}

impl Table for AnyWeights<'_> {
    #[inline]
    fn len(&self) -> usize {
        match self {
            AnyWeights::I8(w) => w.len(),
            AnyWeights::I16(w) => w.len(),
        }
    }
    fn at(&self, i: usize) -> i32 {
        match self {
            AnyWeights::I8(w) => w[i] as i32,
            AnyWeights::I16(w) => w[i] as i32,
        }
    }
}

/// Any layer's weights: aligned slices or the byte accessors. The decoder calls the generic
/// loops with this type only (one instantiation each: code size).
#[derive(Clone, Copy)]
pub(crate) enum Weights<'l, 'a> {
    Slice(AnyWeights<'a>),
    Raw(&'l Layer<'a>),
}

impl Table for Weights<'_, '_> {
    fn len(&self) -> usize {
        match self {
            Weights::Slice(w) => w.len(),
            Weights::Raw(l) => l.weight_count(),
        }
    }
    #[inline]
    fn at(&self, i: usize) -> i32 {
        match self {
            Weights::Slice(w) => w.at(i),
            Weights::Raw(l) => l.weight(i),
        }
    }
}

/// Any layer's biases, as [`Weights`].
#[derive(Clone, Copy)]
pub(crate) enum Biases<'l, 'a> {
    Slice(&'a [i32]),
    Raw(&'l Layer<'a>),
}

impl Table for Biases<'_, '_> {
    fn len(&self) -> usize {
        match self {
            Biases::Slice(b) => b.len(),
            Biases::Raw(l) => l.bias_count(),
        }
    }
    #[inline]
    fn at(&self, i: usize) -> i32 {
        match self {
            Biases::Slice(b) => b[i],
            Biases::Raw(l) => l.bias(i),
        }
    }
}

pub(crate) fn layer<W: Table, B: Table>(
    l: &Layer,
    rq: Requant,
    w: &W,
    b: &B,
    x: &[i16],
    y: &mut [i16],
) -> Result<(), ()> {
    let k2 = l.kernel as usize * l.kernel as usize;
    let (want_w, want_b) = match l.kind {
        LayerKind::Dense => (l.input.len() * l.output.len(), l.output.len()),
        LayerKind::ConvTranspose2d | LayerKind::UpConv => (
            l.input.c as usize * l.output.c as usize * k2,
            l.output.c as usize,
        ),
        LayerKind::Crop => return Err(()),
    };
    if w.len() != want_w
        || b.len() != want_b
        || x.len() != l.input.len()
        || y.len() != l.output.len()
    {
        return Err(());
    }
    match l.kind {
        LayerKind::Dense => {
            dense(rq, w, b, x, y);
            Ok(())
        }
        LayerKind::ConvTranspose2d => conv_transpose(l, rq, w, b, x, y),
        LayerKind::UpConv => up_conv(l, rq, w, b, x, y),
        LayerKind::Crop => Err(()),
    }
}

/// `y[o] = rq(b[o] + sum_i w[o][i] x[i])`.
pub(crate) fn dense<W: Table, B: Table>(rq: Requant, w: &W, b: &B, x: &[i16], y: &mut [i16]) {
    let n_in = x.len();
    for (o, out) in y.iter_mut().enumerate() {
        let mut acc = b.at(o);
        let base = o * n_in;
        for (i, &xi) in x.iter().enumerate() {
            acc = acc.wrapping_add(w.at(base + i) * xi as i32);
        }
        *out = rq.apply(acc);
    }
}

/// A Dense in the blob's blocked order (`w` and `b` as stored: weights `[y][x][g][c][BLOCK]`,
/// biases `[y][x][c]`), written in the usual CHW order.
pub(crate) fn dense_blocked<W: Table, B: Table>(
    l: &Layer,
    rq: Requant,
    w: &W,
    b: &B,
    x: &[i16],
    y: &mut [i16],
) -> Result<(), ()> {
    let (n_in, c_n) = (x.len(), l.output.c as usize);
    let hw = l.output.h as usize * l.output.w as usize;
    if !n_in.is_multiple_of(BLOCK)
        || y.len() != c_n * hw
        || w.len() != n_in * y.len()
        || b.len() != y.len()
    {
        return Err(());
    }
    for (o, out) in y.iter_mut().enumerate() {
        let (c, px) = (o / hw, o % hw);
        let mut acc = b.at(px * c_n + c);
        for (g, xb) in x.chunks_exact(BLOCK).enumerate() {
            let at = (px * n_in + g * BLOCK) * c_n + c * BLOCK;
            for (r, &xi) in xb.iter().enumerate() {
                acc = acc.wrapping_add(w.at(at + r) * xi as i32);
            }
        }
        *out = rq.apply(acc);
    }
    Ok(())
}

/// Valid (kernel tap, input index) pairs of one output coordinate, at most `MAX_K` of them.
pub(crate) const MAX_K: usize = 32;

pub(crate) struct Taps {
    pub(crate) n: usize,
    pub(crate) k: [u8; MAX_K],
    pub(crate) i: [u16; MAX_K],
}

impl Taps {
    /// ConvTranspose2d: output `o` takes input `i` through tap `t` when `o + p - t = i * s`.
    pub(crate) fn transpose(o: usize, k: usize, s: usize, p: usize, n_in: usize) -> Taps {
        let mut taps = Taps {
            n: 0,
            k: [0; MAX_K],
            i: [0; MAX_K],
        };
        for t in 0..k.min(MAX_K) {
            let Some(v) = (o + p).checked_sub(t) else {
                continue;
            };
            if v % s != 0 || v / s >= n_in {
                continue;
            }
            taps.k[taps.n] = t as u8;
            taps.i[taps.n] = (v / s) as u16;
            taps.n += 1;
        }
        taps
    }

    /// UpConv: output `o` reads upsampled position `o + t - p`, i.e. input `(o + t - p) / s`.
    fn upsampled(o: usize, k: usize, s: usize, p: usize, n_in: usize) -> Taps {
        let mut taps = Taps {
            n: 0,
            k: [0; MAX_K],
            i: [0; MAX_K],
        };
        for t in 0..k.min(MAX_K) {
            let Some(u) = (o + t).checked_sub(p) else {
                continue;
            };
            if u >= n_in * s {
                continue;
            }
            taps.k[taps.n] = t as u8;
            taps.i[taps.n] = (u / s) as u16;
            taps.n += 1;
        }
        taps
    }
}

fn conv_transpose<W: Table, B: Table>(
    l: &Layer,
    rq: Requant,
    w: &W,
    b: &B,
    x: &[i16],
    y: &mut [i16],
) -> Result<(), ()> {
    let (ic_n, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (oc_n, oh, ow) = (
        l.output.c as usize,
        l.output.h as usize,
        l.output.w as usize,
    );
    let (k, s, p) = (l.kernel as usize, l.stride as usize, l.padding as usize);
    if k > MAX_K || s == 0 {
        return Err(());
    }
    // Weights [ic][oc][ky][kx]: the next input channel is oc_n * k * k further on.
    let w_step = oc_n * k * k;
    let x_step = ih * iw;
    for oc in 0..oc_n {
        let bias = b.at(oc);
        for oy in 0..oh {
            let ty = Taps::transpose(oy, k, s, p, ih);
            for ox in 0..ow {
                let tx = Taps::transpose(ox, k, s, p, iw);
                let mut acc = bias;
                for a in 0..ty.n {
                    for c in 0..tx.n {
                        let mut wi = (oc * k + ty.k[a] as usize) * k + tx.k[c] as usize;
                        let mut xi = ty.i[a] as usize * iw + tx.i[c] as usize;
                        for _ in 0..ic_n {
                            acc = acc.wrapping_add(w.at(wi) * x[xi] as i32);
                            wi += w_step;
                            xi += x_step;
                        }
                    }
                }
                y[(oc * oh + oy) * ow + ox] = rq.apply(acc);
            }
        }
    }
    Ok(())
}

fn up_conv<W: Table, B: Table>(
    l: &Layer,
    rq: Requant,
    w: &W,
    b: &B,
    x: &[i16],
    y: &mut [i16],
) -> Result<(), ()> {
    let (ic_n, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (oc_n, oh, ow) = (
        l.output.c as usize,
        l.output.h as usize,
        l.output.w as usize,
    );
    let (k, s, p) = (l.kernel as usize, l.stride as usize, l.padding as usize);
    if k > MAX_K || s == 0 {
        return Err(());
    }
    // Weights [oc][ic][ky][kx]: the next input channel is k * k further on.
    let w_step = k * k;
    let x_step = ih * iw;
    for oc in 0..oc_n {
        let bias = b.at(oc);
        for oy in 0..oh {
            let ty = Taps::upsampled(oy, k, s, p, ih);
            for ox in 0..ow {
                let tx = Taps::upsampled(ox, k, s, p, iw);
                let mut acc = bias;
                for a in 0..ty.n {
                    for c in 0..tx.n {
                        let mut wi = ((oc * ic_n) * k + ty.k[a] as usize) * k + tx.k[c] as usize;
                        let mut xi = ty.i[a] as usize * iw + tx.i[c] as usize;
                        for _ in 0..ic_n {
                            acc = acc.wrapping_add(w.at(wi) * x[xi] as i32);
                            wi += w_step;
                            xi += x_step;
                        }
                    }
                }
                y[(oc * oh + oy) * ow + ox] = rq.apply(acc);
            }
        }
    }
    Ok(())
}
