//! Cortex-M4 kernels in assembly (QEMU counts each instruction once, an `LDM` of four words
//! included; the comments count instructions).
//!
//! - Dense, i16 weights (`msr_dense2_*`): two rows per pass share each load of four input words
//!   (`LDM`), their weights come four words per `LDM`, each word pair is one `SMLAD`. The groups
//!   of four words are unrolled and entered by a computed jump (no loop in a row).
//! - Dense, i8 weights (`msr_dense2_i8_*`): `SXTB16` splits each weight word into two pairs
//!   against the input re-paired ((x0, x2), (x1, x3)); blocks of 32 inputs, looped.
//! - [`Fused`]: a tanh Dense writing a 4-channel interleaved, zero-padded image, then the last
//!   ConvTranspose2d k4 s2 (sigmoid to grey) two outputs of a phase per pass
//!   (`msr_convt_k4s2c4_grey`), the crop after it written directly.
//!
//! Each output ends with the table step: shift, `SSAT`, one load (tanh: the rounding shift to
//! `out_shift`; grey: `s - (s >> 8)`), halfword store. The portable definitions are
//! `super::fast::dense_pairs` / `super::kernels` with `Requant::apply`: sums wrap in i32 (order
//! does not matter) and the steps are [`super::TanhAct`] / [`super::GreyAct`] instruction for
//! instruction, so both give the same bits (`msr bench` and the QEMU tests compare the board's
//! faces with the host build's).

#![cfg_attr(not(target_arch = "arm"), allow(unused_macros))]

use super::kernels::{AnyWeights, Table};
use super::{Activate, AsmAct, Requant};
use msr_shared::blob::{Layer, LayerKind, WeightType, MAX_ACTIVATION_LEN};

/// Most groups of four words a row may have here (the unrolled block's length).
pub(crate) const MAX_GROUPS: usize = 16;

/// What the assembly reads, in this order (see the prologue's `LDM`).
#[repr(C)]
struct Job {
    x: *const u32,
    bias: *const i32,
    y: *mut i16,
    pairs: u32,
    row_bytes: u32,
    /// The table's centre (entry of index 0).
    table: *const i16,
    sh: u32,
    rnd: i32,
    k: u32,
    w: *const u32,
}

/// One 4-word group of two rows: x in r5-r8, row 0 (r1) and row 1 (r2) through r9-r12; 44 bytes
/// (every instruction 32-bit, so that the computed jump can count them).
macro_rules! dense2_asm {
    ($name:literal, $act:expr, $groups:literal) => {
        core::arch::global_asm!(
            concat!(".section .text.", $name, ",\"ax\",%progbits"),
            concat!(".global ", $name),
            concat!(".type ", $name, ",%function"),
            ".p2align 2",
            ".thumb_func",
            concat!($name, ":"),
            "push {{r4-r11, lr}}",
            "sub sp, sp, #40",
            // r1 x, r2 bias, r3 y, r4 pairs, r5 row_bytes, r6 table, r7 sh, r8 rnd, r9 k, r10 w.
            "ldm r0, {{r1-r10}}",
            "stm sp, {{r1-r10}}",
            // Entry into the unrolled block: 4f - groups * 44, groups = row_bytes / 16.
            "lsrs r11, r5, #4",
            "movs r12, #44",
            "mul r11, r11, r12",
            "adr.w r12, 4f",
            "subs r12, r12, r11",
            "orr r12, r12, #1",
            "str r12, [sp, #36]",
            "mov r0, r1",
            "ldrd r3, r4, [r2], #8",
            "str r2, [sp, #4]",
            "mov r1, r10",
            "add r2, r10, r5",
            "bx r12",
            ".p2align 2",
            "3:",
            concat!(".rept ", $groups),
            "ldm.w r0!, {{r5-r8}}",
            "ldm.w r1!, {{r9-r12}}",
            "smlad r3, r5, r9, r3",
            "smlad r3, r6, r10, r3",
            "smlad r3, r7, r11, r3",
            "smlad r3, r8, r12, r3",
            "ldm.w r2!, {{r9-r12}}",
            "smlad r4, r5, r9, r4",
            "smlad r4, r6, r10, r4",
            "smlad r4, r7, r11, r4",
            "smlad r4, r8, r12, r4",
            ".endr",
            "4:",
            // r5 x, r6 bias, r7 y, r8 pairs, r9 row_bytes, r10 table, r11 sh, r12 rnd, lr k.
            "ldm sp, {{r5-r12, lr}}",
            // Row 0 ended where row 1 starts; row 1 where the next pair starts.
            "mov r1, r2",
            "add r2, r2, r9",
            $act,
            "subs r8, r8, #1",
            "beq 5f",
            "ldrd r3, r4, [r6], #8",
            "mov r0, r5",
            "stm sp, {{r5-r8}}",
            // Into the unrolled block again (the entry address has its Thumb bit).
            "ldr pc, [sp, #36]",
            "5:",
            "add sp, sp, #40",
            "pop {{r4-r11, pc}}",
            concat!(".size ", $name, ", . - ", $name),
        );
    };
}

