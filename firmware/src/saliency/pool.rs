//! The pooled one-sided saliency (the default test of a pooled model), row by row in one
//! assembly routine on the Cortex-M4, the same steps in Rust elsewhere.
//!
//! The test: pixel `x` is salient when the magnitude of the mean of the signed error
//! `v(I) - pred` (Q8.8; `v` the frame's photometric fit, [`crate::light`], `I << 8` unfitted) over the `(2 r + 1)^2` window, clipped at the border, exceeds
//! `mu + tn`: `|s| > T k`, with `s` the window's sum, `k` its pixels and `T = min(mu + tn, 65535)` per
//! pixel in the threshold table ([`combined_table`]; `tn` is `t` sigma in Q8.8, rounded down).
//! The mean is not rounded, and a saturated `T` never fires.
//!
//! Per row ([`pooled_one_sided`]), with the column sums of the window's rows kept between rows:
//! 1. each column's sum takes in the error of row `y + r` and gives up that of row `y - r - 1`,
//!    which a ring of `2 r + 1` error rows still holds (each error is computed once);
//! 2. the window sum slides along the row, a column in, a column out, and each pixel is tested.
//!
//! Both steps run in one pass, a column's update `r` pixels ahead of the test that first needs
//! it: 19 instructions a pixel inside the row, 17 for the default radius of 2, whose pixels
//! go in pairs with the ring and the column sums read and written two words at a time, two
//! pairs a loop step (the routine's comments count them), against 39 for the two loops LLVM
//! made of the Rust; the
//! row's salient pixels are counted at its end, four mask bytes an instruction. The edges take
//! the clipped window's `k`. The table is made again when the head changes pose cell: 2.5
//! instructions a pixel, eight at a time, with no range check (the model's largest sigma,
//! found once, bounds them all). The benchmark image checks the routine against
//! [`reference()`] on random faces of every radius before it times anything.

use msr_shared::blob::{Normalisation, MAX_FACE_W, MAX_POOL};

use super::threshold_q88;

/// Zero columns on either side of the column sums: one more than the largest radius, so that
/// the column leaving the window at `x = 0` is one of them.
pub const PAD: usize = MAX_POOL as usize + 1;

/// Rows past the face's bottom, as frame bytes: their error is zero against a prediction row
/// of `v(0)`.
static ZERO_ROW: [u16; MAX_FACE_W] = [0; MAX_FACE_W];

/// What the row routine reads (see its prologue).
#[repr(C)]
struct RowJob {
    /// Row `y + r` of the frame (or zeros past the bottom).
    frame: *const u8,
    /// The same row of the prediction, Q8.8.
    pred: *const u16,
    /// The ring's row for `y + r`: holds row `y - r - 1`'s errors (or zeros), gets row `y + r`'s.
    ring: *mut i32,
    /// Column 0 of the column sums, with [`PAD`] zero columns before and after.
    cols: *mut i32,
    /// Row `y` of the combined thresholds `T`.
    thr: *const u16,
    /// Row `y` of the mask.
    mask: *mut u8,
    w: u32,
    r: u32,
    /// Rows inside the window (fewer at the top and bottom).
    rows: u32,
    /// Non-zero: only take row `y + r` into the column sums (the rows above the first output).
    prime: u32,
    /// The frame's fitted grey levels `v(I)`, 256 entries, Q8.8 ([`crate::light`]).
    lut: *const u16,
}

/// One row; returns its salient pixels. The caller guarantees `w > 2 r`, `1 <= r <= MAX_POOL`,
/// `w` bytes/values/words behind each row pointer, and `cols` with `PAD` columns either side.
#[cfg(target_arch = "arm")]
unsafe fn run_row(job: &RowJob) -> u32 {
    // SAFETY: the caller's contract above; the routine keeps AAPCS.
    unsafe { msr_pool_row(job) }
}

#[cfg(target_arch = "arm")]
extern "C" {
    fn msr_pool_row(job: *const RowJob) -> u32;
    fn msr_pool_table(job: *const TableJob);
}

