//! A tanh Dense feeding the last ConvTranspose2d (k4 s2, 4 input channels, sigmoid to grey),
//! run as one step on the Cortex-M4 (the conv decoder's two big layers).
//!
//! - The Dense writes a zero-bordered, channel-interleaved image (`mid`): one pixel is the four
//!   channels' i16 = two words, rows [`STRIDE`] pixels apart (a constant, so that the convolution
//!   reaches the next row by an immediate offset). With weights in the blob's blocked order,
//!   `msr_dense_px4` computes the four channels of one pixel per pass: the weights stream in
//!   one load after the other (i16: `LDM` of 4 words per channel and block, 16 `SMLAD`; i8:
//!   `LDRD` of 8 weights split by `SXTB16` against the input re-paired), the four results are
//!   stored as two packed words (tanh step rounded by `SHADD16` when `out_shift` is 14, not
//!   rounded at all when it is 15). i8 weights in PyTorch order (blobs written before the
//!   blocked order) take the 2-row kernel of `decoder::arm` writing every fourth halfword.
//! - The convolution computes four adjacent outputs of a row per pass (`msr_convt4_grey`): both
//!   column phases, each output 16 MACs (2 x 2 taps x 4 channels) as 8 `SMLAD` on channel pairs;
//!   the pass reads 4 pixels of 2 input rows. The grey step is `y - (y >> 8)` then `+32640` on
//!   both packed halves. The window (the crop after the convolution) is computed in groups of
//!   four from an output whose column phase suits the kernel; a first output of the other phase
//!   is computed alone, and the last group may compute up to 3 outputs past the row end: they
//!   land on the next row's first outputs before those are computed (rows run top down), or, in
//!   the last row, in the buffer's slack.
//! - Once the board has learnt the room ([`crate::room`], rule 4), `msr_convt4_grey_room` adds
//!   its offsets as it stores: a group of four outputs is a half cell, one offset, two
//!   saturating halfword steps a word (1.5 instructions a pixel, where a pass of its own over
//!   the face took 2.3).
//!
//! Elsewhere (the host's tests) the two routines are Rust, step for step, so that what surrounds
//! them (padding, packing, phases, crop) is tested against the layer-by-layer path.

use super::arm::{dense2_i8_x4, pair_i8, I8_BLOCK, I8_MAX_IN};
use super::arm::smlad;
use super::kernels::{AnyWeights, Table};
use super::{AsmAct, Requant};
use crate::room::{self, rows::Packed};
use msr_shared::blob::{
    Layer, LayerKind, WeightOrder, WeightType, BLOCK, MAX_ACTIVATION_LEN, MAX_FACE_H, MAX_FACE_W,
};

/// Pixels per row of `mid` (row bytes = STRIDE * 8, an `LDRD` offset).
pub(crate) const STRIDE: usize = 52;
/// Channels of `mid`.
const C: usize = 4;
/// Most input blocks (of 8) of the px4 Dense (its unrolled block).
const PX4_MAX_GROUPS: usize = 16;
const _: () = assert!(PX4_MAX_GROUPS * BLOCK / 2 == I8_MAX_IN / 2);

/// What `msr_dense_px4` reads, in its frame's order.
#[repr(C)]
struct Px4Job {
    y: *mut i16,
    bias: *const i32,
    table: *const i16,
    sh: u32,
    /// `(1 << k) >> 1`, or `0x0001_0001` when `k1` (the `SHADD16` operand).
    rnd: u32,
    k: u32,
    y_end: *mut i16,
    x: *const u32,
    groups: u32,
    w: *const u32,
    k1: u32,
    /// Image rows, and the bytes from one row's end to the next row's first pixel.
    rows: u32,
    skip: u32,
    /// i8 weights (x re-paired as `pair_i8` does), else i16.
    i8w: u32,
}

/// What `msr_convt4_grey` reads.
#[repr(C)]
struct Conv4Job {
    x: *const u32,
    w: *const u32,
    y: *mut i16,
    groups: u32,
    table: *const i16,
    sh: u32,
    bias: i32,
    rows: u32,
    /// Output bytes from one row's start to the next.
    y_step: u32,
    /// The other row phase's weights (they alternate row by row).
    w_other: *const u32,
    /// Bytes from one row's row A to the next's: after an even then an odd output row (they
    /// alternate).
    x_steps: [u32; 2],
    /// `msr_convt4_grey_room` only: the first row's first group's offsets, then one entry a
    /// group ([`crate::room::Room::halves`]); every row takes the same row of entries.
    room: *const Packed,
}

