//! Microseconds since boot from the Cortex-M4 cycle counter (DWT CYCCNT), extended to 64 bits.
//! The main loop calls [`Clock::millis`] far more often than the 24 s the 32-bit counter takes
//! to wrap at 180 MHz, which is all the extension needs.

use cortex_m::peripheral::{DCB, DWT};

pub struct Clock {
    hz: u32,
    last: u32,
    high: u64,
}

impl Clock {
    pub fn start(mut dcb: DCB, mut dwt: DWT, hz: u32) -> Clock {
        dcb.enable_trace();
        dwt.enable_cycle_counter();
        Clock { hz, last: DWT::cycle_count(), high: 0 }
    }

    /// Core cycles since start.
    pub fn cycles(&mut self) -> u64 {
        let now = DWT::cycle_count();
        if now < self.last {
            self.high += 1 << 32;
        }
        self.last = now;
        self.high + now as u64
    }

    /// Microseconds since start: the board's clock.
    pub fn micros(&mut self) -> u64 {
        self.cycles() / (self.hz as u64 / 1_000_000)
    }
}
