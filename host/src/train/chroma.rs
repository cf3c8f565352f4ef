//! The face's colour for the blob's chroma section (`msr_shared::blob::chroma`), from the
//! training frames' chroma planes. The board's stage is `msr_firmware::chroma`; every number
//! here is measured with its own functions, so the statistics are those it will compute.
//!
//! Tables per cell of the model's pose grid, as its grey statistics: at the edges of the head's
//! range the crop's border shows the face's edge and what lies behind it, whose colour the
//! middle poses never see.
//!
//! 1. Each block's mean normalised chroma over the frames, rounded.
//! 2. Each block's spread: the root mean square over the frames of its error after the frame's
//!    shift (the board's rule 2), per axis; at least [`SPREAD_FLOOR`].
//! 3. The reference: the [`calibrate::SPREAD_QUANTILE`] of the frames' median `q` (the board's
//!    rule 3 widens a frame's spreads by how far its own median lies beyond it).
//! 4. The threshold: [`MARGIN`] times the largest detection score any training frame's colour
//!    gives alone (the highest threshold at which a blob of `min_area` survives), at least
//!    [`MIN_THRESHOLD`].
use crate::data::crop::{CropMode, Face};
use crate::data::Dataset;
use crate::eval::metrics;
use crate::train::calibrate;
use anyhow::{anyhow, ensure, Context, Result};
use msr_firmware::chroma::{self as fw, Q_ONE};
use msr_shared::blob::chroma::{block_grey, blocks, normalise, SPREAD_ONE};
use msr_shared::blob::{set_chroma, ChromaCell, ChromaSpec, Model, PoseGrid};
use msr_sim::layout::Split;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The least spread, in `1 / SPREAD_ONE` units: half a unit of normalised chroma, which comes in
/// whole units (its rounding alone spreads 0.29).
pub const SPREAD_FLOOR: u8 = SPREAD_ONE / 2;
/// Rule 4's factor over the training frames' largest score.
pub const MARGIN: f64 = 1.25;
/// Rule 4's least threshold, in spreads.
pub const MIN_THRESHOLD: f64 = 5.0;

/// What the calibration found, for the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChromaCalibration {
    /// Frames the statistics came from.
    pub frames: usize,
    /// Sets of tables: one per pose cell, or one.
    pub cells: usize,
    /// The threshold chosen (rule 4), in spreads.
    pub threshold: f64,
    /// The training frames' largest detection score by colour alone.
    pub max_score: f64,
    /// The reference median `q` (rule 3), in spreads squared.
    pub spread_ref: f64,
    /// The median block spread, normalised chroma units.
    pub median_spread: f64,
}

/// Block `b`'s normalised chroma `[u, v]` in a face's grey and planes.
fn block_chroma(grey: &[u8], planes: &[u8], h: usize, w: usize, b: usize) -> [i8; 2] {
    let n = blocks(h, w);
    let (sum, px) = block_grey(grey, h, w, b);
    [normalise(planes[b], sum, px), normalise(planes[n + b], sum, px)]
}

/// Fewest frames a pose cell's own tables are made from; a cell with fewer takes the tables
/// of all the frames.
pub const MIN_CELL_FRAMES: usize = 20;

/// Rules 1 and 2 over `faces`: the mean chroma and spread of each block.
fn tables_of(faces: &[&Face], h: usize, w: usize) -> Result<(Vec<[i8; 2]>, Vec<u8>)> {
    let n = blocks(h, w);
    let mut sums = vec![[0i64; 2]; n];
    for f in faces {
        for (b, s) in sums.iter_mut().enumerate() {
            let c = block_chroma(&f.grey, &f.chroma, h, w, b);
            s[0] += c[0] as i64;
            s[1] += c[1] as i64;
        }
    }
    let k = faces.len() as f64;
    let mu: Vec<[i8; 2]> = sums.iter().map(|s| s.map(|v| (v as f64 / k).round().clamp(-127.0, 127.0) as i8)).collect();
    // Rule 2, the shift taken out by the board's own code (spreads of one unit meanwhile).
    let spec = ChromaSpec { threshold: MIN_THRESHOLD as f32, spread_ref: 1.0, cells: vec![(mu, vec![SPREAD_ONE; n])] };
    let t = Tables::of(&spec, 0);
    let c = t.view(&spec)?;
    let mut e = vec![[0i16; 2]; n];
    let mut sq = vec![0f64; n];
    for f in faces {
        fw::errors(&c, &f.grey, &f.chroma, h, w, &mut e).context("chroma sizes")?;
        for (s, eb) in sq.iter_mut().zip(&e) {
            *s += (eb[0] as f64).powi(2) + (eb[1] as f64).powi(2);
        }
    }
    let spread = sq
        .iter()
        .map(|s| ((s / (2.0 * k)).sqrt() * SPREAD_ONE as f64).round().clamp(SPREAD_FLOOR as f64, 255.0) as u8)
        .collect();
    let (mu, _) = spec.cells.into_iter().next().expect("one cell");
    Ok((mu, spread))
}

