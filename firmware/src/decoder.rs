//! Fixed-point decoder: the head angles the servos report -> the predicted face.
//!
//! Semantics are those of `msr_shared::blob`: every layer takes i16 activations with `in_shift`
//! fraction bits, multiplies by weights with `w_shift` bits into a wrapping i32 accumulator that
//! starts at the bias, and writes `sat_i16(round(act(acc * 2^-(w_shift+in_shift)) * 2^out_shift))`.
//!
//! - Rounding is half-up everywhere (`floor(x + 0.5)`), the accumulator wraps on overflow (the
//!   quantizer chooses shifts so that it does not), results saturate to i16.
//! - tanh and sigmoid come from one table (`tanh_table.rs`): tanh on [0, 8] in steps of 1/128 with
//!   linear interpolation (error below 2.5e-5, under one Q15 step); `sigmoid(x) = (1 + tanh(x/2)) / 2`.
//! - i16 weights take paired paths (`fast.rs`: Dense rows and ConvTranspose2d phases) whose
//!   multiply-accumulates are SMLAD on `target_arch = "arm"` (v7E-M DSP) and the same wrapping
//!   sums elsewhere, so host and board agree bit for bit; other layers use generic loops.
//!
//! The predicted face is kept, converted to Q8.8 grey levels, until the quantised head pose or
//! the model changes ([`Decoder::predict`]); [`Decoder::predict_uncached`] always runs it.

use msr_shared::blob::{Activation, Layer, LayerKind, Model, WeightType, MAX_ACTIVATION_LEN};

mod fast;
mod kernels;
mod tanh_table;

use tanh_table::TANH_Q24;

/// Why the decoder did not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// A head angle is NaN or infinite.
    BadInput,
    /// A layer does not fit the buffers or its tables (cannot happen after `Model::parse`).
    Shape(u8),
    /// A layer's `in_shift` differs from the previous layer's `out_shift`.
    Scale(u8),
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DecodeError::BadInput => f.write_str("head angles must be finite"),
            DecodeError::Shape(i) => write!(f, "decoder layer {i} does not fit the buffers"),
            DecodeError::Scale(i) => {
                write!(
                    f,
                    "decoder layer {i}: in_shift differs from the previous out_shift"
                )
            }
        }
    }
}

/// Checks what `Model::parse` does not: that each layer reads the scale the previous one wrote.
pub fn check_scales(model: &Model) -> Result<(), DecodeError> {
    for (i, pair) in model.layers.windows(2).enumerate() {
        if pair[1].in_shift != pair[0].out_shift {
            return Err(DecodeError::Scale(i as u8 + 1));
        }
    }
    Ok(())
}

/// One activation buffer, 4-byte aligned so that i16 pairs load as words (SMLAD operands).
#[repr(C, align(4))]
struct Act([i16; MAX_ACTIVATION_LEN]);