/// The tanh step of one accumulator (`$a`) into the halfword at r7, r7 then moved by `$inc`.
#[rustfmt::skip]
macro_rules! tanh_step {
    ($a:literal, $inc:literal) => {
        concat!(
            "asr ", $a, ", ", $a, ", r11\n",
            "ssat ", $a, ", #13, ", $a, "\n",
            "ldrsh.w ", $a, ", [r10, ", $a, ", lsl #1]\n",
            "add ", $a, ", ", $a, ", r12\n",
            "asr ", $a, ", ", $a, ", lr\n",
            "strh ", $a, ", [r7], #", $inc, "\n"
        )
    };
}

/// The last-layer step of `$a`: Q16 sigmoid from the tanh table, times 255/256, stored at r7.
#[rustfmt::skip]
macro_rules! grey_step {
    ($a:literal) => {
        concat!(
            "asr ", $a, ", ", $a, ", r11\n",
            "ssat ", $a, ", #13, ", $a, "\n",
            "ldrsh.w ", $a, ", [r10, ", $a, ", lsl #1]\n",
            "add ", $a, ", ", $a, ", #32768\n",
            "sub ", $a, ", ", $a, ", ", $a, ", lsr #8\n",
            "strh ", $a, ", [r7], #2\n"
        )
    };
}

#[cfg(target_arch = "arm")]
dense2_asm!(
    "msr_dense2_tanh",
    concat!(tanh_step!("r3", "2"), tanh_step!("r4", "2")),
    "16"
);
// Outputs 4 halfwords apart: a 4-channel interleaved (HWC) image for the transposed convolution;
// rows of at most X4_GROUPS groups.
#[cfg(target_arch = "arm")]
dense2_asm!(
    "msr_dense2_tanh_x4",
    concat!(tanh_step!("r3", "8"), tanh_step!("r4", "8")),
    "4"
);

#[cfg(target_arch = "arm")]
dense2_asm!(
    "msr_dense2_grey",
    concat!(grey_step!("r3"), grey_step!("r4")),
    "16"
);

/// Groups of the x4 routine's unrolled block (code size: the fused Dense is small).
const X4_GROUPS: usize = 4;

/// Dense with i8 weights, two rows per pass: each weight word (four i8) becomes two pairs by
/// `SXTB16` (bytes 0, 2 and, rotated, 1, 3), multiplied by the input re-paired the same way
/// ((x0, x2), (x1, x3)) with `SMLAD`. Blocks of 32 inputs (8 words of one row), looped.
/// Same job layout as the i16 routine (row_bytes = inputs); [sp, #36] holds the blocks per row.
macro_rules! dense2_i8_asm {
    ($name:literal, $act:expr) => {
        core::arch::global_asm!(
            concat!(".section .text.", $name, ",\"ax\",%progbits"),
            concat!(".global ", $name),
            concat!(".type ", $name, ",%function"),
            ".p2align 2",
            ".thumb_func",
            concat!($name, ":"),
            "push {{r4-r11, lr}}",
            "sub sp, sp, #40",
            "ldm r0, {{r1-r10}}",
            "stm sp, {{r1-r10}}",
            "lsrs r11, r5, #5",
            "str r11, [sp, #36]",
            "mov r0, r1",
            "ldrd r3, r4, [r2], #8",
            "str r2, [sp, #4]",
            "mov r1, r10",
            "add r2, r10, r5",
            "mov lr, r11",
            "3:",
            ".rept 4",
            "ldm.w r0!, {{r5-r8}}",
            "ldrd r9, r10, [r1], #8",
            "sxtb16 r11, r9",
            "smlad r3, r11, r5, r3",
            "sxtb16 r11, r9, ror #8",
            "smlad r3, r11, r6, r3",
            "sxtb16 r11, r10",
            "smlad r3, r11, r7, r3",
            "sxtb16 r11, r10, ror #8",
            "smlad r3, r11, r8, r3",
            "ldrd r9, r10, [r2], #8",
            "sxtb16 r11, r9",
            "smlad r4, r11, r5, r4",
            "sxtb16 r11, r9, ror #8",
            "smlad r4, r11, r6, r4",
            "sxtb16 r11, r10",
            "smlad r4, r11, r7, r4",
            "sxtb16 r11, r10, ror #8",
            "smlad r4, r11, r8, r4",
            ".endr",
            "subs lr, lr, #1",
            "bne 3b",
            "ldm sp, {{r5-r12, lr}}",
            "mov r1, r2",
            "add r2, r2, r9",
            $act,
            "subs r8, r8, #1",
            "beq 5f",
            "ldrd r3, r4, [r6], #8",
            "mov r0, r5",
            "stm sp, {{r5-r8}}",
            "ldr lr, [sp, #36]",
            "b 3b",
            "5:",
            "add sp, sp, #40",
            "pop {{r4-r11, pc}}",
            concat!(".size ", $name, ", . - ", $name),
        );
    };
}

