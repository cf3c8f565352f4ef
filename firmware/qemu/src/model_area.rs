//! The model's home in "flash": a model built into the image at compile time, and the board's
//! model store (`msr_firmware::store`) on an emulated NOR flash with the F429's sector sizes in
//! the PSRAM ([`FLASH_ADDR`]), which QEMU keeps across a reset (`SYSRESETREQ` does not clear
//! memory): a reset comes back with the uploaded model, so a host can restart the board between
//! trials without uploading again. A fresh QEMU starts with the region zeroed: nothing
//! committed, the built-in model (or none); or with a host file's bytes, kept written through
//! ([`crate::flash_file`]).
//!
//! Built in: set `MSR_MODEL_BLOB=/path/to/model.msrm` when building the image; `build.rs` copies
//! it into the build and [`BUILT_IN`] holds it (4-byte aligned, as the decoder's fast paths
//! want). Without it, [`BUILT_IN`] is empty and the model must be uploaded.
//!
//! Preloaded: a host that starts QEMU may put a model into the board's PSRAM with QEMU's generic
//! loader ([`PRELOAD_ADDR`], see [`take_preload`]) instead of uploading it over the emulated UART
//! (20-40 KB/s: half a minute for the demo's model). At a start with no uploaded model in the
//! flash, the image takes it through the upload's own state machine, CRC and validation
//! included, as if it had come over UART0, and refuses a bad one as an upload would.

use msr_firmware::model::{ModelStore, Upload, UploadError};
use msr_firmware::store::emu::{Cells, EmuFlash};
use msr_firmware::store::{EMULATED, EMULATED_SECTORS};
use msr_shared::msg::ModelSource;

/// Bytes per slot: the published MLP decoder with i16 weights is 1.1 MB.
pub const SLOT: usize = 1536 * 1024;

#[repr(C, align(8))]
struct Aligned<T: ?Sized>(T);

static BUILT_IN_BLOB: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/model.bin")));

/// The model built into the image, empty when there is none.
pub static BUILT_IN: &[u8] = &BUILT_IN_BLOB.0;

/// Where the board's flash lies: 3.5 MiB of the mps2 boards' PSRAM (16 MiB at 0x2100_0000;
/// the preload uses its start), which QEMU keeps across a reset as a board keeps its flash. A
/// fresh QEMU starts with it all zero, which the store takes as flash holding nothing valid.
pub const FLASH_ADDR: usize = 0x2180_0000;

/// The flash region's bytes: the PSRAM at [`FLASH_ADDR`].
pub struct Psram;

impl Cells for Psram {
    fn bytes(&self) -> &[u8] {
        // SAFETY: PSRAM, always mapped under QEMU; only the one store (see [`store`]) uses it.
        unsafe { core::slice::from_raw_parts(FLASH_ADDR as *const u8, EMULATED_LEN) }
    }
    fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as above; `&mut self` is the store's exclusive access.
        unsafe { core::slice::from_raw_parts_mut(FLASH_ADDR as *mut u8, EMULATED_LEN) }
    }
    fn changed(&mut self, from: usize, to: usize) {
        crate::flash_file::write_through(from, &self.bytes()[from..to]);
    }
}

/// Makes the host's flash file (if QEMU was given one, see [`crate::flash_file`]) the flash.
/// Call once at start-up, before the store reads the flash.
pub fn attach_flash_file() -> crate::flash_file::Attach {
    crate::flash_file::attach(Psram.bytes_mut())
}

const EMULATED_LEN: usize = 3584 * 1024;
const _: () = assert!(EMULATED_LEN == EMULATED.len() as usize);

/// The emulated flash: byte programming, the F429's sector sizes (the store's `EMULATED`).
pub type Flash = EmuFlash<Psram, 1>;
/// The board's model store.
pub type FlashStore = msr_firmware::store::FlashStore<Flash>;

/// The board's store over [`FLASH_ADDR`], running [`BUILT_IN`] (when not empty) until an upload
/// is committed.
///
/// # Safety
/// Make one: the store owns the flash region.
pub const unsafe fn store() -> FlashStore {
    msr_firmware::store::FlashStore::new(EmuFlash::new(Psram, &EMULATED_SECTORS), EMULATED, Some(BUILT_IN))
}

#[link_section = ".model"]
static mut SLOT_A: Aligned<[u8; SLOT]> = Aligned([0; SLOT]);

