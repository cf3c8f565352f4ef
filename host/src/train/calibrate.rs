//! Calibration: per-pixel statistics of the prediction error, the saliency score, the threshold
//! policy, and a float reference of the detection stage.
//!
//! Definitions (grey levels, 0..255):
//! - error `e = |255 (I - I_hat)|` per pixel;
//! - `mu` = mean of `e` and `sigma` = its standard deviation (N-1) over the training split, as the
//!   published `mu_for_decoder.npy` / `sigma_for_decoder.npy`;
//! - floor: the normaliser uses `s = max(sigma, sigma_floor)` (default [`DEFAULT_SIGMA_FLOOR`] grey
//!   levels: pixels that never vary would otherwise flag any change at all, and the board stores
//!   sigma in Q8.8, whose smallest step is 1/256);
//! - saliency: `(e - mu) / n` (one-sided, the default) or `|e - mu| / n` (two-sided, the published
//!   code), with `n = s` (standard deviation, the published code) or `n = s^2` (variance, the
//!   paper's text);
//! - detection: pixels with saliency `> threshold`, 8-connected components, those of at least
//!   `min_area` pixels; the largest wins (first in raster order on ties). With a fragment merge
//!   (`NoveltyParams::merge`, off by default: the paper's stage) nearby components are joined
//!   before the area test, as the firmware does (`crate::detect::pipeline::pick`).
//!
//! Threshold policy: the default is the paper's 4.59. With `--threshold-percentile P`, the
//! threshold is the P-th percentile (linear interpolation, as numpy's default) of the *detection
//! scores* of the normal held-out frames: the test-split frames without a mark. A frame's detection
//! score ([`detection_score`]) is the largest threshold at which it would still yield a detection,
//! so at threshold `t` exactly the normal frames scoring above `t` are false alarms: P = 99 allows
//! about 1 % of them, P = 100 none (in float).
use anyhow::{bail, ensure, Context, Result};
use image::{GrayImage, Luma};
use imageproc::region_labelling::{connected_components, Connectivity};
use msr_shared::blob::{Merge, Normalisation, PoseRegion, Sided};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The paper's threshold (1.8 % of 255).
pub const DEFAULT_THRESHOLD: f64 = 0.018 * 255.0;
/// The paper's smallest blob.
pub const DEFAULT_MIN_AREA: u16 = 30;
/// Grey levels; see the module doc.
pub const DEFAULT_SIGMA_FLOOR: f64 = 0.5;

/// Per-pixel error statistics, row-major `h x w`, grey levels.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorStats {
    pub h: usize,
    pub w: usize,
    pub mu: Vec<f64>,
    /// Standard deviation (N-1), not floored.
    pub sigma: Vec<f64>,
    /// Frames the statistics were made from.
    pub frames: usize,
}

/// `e = |255 (I - I_hat)|` per pixel.
pub fn error_map(observed: &[f32], predicted: &[f32]) -> Vec<f64> {
    observed.iter().zip(predicted).map(|(&i, &p)| (255.0 * (i as f64 - p as f64)).abs()).collect()
}

/// Accumulates error maps one at a time (Welford's update: stable, one pass, no frame kept).
#[derive(Clone, Debug)]
pub struct StatsAccumulator {
    h: usize,
    w: usize,
    n: usize,
    mean: Vec<f64>,
    m2: Vec<f64>,
}

impl StatsAccumulator {
    pub fn new(h: usize, w: usize) -> Self {
        StatsAccumulator { h, w, n: 0, mean: vec![0.0; h * w], m2: vec![0.0; h * w] }
    }

    pub fn add(&mut self, e: &[f64]) -> Result<()> {
        ensure!(e.len() == self.h * self.w, "error map has {} pixels, expected {}", e.len(), self.h * self.w);
        ensure!(e.iter().all(|v| v.is_finite()), "error map has non-finite values");
        self.n += 1;
        let n = self.n as f64;
        for ((m, m2), &x) in self.mean.iter_mut().zip(self.m2.iter_mut()).zip(e) {
            let d = x - *m;
            *m += d / n;
            *m2 += d * (x - *m);
        }
        Ok(())
    }

    pub fn finish(self) -> Result<ErrorStats> {
        ensure!(self.n >= 2, "error statistics need at least 2 frames, got {}", self.n);
        let d = (self.n - 1) as f64;
        Ok(ErrorStats {
            h: self.h,
            w: self.w,
            sigma: self.m2.iter().map(|v| (v / d).max(0.0).sqrt()).collect(),
            mu: self.mean,
            frames: self.n,
        })
    }
}

