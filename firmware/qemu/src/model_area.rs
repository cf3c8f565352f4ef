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
//!
//! Preloaded: a host that starts QEMU may put a model into the board's PSRAM with QEMU's generic
//! loader ([`PRELOAD_ADDR`], see [`take_preload`]) instead of uploading it over the emulated UART
//! (20-40 KB/s: half a minute for the demo's model). At a start with no uploaded model in the
//! slots, the image takes it through the upload's own state machine, CRC and validation
//! included, as if it had come over UART0, and refuses a bad one as an upload would.

use msr_firmware::model::{ModelStore, Upload, UploadError};

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
    /// At most one `FlashStore` may be in use at a time (apart from [`take_preload`]'s own, used
    /// before any other), and [`bench_area`] must not be used with it.
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

/// Where a host may preload a model: the mps2 boards' 16 MiB PSRAM, which this image does not
/// use otherwise. A 16-byte header, then the blob:
/// `magic "MSRP" | len | CRC-32 of the blob (as in ModelBegin) | magic ^ len ^ crc`, little endian.
/// QEMU writes it again at every reset of the machine (the loader's data is kept like a ROM's).
pub const PRELOAD_ADDR: usize = 0x2100_0000;
/// `"MSRP"`, the header's first word.
pub const PRELOAD_MAGIC: u32 = 0x4D53_5250;
const PRELOAD_HEADER: usize = 16;

/// What [`take_preload`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preload {
    /// No preload header (or a damaged one) at [`PRELOAD_ADDR`].
    None,
    /// An uploaded model is active in the slots (a reset after an upload or an earlier preload):
    /// the preload is left alone, as a board keeps its flash.
    Kept,
    /// Verified and active; its CRC-32.
    Taken(u32),
    /// Refused, as an upload of the same bytes would have been.
    Refused(UploadError),
}

/// Takes a preloaded model into the slots when none is active there, through [`Upload`] (CRC and
/// blob validation as for `ModelCommit`). Call once at start-up, before the board uses its store.
pub fn take_preload() -> Preload {
    let base = PRELOAD_ADDR as *const u32;
    // SAFETY: PSRAM on mps2-an385/386/500/511, always mapped under QEMU; any bit pattern is a
    // valid u32, and a fresh machine's zeroes fail the magic.
    let [magic, len, crc, check] = core::array::from_fn(|i| unsafe { core::ptr::read_volatile(base.add(i)) });
    if magic != PRELOAD_MAGIC || check != magic ^ len ^ crc {
        return Preload::None;
    }
    if read_meta().active().is_some() {
        return Preload::Kept;
    }
    // SAFETY: called at start-up, before the board's store is used; this store is dropped
    // before that and holds nothing but the length announced by `begin` below.
    let mut store = unsafe { FlashStore::new() };
    let mut upload = Upload::new();
    if let Err(e) = upload.begin(&mut store, len, crc) {
        return Preload::Refused(e);
    }
    // `begin` refused anything longer than a slot, so the blob lies inside the 16 MiB PSRAM.
    // SAFETY: `len <= SLOT` bytes of mapped PSRAM after the header, read-only while alive.
    let blob = unsafe { core::slice::from_raw_parts((PRELOAD_ADDR + PRELOAD_HEADER) as *const u8, len as usize) };
    if let Err(e) = upload.chunk(&mut store, 0, blob) {
        return Preload::Refused(e);
    }
    match upload.commit(&mut store) {
        Ok(crc) => Preload::Taken(crc),
        Err(e) => Preload::Refused(e),
    }
}
