//! One row of rule 2 (the samples' sums) and of rule 4 (the offsets added), over a row's whole
//! cells: Thumb-2 routines on the board, the same steps in Rust elsewhere. The board's routines
//! are checked against the Rust ones by the benchmark image (`msr bench --backend qemu`).
//!
//! On a 75 x 58 face (`msr bench --backend qemu`, the red demo model) the Rust loops took 36.1 k
//! instructions a frame learnt from (rule 2: the table's and the rows' addresses went to the
//! stack) and 49.1 k a new prediction (rule 4); with these routines 18.4 k and 18.7 k, rule 4
//! two values at a time with saturating halfword arithmetic.

use super::{Acc, CELL};

/// One row's whole cells for [`gather`].
#[repr(C)]
pub struct GatherJob {
    /// The row's first pixel of the frame, of the prediction (Q8.8) and of the mask.
    pub frame: *const u8,
    /// See [`GatherJob::frame`].
    pub pred: *const u16,
    /// See [`GatherJob::frame`].
    pub mask: *const u8,
    /// The frame's fitted grey levels, 256 entries.
    pub v: *const u16,
    /// The first cell's sums; one [`Acc`] a cell.
    pub acc: *mut Acc,
    /// Whole cells (of [`CELL`] pixels) in the row, at least 1.
    pub cells: u32,
    /// A pixel of grey `f` is a sample when its mask is 0 and `f - first < span` (in u32).
    pub first: u32,
    /// See [`GatherJob::first`].
    pub span: u32,
}

/// Rule 2 for one row: each cell's pixels 0, 2, 4 and 6 added to its sums.
///
/// # Safety
/// `cells >= 1`; `cells * CELL` values behind each row pointer, `cells` sums behind `acc`, 256
/// behind `v`.
#[inline]
pub unsafe fn gather(job: &GatherJob) {
    #[cfg(target_arch = "arm")]
    // SAFETY: the caller's contract; the routine keeps AAPCS.
    unsafe {
        msr_room_gather(job)
    }
    #[cfg(not(target_arch = "arm"))]
    // SAFETY: the caller's contract.
    unsafe {
        gather_reference(job)
    }
}

/// [`gather`] in Rust.
///
/// # Safety
/// As [`gather`].
pub unsafe fn gather_reference(job: &GatherJob) {
    for c in 0..job.cells as usize {
        // SAFETY: inside the caller's rows and sums.
        unsafe {
            let a = &mut *job.acc.add(c);
            for j in (0..CELL).step_by(2) {
                let x = c * CELL + j;
                let f = *job.frame.add(x) as u32;
                if *job.mask.add(x) == 0 && f.wrapping_sub(job.first) < job.span {
                    let p = *job.pred.add(x) as i32;
                    a.sum += *job.v.add(f as usize) as i32 - p;
                    a.pred += p;
                    a.count += 1;
                }
            }
        }
    }
}

/// Rule 4 for one row: each whole cell's offset added to its [`CELL`] predicted values, the sum
/// held to `0..=65280`.
///
/// # Safety
/// `cells * CELL` values behind `pred`, `cells` behind `offsets`.
#[inline]
pub unsafe fn apply(pred: *mut u16, offsets: *const i16, cells: u32) {
    #[cfg(target_arch = "arm")]
    // SAFETY: the caller's contract; the routine keeps AAPCS.
    unsafe {
        msr_room_apply(pred, offsets, cells)
    }
    #[cfg(not(target_arch = "arm"))]
    // SAFETY: the caller's contract.
    unsafe {
        apply_reference(pred, offsets, cells)
    }
}

/// [`apply`] in Rust.
///
/// # Safety
/// As [`apply`].
pub unsafe fn apply_reference(pred: *mut u16, offsets: *const i16, cells: u32) {
    for c in 0..cells as usize {
        // SAFETY: inside the caller's row and offsets.
        unsafe {
            let o = *offsets.add(c) as i32;
            for x in c * CELL..(c + 1) * CELL {
                let p = pred.add(x);
                *p = (*p as i32 + o).clamp(0, 255 << 8) as u16;
            }
        }
    }
}

