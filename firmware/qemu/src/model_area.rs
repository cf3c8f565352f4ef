//! The model's home in "flash": a model built into the image at compile time, and two slots an
//! uploaded one is written to (active and staging, as a board with flash would do it).
//!
//! Built in: set `MSR_MODEL_BLOB=/path/to/model.msrm` when building the image; `build.rs` copies
//! it into the build and [`BUILT_IN`] holds it (4-byte aligned, as the decoder's fast paths
//! want). Without it, [`BUILT_IN`] is empty and the model must be uploaded.
//!
//! The slots live in the `.model` section, which `memory.x` places in the code memory without
//! loading it: on mps2 that memory is RAM, so the image can write it like programmed flash.

use msr_firmware::model::{ModelStore, UploadError};

/// Bytes per slot: the published MLP decoder with i16 weights is 1.1 MB.
pub const SLOT: usize = 1536 * 1024;

#[repr(C, align(8))]
struct Aligned<T: ?Sized>(T);

static BUILT_IN_BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

/// The model built into the image, empty when there is none.
pub static BUILT_IN: &[u8] = &BUILT_IN_BLOB.0;

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
/// good commit; the built-in model runs until then. Make only one (it owns the slots).
pub struct FlashStore {
    lens: [usize; 2],
    active: Option<usize>,
}

impl FlashStore {
    /// # Safety
    /// At most one `FlashStore` may exist, and [`bench_area`] must not be used with it.
    pub const unsafe fn new() -> FlashStore {
        FlashStore { lens: [0; 2], active: None }
    }

    fn staging(&self) -> usize {
        self.active.map_or(0, |i| 1 - i)
    }
}

impl ModelStore for FlashStore {
    fn active(&self) -> Option<&[u8]> {
        match self.active {
            // SAFETY: the active slot is only read while active; `&self` ties the borrow to the
            // store, so no write (which takes `&mut self`) can overlap it.
            Some(i) => Some(unsafe { &(&*slot_ptr(i))[..self.lens[i]] }),
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
        self.lens[s] = len;
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
        unsafe { &(&*slot_ptr(s))[..self.lens[s].min(SLOT)] }
    }

    fn activate(&mut self) {
        self.active = Some(self.staging());
    }
}