// Registers in the row: r0 frame, r1 pred, r2 ring, r3 the column entering (x + r), r4 T,
// r5 mask, r6 the column leaving (x - r - 1), r7 the window sum, r8 the count (at the end; a
// scratch register in the pairs), r9 k, r10 and r11 scratch, r12 the phase's end, lr the fit's table. On the stack: r, w, prime (then the end of the
// inside), rows.
#[cfg(target_arch = "arm")]
core::arch::global_asm!(
    // Column x + r takes row y + r in and row y - r - 1 out (11 instructions).
    ".macro MSR_POOL_COLUMN",
    "ldrb r10, [r0], #1",
    "ldrh r10, [lr, r10, lsl #1]",
    "ldrh r11, [r1], #2",
    "sub r10, r10, r11",
    "ldr r11, [r2]",
    "str r10, [r2], #4",
    "sub r10, r10, r11",
    "ldr r11, [r3]",
    "add r11, r11, r10",
    "str r11, [r3], #4",
    ".endm",
    // The test of pixel x once the window sum is in r7: T k - |s| < 0 (6 instructions; the
    // row's salient pixels are counted at its end).
    ".macro MSR_POOL_TEST",
    "eor r10, r7, r7, asr #31",
    "rsb r10, r10, r7, asr #31",
    "ldrh r11, [r4], #2",
    "mla r10, r11, r9, r10",
    "lsr r10, r10, #31",
    "strb r10, [r5], #1",
    ".endm",
    // A whole pixel: its column in, the window slid, the test (19 instructions).
    ".macro MSR_POOL_PIXEL",
    "MSR_POOL_COLUMN",
    "add r7, r7, r11",
    "ldr r11, [r6], #4",
    "sub r7, r7, r11",
    "MSR_POOL_TEST",
    ".endm",
    // Two pixels x, x + 1 inside the row for a radius of 2 (33 instructions): columns x + 2
    // and x + 3 in, their ring words and sums read and written as pairs (LDRD/STRD); r3 then
    // points at column x + 4, so the columns leaving, x - 3 and x - 2, are the pair 28 bytes
    // back, read at once too. r6 and r8 are scratch here.
    ".macro MSR_POOL_PAIR2",
    "ldrb r10, [r0], #1",
    "ldrb r11, [r0], #1",
    "ldrh r10, [lr, r10, lsl #1]",
    "ldrh r11, [lr, r11, lsl #1]",
    "ldrh r6, [r1], #2",
    "sub r10, r10, r6",
    "ldrh r6, [r1], #2",
    "sub r11, r11, r6",
    "ldrd r6, r8, [r2]",
    "strd r10, r11, [r2], #8",
    "sub r10, r10, r6",
    "sub r11, r11, r8",
    "ldrd r6, r8, [r3]",
    "add r6, r6, r10",
    "add r8, r8, r11",
    "strd r6, r8, [r3], #8",
    // The window's two steps: r6 = c(x + 2) - c(x - 3), r8 = c(x + 3) - c(x - 2).
    "ldrd r10, r11, [r3, #-28]",
    "sub r6, r6, r10",
    "sub r8, r8, r11",
    "add r7, r7, r6",
    "MSR_POOL_TEST",
    "add r7, r7, r8",
    "MSR_POOL_TEST",
    ".endm",
    ".section .text.msr_pool_row,\"ax\",%progbits",
    ".global msr_pool_row",
    ".type msr_pool_row,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_pool_row:",
    "push {{r4-r11, lr}}",
    "ldr r9, [r0, #28]",
    "ldr r10, [r0, #24]",
    "ldr r11, [r0, #36]",
    "ldr r12, [r0, #32]",
    "push {{r9-r12}}",
    "ldr lr, [r0, #40]",
    "ldm r0, {{r0-r5}}",
    "movs r7, #0",
    "mov r8, #0",
    // The column leaving the window of x = 0: -r - 1.
    "add r6, r9, #1",
    "sub r6, r3, r6, lsl #2",
    // 1. Columns 0 .. r (all w when priming) into the sums; the window of x = -1 is their sum.
    "cmp r11, #0",
    "ite ne",
    "movne r12, r10",
    "moveq r12, r9",
    "add r12, r3, r12, lsl #2",
    "1:",
    "MSR_POOL_COLUMN",
    "add r7, r7, r11",
    "cmp r3, r12",
    "bne 1b",
    "ldr r11, [sp, #8]",
    "cmp r11, #0",
    "bne 9f",
    // 2. The left edge, x < r: k = rows (x + r + 1).
    "ldr r12, [sp, #12]",
    "ldr r10, [sp]",
    "add r9, r10, #1",
    "mul r9, r9, r12",
    "add r12, r5, r10",
    "2:",
    "MSR_POOL_PIXEL",
    "ldr r10, [sp, #12]",
    "add r9, r9, r10",
    "cmp r5, r12",
    "bne 2b",
    // 3. The inside, k = rows (2 r + 1): w - 2 r pixels. A radius of 2 (the default pool):
    //    an odd one first, then a pair if the rest is not a multiple of four, then two pairs
    //    a step; any other: (w - 2 r) % 4 single ones first, then fours.
    "ldr r10, [sp, #4]",
    "ldr r11, [sp]",
    "sub r10, r10, r11, lsl #1",
    "add r12, r5, r10",
    "cmp r11, #2",
    "bne 20f",
    "tst r10, #1",
    "beq 21f",
    "MSR_POOL_PIXEL",
    "21:",
    "sub r10, r12, r5",
    "tst r10, #2",
    "beq 24f",
    "MSR_POOL_PAIR2",
    "24:",
    "cmp r5, r12",
    "beq 22f",
    "23:",
    "MSR_POOL_PAIR2",
    "MSR_POOL_PAIR2",
    "cmp r5, r12",
    "bne 23b",
    "22:",
    // The columns leaving for the right edge: x - 3 for r3 at x + 2.
    "sub r6, r3, #20",
    "b 4f",
    "20:",
    "ands r10, r10, #3",
    "beq 3f",
    "str r12, [sp, #8]",
    "add r12, r5, r10",
    "11:",
    "MSR_POOL_PIXEL",
    "cmp r5, r12",
    "bne 11b",
    "ldr r12, [sp, #8]",
    "3:",
    "cmp r5, r12",
    "beq 4f",
    "5:",
    "MSR_POOL_PIXEL",
    "MSR_POOL_PIXEL",
    "MSR_POOL_PIXEL",
    "MSR_POOL_PIXEL",
    "cmp r5, r12",
    "bne 5b",
    "4:",
    // 4. The right edge, x >= w - r: no column comes in; k = rows (w - x + r).
    "ldr r10, [sp]",
    "add r12, r5, r10",
    "6:",
    "ldr r10, [sp, #12]",
    "sub r9, r9, r10",
    "ldr r11, [r6], #4",
    "sub r7, r7, r11",
    "MSR_POOL_TEST",
    "cmp r5, r12",
    "bne 6b",
    // 5. The row's salient pixels (its mask bytes are 0 or 1): USADA8 adds four bytes a word,
    //    four words a loop step, then the words left, then the bytes left.
    "ldr r10, [sp, #4]",
    "sub r0, r5, r10",
    "movs r6, #0",
    "mov r8, #0",
    "lsrs r1, r10, #4",
    "beq 14f",
    "15:",
    "ldr r11, [r0], #4",
    "usada8 r8, r11, r6, r8",
    "ldr r11, [r0], #4",
    "usada8 r8, r11, r6, r8",
    "ldr r11, [r0], #4",
    "usada8 r8, r11, r6, r8",
    "ldr r11, [r0], #4",
    "usada8 r8, r11, r6, r8",
    "subs r1, r1, #1",
    "bne 15b",
    "14:",
    "ubfx r1, r10, #2, #2",
    "cbz r1, 7f",
    "12:",
    "ldr r11, [r0], #4",
    "usada8 r8, r11, r6, r8",
    "subs r1, r1, #1",
    "bne 12b",
    "7:",
    "cmp r0, r5",
    "beq 9f",
    "13:",
    "ldrb r11, [r0], #1",
    "add r8, r8, r11",
    "cmp r0, r5",
    "bne 13b",
    "9:",
    "mov r0, r8",
    "add sp, sp, #16",
    "pop {{r4-r11, pc}}",
    ".size msr_pool_row, . - msr_pool_row",
    // The combined table, eight pixels a step (19 instructions): four sigma pairs by LDM,
    // tn = floor(tq sigma / 2^16) of each by SMULWB/SMULWT, paired, added to the mu pairs
    // saturating, stored by STM. No range checks: the caller knows every sigma is under 2^15
    // and every tn under 2^16. An odd step first, then two at a time. r0 sigma, r1 mu, r2 out,
    // r3 the double steps, r12 tq, lr scratch.
    ".macro MSR_POOL_T8",
    "ldm r0!, {{r4-r7}}",
    "smulwb lr, r12, r4",
    "smulwt r4, r12, r4",
    "pkhbt r4, lr, r4, lsl #16",
    "smulwb lr, r12, r5",
    "smulwt r5, r12, r5",
    "pkhbt r5, lr, r5, lsl #16",
    "smulwb lr, r12, r6",
    "smulwt r6, r12, r6",
    "pkhbt r6, lr, r6, lsl #16",
    "smulwb lr, r12, r7",
    "smulwt r7, r12, r7",
    "pkhbt r7, lr, r7, lsl #16",
    "ldm r1!, {{r8-r11}}",
    "uqadd16 r4, r4, r8",
    "uqadd16 r5, r5, r9",
    "uqadd16 r6, r6, r10",
    "uqadd16 r7, r7, r11",
    "stm r2!, {{r4-r7}}",
    ".endm",
    ".section .text.msr_pool_table,\"ax\",%progbits",
    ".global msr_pool_table",
    ".type msr_pool_table,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_pool_table:",
    "push {{r4-r11, lr}}",
    "ldm r0, {{r0-r3, r12}}",
    "lsrs r3, r3, #1",
    "bcc 8f",
    "MSR_POOL_T8",
    // The flags are still those of LSRS (the steps set none).
    "8:",
    "beq 9f",
    "10:",
    "MSR_POOL_T8",
    "MSR_POOL_T8",
    "subs r3, r3, #1",
    "bne 10b",
    "9:",
    "pop {{r4-r11, pc}}",
    ".size msr_pool_table, . - msr_pool_table",
    ".purgem MSR_POOL_COLUMN",
    ".purgem MSR_POOL_TEST",
    ".purgem MSR_POOL_PIXEL",
    ".purgem MSR_POOL_PAIR2",
    ".purgem MSR_POOL_T8",
);