#[cfg(target_arch = "arm")]
extern "C" {
    fn msr_room_gather(job: *const GatherJob);
    fn msr_room_apply(pred: *mut u16, offsets: *const i16, cells: u32);
}

const _: () = assert!(CELL == 8, "the routines below take a cell as 8 pixels");

// Rule 2. r3 frame, r4 pred, r5 mask, r6 v, r7 the cell's sums (ldm/stm: sum, pred, count in
// r11, r12, lr), r8 cells left, r9 first, r10 span; r0 and r1 scratch.
#[cfg(target_arch = "arm")]
core::arch::global_asm!(
    // Pixel `fo` of the cell (its prediction at byte `po`), 12 instructions when it is a sample.
    ".macro MSR_ROOM_SAMPLE fo, po",
    "ldrb r0, [r5, #\\fo]",
    "cbnz r0, 2f",
    "ldrb r0, [r3, #\\fo]",
    "sub r1, r0, r9",
    "cmp r1, r10",
    "bhs 2f",
    "ldrh r0, [r6, r0, lsl #1]",
    "ldrh r1, [r4, #\\po]",
    "sub r0, r0, r1",
    "add r11, r11, r0",
    "add r12, r12, r1",
    "add lr, lr, #1",
    "2:",
    ".endm",
    ".section .text.msr_room_gather,\"ax\",%progbits",
    ".global msr_room_gather",
    ".type msr_room_gather,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_room_gather:",
    "push {{r4-r11, lr}}",
    "ldm r0, {{r3-r10}}",
    "1:",
    "ldm r7, {{r11, r12, lr}}",
    "MSR_ROOM_SAMPLE 0, 0",
    "MSR_ROOM_SAMPLE 2, 4",
    "MSR_ROOM_SAMPLE 4, 8",
    "MSR_ROOM_SAMPLE 6, 12",
    "stmia r7!, {{r11, r12, lr}}",
    "add r3, r3, #8",
    "add r5, r5, #8",
    "add r4, r4, #16",
    "subs r8, r8, #1",
    "bne 1b",
    "pop {{r4-r11, pc}}",
    ".size msr_room_gather, . - msr_room_gather",
    // Rule 4, two values a word: UQADD16 (UQSUB16 for a negative offset) saturates at 65535 (0),
    // USUB16 and SEL hold the top at 0xff00. r0 pred, r1 offsets, r2 cells left, r3 0xff00ff00,
    // r4 the offset in both halves, r5 and r6 scratch.
    ".macro MSR_ROOM_PAIR op, at",
    "ldr r5, [r0, #\\at]",
    "\\op r5, r5, r4",
    "usub16 r6, r5, r3",
    "sel r5, r3, r5",
    "str r5, [r0, #\\at]",
    ".endm",
    ".section .text.msr_room_apply,\"ax\",%progbits",
    ".global msr_room_apply",
    ".type msr_room_apply,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_room_apply:",
    "push {{r4-r6, lr}}",
    "mov r3, #0xff00ff00",
    "1:",
    "ldrsh r4, [r1], #2",
    "cmp r4, #0",
    "blt 3f",
    "pkhbt r4, r4, r4, lsl #16",
    "MSR_ROOM_PAIR uqadd16, 0",
    "MSR_ROOM_PAIR uqadd16, 4",
    "MSR_ROOM_PAIR uqadd16, 8",
    "MSR_ROOM_PAIR uqadd16, 12",
    "b 4f",
    "3:",
    "neg r4, r4",
    "pkhbt r4, r4, r4, lsl #16",
    "MSR_ROOM_PAIR uqsub16, 0",
    "MSR_ROOM_PAIR uqsub16, 4",
    "MSR_ROOM_PAIR uqsub16, 8",
    "MSR_ROOM_PAIR uqsub16, 12",
    "4:",
    "add r0, r0, #16",
    "subs r2, r2, #1",
    "bne 1b",
    "pop {{r4-r6, pc}}",
    ".size msr_room_apply, . - msr_room_apply",
);
