//! A model store in NOR flash that survives reset and power loss, for any chip whose flash
//! implements the `embedded-storage` NOR-flash traits (the STM32 HAL's does) and can be read in
//! place ([`MappedFlash`]: the running model is used where it lies).
//!
//! # Layout ([`Layout`])
//! Two model slots and a record log in two halves, each a run of erase sectors. An upload goes
//! to the slot that is not running; the slot is erased sector by sector in [`FlashStore::step`]
//! (between control periods), programmed chunk by chunk, read back and CRC-checked whole, and
//! only then made current by one small **commit record** (slot, length, CRC-32 of the blob, a
//! sequence number, and the record's own CRC-32) appended to the log. Statistics are records in
//! the same log (opaque bytes, tied to the model they were measured for).
//!
//! # Start-up ([`FlashStore::start`])
//! Both log halves are scanned for records whose CRC holds; for each slot the newest commit is a
//! candidate, newest first, and a candidate runs only if its slot's bytes still match its length
//! and CRC. Else the built-in model, else none; [`ModelSource`] says which.
//!
//! # Why any power cut leaves the old or the new model
//! - The running slot is never erased or programmed.
//! - A commit record is written only after its slot verified; a torn record fails its CRC and the
//!   previous commit (of the other, untouched slot) wins.
//! - The log is compacted into the other half (erase, then copy the current commit from RAM and
//!   the newest statistics from the half that stays) only while the half that stays holds the
//!   newest of each kind; a start-up that finds the newest statistics in the other half copies
//!   them over first. A torn erase or copy leaves the half that stays as it was.
//!
//! The tests (`store/tests.rs`) cut power at every program and erase of uploads and statistics
//! saves, and at a random byte inside each, on an emulated F429 flash ([`emu`]).

pub mod emu;
mod flash;

use crate::model::{ModelStore, UploadError};
use embedded_storage::nor_flash::NorFlash;
use msr_shared::blob::CRC32;
pub use flash::{Layout, MappedFlash, EMULATED, EMULATED_SECTORS, F429_BANK2, F429_BANK_SECTORS};
pub use msr_shared::msg::{ModelSource, StatsAge};

/// Record kinds.
const COMMIT: u32 = 1;
const STATS: u32 = 2;
const STATS_RESET: u32 = 3;
const MAGIC: u32 = 0x4C52_534D; // "MSRL"
const HEADER: u32 = 16;
/// Records start on 8-byte boundaries (so any write size up to 8 works).
const ALIGN: u32 = 8;
/// Largest statistics record payload.
pub const MAX_STATS: usize = 4096;
/// Payload bytes before the statistics themselves: model CRC, save time (ms, u64).
const STATS_HEAD: u32 = 12;

fn rec_size(len: u32) -> u32 {
    (HEADER + len + 4).div_ceil(ALIGN) * ALIGN
}

/// A record found in the log: where (region offset), its sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Found {
    at: u32,
    seq: u32,
    kind: u32,
    len: u32,
}

/// A commit: slot, blob length and CRC-32 (as `ModelBegin` announced it), sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Commit {
    slot: u8,
    len: u32,
    crc: u32,
    seq: u32,
}

/// Statistics as saved: the model they belong to, the board time of the save, the bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stats<'a> {
    /// CRC of the model they were measured with (as the caller gave it).
    pub model_crc: u32,
    /// When and in which start-up they were saved.
    pub age: StatsAge,
    /// What was saved.
    pub bytes: &'a [u8],
}

/// Why a statistics save did not happen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StatsError {
    /// More than [`MAX_STATS`] bytes.
    TooLarge,
    /// The log is being compacted (or a slot erased): try again after a few [`FlashStore::step`]s.
    Busy,
    /// The flash refused a write or an erase.
    Flash,
}

/// Work left for [`FlashStore::step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Erase {
    /// Next sector to erase, and the end of the run.
    next: u8,
    end: u8,
    /// A log compaction (copy into the erased half, which becomes the active one) follows.
    compact: bool,
}


/// A record's payload after its first part: bytes in RAM, or bytes already in flash (a copy).
#[derive(Clone, Copy)]
enum Body<'a> {
    Ram(&'a [u8]),
    Flash { at: u32, len: u32 },
}

