//! The light routines' Cortex-M4 assembly ([`ramp`], [`any_clipped`], [`sample_levels`]), and the
//! same functions in plain Rust for every other build.

pub use imp::{any_clipped, ramp, sample_levels};

#[cfg(target_arch = "arm")]
mod imp {
    use super::super::{Lut, MAX_SAMPLES};

    /// [`ramp_reference`](super::super::ramp_reference); on the board two entries a step, 4.5 instructions an entry where the
    /// compiled loop took 10 (a frame's table: 3.1 k instructions, 0.7 a pixel): `USAT` clamps
    /// each to 0..65535, and the pair's excess over `V_MAX` (`UQSUB16`) is taken back (`USUB16`).
    pub fn ramp(out: &mut [u16; 256], first: i32, gain: i32) {
        // SAFETY: 256 halfwords behind `out`, written as 128 words (the Cortex-M4 takes the
        // unaligned ones); the routine touches nothing else and keeps AAPCS.
        unsafe { msr_fit_ramp(out.as_mut_ptr(), first, gain) }
    }


    extern "C" {
        fn msr_fit_ramp(out: *mut u16, first: i32, gain: i32);
    }

    // r0 the table, r1 the accumulator, r2 the gain, r3 the steps left (64 of four entries),
    // r12 V_MAX in both halves, r4 and r5 scratch.
    core::arch::global_asm!(
        ".macro MSR_FIT_RAMP2",
        "usat r4, #16, r1, asr #8",
        "add r1, r1, r2",
        "usat r5, #16, r1, asr #8",
        "add r1, r1, r2",
        "pkhbt r4, r4, r5, lsl #16",
        "uqsub16 r5, r4, r12",
        "usub16 r4, r4, r5",
        "str r4, [r0], #4",
        ".endm",
        ".section .text.msr_fit_ramp,\"ax\",%progbits",
        ".global msr_fit_ramp",
        ".type msr_fit_ramp,%function",
        ".p2align 2",
        ".thumb_func",
        "msr_fit_ramp:",
        "push {{r4, r5}}",
        "movs r3, #64",
        "mov r12, #0xFF00FF00",
        "1:",
        "MSR_FIT_RAMP2",
        "MSR_FIT_RAMP2",
        "subs r3, r3, #1",
        "bne 1b",
        "pop {{r4, r5}}",
        "bx lr",
        ".size msr_fit_ramp, . - msr_fit_ramp",
        ".purgem MSR_FIT_RAMP2",
    );

    /// Whether a byte of `row` is at or past a clip level of `lut` (`<= lo` or `>= hi`), four at a
    /// time (asked of the whole frame, then of each row when the frame has one: a byte at a time
    /// took 7 instructions a pixel on the board, a word test in Rust 2.9, the board's routine 1.15).
    #[inline]
    pub fn any_clipped(row: &[u8], lut: &Lut) -> bool {
        let (lo, hi) = (lut.lo, lut.hi);
        if hi <= lo.saturating_add(1) {
            return !row.is_empty();
        }
        let words = row.len() / 4;
        // `b - hi` (wrapping) puts the levels strictly between lo and hi at 257 - (hi - lo) ..= 255
        // and every other level under it.
        let add = (hi as u32).wrapping_neg() & 0xFF;
        let least = 257 - (hi as u32 - lo as u32);
        // SAFETY: `words` whole words lie behind the pointer (word loads, which the Cortex-M4
        // takes unaligned); the routine reads nothing else and keeps AAPCS.
        let unclipped = unsafe { msr_unclipped_words(row.as_ptr(), words as u32, add * 0x0101_0101, least * 0x0101_0101) };
        unclipped != u32::MAX || row[words * 4..].iter().any(|&f| f <= lo || f >= hi)
    }

    extern "C" {
        fn msr_unclipped_words(row: *const u8, words: u32, add: u32, least: u32) -> u32;
    }

    // Per word: each byte + (256 - hi) (UADD8, wrapping: hi goes to 0, lo to 256 - (hi - lo)),
    // then - (257 - (hi - lo)) (USUB8 sets a byte's GE flag when no borrow: the byte was strictly
    // between lo and hi), and SEL keeps the accumulator's byte where GE is set and takes 0 where
    // not (4 instructions a word; 0 and 255 give the constants 1 and 2). All ones back: nothing
    // clipped. Four words a turn, the 0 to 3 left over first. r0 the row, r1 words, r2 the addend,
    // r3 the least, r12 the accumulator.
    core::arch::global_asm!(
        ".macro MSR_UNCLIPPED_WORD",
        "ldr r4, [r0], #4",
        "uadd8 r4, r4, r2",
        "usub8 r4, r4, r3",
        "sel r12, r12, r5",
        ".endm",
        ".section .text.msr_unclipped_words,\"ax\",%progbits",
        ".global msr_unclipped_words",
        ".type msr_unclipped_words,%function",
        ".p2align 2",
        ".thumb_func",
        "msr_unclipped_words:",
        "push {{r4, r5, r6}}",
        "mov r12, #0xFFFFFFFF",
        "movs r5, #0",
        "ands r6, r1, #3",
        "add r1, r0, r1, lsl #2",
        "beq 2f",
        "3:",
        "MSR_UNCLIPPED_WORD",
        "subs r6, r6, #1",
        "bne 3b",
        "2:",
        "cmp r0, r1",
        "beq 9f",
        "1:",
        "MSR_UNCLIPPED_WORD",
        "MSR_UNCLIPPED_WORD",
        "MSR_UNCLIPPED_WORD",
        "MSR_UNCLIPPED_WORD",
        "cmp r0, r1",
        "bne 1b",
        "9:",
        "mov r0, r12",
        "pop {{r4, r5, r6}}",
        "bx lr",
        ".size msr_unclipped_words, . - msr_unclipped_words",
        ".purgem MSR_UNCLIPPED_WORD",
    );