#[cfg(target_arch = "arm")]
dense2_i8_asm!(
    "msr_dense2_i8_tanh",
    concat!(tanh_step!("r3", "2"), tanh_step!("r4", "2"))
);
#[cfg(target_arch = "arm")]
dense2_i8_asm!(
    "msr_dense2_i8_tanh_x4",
    concat!(tanh_step!("r3", "8"), tanh_step!("r4", "8"))
);
#[cfg(target_arch = "arm")]
dense2_i8_asm!(
    "msr_dense2_i8_grey",
    concat!(grey_step!("r3"), grey_step!("r4"))
);

/// Inputs per block of the i8 routine, and the most it takes (its re-paired copy of the input
/// is on the stack).
const I8_BLOCK: usize = 32;
const I8_MAX_IN: usize = 128;

/// Dense rows with i8 weights in pairs with a table activation (see [`dense2`]).
pub(crate) fn dense2_i8<A: Activate>(
    rq: A,
    w: &[i8],
    b: &[i32],
    x: &[i16],
    y: &mut [i16],
) -> usize {
    let pairs = y.len() / 2;
    if !i8_suits(x.len(), pairs, w, b) {
        return 0;
    }
    let Some(act) = rq.asm_act() else {
        return 0;
    };
    let xp = pair_i8(x);
    // SAFETY: shapes checked by i8_suits; y holds 2 * pairs adjacent halfwords.
    unsafe { dense2_i8_raw(act, w, b, &xp, x.len(), y.as_mut_ptr(), pairs, false) };
    2 * pairs
}

fn i8_suits(n_in: usize, pairs: usize, w: &[i8], b: &[i32]) -> bool {
    n_in > 0
        && n_in.is_multiple_of(I8_BLOCK)
        && n_in <= I8_MAX_IN
        && pairs > 0
        && w.len() >= 2 * pairs * n_in
        && b.len() >= 2 * pairs
        && (w.as_ptr() as usize).is_multiple_of(4)
}

/// The input re-paired as SXTB16 splits a weight word: (x0, x2), (x1, x3) per four.
fn pair_i8(x: &[i16]) -> [u32; I8_MAX_IN / 2] {
    let mut xp = [0u32; I8_MAX_IN / 2];
    for (q, c) in xp.chunks_exact_mut(2).zip(x.chunks_exact(4)) {
        q[0] = c[0] as u16 as u32 | (c[2] as u16 as u32) << 16;
        q[1] = c[1] as u16 as u32 | (c[3] as u16 as u32) << 16;
    }
    xp
}

/// # Safety
/// `i8_suits(n_in, pairs, w, b)`, `xp` from [`pair_i8`], and `y` valid for `2 * pairs`
/// halfwords, 4 apart when `x4`, else adjacent.
#[allow(clippy::too_many_arguments)]
unsafe fn dense2_i8_raw(
    act: AsmAct,
    w: &[i8],
    b: &[i32],
    xp: &[u32; I8_MAX_IN / 2],
    n_in: usize,
    y: *mut i16,
    pairs: usize,
    x4: bool,
) {
    let (table, sh, rnd, k, grey) = match act {
        AsmAct::Tanh { table, sh, rnd, k } => (table, sh, rnd, k, false),
        AsmAct::Grey { table, sh } => (table, sh, 0, 0, true),
    };
    let job = Job {
        x: xp.as_ptr(),
        bias: b.as_ptr(),
        y,
        pairs: pairs as u32,
        row_bytes: n_in as u32,
        table,
        sh,
        rnd,
        k,
        w: w.as_ptr() as *const u32,
    };
    // SAFETY: reads n_in / 2 words of xp per pair, 2 * pairs word-aligned rows of n_in bytes of
    // `w` (LDRD: aligned), 2 * pairs biases, the table within its saturated range; writes the
    // 2 * pairs halfwords of `y` (caller's contract). AAPCS kept.
    unsafe {
        match (grey, x4) {
            (true, _) => msr_dense2_i8_grey(&job),
            (false, false) => msr_dense2_i8_tanh(&job),
            (false, true) => msr_dense2_i8_tanh_x4(&job),
        }
    }
}

