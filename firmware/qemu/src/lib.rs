//! Board support for QEMU's mps2-an386 (Cortex-M4): CMSDK UARTs, a SysTick time base that counts
//! emulated instructions under `-icount shift=0`, stack painting, semihosting exit, and the
//! model's place in flash.
#![no_std]

pub mod clock;
pub mod exit;
pub mod memory;
pub mod model_area;
pub mod uart;