impl Body<'_> {
    fn len(&self) -> u32 {
        match self {
            Body::Ram(b) => b.len() as u32,
            Body::Flash { len, .. } => *len,
        }
    }
}

/// Programs a byte stream in whole write units, the last one padded with erased bytes.
struct Prog {
    pos: u32,
    buf: [u8; 64],
    n: usize,
    ok: bool,
}

impl Prog {
    fn put<F: NorFlash>(&mut self, f: &mut F, mut data: &[u8]) {
        let w = F::WRITE_SIZE.clamp(1, 64);
        if self.n > 0 {
            let take = (w - self.n).min(data.len());
            self.buf[self.n..self.n + take].copy_from_slice(&data[..take]);
            self.n += take;
            data = &data[take..];
            if self.n == w {
                self.ok &= f.write(self.pos, &self.buf[..w]).is_ok();
                self.pos += w as u32;
                self.n = 0;
            }
        }
        let whole = data.len() / w * w;
        if whole > 0 {
            self.ok &= f.write(self.pos, &data[..whole]).is_ok();
            self.pos += whole as u32;
        }
        let rest = &data[whole..];
        self.buf[self.n..self.n + rest.len()].copy_from_slice(rest);
        self.n += rest.len();
    }

    fn finish<F: NorFlash>(&mut self, f: &mut F) -> bool {
        let w = F::WRITE_SIZE.clamp(1, 64);
        if self.n > 0 {
            self.buf[self.n..w].fill(0xFF);
            self.ok &= f.write(self.pos, &self.buf[..w]).is_ok();
        }
        self.ok
    }
}

/// The store. `F` is the flash region given to it (e.g. the F429's bank 2).
pub struct FlashStore<F> {
    flash: F,
    layout: Layout,
    builtin: Option<&'static [u8]>,
    started: bool,
    current: Option<Commit>,
    /// The log half appended to, the offset of its free space, the next sequence number.
    half: u8,
    tail: u32,
    next_seq: u32,
    /// Sequence numbers from this one on were written in this start-up.
    boot_seq: u32,
    /// The newest statistics record (or reset), if any.
    stats: Option<Found>,
    /// The slot being uploaded into and its announced length.
    staging: Option<(u8, u32)>,
    /// Bytes of the staging slot erased, from its start.
    erased_to: u32,
    /// The erase run in progress, and the one queued after it.
    job: Option<Erase>,
    after: Option<Erase>,
    /// Flash operations that failed.
    pub flash_errors: u32,
}

impl<F: MappedFlash> FlashStore<F> {
    /// A store on `flash` laid out as `layout`, running `builtin` (if any) when no uploaded
    /// model is committed. Nothing is read before [`ModelStore::start`]. The flash's write size
    /// must be at most 8 bytes.
    pub const fn new(flash: F, layout: Layout, builtin: Option<&'static [u8]>) -> Self {
        assert!(F::WRITE_SIZE <= ALIGN as usize && ALIGN as usize % F::WRITE_SIZE == 0);
        FlashStore {
            flash,
            layout,
            builtin,
            started: false,
            current: None,
            half: 0,
            tail: 0,
            next_seq: 1,
            boot_seq: 1,
            stats: None,
            staging: None,
            erased_to: 0,
            job: None,
            after: None,
            flash_errors: 0,
        }
    }

