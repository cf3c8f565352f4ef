//! Online self-calibration: what the board learns about the room's light while it runs.
//!
//! The per-frame fit ([`crate::light`]) takes back a gain and an offset. A lamp that turns or a
//! light that warms also changes the face's shading: a smooth pattern of error that no gain and
//! offset remove, and that statistics measured in the calibration room call salient. The board
//! learns that pattern as it runs, as an offset to the predicted face, one per cell of
//! [`CELL`] x [`CELL`] pixels; the error statistics stay the model's. The rules:
//!
//! 1. Learn only from a frame that shows the face (the fit's verdict is `Face`), has no blob and
//!    no candidate in the confirmation window, in the observe posture with the head still,
//!    whose predicted face came from the cache (a frame that made a new one has paid for it:
//!    `pipeline::Workspace::afresh`; the board decides and calls [`Room::learn`]), and at
//!    most one frame every [`MIN_GAP_US`].
//! 2. Of such a frame, every second pixel of every second row that is neither salient nor in a
//!    salient pixel's pooling window (the mask is not 0) nor clipped (`Lut::lo`, `Lut::hi`): its signed
//!    error `v(I) - pred` against the prediction with the offsets, summed per cell. A mark's
//!    pixels are salient, so they never teach the board that the mark belongs to the face.
//! 3. After [`BATCH`] such frames, on the next frame whose predicted face came from the cache
//!    ([`Room::settle`]; that frame is not learnt from, so the update's cost never falls on a
//!    frame that also pays for samples or a prediction), each cell
//!    with at least [`MIN_SAMPLES`] samples moves its offset by 1/2^[`RATE_SHIFT`] of the
//!    batch's mean error. Then the part of these offsets
//!    that a gain and an offset would make (a least-squares line in the cells' mean predicted
//!    grey level) is taken out: the per-frame fit already takes that part each frame, so the
//!    room would otherwise wander along it unchecked. No offset goes further than [`LIMIT`]
//!    from 0 (the model as calibrated): a slow, bounded follower of the room's shading.
//! 4. The offsets are added to the predicted face ([`Room::apply`]), before the photometric
//!    fit and every saliency test: the error is taken against the face as this room shows it,
//!    and judged by the model's own statistics.
//! 5. Freeze stops rules 1-3 and keeps the offsets; reset returns them to 0. A new model starts
//!    at 0, or at the offsets the store saved for it ([`Room::restore`]).
//!
//! Integers, and one line fit in f32 per update, so the host and the board agree bit for bit
//! (`msr bench --backend qemu` checks it). 96 cells: about 2.6 KiB of RAM (the batch's sums, and
//! the offsets as rule 4 adds them, two words a half cell).
//! Rule 4 costs 1.8 instructions a pixel each time the network runs (a new head pose; added by
//! the decoder's last layer as it stores the face, `decoder::fused`, else 2.3 in a pass of its
//! own, [`rows`]), rule 2 4.2 on a frame learnt from ([`rows`]), rule 3 2.3 on the frame that
//! settles a batch.

use msr_shared::blob::{MAX_FACE_H, MAX_FACE_W};
pub use msr_shared::msg::{RoomReport, RoomState};

/// Side of a cell, pixels.
pub const CELL: usize = 8;
/// Cells across the widest face.
pub const COLS: usize = MAX_FACE_W.div_ceil(CELL);
/// Cells down the tallest face.
pub const ROWS: usize = MAX_FACE_H.div_ceil(CELL);
/// Cells in all.
pub const CELLS: usize = COLS * ROWS;
/// Pixels of a half cell: one entry of [`Room::halves`].
pub const HALF: usize = CELL / 2;
/// Least time between two frames learnt from (rule 1).
pub const MIN_GAP_US: u64 = 400_000;
/// Frames per update (rule 3).
pub const BATCH: u16 = 8;
/// Each update moves an offset `1 / 2^RATE_SHIFT` of the way (rule 3).
pub const RATE_SHIFT: u32 = 3;
/// Farthest an offset may move from the calibrated statistics: 12 grey levels, Q8.8.
pub const LIMIT: i16 = 12 * 256;
/// Samples a cell needs in a batch to be updated (a whole cell gives 16 a frame).
pub const MIN_SAMPLES: u32 = 32;
/// Bytes of [`Room::save`]: a version, the cell side, the columns and rows, then the offsets.
pub const SAVED_LEN: usize = 4 + 2 * CELLS;
/// Bytes from one row of cells of [`Room::halves`] to the next.
pub const HALVES_STRIDE: usize = 2 * COLS * core::mem::size_of::<rows::Packed>();
const VERSION: u8 = 1;

