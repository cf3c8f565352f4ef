//! Optional fragment merge (a deviation from the paper, off unless the model enables it): a mark
//! whose grey is close to a textured cover differs mostly over the texture's dark spots, so its
//! salient pixels break up into pieces that no single 8-connected component of `min_area` holds.
//!
//! As OpenMV's `find_blobs(merge=True, margin=N)`: components of at least `fragment` pixels are
//! kept; two whose boxes come within the margin (one box grown by `margin` pixels on every side
//! overlaps the other) are merged (area and coordinate sums added, boxes joined, the earlier
//! first pixel kept), again and again until no two are that close. Merging only grows boxes, so
//! the groups do not depend on the order the components arrive in. The winner is then the
//! largest group of at least `min_area` pixels (ties: first pixel first in raster order).
//!
//! At most [`MAX_FRAGMENTS`] fragments are kept; a frame with more (a face that is salient all
//! over) is not merged at all: the caller uses the paper's winner for it.

use super::{Blob, Labeller, Summary};
use msr_shared::blob::Merge;

/// Fragments kept per frame.
pub const MAX_FRAGMENTS: usize = 32;

/// Whether box `a` grown by `m` pixels overlaps box `b`.
#[inline]
pub fn near(a: &Blob, b: &Blob, m: u16) -> bool {
    let m = m as u32;
    a.x0 as u32 <= b.x1 as u32 + m
        && b.x0 as u32 <= a.x1 as u32 + m
        && a.y0 as u32 <= b.y1 as u32 + m
        && b.y0 as u32 <= a.y1 as u32 + m
}

/// The fragments of one frame.
pub struct Fragments {
    items: [Blob; MAX_FRAGMENTS],
    n: usize,
    fragment: u32,
    /// More fragments than fit: the frame is not merged.
    pub overflow: bool,
}

impl Fragments {
    /// No fragments yet; components smaller than `fragment` pixels will be dropped.
    pub const fn new(fragment: u16) -> Self {
        Fragments {
            items: [super::EMPTY_BLOB; MAX_FRAGMENTS],
            n: 0,
            fragment: fragment as u32,
            overflow: false,
        }
    }

    /// Keeps `b` when it is large enough to be a fragment.
    pub fn offer(&mut self, b: &Blob) {
        if b.area < self.fragment {
            return;
        }
        if self.n == MAX_FRAGMENTS {
            self.overflow = true;
            return;
        }
        self.items[self.n] = *b;
        self.n += 1;
    }

    /// Merges until no two fragments are within `margin`; returns the groups (None after an
    /// overflow).
    pub fn merge(&mut self, margin: u8) -> Option<&[Blob]> {
        if self.overflow {
            return None;
        }
        let m = margin as u16;
        let mut changed = true;
        while changed {
            changed = false;
            let mut i = 0;
            while i < self.n {
                let mut j = i + 1;
                while j < self.n {
                    if near(&self.items[i], &self.items[j], m) {
                        let b = self.items[j];
                        self.items[i].merge(&b);
                        self.n -= 1;
                        self.items[j] = self.items[self.n];
                        changed = true;
                    } else {
                        j += 1;
                    }
                }
                i += 1;
            }
        }
        Some(&self.items[..self.n])
    }
}

/// Stages 3 and 4 on a mask: the components, and the winner among them, or among the merged
/// fragments when `merge` is on (the paper's winner for a frame that overflows the fragments).
/// `counts`: the mask's set pixels per row, when known (`Labeller::label_rows`), else empty.
pub fn pick<const L: usize, const R: usize>(
    labeller: &mut Labeller<L, R>,
    mask: &[u8],
    w: usize,
    h: usize,
    counts: &[u16],
    min_area: u16,
    merge: Merge,
) -> (Option<Blob>, Summary) {
    let mut plain = crate::winner::Winner::new(min_area);
    // Only a merge needs the fragments' table (1 KiB that every frame would clear).
    let mut frags = merge.is_on().then(|| Fragments::new(merge.fragment));
    let summary = labeller
        .label_rows(mask, w, h, counts, |b| {
            plain.offer(b);
            if let Some(f) = frags.as_mut() {
                f.offer(b);
            }
        })
        .unwrap_or(Summary {
            overflow: true,
            ..Summary::default()
        });
    let best = match frags.as_mut() {
        Some(f) => winner(f, merge, min_area).unwrap_or(plain.best),
        None => plain.best,
    };
    (best, summary)
}

/// The merged groups' winner when `merge` is on and the frame did not overflow; `None` means
/// "use the paper's winner".
pub fn winner(frags: &mut Fragments, merge: Merge, min_area: u16) -> Option<Option<Blob>> {
    if !merge.is_on() {
        return None;
    }
    let groups = frags.merge(merge.margin)?;
    let mut w = crate::winner::Winner::new(min_area);
    for g in groups {
        w.offer(g);
    }
    Some(w.best)
}