// The assembly's row offsets (`arm.rs`) are STRIDE * 8 - 16, - 8, + 0, + 8.
const _: () = assert!(STRIDE * 8 == 416);

#[cfg(target_arch = "arm")]
use self::arm::{msr_convt4_grey, msr_convt4_grey_room, msr_dense_px4};
#[cfg(not(target_arch = "arm"))]
use portable::*;

#[cfg(target_arch = "arm")]
mod arm;
#[cfg(not(target_arch = "arm"))]
mod portable;

/// How the Dense half runs.
#[derive(Clone, Copy)]
enum DenseKind {
    /// Blocked order, i16 or i8: `msr_dense_px4`.
    Px4,
    /// i8, PyTorch order: the 2-row i8 kernel, every fourth halfword.
    I8Rows,
}

/// The fused pair, checked: every read of the convolution stays inside `mid`, every write
/// inside the output buffer (with the slack that [`Fused::run`] checks).
pub(crate) struct Fused<'l, 'a> {
    dense: &'l Layer<'a>,
    kind: DenseKind,
    dact: AsmAct,
    conv: &'l Layer<'a>,
    cact: AsmAct,
    /// The exact crop that follows, written directly: (top, left, height, width).
    crop: Option<(usize, usize, usize, usize)>,
}

/// The first output column of a group of four: this phase (`ox mod 2`) makes the slots read
/// pixels 0, 1, 1, 2 (padding odd: even columns; even: odd ones).
fn group_phase(p: usize) -> usize {
    1 - p % 2
}

impl<'l, 'a> Fused<'l, 'a> {
    pub(crate) fn of(
        dense: &'l Layer<'a>,
        drq: Requant,
        conv: &'l Layer<'a>,
        crq: Requant,
    ) -> Option<Self> {
        let dact = drq.tanh_act()?.asm_act()?;
        let cact = crq.grey_act()?.asm_act()?;
        let n_in = dense.input.len();
        let kind = match (dense.weight_type, dense.order) {
            (_, WeightOrder::Blocked)
                if n_in.is_multiple_of(BLOCK)
                    && n_in / BLOCK <= PX4_MAX_GROUPS
                    && (dense.weights.as_ptr() as usize).is_multiple_of(4) =>
            {
                DenseKind::Px4
            }
            (WeightType::I8, WeightOrder::Torch)
                if n_in.is_multiple_of(I8_BLOCK) && n_in <= I8_MAX_IN =>
            {
                DenseKind::I8Rows
            }
            _ => return None,
        };
        let (h, w) = (conv.input.h as usize, conv.input.w as usize);
        let ok = dense.kind == LayerKind::Dense
            && conv.kind == LayerKind::ConvTranspose2d
            && conv.kernel == 4
            && conv.stride == 2
            && conv.padding <= 3
            && conv.input.c as usize == C
            && dense.output.len() == conv.input.len()
            && (matches!(kind, DenseKind::Px4) || w.is_multiple_of(2))
            && w + 2 <= STRIDE
            && (h + 2) * STRIDE * C <= MAX_ACTIVATION_LEN
            && AnyWeights::of(dense).is_some()
            && dense.bias_i32().is_some()
            && AnyWeights::of(conv).is_some()
            && conv.bias_i32().is_some();
        let f = Fused {
            dense,
            kind,
            dact,
            conv,
            cact,
            crop: None,
        };
        (ok && f.reads_inside()).then_some(f)
    }

    /// Also takes the crop `l` that follows (an exact copy of a window), so that the
    /// convolution computes and writes only the window.
    pub(crate) fn with_crop(mut self, l: &Layer) -> Option<Self> {
        let (top, left) = (l.crop_top as usize, l.crop_left as usize);
        let (fh, fw) = (l.output.h as usize, l.output.w as usize);
        let c = self.conv;
        let ok = l.kind == LayerKind::Crop
            && l.in_shift == l.out_shift
            && l.input == c.output
            && l.output.c == c.output.c
            && top + fh <= c.output.h as usize
            && left + fw <= c.output.w as usize;
        self.crop = Some((top, left, fh, fw));
        (ok && self.reads_inside()).then_some(self)
    }

