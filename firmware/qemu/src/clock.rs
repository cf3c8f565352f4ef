//! A 64-bit time base from SysTick.
//!
//! SysTick runs from the 25 MHz system clock of mps2-an386. Under `-icount shift=0` QEMU's virtual
//! clock advances exactly 1 ns per emulated instruction, so one SysTick tick (40 ns) is exactly
//! [`INSTRUCTIONS_PER_TICK`] instructions: differences of [`Clock::now`] are instruction counts
//! with a resolution of 40 instructions. The calibration is checked at start-up by
//! [`Clock::calibrate`] against a loop of known length. While the image sleeps (`wfi`) QEMU's
//! virtual clock follows real time (`-icount` with its default `sleep=on`).

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};

/// mps2-an386's SYSCLK.
pub const SYSCLK_HZ: u32 = 25_000_000;
/// Emulated instructions per SysTick tick under `-icount shift=0` (1 ns each).
pub const INSTRUCTIONS_PER_TICK: u64 = 1_000_000_000 / SYSCLK_HZ as u64;
const RELOAD: u32 = 0x00FF_FFFF;

static WRAPS: AtomicU32 = AtomicU32::new(0);

#[cortex_m_rt::exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// The free-running SysTick.
pub struct Clock {
    _syst: SYST,
    base: u64,
    reload: u32,
}

/// A SysTick period of 1 ms, for images that sleep between events and must wake for their
/// timers.
pub const RELOAD_1MS: u32 = SYSCLK_HZ / 1000 - 1;

impl Clock {
    pub fn start(syst: SYST) -> Clock {
        Self::start_with_reload(syst, RELOAD)
    }

    /// Starts with a SysTick wrap every `reload + 1` ticks (at most 2^24).
    pub fn start_with_reload(mut syst: SYST, reload: u32) -> Clock {
        let reload = reload.clamp(1, RELOAD);
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(reload);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
        // The counter starts at 0 and loads RELOAD on the first tick; start counting after that.
        while SYST::get_current() == 0 {}
        let mut c = Clock { _syst: syst, base: 0, reload };
        c.base = c.raw();
        c
    }

    fn raw(&self) -> u64 {
        loop {
            let hi = WRAPS.load(Ordering::Relaxed);
            let val = SYST::get_current();
            let pending = SCB::is_pendst_pending();
            // A wrap between the reads would pair an old count with a new value: read again.
            if WRAPS.load(Ordering::Relaxed) != hi {
                continue;
            }
            // Wrapped, but the exception is not taken yet (QEMU delivers it at the end of a
            // translation block): count the wrap here. A large value means it came before `val`.
            let wraps = hi as u64 + (pending && val > self.reload / 2) as u64;
            return wraps * (self.reload as u64 + 1) + (self.reload - val) as u64;
        }
    }

    /// Ticks since [`Clock::start`].
    pub fn ticks(&self) -> u64 {
        self.raw() - self.base
    }

    /// Emulated instructions since start (under `-icount shift=0`).
    pub fn instructions(&self) -> u64 {
        self.ticks() * INSTRUCTIONS_PER_TICK
    }

    /// Milliseconds of virtual time since start.
    pub fn millis(&self) -> u32 {
        (self.ticks() / (SYSCLK_HZ as u64 / 1000)) as u32
    }

    /// Measures a loop of exactly `4 * n` instructions (plus a few around it) and returns the
    /// instruction count the clock saw, so that the caller can check the calibration.
    pub fn calibrate(&self, n: u32) -> u64 {
        let t0 = self.instructions();
        spin(n);
        self.instructions() - t0
    }
}

/// Four instructions per iteration: two NOPs, a subtract and the branch.
#[inline(never)]
fn spin(n: u32) {
    if n == 0 {
        return;
    }
    // SAFETY: a counted loop on a scratch register, no memory access.
    unsafe {
        core::arch::asm!(
            "2:",
            "nop",
            "nop",
            "subs {0}, {0}, #1",
            "bne 2b",
            inout(reg) n => _,
            options(nomem, nostack),
        );
    }
}