pub mod rows;

/// One cell's samples in the batch being gathered (the routines of [`rows`] read and write
/// the three words in this order).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Acc {
    /// Their errors, Q8.8.
    pub sum: i32,
    /// Their predicted grey levels, Q8.8 (for rule 3's line).
    pub pred: i32,
    /// How many.
    pub count: u32,
}

impl Acc {
    /// No samples.
    pub const ZERO: Acc = Acc { sum: 0, pred: 0, count: 0 };
}

/// The learnt offsets and the batch being gathered.
#[derive(Clone, Debug)]
pub struct Room {
    /// The offsets as rule 4's routines add them ([`rows::Packed`]; the offset itself is
    /// `add - sub`, [`Room::offset`]), twice a cell: one for each half of [`HALF`] pixels, as
    /// the decoder's last layer writes its outputs in groups of four ([`Room::halves`]). The
    /// only copy of the offsets (RAM: the board's state is within 60 KiB).
    packed: [rows::Packed; 2 * CELLS],
    /// Some offset is not 0 (rule 4 has something to add).
    any: bool,
    acc: [Acc; CELLS],
    batch: u16,
    /// The batch is complete: [`Room::settle`] updates the offsets.
    pending: bool,
    frozen: bool,
    last_us: Option<u64>,
    frames: u32,
    updates: u32,
    generation: u32,
}

impl Default for Room {
    fn default() -> Self {
        Self::new()
    }
}

impl Room {
    /// Offsets 0, learning.
    pub const fn new() -> Self {
        Room {
            packed: [rows::Packed::ZERO; 2 * CELLS],
            any: false,
            acc: [Acc::ZERO; CELLS],
            batch: 0,
            pending: false,
            frozen: false,
            last_us: None,
            frames: 0,
            updates: 0,
            generation: 0,
        }
    }

    /// Back to the calibrated statistics (offsets 0, counters 0); frozen or not stays.
    pub fn reset(&mut self) {
        // Field by field: `*self = Room::new()` may build the 2.7 KiB value on the stack first.
        self.packed.fill(rows::Packed::ZERO);
        self.any = false;
        self.clear_batch();
        self.last_us = None;
        self.frames = 0;
        self.updates = 0;
        self.generation = self.generation.wrapping_add(1);
    }

    /// Stops (`true`) or resumes learning; the offsets stay as they are.
    pub fn freeze(&mut self, frozen: bool) {
        self.frozen = frozen;
        self.clear_batch();
    }

    /// Whether learning is stopped.
    pub fn frozen(&self) -> bool {
        self.frozen
    }

    /// Changes whenever the offsets do: part of the threshold table's cache key.
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// The offset of the cell holding pixel `(x, y)`, Q8.8 grey levels.
    pub fn offset_at(&self, x: usize, y: usize) -> i16 {
        let c = (y / CELL) * COLS + x / CELL;
        if x < COLS * CELL && c < CELLS {
            self.offset(c)
        } else {
            0
        }
    }

    /// Every offset, row-major over [`COLS`] x [`ROWS`] cells.
    pub fn offsets(&self) -> [i16; CELLS] {
        core::array::from_fn(|c| self.offset(c))
    }

    /// Cell `c`'s offset: `add - sub` of its packed words (`Packed::of` adds 255 to both).
    fn offset(&self, c: usize) -> i16 {
        let p = self.packed[2 * c];
        ((p.add & 0xffff) as i32 - (p.sub & 0xffff) as i32) as i16
    }

    /// Sets cell `c`'s offset (both halves); [`Room::refresh`] after the last.
    fn set(&mut self, c: usize, o: i16) {
        self.packed[2 * c..2 * c + 2].fill(rows::Packed::of(o));
    }

    /// `any` and `generation` after the offsets changed.
    fn refresh(&mut self) {
        self.any = (0..CELLS).any(|c| self.offset(c) != 0);
        self.generation = self.generation.wrapping_add(1);
    }

    /// Sets every offset.
    pub(crate) fn set_offsets(&mut self, offsets: &[i16; CELLS]) {
        for (c, &o) in offsets.iter().enumerate() {
            self.set(c, o);
        }
        self.refresh();
    }