/// The bench image's model area (code memory, not part of the image file).
pub fn bench_area() -> &'static mut [u8; SLOT] {
    // SAFETY: the benchmark image calls this once; nothing else uses the area.
    unsafe { &mut *core::ptr::addr_of_mut!(SLOT_A.0) }
}

/// Where a host may preload a model: the mps2 boards' 16 MiB PSRAM, which this image does not
/// use otherwise. A 16-byte header, then the blob:
/// `magic "MSRP" | len | CRC-32 of the blob (as in ModelBegin) | magic ^ len ^ crc`, little endian.
/// QEMU writes it again at every reset of the machine (the loader's data is kept like a ROM's).
pub const PRELOAD_ADDR: usize = 0x2100_0000;
/// `"MSRP"`, the header's first word.
pub const PRELOAD_MAGIC: u32 = 0x4D53_5250;
const PRELOAD_HEADER: usize = 16;

/// The preload header's length and CRC-32, when its magic and check word hold.
fn preload_header() -> Option<(u32, u32)> {
    let base = PRELOAD_ADDR as *const u32;
    // SAFETY: PSRAM on mps2-an385/386/500/511, always mapped under QEMU; any bit pattern is a
    // valid u32, and a fresh machine's zeroes fail the magic.
    let [magic, len, crc, check] = core::array::from_fn(|i| unsafe { core::ptr::read_volatile(base.add(i)) });
    (magic == PRELOAD_MAGIC && check == magic ^ len ^ crc).then_some((len, crc))
}

/// Why a preloaded blob was not taken by [`preloaded_blob`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PreloadError {
    /// Longer than a model slot.
    TooLarge,
    /// Its bytes do not have the header's CRC-32.
    Crc,
}

/// The preloaded blob in place, for an image that reads its model without the store (the
/// benchmark image): `None` without a preload header, an error when it is longer than a slot or
/// its CRC-32 is not the header's.
pub fn preloaded_blob() -> Result<Option<&'static [u8]>, PreloadError> {
    let Some((len, crc)) = preload_header() else {
        return Ok(None);
    };
    if len as usize > SLOT {
        return Err(PreloadError::TooLarge);
    }
    // SAFETY: a slot's length of mapped PSRAM after the header (a slot is smaller than the
    // 8 MiB before the flash region), not written while the image runs.
    let blob = unsafe { core::slice::from_raw_parts((PRELOAD_ADDR + PRELOAD_HEADER) as *const u8, len as usize) };
    if msr_shared::blob::CRC32.checksum(blob) != crc {
        return Err(PreloadError::Crc);
    }
    Ok(Some(blob))
}

/// What [`take_preload`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preload {
    /// No preload header (or a damaged one) at [`PRELOAD_ADDR`].
    None,
    /// An uploaded model is committed in the flash (a reset after an upload or an earlier
    /// preload): the preload is left alone, as a board keeps its flash.
    Kept,
    /// Verified and active; its CRC-32.
    Taken(u32),
    /// Refused, as an upload of the same bytes would have been.
    Refused(UploadError),
}

/// Takes a preloaded model into the slots when none is active there, through [`Upload`] (CRC and
/// blob validation as for `ModelCommit`). Call once at start-up, before the board uses its store.
pub fn take_preload(store: &mut FlashStore) -> Preload {
    let Some((len, crc)) = preload_header() else {
        return Preload::None;
    };
    store.start();
    if matches!(store.source(), ModelSource::Flash { .. }) {
        return Preload::Kept;
    }
    let mut upload = Upload::new();
    if let Err(e) = upload.begin(store, len, crc) {
        return Preload::Refused(e);
    }
    while store.busy() {
        store.step();
    }
    // `begin` refused anything longer than a slot, so the blob lies inside the 16 MiB PSRAM
    // (below the flash region: a slot is smaller than the 8 MiB before it).
    // SAFETY: `len` bytes of mapped PSRAM after the header, read-only while alive.
    let blob = unsafe { core::slice::from_raw_parts((PRELOAD_ADDR + PRELOAD_HEADER) as *const u8, len as usize) };
    if let Err(e) = upload.chunk(store, 0, blob) {
        return Preload::Refused(e);
    }
    match upload.commit(store) {
        Ok(crc) => Preload::Taken(crc),
        Err(e) => Preload::Refused(e),
    }
}