/// Statistics of `|255 (I - I_hat)|` over (observed, predicted) pairs.
pub fn error_stats<'a>(h: usize, w: usize, pairs: impl IntoIterator<Item = (&'a [f32], &'a [f32])>) -> Result<ErrorStats> {
    let mut acc = StatsAccumulator::new(h, w);
    for (obs, pred) in pairs {
        ensure!(obs.len() == pred.len(), "observed and predicted faces differ in size");
        acc.add(&error_map(obs, pred))?;
    }
    acc.finish()
}

/// How error becomes a detection. Stored in the model's JSON and the blob header.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoveltyParams {
    pub normalisation: Normalisation,
    pub sided: Sided,
    pub threshold: f64,
    pub sigma_floor: f64,
    pub min_area: u16,
    /// Fragment merge before the area test; off (the paper) by default and in older files.
    #[serde(default)]
    pub merge: Merge,
    /// A threshold and merge of their own near one head pose (the observe posture), as the
    /// calibrated policy sets them; none by default and in older files.
    #[serde(default)]
    pub region: Option<PoseRegion>,
}

impl Default for NoveltyParams {
    fn default() -> Self {
        NoveltyParams {
            normalisation: Normalisation::StdDev,
            sided: Sided::One,
            threshold: DEFAULT_THRESHOLD,
            sigma_floor: DEFAULT_SIGMA_FLOOR,
            min_area: DEFAULT_MIN_AREA,
            merge: Merge::OFF,
            region: None,
        }
    }
}

impl NoveltyParams {
    pub fn check(&self) -> Result<()> {
        ensure!(self.threshold.is_finite() && self.threshold > 0.0, "threshold must be positive, got {}", self.threshold);
        ensure!(self.sigma_floor.is_finite() && self.sigma_floor >= 0.0, "sigma floor must be >= 0, got {}", self.sigma_floor);
        ensure!(self.min_area >= 1, "minimum blob area must be at least 1");
        ensure!(
            self.merge.is_valid(self.min_area),
            "merge {:?}: the margin must be 0 (off, fragment 0) or 1..={}, with a fragment size of 1..=min_area",
            self.merge,
            msr_shared::blob::MAX_MERGE_MARGIN
        );
        if let Some(g) = &self.region {
            ensure!(
                g.is_valid(self.min_area),
                "pose region {g:?}: needs a finite centre, a radius in (0, {}] rad, a positive threshold and a valid merge",
                msr_shared::blob::MAX_REGION_RADIUS
            );
        }
        Ok(())
    }

    /// The settings for a frame seen with the head at `head`: the region's threshold and merge
    /// inside the pose region, these elsewhere (as the firmware's `Settings::at`).
    pub fn at(&self, head: [f32; 2]) -> NoveltyParams {
        match self.region {
            Some(g) if g.contains(head) => NoveltyParams { threshold: g.threshold as f64, merge: g.merge, ..*self },
            _ => *self,
        }
    }
}

/// The normaliser per pixel: floored sigma, or its square.
pub fn normaliser(sigma: &[f64], p: &NoveltyParams) -> Vec<f64> {
    sigma
        .iter()
        .map(|&s| {
            // A floor of 0 would divide by zero; keep the published code's 1e-5 as a last resort.
            let s = s.max(p.sigma_floor).max(1e-5);
            match p.normalisation {
                Normalisation::StdDev => s,
                Normalisation::Variance => s * s,
            }
        })
        .collect()
}

/// Saliency per pixel from an error map.
pub fn saliency(e: &[f64], stats: &ErrorStats, p: &NoveltyParams) -> Vec<f64> {
    let n = normaliser(&stats.sigma, p);
    e.iter()
        .zip(&stats.mu)
        .zip(&n)
        .map(|((&e, &mu), &n)| match p.sided {
            Sided::One => (e - mu) / n,
            Sided::Two => (e - mu).abs() / n,
        })
        .collect()
}

/// A detected blob in face-crop pixels; the box is inclusive, the centroid is the pixel mean.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Blob {
    pub area: u32,
    pub box_xyxy: [u32; 4],
    pub centroid: [f64; 2],
}