/// The routine's steps in Rust, in the same order, for builds that are not the board's.
#[cfg(not(target_arch = "arm"))]
unsafe fn run_row(job: &RowJob) -> u32 {
    let (w, r) = (job.w as usize, job.r as usize);
    // SAFETY: the caller's contract on `run_row` (w values behind each row pointer; PAD
    // columns either side of `cols`).
    let (frame, pred, ring, thr, mask, cols, lut) = unsafe {
        (
            core::slice::from_raw_parts(job.frame, w),
            core::slice::from_raw_parts(job.pred, w),
            core::slice::from_raw_parts_mut(job.ring, w),
            core::slice::from_raw_parts(job.thr, w),
            core::slice::from_raw_parts_mut(job.mask, w),
            core::slice::from_raw_parts_mut(job.cols.sub(PAD), w + 2 * PAD),
            core::slice::from_raw_parts(job.lut, 256),
        )
    };
    // Column j takes row y + r in and row y - r - 1 out; returns its new sum.
    let column = |j: usize, cols: &mut [i32], ring: &mut [i32]| {
        let e = lut[frame[j] as usize] as i32 - pred[j] as i32;
        let c = &mut cols[PAD + j];
        *c = c.wrapping_add(e.wrapping_sub(ring[j]));
        ring[j] = e;
        *c
    };
    let mut sum = 0i32;
    for j in 0..if job.prime != 0 { w } else { r } {
        sum = sum.wrapping_add(column(j, cols, ring));
    }
    if job.prime != 0 {
        return 0;
    }
    let rows = job.rows as i32;
    let mut count = 0u32;
    let mut k = rows.wrapping_mul(r as i32 + 1);
    for x in 0..w {
        if x + r < w {
            sum = sum.wrapping_add(column(x + r, cols, ring));
        } else {
            k = k.wrapping_sub(rows);
        }
        sum = sum.wrapping_sub(cols[PAD + x - (r + 1)]);
        let a = (sum ^ (sum >> 31)).wrapping_sub(sum >> 31);
        let d = (thr[x] as i32).wrapping_mul(k).wrapping_sub(a);
        let s = (d as u32 >> 31) as u8;
        mask[x] = s;
        count += s as u32;
        if x < r {
            k = k.wrapping_add(rows);
        }
    }
    count
}

