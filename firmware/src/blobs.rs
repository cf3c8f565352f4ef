//! 8-connected components of a binary mask, in fixed memory, in one pass.
//!
//! Row by row, the mask becomes runs of set pixels; a run joins every run of the row above that
//! touches it (8-connectivity: overlapping or diagonal). Each component's statistics (area,
//! inclusive box, coordinate sums for the centroid, first pixel in raster order) are summed per
//! run and merged on union. A component that no run of the current row continues is finished:
//! it is handed to the caller and its slot is free again. So the slots in use are at most the
//! runs of two rows, `2 * RUNS`, and with `LABELS >= 2 * RUNS` the labeller cannot overflow.
//!
//! The statistics are those of OpenCV's `connectedComponentsWithStats` (8-connectivity): area,
//! box, centroid = mean of the pixel coordinates. When the slots run out ([`Labeller`] with a
//! small `LABELS`), a run that needs a new slot is dropped, the result says `overflow`, and every
//! component that contains a dropped run is withheld, so what is reported is still exact.

use msr_shared::blob::MAX_FACE_W;

/// Runs per row of the widest face.
pub const FACE_RUNS: usize = MAX_FACE_W / 2 + 1;
/// Slots of the board's labeller: enough that a face can never overflow it.
pub const MAX_LABELS: usize = 2 * FACE_RUNS;
/// The labeller the board uses for faces up to `MAX_FACE_W` wide.
pub type FaceLabeller = Labeller<MAX_LABELS, FACE_RUNS>;

const NONE: u16 = u16::MAX;

/// One connected component.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Blob {
    /// Pixels in the component.
    pub area: u32,
    /// Inclusive box.
    pub x0: u16,
    /// Top row of the box (see `x0`).
    pub y0: u16,
    /// Right column of the box, inclusive.
    pub x1: u16,
    /// Bottom row of the box, inclusive.
    pub y1: u16,
    /// Sums of the pixels' column and row indices. 64 bits: a component of every pixel of the
    /// widest, tallest mask the labeller takes sums to about 2^40, far past 32 bits (a 4000 x
    /// 3000 mask already wraps a u32).
    pub sum_x: u64,
    /// See `sum_x`.
    pub sum_y: u64,
    /// Raster index (`y * width + x`) of the component's first pixel: the OpenCV label order.
    pub first: u32,
}

impl Blob {
    /// Mean column and row of the pixels.
    pub fn centroid(&self) -> [f32; 2] {
        let a = self.area.max(1) as f64;
        [
            (self.sum_x as f64 / a) as f32,
            (self.sum_y as f64 / a) as f32,
        ]
    }

    /// Joins `o` into `self` (statistics of the union of two disjoint pixel sets).
    pub fn merge(&mut self, o: &Blob) {
        self.area += o.area;
        self.x0 = self.x0.min(o.x0);
        self.y0 = self.y0.min(o.y0);
        self.x1 = self.x1.max(o.x1);
        self.y1 = self.y1.max(o.y1);
        self.sum_x += o.sum_x;
        self.sum_y += o.sum_y;
        self.first = self.first.min(o.first);
    }
}

/// What one labelling pass found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Summary {
    /// Components handed to the caller.
    pub components: u32,
    /// The slots ran out; some components were withheld.
    pub overflow: bool,
    /// Components withheld because they contained a dropped run.
    pub withheld: u32,
}

/// Why a mask was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaskError {
    /// Zero size, fewer bytes than `width * height`, or wider than the run buffers allow.
    Shape,
}

#[derive(Clone, Copy)]
struct Run {
    x0: u16,
    x1: u16,
    label: u16,
}

const EMPTY_RUN: Run = Run {
    x0: 0,
    x1: 0,
    label: NONE,
};
const EMPTY_BLOB: Blob = Blob {
    area: 0,
    x0: 0,
    y0: 0,
    x1: 0,
    y1: 0,
    sum_x: 0,
    sum_y: 0,
    first: 0,
};

#[derive(Clone, Copy)]
struct Slot {
    blob: Blob,
    parent: u16,
    used: bool,
    tainted: bool,
    /// Last row (plus one) with a run of this component.
    seen: u16,
}

const EMPTY_SLOT: Slot = Slot {
    blob: EMPTY_BLOB,
    parent: NONE,
    used: false,
    tainted: false,
    seen: 0,
};

/// A labeller with `LABELS` component slots for masks up to `2 * RUNS - 1` pixels wide.
pub struct Labeller<const LABELS: usize, const RUNS: usize> {
    slots: [Slot; LABELS],
    /// Released slots, the last released on top.
    free: [u16; LABELS],
    n_free: usize,
    /// Slots `fresh..` have not been used since the last reset (so a reset touches none).
    fresh: usize,
    rows: [[Run; RUNS]; 2],
    n_rows: [usize; 2],
}

