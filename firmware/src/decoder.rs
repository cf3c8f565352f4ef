//! Fixed-point decoder: the head angles the servos report -> the predicted face.
//!
//! Semantics are those of `msr_shared::blob`: every layer takes i16 activations with `in_shift`
//! fraction bits, multiplies by weights with `w_shift` bits into a wrapping i32 accumulator that
//! starts at the bias, and writes `sat_i16(round(act(acc * 2^-(w_shift+in_shift)) * 2^out_shift))`.
//!
//! - Rounding is half-up everywhere (`floor(x + 0.5)`), the accumulator wraps on overflow (the
//!   quantizer chooses shifts so that it does not), results saturate to i16.
//! - Activations by table without interpolation (`Requant::apply` is the definition): tanh is
//!   `TANH_Q15` (`tanh_table.rs`) at the midpoint of `x`'s cell of 2^-9 (error below 2^-10),
//!   sigmoid `(1 + tanh(x/2)) / 2` from the same table. So an activation is a shift, a
//!   saturation (`SSAT`) and one load on the Cortex-M4.
//! - The last layer, when it is a sigmoid (crops after it allowed), writes the face in Q8.8 grey
//!   directly: `s - (s >> 8)` of the Q16 sigmoid `s` (error below 0.13 grey levels); its
//!   `out_shift` is then not used. Otherwise the last output is converted by `to_grey_q88`.
//! - Fast paths: Dense rows in pairs and ConvTranspose2d by phase with packed weight pairs
//!   (`fast.rs`, SMLAD on the M4); on the M4 Dense layers run in assembly (`arm.rs`, i16 and i8
//!   weights), and a tanh Dense feeding a last ConvTranspose2d k4 s2 over 4 channels (the
//!   default conv decoder) runs fused, crop included. Sums wrap in any order and the table steps
//!   are the same, so host and board agree bit for bit (the QEMU tests and `msr bench` check it).
//!
//! The predicted face is kept, in Q8.8 grey levels, until the quantised head pose or the model
//! changes ([`Decoder::predict`]); [`Decoder::predict_uncached`] always runs it.

use crate::room::{self, rows::Packed, Room};
use kernels::{Biases, Weights};
use msr_shared::blob::{Activation, Layer, LayerKind, Model, WeightType, MAX_ACTIVATION_LEN};

// The M4 kernels; elsewhere compiled with Rust stand-ins for the tests only.
#[cfg_attr(not(target_arch = "arm"), allow(dead_code))]
mod arm;
mod fast;
#[cfg_attr(not(target_arch = "arm"), allow(dead_code))]
mod fused;
mod kernels;
mod tanh_table;

