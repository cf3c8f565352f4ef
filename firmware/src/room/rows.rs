//! One row of rule 2 (the samples' sums) over a row's whole cells, and rule 4 (the offsets
//! added) over a whole face: Thumb-2 routines on the board, the same steps in Rust elsewhere.
//! The board's routines are checked against the Rust ones by the benchmark image
//! (`msr bench --backend qemu`).
//!
//! On a 75 x 58 face (`msr bench --backend qemu`, the red demo model) the Rust loops took 36.1 k
//! instructions a frame learnt from (rule 2: the table's and the rows' addresses went to the
//! stack) and 49.1 k a new prediction (rule 4); with these routines 18.4 k and 11.5 k, rule 4
//! two values at a time with saturating halfword arithmetic (18.7 k while the rows' loop and
//! their partial last cell were Rust and the clamp took two more instructions a word).

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

/// A cell's offset as rule 4 adds it, two words: in each half of a 32-bit word, a value `p`
/// becomes `p + add` saturated at 65535 (UQADD16), then `- sub` saturated at 0 (UQSUB16). With
/// `add = max(o, 0) + 255` and `sub = max(-o, 0) + 255` that is
/// `(min(p, 65280) + o).clamp(0, 65280)`: the prediction held to the grey range, plus the offset,
/// held to it again, in two instructions for two values and whatever the offset's sign.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packed {
    /// `max(o, 0) + 255` in both halves.
    pub add: u32,
    /// `max(-o, 0) + 255` in both halves.
    pub sub: u32,
}

impl Packed {
    /// Offset 0.
    pub const ZERO: Packed = Packed::of(0);

    /// Offset `o`, Q8.8 grey levels (any i16: `add` and `sub` stay under 2^16).
    pub const fn of(o: i16) -> Packed {
        let o = o as i32;
        let add = (if o > 0 { o } else { 0 }) as u32 + 255;
        let sub = (if o < 0 { -o } else { 0 }) as u32 + 255;
        Packed { add: add * 0x1_0001, sub: sub * 0x1_0001 }
    }

    /// One value, as the routine's halfword arithmetic does it.
    pub fn add_to(self, p: u16) -> u16 {
        let x = (p as u32 + (self.add & 0xffff)).min(0xffff);
        x.saturating_sub(self.sub & 0xffff) as u16
    }
}

/// A whole face for [`apply`]: `rows` rows of `full * CELL + tail` values from `pred`, row `y`
/// taking its offsets from the row of cells `y / CELL`.
#[repr(C)]
pub struct ApplyJob {
    /// The face's first predicted value (Q8.8); any halfword alignment.
    pub pred: *mut u16,
    /// The first row of cells (4-byte aligned, as `Packed` is): two entries a cell, one for
    /// each half ([`super::Room::halves`]); this routine reads the first.
    pub cells: *const Packed,
    /// Whole cells a row.
    pub full: u32,
    /// Values past them in a row (`0..CELL`), which take the next cell's offset.
    pub tail: u32,
    /// Rows of values, at least 1.
    pub rows: u32,
    /// Bytes from one row of cells to the next.
    pub stride: u32,
}

/// Rule 4 over a face: each value's cell offset added ([`Packed`]).
///
/// # Safety
/// `rows >= 1`, `tail < CELL`; `rows * (full * CELL + tail)` values behind `pred`; behind `cells`,
/// `rows.div_ceil(CELL)` rows of cells `stride` bytes apart, each of `full` cells (two entries
/// each) and one more when `tail > 0`.
#[inline]
pub unsafe fn apply(job: &ApplyJob) {
    #[cfg(target_arch = "arm")]
    // SAFETY: the caller's contract; the routine keeps AAPCS.
    unsafe {
        msr_room_apply(job)
    }
    #[cfg(not(target_arch = "arm"))]
    // SAFETY: the caller's contract.
    unsafe {
        apply_reference(job)
    }
}

/// [`apply`] in Rust.
///
/// # Safety
/// As [`apply`].
pub unsafe fn apply_reference(job: &ApplyJob) {
    let w = job.full as usize * CELL + job.tail as usize;
    for y in 0..job.rows as usize {
        // SAFETY: inside the caller's face and rows of cells.
        unsafe {
            let cells = job.cells.cast::<u8>().add((y / CELL) * job.stride as usize).cast::<Packed>();
            for x in 0..w {
                let p = job.pred.add(y * w + x);
                *p = (*cells.add(2 * (x / CELL))).add_to(*p);
            }
        }
    }
}

