//! The running model and model uploads.
//!
//! A model blob comes built in (flash) or over the host link in chunks. Uploads go to a staging
//! area behind [`ModelStore`], so a binary can put it in RAM ([`RamStore`]) or flash. Nothing
//! changes until the whole upload arrived, its CRC-32 matches what `ModelBegin` announced and
//! `Model::parse` (plus [`crate::decoder::check_scales`]) accepts it; only then does the store
//! swap staging and active. A bad upload leaves the previous model running.

use crate::decoder;
use msr_shared::blob::{BlobError, Model, CRC32};
use msr_shared::msg::{ModelSource, StatsAge};

/// Why an upload step was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UploadError {
    /// Larger than the staging area.
    TooLarge,
    /// A chunk out of order or past the announced length, or a commit without a begin.
    Sequence,
    /// The staging area could not be written (flash error).
    Store,
    /// All bytes arrived but their CRC-32 differs from the announced one.
    Crc,
    /// The blob failed validation.
    Invalid(BlobError),
    /// A commit before all bytes arrived; the board wants `next` next.
    /// `next`: the byte offset the board wants next.
    #[allow(missing_docs)]
    Incomplete { next: u32 },
}

impl UploadError {
    /// The `detail` number sent with the error.
    pub fn detail(&self) -> u32 {
        match self {
            UploadError::TooLarge => 1,
            UploadError::Sequence => 2,
            UploadError::Store => 3,
            UploadError::Crc => 4,
            UploadError::Invalid(e) => e.code(),
            UploadError::Incomplete { .. } => 5,
        }
    }
}

/// Where model blobs live: one active blob (or none) and a staging area for uploads.
///
/// Implementations keep blobs 4-byte aligned (the decoder's fast paths need aligned tables).
pub trait ModelStore {
    /// The blob in use, if any.
    fn active(&self) -> Option<&[u8]>;
    /// Bytes the staging area holds.
    fn capacity(&self) -> usize;
    /// Prepares staging for a blob of `len` bytes (e.g. erases flash).
    fn begin(&mut self, len: usize) -> Result<(), UploadError>;
    /// Writes `data` at `offset` into staging; `offset + data.len() <= len` is checked before.
    fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), UploadError>;
    /// The staged bytes, `len` of them.
    fn staged(&self) -> &[u8];
    /// Makes the staged blob the active one (a flash store writes its commit record); `crc32`
    /// is the CRC-32 of the staged bytes, as read back from staging.
    fn activate(&mut self, crc32: u32) -> Result<(), UploadError>;
    /// Called once before the first use: a flash store finds its model here.
    fn start(&mut self) {}
    /// One piece of background work (a flash sector erase), between control periods.
    fn step(&mut self) {}
    /// Background work is pending: `begin`'s erase is not done, `write` would be refused.
    fn busy(&self) -> bool {
        false
    }
    /// Where the active blob came from.
    fn source(&self) -> ModelSource;
    /// When the statistics saved for model `model_crc` were saved, if any are.
    fn stats_age(&self, model_crc: u32) -> Option<StatsAge> {
        let _ = model_crc;
        None
    }
    /// Drops the statistics saved for model `model_crc`; `false` if that could not be done now.
    fn reset_stats(&mut self, model_crc: u32) -> bool {
        let _ = model_crc;
        true
    }
    /// Saves statistics measured with model `model_crc` at board time `now_ms`, so that they
    /// survive reset; `false` if they could not be saved now (or this store keeps nothing).
    fn save_stats(&mut self, model_crc: u32, now_ms: u64, bytes: &[u8]) -> bool {
        let _ = (model_crc, now_ms, bytes);
        false
    }
    /// The newest statistics saved for model `model_crc`, if any.
    fn saved_stats(&self, model_crc: u32) -> Option<&[u8]> {
        let _ = model_crc;
        None
    }
}

/// Copies an upload chunk into a staging area: an offset that overflows is out of sequence, one
/// past the area's end too large (the stores' one `write`).
fn write_at(dst: &mut [u8], offset: usize, data: &[u8]) -> Result<(), UploadError> {
    let end = offset.checked_add(data.len()).ok_or(UploadError::Sequence)?;
    dst.get_mut(offset..end).ok_or(UploadError::TooLarge)?.copy_from_slice(data);
    Ok(())
}

#[repr(C, align(8))]
struct Slot<const N: usize>([u8; N]);

/// A store in RAM: two slots of `N` bytes (active and staging, swapped on commit), plus an
/// optional built-in blob (e.g. in flash) that runs until the first good upload.
pub struct RamStore<const N: usize> {
    slots: [Slot<N>; 2],
    lens: [usize; 2],
    /// Which slot is active; `None`: the built-in blob (if any).
    active: Option<usize>,
    builtin: Option<&'static [u8]>,
}