impl<const LABELS: usize, const RUNS: usize> Default for Labeller<LABELS, RUNS> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const LABELS: usize, const RUNS: usize> Labeller<LABELS, RUNS> {
    /// An empty labeller; `const`, so it can live in a `static`.
    pub const fn new() -> Self {
        Labeller {
            slots: [EMPTY_SLOT; LABELS],
            free: [0; LABELS],
            n_free: 0,
            fresh: 0,
            rows: [[EMPTY_RUN; RUNS]; 2],
            n_rows: [0; 2],
        }
    }

    /// Widest mask this labeller takes.
    pub const fn max_width() -> usize {
        2 * RUNS - 1
    }

    fn reset(&mut self) {
        self.n_free = 0;
        self.fresh = 0;
        self.n_rows = [0; 2];
    }

    /// A released slot if there is one (the last released), else the lowest fresh one.
    fn alloc(&mut self) -> u16 {
        let l = if self.n_free > 0 {
            self.n_free -= 1;
            self.free[self.n_free]
        } else if self.fresh < LABELS.min(NONE as usize) {
            self.fresh += 1;
            (self.fresh - 1) as u16
        } else {
            return NONE;
        };
        self.slots[l as usize] = Slot {
            used: true,
            parent: l,
            ..EMPTY_SLOT
        };
        l
    }

    fn release(&mut self, l: u16) {
        let s = &mut self.slots[l as usize];
        if s.used {
            s.used = false;
            if self.n_free < LABELS {
                self.free[self.n_free] = l;
                self.n_free += 1;
            }
        }
    }

    fn find(&self, mut l: u16) -> u16 {
        // Chains only link slots of the row above; LABELS steps bound the walk regardless.
        for _ in 0..LABELS {
            let p = self.slots[l as usize].parent;
            if p == l || p == NONE {
                break;
            }
            l = p;
        }
        l
    }

    /// Joins two roots; the survivor keeps both statistics.
    fn union(&mut self, a: u16, b: u16) -> u16 {
        if a == b {
            return a;
        }
        let sb = self.slots[b as usize];
        let sa = &mut self.slots[a as usize];
        sa.blob.merge(&sb.blob);
        sa.tainted |= sb.tainted;
        sa.seen = sa.seen.max(sb.seen);
        self.slots[b as usize].parent = a;
        a
    }

    fn emit<F: FnMut(&Blob)>(&mut self, l: u16, sum: &mut Summary, f: &mut F) {
        let s = self.slots[l as usize];
        if s.tainted {
            sum.withheld += 1;
        } else {
            sum.components += 1;
            f(&s.blob);
        }
        self.release(l);
    }

    /// Labels `mask` (`width x height`, row-major, non-zero = set) and calls `emit` once per
    /// component, in the order components finish.
    pub fn label<F: FnMut(&Blob)>(
        &mut self,
        mask: &[u8],
        width: usize,
        height: usize,
        emit: F,
    ) -> Result<Summary, MaskError> {
        self.label_rows(mask, width, height, &[], emit)
    }

    /// [`label`](Self::label), told how many pixels each row has set: a row `y` with
    /// `counts[y] == 0` is not read, and the others only up to their last set pixel (rows past
    /// `counts` are read whole). The counts must be the mask's own (the saliency that wrote it
    /// counts them); most rows of a face are empty, and reading them was most of this stage's
    /// cost.
    pub fn label_rows<F: FnMut(&Blob)>(
        &mut self,
        mask: &[u8],
        width: usize,
        height: usize,
        counts: &[u16],
        mut emit: F,
    ) -> Result<Summary, MaskError> {
        if width == 0
            || height == 0
            || width > Self::max_width()
            || height > u16::MAX as usize - 1
            || width.checked_mul(height).is_none_or(|n| n > mask.len())
        {
            return Err(MaskError::Shape);
        }
        let mut sum = Summary::default();
        if counts.len() >= height && counts[..height].iter().all(|&c| c == 0) {
            return Ok(sum);
        }
        self.reset();
        let mut cur = 0usize;
        for y in 0..height {
            let prev = 1 - cur;
            match counts.get(y) {
                Some(0) => {
                    self.n_rows[cur] = 0;
                    if self.n_rows[prev] == 0 {
                        // Nothing here, nothing above to finish.
                        cur = prev;
                        continue;
                    }
                }
                c => self.scan_row(&mask[y * width..(y + 1) * width], cur, c.map_or(usize::MAX, |&c| c as usize)),
            }
            self.connect(y, width, cur, prev, &mut sum);
            // Resolve this row's runs to their roots, then free or finish the row above's.
            for i in 0..self.n_rows[cur] {
                let l = self.rows[cur][i].label;
                if l != NONE {
                    self.rows[cur][i].label = self.find(l);
                }
            }
            for i in 0..self.n_rows[prev] {
                let l = self.rows[prev][i].label;
                if l == NONE || !self.slots[l as usize].used {
                    continue;
                }
                if self.slots[l as usize].parent != l {
                    self.release(l);
                } else if self.slots[l as usize].seen != y as u16 + 1 {
                    self.emit(l, &mut sum, &mut emit);
                }
            }
            cur = prev;
        }
        let last = 1 - cur;
        for i in 0..self.n_rows[last] {
            let l = self.rows[last][i].label;
            if l != NONE && self.slots[l as usize].used {
                self.emit(l, &mut sum, &mut emit);
            }
        }
        Ok(sum)
    }