/// All 8-connected components of `mask` (row-major, `h x w`) with at least `min_area` pixels, in
/// raster order of their first pixel.
pub fn blobs(mask: &[bool], h: usize, w: usize, min_area: u32) -> Vec<Blob> {
    let img = GrayImage::from_fn(w as u32, h as u32, |x, y| Luma([mask[y as usize * w + x as usize] as u8]));
    let labels = connected_components(&img, Connectivity::Eight, Luma([0u8]));
    let mut acc: Vec<(u32, [u32; 4], f64, f64)> = Vec::new();
    for (x, y, l) in labels.enumerate_pixels() {
        let l = l[0] as usize;
        if l == 0 {
            continue;
        }
        if acc.len() < l {
            acc.resize(l, (0, [u32::MAX, u32::MAX, 0, 0], 0.0, 0.0));
        }
        let a = &mut acc[l - 1];
        a.0 += 1;
        a.1 = [a.1[0].min(x), a.1[1].min(y), a.1[2].max(x), a.1[3].max(y)];
        a.2 += x as f64;
        a.3 += y as f64;
    }
    acc.into_iter()
        .filter(|a| a.0 >= min_area)
        .map(|(n, b, sx, sy)| Blob { area: n, box_xyxy: b, centroid: [sx / n as f64, sy / n as f64] })
        .collect()
}

/// The float detection: saliency above the threshold, then (with `p.merge`) the merge of
/// nearby fragments, the largest blob of at least `min_area` (first in raster order on ties).
pub fn detect(sal: &[f64], h: usize, w: usize, p: &NoveltyParams) -> Option<Blob> {
    let mask: Vec<bool> = sal.iter().map(|&s| s > p.threshold).collect();
    let all: Vec<crate::detect::pipeline::Blob> = blobs(&mask, h, w, 1)
        .into_iter()
        .map(|b| crate::detect::pipeline::Blob { area: b.area, box_xyxy: b.box_xyxy, centroid: b.centroid })
        .collect();
    crate::detect::pipeline::pick(&all, p.min_area as u32, p.merge)
        .map(|b| Blob { area: b.area, box_xyxy: b.box_xyxy, centroid: b.centroid })
}

/// The largest threshold at which the frame still yields a blob of `min_area` pixels (8-connected):
/// a detection happens exactly for thresholds below this score. `-inf` if the face has fewer than
/// `min_area` pixels. Pixels are added in decreasing saliency into a union-find.
pub fn detection_score(sal: &[f64], h: usize, w: usize, min_area: u16) -> f64 {
    let n = h * w;
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| sal[b].total_cmp(&sal[a]));
    let mut parent: Vec<usize> = (0..n).collect();
    let mut size = vec![0usize; n];
    let mut on = vec![false; n];
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    let mut biggest = 0;
    let mut i = 0;
    while i < n {
        // Add every pixel of this saliency value before testing: `s > t` keeps or drops them together.
        let v = sal[order[i]];
        while i < n && sal[order[i]] == v {
            let px = order[i];
            on[px] = true;
            size[px] = 1;
            let (r, c) = ((px / w) as isize, (px % w) as isize);
            for dr in -1..=1 {
                for dc in -1..=1 {
                    let (rr, cc) = (r + dr, c + dc);
                    if (dr, dc) == (0, 0) || rr < 0 || cc < 0 || rr >= h as isize || cc >= w as isize {
                        continue;
                    }
                    let q = rr as usize * w + cc as usize;
                    if on[q] {
                        let (a, b) = (find(&mut parent, px), find(&mut parent, q));
                        if a != b {
                            parent[b] = a;
                            size[a] += size[b];
                        }
                    }
                }
            }
            let root = find(&mut parent, px);
            biggest = biggest.max(size[root]);
            i += 1;
        }
        if biggest >= min_area as usize {
            return v;
        }
    }
    f64::NEG_INFINITY
}

/// The `p`-th percentile (0..=100) with linear interpolation between order statistics (numpy's
/// default).
pub fn percentile(values: &[f64], p: f64) -> Result<f64> {
    ensure!((0.0..=100.0).contains(&p), "percentile must be within 0..=100, got {p}");
    ensure!(!values.is_empty(), "no values to take a percentile of");
    ensure!(values.iter().all(|v| !v.is_nan()), "NaN among the scores");
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = p / 100.0 * (v.len() - 1) as f64;
    let (lo, hi) = (rank.floor() as usize, rank.ceil() as usize);
    Ok(v[lo] + (v[hi] - v[lo]) * (rank - lo as f64))
}

