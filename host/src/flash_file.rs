//! An emulated board's flash kept in a file: the firmware's emulated
//! NOR flash ([`msr_firmware::store::emu`]) over bytes that are written through to the file at
//! every program and erase, so a killed server leaves the file as a power cut at that moment
//! would leave the flash (the firmware's store is tested against every such cut). The file is
//! locked while a board has it (two boards on one flash would each write over what the other
//! saved) and watched: a file removed or replaced under a running board keeps nothing.
use anyhow::{anyhow, bail, Context, Result};
use msr_firmware::store::emu::{Cells, EmuFlash};
use msr_firmware::store::{FlashStore, Layout};
use std::fs::File;
use std::os::unix::fs::{FileExt, MetadataExt};
use std::path::{Path, PathBuf};

/// The bytes of a flash file, 8-byte aligned in memory (the decoder reads the model in place).
pub struct FileCells {
    words: Vec<u64>,
    len: usize,
    file: File,
    /// Writes to the file that failed (the first error is printed).
    pub write_errors: u32,
}

impl FileCells {
    /// Opens `path`, or creates it erased (all 0xFF) when missing; it must be `len` bytes. The
    /// file is locked (`flock`) for as long as these cells or a [`FlashWatch`] of them live: a
    /// file another board holds is refused.
    pub fn open(path: &Path, len: usize) -> Result<FileCells> {
        let exists = path.exists();
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .with_context(|| format!("opening the flash file {}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => bail!(
                "the flash file {} is in use by another board (an `msr serve --flash` running): stop that one, \
                 or give another file",
                path.display()
            ),
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(e).with_context(|| format!("locking the flash file {}", path.display()))
            }
        }
        let mut words = vec![u64::MAX; len.div_ceil(8)];
        let bytes = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..len];
        if exists {
            let have = file.metadata().with_context(|| format!("reading {}", path.display()))?.len();
            if have != len as u64 {
                bail!(
                    "the flash file {} is {have} bytes, an emulated board's flash is {len}: give another file \
                     (a missing one is created)",
                    path.display()
                );
            }
            file.read_exact_at(bytes, 0).with_context(|| format!("reading {}", path.display()))?;
        } else {
            file.write_all_at(bytes, 0).with_context(|| format!("creating {}", path.display()))?;
        }
        Ok(FileCells { words, len, file, write_errors: 0 })
    }

    /// A watch on the file these cells write through to (sharing their lock).
    pub fn watch(&self, path: &Path) -> Result<FlashWatch> {
        let file = self.file.try_clone().with_context(|| format!("the flash file {}", path.display()))?;
        let m = file.metadata().with_context(|| format!("reading {}", path.display()))?;
        Ok(FlashWatch { _lock: file, path: path.into(), id: (m.dev(), m.ino()) })
    }
}

/// The flash file a board runs on: its lock, held while this lives, and a check that the file
/// is still where it was named.
#[derive(Debug)]
pub struct FlashWatch {
    /// Holds the lock (shared with the cells' handle).
    _lock: File,
    path: PathBuf,
    id: (u64, u64),
}

impl FlashWatch {
    /// Errs when the file was removed, or another put in its place: what the board writes from
    /// then on is kept nowhere, and a restart would not find it.
    pub fn check(&self) -> Result<()> {
        let gone = |how: &str| {
            anyhow!(
                "the flash file {} was {how} while the board ran on it: nothing it saves from now on is kept",
                self.path.display()
            )
        };
        match std::fs::metadata(&self.path) {
            Ok(m) if (m.dev(), m.ino()) == self.id => Ok(()),
            Ok(_) => Err(gone("replaced by another file")),
            Err(_) => Err(gone("removed")),
        }
    }
}

impl Cells for FileCells {
    fn bytes(&self) -> &[u8] {
        &bytemuck::cast_slice::<u64, u8>(&self.words)[..self.len]
    }
    fn bytes_mut(&mut self) -> &mut [u8] {
        &mut bytemuck::cast_slice_mut::<u64, u8>(&mut self.words)[..self.len]
    }
    fn changed(&mut self, from: usize, to: usize) {
        let b = &bytemuck::cast_slice::<u64, u8>(&self.words)[from..to];
        if let Err(e) = self.file.write_all_at(b, from as u64) {
            if self.write_errors == 0 {
                eprintln!("writing the flash file: {e}");
            }
            self.write_errors += 1;
        }
    }
}

/// The emulated boards' flash: byte programming, as the STM32F4 HAL does it.
pub type FileFlash = EmuFlash<FileCells, 1>;
/// A model store on a flash file.
pub type FileStore = FlashStore<FileFlash>;

/// A store on the flash file `path` (created erased when missing) laid out as `layout`,
/// running `builtin` when no upload is committed there.
/// With the store, the watch on its file.
pub fn open_store(path: &Path, layout: Layout, builtin: Option<&'static [u8]>) -> Result<(FileStore, FlashWatch)> {
    let cells = FileCells::open(path, layout.len() as usize)?;
    let watch = cells.watch(path)?;
    Ok((FlashStore::new(EmuFlash::new(cells, layout.sectors), layout, builtin), watch))
}

/// `blob` copied to memory that lives as long as the process, 8-byte aligned.
pub fn leak_aligned(blob: &[u8]) -> &'static [u8] {
    let mut words = vec![0u64; blob.len().div_ceil(8)];
    bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..blob.len()].copy_from_slice(blob);
    &bytemuck::cast_slice::<u64, u8>(Vec::leak(words))[..blob.len()]
}