// ConvTranspose2d k4 s2 over a 4-channel interleaved, zero-padded input, last-layer sigmoid to
// grey: two outputs of one phase per pass (columns m and m + 1 read input columns a, a+1 and
// a+1, a+2 of two input rows; one weight load serves both).
//
// Frame: sp+0 y, +4 table, +8 sh, +12 and +16 bias; r0 row A, r1 row B, r2 the phase's
// row B weights (row A's 4 words just before), lr pairs left.
#[cfg(target_arch = "arm")]
core::arch::global_asm!(
    ".section .text.msr_convt_k4s2c4_grey,\"ax\",%progbits",
    ".global msr_convt_k4s2c4_grey",
    ".type msr_convt_k4s2c4_grey,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_convt_k4s2c4_grey:",
    "push {{r4-r11, lr}}",
    "sub sp, sp, #24",
    // r1 x, r2 w, r3 y, r4 pairs, r5 table, r6 sh, r7 bias, r8 row_bytes.
    "ldm r0, {{r1-r8}}",
    "str r3, [sp, #0]",
    "str r5, [sp, #4]",
    "str r6, [sp, #8]",
    "str r7, [sp, #12]",
    "str r7, [sp, #16]",
    "mov r0, r1",
    "add r1, r1, r8",
    // r2 at row B's weights: row A's are the 16 bytes before.
    "add r2, r2, #16",
    "mov lr, r4",
    "1:",
    "ldrd r3, r4, [sp, #12]",
    // Row A: columns a, a+1 (r0 moves on two columns), then a+2 for the second output.
    "ldm r0!, {{r5-r8}}",
    "ldmdb r2, {{r9-r12}}",
    "smlad r3, r5, r9, r3",
    "smlad r3, r6, r10, r3",
    "smlad r3, r7, r11, r3",
    "smlad r3, r8, r12, r3",
    "smlad r4, r7, r9, r4",
    "smlad r4, r8, r10, r4",
    "ldrd r5, r6, [r0]",
    "smlad r4, r5, r11, r4",
    "smlad r4, r6, r12, r4",
    // Row B.
    "ldm r1!, {{r5-r8}}",
    "ldm r2, {{r9-r12}}",
    "smlad r3, r5, r9, r3",
    "smlad r3, r6, r10, r3",
    "smlad r3, r7, r11, r3",
    "smlad r3, r8, r12, r3",
    "smlad r4, r7, r9, r4",
    "smlad r4, r8, r10, r4",
    "ldrd r5, r6, [r1]",
    "smlad r4, r5, r11, r4",
    "smlad r4, r6, r12, r4",
    // r7 y, r9 table, r10 sh.
    "ldm sp, {{r7, r9, r10}}",
    "asr r3, r3, r10",
    "ssat r3, #13, r3",
    "ldrsh.w r3, [r9, r3, lsl #1]",
    "add r3, r3, #32768",
    "sub r3, r3, r3, lsr #8",
    "strh r3, [r7], #4",
    "asr r4, r4, r10",
    "ssat r4, #13, r4",
    "ldrsh.w r4, [r9, r4, lsl #1]",
    "add r4, r4, #32768",
    "sub r4, r4, r4, lsr #8",
    "strh r4, [r7], #4",
    "str r7, [sp, #0]",
    "subs lr, lr, #1",
    "bne 1b",
    "add sp, sp, #24",
    "pop {{r4-r11, pc}}",
    ".size msr_convt_k4s2c4_grey, . - msr_convt_k4s2c4_grey",
);

#[repr(C)]
struct ConvJob {
    x: *const i16,
    w: *const u32,
    y: *mut i16,
    pairs: u32,
    table: *const i16,
    sh: u32,
    bias: i32,
    row_bytes: u32,
}