/// What the table routine reads.
#[cfg(target_arch = "arm")]
#[repr(C)]
struct TableJob {
    sigma: *const u16,
    mu: *const u16,
    out: *mut u16,
    /// Steps of eight pixels.
    steps: u32,
    tq: u32,
}

/// How `T = min(mu + tn, 65535)` is made from a pixel's sigma and mu, `tn` being `t` times the
/// normalisation in Q8.8: for [`Normalisation::StdDev`] (the default) `floor(sigma tq / 2^16)`
/// with `tq = round(t 2^16)` (one multiply a pixel; within one Q8.8 step under `t sigma`, give
/// or take `sigma / 2^17`), for
/// [`Normalisation::Variance`] [`threshold_q88`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Combine {
    t: f32,
    normalisation: Normalisation,
    /// `round(t 2^16)`, saturating.
    tq: u64,
}

impl Combine {
    /// The rule for threshold `t` and `normalisation`.
    pub fn new(t: f32, normalisation: Normalisation) -> Combine {
        // Scaling by 2^16 is exact in f32; `as` saturates (NaN gives 0).
        let tq = (t * 65536.0 + 0.5) as u64;
        Combine { t, normalisation, tq }
    }

    /// Whether the board's routine computes `T` of every sigma up to `sigma_max` without a
    /// range check: `tn` by `SMULWB`/`SMULWT` (sigma under 2^15, `tq` under 2^31) fits a
    /// halfword.
    #[cfg_attr(not(target_arch = "arm"), allow(dead_code))]
    fn packs(&self, sigma_max: u16) -> bool {
        self.normalisation == Normalisation::StdDev
            && self.tq < 1 << 31
            && sigma_max < 1 << 15
            && (sigma_max as u64 * self.tq) >> 16 <= 0xFFFF
    }