impl<const N: usize> Default for RamStore<N> {
    fn default() -> Self {
        Self::new(None)
    }
}

impl<const N: usize> RamStore<N> {
    /// Empty slots, running `builtin` (if any) until the first good upload.
    pub const fn new(builtin: Option<&'static [u8]>) -> Self {
        RamStore {
            slots: [Slot([0; N]), Slot([0; N])],
            lens: [0; 2],
            active: None,
            builtin,
        }
    }

    fn staging(&self) -> usize {
        match self.active {
            Some(i) => 1 - i,
            None => 0,
        }
    }
}

impl<const N: usize> ModelStore for RamStore<N> {
    fn active(&self) -> Option<&[u8]> {
        match self.active {
            Some(i) => Some(&self.slots[i].0[..self.lens[i]]),
            None => self.builtin,
        }
    }
    fn capacity(&self) -> usize {
        N
    }
    fn begin(&mut self, len: usize) -> Result<(), UploadError> {
        if len > N {
            return Err(UploadError::TooLarge);
        }
        let s = self.staging();
        self.lens[s] = len;
        Ok(())
    }
    fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), UploadError> {
        let s = self.staging();
        write_at(&mut self.slots[s].0, offset, data)
    }
    fn staged(&self) -> &[u8] {
        let s = self.staging();
        &self.slots[s].0[..self.lens[s].min(N)]
    }
    fn activate(&mut self, _crc32: u32) -> Result<(), UploadError> {
        self.active = Some(self.staging());
        Ok(())
    }
    fn source(&self) -> ModelSource {
        match (self.active, self.builtin) {
            (Some(_), _) => ModelSource::Ram,
            (None, Some(_)) => ModelSource::BuiltIn,
            (None, None) => ModelSource::None,
        }
    }
}

/// Validates a blob for this firmware: `Model::parse` and the scale chaining the decoder needs.
pub fn validate(bytes: &[u8]) -> Result<Model<'_>, BlobError> {
    chained(Model::parse(bytes)?)
}

/// [`validate`] without the CRC pass, for a blob that passed [`validate`] and has not changed.
pub fn validate_trusted(bytes: &[u8]) -> Result<Model<'_>, BlobError> {
    chained(Model::parse_trusted(bytes)?)
}

