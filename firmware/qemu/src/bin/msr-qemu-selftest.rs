//! Checks the board support itself: the SysTick instruction count against loops of known length,
//! then the two UARTs: every byte from UART0 goes out on UART1 xor 0x55, every byte from UART1
//! comes back on UART0; a 0x00 on UART0 ends the run. Exit code 0, or 2 if the clock is off.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::hprintln;
use msr_qemu::clock::Clock;
use msr_qemu::exit::exit;
use msr_qemu::uart::{Uart, UART0, UART1};

#[entry]
fn main() -> ! {
    let cp = cortex_m::Peripherals::take().unwrap_or_else(|| exit(3));
    let clock = Clock::start(cp.SYST);
    let mut ok = true;
    for n in [10_000u32, 1_000_000] {
        let got = clock.calibrate(n);
        let want = 4 * n as u64;
        hprintln!("calibration: {} loop instructions, clock says {}", want, got);
        // The call, the return and one tick of resolution either side.
        ok &= got + 80 >= want && got <= want + 80;
    }
    if !ok {
        exit(2);
    }
    // SAFETY: this image owns both UARTs.
    let (mut host, mut servo) = unsafe { (Uart::new(UART0), Uart::new(UART1)) };
    hprintln!("echo: ready");
    loop {
        if let Some(b) = host.try_read() {
            if b == 0 {
                hprintln!("echo: done at {} ms virtual", clock.millis());
                exit(0);
            }
            servo.write_byte(b ^ 0x55);
        }
        if let Some(b) = servo.try_read() {
            host.write_byte(b);
        }
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    exit(101)
}