    /// Rule 4: adds each pixel's cell offset to the predicted face `pred` (Q8.8, `w` pixels a
    /// row): `(min(p, 65280) + o).clamp(0, 65280)`, the sum held to the grey range. Nothing to
    /// do while every offset is 0.
    pub fn apply(&self, pred: &mut [u16], w: usize) {
        if w == 0 || w > MAX_FACE_W || !self.any {
            return;
        }
        let n = (pred.len() / w).min(MAX_FACE_H);
        if n == 0 {
            return;
        }
        let job = rows::ApplyJob {
            pred: pred.as_mut_ptr(),
            cells: self.packed.as_ptr(),
            full: (w / CELL) as u32,
            tail: (w % CELL) as u32,
            rows: n as u32,
            stride: HALVES_STRIDE as u32,
        };
        // SAFETY: `n * w <= pred.len()`; `n <= MAX_FACE_H` needs at most `ROWS` rows of
        // cells and `w <= MAX_FACE_W` at most `COLS` cells a row, inside `packed`.
        unsafe { rows::apply(&job) };
    }

    /// Rule 4 as the decoder's last layer takes it, while some offset is not 0: the offsets
    /// ([`rows::Packed`]) of each half cell of [`HALF`] pixels, row-major, [`HALVES_STRIDE`]
    /// bytes from one row of cells to the next. Pixel `(x, y)` takes entry
    /// `(y / CELL) * 2 * COLS + x / HALF`, which adds what [`Room::apply`] adds.
    pub fn halves(&self) -> Option<&[rows::Packed; 2 * CELLS]> {
        self.any.then_some(&self.packed)
    }

    /// Rules 1 and 2 for one frame the board may learn from, taken at `now_us`: `frame` the
    /// crop, `pred` the prediction with the offsets (Q8.8), `lut` the frame's fitted grey
    /// levels, `mask` the saliency mask, `w` the face's width. Returns true when the offsets
    /// changed (the prediction must be made again): only on the frame after a batch's last,
    /// which this call settles ([`Room::settle`]) instead of learning from (its prediction has
    /// the offsets of before). The board calls this or `settle` on every frame, so the update
    /// comes on the frame after the batch's last either way.
    pub fn learn(&mut self, now_us: u64, frame: &[u8], pred: &[u16], lut: &crate::light::Lut, mask: &[u8], w: usize) -> bool {
        if self.frozen || w == 0 || w > MAX_FACE_W {
            return false;
        }
        // Before the gap's test: the frame right after the batch's last settles it. Not learnt
        // from: its prediction has the offsets of before the update.
        if self.pending {
            return self.settle();
        }
        if self.last_us.is_some_and(|t| now_us.saturating_sub(t) < MIN_GAP_US) {
            return false;
        }
        self.last_us = Some(now_us);
        // Strictly between the clip levels: `f - (lo + 1) < hi - lo - 1`, one test; with
        // constants when they are the camera's own 0 and 255 (most frames: the rows' last,
        // partial cells take 300 instructions fewer a frame on the board).
        let (first, span) = (lut.lo.wrapping_add(1), lut.hi.saturating_sub(lut.lo).saturating_sub(1));
        if (first, span) == (1, 254) {
            self.gather(frame, pred, &lut.v, mask, w, 1, 254);
        } else {
            self.gather(frame, pred, &lut.v, mask, w, first, span);
        }
        self.frames = self.frames.saturating_add(1);
        self.batch += 1;
        self.pending = self.batch >= BATCH;
        false
    }

    /// Whether a complete batch waits for [`Room::settle`].
    pub fn pending(&self) -> bool {
        self.pending
    }

    /// Rule 3 once a batch is complete (else nothing): the offsets move. Returns true when they
    /// changed (the prediction must be made again).
    pub fn settle(&mut self) -> bool {
        if !self.pending {
            return false;
        }
        // Moved offsets (not yet clamped), and the least-squares line through them in the
        // cells' mean predicted grey level. In f32: IEEE single on the host and the board
        // alike (no fused operations), so the result is the same bit for bit.
        let mut moved = [0i32; CELLS];
        let mut level = [0f32; CELLS];
        let (mut n, mut so, mut sp, mut sop, mut spp) = (0f32, 0f32, 0f32, 0f32, 0f32);
        for c in 0..CELLS {
            let Acc { sum, pred, count: k } = self.acc[c];
            if k < MIN_SAMPLES {
                continue;
            }
            let o = self.offset(c) as i32 + ((sum / k as i32) >> RATE_SHIFT);
            let p = (pred / k as i32) as f32 / 256.0;
            moved[c] = o;
            level[c] = p;
            n += 1.0;
            so += o as f32;
            sp += p;
            sop += o as f32 * p;
            spp += p * p;
        }
        let (var, cov) = (n * spp - sp * sp, n * sop - so * sp);
        let b = if var > 0.0 { cov / var } else { 0.0 };
        let a = if n > 0.0 { (so - b * sp) / n } else { 0.0 };
        let mut changed = false;
        for c in 0..CELLS {
            if self.acc[c].count < MIN_SAMPLES {
                continue;
            }
            let line = (a + b * level[c]) as i32;
            let o = (moved[c] - line).clamp(-(LIMIT as i32), LIMIT as i32) as i16;
            if o != self.offset(c) {
                self.set(c, o);
                changed = true;
            }
        }
        self.clear_batch();
        self.updates = self.updates.saturating_add(1);
        if changed {
            self.refresh();
        }
        changed
    }