/// Rules 1 to 4 over `samples` (each face with its chroma planes, and the head pose it was
/// seen at) of an `h x w` model whose blobs need `min_area` pixels: tables per cell of `grid`
/// (the model's pose grid, as its grey statistics), or one set without one.
pub fn fit(samples: &[(&Face, [f32; 2])], h: usize, w: usize, min_area: u16, grid: Option<PoseGrid>) -> Result<(ChromaSpec, ChromaCalibration)> {
    let n = blocks(h, w);
    ensure!(!samples.is_empty(), "no frames to learn the face's colour from");
    ensure!(
        samples.iter().all(|(f, _)| f.grey.len() == h * w && f.chroma.len() == 2 * n),
        "every frame needs its colour to learn the face's colour (a grey dataset has none)"
    );
    let cell_of = |head: [f32; 2]| grid.as_ref().and_then(|g| g.bin(head)).unwrap_or(0);
    let cells = grid.as_ref().map_or(1, |g| g.len());
    let all: Vec<&Face> = samples.iter().map(|(f, _)| *f).collect();
    let everywhere = tables_of(&all, h, w)?;
    let mut spec = ChromaSpec { threshold: MIN_THRESHOLD as f32, spread_ref: 1.0, cells: Vec::with_capacity(cells) };
    for k in 0..cells {
        let own: Vec<&Face> = samples.iter().filter(|(_, hd)| cell_of(*hd) == k).map(|(f, _)| *f).collect();
        spec.cells.push(if own.len() >= MIN_CELL_FRAMES { tables_of(&own, h, w)? } else { everywhere.clone() });
    }
    let mut e = vec![[0i16; 2]; n];
    // Rule 3.
    let tables: Vec<Tables> = (0..cells).map(|k| Tables::of(&spec, k)).collect();
    let mut medians = Vec::with_capacity(samples.len());
    for (f, hd) in samples {
        let c = tables[cell_of(*hd)].view(&spec)?;
        let fr = fw::errors(&c, &f.grey, &f.chroma, h, w, &mut e).context("chroma sizes")?;
        medians.push(fr.median_q as f64 / Q_ONE as f64);
    }
    let reference = calibrate::percentile(&medians, 100.0 * calibrate::SPREAD_QUANTILE)?.max(1.0 / Q_ONE as f64);
    spec.spread_ref = reference.min(msr_shared::blob::chroma::MAX_SPREAD_REF as f64) as f32;
    // Rule 4.
    let mut max_score = 0f64;
    for (f, hd) in samples {
        let c = tables[cell_of(*hd)].view(&spec)?;
        let sal = saliency(&c, f, h, w)?;
        max_score = max_score.max(metrics::detection_score(&sal, w, min_area));
    }
    let threshold = (MARGIN * max_score).max(MIN_THRESHOLD).min(msr_shared::blob::chroma::MAX_THRESHOLD as f64);
    spec.threshold = threshold as f32;
    let mut spreads: Vec<f64> = spec.cells.iter().flat_map(|(_, s)| s.iter().map(|&v| v as f64 / SPREAD_ONE as f64)).collect();
    spreads.sort_by(f64::total_cmp);
    let cal = ChromaCalibration {
        frames: samples.len(),
        cells,
        threshold,
        max_score,
        spread_ref: reference,
        median_spread: spreads[spreads.len() / 2],
    };
    Ok((spec, cal))
}

/// Each pixel's colour saliency in `face`, in spreads (`detect::colour::saliency`).
pub fn saliency(c: &ChromaCell, face: &Face, h: usize, w: usize) -> Result<Vec<f64>> {
    let (sal, _) = crate::detect::colour::saliency(c, &face.grey, &face.chroma, h, w).context("chroma sizes")?;
    Ok(sal.into_iter().map(f64::from).collect())
}

/// A [`ChromaSpec`]'s tables as the blob stores them, for the board's functions to read.
struct Tables {
    u: Vec<u8>,
    v: Vec<u8>,
    s: Vec<u8>,
}

impl Tables {
    /// Cell `k`'s.
    fn of(spec: &ChromaSpec, k: usize) -> Tables {
        let (mu, s) = &spec.cells[k];
        Tables { u: mu.iter().map(|p| p[0] as u8).collect(), v: mu.iter().map(|p| p[1] as u8).collect(), s: s.clone() }
    }

    fn view(&self, spec: &ChromaSpec) -> Result<ChromaCell<'_>> {
        ChromaCell::from_tables(spec.threshold, spec.spread_ref, &self.u, &self.v, &self.s)
            .ok_or_else(|| anyhow!("chroma statistics out of range"))
    }
}

