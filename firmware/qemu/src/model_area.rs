//! The model's home in "flash": a model built into the image at compile time, and two slots an
//! uploaded one is written to (active and staging, as a board with flash would do it).
//!
//! Built in: set `MSR_MODEL_BLOB=/path/to/model.msrm` when building the image; `build.rs` copies
//! it into the build and [`BUILT_IN`] holds it (4-byte aligned, as the decoder's fast paths
//! want). Without it, [`BUILT_IN`] is empty and the model must be uploaded.
//!
//! The slots live in the `.model` section, which `memory.x` places in the code memory without
//! loading it: on mps2 that memory is RAM, so the image can write it like programmed flash.
//! Which slot is active is kept there too ([`Meta`]), as a board keeps it in flash: a reset
//! (`SYSRESETREQ`, which QEMU performs without clearing memory) comes back with the uploaded
//! model, so a host can restart the board between trials without uploading again. A fresh QEMU
//! starts with zeroed memory: no record, the built-in model.

use msr_firmware::model::{ModelStore, UploadError};

/// Bytes per slot: the published MLP decoder with i16 weights is 1.1 MB.
pub const SLOT: usize = 1536 * 1024;

#[repr(C, align(8))]
struct Aligned<T: ?Sized>(T);

static BUILT_IN_BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

/// The model built into the image, empty when there is none.
pub static BUILT_IN: &[u8] = &BUILT_IN_BLOB.0;

/// The active slot's record, written last on a commit.
#[repr(C)]
#[derive(Clone, Copy)]
struct Meta {
    magic: u32,
    slot: u32,
    len: u32,
    /// `magic ^ slot ^ len`, so a half-written or stray record is not taken.
    check: u32,
}

const META_MAGIC: u32 = 0x4D53_524D; // "MSRM"

impl Meta {
    fn active(self) -> Option<(usize, usize)> {
        let ok = self.magic == META_MAGIC
            && self.check == self.magic ^ self.slot ^ self.len
            && self.slot < 2
            && self.len as usize <= SLOT;
        ok.then_some((self.slot as usize, self.len as usize))
    }
}

#[link_section = ".model"]
static mut META: Meta = Meta { magic: 0, slot: 0, len: 0, check: 0 };

fn read_meta() -> Meta {
    // SAFETY: a plain read of the record; only `FlashStore::activate` writes it.
    unsafe { core::ptr::read_volatile(core::ptr::addr_of!(META)) }
}

#[link_section = ".model"]
static mut SLOT_A: Aligned<[u8; SLOT]> = Aligned([0; SLOT]);
#[link_section = ".model"]
static mut SLOT_B: Aligned<[u8; SLOT]> = Aligned([0; SLOT]);

fn slot_ptr(i: usize) -> *mut [u8; SLOT] {
    // SAFETY: only the addresses are taken here.
    unsafe {
        if i == 0 {
            core::ptr::addr_of_mut!(SLOT_A.0)
        } else {
            core::ptr::addr_of_mut!(SLOT_B.0)
        }
    }
}

/// The whole first slot, for the benchmark image, which takes a model without the link
/// protocol. Must not be used together with a [`FlashStore`].
pub fn bench_area() -> &'static mut [u8; SLOT] {
    // SAFETY: the benchmark image calls this once and has no FlashStore.
    unsafe { &mut *slot_ptr(0) }
}

/// The two slots behind the library's [`ModelStore`]: one active, one staging, swapped on a
/// good commit; the built-in model runs until then (or the model a reset left active). Make
/// only one (it owns the slots).
pub struct FlashStore {
    /// Bytes announced for the staging slot.
    staging_len: usize,
}

impl FlashStore {
    /// # Safety
    /// At most one `FlashStore` may exist, and [`bench_area`] must not be used with it.
    pub const unsafe fn new() -> FlashStore {
        FlashStore { staging_len: 0 }
    }

    fn staging(&self) -> usize {
        read_meta().active().map_or(0, |(i, _)| 1 - i)
    }
}

impl ModelStore for FlashStore {
    fn active(&self) -> Option<&[u8]> {
        match read_meta().active() {
            // SAFETY: the active slot is never the staging one, the only one written; `&self`
            // ties the borrow to the store, so no commit (`&mut self`) can overlap it.
            Some((i, len)) => Some(unsafe { &(&*slot_ptr(i))[..len] }),
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
        self.staging_len = len;
        Ok(())
    }

    fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), UploadError> {
        let s = self.staging();
        let end = offset.checked_add(data.len()).ok_or(UploadError::TooLarge)?;
        // SAFETY: the staging slot, never handed out while staging; `&mut self` is exclusive.
        let slot = unsafe { &mut *slot_ptr(s) };
        slot.get_mut(offset..end).ok_or(UploadError::TooLarge)?.copy_from_slice(data);
        Ok(())
    }

    fn staged(&self) -> &[u8] {
        let s = self.staging();
        // SAFETY: read-only view of the staging slot tied to `&self`.
        unsafe { &(&*slot_ptr(s))[..self.staging_len.min(SLOT)] }
    }

    fn activate(&mut self) {
        let slot = self.staging() as u32;
        let len = self.staging_len as u32;
        let m = Meta { magic: META_MAGIC, slot, len, check: META_MAGIC ^ slot ^ len };
        // SAFETY: `&mut self` is exclusive; nothing borrows the record.
        unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(META), m) };
    }
}
