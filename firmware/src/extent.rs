//! The salient extent of a pooled mask. The pooled test decides (a faint mark adds up over its
//! window), but the window also spreads a mark's salient area by its radius on every side, so
//! the mask covers more face than mark (the paper's a_i / (a_i + a_d) fell from 0.89 to 0.67).
//! [`mark_spread`] keeps the decision and marks [`SPREAD`] the salient pixels whose own error
//! does not pass the same threshold: the components, the winner and its centroid are those of
//! the pooled mask (any non-zero byte is salient), the extent is the pixels left at 1.

/// A pixel salient through its window only (its own error is under the threshold).
pub const SPREAD: u8 = 2;

/// Marks [`SPREAD`] each salient pixel of the `w`-wide `mask` whose own error fails the pooled
/// one-sided test taken with a window of one (`|v(I) - pred| > T`, `lut` the light fit's `v`,
/// `thr` the table of `T`);
/// returns the salient pixels left at 1. Rows with a zero in `row_counts` are empty and not
/// read; the others only up to their last salient pixel.
pub fn mark_spread(frame: &[u8], pred: &[u16], lut: &crate::light::Lut, thr: &[u16], mask: &mut [u8], w: usize, row_counts: &[u16]) -> u32 {
    if w == 0 {
        return 0;
    }
    let n = frame.len().min(pred.len()).min(thr.len()).min(mask.len()) / w * w;
    let mut kept = 0u32;
    for (y, m) in mask[..n].chunks_exact_mut(w).enumerate() {
        let mut left = row_counts.get(y).map_or(usize::MAX, |&c| c as usize);
        if left == 0 {
            continue;
        }
        // Rows of one length: the indexing below needs no bounds checks.
        let at = y * w;
        let (f, p, t) = (&frame[at..at + w], &pred[at..at + w], &thr[at..at + w]);
        let mut x = 0;
        while x < w {
            // Four pixels at a time (one word load on the board): most are empty.
            let end = (x + 4).min(w);
            if end - x == 4 && u32::from_ne_bytes([m[x], m[x + 1], m[x + 2], m[x + 3]]) == 0 {
                x = end;
                continue;
            }
            for i in x..end {
                if m[i] != 0 {
                    left -= 1;
                    let e = crate::light::error(lut, f[i], p[i]);
                    if e.unsigned_abs() > t[i] as u32 {
                        kept += 1;
                    } else {
                        m[i] = SPREAD;
                    }
                }
            }
            if left == 0 {
                break;
            }
            x = end;
        }
    }
    kept
}

/// [`mark_spread`] of one row whose own errors are at hand: `err` is the row of `v(I) - pred`,
/// censored ([`crate::light::error`]), as the pooled routine's ring holds it while the row is
/// tested (one load a salient pixel instead of the frame, the fit's table and the prediction);
/// `salient` of the row's `mask` bytes are non-zero (the scan stops after the last). On the
/// board the pixels go through a Thumb-2 loop, 14 instructions a salient pixel against 18
/// for what LLVM made of [`spread_pixels`] (the benchmark image checks it against
/// [`mark_spread`] before it times anything).
pub fn spread_row(err: &[i32], thr: &[u16], mask: &mut [u8], salient: u32) {
    if salient == 0 {
        return;
    }
    let n = err.len().min(thr.len()).min(mask.len());
    // Empty words before the first salient pixel, four bytes a load (unaligned on the board).
    let x = 4 * crate::blobs::words_while(&mask[..n], |v| v == 0);
    if x == n {
        return;
    }
    #[cfg(target_arch = "arm")]
    {
        let job = SpreadJob {
            err: err[x..n].as_ptr(),
            thr: thr[x..n].as_ptr(),
            mask: mask[x..n].as_mut_ptr(),
            n: (n - x) as u32,
            left: salient,
        };
        // SAFETY: n - x >= 1 values behind each pointer, and the routine reads and writes
        // below n - x only; nothing else holds the slices while it runs.
        unsafe { msr_spread_row(&job) };
    }
    #[cfg(not(target_arch = "arm"))]
    spread_pixels(&err[x..n], &thr[x..n], &mut mask[x..n], salient);
}

/// The pixels of [`spread_row`] from its first salient word on, stopping after the `left`-th
/// salient one: each salient pixel whose own `|err|` is not over its `thr` becomes [`SPREAD`].
pub fn spread_pixels(err: &[i32], thr: &[u16], mask: &mut [u8], mut left: u32) {
    for ((m, &e), &t) in mask.iter_mut().zip(err).zip(thr) {
        if *m == 0 {
            continue;
        }
        if e.unsigned_abs() <= t as u32 {
            *m = SPREAD;
        }
        left -= 1;
        if left == 0 {
            break;
        }
    }
}

/// What the row routine reads.
#[cfg(target_arch = "arm")]
#[repr(C)]
struct SpreadJob {
    err: *const i32,
    thr: *const u16,
    mask: *mut u8,
    /// Pixels behind each pointer (at least one).
    n: u32,
    /// Salient pixels still to come (the loop stops after the last).
    left: u32,
}

#[cfg(target_arch = "arm")]
extern "C" {
    fn msr_spread_row(job: *const SpreadJob);
}

// r0 err, r1 thr, r2 mask, r3 n, r12 left, r5 x, r8 the constant SPREAD. A pixel: 5
// instructions when it is not salient, 14 when it is.
#[cfg(target_arch = "arm")]
core::arch::global_asm!(
    ".section .text.msr_spread_row,\"ax\",%progbits",
    ".global msr_spread_row",
    ".type msr_spread_row,%function",
    ".p2align 2",
    ".thumb_func",
    "msr_spread_row:",
    "push {{r4-r8, lr}}",
    "ldm r0, {{r0-r3, r12}}",
    "movs r5, #0",
    "mov r8, #{spread}",
    "1:",
    "ldrb r4, [r2, r5]",
    "cbnz r4, 3f",
    "2:",
    "add r5, r5, #1",
    "cmp r5, r3",
    "bne 1b",
    "b 9f",
    // |e| (unsigned, as `unsigned_abs`) against T: not over it, the pixel is spread only.
    "3:",
    "ldr r6, [r0, r5, lsl #2]",
    "ldrh r7, [r1, r5, lsl #1]",
    "eor r4, r6, r6, asr #31",
    "sub r4, r4, r6, asr #31",
    "cmp r4, r7",
    "it ls",
    "strbls r8, [r2, r5]",
    "subs r12, r12, #1",
    "bne 2b",
    "9:",
    "pop {{r4-r8, pc}}",
    ".size msr_spread_row, . - msr_spread_row",
    spread = const SPREAD,
);