    /// [`Combine::at`] where [`Combine::packs`] holds for `sigma` (`tn` then fits 16 bits, so
    /// neither the product nor the sum needs saturating): the routine's last pixels, at a
    /// quarter of `at`'s instructions.
    #[cfg_attr(not(target_arch = "arm"), allow(dead_code))]
    fn at_packed(&self, sigma: u16, mu: u16) -> u16 {
        ((((sigma as u64 * self.tq) >> 16) as u32 + mu as u32).min(0xFFFF)) as u16
    }

    /// `T` of one pixel.
    pub fn at(&self, sigma: u16, mu: u16) -> u16 {
        let tn = match self.normalisation {
            Normalisation::StdDev => (sigma as u64).saturating_mul(self.tq) >> 16,
            Normalisation::Variance => threshold_q88(sigma, self.t, self.normalisation) as u64,
        };
        tn.saturating_add(mu as u64).min(0xFFFF) as u16
    }
}

/// [`Combine::at`] for each pixel; `sigma`, `mu` and `out` run to the shortest. `sigma_max` is
/// a bound the caller knows (every sigma is at most it; `u16::MAX` when unknown). On the board,
/// eight pixels at a time through `SMULWB`/`SMULWT` and saturating halfword adds with no range
/// check, when the bound keeps every `tn` under 2^16 and every sigma under 2^15 (so `SMULW`
/// reads it as positive) and the three tables are word-aligned; else the Rust loop.
#[cfg_attr(not(target_arch = "arm"), allow(unused_variables))]
pub fn combined_table(sigma: &[u16], mu: &[u16], c: &Combine, sigma_max: u16, out: &mut [u16]) {
    let n = sigma.len().min(mu.len()).min(out.len());
    let (sigma, mu, out) = (&sigma[..n], &mu[..n], &mut out[..n]);
    #[cfg(target_arch = "arm")]
    if c.packs(sigma_max)
        && [sigma.as_ptr() as usize, mu.as_ptr() as usize, out.as_ptr() as usize].iter().all(|a| a % 4 == 0)
    {
        let job = TableJob {
            sigma: sigma.as_ptr(),
            mu: mu.as_ptr(),
            out: out.as_mut_ptr(),
            steps: (n / 8) as u32,
            tq: c.tq as u32,
        };
        // SAFETY: 8 * steps <= n values behind each pointer, each pointer word-aligned (LDM and
        // STM need it).
        unsafe { msr_pool_table(&job) };
        let n8 = n / 8 * 8;
        for ((o, &s), &m) in out[n8..].iter_mut().zip(&sigma[n8..]).zip(&mu[n8..]) {
            *o = c.at_packed(s, m);
        }
        return;
    }
    for ((o, &s), &m) in out.iter_mut().zip(sigma).zip(mu) {
        *o = c.at(s, m);
    }
}

