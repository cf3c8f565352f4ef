//! Cortex-M4 kernels in assembly: a whole Dense layer with a table activation, two rows per pass.
//!
//! Per pass two rows share each load of four input words (`LDM`), their weights come four words
//! per `LDM`, and each word pair is one `SMLAD` (two multiply-accumulates). The groups of four
//! words are unrolled 16 times and entered by a computed jump, so a row of `4 * g` words
//! (g <= 16) has no loop overhead. The activation is the table's: shift, `SSAT`, one load (and
//! for tanh the rounding shift to `out_shift`), then a halfword store.
//!
//! The portable definition is [`super::fast::dense_pairs`] with the same [`Activate`]: sums are
//! wrapping i32 (order does not matter) and the activation is [`TanhAct`] / [`GreyAct`] step for
//! step, so both give the same bits (the QEMU tests compare the board with the host build).

use super::{Activate, AsmAct};

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
    ($name:literal, $act:literal) => {
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
            ".rept 16",
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
            "ldr r12, [sp, #36]",
            "bx r12",
            "5:",
            "add sp, sp, #40",
            "pop {{r4-r11, pc}}",
            concat!(".size ", $name, ", . - ", $name),
        );
    };
}

dense2_asm!(
    "msr_dense2_tanh",
    "asr r3, r3, r11
    ssat r3, #13, r3
    ldrsh.w r3, [r10, r3, lsl #1]
    add r3, r3, r12
    asr r3, r3, lr
    strh r3, [r7], #2
    asr r4, r4, r11
    ssat r4, #13, r4
    ldrsh.w r4, [r10, r4, lsl #1]
    add r4, r4, r12
    asr r4, r4, lr
    strh r4, [r7], #2"
);

dense2_asm!(
    "msr_dense2_grey",
    "asr r3, r3, r11
    ssat r3, #12, r3
    ldrh.w r3, [r10, r3, lsl #1]
    strh r3, [r7], #2
    asr r4, r4, r11
    ssat r4, #12, r4
    ldrh.w r4, [r10, r4, lsl #1]
    strh r4, [r7], #2"
);

extern "C" {
    fn msr_dense2_tanh(job: *const Job);
    fn msr_dense2_grey(job: *const Job);
}

/// Dense rows in pairs with a table activation. Returns how many outputs it wrote (an even
/// number, from the start of `y`); 0 when the layer does not suit it (the caller does the rest).
/// `w` is `[out][np]` words, `x` is `np` words, `np = 4 * g` with `1 <= g <= MAX_GROUPS`.
pub(crate) fn dense2<A: Activate>(rq: A, w: &[u32], b: &[i32], x: &[u32], y: &mut [i16]) -> usize {
    let np = x.len();
    let pairs = y.len() / 2;
    let Some(act) = rq.asm_act() else {
        return 0;
    };
    if np == 0
        || !np.is_multiple_of(4)
        || np / 4 > MAX_GROUPS
        || pairs == 0
        || w.len() < 2 * pairs * np
        || b.len() < 2 * pairs
    {
        return 0;
    }
    let (table, sh, rnd, k, grey) = match act {
        AsmAct::Tanh { table, sh, rnd, k } => (table, sh, rnd, k, false),
        AsmAct::Grey { table, sh } => (table, sh, 0, 0, true),
    };
    let job = Job {
        x: x.as_ptr(),
        bias: b.as_ptr(),
        y: y.as_mut_ptr(),
        pairs: pairs as u32,
        row_bytes: (np * 4) as u32,
        table,
        sh,
        rnd,
        k,
        w: w.as_ptr(),
    };
    // SAFETY: the routine reads `np` words of `x` per pair, `2 * pairs` rows of `np` words of
    // `w`, `2 * pairs` biases, the table within its saturated index range, and writes
    // `2 * pairs` halfwords of `y`; all checked above. It keeps the AAPCS (saves r4-r11, lr;
    // restores sp).
    unsafe {
        if grey {
            msr_dense2_grey(&job);
        } else {
            msr_dense2_tanh(&job);
        }
    }
    2 * pairs
}