    /// The window: all of the output, or the crop's.
    fn window(&self) -> (usize, usize, usize, usize) {
        let c = self.conv;
        self.crop
            .unwrap_or((0, 0, c.output.h as usize, c.output.w as usize))
    }

    /// Columns of the window's groups: the first output computed alone (if its phase does not
    /// suit), the first group's column and the number of groups.
    fn columns(&self) -> (bool, usize, usize) {
        let (_, left, _, fw) = self.window();
        let q = group_phase(self.conv.padding as usize);
        let single = left % 2 != q && fw > 0;
        let g0 = left + single as usize;
        (single, g0, (left + fw).saturating_sub(g0).div_ceil(4))
    }

    /// Rows (padded) and columns (in `mid`, up to STRIDE) that the convolution reads.
    fn reads_inside(&self) -> bool {
        let c = self.conv;
        let p = c.padding as usize;
        let h = c.input.h as usize;
        let (top, left, fh, _) = self.window();
        if fh == 0 {
            return true;
        }
        // Output row 2n + py reads padded rows n + r0 and n + r0 + 1, r0 = (py + p) / 2: the
        // last row reads the furthest.
        let last = top + fh - 1;
        let rows_ok = last / 2 + (last % 2 + p) / 2 < h + 1;
        // The single output reads 2 pixels from column m + c0; group g reads 4 from its base.
        let (single, g0, groups) = self.columns();
        let q = group_phase(p);
        let single_ok = !single || left / 2 + (left % 2 + p) / 2 + 2 <= STRIDE;
        let last_base = (g0 + 4 * groups.saturating_sub(1) - q) / 2 + (q + p) / 2;
        rows_ok && single_ok && (groups == 0 || last_base + 4 <= STRIDE)
    }

