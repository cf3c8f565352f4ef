//! NUCLEO-F429ZI image: the firmware library's `Board` with the host link on USART3 (ST-LINK VCP,
//! PD8 TX / PD9 RX), the servo bus on USART2, the DWT cycle counter as its clock, models in flash
//! (built in, or uploaded into bank 2, where they survive reset and power loss: `store.rs`),
//! logging with defmt over RTT.
//!
//! The servo bus is a Dynamixel Protocol 2.0 chain, the board its master: USART2 in single-wire
//! half-duplex mode on PD5 (open drain, pull-up), 1 Mbaud. With the `framed-servo-bus` feature it
//! is the project's framed protocol instead, full duplex on PD5 TX / PD6 RX.
#![no_std]
#![no_main]

use defmt_rtt as _;
use panic_probe as _;

use stm32f4xx_hal::{pac, pac::interrupt, prelude::*, serial::Serial};

mod clock;
mod port;
mod store;

use msr_firmware::board::Board;
use msr_firmware::model::ModelStore;
use store::FlashStore;

// SAFETY (store::store): the one store of this image.
static mut BOARD: Board<FlashStore> = Board::new(unsafe { store::store() });

/// Host link: the ST-LINK virtual COM port.
const HOST_BAUD: u32 = 921_600;
/// Servo bus: the Dynamixel default rate.
const SERVO_BAUD: u32 = 1_000_000;
const SYSCLK_HZ: u32 = 180_000_000;

#[cortex_m_rt::entry]
fn main() -> ! {
    let dp = pac::Peripherals::take().expect("peripherals taken once");
    let cp = cortex_m::Peripherals::take().expect("core peripherals taken once");
    // The ST-LINK feeds an 8 MHz clock to the HSE input (MCO, bypass mode).
    let rcc = dp.RCC.constrain();
    let clocks = rcc.cfgr.use_hse(8.MHz()).bypass_hse_oscillator().sysclk(SYSCLK_HZ.Hz()).freeze();
    let mut clock = clock::Clock::start(cp.DCB, cp.DWT, clocks.sysclk().raw());

    let gpiod = dp.GPIOD.split();
    let mut host: Serial<pac::USART3> = Serial::new(
        dp.USART3,
        (gpiod.pd8, gpiod.pd9),
        stm32f4xx_hal::serial::Config::default().baudrate(HOST_BAUD.bps()),
        &clocks,
    )
    .expect("host link baud rate is reachable");
    let mut servo: Serial<pac::USART2> = Serial::new(
        dp.USART2,
        (gpiod.pd5, gpiod.pd6),
        stm32f4xx_hal::serial::Config::default().baudrate(SERVO_BAUD.bps()),
        &clocks,
    )
    .expect("servo bus baud rate is reachable");
    #[cfg(not(feature = "framed-servo-bus"))]
    {
        single_wire_half_duplex();
        board_dynamixel();
    }
    host.listen(stm32f4xx_hal::serial::Event::RxNotEmpty);
    servo.listen(stm32f4xx_hal::serial::Event::RxNotEmpty);
    // The ports drive the registers from here on; the HAL objects only did the set-up, and
    // letting them go leaves the USARTs as configured (they have no Drop).
    let _ = (host, servo);
    // SAFETY: the handlers below only touch their own port's ring.
    unsafe {
        cortex_m::peripheral::NVIC::unmask(pac::Interrupt::USART3);
        cortex_m::peripheral::NVIC::unmask(pac::Interrupt::USART2);
    }
    // SAFETY: static register blocks of USART3/USART2, configured above.
    let mut host = port::Port::new(unsafe { &*pac::USART3::ptr() }, &port::HOST_RX);
    let mut servo = port::Port::new(unsafe { &*pac::USART2::ptr() }, &port::SERVO_RX);
    // SAFETY: the only reference to BOARD, taken once; interrupts do not touch it.
    let board = unsafe { &mut *core::ptr::addr_of_mut!(BOARD) };
    board.store_mut().start();
    defmt::info!(
        "msr-nucleo: {} Hz, host link USART3 {} baud, servo bus USART2 {} baud, built-in model {} bytes, model in use: {}",
        clocks.sysclk().raw(),
        HOST_BAUD,
        SERVO_BAUD,
        store::BUILT_IN.len(),
        defmt::Debug2Format(&board.store().source())
    );
    let mut next_log_ms = 0u32;
    loop {
        let now_us = clock.micros();
        board.poll(now_us, &mut host, &mut servo);
        let now_ms = (now_us / 1000) as u32;
        if now_ms >= next_log_ms {
            next_log_ms = now_ms + 5_000;
            let s = board.status();
            defmt::info!(
                "t={} ms mode={} model={=u32:x} frames={} detections={} reaches={} host crc/resync={}/{} servo crc/resync={}/{} face/servo wd={}/{} clamped={} rx dropped host/servo={}/{}",
                now_ms,
                defmt::Debug2Format(&s.mode),
                s.model_crc,
                s.frames,
                s.detections,
                s.reaches,
                s.host_link.crc_errors,
                s.host_link.resyncs(),
                s.servo_link.crc_errors,
                s.servo_link.resyncs(),
                s.face_watchdog_trips,
                s.servo_watchdog_trips,
                s.clamped_targets,
                port::HOST_RX.dropped.load(core::sync::atomic::Ordering::Relaxed),
                port::SERVO_RX.dropped.load(core::sync::atomic::Ordering::Relaxed)
            );
        }
    }
}

/// USART2 as one bidirectional line on PD5: HDSEL set (with the USART off, as RM0090 asks for
/// mode changes), PD5 open drain with its pull-up, so that the servos can drive the line while
/// the board listens. The receiver then also hears the board's own bytes; the master skips
/// them (an instruction packet is never taken for a status).
#[cfg(not(feature = "framed-servo-bus"))]
fn single_wire_half_duplex() {
    // SAFETY: USART2 and GPIOD were configured above and nothing else uses them yet; these
    // read-modify-writes touch only the bits named.
    unsafe {
        let usart = &*pac::USART2::ptr();
        usart.cr1().modify(|_, w| w.ue().clear_bit());
        usart.cr2().modify(|_, w| w.linen().clear_bit().clken().clear_bit());
        usart.cr3().modify(|_, w| w.scen().clear_bit().iren().clear_bit().hdsel().set_bit());
        usart.cr1().modify(|_, w| w.ue().set_bit());
        let gpiod = &*pac::GPIOD::ptr();
        gpiod.otyper().modify(|_, w| w.ot5().set_bit());
        gpiod.pupdr().modify(|_, w| w.pupdr5().pull_up());
    }
}

/// The board as Dynamixel bus master with the default joint map (the host may send another).
#[cfg(not(feature = "framed-servo-bus"))]
fn board_dynamixel() {
    // SAFETY: called once from `main` before the loop takes its reference to BOARD.
    let board = unsafe { &mut *core::ptr::addr_of_mut!(BOARD) };
    board.set_servo_bus(Some(msr_firmware::dynamixel::Master::new()));
}

#[interrupt]
fn USART3() {
    // SAFETY: read-only use of the status and data registers.
    port::on_rx_interrupt(unsafe { &*pac::USART3::ptr() }, &port::HOST_RX);
}

#[interrupt]
fn USART2() {
    // SAFETY: as above.
    port::on_rx_interrupt(unsafe { &*pac::USART2::ptr() }, &port::SERVO_RX);
}