use tanh_table::TANH_Q15;

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
    /// Times the network ran (wrapping).
    runs: u32,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// Empty buffers, nothing cached; `const`, so it can live in a `static` (about 32 KiB).
    pub const fn new() -> Self {
        Decoder {
            act: [Act([0; MAX_ACTIVATION_LEN]), Act([0; MAX_ACTIVATION_LEN])],
            face: None,
            key: None,
            runs: 0,
        }
    }

    /// Times the network has run (wrapping): a caller that reads it before and after a
    /// prediction knows whether the face was made for it or came from the cache.
    pub fn runs(&self) -> u32 {
        self.runs
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
        self.predict_in(model, head, None, false)
    }

    /// [`predict`](Self::predict), with the room's offsets added ([`Room`], rule 4) each time
    /// the network runs (the cached face keeps them): by the network's last layer as it stores
    /// the face where it can (the default conv decoder on the board), else by [`Room::apply`].
    /// The same face either way.
    pub fn predict_with(
        &mut self,
        model: &Model,
        head: [f32; 2],
        room: &Room,
    ) -> Result<&[u16], DecodeError> {
        self.predict_in(model, head, Some(room), false)
    }

    /// Like [`predict`](Self::predict) but always runs the whole network (for benchmarks).
    pub fn predict_uncached(
        &mut self,
        model: &Model,
        head: [f32; 2],
    ) -> Result<&[u16], DecodeError> {
        self.predict_in(model, head, None, true)
    }

    /// Like [`predict_with`](Self::predict_with) but always runs the whole network (for
    /// benchmarks: the cost of the room's offsets is this less
    /// [`predict_uncached`](Self::predict_uncached)).
    pub fn predict_uncached_with(
        &mut self,
        model: &Model,
        head: [f32; 2],
        room: &Room,
    ) -> Result<&[u16], DecodeError> {
        self.predict_in(model, head, Some(room), true)
    }

    /// The four above: the network runs when `always`, or when the key differs from the
    /// cached face's; with `room`, its offsets are added.
    fn predict_in(
        &mut self,
        model: &Model,
        head: [f32; 2],
        room: Option<&Room>,
        always: bool,
    ) -> Result<&[u16], DecodeError> {
        let input = quantise_input(model, head)?;
        let key = (model.crc32, input);
        if always || self.key != Some(key) || self.face.is_none() {
            let added = self.run(model, input, room.and_then(Room::halves))?;
            if let (Some(room), Some((k, n)), false) = (room, self.face, added) {
                let face = &mut bytemuck::cast_slice_mut(&mut self.act[k].0[..])[..n];
                room.apply(face, model.face_w as usize);
            }
            self.key = Some(key);
        }
        Ok(self.face().unwrap_or(&[]))
    }

    /// The last predicted face, if any.
    pub fn face(&self) -> Option<&[u16]> {
        let (k, n) = self.face?;
        Some(&bytemuck::cast_slice(&self.act[k].0[..])[..n])
    }

    /// The last predicted face, to change in place (the cache keeps the change).
    pub fn face_mut(&mut self) -> Option<&mut [u16]> {
        let (k, n) = self.face?;
        Some(&mut bytemuck::cast_slice_mut(&mut self.act[k].0[..])[..n])
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

    /// The network; with `room` ([`Room::halves`]), returns whether its last layer added the
    /// offsets (else the face has none).
    #[cfg_attr(not(target_arch = "arm"), allow(unused_variables))]
    fn run(
        &mut self,
        model: &Model,
        input: [i16; 2],
        room: Option<&[Packed; 2 * room::CELLS]>,
    ) -> Result<bool, DecodeError> {
        self.face = None;
        self.key = None;
        self.runs = self.runs.wrapping_add(1);
        check_scales(model)?;
        let grey_at = grey_layer(model);
        let [Act(a), Act(b)] = &mut self.act;
        a[0] = input[0];
        a[1] = input[1];
        let mut cur = 0usize;
        #[cfg_attr(not(target_arch = "arm"), allow(unused_mut))]
        let mut added = false;
        let rq = |i: usize| {
            let r = Requant::of(&model.layers[i]);
            if grey_at == Some(i) {
                r.last()
            } else {
                r
            }
        };
        let mut i = 0;
        while let Some(layer) = model.layers.get(i) {
            let (src, dst) = if cur == 0 {
                (&mut a[..], &mut b[..])
            } else {
                (&mut b[..], &mut a[..])
            };
            // On the M4, a Dense feeding the last ConvTranspose2d may run fused (same bits).
            // With the crop after it, the convolution writes only the window. The result is
            // in `src` either way.
            #[cfg(target_arch = "arm")]
            {
                let fused = || {
                    let next = model.layers.get(i + 1).filter(|_| grey_at == Some(i + 1))?;
                    fused::Fused::of(layer, rq(i), next, rq(i + 1))
                };
                let with_crop = model
                    .layers
                    .get(i + 2)
                    .and_then(|c| fused()?.with_crop(c))
                    .map(|f| (f, 3));
                if let Some((f, n)) = with_crop.or_else(|| fused().map(|f| (f, 2))) {
                    // The room's offsets only where its output is the face (no crop after).
                    let room = room.filter(|_| i + n == model.layers.len());
                    added = f.run(src, dst, room).map_err(|_| DecodeError::Shape(i as u8))?;
                    i += n;
                    continue;
                }
            }
            run_layer_as(layer, rq(i), src, dst).map_err(|_| DecodeError::Shape(i as u8))?;
            cur = 1 - cur;
            i += 1;
        }
        let n = model.face_pixels();
        let last = model.layers.last().ok_or(DecodeError::Shape(0))?;
        let face = if cur == 0 { &mut a[..] } else { &mut b[..] };
        if n > face.len() {
            return Err(DecodeError::Shape(model.layers.len() as u8 - 1));
        }
        if grey_at.is_none() {
            to_grey_q88(&mut face[..n], last.out_shift as u32);
        }
        self.face = Some((cur, n));
        Ok(added)
    }
}

