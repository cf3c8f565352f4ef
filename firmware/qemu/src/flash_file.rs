//! The board's flash kept in a file on the host (`msr serve --backend qemu --flash FILE`), through
//! semihosting: QEMU's `-semihosting-config enable=on,target=native,arg=msr-qemu,arg=flash=PATH`
//! makes the image's command line `msr-qemu flash=PATH` ([`crate::cmdline`]).
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
use cortex_m_semihosting::{nr, syscall};

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
    let line = match crate::cmdline::Line::read() {
        Ok(line) => line,
        Err(why) => return Attach::Failed(why),
    };
    let Some(path) = line.args().flash else { return Attach::None };
    // `path` ends in the line's NUL.
    let (path, path_len) = (path.as_ptr() as usize, path.len() - 1);
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