/// The decoder's two activation buffers and its cached prediction.
pub struct Decoder {
    act: [Act; 2],
    /// Which buffer holds the face (as Q8.8 grey, u16 bit patterns), and how many pixels.
    face: Option<(usize, usize)>,
    /// (model CRC, quantised head angles) of the cached face.
    key: Option<(u32, [i16; 2])>,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Decoder {
            act: [Act([0; MAX_ACTIVATION_LEN]), Act([0; MAX_ACTIVATION_LEN])],
            face: None,
            key: None,
        }
    }

    /// Forgets the cached face (e.g. after a model change).
    pub fn invalidate(&mut self) {
        self.face = None;
        self.key = None;
    }

    /// The predicted face for the head angles `[HeadYaw, HeadPitch]` (radians), Q8.8 grey levels
    /// (0..=65280), row-major `face_h x face_w`. Runs the network only when the angles, quantised
    /// to the first layer's input scale, or the model differ from the last call.
    pub fn predict(&mut self, model: &Model, head: [f32; 2]) -> Result<&[u16], DecodeError> {
        let input = quantise_input(model, head)?;
        let key = (model.crc32, input);
        if self.key != Some(key) || self.face.is_none() {
            self.run(model, input)?;
            self.key = Some(key);
        }
        Ok(self.face().unwrap_or(&[]))
    }

    /// Like [`predict`](Self::predict) but always runs the whole network (for benchmarks).
    pub fn predict_uncached(
        &mut self,
        model: &Model,
        head: [f32; 2],
    ) -> Result<&[u16], DecodeError> {
        let input = quantise_input(model, head)?;
        self.run(model, input)?;
        self.key = Some((model.crc32, input));
        Ok(self.face().unwrap_or(&[]))
    }

    /// The last predicted face, if any.
    pub fn face(&self) -> Option<&[u16]> {
        let (k, n) = self.face?;
        Some(&bytemuck::cast_slice(&self.act[k].0[..])[..n])
    }

    /// The buffer that does not hold the face, as bytes: scratch space for the saliency mask.
    /// Its contents are lost at the next decoder run.
    pub fn scratch(&mut self) -> &mut [u8] {
        let k = self.face.map_or(1, |(k, _)| 1 - k);
        bytemuck::cast_slice_mut(&mut self.act[k].0[..])
    }

    /// The face and the scratch buffer together.
    pub fn face_and_scratch(&mut self) -> (Option<&[u16]>, &mut [u8]) {
        let [Act(a), Act(b)] = &mut self.act;
        match self.face {
            Some((0, n)) => (
                Some(&bytemuck::cast_slice::<i16, u16>(&a[..])[..n]),
                bytemuck::cast_slice_mut(&mut b[..]),
            ),
            Some((_, n)) => (
                Some(&bytemuck::cast_slice::<i16, u16>(&b[..])[..n]),
                bytemuck::cast_slice_mut(&mut a[..]),
            ),
            None => (None, bytemuck::cast_slice_mut(&mut b[..])),
        }
    }

    fn run(&mut self, model: &Model, input: [i16; 2]) -> Result<(), DecodeError> {
        self.face = None;
        self.key = None;
        check_scales(model)?;
        let [Act(a), Act(b)] = &mut self.act;
        a[0] = input[0];
        a[1] = input[1];
        let mut cur = 0usize;
        for (i, layer) in model.layers.iter().enumerate() {
            let (src, dst) = if cur == 0 {
                (&a[..], &mut b[..])
            } else {
                (&b[..], &mut a[..])
            };
            run_layer(layer, src, dst).map_err(|_| DecodeError::Shape(i as u8))?;
            cur = 1 - cur;
        }
        let n = model.face_pixels();
        let last = model.layers.last().ok_or(DecodeError::Shape(0))?;
        let face = if cur == 0 { &mut a[..] } else { &mut b[..] };
        if n > face.len() {
            return Err(DecodeError::Shape(model.layers.len() as u8 - 1));
        }
        to_grey_q88(&mut face[..n], last.out_shift as u32);
        self.face = Some((cur, n));
        Ok(())
    }
}

/// The first layer's input: the angles with `in_shift` fraction bits, rounded half-up, saturated.
pub fn quantise_input(model: &Model, head: [f32; 2]) -> Result<[i16; 2], DecodeError> {
    if !head.iter().all(|a| a.is_finite()) {
        return Err(DecodeError::BadInput);
    }
    let shift = model.layers.first().map_or(0, |l| l.in_shift) as i32;
    let scale = libm::ldexpf(1.0, shift);
    let q = |a: f32| libm::floorf(a * scale + 0.5).clamp(i16::MIN as f32, i16::MAX as f32) as i16;
    Ok([q(head[0]), q(head[1])])
}

/// In place: the last layer's output (grey/255 with `shift` fraction bits) -> Q8.8 grey levels,
/// `round(y * 255 * 256 / 2^shift)` clamped to `0..=65280`, stored as u16 bit patterns.
fn to_grey_q88(face: &mut [i16], shift: u32) {
    for v in face.iter_mut() {
        // 32767 * 65280 < 2^32: u32 holds the product.
        let y = (*v).max(0) as u32 * 65280;
        let g = match shift {
            0 => y,
            1..=31 => ((y >> (shift - 1)) >> 1) + ((y >> (shift - 1)) & 1),
            _ => 0,
        };
        *v = g.min(65280) as u16 as i16;
    }
}