#[cfg(target_arch = "arm")]
extern "C" {
    fn msr_room_gather(job: *const GatherJob);
    fn msr_room_apply(job: *const ApplyJob);
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
    // Rule 4 over a face, two values a word (`Packed`): UQADD16 then UQSUB16. Loads and stores
    // of a row's words may be unaligned (an odd row of an odd width); LDRD of a cell is not. A
    // row that starts on a word takes its whole cells by one LDM and one STM each (13
    // instructions a cell, 19 a word at a time; LDM and STM fault unaligned, so the other rows
    // go a word at a time). r4 pred, r5 the row of cells, r7 tail, r8 rows left, r9 stride,
    // r10 rows left in this row of cells, r11 the cell, r12 cells left, r0 and r1 the cell's
    // add and sub, r2, r3, r6 and lr scratch; `full` on the stack.
    ".macro MSR_ROOM_PAIRS at",
    "ldr r2, [r4, #\\at]",
    "ldr r3, [r4, #\\at + 4]",
    "uqadd16 r2, r2, r0",
    "uqadd16 r3, r3, r0",
    "uqsub16 r2, r2, r1",
    "uqsub16 r3, r3, r1",
    "str r2, [r4, #\\at]",
    "str r3, [r4, #\\at + 4]",
    ".endm",
    ".section .text.msr_room_apply,\"ax\",%progbits",
    ".global msr_room_apply",
    ".type msr_room_apply,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_room_apply:",
    "push {{r4-r11, lr}}",
    "ldm r0, {{r4-r9}}",
    "push {{r6}}",
    "mov r10, #8",
    // A row: its whole cells, then its tail.
    "1:",
    "mov r11, r5",
    "ldr r12, [sp]",
    "cmp r12, #0",
    "beq 3f",
    "tst r4, #2",
    "bne 2f",
    "7:",
    "ldrd r0, r1, [r11], #16",
    "ldm r4, {{r2, r3, r6, lr}}",
    "uqadd16 r2, r2, r0",
    "uqadd16 r3, r3, r0",
    "uqadd16 r6, r6, r0",
    "uqadd16 lr, lr, r0",
    "uqsub16 r2, r2, r1",
    "uqsub16 r3, r3, r1",
    "uqsub16 r6, r6, r1",
    "uqsub16 lr, lr, r1",
    "stmia r4!, {{r2, r3, r6, lr}}",
    "subs r12, r12, #1",
    "bne 7b",
    "b 3f",
    "2:",
    "ldrd r0, r1, [r11], #16",
    "ldr lr, [r4]",
    "uqadd16 lr, lr, r0",
    "uqsub16 lr, lr, r1",
    "ldr r2, [r4, #4]",
    "uqadd16 r2, r2, r0",
    "uqsub16 r2, r2, r1",
    "str r2, [r4, #4]",
    "MSR_ROOM_PAIRS 8",
    // The first word last, its store stepping to the next cell.
    "str lr, [r4], #16",
    "subs r12, r12, #1",
    "bne 2b",
    // The tail: its pairs a word at a time, then an odd value alone.
    "3:",
    "cbz r7, 5f",
    "ldrd r0, r1, [r11]",
    "lsrs r12, r7, #1",
    "beq 6f",
    "4:",
    "ldr r2, [r4]",
    "uqadd16 r2, r2, r0",
    "uqsub16 r2, r2, r1",
    "str r2, [r4], #4",
    "subs r12, r12, #1",
    "bne 4b",
    "6:",
    "tst r7, #1",
    "beq 5f",
    "ldrh r2, [r4]",
    "uqadd16 r2, r2, r0",
    "uqsub16 r2, r2, r1",
    "strh r2, [r4], #2",
    // The next row; every CELL rows, the next row of cells.
    "5:",
    "subs r10, r10, #1",
    "itt eq",
    "addeq r5, r5, r9",
    "moveq r10, #8",
    "subs r8, r8, #1",
    "bne 1b",
    "add sp, sp, #4",
    "pop {{r4-r11, pc}}",
    ".size msr_room_apply, . - msr_room_apply",
);