    /// The Dense from `buf` into `mid`, then the convolution into `buf`. Not inlined: its
    /// frame stays off the other layers' paths (stack peak).
    ///
    /// With `room` ([`room::Room::halves`]), the convolution also adds the room's offsets
    /// when its groups fall on the half cells (one output channel, no output computed alone,
    /// a window within the largest face): it returns whether it did (else the caller adds
    /// them). It then runs once per row of cells, each run's rows reading that row's entries.
    #[inline(never)]
    pub(crate) fn run(
        &self,
        buf: &mut [i16],
        mid: &mut [i16],
        room: Option<&[Packed; 2 * room::CELLS]>,
    ) -> Result<bool, ()> {
        let (d, c) = (self.dense, self.conv);
        let (h, w) = (c.input.h as usize, c.input.w as usize);
        let n_in = d.input.len();
        let (Some(dw), Some(db), Some(cw), Some(cb)) = (
            AnyWeights::of(d),
            d.bias_i32(),
            AnyWeights::of(c),
            c.bias_i32(),
        ) else {
            return Err(());
        };
        let (top, left, fh, fw) = self.window();
        let oc_n = c.output.c as usize;
        // Up to 3 outputs past the window (see the module notes).
        if mid.len() < (h + 2) * STRIDE * C || buf.len() < oc_n * fh * fw + 3 || cb.len() < oc_n {
            return Err(());
        }
        self.borders(mid, h, w);
        self.dense(buf.get(..n_in).ok_or(())?, dw, db, mid)?;
        let AsmAct::Grey { table, sh } = self.cact else {
            return Err(());
        };
        let p = c.padding as usize;
        let q = group_phase(p);
        let (single, g0, groups) = self.columns();
        let y = buf;
        let row = STRIDE * C;
        // The room's offsets in the convolution: its groups of four are the half cells.
        let fused_room = oc_n == 1 && !single && fh <= MAX_FACE_H && fw <= MAX_FACE_W;
        for oc in 0..oc_n {
            let packs = self.packs(cw, oc);
            let bias = *cb.get(oc).ok_or(())?;
            // Row A of output row oy: padded row oy / 2 + (oy % 2 + p) / 2.
            let ra = |oy: usize| (oy / 2 + (oy % 2 + p) / 2) * row;
            let yo = |oy: usize| (oc * fh + oy - top) * fw;
            if groups > 0 && fh > 0 {
                let base = ((g0 - q) / 2 + (q + p) / 2) * C;
                let step = |oy: usize| ((ra(oy + 1) - ra(oy)) * 2) as u32;
                // Rows `from` on, `rows` of them; with the room's entries from `entries`.
                let mut job = |from: usize, rows: usize, entries: *const Packed| Conv4Job {
                    x: mid[ra(from) + base..].as_ptr() as *const u32,
                    w: packs[from % 2].as_ptr(),
                    y: y[yo(from) + g0 - left..].as_mut_ptr(),
                    groups: groups as u32,
                    table,
                    sh,
                    bias,
                    rows: rows as u32,
                    y_step: (fw * 2) as u32,
                    w_other: packs[1 - from % 2].as_ptr(),
                    x_steps: [step(from), step(from + 1)],
                    room: entries,
                };
                match room.filter(|_| fused_room) {
                    Some(halves) => {
                        for (k, from) in (top..top + fh).step_by(room::CELL).enumerate() {
                            let rows = (top + fh - from).min(room::CELL);
                            let entries = halves[k * 2 * room::COLS..].as_ptr();
                            // SAFETY: as below; and `groups` entries from `entries`, inside
                            // `halves` (fused_room: the window fits the largest face, so a
                            // row of cells has an entry for each of its groups).
                            unsafe { msr_convt4_grey_room(&job(from, rows, entries)) };
                        }
                    }
                    // SAFETY: `reads_inside` checked every read (rows A and B, 4 pixels per
                    // group, inside the STRIDE-wide rows of `mid`, whose size is checked
                    // above); the writes are 4 * groups halfwords per row from the window's
                    // output g0, at most 3 past the window's row, inside `y` (checked above).
                    None => unsafe { msr_convt4_grey(&job(top, fh, core::ptr::null())) },
                }
            }
            // Output `left` alone (after the groups: the row above may spill onto it): phase
            // 1 - q, slot 1's weights.
            for oy in (top..top + fh).filter(|_| single) {
                let py = oy % 2;
                let xa = ra(oy) + (left / 2 + (left % 2 + p) / 2) * C;
                let (wa, wb) = (&packs[py][4..8], &packs[py][12..16]);
                let mut acc = bias;
                for (r, ws) in [(0, wa), (row, wb)] {
                    let xs: &[u32] =
                        bytemuck::try_cast_slice(&mid[xa + r..xa + r + 2 * C]).map_err(|_| ())?;
                    for (&xv, &wv) in xs.iter().zip(ws) {
                        acc = smlad(xv, wv, acc);
                    }
                }
                y[yo(oy)] = super::GreyAct { sh }.act(acc);
            }
        }
        Ok(room.is_some() && fused_room)
    }

