//! An emulated board's flash kept in a file (`msr serve --flash FILE`): the firmware's emulated
//! NOR flash ([`msr_firmware::store::emu`]) over bytes that are written through to the file at
//! every program and erase, so a killed server leaves the file as a power cut at that moment
//! would leave the flash (the firmware's store is tested against every such cut).
use anyhow::{bail, Context, Result};
use msr_firmware::store::emu::{Cells, EmuFlash};
use msr_firmware::store::{FlashStore, Layout};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// The bytes of a flash file, 8-byte aligned in memory (the decoder reads the model in place).
pub struct FileCells {
    words: Vec<u64>,
    len: usize,
    file: File,
    /// Writes to the file that failed (the first error is printed).
    pub write_errors: u32,
}

impl FileCells {
    /// Opens `path`, or creates it erased (all 0xFF) when missing; it must be `len` bytes.
    pub fn open(path: &Path, len: usize) -> Result<FileCells> {
        let exists = path.exists();
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .with_context(|| format!("opening the flash file {}", path.display()))?;
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
pub fn open_store(path: &Path, layout: Layout, builtin: Option<&'static [u8]>) -> Result<FileStore> {
    let cells = FileCells::open(path, layout.len() as usize)?;
    Ok(FlashStore::new(EmuFlash::new(cells, layout.sectors), layout, builtin))
}

/// `blob` copied to memory that lives as long as the process, 8-byte aligned.
pub fn leak_aligned(blob: &[u8]) -> &'static [u8] {
    let mut words = vec![0u64; blob.len().div_ceil(8)];
    bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..blob.len()].copy_from_slice(blob);
    &bytemuck::cast_slice::<u64, u8>(Vec::leak(words))[..blob.len()]
}
