//! The blob stage after the mask, on the host: the firmware's own integer code (its 8-connected
//! labeller, fragment merge and winner), with a labeller sized for any mask the host sees. The
//! float engine, calibration, `msr blobs` and `msr eval` all take their blobs from here, so the
//! host cannot disagree with the board about what a mask holds.
use anyhow::{anyhow, ensure, Result};
use msr_firmware::blobs::{self as fw, merge, Labeller};
use msr_shared::blob::Merge;
use serde::Serialize;
use std::cell::RefCell;

/// A connected component (or merged group) of salient pixels. Coordinates are in whatever frame
/// it was found in (face or full frame; see [`Blob::offset`]); boxes are inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Blob {
    /// Pixels in the blob.
    pub area: u32,
    /// Bounding box `[x0, y0, x1, y1]`, pixels, inclusive.
    pub box_xyxy: [u32; 4],
    /// Mean of the pixel coordinates (x, y).
    pub centroid: [f64; 2],
}

impl Blob {
    /// The same blob `dx`, `dy` pixels further right and down (face crop -> full frame).
    pub fn offset(&self, dx: u32, dy: u32) -> Blob {
        let [x0, y0, x1, y1] = self.box_xyxy;
        Blob {
            area: self.area,
            box_xyxy: [x0 + dx, y0 + dy, x1 + dx, y1 + dy],
            centroid: [self.centroid[0] + dx as f64, self.centroid[1] + dy as f64],
        }
    }
}

impl From<&fw::Blob> for Blob {
    fn from(b: &fw::Blob) -> Blob {
        let a = b.area.max(1) as f64;
        Blob {
            area: b.area,
            box_xyxy: [b.x0 as u32, b.y0 as u32, b.x1 as u32, b.y1 as u32],
            centroid: [b.sum_x as f64 / a, b.sum_y as f64 / a],
        }
    }
}

/// Widest mask the host labeller takes (the board's own takes faces up to `MAX_FACE_W`).
pub const HOST_MAX_WIDTH: usize = 2 * HOST_RUNS - 1;
const HOST_RUNS: usize = 2048;
/// Enough slots for two rows of runs: the labeller cannot overflow.
const HOST_LABELS: usize = 2 * HOST_RUNS;
type HostLabeller = Labeller<HOST_LABELS, HOST_RUNS>;

thread_local! {
    // One labeller per thread, reused: it resets itself on every mask.
    static LABELLER: RefCell<Box<HostLabeller>> = RefCell::new(Box::new(HostLabeller::new()));
}

fn check(mask: &[bool], w: usize, h: usize) -> Result<Vec<u8>> {
    ensure!(
        w >= 1 && h >= 1 && w <= HOST_MAX_WIDTH && h < u16::MAX as usize,
        "mask {w}x{h} is outside 1..={HOST_MAX_WIDTH} x 1..{}",
        u16::MAX
    );
    ensure!(mask.len() == w * h, "mask has {} pixels, not {w}x{h}", mask.len());
    Ok(mask.iter().map(|&m| m as u8).collect())
}

/// Every 8-connected blob of `mask` (row-major `w x h`), in raster order of each blob's first
/// pixel (OpenCV 5 numbers them in its own block order: compare as sets), and whether the
/// labeller overflowed (it cannot at this size; kept for the report).
pub fn label(mask: &[bool], w: usize, h: usize) -> Result<(Vec<Blob>, bool)> {
    let bytes = check(mask, w, h)?;
    let mut found: Vec<fw::Blob> = Vec::new();
    let summary = LABELLER
        .with(|l| l.borrow_mut().label(&bytes, w, h, |b| found.push(*b)))
        .map_err(|e| anyhow!("firmware blob stage refused the mask: {e:?}"))?;
    found.sort_by_key(|b| b.first);
    Ok((found.iter().map(Blob::from).collect(), summary.overflow))
}

/// The board's winner of `mask`: its components, merged first when `merge` is on (a frame with
/// more than `MAX_FRAGMENTS` fragments is not merged), the largest of at least `min_area`
/// pixels, the earlier first pixel on ties (`msr_firmware::blobs::merge::pick`).
pub fn pick(mask: &[bool], w: usize, h: usize, min_area: u16, merge: Merge) -> Result<Option<Blob>> {
    let bytes = check(mask, w, h)?;
    let (best, _) = LABELLER.with(|l| merge::pick(&mut **l.borrow_mut(), &bytes, w, h, &[], min_area, merge));
    Ok(best.as_ref().map(Blob::from))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merge_joins_a_broken_mark_that_the_papers_stage_misses() {
        // A 12 x 12 mark seen only over a 4 px grid of 2 x 2 spots (36 px), as on the taxel cover.
        let (w, h) = (30, 20);
        let mut mask = vec![false; w * h];
        for y in (4..16).step_by(4) {
            for x in (6..18).step_by(4) {
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    mask[(y + dy) * w + x + dx] = true;
                }
            }
        }
        assert_eq!(pick(&mask, w, h, 30, Merge::OFF).unwrap(), None);
        assert_eq!(pick(&mask, w, h, 30, Merge { margin: 2, fragment: 3 }).unwrap(), None, "gaps of 2 need margin 3");
        let b = pick(&mask, w, h, 30, Merge { margin: 3, fragment: 3 }).unwrap().unwrap();
        assert_eq!((b.area, b.box_xyxy), (36, [6, 4, 15, 13]));
        assert_eq!(b.centroid, [10.5, 8.5]);
    }

    #[test]
    fn blobs_are_8_connected_and_filtered_by_area() {
        // Two diagonal pixels are one 8-connected blob; the lone pixel is its own.
        #[rustfmt::skip]
        let m = [
            true,  false, false, false,
            false, true,  false, true,
            false, false, false, false,
        ].map(|v| v);
        let (all, overflow) = label(&m, 4, 3).unwrap();
        assert!(!overflow);
        assert_eq!(all.len(), 2);
        assert_eq!((all[0].area, all[0].box_xyxy, all[0].centroid), (2, [0, 0, 1, 1], [0.5, 0.5]));
        assert_eq!((all[1].area, all[1].box_xyxy), (1, [3, 1, 3, 1]));
        assert_eq!(pick(&m, 4, 3, 2, Merge::OFF).unwrap().map(|b| b.area), Some(2));
        assert_eq!(pick(&m, 4, 3, 3, Merge::OFF).unwrap(), None);
        // A mask of the wrong size is an error, not a panic.
        assert!(label(&m, 5, 3).is_err());
        assert!(pick(&m, 0, 3, 1, Merge::OFF).is_err());
    }
}
