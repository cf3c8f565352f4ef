//! Cortex-M4 kernels in assembly (QEMU counts each instruction once, an `LDM` of four words
//! included; the comments count instructions).
//!
//! - Dense, i16 weights (`msr_dense2_*`): two rows per pass share each load of four input words
//!   (`LDM`), their weights come four words per `LDM`, each word pair is one `SMLAD`. The groups
//!   of four words are unrolled and entered by a computed jump (no loop in a row).
//! - Dense, i8 weights (`msr_dense2_i8_*`): `SXTB16` splits each weight word into two pairs
//!   against the input re-paired ((x0, x2), (x1, x3)); blocks of 32 inputs, looped.
//! - The fused Dense -> ConvTranspose2d step is in `super::fused`; it uses the i8 routine here
//!   with outputs every fourth halfword (`msr_dense2_i8_tanh_x4`).
//!
//! Each output ends with the table step: shift, `SSAT`, one load (tanh: the rounding shift to
//! `out_shift`; grey: `s - (s >> 8)`), halfword store. The portable definitions are
//! `super::fast::dense_pairs` / `super::kernels` with `Requant::apply`: sums wrap in i32 (order
//! does not matter) and the steps are [`super::TanhAct`] / [`super::GreyAct`] instruction for
//! instruction, so both give the same bits (`msr bench` and the QEMU tests compare the board's
//! faces with the host build's).

#![cfg_attr(not(target_arch = "arm"), allow(unused_macros))]

use super::{Activate, AsmAct};

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
#[cfg(target_arch = "arm")]
dense2_asm!(
    "msr_dense2_grey",
    concat!(grey_step!("r3"), grey_step!("r4")),
    "16"
);

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
pub(crate) const I8_BLOCK: usize = 32;
pub(crate) const I8_MAX_IN: usize = 128;

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

/// Tanh Dense rows with i8 weights into every fourth halfword of `y` (one channel of a
/// 4-channel interleaved image), `b.len()` rows, an even number; `xp` from [`pair_i8`].
/// False (nothing written) when the shapes do not suit.
pub(crate) fn dense2_i8_x4(
    act: AsmAct,
    w: &[i8],
    b: &[i32],
    xp: &[u32; I8_MAX_IN / 2],
    n_in: usize,
    y: &mut [i16],
) -> bool {
    let pairs = b.len() / 2;
    if !b.len().is_multiple_of(2)
        || !i8_suits(n_in, pairs, w, b)
        || y.len() < 4 * (2 * pairs - 1) + 1
        || !matches!(act, AsmAct::Tanh { .. })
    {
        return false;
    }
    // SAFETY: shapes checked by i8_suits; y holds the 2 * pairs outputs 4 apart.
    unsafe { dense2_i8_raw(act, w, b, xp, n_in, y.as_mut_ptr(), pairs, true) };
    true
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
pub(crate) fn pair_i8(x: &[i16]) -> [u32; I8_MAX_IN / 2] {
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

#[cfg(target_arch = "arm")]
extern "C" {
    fn msr_dense2_i8_tanh(job: *const Job);
    fn msr_dense2_i8_grey(job: *const Job);
    fn msr_dense2_i8_tanh_x4(job: *const Job);
    fn msr_dense2_tanh(job: *const Job);
    fn msr_dense2_grey(job: *const Job);
}

// Elsewhere (the host's tests), the same routines in Rust, step for step: what the fused path
// does around them (padding, packing, phases, crop) is then tested against the generic loops.
#[cfg(not(target_arch = "arm"))]
use portable::*;

#[cfg(not(target_arch = "arm"))]
mod portable {
    use super::{smlad, Job};

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
    unsafe { dense2_raw(act, w, b, x, y.as_mut_ptr(), pairs) };
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
/// `dense_suits(x.len(), pairs, w, b)`, and `y` valid for `2 * pairs` adjacent halfwords.
unsafe fn dense2_raw(act: AsmAct, w: &[u32], b: &[i32], x: &[u32], y: *mut i16, pairs: usize) {
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
        if grey {
            msr_dense2_grey(&job)
        } else {
            msr_dense2_tanh(&job)
        }
    }
}
