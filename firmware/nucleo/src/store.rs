//! The model store in the STM32F429's flash bank 2 (0x0810_0000, 1 MiB): the firmware library's
//! power-safe [`FlashStore`] with the `F429_BANK2` layout (record log in sectors 12 and 13, slot
//! 0 in 14..=19, slot 1 in 20..=23), and the built-in model (`MSR_MODEL_BLOB` at build time, in
//! bank 1 with the code) that runs when no upload is committed.
//!
//! Programs go through the HAL's `embedded-storage` implementation (byte programming). Erases
//! are started here and polled ([`MappedFlash::erase_step`]), one sector at a time between
//! control periods: the code runs from bank 1 while bank 2 is erased (read-while-write), so the
//! main loop and the USART interrupts go on. A read of bank 2 (the running model) while it is
//! erased would stall the CPU until the erase ends: the board answers frames with `StoreBusy`
//! meanwhile (`Board` asks the store whether it is busy).

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use msr_firmware::store::{MappedFlash, F429_BANK2, F429_BANK_SECTORS};
use stm32f4xx_hal::flash::{Error, FlashExt};
use stm32f4xx_hal::pac;

/// Bank 2's offset from the flash base, and its size.
const BANK2: u32 = 0x10_0000;
const BANK2_LEN: usize = 1024 * 1024;
const FLASH_BASE: usize = 0x0800_0000;

#[repr(C, align(8))]
struct Aligned<T: ?Sized>(T);

static BUILT_IN_BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

/// The model built into the image, empty when there is none.
pub static BUILT_IN: &[u8] = &BUILT_IN_BLOB.0;

/// Flash bank 2 as `embedded-storage` NOR flash, offsets from its start.
pub struct Bank2 {
    /// The sector whose erase was started (its offset), until it is seen done.
    erasing: Option<u32>,
}

/// The board's store.
pub type FlashStore = msr_firmware::store::FlashStore<Bank2>;

/// The one store of this image.
///
/// # Safety
/// Make one: it alone erases and programs the flash (it steals the FLASH peripheral for it).
pub const unsafe fn store() -> FlashStore {
    msr_firmware::store::FlashStore::new(Bank2 { erasing: None }, F429_BANK2, Some(BUILT_IN))
}

fn flash() -> pac::FLASH {
    // SAFETY: see `store`: nothing else uses the FLASH peripheral.
    unsafe { pac::FLASH::steal() }
}

impl ErrorType for Bank2 {
    type Error = Error;
}

impl ReadNorFlash for Bank2 {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        let m = self.mapped();
        let s = offset as usize;
        match m.get(s..s + bytes.len()) {
            Some(src) => {
                bytes.copy_from_slice(src);
                Ok(())
            }
            None => Err(Error::ProgrammingAlignment),
        }
    }

    fn capacity(&self) -> usize {
        BANK2_LEN
    }
}

impl NorFlash for Bank2 {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 16 * 1024;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        let mut f = flash();
        let mut u = f.unlocked();
        NorFlash::erase(&mut u, BANK2 + from, BANK2 + to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        let mut f = flash();
        let mut u = f.unlocked();
        u.program((BANK2 + offset) as usize, bytes.iter())
    }
}

/// The HAL's sector number of the bank-2 sector at `offset`, and the SNB field's value
/// (sectors 12..=23 are 16..=27 there, RM0090 3.9.8).
fn sector_of(offset: u32) -> Option<u8> {
    let mut at = 0;
    for (i, s) in F429_BANK_SECTORS.iter().enumerate() {
        if at == offset {
            return Some(12 + i as u8);
        }
        at += s;
    }
    None
}

impl MappedFlash for Bank2 {
    fn mapped(&self) -> &[u8] {
        // SAFETY: memory-mapped flash, read-only here.
        unsafe { core::slice::from_raw_parts((FLASH_BASE + BANK2 as usize) as *const u8, BANK2_LEN) }
    }

    /// Starts a sector erase and returns; later calls poll BSY (RM0090 3.6.3).
    fn erase_step(&mut self, from: u32, to: u32) -> Result<bool, Error> {
        let _ = to;
        // SAFETY: register access of the FLASH block this store owns.
        let regs = unsafe { &*pac::FLASH::ptr() };
        if regs.sr().read().bsy().bit() {
            return Ok(false);
        }
        if self.erasing == Some(from) {
            self.erasing = None;
            let sr = regs.sr().read();
            let failed = sr.wrperr().bit() || sr.pgaerr().bit() || sr.pgperr().bit() || sr.pgserr().bit() || sr.operr().bit();
            regs.cr().modify(|_, w| w.ser().clear_bit().lock().set_bit());
            return if failed { Err(Error::Operation) } else { Ok(true) };
        }
        let Some(sector) = sector_of(from) else { return Err(Error::ProgrammingAlignment) };
        let snb = sector + 4;
        regs.keyr().write(|w| unsafe { w.key().bits(0x4567_0123) });
        regs.keyr().write(|w| unsafe { w.key().bits(0xCDEF_89AB) });
        // Clear old error flags (write 1 to clear), then start.
        regs.sr().write(|w| unsafe { w.bits(0xF3) });
        regs.cr().modify(|_, w| {
            w.psize().psize8();
            unsafe { w.snb().bits(snb) };
            w.ser().set_bit();
            w.pg().clear_bit()
        });
        regs.cr().modify(|_, w| w.strt().set_bit());
        self.erasing = Some(from);
        Ok(false)
    }
}