/// Threshold from normal frames' detection scores (see the module doc for the policy).
pub fn threshold_from_normal(scores: &[f64], p: f64) -> Result<f64> {
    let finite: Vec<f64> = scores.iter().copied().filter(|s| s.is_finite()).collect();
    ensure!(!finite.is_empty(), "no normal held-out frames to pick a threshold from");
    let t = percentile(&finite, p)?;
    // Scores are finite here, so `<= 0` is the whole "not positive" case.
    if t <= 0.0 {
        bail!("the {p}th percentile of the normal frames' scores is {t}; a threshold must be positive");
    }
    Ok(t)
}

/// Writes an `h x w` float64 array (like the published statistics).
pub fn write_npy(path: &Path, h: usize, w: usize, data: &[f64]) -> Result<()> {
    use npyz::WriterBuilder;
    ensure!(data.len() == h * w, "npy data has {} values for {h}x{w}", data.len());
    let f = std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut wr = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[h as u64, w as u64])
        .writer(std::io::BufWriter::new(f))
        .begin_nd()
        .with_context(|| format!("writing {}", path.display()))?;
    wr.extend(data.iter().copied()).with_context(|| format!("writing {}", path.display()))?;
    wr.finish().with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Reads a 2-d float array (float64 or float32) as `(h, w, values)`.