#[cfg(target_arch = "arm")]
extern "C" {
    fn msr_convt_k4s2c4_grey(job: *const ConvJob);
    fn msr_dense2_i8_tanh(job: *const Job);
    fn msr_dense2_i8_grey(job: *const Job);
    fn msr_dense2_i8_tanh_x4(job: *const Job);
    fn msr_dense2_tanh(job: *const Job);
    fn msr_dense2_tanh_x4(job: *const Job);
    fn msr_dense2_grey(job: *const Job);
}

// Elsewhere (the host's tests), the same routines in Rust, step for step: what the fused path
// does around them (padding, packing, phases, crop) is then tested against the generic loops.
#[cfg(not(target_arch = "arm"))]
use portable::*;

#[cfg(not(target_arch = "arm"))]
mod portable {
    use super::{ConvJob, Job};
    use crate::decoder::fast::smlad;

    /// The table step of the assembly: tanh (rounded to out_shift) or grey.
    unsafe fn step(job: &Job, acc: i32, grey: bool) -> i16 {
        let i = (acc >> job.sh).clamp(-4096, 4095);
        // SAFETY: `table` is the tanh table's centre, i within its half-length.
        let y = unsafe { *job.table.offset(i as isize) } as i32;
        if grey {
            let s = (1 << 15) + y;
            (s - (s >> 8)) as u16 as i16
        } else {
            ((y + job.rnd) >> job.k) as i16
        }
    }

    /// SXTB16 of `w` (rotated right by `rot` bits first).
    fn sxtb16(w: u32, rot: u32) -> u32 {
        let v = w.rotate_right(rot);
        (v as u8 as i8 as i16 as u16 as u32)
            | ((((v >> 16) as u8 as i8 as i16) as u16 as u32) << 16)
    }

    /// # Safety
    /// As the assembly's callers guarantee.
    unsafe fn dense2(job: *const Job, i8w: bool, grey: bool, y_step: usize) {
        let job = unsafe { &*job };
        // Words of one row: n_in / 2 of i16 pairs, or n_in / 4 of four i8.
        let words = job.row_bytes as usize / 4;
        let (mut w, mut b, mut y) = (job.w, job.bias, job.y);
        for _ in 0..job.pairs {
            for _ in 0..2 {
                let mut acc = unsafe { *b };
                for j in 0..words {
                    let wv = unsafe { *w.add(j) };
                    if i8w {
                        let (x0, x1) = unsafe { (*job.x.add(2 * j), *job.x.add(2 * j + 1)) };
                        acc = smlad(sxtb16(wv, 0), x0, acc);
                        acc = smlad(sxtb16(wv, 8), x1, acc);
                    } else {
                        acc = smlad(wv, unsafe { *job.x.add(j) }, acc);
                    }
                }
                unsafe {
                    *y = step(job, acc, grey);
                    y = y.add(y_step);
                    b = b.add(1);
                    w = w.add(words);
                }
            }
        }
    }

    pub(super) unsafe fn msr_dense2_tanh(job: *const Job) {
        unsafe { dense2(job, false, false, 1) }
    }
    pub(super) unsafe fn msr_dense2_tanh_x4(job: *const Job) {
        unsafe { dense2(job, false, false, 4) }
    }
    pub(super) unsafe fn msr_dense2_grey(job: *const Job) {
        unsafe { dense2(job, false, true, 1) }
    }
    pub(super) unsafe fn msr_dense2_i8_tanh(job: *const Job) {
        unsafe { dense2(job, true, false, 1) }
    }
    pub(super) unsafe fn msr_dense2_i8_tanh_x4(job: *const Job) {
        unsafe { dense2(job, true, false, 4) }
    }
    pub(super) unsafe fn msr_dense2_i8_grey(job: *const Job) {
        unsafe { dense2(job, true, true, 1) }
    }

    /// Two outputs of one phase per pass, as `msr_convt_k4s2c4_grey`.
    pub(super) unsafe fn msr_convt_k4s2c4_grey(job: *const ConvJob) {
        let c = unsafe { &*job };
        let step_job = Job {
            x: core::ptr::null(),
            bias: core::ptr::null(),
            y: core::ptr::null_mut(),
            pairs: 0,
            row_bytes: 0,
            table: c.table,
            sh: c.sh,
            rnd: 0,
            k: 0,
            w: core::ptr::null(),
        };
        let rb = c.row_bytes as usize / 4;
        let (mut xa, mut y) = (c.x as *const u32, c.y);
        for _ in 0..c.pairs {
            let (mut a0, mut a1) = (c.bias, c.bias);
            for row in 0..2 {
                let xr = unsafe { xa.add(row * rb) };
                let w = unsafe { core::slice::from_raw_parts(c.w.add(4 * row), 4) };
                let x = unsafe { core::slice::from_raw_parts(xr, 6) };
                for t in 0..4 {
                    a0 = smlad(x[t], w[t], a0);
                    a1 = smlad(x[t + 2], w[t], a1);
                }
            }
            unsafe {
                *y = step(&step_job, a0, true);
                *y.add(2) = step(&step_job, a1, true);
                y = y.add(4);
                xa = xa.add(4);
            }
        }
    }
}