    /// The flash (e.g. to save an emulated one).
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// The flash, to change it under the store (a test's power cut).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Takes the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    fn bytes(&self, at: u32, len: u32) -> &[u8] {
        let m = self.flash.mapped();
        m.get(at as usize..(at as usize).saturating_add(len as usize)).unwrap_or(&[])
    }

    fn word(&self, at: u32) -> u32 {
        match *self.bytes(at, 4) {
            [a, b, c, d] => u32::from_le_bytes([a, b, c, d]),
            _ => u32::MAX,
        }
    }

    /// A valid record at `at` inside `[at, end)`, if any.
    fn record_at(&self, at: u32, end: u32) -> Option<Found> {
        if at + HEADER + 4 > end || self.word(at) != MAGIC {
            return None;
        }
        let (kind, seq, len) = (self.word(at + 4), self.word(at + 8), self.word(at + 12));
        if len > STATS_HEAD + MAX_STATS as u32 || at + rec_size(len) > end {
            return None;
        }
        let crc = CRC32.checksum(self.bytes(at, HEADER + len));
        (crc == self.word(at + HEADER + len)).then_some(Found { at, seq, kind, len })
    }

    /// Every valid record of log half `h`, and where its free space starts: past the last byte
    /// that is not erased, so a torn record (or a torn erase) is stepped over.
    fn scan(&self, h: usize, mut each: impl FnMut(Found)) -> u32 {
        let (start, end) = self.layout.span(self.layout.log[h]);
        let mut at = start;
        while at + HEADER + 4 <= end {
            match self.record_at(at, end) {
                Some(f) => {
                    each(f);
                    at += rec_size(f.len);
                }
                None => at += ALIGN,
            }
        }
        let used = self.bytes(start, end - start).iter().rposition(|b| *b != 0xFF);
        used.map_or(start, |i| (start + i as u32 + 1).div_ceil(ALIGN) * ALIGN).min(end)
    }

    fn commit_of(&self, f: Found) -> Option<Commit> {
        let p = f.at + HEADER;
        let slot = self.word(p);
        (f.kind == COMMIT && f.len == 12 && slot < 2).then(|| Commit {
            slot: slot as u8,
            len: self.word(p + 4),
            crc: self.word(p + 8),
            seq: f.seq,
        })
    }

    /// Does slot `c.slot` hold `c.len` bytes with CRC `c.crc`?
    fn verifies(&self, c: &Commit) -> bool {
        let (start, _) = self.layout.span(self.layout.slots[c.slot as usize]);
        c.len <= self.layout.slot_len(c.slot as usize) && CRC32.checksum(self.bytes(start, c.len)) == c.crc
    }

    /// Scans the log and picks the model (see the module docs).
    fn boot(&mut self) {
        self.started = true;
        let mut best: [Option<Commit>; 2] = [None; 2];
        let mut stats: Option<(Found, usize)> = None;
        let mut top = [0u32; 2];
        let mut tails = [0u32; 2];
        let this = &*self;
        for h in 0..2 {
            tails[h] = this.scan(h, |f| {
                top[h] = top[h].max(f.seq);
                if (f.kind == STATS || f.kind == STATS_RESET) && stats.is_none_or(|(s, _)| f.seq > s.seq) {
                    stats = Some((f, h));
                }
                if let Some(c) = this.commit_of(f) {
                    let b = &mut best[c.slot as usize];
                    if b.is_none_or(|o| c.seq > o.seq) {
                        *b = Some(c);
                    }
                }
            });
        }
        let half = usize::from(top[1] > top[0]);
        let mut cands = [best[0], best[1]];
        if best[1].map_or(0, |c| c.seq) > best[0].map_or(0, |c| c.seq) {
            cands = [best[1], best[0]];
        }
        let current = cands.into_iter().flatten().find(|c| this.verifies(c));
        self.current = current;
        self.half = half as u8;
        self.tail = tails[half];
        self.next_seq = top[0].max(top[1]).wrapping_add(1).max(1);
        self.boot_seq = self.next_seq;
        self.stats = stats.map(|(s, _)| s);
        // The active half must hold the newest statistics before the other may be erased.
        if let Some((s, h)) = stats {
            if h != half {
                let _ = self.copy_stats(s);
            }
        }
    }

    /// Appends a record to the active half. [`StatsError::Busy`]: no room (compact first).
    fn append(&mut self, kind: u32, head: &[u8], body: Body) -> Result<Found, StatsError> {
        let len = head.len() as u32 + body.len();
        let (_, end) = self.layout.span(self.layout.log[self.half as usize]);
        if self.tail + rec_size(len) > end {
            return Err(StatsError::Busy);
        }
        let at = self.tail;
        // Whatever happens next, this space is used.
        self.tail = at + rec_size(len);
        let seq = self.next_seq;
        self.next_seq = seq.wrapping_add(1).max(1);
        let mut h = [0u8; HEADER as usize];
        for (i, w) in [MAGIC, kind, seq, len].iter().enumerate() {
            h[i * 4..i * 4 + 4].copy_from_slice(&w.to_le_bytes());
        }
        let mut crc = CRC32.digest();
        crc.update(&h);
        crc.update(head);
        let mut p = Prog { pos: at, buf: [0xFF; 64], n: 0, ok: true };
        p.put(&mut self.flash, &h);
        p.put(&mut self.flash, head);
        match body {
            Body::Ram(b) => {
                crc.update(b);
                p.put(&mut self.flash, b);
            }
            Body::Flash { at: from, len } => {
                // Through a small buffer: the source is flash too.
                let mut buf = [0u8; 64];
                let mut i = 0;
                while i < len {
                    let n = (len - i).min(64);
                    buf[..n as usize].copy_from_slice(self.bytes(from + i, n));
                    crc.update(&buf[..n as usize]);
                    p.put(&mut self.flash, &buf[..n as usize]);
                    i += n;
                }
            }
        }
        p.put(&mut self.flash, &crc.finalize().to_le_bytes());
        if !p.finish(&mut self.flash) {
            self.flash_errors = self.flash_errors.saturating_add(1);
            return Err(StatsError::Flash);
        }
        Ok(Found { at, seq, kind, len })
    }

    fn write_commit(&mut self, c: Commit) -> Result<u32, StatsError> {
        let mut p = [0u8; 12];
        for (i, w) in [c.slot as u32, c.len, c.crc].iter().enumerate() {
            p[i * 4..i * 4 + 4].copy_from_slice(&w.to_le_bytes());
        }
        self.append(COMMIT, &p, Body::Ram(&[])).map(|f| f.seq)
    }

    /// Copies statistics record (or reset) `s`, which lies in the other half, into the active one.
    fn copy_stats(&mut self, s: Found) -> Result<(), StatsError> {
        let p = s.at + HEADER;
        let f = if s.kind == STATS {
            let mut head = [0u8; STATS_HEAD as usize];
            head.copy_from_slice(self.bytes(p, STATS_HEAD));
            self.append(STATS, &head, Body::Flash { at: p + STATS_HEAD, len: s.len - STATS_HEAD })?
        } else {
            let crc = self.word(p).to_le_bytes();
            self.append(STATS_RESET, &crc, Body::Ram(&[]))?
        };
        self.stats = Some(f);
        Ok(())
    }

    /// Too little room left in the active half for a commit and a full statistics record?
    fn log_low(&self) -> bool {
        let (_, end) = self.layout.span(self.layout.log[self.half as usize]);
        end.saturating_sub(self.tail) < rec_size(12) + rec_size(STATS_HEAD + MAX_STATS as u32)
    }

    fn compaction(&self) -> Erase {
        let (a, b) = self.layout.log[1 - self.half as usize];
        Erase { next: a, end: b, compact: true }
    }

    /// Queues a compaction of the log into the other half (once), before any slot erase: it is
    /// one small sector and unblocks statistics saves. A slot erase it interrupts starts again
    /// at the sector it was on (a driver erasing in the background finishes that one first).
    fn want_compaction(&mut self) {
        if self.job.is_some_and(|e| e.compact) || self.after.is_some_and(|e| e.compact) {
            return;
        }
        self.after = self.job.take().or(self.after);
        self.job = Some(self.compaction());
    }

    /// After the other half is erased: the current commit (from RAM) and the newest statistics
    /// (from the half that stays) go there, and it becomes the active half.
    fn finish_compaction(&mut self) {
        let old = self.half as usize;
        let (a, b) = self.layout.span(self.layout.log[old]);
        let stats = self.stats.filter(|s| (a..b).contains(&s.at));
        self.half = 1 - self.half;
        self.tail = self.layout.span(self.layout.log[self.half as usize]).0;
        if let Some(c) = self.current {
            if let Ok(seq) = self.write_commit(c) {
                self.current = Some(Commit { seq, ..c });
            }
        }
        if let Some(s) = stats {
            let _ = self.copy_stats(s);
        }
    }

    /// One piece of pending flash work: one sector's erase (started, polled or done), and a
    /// log compaction's copy when its erase is done. Call it between control periods.
    pub fn step(&mut self) {
        if !self.started {
            self.boot();
        }
        let Some(mut e) = self.job else { return };
        if e.next < e.end {
            let from = self.layout.sector_start(e.next);
            let to = self.layout.sector_start(e.next + 1);
            match self.flash.erase_step(from, to) {
                Ok(false) => return,
                Ok(true) => {
                    if let (false, Some((slot, _))) = (e.compact, self.staging) {
                        let (s0, s1) = self.layout.span(self.layout.slots[slot as usize]);
                        if from >= s0 && from < s1 && from - s0 == self.erased_to {
                            self.erased_to = to - s0;
                        }
                    }
                    e.next += 1;
                }
                Err(_) => {
                    self.flash_errors = self.flash_errors.saturating_add(1);
                    // A slot that cannot be erased cannot be uploaded into.
                    if !e.compact {
                        self.staging = None;
                    }
                    self.job = self.after.take();
                    return;
                }
            }
        }
        if e.next < e.end {
            self.job = Some(e);
            return;
        }
        self.job = self.after.take();
        if e.compact {
            self.finish_compaction();
        }
    }

    /// Flash work is pending: an upload waits for its slot's erase; a save may be refused.
    pub fn is_busy(&self) -> bool {
        self.job.is_some()
    }

    fn compacting(&self) -> bool {
        self.job.is_some_and(|e| e.compact)
    }

    /// Saves statistics measured with model `model_crc` at board time `now_ms`. Refused with
    /// [`StatsError::Busy`] while the log is being compacted: call again after some
    /// [`FlashStore::step`]s.
    pub fn save_stats(&mut self, model_crc: u32, now_ms: u64, bytes: &[u8]) -> Result<(), StatsError> {
        if bytes.len() > MAX_STATS {
            return Err(StatsError::TooLarge);
        }
        let mut head = [0u8; STATS_HEAD as usize];
        head[..4].copy_from_slice(&model_crc.to_le_bytes());
        head[4..].copy_from_slice(&now_ms.to_le_bytes());
        self.add_stats(STATS, &head, bytes)
    }

    /// Back to the model's own statistics: [`FlashStore::load_stats`] finds none until the next save.
    pub fn reset_stats(&mut self, model_crc: u32) -> Result<(), StatsError> {
        self.add_stats(STATS_RESET, &model_crc.to_le_bytes(), &[])
    }

    fn add_stats(&mut self, kind: u32, head: &[u8], body: &[u8]) -> Result<(), StatsError> {
        if !self.started {
            self.boot();
        }
        if self.compacting() {
            return Err(StatsError::Busy);
        }
        match self.append(kind, head, Body::Ram(body)) {
            Ok(f) => {
                self.stats = Some(f);
                if self.log_low() {
                    self.want_compaction();
                }
                Ok(())
            }
            Err(StatsError::Busy) => {
                self.want_compaction();
                Err(StatsError::Busy)
            }
            Err(e) => Err(e),
        }
    }

    /// The newest saved statistics for model `model_crc` (none after a reset, or when they
    /// belong to another model).
    pub fn load_stats(&self, model_crc: u32) -> Option<Stats<'_>> {
        let s = self.stats.filter(|s| s.kind == STATS)?;
        let p = s.at + HEADER;
        if self.word(p) != model_crc {
            return None;
        }
        let saved_ms = self.word(p + 4) as u64 | (self.word(p + 8) as u64) << 32;
        Some(Stats {
            model_crc,
            age: StatsAge { saved_ms, this_boot: s.seq >= self.boot_seq, seq: s.seq },
            bytes: self.bytes(p + STATS_HEAD, s.len - STATS_HEAD),
        })
    }

    /// Where the running model came from.
    pub fn model_source(&self) -> ModelSource {
        match self.current {
            Some(c) => ModelSource::Flash { slot: c.slot, seq: c.seq },
            None if self.builtin.is_some_and(|b| !b.is_empty()) => ModelSource::BuiltIn,
            None => ModelSource::None,
        }
    }

    fn staging_slot(&self) -> u8 {
        self.current.map_or(0, |c| 1 - c.slot)
    }
}

