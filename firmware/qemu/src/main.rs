//! The board image for QEMU's mps2-an386: the firmware library's [`Board`] on UART0 (host link)
//! and UART1 (servo bus), with SysTick as its microsecond clock (virtual time: 1 ns per
//! instruction under `-icount shift=0`).
//!
//! The model is the built-in one (`MSR_MODEL_BLOB` at build time) or whatever the host uploads
//! (`ModelBegin` / `ModelChunk` / `ModelCommit`) into the two flash slots.
//!
//! For tests, [`EXIT_SEQUENCE`] on UART0 ends the run: the image prints its status, stack peak
//! and sizes on the semihosting console and exits with code 0. The sequence cannot occur inside
//! a COBS frame (it holds zeros) and is not a valid frame, so no real traffic triggers it.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use msr_firmware::board::Board;
use msr_qemu::clock::Clock;
use msr_qemu::exit::exit;
use msr_qemu::model_area::{self, FlashStore};
use msr_qemu::uart::{Uart, UART0, UART1};
use msr_qemu::memory;

/// Three delimiters, an ASCII word, a delimiter.
pub const EXIT_SEQUENCE: &[u8; 12] = b"\0\0\0MSR-EXIT\0";

// SAFETY (FlashStore::new): the one store of this image; the bench area is not used here.
static mut BOARD: Board<FlashStore> = Board::new(unsafe { FlashStore::new() });

/// UART0 with a watch for [`EXIT_SEQUENCE`] on what the board reads.
struct HostLink {
    uart: Uart,
    /// The last bytes read, newest last.
    recent: [u8; EXIT_SEQUENCE.len()],
    exit: bool,
}

impl embedded_io::ErrorType for HostLink {
    type Error = core::convert::Infallible;
}

impl embedded_io::ReadReady for HostLink {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        self.uart.read_ready()
    }
}

impl embedded_io::Read for HostLink {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = embedded_io::Read::read(&mut self.uart, buf)?;
        for &b in &buf[..n] {
            self.recent.copy_within(1.., 0);
            self.recent[EXIT_SEQUENCE.len() - 1] = b;
            self.exit |= self.recent == *EXIT_SEQUENCE;
        }
        Ok(n)
    }
}

impl embedded_io::Write for HostLink {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        embedded_io::Write::write(&mut self.uart, buf)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}


#[entry]
fn main() -> ! {
    memory::paint_stack();
    let cp = cortex_m::Peripherals::take().unwrap_or_else(|| exit(3));
    let clock = Clock::start(cp.SYST);
    // SAFETY: this image owns both UARTs.
    let (host, mut servo) = unsafe { (Uart::new(UART0), Uart::new(UART1)) };
    let mut host = HostLink { uart: host, recent: [0xFF; EXIT_SEQUENCE.len()], exit: false };
    // SAFETY: the only reference to BOARD, taken once in this single-threaded image.
    let board = unsafe { &mut *core::ptr::addr_of_mut!(BOARD) };
    let sizes = memory::sizes();
    hprintln!(
        "msr-qemu: ready; built-in model {} bytes; static RAM {} bytes, code {} bytes, .data initial values {} bytes",
        model_area::BUILT_IN.len(),
        sizes.static_ram,
        sizes.code - model_area::BUILT_IN.len(),
        sizes.data_init
    );
    loop {
        // 25 SysTick ticks of 40 ns per microsecond.
        let now_us = clock.ticks() / 25;
        board.poll(now_us, &mut host, &mut servo);
        if host.exit {
            let s = board.status();
            hprintln!("msr-qemu: exit requested at {} us virtual", now_us);
            hprintln!("msr-qemu: status {:?}", s);
            hprintln!("msr-qemu: stack peak {} bytes", memory::stack_peak());
            exit(0);
        }
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("msr-qemu: PANIC {}", info);
    exit(101)
}