/// Dense rows in pairs with a table activation. Returns how many outputs it wrote (an even
/// number, from the start of `y`); 0 when the layer does not suit it (the caller does the rest).
/// `w` is `[out][np]` words, `x` is `np` words, `np = 4 * g` with `1 <= g <= MAX_GROUPS`.
pub(crate) fn dense2<A: Activate>(rq: A, w: &[u32], b: &[i32], x: &[u32], y: &mut [i16]) -> usize {
    let pairs = y.len() / 2;
    if !dense_suits(x.len(), pairs, w, b) {
        return 0;
    }
    let Some(act) = rq.asm_act() else {
        return 0;
    };
    // SAFETY: shapes checked by dense_suits; y holds 2 * pairs adjacent halfwords.
    unsafe { dense2_raw(act, w, b, x, y.as_mut_ptr(), pairs, false) };
    2 * pairs
}

fn dense_suits(np: usize, pairs: usize, w: &[u32], b: &[i32]) -> bool {
    np > 0
        && np.is_multiple_of(4)
        && np / 4 <= MAX_GROUPS
        && pairs > 0
        && w.len() >= 2 * pairs * np
        && b.len() >= 2 * pairs
}

/// # Safety
/// `dense_suits(x.len(), pairs, w, b)`, and `y` valid for `2 * pairs` halfwords, 4 apart when
/// `x4`, else adjacent.
unsafe fn dense2_raw(
    act: AsmAct,
    w: &[u32],
    b: &[i32],
    x: &[u32],
    y: *mut i16,
    pairs: usize,
    x4: bool,
) {
    let (table, sh, rnd, k, grey) = match act {
        AsmAct::Tanh { table, sh, rnd, k } => (table, sh, rnd, k, false),
        AsmAct::Grey { table, sh } => (table, sh, 0, 0, true),
    };
    let job = Job {
        x: x.as_ptr(),
        bias: b.as_ptr(),
        y,
        pairs: pairs as u32,
        row_bytes: (x.len() * 4) as u32,
        table,
        sh,
        rnd,
        k,
        w: w.as_ptr(),
    };
    // SAFETY: the routine reads `np` words of `x` per pair, `2 * pairs` rows of `np` words of
    // `w`, `2 * pairs` biases, the table within its saturated index range, and writes the
    // `2 * pairs` halfwords of `y` (caller's contract). It keeps the AAPCS (saves r4-r11, lr;
    // restores sp).
    unsafe {
        match (grey, x4) {
            (true, _) => msr_dense2_grey(&job),
            (false, false) => msr_dense2_tanh(&job),
            (false, true) => msr_dense2_tanh_x4(&job),
        }
    }
}

/// Channels of the interleaved image between the fused Dense and ConvTranspose2d.
const FUSED_C: usize = 4;

/// A Dense layer (tanh) whose output is a 4 x h x w image read by a ConvTranspose2d k4 s2 that
/// writes the face (sigmoid to grey): the Dense writes the image channel-interleaved with a zero
/// border, so the convolution reads each tap row of two outputs with one `LDM` and never tests
/// a border.
pub(crate) struct Fused<'l, 'a> {
    dense: &'l Layer<'a>,
    dact: AsmAct,
    conv: &'l Layer<'a>,
    cact: AsmAct,
    /// The exact crop that follows, written directly: (top, left, height, width).
    crop: Option<(usize, usize, usize, usize)>,
}

