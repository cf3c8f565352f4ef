//! Model storage in the STM32F429's flash bank 2: two upload slots of 512 KiB (active and
//! staging, swapped on a good commit) behind the library's `ModelStore`, and the built-in model
//! (`MSR_MODEL_BLOB` at build time, in bank 1 with the code) that runs until the first upload.
//!
//! Code runs from bank 1 while bank 2 is erased and programmed (read-while-write), so the USART
//! interrupts keep filling their rings; the main loop itself stalls while a slot is erased
//! (about 1 s per 128 KiB sector), so upload while the robot rests. An upload lasts until reset:
//! at start-up the built-in model runs again.

use msr_firmware::model::{ModelStore, UploadError};
use stm32f4xx_hal::flash::FlashExt;
use stm32f4xx_hal::pac;

/// Bank 2 sector numbers (as the HAL counts them) and offsets from the flash base.
const SLOTS: [(u32, &[u8]); 2] = [(0x10_0000, &[12, 13, 14, 15, 16, 17, 18, 19]), (0x18_0000, &[20, 21, 22, 23])];
/// Sizes of sectors 12..=23: 4 x 16 KiB, 64 KiB, 7 x 128 KiB.
const fn sector_size(n: u8) -> u32 {
    match n {
        12..=15 => 16 * 1024,
        16 => 64 * 1024,
        _ => 128 * 1024,
    }
}
pub const SLOT: usize = 512 * 1024;
const FLASH_BASE: usize = 0x0800_0000;

#[repr(C, align(8))]
struct Aligned<T: ?Sized>(T);

static BUILT_IN_BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

/// The model built into the image, empty when there is none.
pub static BUILT_IN: &[u8] = &BUILT_IN_BLOB.0;

pub struct FlashStore {
    lens: [usize; 2],
    active: Option<usize>,
}

impl FlashStore {
    /// # Safety
    /// The one store; it alone erases and programs flash (it steals the FLASH peripheral for it).
    pub const unsafe fn new() -> FlashStore {
        FlashStore { lens: [0; 2], active: None }
    }

    fn staging(&self) -> usize {
        self.active.map_or(0, |i| 1 - i)
    }

    fn slot(i: usize, len: usize) -> &'static [u8] {
        // SAFETY: memory-mapped flash, read-only here; `len <= SLOT` inside bank 2.
        unsafe { core::slice::from_raw_parts((FLASH_BASE + SLOTS[i].0 as usize) as *const u8, len.min(SLOT)) }
    }

    fn flash() -> pac::FLASH {
        // SAFETY: see `new`: nothing else uses the FLASH peripheral.
        unsafe { pac::FLASH::steal() }
    }
}

impl ModelStore for FlashStore {
    fn active(&self) -> Option<&[u8]> {
        match self.active {
            Some(i) => Some(Self::slot(i, self.lens[i])),
            None => (!BUILT_IN.is_empty()).then_some(BUILT_IN),
        }
    }

    fn capacity(&self) -> usize {
        SLOT
    }

    fn begin(&mut self, len: usize) -> Result<(), UploadError> {
        if len > SLOT {
            return Err(UploadError::TooLarge);
        }
        let s = self.staging();
        let mut flash = Self::flash();
        let mut unlocked = flash.unlocked();
        let mut covered = 0u32;
        for &n in SLOTS[s].1 {
            if covered as usize >= len {
                break;
            }
            unlocked.erase(n).map_err(|_| UploadError::Store)?;
            covered += sector_size(n);
        }
        self.lens[s] = len;
        Ok(())
    }

    fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), UploadError> {
        let s = self.staging();
        let end = offset.checked_add(data.len()).ok_or(UploadError::TooLarge)?;
        if end > SLOT {
            return Err(UploadError::TooLarge);
        }
        let mut flash = Self::flash();
        let mut unlocked = flash.unlocked();
        unlocked.program(SLOTS[s].0 as usize + offset, data.iter()).map_err(|_| UploadError::Store)
    }

    fn staged(&self) -> &[u8] {
        let s = self.staging();
        Self::slot(s, self.lens[s])
    }

    fn activate(&mut self) {
        self.active = Some(self.staging());
    }
}