/// The layer that writes the face as Q8.8 grey directly: the last one that is not a crop, when
/// it is a sigmoid and every crop after it copies exactly (same shift in and out). Its output
/// then skips the `out_shift` step (see [`Requant::apply`]).
fn grey_layer(model: &Model) -> Option<usize> {
    let i = model
        .layers
        .iter()
        .rposition(|l| l.kind != LayerKind::Crop)?;
    let exact_crops = model.layers[i + 1..]
        .iter()
        .all(|l| l.in_shift == l.out_shift);
    (model.layers[i].activation == Activation::Sigmoid && exact_crops).then_some(i)
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
    /// Sigmoid straight to Q8.8 grey levels (the decoder's last layer), see [`GreyAct`].
    grey: bool,
}

/// One accumulator to one output, as the kernels inline it (one type per form, so that each
/// kernel is compiled for each without a branch per output).
pub(crate) trait Activate: Copy {
    fn act(self, acc: i32) -> i16;
    /// The same step for the assembly kernels, when they have it.
    #[allow(dead_code)]
    fn asm_act(self) -> Option<AsmAct> {
        None
    }
}

/// A table activation as the assembly kernels take it (`table` points at index 0).
#[allow(dead_code)]
#[derive(Clone, Copy, Debug)]
pub(crate) enum AsmAct {
    Tanh {
        table: *const i16,
        sh: u32,
        rnd: i32,
        k: u32,
    },
    Grey {
        table: *const i16,
        sh: u32,
    },
}

/// tanh: `TANH_Q15[sat13(acc >> sh)]`, then `(y + rnd) >> k` (k = 15 - out_bits): a shift, a
/// saturation, one load and the rounding shift. Same bits as [`Requant::apply`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct TanhAct {
    sh: u32,
    k: u32,
    rnd: i32,
}

/// The last layer's sigmoid as Q8.8 grey: `s = 2^15 + TANH_Q15[sat13(acc >> sh)]` (sigmoid in
/// Q16), then `s - (s >> 8)` (times 255/256). Same bits as [`Requant::apply`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct GreyAct {
    sh: u32,
}

impl Activate for TanhAct {
    #[inline(always)]
    fn act(self, acc: i32) -> i16 {
        let i = sat13(acc >> self.sh);
        // SAFETY: sat13 keeps i + 4096 in 0..8192, the table's length.
        let y = unsafe { *TANH_Q15.as_ptr().offset(i as isize + 4096) } as i32;
        ((y + self.rnd) >> self.k) as i16
    }
    fn asm_act(self) -> Option<AsmAct> {
        Some(AsmAct::Tanh {
            table: TANH_Q15.as_ptr().wrapping_add(4096),
            sh: self.sh,
            rnd: self.rnd,
            k: self.k,
        })
    }
}

impl Activate for GreyAct {
    #[inline(always)]
    fn act(self, acc: i32) -> i16 {
        let i = sat13(acc >> self.sh);
        // SAFETY: sat13 keeps i + 4096 in 0..8192, the table's length.
        let s = (1 << 15) + unsafe { *TANH_Q15.as_ptr().offset(i as isize + 4096) } as i32;
        (s - (s >> 8)) as u16 as i16
    }
    fn asm_act(self) -> Option<AsmAct> {
        Some(AsmAct::Grey {
            table: TANH_Q15.as_ptr().wrapping_add(4096),
            sh: self.sh,
        })
    }
}

impl Activate for Requant {
    #[inline(always)]
    fn act(self, acc: i32) -> i16 {
        self.apply(acc)
    }
    fn asm_act(self) -> Option<AsmAct> {
        match self.tanh_act() {
            Some(t) => t.asm_act(),
            None => self.grey_act()?.asm_act(),
        }
    }
}

