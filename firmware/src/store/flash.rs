//! What the store needs of the flash, and how it divides it: sectors, log halves, model slots.
use embedded_storage::nor_flash::NorFlash;

/// Flash the store can read in place. `mapped()` is the whole region, as `read` returns it.
pub trait MappedFlash: NorFlash {
    /// The region's bytes.
    fn mapped(&self) -> &[u8];
    /// Erases `[from, to)` (one sector), or goes on with it: `Ok(true)` once done. A driver that
    /// can start an erase and poll for its end returns `Ok(false)` meanwhile, so the control
    /// loop keeps its period; the default erases at once.
    fn erase_step(&mut self, from: u32, to: u32) -> Result<bool, Self::Error> {
        self.erase(from, to).map(|()| true)
    }
}

/// Where things lie in the region: erase sectors by size, from offset 0, and which sectors
/// (`[first, end)` indices) hold the log halves and the model slots.
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    /// Sector sizes in bytes, in address order.
    pub sectors: &'static [u32],
    /// The record log's two halves.
    pub log: [(u8, u8); 2],
    /// The two model slots.
    pub slots: [(u8, u8); 2],
}

/// The STM32F429's bank 2 as this project uses it (sectors 12..=23: 4 x 16 KiB, 64 KiB,
/// 7 x 128 KiB, RM0090 table 6): log halves in sectors 12 and 13 (16 KiB each), slot 0 in
/// 14..=19 (480 KiB), slot 1 in 20..=23 (512 KiB).
pub const F429_BANK2: Layout = Layout {
    sectors: &F429_BANK_SECTORS,
    log: [(0, 1), (1, 2)],
    slots: [(2, 8), (8, 12)],
};

/// The emulated boards' flash (`msr serve --flash`, the QEMU image): the F429's sector sizes
/// continued to 3.5 MiB, so that both slots take the published decoder with i16 weights
/// (1.1 MB): log halves in the two first 16 KiB sectors, slot 0 (1632 KiB) and slot 1
/// (1920 KiB) after them.
pub const EMULATED: Layout = Layout {
    sectors: &EMULATED_SECTORS,
    log: [(0, 1), (1, 2)],
    slots: [(2, 17), (17, 32)],
};

/// 4 x 16 KiB, 64 KiB, 27 x 128 KiB = 3.5 MiB.
pub const EMULATED_SECTORS: [u32; 32] = {
    let mut s = [128 * 1024; 32];
    let mut i = 0;
    while i < 5 {
        s[i] = F429_BANK_SECTORS[i];
        i += 1;
    }
    s
};

/// One bank of the F429 (RM0090 table 6): 4 x 16 KiB, 1 x 64 KiB, 7 x 128 KiB = 1 MiB.
pub const F429_BANK_SECTORS: [u32; 12] = {
    let mut s = [128 * 1024; 12];
    let mut i = 0;
    while i < 4 {
        s[i] = 16 * 1024;
        i += 1;
    }
    s[4] = 64 * 1024;
    s
};

impl Layout {
    /// Offset of sector `i` (the region's end for `i == sectors.len()`).
    pub fn sector_start(&self, i: u8) -> u32 {
        self.sectors[..i as usize].iter().sum()
    }
    pub(super) fn span(&self, (a, b): (u8, u8)) -> (u32, u32) {
        (self.sector_start(a), self.sector_start(b))
    }
    /// Bytes of slot `i`.
    pub fn slot_len(&self, i: usize) -> u32 {
        let (a, b) = self.span(self.slots[i]);
        b - a
    }
    /// The region's size.
    pub const fn len(&self) -> u32 {
        let (mut i, mut n) = (0, 0);
        while i < self.sectors.len() {
            n += self.sectors[i];
            i += 1;
        }
        n
    }
    /// An empty layout (no sectors).
    pub const fn is_empty(&self) -> bool {
        self.sectors.is_empty()
    }
}