fn chained(m: Model<'_>) -> Result<Model<'_>, BlobError> {
    if let Err(decoder::DecodeError::Scale(i)) = decoder::check_scales(&m) {
        return Err(BlobError::Chain(i));
    }
    Ok(m)
}

/// An upload in progress. Chunks are taken in order only (flash is written once, forwards);
/// what arrived is kept until a `ModelBegin` of another blob, so an upload resumes from the
/// last good chunk after a lost chunk or a restarted host.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Upload {
    state: Option<UploadState>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct UploadState {
    len: usize,
    crc32: u32,
    received: usize,
    /// A gap was reported since the last good chunk (report it once, not per chunk).
    gap_reported: bool,
}

impl Upload {
    /// No upload in progress.
    pub const fn new() -> Self {
        Upload { state: None }
    }

    /// The byte offset wanted next, while an upload is open.
    pub fn next(&self) -> Option<u32> {
        self.state.map(|s| s.received as u32)
    }

    /// A `ModelBegin` was accepted and no commit (or store write failure) has ended it yet.
    pub fn in_progress(&self) -> bool {
        self.state.is_some()
    }

    /// `ModelBegin`: the offset wanted next. An unfinished upload of the same length and CRC
    /// resumes where it stopped; anything else starts over.
    pub fn begin<S: ModelStore>(
        &mut self,
        store: &mut S,
        len: u32,
        crc32: u32,
    ) -> Result<u32, UploadError> {
        if let Some(st) = self.state.as_mut() {
            if st.len == len as usize && st.crc32 == crc32 {
                st.gap_reported = false;
                return Ok(st.received as u32);
            }
        }
        self.state = None;
        let len = len as usize;
        if len > store.capacity() {
            return Err(UploadError::TooLarge);
        }
        store.begin(len)?;
        self.state = Some(UploadState {
            len,
            crc32,
            received: 0,
            gap_reported: false,
        });
        Ok(0)
    }

    /// `ModelChunk`: stores the bytes past what arrived; `Ok(Some(next))` asks the host to go
    /// back to `next` (a chunk came after a gap; said once per gap). Duplicates are ignored.
    pub fn chunk<S: ModelStore>(
        &mut self,
        store: &mut S,
        offset: u32,
        data: &[u8],
    ) -> Result<Option<u32>, UploadError> {
        let Some(st) = self.state.as_mut() else {
            return Err(UploadError::Sequence);
        };
        let offset = offset as usize;
        let Some(end) = offset.checked_add(data.len()).filter(|e| *e <= st.len) else {
            return Err(UploadError::Sequence);
        };
        if offset > st.received {
            let first = !core::mem::replace(&mut st.gap_reported, true);
            return Ok(first.then_some(st.received as u32));
        }
        if end <= st.received {
            return Ok(None);
        }
        let fresh = &data[st.received - offset..];
        if let Err(e) = store.write(st.received, fresh) {
            self.state = None;
            return Err(e);
        }
        st.received = end;
        st.gap_reported = false;
        Ok(None)
    }

    /// `ModelCommit`: checks and switches. Returns the new model's CRC (its identity). Before
    /// all bytes arrived: [`UploadError::Incomplete`], and the upload stays open.
    pub fn commit<S: ModelStore>(&mut self, store: &mut S) -> Result<u32, UploadError> {
        let st = self.state.ok_or(UploadError::Sequence)?;
        if st.received != st.len {
            return Err(UploadError::Incomplete { next: st.received as u32 });
        }
        self.state = None;
        let bytes = store.staged();
        if bytes.len() != st.len || CRC32.checksum(bytes) != st.crc32 {
            return Err(UploadError::Crc);
        }
        let crc = validate(bytes).map_err(UploadError::Invalid)?.crc32;
        store.activate(st.crc32)?;
        Ok(crc)
    }
}

#[cfg(feature = "std")]
mod heap {
    use super::{ModelSource, ModelStore, UploadError};

    /// A model store on the heap (with the `std` feature: the in-process board on a PC, and tests):
    /// the active blob and a staging area, 4-byte aligned.
    pub struct HeapStore {
        slots: [std::vec::Vec<u32>; 2],
        lens: [usize; 2],
        active: Option<usize>,
        capacity: usize,
        /// The active blob came by upload (else: built in).
        uploaded: bool,
    }

    impl HeapStore {
        /// A store whose uploads may take `capacity` bytes, running `builtin` until an upload.
        pub fn new(builtin: Option<&[u8]>, capacity: usize) -> HeapStore {
            let words = capacity.div_ceil(4);
            let mut s = HeapStore {
                slots: [std::vec![0; words], std::vec![0; words]],
                lens: [0; 2],
                active: None,
                capacity,
                uploaded: false,
            };
            if let Some(b) = builtin {
                let mut w = std::vec![0u32; b.len().div_ceil(4)];
                bytemuck::cast_slice_mut::<u32, u8>(&mut w)[..b.len()].copy_from_slice(b);
                s.slots[0] = w;
                s.lens[0] = b.len();
                s.active = Some(0);
                if s.slots[1].len() < words {
                    s.slots[1] = std::vec![0; words];
                }
            }
            s
        }

        fn staging(&self) -> usize {
            self.active.map_or(0, |i| 1 - i)
        }
    }

    impl ModelStore for HeapStore {
        fn active(&self) -> Option<&[u8]> {
            self.active
                .map(|i| &bytemuck::cast_slice::<u32, u8>(&self.slots[i])[..self.lens[i]])
        }
        fn capacity(&self) -> usize {
            self.capacity
        }
        fn begin(&mut self, len: usize) -> Result<(), UploadError> {
            if len > self.capacity {
                return Err(UploadError::TooLarge);
            }
            let s = self.staging();
            if self.slots[s].len() * 4 < len {
                self.slots[s] = std::vec![0; len.div_ceil(4)];
            }
            self.lens[s] = len;
            Ok(())
        }
        fn write(&mut self, offset: usize, data: &[u8]) -> Result<(), UploadError> {
            let s = self.staging();
            super::write_at(bytemuck::cast_slice_mut::<u32, u8>(&mut self.slots[s]), offset, data)
        }
        fn staged(&self) -> &[u8] {
            let s = self.staging();
            let b = bytemuck::cast_slice::<u32, u8>(&self.slots[s]);
            &b[..self.lens[s].min(b.len())]
        }
        fn activate(&mut self, _crc32: u32) -> Result<(), UploadError> {
            self.active = Some(self.staging());
            self.uploaded = true;
            Ok(())
        }
        fn source(&self) -> ModelSource {
            match (self.active, self.uploaded) {
                (None, _) => ModelSource::None,
                (Some(_), false) => ModelSource::BuiltIn,
                (Some(_), true) => ModelSource::Ram,
            }
        }
    }
}
#[cfg(feature = "std")]
pub use heap::HeapStore;