impl<'l, 'a> Fused<'l, 'a> {
    /// The pair, when both suit the kernels; every read of the convolution then stays inside
    /// the padded image (checked here).
    pub(crate) fn of(
        dense: &'l Layer<'a>,
        drq: Requant,
        conv: &'l Layer<'a>,
        crq: Requant,
    ) -> Option<Self> {
        let dact = drq.tanh_act()?.asm_act()?;
        let cact = crq.grey_act()?.asm_act()?;
        let (h, w) = (conv.input.h as usize, conv.input.w as usize);
        let (oh, ow) = (conv.output.h as usize, conv.output.w as usize);
        let p = conv.padding as usize;
        let n_in = dense.input.len();
        let dense_ok = match dense.weight_type {
            WeightType::I16 => n_in.is_multiple_of(8) && n_in / 8 <= X4_GROUPS,
            WeightType::I8 => n_in.is_multiple_of(I8_BLOCK) && n_in <= I8_MAX_IN,
        };
        let ok = dense.kind == LayerKind::Dense
            && dense_ok
            && conv.kind == LayerKind::ConvTranspose2d
            && conv.kernel == 4
            && conv.stride == 2
            && p <= 3
            && conv.input.c as usize == FUSED_C
            && dense.output.len() == conv.input.len()
            && w.is_multiple_of(2)
            && ow >= 4
            && (h + 2) * (w + 2) * FUSED_C <= MAX_ACTIVATION_LEN
            && AnyWeights::of(dense).is_some()
            && dense.bias_i32().is_some()
            && AnyWeights::of(conv).is_some()
            && conv.bias_i32().is_some();
        if !ok {
            return None;
        }
        // Output row 2n + py reads padded rows n + r0 and n + r0 + 1; the pair m, m + 1 of
        // phase px reads padded columns m + c0 .. m + c0 + 2, for m + 1 < outputs of the phase.
        for ph in 0..2 {
            let r0 = (ph + p) / 2;
            if oh > ph && (oh - 1 - ph) / 2 + r0 + 1 > h + 1 {
                return None;
            }
            let c0 = (ph + p) / 2;
            if (ow - ph).div_ceil(2) + c0 > w + 1 {
                return None;
            }
        }
        Some(Fused {
            dense,
            dact,
            conv,
            cact,
            crop: None,
        })
    }

    /// Also takes the crop `l` that follows (an exact copy of a window at least 4 wide), so
    /// that the convolution computes and writes only the window.
    pub(crate) fn with_crop(mut self, l: &Layer) -> Option<Self> {
        let (top, left) = (l.crop_top as usize, l.crop_left as usize);
        let (fh, fw) = (l.output.h as usize, l.output.w as usize);
        let c = self.conv;
        let ok = l.kind == LayerKind::Crop
            && l.in_shift == l.out_shift
            && l.input == c.output
            && l.output.c == c.output.c
            && top + fh <= c.output.h as usize
            && left + fw <= c.output.w as usize
            && fw >= 4;
        self.crop = Some((top, left, fh, fw));
        ok.then_some(self)
    }

