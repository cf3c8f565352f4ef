//! NUCLEO-F429ZI image: host link on USART3 (ST-LINK VCP, PD8 TX / PD9 RX), servo bus on USART2
//! (PD5 TX / PD6 RX), defmt over RTT.
#![no_std]
#![no_main]

use defmt_rtt as _;
use panic_probe as _;

use stm32f4xx_hal::{pac, pac::interrupt, prelude::*, serial::Serial};

mod clock;
mod port;

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
    host.listen(stm32f4xx_hal::serial::Event::RxNotEmpty);
    servo.listen(stm32f4xx_hal::serial::Event::RxNotEmpty);
    // The ports drive the registers from here on; the HAL objects only did the set-up.
    core::mem::forget((host, servo));
    // SAFETY: the handlers below only touch their own port's ring.
    unsafe {
        cortex_m::peripheral::NVIC::unmask(pac::Interrupt::USART3);
        cortex_m::peripheral::NVIC::unmask(pac::Interrupt::USART2);
    }
    // SAFETY: static register blocks of USART3/USART2, configured above.
    let mut _host = port::Port::new(unsafe { &*pac::USART3::ptr() }, &port::HOST_RX);
    let mut _servo = port::Port::new(unsafe { &*pac::USART2::ptr() }, &port::SERVO_RX);
    defmt::info!("msr-nucleo: {} Hz, host link {} baud, servo bus {} baud", clocks.sysclk().raw(), HOST_BAUD, SERVO_BAUD);
    loop {
        let _ = clock.millis();
    }
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