    /// The runs of one row into `rows[slot]`; `set`: the row's set pixels when known (the
    /// scan stops once it has found them all), else `usize::MAX`.
    fn scan_row(&mut self, row: &[u8], slot: usize, mut set: usize) {
        let runs = &mut self.rows[slot];
        let mut n = 0usize;
        let mut x = 0usize;
        let w = row.len();
        while x < w && set > 0 {
            // Skip empty pixels four at a time (one unaligned word load on the board): most of
            // a face is not salient.
            x += 4 * words_while(&row[x..], |v| v == 0);
            while x < w && row[x] == 0 {
                x += 1;
            }
            if x >= w {
                break;
            }
            let x0 = x;
            // A run's pixels four at a time too, while no byte of the word is zero.
            x += 4 * words_while(&row[x..], |v| v.wrapping_sub(0x0101_0101) & !v & 0x8080_8080 == 0);
            while x < w && row[x] != 0 {
                x += 1;
            }
            set = set.saturating_sub(x - x0);
            if n < RUNS {
                runs[n] = Run {
                    x0: x0 as u16,
                    x1: (x - 1) as u16,
                    label: NONE,
                };
                n += 1;
            }
        }
        self.n_rows[slot] = n;
    }

    /// Gives each run of row `cur` a slot, joining the runs of `prev` that touch it.
    fn connect(&mut self, y: usize, width: usize, cur: usize, prev: usize, sum: &mut Summary) {
        let mut j = 0usize;
        for i in 0..self.n_rows[cur] {
            let r = self.rows[cur][i];
            // Runs of the row above that end left of this one's reach never touch a later run.
            while j < self.n_rows[prev] && self.rows[prev][j].x1 as usize + 1 < r.x0 as usize {
                j += 1;
            }
            let mut label = NONE;
            let mut tainted = false;
            let mut k = j;
            while k < self.n_rows[prev] && self.rows[prev][k].x0 as usize <= r.x1 as usize + 1 {
                let pl = self.rows[prev][k].label;
                if pl == NONE {
                    tainted = true;
                } else {
                    let root = self.find(pl);
                    label = if label == NONE {
                        root
                    } else {
                        self.union(label, root)
                    };
                }
                k += 1;
            }
            let len = (r.x1 - r.x0) as u32 + 1;
            // The run's column sum: (x0 + x1) len / 2 is whole, as one of the two factors is even.
            let sum_x = (r.x0 as u32 + r.x1 as u32) as u64 * len as u64 / 2;
            if label == NONE {
                label = self.alloc();
                if label == NONE {
                    sum.overflow = true;
                    continue;
                }
                self.slots[label as usize].blob = Blob {
                    area: len,
                    x0: r.x0,
                    y0: y as u16,
                    x1: r.x1,
                    y1: y as u16,
                    sum_x,
                    sum_y: y as u64 * len as u64,
                    first: (y * width) as u32 + r.x0 as u32,
                };
            } else {
                // Joined to runs of the rows above: the component's top row and first pixel
                // stay, its bottom row is this one (`Blob::merge` of the run, written out).
                let b = &mut self.slots[label as usize].blob;
                b.area += len;
                b.x0 = b.x0.min(r.x0);
                b.x1 = b.x1.max(r.x1);
                b.y1 = y as u16;
                b.sum_x += sum_x;
                b.sum_y += y as u64 * len as u64;
            }
            let s = &mut self.slots[label as usize];
            s.tainted |= tainted;
            s.seen = y as u16 + 1;
            self.rows[cur][i].label = label;
        }
    }
}

/// How many whole words from the start of `bytes` pass `ok`, each read as one (unaligned)
/// load: a mask's rows start anywhere. Written with a pointer because LLVM turns the same
/// test on four byte values into four byte loads.
#[inline(always)]
pub(crate) fn words_while(bytes: &[u8], ok: impl Fn(u32) -> bool) -> usize {
    let (n, p) = (bytes.len() / 4, bytes.as_ptr());
    let mut i = 0;
    while i < n {
        // SAFETY: i < len / 4, so the four bytes from 4 i are inside `bytes`; an unaligned
        // read takes any address.
        let v = unsafe { core::ptr::read_unaligned(p.add(4 * i) as *const u32) };
        if !ok(v) {
            break;
        }
        i += 1;
    }
    i
}

pub mod merge;

#[cfg(test)]
mod tests;