    /// Rule 2's sums for one frame: the pixels whose grey level `f` has `f - first < span`
    /// (in u32: `f` under `first` is past any span, as it is in bytes).
    #[allow(clippy::too_many_arguments)]
    fn gather(&mut self, frame: &[u8], pred: &[u16], v: &[u16; 256], mask: &[u8], w: usize, first: u8, span: u8) {
        let n = frame.len().min(pred.len()).min(mask.len());
        let (full, tail) = (w / CELL, w % CELL);
        let (first, span) = (first as u32, span as u32);
        // No sum can overflow: a cell takes at most (CELL / 2)^2 samples a frame, BATCH frames.
        for y in (0..(n / w).min(MAX_FACE_H)).step_by(2) {
            let at = y * w;
            let (f, p, m) = (&frame[at..at + w], &pred[at..at + w], &mask[at..at + w]);
            let acc = &mut self.acc[(y / CELL) * COLS..][..w.div_ceil(CELL)];
            if full > 0 {
                let job = rows::GatherJob {
                    frame: f.as_ptr(),
                    pred: p.as_ptr(),
                    mask: m.as_ptr(),
                    v: v.as_ptr(),
                    acc: acc.as_mut_ptr(),
                    cells: full as u32,
                    first,
                    span,
                };
                // SAFETY: `full` whole cells lie inside each row and `acc` (w.div_ceil(CELL) >= full
                // sums); `v` has 256 entries.
                unsafe { rows::gather(&job) };
            }
            if tail > 0 {
                let a = &mut acc[full];
                for x in (full * CELL..w).step_by(2) {
                    if m[x] == 0 && (f[x] as u32).wrapping_sub(first) < span {
                        a.sum += v[f[x] as usize] as i32 - p[x] as i32;
                        a.pred += p[x] as i32;
                        a.count += 1;
                    }
                }
            }
        }
    }

    fn clear_batch(&mut self) {
        self.acc.fill(Acc::ZERO);
        self.batch = 0;
        self.pending = false;
    }

    /// The state for `Status`; `applies`: a model is loaded (rule 4 has a face to add to).
    pub fn report(&self, applies: bool) -> RoomReport {
        let offsets = self.offsets();
        let largest = offsets.iter().map(|o| o.unsigned_abs()).max().unwrap_or(0);
        RoomReport {
            state: match (applies, self.frozen) {
                (false, _) => RoomState::Off,
                (true, false) => RoomState::Learning,
                (true, true) => RoomState::Frozen,
            },
            frames: self.frames,
            updates: self.updates,
            largest_q88: largest,
            at_limit: offsets.iter().filter(|o| o.unsigned_abs() >= LIMIT as u16).count() as u16,
        }
    }

    /// The offsets as the store keeps them ([`SAVED_LEN`] bytes).
    pub fn save(&self, out: &mut [u8; SAVED_LEN]) {
        out[..4].copy_from_slice(&[VERSION, CELL as u8, COLS as u8, ROWS as u8]);
        for (o, b) in self.offsets().iter().zip(out[4..].chunks_exact_mut(2)) {
            b.copy_from_slice(&o.to_le_bytes());
        }
    }

    /// Takes offsets saved by [`Room::save`]; anything else (another version or layout, a
    /// length that differs, an offset past [`LIMIT`]) is refused whole and changes nothing.
    pub fn restore(&mut self, bytes: &[u8]) -> bool {
        if bytes.len() != SAVED_LEN || bytes[..4] != [VERSION, CELL as u8, COLS as u8, ROWS as u8] {
            return false;
        }
        let mut offset = [0i16; CELLS];
        for (o, b) in offset.iter_mut().zip(bytes[4..].chunks_exact(2)) {
            *o = i16::from_le_bytes([b[0], b[1]]);
            if o.unsigned_abs() > LIMIT as u16 {
                return false;
            }
        }
        self.reset();
        self.set_offsets(&offset);
        true
    }
}

#[cfg(test)]
mod tests;