    /// The Dense: `x` into the image rows of `mid` (borders not touched).
    #[inline(never)]
    fn dense(&self, x: &[i16], dw: AnyWeights, db: &[i32], mid: &mut [i16]) -> Result<(), ()> {
        let c = self.conv;
        let (h, w, n_in) = (c.input.h as usize, c.input.w as usize, x.len());
        let d_i16 = matches!(dw, AnyWeights::I16(_));
        // The input, copied out (`buf` takes the output) into one array (stack): words of i16
        // pairs for i16 weights, re-paired for i8 ones.
        let mut xw = [0u32; I8_MAX_IN / 2];
        match self.kind {
            DenseKind::Px4 if d_i16 => {
                let xin: &[u32] = bytemuck::try_cast_slice(x).map_err(|_| ())?;
                xw.get_mut(..n_in / 2).ok_or(())?.copy_from_slice(xin);
            }
            _ => xw = pair_i8(x),
        }
        let row = STRIDE * C;
        match (self.kind, dw) {
            (DenseKind::Px4, _) => {
                let AsmAct::Tanh { table, sh, rnd, k } = self.dact else {
                    return Err(());
                };
                // Words per pixel: 4 channels of n_in i16 or i8.
                let (dw, wpx): (&[u32], usize) = match dw {
                    AnyWeights::I16(v) => (bytemuck::try_cast_slice(v).map_err(|_| ())?, n_in * 2),
                    AnyWeights::I8(v) => (bytemuck::try_cast_slice(v).map_err(|_| ())?, n_in),
                };
                let bpx = C;
                if dw.len() != h * w * wpx || db.len() != h * w * bpx {
                    return Err(());
                }
                // Pixels (iy + 1, 1..=w) of `mid`, row by row.
                let first = row + C;
                let out = mid
                    .get_mut(first..first + (h - 1) * row + w * C)
                    .ok_or(())?;
                let job = Px4Job {
                    y: out.as_mut_ptr(),
                    bias: db.as_ptr(),
                    table,
                    sh,
                    rnd: if k == 1 { 0x0001_0001 } else { rnd as u32 },
                    k,
                    y_end: out[w * C..].as_mut_ptr(),
                    x: xw.as_ptr(),
                    groups: (n_in / BLOCK) as u32,
                    w: dw.as_ptr(),
                    k1: (k == 1) as u32,
                    rows: h as u32,
                    skip: ((STRIDE - w) * C * 2) as u32,
                    i8w: !d_i16 as u32,
                };
                // SAFETY: h rows of w pixels of 4 outputs: weights and biases are the layer's
                // tables (lengths checked), the outputs inside `out`, x inside `xw`.
                unsafe { msr_dense_px4(&job) };
            }
            (DenseKind::I8Rows, AnyWeights::I8(dw)) => {
                // Channel by channel (c.input.c == C, a run-time bound: not unrolled).
                for ch in 0..c.input.c as usize {
                    for iy in 0..h {
                        let r = (ch * h + iy) * w;
                        let at = (iy + 1) * row + C + ch;
                        let out = &mut mid[at..at + C * (w - 1) + 1];
                        let (wr, br) = (dw.get(r * n_in..(r + w) * n_in), db.get(r..r + w));
                        let (Some(wr), Some(br)) = (wr, br) else {
                            return Err(());
                        };
                        if !dense2_i8_x4(self.dact, wr, br, &xw, n_in, out) {
                            return Err(());
                        }
                    }
                }
            }
            _ => return Err(()),
        }
        Ok(())
    }

    /// The convolution's weight words for output channel `oc`, per row phase py: W0A, W1A,
    /// W0B, W1B; W0 is column phase q, W1 the other; row A is tap ky0 + 2, B ky0; in each,
    /// column A (kx0 + 2) then B (kx0), channel pairs (0, 1) and (2, 3).
    #[inline(never)]
    fn packs(&self, cw: AnyWeights, oc: usize) -> [[u32; 16]; 2] {
        let p = self.conv.padding as usize;
        let (q, oc_n) = (group_phase(p), self.conv.output.c as usize);
        let wt = |ic: usize, ky: usize, kx: usize| -> u32 {
            cw.at(((ic * oc_n + oc) * 4 + ky) * 4 + kx) as u16 as u32
        };
        let mut packs = [[0u32; 16]; 2];
        for (py, pack) in packs.iter_mut().enumerate() {
            for (i, v) in pack.iter_mut().enumerate() {
                let (rw, slot, cl, cp) = (i / 8, i / 4 % 2, i / 2 % 2, i % 2);
                let ky = (py + p) % 2 + 2 * (1 - rw);
                let kx = ((q + slot) % 2 + p) % 2 + 2 * (1 - cl);
                *v = wt(2 * cp, ky, kx) | (wt(2 * cp + 1, ky, kx) << 16);
            }
        }
        packs
    }

    /// Zeros what the convolution reads around the image: rows 0 and h + 1, column 0 and the
    /// columns from w + 1 that it reaches.
    fn borders(&self, mid: &mut [i16], h: usize, w: usize) {
        let row = STRIDE * C;
        let (_, g0, groups) = self.columns();
        let q = group_phase(self.conv.padding as usize);
        let p = self.conv.padding as usize;
        let reach = if groups == 0 {
            w + 2
        } else {
            ((g0 + 4 * (groups - 1) - q) / 2 + (q + p) / 2 + 4).max(w + 2)
        }
        .min(STRIDE);
        mid[..row].fill(0);
        mid[(h + 1) * row..(h + 2) * row].fill(0);
        for iy in 1..=h {
            let r = iy * row;
            mid[r..r + C].fill(0);
            mid[r + (w + 1) * C..r + reach * C].fill(0);
        }
    }
}

use super::Activate;