/// Runs `$body` with `$a` bound to the fastest [`Activate`] for `$rq`.
#[cfg_attr(target_arch = "arm", allow(unused_macros))]
macro_rules! with_act {
    ($rq:expr, |$a:ident| $body:expr) => {{
        let rq: $crate::decoder::Requant = $rq;
        if let Some(t) = rq.tanh_act() {
            let $a = t;
            $body
        } else if let Some(g) = rq.grey_act() {
            let $a = g;
            $body
        } else {
            let $a = rq;
            $body
        }
    }};
}

/// Table cell of `x = acc * 2^-bits` in steps of `2^-frac`: `floor(x * 2^frac)` clamped to
/// `-half..half`, plus `half` (an index into a table of `2 * half` entries).
#[inline]
fn cell(acc: i32, bits: u32, frac: u32, half: i32) -> usize {
    let i = if bits >= frac {
        acc >> (bits - frac).min(31)
    } else {
        ((acc as i64) << (frac - bits)).clamp(i32::MIN as i64, i32::MAX as i64) as i32
    };
    (i.clamp(-half, half - 1) + half) as usize
}

/// `v` clamped to the 13-bit signed range (`SSAT #13` on the Cortex-M4).
#[inline(always)]
pub(crate) fn sat13(v: i32) -> i32 {
    #[cfg(target_arch = "arm")]
    {
        let r: i32;
        // SAFETY: SSAT reads one register and writes one.
        unsafe {
            core::arch::asm!("ssat {r}, #13, {v}", r = lateout(reg) r, v = in(reg) v,
                options(pure, nomem, nostack));
        }
        r
    }
    #[cfg(not(target_arch = "arm"))]
    {
        v.clamp(-4096, 4095)
    }
}

impl Requant {
    pub(crate) fn of(l: &Layer) -> Requant {
        let acc_bits = (l.w_shift as i32 + l.in_shift as i32).max(0) as u32;
        Requant::new(l.activation, acc_bits, l.out_shift.max(0) as u32)
    }

    pub(crate) fn new(act: Activation, acc_bits: u32, out_bits: u32) -> Requant {
        Requant {
            act,
            acc_bits,
            out_bits,
            grey: false,
        }
    }

    /// The same layer as the decoder's last: a sigmoid writes Q8.8 grey levels.
    pub(crate) fn last(self) -> Requant {
        Requant {
            grey: self.act == Activation::Sigmoid,
            ..self
        }
    }

    /// The inlined tanh, when the shifts allow it.
    pub(crate) fn tanh_act(&self) -> Option<TanhAct> {
        if self.act != Activation::Tanh || self.acc_bits < 9 || self.out_bits > 15 {
            return None;
        }
        let k = 15 - self.out_bits;
        Some(TanhAct {
            sh: (self.acc_bits - 9).min(31),
            k,
            rnd: (1 << k) >> 1,
        })
    }

    /// The inlined last-layer sigmoid, when the shifts allow it.
    pub(crate) fn grey_act(&self) -> Option<GreyAct> {
        if self.act != Activation::Sigmoid || !self.grey || self.acc_bits < 8 {
            return None;
        }
        Some(GreyAct {
            sh: (self.acc_bits - 8).min(31),
        })
    }

