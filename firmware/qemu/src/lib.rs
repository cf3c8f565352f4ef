//! Board support for QEMU's mps2-an386 (Cortex-M4): CMSDK UARTs, a SysTick time base that counts
//! emulated instructions under `-icount shift=0`, stack painting, semihosting exit and command line, the
//! model's place in flash, that flash kept in a host file, and the lockstep channel's pipe.
#![no_std]

pub mod clock;
pub mod cmdline;
pub mod exit;
pub mod flash_file;
pub mod memory;
pub mod model_area;
pub mod pipe;
pub mod uart;