/// `blob` with the colour of the training frames of the dataset at `data` (rules 1 to 4),
/// cropped as the blob says; `None` (the blob as it is, a grey model) for a dataset of grey
/// frames, as a grey camera records.
pub fn attach(blob: &[u8], data: &Path) -> Result<(Vec<u8>, Option<ChromaCalibration>)> {
    let m = Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let crop = m.template.map_or(CropMode::Pixel, |t| t.crop);
    let (h, w) = (m.face_h as usize, m.face_w as usize);
    let ds = Dataset::load_split(data, Some(Split::Train), crop)
        .with_context(|| format!("loading the training frames of {} for the face's colour", data.display()))?;
    if ds.samples.iter().all(|s| s.face.chroma.is_empty()) {
        return Ok((blob.to_vec(), None));
    }
    let samples: Vec<(&Face, [f32; 2])> = ds.samples.iter().map(|s| (&s.face, s.head)).collect();
    let (spec, cal) = fit(&samples, h, w, m.novelty.min_area, m.pose.map(|p| p.grid))?;
    let out = set_chroma(blob, Some(&spec)).map_err(|e| anyhow!("chroma section: {e}"))?;
    Ok((out, Some(cal)))
}

/// [`attach`] on the blob a quantization wrote, with the dataset it measured, its report
/// brought up to date (size, CRC); `None` for a grey dataset (the blob left as it is).
pub fn colour_quantized(quantized: &mut crate::quant::quantize::Report) -> Result<Option<ChromaCalibration>> {
    let path = std::path::PathBuf::from(&quantized.blob);
    let blob = crate::fsio::read_blob(&path)?;
    let (coloured, cal) = attach(&blob, Path::new(&quantized.data))?;
    if cal.is_none() {
        return Ok(None);
    }
    crate::fsio::write(&path, &coloured)?;
    let model = Model::parse(&coloured).map_err(|e| anyhow!("model blob: {e}"))?;
    quantized.blob_bytes = coloured.len();
    quantized.crc32 = format!("{:08x}", model.crc32);
    Ok(cal)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::crop::CropBox;

    const H: usize = 12;
    const W: usize = 16;

    /// A face whose left half is reddish, with a little noise from `seed`.
    fn face(seed: u64) -> Face {
        let n = blocks(H, W);
        let mut r = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let mut noise = move || {
            r = r.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((r >> 33) % 3) as i32 - 1
        };
        let grey = (0..H * W).map(|i| (100 + (i % 5) as i32 * 4 + noise()) as u8).collect();
        let mut chroma = vec![128u8; 2 * n];
        for b in 0..n {
            let red = b % (W / 2) < W / 4;
            chroma[b] = (if red { 120 } else { 128 } + noise()) as u8;
            chroma[n + b] = (if red { 150 } else { 128 } + noise()) as u8;
        }
        Face { crop: CropBox { x: 0, y: 0, width: W as u32, height: H as u32 }, shift: [0.0; 2], at: [0.0; 2], grey, chroma, score: 0.0 }
    }

    #[test]
    fn the_training_faces_are_quiet_and_a_hue_patch_is_not() {
        let faces: Vec<Face> = (0..60).map(face).collect();
        let samples: Vec<(&Face, [f32; 2])> = faces.iter().map(|f| (f, [0.0, 0.0])).collect();
        let (spec, cal) = fit(&samples, H, W, 8, None).unwrap();
        assert_eq!((cal.frames, cal.cells, spec.cells.len()), (60, 1, 1));
        assert!(cal.threshold >= MIN_THRESHOLD && spec.is_valid(H, W, 0), "{cal:?}");
        // The reddish blocks' mean is the reddish chroma over their grey.
        let (mu, spread) = &spec.cells[0];
        assert!(mu[0][0] < 0 && mu[0][1] > 10 && mu[W / 2 - 1] == [0, 0], "{:?}", &mu[..W / 2]);
        assert!(spread.iter().all(|&s| s >= SPREAD_FLOOR));
        let t = Tables::of(&spec, 0);
        let c = t.view(&spec).unwrap();
        let quiet = saliency(&c, &faces[7], H, W).unwrap();
        assert!(metrics::detection_score(&quiet, W, 8) < cal.threshold);
        // A green 2 x 2 blocks patch on the neutral half, its grey unchanged.
        let mut marked = face(99);
        let n = blocks(H, W);
        for b in [W / 2 * 2 + 5, W / 2 * 2 + 6, W / 2 * 3 + 5, W / 2 * 3 + 6] {
            (marked.chroma[b], marked.chroma[n + b]) = (90, 80);
        }
        let loud = saliency(&c, &marked, H, W).unwrap();
        assert!(metrics::detection_score(&loud, W, 8) > 2.0 * cal.threshold);
    }

    #[test]
    fn faces_without_colour_are_refused() {
        let mut f = face(1);
        f.chroma.clear();
        let err = fit(&[(&f, [0.0, 0.0])], H, W, 8, None).unwrap_err().to_string();
        assert!(err.contains("colour"), "{err}");
    }
}