    /// [`sample_levels_reference`](super::super::sample_levels_reference) of the first `n` bytes of `xs`; on the board four at a time (the
    /// plain loops took 2 300 instructions a frame, half an instruction a pixel). Pads `xs` past
    /// `n` to a whole word with its first byte and takes the padding back out of the counts.
    pub fn sample_levels(xs: &mut [u8; MAX_SAMPLES], n: usize) -> [u16; 4] {
        let n = n.min(MAX_SAMPLES);
        if n == 0 {
            return [255, 0, 0, 0];
        }
        let pad = (4 - n % 4) % 4;
        let first = xs[0];
        xs[n..n + pad].fill(first);
        // SAFETY: (n + pad) / 4 whole words lie in `xs` (n + pad <= MAX_SAMPLES, a multiple of 4
        // since MAX_SAMPLES is); the routine reads nothing else and keeps AAPCS.
        let r = unsafe { msr_sample_levels(xs.as_ptr(), ((n + pad) / 4) as u32) };
        let (top, bottom) = ((r & 0xFF) as u16, ((r >> 8) & 0xFF) as u16);
        let (mut at_top, mut at_bottom) = (((r >> 32) & 0xFFFF) as u16, (r >> 48) as u16);
        if first as u16 == top {
            at_top -= pad as u16;
        }
        if first as u16 == bottom {
            at_bottom -= pad as u16;
        }
        [bottom, top, at_bottom, at_top]
    }


    extern "C" {
        fn msr_sample_levels(xs: *const u8, words: u32) -> u64;
    }

    // Two passes over `words` (at least 1) words. First the bytewise largest and smallest (USUB8
    // sets a byte's GE flag where the first operand is at least the second, SEL takes those bytes
    // from its first operand), then each folded across the four bytes (rotations by 16 and by 8:
    // every byte ends holding the extreme). Then the bytes equal to each (USUB8 against the extreme
    // sets GE exactly there, SEL makes them 1, USADA8 adds the four). Returns the top in r0's byte 0
    // and the bottom in byte 1; the count at the top in r1's low half, at the bottom in its high.
    // r0 the samples, r1 the end, r2 top, r3 bottom, r4 a word, r5 scratch, r6 r7 the counts,
    // r8 zero, r12 ones.
    core::arch::global_asm!(
        ".section .text.msr_sample_levels,\"ax\",%progbits",
        ".global msr_sample_levels",
        ".type msr_sample_levels,%function",
        ".p2align 2",
        ".thumb_func",
        "msr_sample_levels:",
        "push {{r4, r5, r6, r7, r8}}",
        "add r1, r0, r1, lsl #2",
        "mov r12, r0",
        "ldr r2, [r0]",
        "mov r3, r2",
        "1:",
        "ldr r4, [r0], #4",
        "usub8 r5, r4, r2",
        "sel r2, r4, r2",
        "usub8 r5, r3, r4",
        "sel r3, r4, r3",
        "cmp r0, r1",
        "bne 1b",
        "ror r5, r2, #16",
        "usub8 r4, r2, r5",
        "sel r2, r2, r5",
        "ror r5, r2, #8",
        "usub8 r4, r2, r5",
        "sel r2, r2, r5",
        "ror r5, r3, #16",
        "usub8 r4, r5, r3",
        "sel r3, r3, r5",
        "ror r5, r3, #8",
        "usub8 r4, r5, r3",
        "sel r3, r3, r5",
        "mov r0, r12",
        "movs r6, #0",
        "movs r7, #0",
        "mov r8, #0",
        "mov r12, #0x01010101",
        "2:",
        "ldr r4, [r0], #4",
        "usub8 r5, r4, r2",
        "sel r5, r12, r8",
        "usada8 r6, r5, r8, r6",
        "usub8 r5, r3, r4",
        "sel r5, r12, r8",
        "usada8 r7, r5, r8, r7",
        "cmp r0, r1",
        "bne 2b",
        "and r0, r2, #0xFF",
        "and r3, r3, #0xFF",
        "orr r0, r0, r3, lsl #8",
        "orr r1, r6, r7, lsl #16",
        "pop {{r4, r5, r6, r7, r8}}",
        "bx lr",
        ".size msr_sample_levels, . - msr_sample_levels",
    );
}

#[cfg(not(target_arch = "arm"))]
mod imp {
    use super::super::{ramp_reference, sample_levels_reference, Lut, MAX_SAMPLES};

    /// The same, for builds that are not the board's.
    pub fn ramp(out: &mut [u16; 256], first: i32, gain: i32) {
        ramp_reference(out, first, gain)
    }

    /// The same test, for builds that are not the board's.
    #[inline]
    pub fn any_clipped(row: &[u8], lut: &Lut) -> bool {
        let (lo, hi) = (lut.lo, lut.hi);
        // Branch-free over the row (the compiler vectorises it): one test at the end.
        row.iter().fold(false, |a, &f| a | (f <= lo) | (f >= hi))
    }

    /// The same, for builds that are not the board's.
    pub fn sample_levels(xs: &mut [u8; MAX_SAMPLES], n: usize) -> [u16; 4] {
        sample_levels_reference(&xs[..n.min(MAX_SAMPLES)])
    }
}