    /// The Dense from `buf` into `mid` (interleaved, padded), then the convolution into `buf`.
    pub(crate) fn run(&self, buf: &mut [i16], mid: &mut [i16]) -> Result<(), ()> {
        let (d, c) = (self.dense, self.conv);
        let (h, w) = (c.input.h as usize, c.input.w as usize);
        let pw = w + 2;
        let n_in = d.input.len();
        let (Some(dw), Some(db), Some(cw), Some(cb)) = (
            AnyWeights::of(d),
            d.bias_i32(),
            AnyWeights::of(c),
            c.bias_i32(),
        ) else {
            return Err(());
        };
        let np = n_in / 2;
        // The input, copied out (`buf` takes the output): words of i16 pairs for i16 weights,
        // re-paired for i8 ones.
        let x = buf.get(..n_in).ok_or(())?;
        let xw = match dw {
            AnyWeights::I16(_) => {
                let mut xw = [0u32; I8_MAX_IN / 2];
                let xin: &[u32] = bytemuck::try_cast_slice(x).map_err(|_| ())?;
                xw.get_mut(..np).ok_or(())?.copy_from_slice(xin);
                xw
            }
            AnyWeights::I8(_) => pair_i8(x),
        };
        let y = buf;
        let (oc_n, oh, ow) = (
            c.output.c as usize,
            c.output.h as usize,
            c.output.w as usize,
        );
        let out_len = self
            .crop
            .map_or(c.output.len(), |(_, _, fh, fw)| oc_n * fh * fw);
        if mid.len() < (h + 2) * pw * FUSED_C || y.len() < out_len || cb.len() < oc_n {
            return Err(());
        }
        // The zero border.
        mid[..pw * FUSED_C].fill(0);
        mid[(h + 1) * pw * FUSED_C..(h + 2) * pw * FUSED_C].fill(0);
        for iy in 1..=h {
            let r = iy * pw * FUSED_C;
            mid[r..r + FUSED_C].fill(0);
            mid[r + (w + 1) * FUSED_C..r + pw * FUSED_C].fill(0);
        }
        // Dense rows of one channel and image row at a time: w outputs, 4 halfwords apart.
        for ch in 0..FUSED_C {
            for iy in 0..h {
                let r = (ch * h + iy) * w;
                let br = &db[r..r + w];
                let at = ((iy + 1) * pw + 1) * FUSED_C + ch;
                // The row's w outputs go 4 apart from `at`: the last, at + 4 * (w - 1), is
                // inside row iy + 1 of `mid`.
                let out = mid[at..at + 4 * (w - 1) + 1].as_mut_ptr();
                match dw {
                    AnyWeights::I16(dw) => {
                        let dw: &[u32] = bytemuck::try_cast_slice(dw).map_err(|_| ())?;
                        let wr = &dw[r * np..(r + w) * np];
                        if !dense_suits(np, w / 2, wr, br) || np / 4 > X4_GROUPS {
                            return Err(());
                        }
                        // SAFETY: checked by dense_suits and the slice of `mid` above.
                        unsafe { dense2_raw(self.dact, wr, br, &xw[..np], out, w / 2, true) };
                    }
                    AnyWeights::I8(dw) => {
                        let wr = &dw[r * n_in..(r + w) * n_in];
                        if !i8_suits(n_in, w / 2, wr, br) {
                            return Err(());
                        }
                        // SAFETY: checked by i8_suits and the slice of `mid` above.
                        unsafe { dense2_i8_raw(self.dact, wr, br, &xw, n_in, out, w / 2, true) };
                    }
                }
            }
        }
        let AsmAct::Grey { table, sh } = self.cact else {
            return Err(());
        };
        let p = c.padding as usize;
        let wt = |ic: usize, oc: usize, ky: usize, kx: usize| -> u32 {
            cw.at(((ic * oc_n + oc) * 4 + ky) * 4 + kx) as u16 as u32
        };
        for oc in 0..oc_n {
            // Weight words per phase (py, px): row A (tap ky0 + 2) then row B (ky0); in each,
            // column A (kx0 + 2) then B (kx0), channel pairs (0, 1) and (2, 3).
            let mut packs = [[0u32; 8]; 4];
            for (ph, pack) in packs.iter_mut().enumerate() {
                let (ky0, kx0) = ((ph / 2 + p) % 2, (ph % 2 + p) % 2);
                for (rw, ky) in [ky0 + 2, ky0].into_iter().enumerate() {
                    for (cl, kx) in [kx0 + 2, kx0].into_iter().enumerate() {
                        for cp in 0..2 {
                            pack[rw * 4 + cl * 2 + cp] =
                                wt(2 * cp, oc, ky, kx) | (wt(2 * cp + 1, oc, ky, kx) << 16);
                        }
                    }
                }
            }
            // The window written: all of the output, or the crop's.
            let (top, left, fh, fw) = self.crop.unwrap_or((0, 0, oh, ow));
            for oy in top..top + fh {
                let (py, n) = (oy % 2, oy / 2);
                let r0 = (py + p) / 2;
                for px in 0..2 {
                    let c0 = (px + p) / 2;
                    // Outputs ox = 2m + px inside [left, left + fw): m in m0..m1.
                    let m0 = left.saturating_sub(px).div_ceil(2);
                    let m1 = (left + fw - px).div_ceil(2);
                    let m_n = m1 - m0;
                    let xa = ((n + r0) * pw + c0) * FUSED_C;
                    let yo = (oc * fh + oy - top) * fw + 2 * m0 + px - left;
                    let (xp, yp) = (mid.as_ptr(), y.as_mut_ptr());
                    let job = |m: usize, pairs: usize| ConvJob {
                        x: xp.wrapping_add(xa + (m0 + m) * FUSED_C),
                        w: packs[py * 2 + px].as_ptr(),
                        y: yp.wrapping_add(yo + 2 * m),
                        pairs: pairs as u32,
                        table,
                        sh,
                        bias: cb[oc],
                        row_bytes: (pw * FUSED_C * 2) as u32,
                    };
                    // SAFETY: `of` checked that every read stays inside the padded image;
                    // the writes are the window's outputs (oc, oy, 2(m0 + m) + px), m < m_n,
                    // inside `y` (`with_crop` checked the window). m_n >= 2 as fw >= 4.
                    unsafe {
                        msr_convt_k4s2c4_grey(&job(0, m_n / 2));
                        if m_n % 2 == 1 {
                            // The last output: the pair ending there (one written twice).
                            msr_convt_k4s2c4_grey(&job(m_n - 2, 1));
                        }
                    }
                }
            }
        }
        Ok(())
    }
}