impl<F: MappedFlash> ModelStore for FlashStore<F> {
    fn start(&mut self) {
        if !self.started {
            self.boot();
        }
    }

    fn active(&self) -> Option<&[u8]> {
        match self.current {
            Some(c) => {
                let (s, _) = self.layout.span(self.layout.slots[c.slot as usize]);
                Some(self.bytes(s, c.len))
            }
            None => self.builtin.filter(|b| !b.is_empty()),
        }
    }

    fn capacity(&self) -> usize {
        self.layout.slot_len(self.staging_slot() as usize) as usize
    }

    fn begin(&mut self, len: usize) -> Result<(), UploadError> {
        if !self.started {
            self.boot();
        }
        let slot = self.staging_slot();
        if len > self.layout.slot_len(slot as usize) as usize {
            return Err(UploadError::TooLarge);
        }
        self.staging = Some((slot, len as u32));
        self.erased_to = 0;
        // The slot's sectors that the blob needs, from its first.
        let (first, last) = self.layout.slots[slot as usize];
        let s0 = self.layout.sector_start(first);
        let mut end = first;
        while end < last && self.layout.sector_start(end) - s0 < len as u32 {
            end += 1;
        }
        let run = Erase { next: first, end, compact: false };
        if self.compacting() {
            self.after = Some(run);
        } else {
            self.job = Some(run);
            self.after = None;
        }
        // The commit at the end must find room in the log.
        if self.log_low() {
            self.want_compaction();
        }
        Ok(())
    }

    fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), UploadError> {
        let Some((slot, len)) = self.staging else {
            return Err(UploadError::Sequence);
        };
        let end = offset.checked_add(data.len()).ok_or(UploadError::Sequence)?;
        if end > len as usize {
            return Err(UploadError::TooLarge);
        }
        if end > self.erased_to as usize || self.is_busy() {
            // Not erased yet (the board acks `ModelBegin` only after the erase).
            return Err(UploadError::Store);
        }
        let (s0, _) = self.layout.span(self.layout.slots[slot as usize]);
        if write_padded(&mut self.flash, s0 + offset as u32, data) {
            Ok(())
        } else {
            self.flash_errors = self.flash_errors.saturating_add(1);
            Err(UploadError::Store)
        }
    }

    fn staged(&self) -> &[u8] {
        match self.staging {
            Some((slot, len)) => {
                let (s0, _) = self.layout.span(self.layout.slots[slot as usize]);
                self.bytes(s0, len)
            }
            None => &[],
        }
    }

    fn activate(&mut self, crc: u32) -> Result<(), UploadError> {
        let Some((slot, len)) = self.staging else {
            return Err(UploadError::Sequence);
        };
        let c = Commit { slot, len, crc, seq: 0 };
        let seq = match self.write_commit(c) {
            Ok(seq) => seq,
            Err(StatsError::Busy) => {
                // No room after all: compact now, in one go.
                self.want_compaction();
                while self.compacting() {
                    self.step();
                }
                self.write_commit(c).map_err(|_| UploadError::Store)?
            }
            Err(_) => return Err(UploadError::Store),
        };
        self.current = Some(Commit { seq, ..c });
        self.staging = None;
        if self.log_low() {
            self.want_compaction();
        }
        Ok(())
    }

    fn step(&mut self) {
        FlashStore::step(self)
    }

    fn busy(&self) -> bool {
        self.is_busy()
    }

    fn source(&self) -> ModelSource {
        self.model_source()
    }

    fn stats_age(&self, model_crc: u32) -> Option<StatsAge> {
        self.load_stats(model_crc).map(|s| s.age)
    }

    fn reset_stats(&mut self, model_crc: u32) -> bool {
        FlashStore::reset_stats(self, model_crc).is_ok()
    }

    fn save_stats(&mut self, model_crc: u32, now_ms: u64, bytes: &[u8]) -> bool {
        FlashStore::save_stats(self, model_crc, now_ms, bytes).is_ok()
    }

    fn saved_stats(&self, model_crc: u32) -> Option<&[u8]> {
        self.load_stats(model_crc).map(|s| s.bytes)
    }
}

/// Writes `data` at `at` in whole write units: a first or last partial unit is padded with
/// erased bytes, which program nothing. `false` when the flash refused.
fn write_padded<F: NorFlash>(flash: &mut F, at: u32, data: &[u8]) -> bool {
    let w = F::WRITE_SIZE.clamp(1, 64) as u32;
    let lead = at % w;
    let mut p = Prog { pos: at - lead, buf: [0xFF; 64], n: lead as usize, ok: true };
    p.put(flash, data);
    p.finish(flash)
}

#[cfg(test)]
mod tests;