/// `floor(v / 2^k + 0.5)` for `k >= 0`, without overflow.
#[inline]
fn round_shift_i64(v: i64, k: u32) -> i64 {
    match k {
        0 => v,
        1..=62 => ((v >> (k - 1)) + 1) >> 1,
        _ => 0,
    }
}

/// How one accumulator becomes one output value.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Requant {
    act: Activation,
    /// Fraction bits of the accumulator (`w_shift + in_shift`).
    acc_bits: u32,
    out_bits: u32,
    /// tanh/sigmoid when both shifts are plain right shifts (the usual case): the shift of
    /// |acc| to the table's Q19 and the final rounding shift. Same results as the general path.
    fast: Option<(u32, u32)>,
}

impl Requant {
    pub(crate) fn of(l: &Layer) -> Requant {
        let acc_bits = (l.w_shift as i32 + l.in_shift as i32).max(0) as u32;
        Requant::new(l.activation, acc_bits, l.out_shift.max(0) as u32)
    }

    pub(crate) fn new(act: Activation, acc_bits: u32, out_bits: u32) -> Requant {
        let fast = match act {
            Activation::Tanh if (19..51).contains(&acc_bits) && (1..=23).contains(&out_bits) => {
                Some((acc_bits - 19, 24 - out_bits))
            }
            Activation::Sigmoid if (18..50).contains(&acc_bits) && (1..=24).contains(&out_bits) => {
                Some((acc_bits + 1 - 19, 25 - out_bits))
            }
            _ => None,
        };
        Requant {
            act,
            acc_bits,
            out_bits,
            fast,
        }
    }

    #[inline]
    pub(crate) fn apply(&self, acc: i32) -> i16 {
        self.apply_inline(acc)
    }

    /// [`apply`](Self::apply), inlined into the fast kernels' loops.
    #[inline(always)]
    pub(crate) fn apply_inline(&self, acc: i32) -> i16 {
        if let Some((sh, k)) = self.fast {
            const LAST: usize = TANH_Q24.len() - 1;
            let t = acc.unsigned_abs() >> sh;
            let idx = (t >> 12) as usize;
            let y = if idx < LAST {
                let lo = TANH_Q24[idx];
                let hi = TANH_Q24[idx + 1];
                lo + (((hi - lo) * (t & 4095)) >> 12)
            } else {
                TANH_Q24[LAST]
            } as i32;
            let y = if acc < 0 { -y } else { y };
            let v = if self.act == Activation::Sigmoid {
                (1 << 24) + y
            } else {
                y
            };
            let r = ((v >> (k - 1)) >> 1) + ((v >> (k - 1)) & 1);
            return r.clamp(i16::MIN as i32, i16::MAX as i32) as i16;
        }
        self.apply_general(acc)
    }

    fn apply_general(&self, acc: i32) -> i16 {
        match self.act {
            Activation::Identity => rescale(acc as i64, self.acc_bits, self.out_bits),
            Activation::Relu => rescale(acc.max(0) as i64, self.acc_bits, self.out_bits),
            Activation::Tanh => rescale(tanh_q24(acc, self.acc_bits) as i64, 24, self.out_bits),
            Activation::Sigmoid => {
                let t = tanh_q24(acc, self.acc_bits + 1);
                rescale(((1i32 << 24) + t) as i64, 25, self.out_bits)
            }
        }
    }
}

/// `sat_i16(round(v * 2^(to - from)))`.
#[inline]
fn rescale(v: i64, from: u32, to: u32) -> i16 {
    // The common case in i32: a right shift of a value that fits.
    if from > to && from - to < 32 && v >= i32::MIN as i64 && v <= i32::MAX as i64 {
        let k = from - to;
        let r = ((v as i32 >> (k - 1)) >> 1) + ((v as i32 >> (k - 1)) & 1);
        return r.clamp(i16::MIN as i32, i16::MAX as i32) as i16;
    }
    let r = if from >= to {
        round_shift_i64(v, from - to)
    } else {
        let k = to - from;
        if k >= 32 {
            v.signum() * (1 << 40)
        } else {
            v << k
        }
    };
    r.clamp(i16::MIN as i64, i16::MAX as i64) as i16
}