pub fn read_npy(path: &Path) -> Result<(usize, usize, Vec<f64>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let npy = npyz::NpyFile::new(&bytes[..]).with_context(|| format!("{} is not a .npy file", path.display()))?;
    let shape = npy.shape().to_vec();
    ensure!(npy.order() == npyz::Order::C, "{}: Fortran-order arrays are not supported", path.display());
    let [h, w] = shape[..] else { bail!("{}: expected a 2-d array, got shape {shape:?}", path.display()) };
    let values: Vec<f64> = match npy.dtype() {
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 8 => {
            npy.into_vec::<f64>()?
        }
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4 => {
            npy.into_vec::<f32>()?.into_iter().map(f64::from).collect()
        }
        d => bail!("{}: expected float64 or float32, got {d:?}", path.display()),
    };
    ensure!(values.len() == (h * w) as usize, "{}: data shorter than its shape", path.display());
    ensure!(values.iter().all(|v| v.is_finite()), "{}: non-finite values", path.display());
    Ok((h as usize, w as usize, values))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn approx(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn stats_by_hand() {
        // One pixel, errors 255*|0.1|, 255*|0.3|, 255*|0.2| = 25.5, 76.5, 51: mean 51, std (N-1) 25.5.
        let obs = [[0.5f32], [0.5], [0.5]];
        let pred = [[0.4f32], [0.8], [0.3]];
        let s = error_stats(1, 1, obs.iter().zip(&pred).map(|(o, p)| (&o[..], &p[..]))).unwrap();
        assert!((s.mu[0] - 51.0).abs() < 1e-4, "{}", s.mu[0]);
        assert!((s.sigma[0] - 25.5).abs() < 1e-4, "{}", s.sigma[0]);
        assert_eq!(s.frames, 3);
        // Fewer than 2 frames is an error, not a NaN.
        assert!(error_stats(1, 1, obs.iter().zip(&pred).take(1).map(|(o, p)| (&o[..], &p[..]))).is_err());
    }

    #[test]
    fn saliency_both_normalisations_and_sides() {
        let stats = ErrorStats { h: 1, w: 3, mu: vec![10.0, 10.0, 10.0], sigma: vec![2.0, 0.0, 4.0], frames: 5 };
        let e = [16.0, 10.3, 2.0];
        let mut p = NoveltyParams { sigma_floor: 0.5, ..Default::default() };
        // std, one-sided: 6/2, 0.3/0.5 (floored), -8/4.
        let s = saliency(&e, &stats, &p);
        assert!(approx(s[0], 3.0) && approx(s[1], 0.6) && approx(s[2], -2.0), "{s:?}");
        p.sided = Sided::Two;
        let s = saliency(&e, &stats, &p);
        assert!(approx(s[2], 2.0), "{s:?}");
        p.normalisation = Normalisation::Variance;
        let s = saliency(&e, &stats, &p);
        assert!(approx(s[0], 1.5) && approx(s[1], 1.2) && approx(s[2], 0.5), "{s:?}");
    }

    #[test]
    fn blobs_are_8_connected_and_filtered_by_area() {
        // Two diagonal pixels are one 8-connected blob; the lone pixel is its own.
        #[rustfmt::skip]
        let m = [
            1, 0, 0, 0,
            0, 1, 0, 1,
            0, 0, 0, 0,
        ].map(|v| v == 1);
        let b = blobs(&m, 3, 4, 1);
        assert_eq!(b.len(), 2);
        assert_eq!(b[0], Blob { area: 2, box_xyxy: [0, 0, 1, 1], centroid: [0.5, 0.5] });
        assert_eq!(b[1].box_xyxy, [3, 1, 3, 1]);
        assert_eq!(blobs(&m, 3, 4, 2).len(), 1);
    }

    #[test]
    fn detect_picks_the_largest_blob_above_threshold() {
        let (h, w) = (6, 6);
        let mut sal = vec![0.0; h * w];
        for &(r, c) in &[(0, 0), (0, 1), (4, 3), (4, 4), (5, 3), (5, 4)] {
            sal[r * w + c] = 10.0;
        }
        let p = NoveltyParams { threshold: 4.59, min_area: 2, ..Default::default() };
        let b = detect(&sal, h, w, &p).unwrap();
        assert_eq!(b.area, 4);
        assert_eq!(b.centroid, [3.5, 4.5]);
        // Exactly at the threshold is not above it.
        let p = NoveltyParams { threshold: 10.0, min_area: 2, ..Default::default() };
        assert!(detect(&sal, h, w, &p).is_none());
    }

    #[test]
    fn detection_score_is_where_detection_stops() {
        let (h, w) = (5, 5);
        let mut sal = vec![0.0; h * w];
        // A 3-pixel diagonal chain (8-connected) with values 9, 7, 5 and an isolated 8.
        sal[0] = 9.0;
        sal[6] = 7.0;
        sal[12] = 5.0;
        sal[4] = 8.0;
        let score = detection_score(&sal, h, w, 3);
        assert_eq!(score, 5.0);
        for t in [4.9, 5.0, 5.1] {
            let p = NoveltyParams { threshold: t, min_area: 3, ..Default::default() };
            assert_eq!(detect(&sal, h, w, &p).is_some(), t < score, "t = {t}");
        }
        // Area 1: the top pixel.
        assert_eq!(detection_score(&sal, h, w, 1), 9.0);
        // More pixels than the face: never.
        assert_eq!(detection_score(&sal, h, w, 26), f64::NEG_INFINITY);
    }

    #[test]
    fn percentile_policy() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(percentile(&v, 50.0).unwrap(), 3.0);
        assert_eq!(percentile(&v, 100.0).unwrap(), 5.0);
        assert!((percentile(&v, 90.0).unwrap() - 4.6).abs() < 1e-12);
        assert!(percentile(&v, 101.0).is_err());
        assert!(percentile(&[], 50.0).is_err());
        assert!(percentile(&[1.0, f64::NAN], 50.0).is_err());
        assert!(threshold_from_normal(&[-3.0, -1.0], 50.0).is_err());
        assert_eq!(threshold_from_normal(&[f64::NEG_INFINITY, 2.0, 4.0], 100.0).unwrap(), 4.0);
    }

    #[test]
    fn npy_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("mu.npy");
        let data: Vec<f64> = (0..6).map(|i| i as f64 * 0.25).collect();
        write_npy(&p, 2, 3, &data).unwrap();
        assert_eq!(read_npy(&p).unwrap(), (2, 3, data));
        std::fs::write(&p, b"not npy").unwrap();
        assert!(read_npy(&p).is_err());
    }

    #[test]
    fn reads_the_published_statistics() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nao-red-real");
        if !dir.exists() {
            eprintln!("skipping: {} not found", dir.display());
            return;
        }
        let (h, w, sigma) = read_npy(&dir.join("sigma_for_decoder.npy")).unwrap();
        assert_eq!((h, w), (58, 75));
        let min = sigma.iter().copied().fold(f64::INFINITY, f64::min);
        let max = sigma.iter().copied().fold(0.0, f64::max);
        eprintln!("published sigma: min {min:.3} max {max:.3}");
        assert!(min > 0.0 && max < 128.0);
    }
}
