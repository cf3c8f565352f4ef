//! The colour stage's saliency per pixel, for pictures, reports and calibration: each pixel's
//! block error over its widened spread (`msr_firmware::chroma`, rules 1 to 3, by the board's
//! own code), in spreads.
use msr_firmware::chroma::{self, Frame, Q_ONE, WIDEN_ONE};
use msr_shared::blob::ChromaCell;

/// Each pixel's colour saliency of an `h x w` face with its chroma `planes`, in spreads (the
/// board's rule 4 compares it with the threshold), row-major, and the frame's colour
/// statistics; `None` when the sizes disagree.
pub fn saliency(c: &ChromaCell, grey: &[u8], planes: &[u8], h: usize, w: usize) -> Option<(Vec<f32>, Frame)> {
    let mut e = vec![[0i16; 2]; msr_shared::blob::chroma::blocks(h, w)];
    let f = chroma::errors(c, grey, planes, h, w, &mut e)?;
    let widen = f.widen as f64 / WIDEN_ONE as f64;
    let bw = w.div_ceil(2);
    let mut sal = vec![0f32; h * w];
    for y in 0..h {
        for x in 0..w {
            let b = (y / 2) * bw + x / 2;
            let (_, s) = c.at(b)?;
            sal[y * w + x] = (chroma::q16(e[b], s) as f64 / Q_ONE as f64 / widen).sqrt() as f32;
        }
    }
    Some((sal, f))
}
