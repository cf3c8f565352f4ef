//! The board's flash kept in a file on the host (`msr serve --backend qemu --flash FILE`), through
//! semihosting: QEMU's `-semihosting-config enable=on,target=native,arg=msr-qemu,arg=flash=PATH`
//! makes the image's command line `msr-qemu flash=PATH`.
//!
//! At every start the image reads the file into the flash region (so the file, not QEMU's
//! PSRAM, is the flash), and from then on every program and erase is written through to the file
//! as it happens ([`write_through`], called by the emulated flash's `Cells::changed`). A QEMU
//! killed at any moment leaves the file as a power cut at that operation would leave the flash,
//! which the store is tested against (`msr_firmware::store`'s power-cut test). The file has the
//! in-process board's layout (`msr serve --backend inproc --flash`): either board reads the
//! other's.
//!
//! Without the argument nothing changes: the flash is the PSRAM alone.

use core::sync::atomic::{AtomicI32, AtomicU32, Ordering};
use cortex_m_semihosting::{nr, syscall, syscall1};

/// The file's semihosting handle, -1 without one.
static HANDLE: AtomicI32 = AtomicI32::new(-1);
/// Writes to the file that failed.
static WRITE_ERRORS: AtomicU32 = AtomicU32::new(0);

/// `r+b`: read and write, the file must exist (the host creates it, erased, when missing).
const MODE_READ_WRITE: usize = 3;

/// What [`attach`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Attach {
    /// No `msr-qemu flash=PATH` command line: the flash is the PSRAM alone.
    None,
    /// The file's bytes are the flash, written through from now on.
    Attached,
    /// The file was named but cannot be the flash.
    Failed(&'static str),
}

/// Reads the semihosting command line and, when it names a flash file, reads the file into
/// `region` and writes later changes through to it. Call once at start-up, before the store
/// reads the flash.
pub fn attach(region: &mut [u8]) -> Attach {
    let mut line = [0u8; 512];
    // The block is read and written by the host: buffer, then its length (in), the string's
    // length (out).
    let mut block = [line.as_mut_ptr() as usize, line.len()];
    let block_ptr = block.as_mut_ptr();
    // SAFETY: GET_CMDLINE writes at most `line.len()` bytes into `line` and the length into the
    // block, both alive across the call. Passed as a raw pointer and read back volatile: through
    // a shared reference the compiler may keep the length it stored.
    if unsafe { syscall1(nr::GET_CMDLINE, block_ptr as usize) } != 0 {
        return Attach::None;
    }
    // SAFETY: the block's second word, written by the host.
    let len = unsafe { core::ptr::read_volatile(block_ptr.add(1)) };
    if len >= line.len() {
        return Attach::Failed("the command line is too long");
    }
    const KEY: &[u8] = b"msr-qemu flash=";
    if !line[..len].starts_with(KEY) {
        return Attach::None;
    }
    // The path runs to the end of the line (it may hold spaces); `line[len]` is its NUL.
    let (path, path_len) = (line[KEY.len()..].as_ptr() as usize, len - KEY.len());
    // SAFETY: OPEN reads the NUL-terminated path; the block lives across the call.
    let handle = unsafe { syscall(nr::OPEN, &[path, MODE_READ_WRITE, path_len]) } as isize;
    if handle < 0 {
        return Attach::Failed("cannot open the file");
    }
    // SAFETY: FLEN reads the one-word block.
    let flen = unsafe { syscall(nr::FLEN, &[handle as usize]) };
    if flen != region.len() {
        return Attach::Failed("the file is not the flash's size");
    }
    // SAFETY: READ writes at most `region.len()` bytes into `region`, which is exclusively ours.
    let unread = unsafe { syscall(nr::READ, &[handle as usize, region.as_mut_ptr() as usize, region.len()]) };
    if unread != 0 {
        return Attach::Failed("the file could not be read whole");
    }
    HANDLE.store(handle as i32, Ordering::Relaxed);
    Attach::Attached
}

/// Writes `bytes`, the flash's bytes from `offset`, to the file (nothing without one).
pub fn write_through(offset: usize, bytes: &[u8]) {
    let handle = HANDLE.load(Ordering::Relaxed);
    if handle < 0 {
        return;
    }
    // SAFETY: SEEK reads its two-word block; WRITE reads `bytes.len()` bytes of `bytes`.
    let ok = unsafe {
        syscall(nr::SEEK, &[handle as usize, offset]) == 0
            && syscall(nr::WRITE, &[handle as usize, bytes.as_ptr() as usize, bytes.len()]) == 0
    };
    if !ok {
        WRITE_ERRORS.fetch_add(1, Ordering::Relaxed);
    }
}

/// Writes to the file that failed since start-up.
pub fn write_errors() -> u32 {
    WRITE_ERRORS.load(Ordering::Relaxed)
}
