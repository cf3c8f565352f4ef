//! The ARM CMSDK APB UART as QEMU's mps2-an386 has it (`hw/char/cmsdk-apb-uart.c`), with the
//! `embedded-io` traits the pipeline's links take. Polled, no interrupts: the firmware loop
//! polls both links every pass anyway.
//!
//! QEMU holds incoming bytes back while RXFULL is set, so nothing is lost if the loop is slow;
//! a byte is only dropped while RX is disabled, which is why [`Uart::new`] enables it first.

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};

/// UART0: the host link.
pub const UART0: usize = 0x4000_4000;
/// UART1: the servo bus.
pub const UART1: usize = 0x4000_5000;

const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const BAUDDIV: usize = 0x10;

const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;

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