/// [`combined_table`] with each sigma widened by the frame's floor `f` (Q8.8,
/// [`crate::floor::widen`]): `T = Combine::at(widen(sigma, f), mu)`. The standard-deviation
/// rule whose `tq` fits 32 bits (every threshold up to 65535) skips `at`'s saturating 64-bit
/// multiply, which no product of a 16-bit sigma reaches: on the board 179 k instructions for a
/// 58 x 75 face against 257 k through `at`.
pub fn widened_table(sigma: &[u16], mu: &[u16], c: &Combine, f: u16, out: &mut [u16]) {
    let ff = f as f32 * f as f32;
    let pairs = out.iter_mut().zip(sigma.iter().zip(mu));
    if c.normalisation == Normalisation::StdDev && c.tq <= u32::MAX as u64 {
        let tq = c.tq;
        for (o, (&s, &m)) in pairs {
            let w = crate::floor::widen_sq(s, ff);
            // w < 2^16 and tq < 2^32: the product fits 48 bits, the sum 33.
            *o = (((w as u64 * tq) >> 16) + m as u64).min(0xFFFF) as u16;
        }
    } else {
        for (o, (&s, &m)) in pairs {
            *o = c.at(crate::floor::widen_sq(s, ff), m);
        }
    }
}

/// The pooled one-sided mask of a `w`-wide face (rows: the shortest input / `w`) against the
/// table `thr` ([`combined_table`]); returns the salient pixels and writes each row's
/// count to `row_counts` (as many rows as it holds). `ring` needs `(2 pool + 1) w` words. A
/// face no wider than the window, a radius of 0 or past [`MAX_POOL`], a width past
/// [`MAX_FACE_W`] or a short ring take [`reference()`] (same result, slower). `lut` is the
/// frame's fitted grey levels ([`crate::light::LightFit::table`]). With `extent`, each row's
/// salient pixels whose own error fails the test are marked [`crate::extent::SPREAD`] as the
/// row is done ([`crate::extent::spread_row`], from the ring: the same mask as
/// [`crate::extent::mark_spread`] after).
#[allow(clippy::too_many_arguments)]
pub fn pooled_one_sided(
    frame: &[u8],
    pred: &[u16],
    lut: &crate::light::Lut,
    thr: &[u16],
    mask: &mut [u8],
    ring: &mut [i32],
    w: usize,
    pool: u8,
    row_counts: &mut [u16],
    extent: bool,
) -> u32 {
    let r = pool as usize;
    if w == 0 || w > MAX_FACE_W {
        return 0;
    }
    let n = frame.len().min(pred.len()).min(thr.len()).min(mask.len()) / w * w;
    let h = n / w;
    let slots = 2 * r + 1;
    if r == 0 || pool > MAX_POOL || w <= 2 * r || ring.len() < slots * w {
        let count = reference(&frame[..n], &pred[..n], lut, &thr[..n], &mut mask[..n], w, pool);
        for (y, c) in row_counts.iter_mut().enumerate().take(h) {
            *c = mask[y * w..y * w + w].iter().filter(|&&m| m != 0).count() as u16;
        }
        if extent {
            crate::extent::mark_spread(&frame[..n], &pred[..n], lut, &thr[..n], &mut mask[..n], w, row_counts);
        }
        return count;
    }
    let ring = &mut ring[..slots * w];
    ring.fill(0);
    let mut cols = [0i32; MAX_FACE_W + 2 * PAD];
    let (fp, rp) = (frame.as_ptr(), ring.as_mut_ptr());
    let (tp, mp) = (thr.as_ptr(), mask.as_mut_ptr());
    let mut job = RowJob {
        frame: fp,
        pred: pred.as_ptr(),
        ring: rp,
        cols: cols[PAD..].as_mut_ptr(),
        thr: tp,
        mask: mp,
        w: w as u32,
        r: r as u32,
        rows: 0,
        prime: 1,
        lut: lut.v.as_ptr(),
    };
    // Both calls below: every pointer is at a row inside the slices checked above (h rows of
    // w, slots rows of w in the ring, ZERO_ROW's w, `censored`'s MAX_FACE_W >= w), `cols` has PAD columns either side of w,
    // 1 <= r <= MAX_POOL and w > 2 r: `run_row`'s contract.
    // Rows 0 .. r into the column sums and ring slots 0 .. r before the first output row.
    // A row with clipped pixels reads its prediction censored ([`crate::light::censor_row`]).
    let mut censored = [0u16; MAX_FACE_W];
    // Most frames have no clipped pixel at all: one test of the whole frame spares each row's.
    let clipped = crate::light::any_clipped(&frame[..n], lut);
    // The rare clipped frame's rows out of line; the others a pointer, here.
    let pp = pred.as_ptr();
    let mut pred_row = |y: usize| if clipped { pred_row(frame, pred, lut, y, w, &mut censored) } else { pp.wrapping_add(y * w) };
    for y in 0..r.min(h) {
        job.frame = fp.wrapping_add(y * w);
        job.pred = pred_row(y);
        job.ring = rp.wrapping_add(y * w);
        // SAFETY: see above.
        unsafe { run_row(&job) };
    }
    job.prime = 0;
    let zero = ZERO_ROW.as_ptr();
    // Past the bottom: frame 0 against a prediction of v(0), an error of zero.
    let below = [lut.v[0]; MAX_FACE_W];
    // Row y + r comes in; its slot, (y + r) mod slots, held row y - r - 1.
    let (mut slot, mut count) = (r, 0u32);
    for y in 0..h {
        let yin = y + r;
        (job.frame, job.pred) = if yin < h {
            (fp.wrapping_add(yin * w), pred_row(yin))
        } else {
            (zero as *const u8, below.as_ptr())
        };
        job.ring = rp.wrapping_add(slot * w);
        job.thr = tp.wrapping_add(y * w);
        job.mask = mp.wrapping_add(y * w);
        job.rows = (yin.min(h - 1) + 1 - y.saturating_sub(r)) as u32;
        // SAFETY: see above.
        let c = unsafe { run_row(&job) };
        if let Some(rc) = row_counts.get_mut(y) {
            *rc = c as u16;
        }
        if extent && c > 0 {
            // Row y's own errors are still in the ring (slot y mod slots; they leave when row
            // y + r + 1 comes in).
            // SAFETY: slot (y mod slots) of the ring and row y of thr and mask, w values each
            // (see above); the routine that wrote them has returned, nothing else holds them.
            let (e, t, m) = unsafe {
                (
                    core::slice::from_raw_parts(rp.wrapping_add((y % slots) * w), w),
                    core::slice::from_raw_parts(tp.wrapping_add(y * w), w),
                    core::slice::from_raw_parts_mut(mp.wrapping_add(y * w), w),
                )
            };
            crate::extent::spread_row(e, t, m, c);
        }
        count += c;
        slot = if slot + 1 == slots { 0 } else { slot + 1 };
    }
    count
}