    /// The definition: identity and ReLU rescale exactly; tanh is `TANH_Q15` at `x` in steps
    /// of 2^-9 (error below 2^-10), sigmoid `(1 + tanh(x / 2)) / 2` from the same table (x in
    /// steps of 2^-8); the result is rounded half-up to `out_bits` and saturated. The last
    /// layer's sigmoid goes to Q8.8 grey instead: `s - (s >> 8)` of the Q16 sigmoid `s`
    /// (error below 0.13 grey levels).
    pub(crate) fn apply(&self, acc: i32) -> i16 {
        match self.act {
            Activation::Identity => rescale(acc as i64, self.acc_bits, self.out_bits),
            Activation::Relu => rescale(acc.max(0) as i64, self.acc_bits, self.out_bits),
            Activation::Tanh => {
                let y = TANH_Q15[cell(acc, self.acc_bits, 9, 4096)];
                rescale(y as i64, 15, self.out_bits)
            }
            Activation::Sigmoid if self.grey => {
                let s = (1i32 << 15) + TANH_Q15[cell(acc, self.acc_bits, 8, 4096)] as i32;
                (s - (s >> 8)) as u16 as i16
            }
            Activation::Sigmoid => {
                let y = TANH_Q15[cell(acc, self.acc_bits, 8, 4096)];
                rescale((1i64 << 15) + y as i64, 16, self.out_bits)
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

/// Runs one layer from `src` into `dst`. Errors only on shapes the parser would refuse.
#[cfg(test)]
pub(crate) fn run_layer(l: &Layer, src: &[i16], dst: &mut [i16]) -> Result<(), ()> {
    run_layer_as(l, Requant::of(l), src, dst)
}

/// [`run_layer`] with the output step given.
pub(crate) fn run_layer_as(l: &Layer, rq: Requant, src: &[i16], dst: &mut [i16]) -> Result<(), ()> {
    let n_in = l.input.len();
    let n_out = l.output.len();
    if n_in > src.len() || n_out > dst.len() {
        return Err(());
    }
    let (x, y) = (&src[..n_in], &mut dst[..n_out]);
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
    // The blocked order (see msr_shared::blob) as stored, or through the PyTorch-order
    // accessors when the tables are not aligned.
    if !l.torch_order() {
        return match (kernels::AnyWeights::of(l), l.bias_i32()) {
            (Some(w), Some(b)) => {
                kernels::dense_blocked(l, rq, &Weights::Slice(w), &Biases::Slice(b), x, y)
            }
            _ => kernels::layer(l, rq, &Weights::Raw(l), &Biases::Raw(l), x, y),
        };
    }
    // Dense rows in pairs for i16 weights.
    if l.weight_type == WeightType::I16 && l.kind == LayerKind::Dense && n_in.is_multiple_of(2) {
        let w = bytemuck::try_cast_slice::<u8, u32>(l.weights);
        let x = bytemuck::try_cast_slice::<i16, u32>(x);
        if let (Ok(w), Ok(x), Some(b)) = (w, x, l.bias_i32()) {
            // The M4 takes the table steps in assembly (one instantiation: code size).
            #[cfg(target_arch = "arm")]
            fast::dense_pairs(rq, w, b, x, y);
            #[cfg(not(target_arch = "arm"))]
            with_act!(rq, |a| fast::dense_pairs(a, w, b, x, y));
            return Ok(());
        }
    }
    // ConvTranspose2d by phase with packed weight pairs, i8 or i16 (aligned tables only: an
    // unaligned blob takes the generic loops); one instantiation (code size), the table step
    // through Requant::apply.
    if l.kind == LayerKind::ConvTranspose2d {
        if let (Some(w), Some(b)) = (kernels::AnyWeights::of(l), l.bias_i32()) {
            if fast::conv_transpose(l, rq, &w, &b, x, y) {
                return Ok(());
            }
        }
    }
    // Aligned tables are read as slices; anything else through the byte accessors. One type
    // for all (one instantiation of each loop: code size).
    let (w, b) = match (kernels::AnyWeights::of(l), l.bias_i32()) {
        (Some(w), Some(b)) => (Weights::Slice(w), Biases::Slice(b)),
        _ => (Weights::Raw(l), Biases::Raw(l)),
    };
    // On the M4, i8 Dense rows in pairs in assembly; the rest (an odd last row, or rows the
    // assembly does not take) in a loop over the i8 slice (the Dense layers of the i8 MLP).
    #[cfg(target_arch = "arm")]
    if let (Some(wi8), Some(bs)) = (l.weights_i8(), l.bias_i32()) {
        if l.kind == LayerKind::Dense && wi8.len() == n_in * n_out && bs.len() == n_out {
            let done = arm::dense2_i8(rq, wi8, bs, x, y);
            kernels::dense(rq, &&wi8[done * n_in..], &&bs[done..], x, &mut y[done..]);
            return Ok(());
        }
    }
    kernels::layer(l, rq, &w, &b, x, y)
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