/// `tanh(acc * 2^-bits)` in Q24, by table and linear interpolation.
#[inline]
pub(crate) fn tanh_q24(acc: i32, bits: u32) -> i32 {
    const LAST: usize = TANH_Q24.len() - 1;
    let a = acc.unsigned_abs();
    // |x| in Q19: table index (steps of 2^-7) in the top bits, interpolation weight in the low 12.
    let t = if bits >= 19 {
        a.checked_shr(bits - 19).unwrap_or(0)
    } else if a >= (8u32 << bits) {
        u32::MAX
    } else {
        a << (19 - bits)
    };
    let idx = (t >> 12) as usize;
    let y = if idx >= LAST {
        TANH_Q24[LAST]
    } else {
        let lo = TANH_Q24[idx];
        let hi = TANH_Q24[idx + 1];
        lo + (((hi - lo) * (t & 4095)) >> 12)
    } as i32;
    if acc < 0 {
        -y
    } else {
        y
    }
}

/// Runs one layer from `src` into `dst`. Errors only on shapes the parser would refuse.
pub(crate) fn run_layer(l: &Layer, src: &[i16], dst: &mut [i16]) -> Result<(), ()> {
    let n_in = l.input.len();
    let n_out = l.output.len();
    if n_in > src.len() || n_out > dst.len() {
        return Err(());
    }
    let (x, y) = (&src[..n_in], &mut dst[..n_out]);
    let rq = Requant::of(l);
    if l.kind == LayerKind::Crop {
        return crop(l, rq, x, y);
    }
    let bias_n = match l.kind {
        LayerKind::Dense => n_out,
        _ => l.output.c as usize,
    };
    if l.bias_count() != bias_n {
        return Err(());
    }
    // Paired fast paths for i16 weights; anything else is the generic loops.
    if l.weight_type == WeightType::I16 {
        match l.kind {
            LayerKind::Dense if n_in.is_multiple_of(2) => {
                let w = bytemuck::try_cast_slice::<u8, u32>(l.weights);
                let x = bytemuck::try_cast_slice::<i16, u32>(x);
                if let (Ok(w), Ok(x), Some(b)) = (w, x, l.bias_i32()) {
                    fast::dense_pairs(rq, w, b, x, y);
                    return Ok(());
                }
            }
            LayerKind::ConvTranspose2d => {
                let done = match (l.weights_i16(), l.bias_i32()) {
                    (Some(w), Some(b)) => fast::conv_transpose(l, rq, &w, &b, x, y),
                    _ => fast::conv_transpose(l, rq, &kernels::Raw(l), &kernels::RawBias(l), x, y),
                };
                if done {
                    return Ok(());
                }
            }
            _ => {}
        }
    }
    // Aligned tables are read as slices; anything else through the byte accessors.
    match (l.weight_type, l.weights_i16(), l.bias_i32()) {
        (WeightType::I16, Some(w), Some(b)) => kernels::layer(l, rq, &w, &b, x, y),
        (WeightType::I8, _, Some(b)) => match l.weights_i8() {
            Some(w) => kernels::layer(l, rq, &w, &b, x, y),
            None => Err(()),
        },
        _ => kernels::layer(l, rq, &kernels::Raw(l), &kernels::RawBias(l), x, y),
    }
}

fn crop(l: &Layer, rq: Requant, x: &[i16], y: &mut [i16]) -> Result<(), ()> {
    let (c, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (oh, ow) = (l.output.h as usize, l.output.w as usize);
    let (top, left) = (l.crop_top as usize, l.crop_left as usize);
    if top + oh > ih || left + ow > iw || l.output.c as usize != c {
        return Err(());
    }
    let exact = rq.acc_bits == rq.out_bits;
    for ch in 0..c {
        for r in 0..oh {
            let s = (ch * ih + top + r) * iw + left;
            let d = (ch * oh + r) * ow;
            let (from, to) = (&x[s..s + ow], &mut y[d..d + ow]);
            if exact {
                to.copy_from_slice(from);
            } else {
                for (o, &i) in to.iter_mut().zip(from) {
                    *o = rq.apply(i as i32);
                }
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