/// Row `y` of the prediction, or its censored copy in `buf` when the frame's row is clipped.
#[inline(never)]
fn pred_row(frame: &[u8], pred: &[u16], lut: &crate::light::Lut, y: usize, w: usize, buf: &mut [u16; MAX_FACE_W]) -> *const u16 {
    let (f, p) = (&frame[y * w..y * w + w], &pred[y * w..y * w + w]);
    if crate::light::censor_row(f, p, lut, &mut buf[..w]) {
        buf.as_ptr()
    } else {
        p.as_ptr()
    }
}

/// The same mask written out plainly: each pixel's clipped window summed, `|s| > T k`.
#[inline(never)]
pub fn reference(frame: &[u8], pred: &[u16], lut: &crate::light::Lut, thr: &[u16], mask: &mut [u8], w: usize, pool: u8) -> u32 {
    if w == 0 || pool > MAX_POOL {
        return 0;
    }
    let n = frame.len().min(pred.len()).min(thr.len()).min(mask.len()) / w * w;
    let (h, r) = (n / w, pool as usize);
    let mut count = 0;
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut k) = (0i64, 0i64);
            for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                    let i = yy * w + xx;
                    s += crate::light::error(lut, frame[i], pred[i]) as i64;
                    k += 1;
                }
            }
            let m = (s.abs() > thr[y * w + x] as i64 * k) as u8;
            mask[y * w + x] = m;
            count += m as u32;
        }
    }
    count
}

#[cfg(test)]
mod tests;
