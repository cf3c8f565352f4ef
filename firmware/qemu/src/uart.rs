//! The ARM CMSDK APB UART as QEMU's mps2-an386 has it (`hw/char/cmsdk-apb-uart.c`), with the
//! `embedded-io` traits the pipeline's links take. Polled; the RX interrupt only wakes the image
//! from `wfi` ([`idle`]).
//!
//! QEMU holds incoming bytes back while RXFULL is set, so nothing is lost if the loop is slow;
//! a byte is only dropped while RX is disabled, which is why [`Uart::new`] enables it first.
//! What that costs: the UART holds one byte, so QEMU moves one byte per turn of its event loop,
//! measured at 15 to 45 KB/s on this machine (a 181 KB model uploads in 7 to 15 s).
//!
//! On the way out QEMU writes each byte to the host's socket as it is sent; when the socket is
//! full (nobody reads that link; each one-byte write takes about 1 KB of socket buffer) the
//! UART stays TX-full and [`Uart::write_byte`] waits, so the host must read both links.

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};

/// UART0: the host link.
pub const UART0: usize = 0x4000_4000;
/// UART1: the servo bus.
pub const UART1: usize = 0x4000_5000;
/// UART2: the simulation clock channel (see `main.rs`).
pub const UART2: usize = 0x4000_6000;
/// The three UARTs' RX interrupt lines on mps2-an386 (each TX line is one above).
pub const RX_IRQS: [u32; 3] = [0, 2, 4];
const NVIC_ISER0: usize = 0xE000_E100;

const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const INTCLEAR: usize = 0x0C;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
const CTRL_RX_INT_EN: u32 = 1 << 3;
const INT_RX: u32 = 1 << 1;

/// The 25 MHz peripheral clock over 115200 baud; QEMU wants at least 16.
const BAUD_115200: u32 = 25_000_000 / 115_200;

pub struct Uart {
    base: usize,
}

impl Uart {
    /// Takes one of [`UART0`] .. UART4 and enables it.
    ///
    /// # Safety
    /// `base` must be a CMSDK UART that nothing else drives.
    pub unsafe fn new(base: usize) -> Uart {
        let u = Uart { base };
        u.write_reg(BAUDDIV, BAUD_115200);
        u.write_reg(CTRL, CTRL_TX_EN | CTRL_RX_EN);
        u
    }

    fn read_reg(&self, off: usize) -> u32 {
        // SAFETY: a register of the UART this value owns (see `new`).
        unsafe { read_volatile((self.base + off) as *const u32) }
    }

    fn write_reg(&self, off: usize, v: u32) {
        // SAFETY: as in `read_reg`.
        unsafe { write_volatile((self.base + off) as *mut u32, v) }
    }

    /// Raises the UART's RX interrupt when a byte arrives, so that the image can sleep (`wfi`)
    /// until there is work instead of spinning on the status register (which, under `-icount`,
    /// also keeps QEMU's virtual clock far behind real time: see [`idle`]).
    pub fn enable_rx_interrupt(&mut self) {
        self.write_reg(CTRL, CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT_EN);
    }

    /// Whether a received byte waits.
    pub fn rx_ready(&self) -> bool {
        self.read_reg(STATE) & STATE_RX_FULL != 0
    }

    /// One received byte, if there is one.
    pub fn try_read(&mut self) -> Option<u8> {
        if self.read_reg(STATE) & STATE_RX_FULL != 0 {
            Some(self.read_reg(DATA) as u8)
        } else {
            None
        }
    }

    /// Sends one byte, waiting while the transmitter is full.
    pub fn write_byte(&mut self, b: u8) {
        while self.read_reg(STATE) & STATE_TX_FULL != 0 {}
        self.write_reg(DATA, b as u32);
    }
}

/// Enables the RX interrupt lines of UART0..2 in the NVIC. The handler ([`clear_rx_interrupts`])
/// only acknowledges: the data stays in the UART for the polling code.
pub fn enable_rx_irqs() {
    let mask = RX_IRQS.iter().fold(0u32, |m, i| m | 1 << i);
    // SAFETY: the NVIC's set-enable register; setting bits only enables those lines.
    unsafe { write_volatile(NVIC_ISER0 as *mut u32, mask) };
}

/// Acknowledges the RX interrupts of UART0..2 (call from the interrupt handler).
pub fn clear_rx_interrupts() {
    for base in [UART0, UART1, UART2] {
        // SAFETY: write-one-to-clear of the interrupt status; no other effect.
        unsafe { write_volatile((base + INTCLEAR) as *mut u32, INT_RX) };
    }
}

/// Status polls [`idle`] spins before it sleeps.
const SPIN_POLLS: u32 = 200;

/// Sleeps until an interrupt (a received byte, SysTick) unless `ready()` says there is work.
/// Interrupts are masked around the check, so a byte that arrives between the check and the
/// `wfi` still wakes it (a pending interrupt ends `wfi` even while masked).
///
/// Why sleep: spinning on the UART status is slow under QEMU (every register read is an I/O
/// exit), so with `-icount shift=0` a spinning image saw about 30 ms of virtual time per second
/// of real time; a sleeping vCPU lets virtual time follow real time (`-icount sleep=on`) and
/// leaves the host's cores to the other side of the links.
pub fn idle(ready: impl Fn() -> bool) {
    // A short spin first: the next byte of a burst is often a few microseconds away, and a
    // sleeping vCPU costs QEMU a thread wake-up to restart (on an idle machine ~25 % of a
    // lockstep trial's wall time).
    for _ in 0..SPIN_POLLS {
        if ready() {
            return;
        }
    }
    cortex_m::interrupt::disable();
    if !ready() {
        cortex_m::asm::wfi();
    }
    // SAFETY: single-threaded image; the only handlers are the clock's and the UART ack.
    unsafe { cortex_m::interrupt::enable() };
}

impl embedded_io::ErrorType for Uart {
    type Error = Infallible;
}

impl embedded_io::ReadReady for Uart {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.read_reg(STATE) & STATE_RX_FULL != 0)
    }
}

impl embedded_io::Read for Uart {
    /// Blocks for the first byte, then returns what is there without waiting more.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        if buf.is_empty() {
            return Ok(0);
        }
        let mut n = 0;
        while n == 0 {
            while n < buf.len() {
                match self.try_read() {
                    Some(b) => {
                        buf[n] = b;
                        n += 1;
                    }
                    None => break,
                }
            }
        }
        Ok(n)
    }
}

impl embedded_io::WriteReady for Uart {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.read_reg(STATE) & STATE_TX_FULL == 0)
    }
}

impl embedded_io::Write for Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}
