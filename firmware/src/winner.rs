//! The winner: the largest component of at least the minimum area.
//!
//! Tie rule: of equal areas, the component whose first pixel comes first in raster order (top
//! row first, then leftmost) wins; that is the one with the lower OpenCV label.

use crate::blobs::Blob;

/// The published minimum mark area, in pixels.
pub const DEFAULT_MIN_AREA: u16 = 30;

/// Keeps the best component offered so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Winner {
    /// Smallest area, pixels, a component needs to be a candidate.
    pub min_area: u32,
    /// The largest candidate so far (ties: first pixel first in raster order).
    pub best: Option<Blob>,
    /// Components offered that were large enough.
    pub candidates: u32,
}

impl Winner {
    /// No winner yet; components under `min_area` pixels will be ignored.
    pub const fn new(min_area: u16) -> Self {
        Winner {
            min_area: min_area as u32,
            best: None,
            candidates: 0,
        }
    }

    /// Considers one component; keeps it if it beats the best so far.
    pub fn offer(&mut self, b: &Blob) {
        if b.area < self.min_area {
            return;
        }
        self.candidates += 1;
        let better = match &self.best {
            None => true,
            Some(cur) => b.area > cur.area || (b.area == cur.area && b.first < cur.first),
        };
        if better {
            self.best = Some(*b);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob(area: u32, first: u32) -> Blob {
        Blob {
            area,
            x0: 0,
            y0: 0,
            x1: 0,
            y1: 0,
            sum_x: 0,
            sum_y: 0,
            first,
        }
    }

    #[test]
    fn largest_above_min_area_and_ties_by_raster_order() {
        let mut w = Winner::new(30);
        w.offer(&blob(29, 0));
        assert_eq!(w.best, None);
        w.offer(&blob(40, 50));
        w.offer(&blob(35, 1));
        w.offer(&blob(40, 20));
        w.offer(&blob(40, 90));
        assert_eq!(w.best, Some(blob(40, 20)));
        assert_eq!(w.candidates, 4);
    }
}
