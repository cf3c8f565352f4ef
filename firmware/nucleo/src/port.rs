//! A USART as an `embedded-io` byte stream: received bytes go into a ring buffer from the RXNE
//! interrupt, so nothing is lost while the pipeline computes (the decoder takes milliseconds;
//! at 921600 baud a byte arrives every 11 us, and the USART holds only one). Sending blocks per
//! byte.

use core::cell::UnsafeCell;
use core::convert::Infallible;
use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};

use stm32f4xx_hal::pac;

/// Bytes buffered per port: more than a whole face frame's worth of chunks in flight.
const RING: usize = 2048;

/// A single-producer (the interrupt), single-consumer (the main loop) byte ring.
pub struct Ring {
    buf: UnsafeCell<[u8; RING]>,
    head: AtomicUsize,
    tail: AtomicUsize,
    /// Bytes lost: the ring was full or the USART overran.
    pub dropped: AtomicU32,
}

// SAFETY: `push` runs only in one interrupt handler and `pop` only in the main loop; the
// head/tail atomics order their accesses to disjoint slots.
unsafe impl Sync for Ring {}

impl Ring {
    pub const fn new() -> Ring {
        Ring {
            buf: UnsafeCell::new([0; RING]),
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
            dropped: AtomicU32::new(0),
        }
    }

    /// Interrupt side.
    fn push(&self, b: u8) {
        let head = self.head.load(Ordering::Relaxed);
        let next = (head + 1) % RING;
        if next == self.tail.load(Ordering::Acquire) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        // SAFETY: slot `head` is not visible to the consumer until `head` is published below.
        unsafe { (*self.buf.get())[head] = b };
        self.head.store(next, Ordering::Release);
    }

    /// Main-loop side.
    fn pop(&self) -> Option<u8> {
        let tail = self.tail.load(Ordering::Relaxed);
        if tail == self.head.load(Ordering::Acquire) {
            return None;
        }
        // SAFETY: the producer published slot `tail` and will not touch it until `tail` moves.
        let b = unsafe { (*self.buf.get())[tail] };
        self.tail.store((tail + 1) % RING, Ordering::Release);
        Some(b)
    }

    fn is_empty(&self) -> bool {
        self.tail.load(Ordering::Relaxed) == self.head.load(Ordering::Acquire)
    }
}

pub static HOST_RX: Ring = Ring::new();
pub static SERVO_RX: Ring = Ring::new();

/// The USART register block all F4 USARTs share.
type Regs = pac::usart1::RegisterBlock;

/// Drains the USART's receive register into `ring`; called from its interrupt.
pub fn on_rx_interrupt(regs: &Regs, ring: &Ring) {
    loop {
        let sr = regs.sr().read();
        if sr.ore().bit_is_set() {
            ring.dropped.fetch_add(1, Ordering::Relaxed);
        }
        if !(sr.rxne().bit_is_set() || sr.ore().bit_is_set()) {
            break;
        }
        // Reading DR after SR clears RXNE and the overrun flag.
        let b = regs.dr().read().dr().bits() as u8;
        ring.push(b);
    }
}

/// One serial link: RX from the ring its interrupt fills, TX by polling.
pub struct Port {
    regs: &'static Regs,
    rx: &'static Ring,
}

impl Port {
    /// `regs` must be a USART already configured (baud rate, pins) with RXNE interrupts on,
    /// whose interrupt handler feeds `rx`.
    pub fn new(regs: &'static Regs, rx: &'static Ring) -> Port {
        Port { regs, rx }
    }

    fn write_byte(&mut self, b: u8) {
        while self.regs.sr().read().txe().bit_is_clear() {}
        // SAFETY: any 8-bit value is a valid data register write.
        self.regs.dr().write(|w| unsafe { w.dr().bits(b as u16) });
    }
}

impl embedded_io::ErrorType for Port {
    type Error = Infallible;
}

impl embedded_io::ReadReady for Port {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(!self.rx.is_empty())
    }
}

impl embedded_io::Read for Port {
    /// Blocks for the first byte, then takes what is buffered.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let mut n = 0;
        while n < buf.len() {
            match self.rx.pop() {
                Some(b) => {
                    buf[n] = b;
                    n += 1;
                }
                None if n > 0 => break,
                None => cortex_m::asm::nop(),
            }
        }
        Ok(n)
    }
}

impl embedded_io::WriteReady for Port {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.regs.sr().read().txe().bit_is_set())
    }
}

impl embedded_io::Write for Port {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        while self.regs.sr().read().tc().bit_is_clear() {}
        Ok(())
    }
}
