//! An emulated NOR flash with a real sector map, for the power-cut test and the emulated boards.
//!
//! As the STM32F4's flash: erased bytes read 0xFF, a program can only clear bits (programming
//! a byte that is not erased is refused here, so a store that relies on it fails its tests),
//! erases go by whole sectors. A power cut can be scheduled at any operation, after any number
//! of its bytes: the operation is torn there (a program leaves the bytes from the cut on
//! somewhere between old and new, bit by bit; an erase leaves arbitrary bytes in the whole
//! sector) and every later operation fails, as on a board whose supply is gone.

use super::flash::MappedFlash;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// What holds the flash's bytes: memory, or memory written through to a file (the host's).
pub trait Cells {
    /// All bytes.
    fn bytes(&self) -> &[u8];
    /// Bytes to change; `done` is called after each change with its range.
    fn bytes_mut(&mut self) -> &mut [u8];
    /// The range `[from, to)` changed (a file-backed store writes it out).
    fn changed(&mut self, from: usize, to: usize) {
        let _ = (from, to);
    }
}

impl Cells for &mut [u8] {
    fn bytes(&self) -> &[u8] {
        self
    }
    fn bytes_mut(&mut self) -> &mut [u8] {
        self
    }
}

#[cfg(any(feature = "std", test))]
impl Cells for std::vec::Vec<u8> {
    fn bytes(&self) -> &[u8] {
        self
    }
    fn bytes_mut(&mut self) -> &mut [u8] {
        self
    }
}

/// Why an operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmuError {
    /// Outside the region, or an erase not on sector boundaries, or a write not on write units.
    Bounds,
    /// A program would have to set a bit (the byte was not erased).
    NotErased,
    /// The power is off.
    PowerCut,
}

impl NorFlashError for EmuError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            EmuError::Bounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// A power cut: during operation `op` (counted from 0 since it was set), after `byte` bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cut {
    /// The operation that is torn.
    pub op: u32,
    /// Bytes of it done before the cut (0: none; past its length: all, then the power goes).
    pub byte: u32,
    /// `byte` is taken modulo the operation's length: a byte inside it, whatever its length.
    pub inside: bool,
}

/// An emulated NOR flash of write unit `W` bytes over `C`'s bytes.
pub struct EmuFlash<C, const W: usize> {
    cells: C,
    sectors: &'static [u32],
    cut: Option<Cut>,
    powered: bool,
    /// Operations since the cut was set (or since creation).
    pub ops: u32,
    /// Programs and erases done in all.
    pub programs: u32,
    #[allow(missing_docs)]
    pub erases: u32,
    rng: u64,
}

impl<C: Cells, const W: usize> EmuFlash<C, W> {
    /// A flash over `cells` (whose length must be the sectors' sum), as it is.
    pub const fn new(cells: C, sectors: &'static [u32]) -> Self {
        EmuFlash { cells, sectors, cut: None, powered: true, ops: 0, programs: 0, erases: 0, rng: 0x9E37_79B9_7F4A_7C15 }
    }

    /// Schedules a power cut (counting operations from now); `seed` chooses the torn bits.
    pub fn cut_at(&mut self, cut: Cut, seed: u64) {
        self.cut = Some(cut);
        self.ops = 0;
        self.rng = seed | 1;
    }

    /// The power is back (a new boot): no cut scheduled, operations counted from 0.
    pub fn power_on(&mut self) {
        self.cut = None;
        self.powered = true;
        self.ops = 0;
    }

    /// Has a cut happened?
    pub fn is_off(&self) -> bool {
        !self.powered
    }

    /// The bytes.
    pub fn cells(&self) -> &C {
        &self.cells
    }

    /// Takes the bytes back.
    pub fn into_cells(self) -> C {
        self.cells
    }

    fn random(&mut self) -> u8 {
        // xorshift64
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.rng = x;
        (x >> 24) as u8
    }

    /// Starts an operation of `len` bytes: `Ok(None)` to do it all, `Ok(Some(k))` to do `k`
    /// bytes and tear it there.
    fn begin_op(&mut self, len: usize) -> Result<Option<usize>, EmuError> {
        if !self.powered {
            return Err(EmuError::PowerCut);
        }
        let op = self.ops;
        self.ops = self.ops.wrapping_add(1);
        match self.cut {
            Some(c) if c.op == op && c.inside => Ok(Some(c.byte as usize % len.max(1))),
            Some(c) if c.op == op => Ok(Some((c.byte as usize).min(len))),
            _ => Ok(None),
        }
    }

    fn sector_bounds(&self, from: u32, to: u32) -> bool {
        let mut at = 0u32;
        let (mut from_ok, mut to_ok) = (false, false);
        for s in self.sectors {
            from_ok |= at == from;
            to_ok |= at == to;
            at += s;
        }
        to_ok |= at == to;
        from_ok && to_ok && from < to
    }
}

impl<C: Cells, const W: usize> ErrorType for EmuFlash<C, W> {
    type Error = EmuError;
}

impl<C: Cells, const W: usize> ReadNorFlash for EmuFlash<C, W> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), EmuError> {
        let src = self.cells.bytes();
        let s = src.get(offset as usize..offset as usize + bytes.len()).ok_or(EmuError::Bounds)?;
        bytes.copy_from_slice(s);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.cells.bytes().len()
    }
}

impl<C: Cells, const W: usize> NorFlash for EmuFlash<C, W> {
    const WRITE_SIZE: usize = W;
    /// The smallest sector (the F429's 16 KiB); erases must match the sector map exactly.
    const ERASE_SIZE: usize = 16 * 1024;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), EmuError> {
        if to as usize > self.capacity() || !self.sector_bounds(from, to) {
            return Err(EmuError::Bounds);
        }
        let torn = self.begin_op((to - from) as usize)?;
        self.erases += 1;
        let (a, b) = (from as usize, to as usize);
        match torn {
            None => self.cells.bytes_mut()[a..b].fill(0xFF),
            Some(_) => {
                // An interrupted erase: any bytes at all.
                for i in a..b {
                    let r = self.random();
                    self.cells.bytes_mut()[i] = r;
                }
                self.powered = false;
            }
        }
        self.cells.changed(a, b);
        if self.powered { Ok(()) } else { Err(EmuError::PowerCut) }
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), EmuError> {
        let (a, n) = (offset as usize, bytes.len());
        if a % W != 0 || n % W != 0 || a + n > self.capacity() {
            return Err(EmuError::Bounds);
        }
        // Only clearing bits: a byte that would need a 1 where it has a 0 was not erased.
        let old = &self.cells.bytes()[a..a + n];
        if old.iter().zip(bytes).any(|(o, b)| b & !o != 0) {
            return Err(EmuError::NotErased);
        }
        let torn = self.begin_op(n)?;
        self.programs += 1;
        let done = torn.unwrap_or(n);
        for i in 0..n {
            let cell = a + i;
            let old = self.cells.bytes()[cell];
            let v = if i < done {
                bytes[i]
            } else if torn.is_some() {
                // Torn: each bit that should clear may or may not have.
                old & (bytes[i] | self.random())
            } else {
                old
            };
            self.cells.bytes_mut()[cell] = v;
        }
        self.cells.changed(a, a + n);
        if torn.is_some() {
            self.powered = false;
            return Err(EmuError::PowerCut);
        }
        Ok(())
    }
}

impl<C: Cells, const W: usize> MappedFlash for EmuFlash<C, W> {
    fn mapped(&self) -> &[u8] {
        self.cells.bytes()
    }
}
