//! Calibration: per-pixel statistics of the prediction error, the saliency score, the threshold
//! policy, and a float reference of the detection stage.
//!
//! Definitions (grey levels, 0..255):
//! - error `e = |255 (I - I_hat)|` per pixel (the paper, `pool` 0), or by default the magnitude
//!   of the signed error `255 (I - I_hat)` averaged over a (2 `pool` + 1)^2 window
//!   ([`DEFAULT_POOL`], [`error_map`]);
//! - `mu` = mean of `e` and `sigma` = its standard deviation (N-1) over the training split, as the
//!   published `mu_for_decoder.npy` / `sigma_for_decoder.npy`; by default also per cell of a
//!   grid over the head pose ([`DEFAULT_POSE_BINS`], [`error_stats_by_pose`]), of which the
//!   detection takes the cell of the frame's head pose;
//! - floor: the normaliser uses `s = max(sigma, sigma_floor)` (default [`DEFAULT_SIGMA_FLOOR`] grey
//!   levels: pixels that never vary would otherwise flag any change at all, and the board stores
//!   sigma in Q8.8, whose smallest step is 1/256);
//! - the frame's floor: `s` widened to `sqrt(s^2 + f^2)`, `f` what the frame's own error spreads
//!   beyond the statistics' frames ([`error_map_floor`], the board's `msr_firmware::floor`), for a
//!   model that carries that reference ([`NoveltyParams::spread_ref`], [`spread_reference`]);
//! - saliency: `(e - mu) / n` (one-sided, the default) or `|e - mu| / n` (two-sided, the published
//!   code), with `n = s` (standard deviation, the published code) or `n = s^2` (variance, the
//!   paper's text);
//! - detection: pixels with saliency `> threshold`, 8-connected components, those of at least
//!   `min_area` pixels; the largest wins (first in raster order on ties). With a fragment merge
//!   (`NoveltyParams::merge`, off by default: the paper's stage) nearby components are joined
//!   before the area test, as the firmware does (`crate::detect::blobs::pick`).
//!
//! Threshold policy: the default is the paper's 4.59. With `--threshold-percentile P`, the
//! threshold is the P-th percentile (linear interpolation, as numpy's default) of the *detection
//! scores* of the normal held-out frames: the test-split frames without a mark. A frame's detection
//! score ([`detection_score`]) is the largest threshold at which it would still yield a detection,
//! so at threshold `t` exactly the normal frames scoring above `t` are false alarms: P = 99 allows
//! about 1 % of them, P = 100 none (in float).
use crate::detect::blobs::{self, Blob};
use crate::detect::pipeline::{self, Settings};
use crate::eval::metrics;
use crate::train::light_copies::LightCopies;
use rand_chacha::ChaCha8Rng;
use anyhow::{bail, ensure, Context, Result};
use msr_shared::blob::{Merge, Normalisation, PoseGrid, PoseRegion, Sided, MAX_POSE_BINS};
use serde::{Deserialize, Serialize};

/// The paper's threshold (1.8 % of 255).
pub const DEFAULT_THRESHOLD: f64 = 0.018 * 255.0;
/// The paper's smallest blob.
pub const DEFAULT_MIN_AREA: u16 = 30;
/// Grey levels; see the module doc.
pub const DEFAULT_SIGMA_FLOOR: f64 = 0.5;
/// The error's pooling radius that `msr train` and `msr demo` use: 2, the signed error averaged
/// over a 5 x 5 window (which keeps a 15 x 15 mark and cancels the skin robot's taxel texture,
/// whose error changes sign from pixel to pixel). Per pixel (0, the paper; `--pool 0`) the skin
/// robot's marks away from the observe posture stayed under the threshold (hit rate 0.51-0.60
/// over three seeds; pooled 0.97-0.995). Pooling alone raises the false alarms (0.00-0.04 ->
/// 0.02-0.10), hence [`DEFAULT_POSE_BINS`] with it.
pub const DEFAULT_POOL: u8 = 2;
/// The head-pose grid (cells per angle) that `msr train` and `msr demo` measure the error
/// statistics over: 3, a 3 x 3 grid over the training poses (about 115 training frames a cell of
/// the paper's 1300). With [`DEFAULT_POOL`] it takes the false alarms to 0 on both robots' three
/// seeds at the paper's threshold, no pose region and no merge (a 2 x 2 grid left one). 0 (the
/// paper; `--pose-bins 0`) is one set of statistics for all poses; every cell needs at least 2
/// training frames, so a small dataset needs `--pose-bins 0` or fewer cells.
pub const DEFAULT_POSE_BINS: u8 = 3;
/// The quantile of the statistics' frames' spreads that is the model's reference
/// ([`spread_reference`]): frames within the spread of nearly all of them (their light copies
/// included) keep the statistics alone, and one odd frame does not set it.
pub const SPREAD_QUANTILE: f64 = 0.99;

/// Per-pixel error statistics, row-major `h x w`, grey levels.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorStats {
    /// Face height, pixels.
    pub h: usize,
    /// Face width, pixels.
    pub w: usize,
    /// Mean error per pixel.
    pub mu: Vec<f64>,
    /// Standard deviation (N-1), not floored.
    pub sigma: Vec<f64>,
    /// Frames the statistics were made from.
    pub frames: usize,
    /// The same statistics per cell of a head-pose grid (the blob's flag bit 5), when made.
    pub pose: Option<PoseErrorStats>,
    /// The spread of each error map the statistics were made from, grey levels
    /// ([`error_map_floor`]), in the order added.
    pub spreads: Vec<f64>,
}

/// Error statistics per cell of a [`PoseGrid`]: cell `k`'s mu and sigma (N-1, not floored),
/// grey levels, over the training frames whose head pose falls in it ([`PoseGrid::bin`]).
#[derive(Clone, Debug, PartialEq)]
pub struct PoseErrorStats {
    /// The head-pose grid the cells belong to.
    pub grid: PoseGrid,
    /// Mean error per pixel, one table per cell.
    pub mu: Vec<Vec<f64>>,
    /// Standard deviation of the error per pixel, one table per cell.
    pub sigma: Vec<Vec<f64>>,
    /// Frames per cell.
    pub frames: Vec<usize>,
}

impl ErrorStats {
    /// The (mu, sigma) for a face seen with the head at `head`: its pose cell's, as the board
    /// takes them (`Model::stats_at`), or the pose-independent ones.
    pub fn at(&self, head: [f32; 2]) -> (&[f64], &[f64]) {
        match self.pose.as_ref().and_then(|p| Some((p, p.grid.bin(head)?))) {
            Some((p, k)) => (&p.mu[k], &p.sigma[k]),
            None => (&self.mu, &self.sigma),
        }
    }
}

/// An `n x n` grid over head poses within +-`max_head` radians (yaw and pitch).
pub fn pose_grid(n: u8, max_head: f32) -> Result<PoseGrid> {
    let g = PoseGrid { bins: [n, n], lo: [-max_head; 2], hi: [max_head; 2] };
    ensure!(g.is_valid(), "pose bins must be 2..={MAX_POSE_BINS} per angle over a positive head range, got {n} over +-{max_head} rad");
    Ok(g)
}

/// [`error_stats`] over all faces, with those per cell of `grid` in its `pose`, each face (and
/// its light copies) filed under its head pose: every error map is made once and goes to both.
/// Every cell needs at least 2 frames.
pub fn error_stats_by_pose<'a>(
    h: usize,
    w: usize,
    pool: u8,
    copies: &LightCopies,
    grid: PoseGrid,
    samples: impl IntoIterator<Item = ([f32; 2], &'a [f32], &'a [f32])>,
) -> Result<ErrorStats> {
    let mut all = StatsAccumulator::new(h, w);
    let mut acc = vec![StatsAccumulator::new(h, w); grid.len()];
    let mut rng = copies.rng();
    for (head, obs, pred) in samples {
        ensure!(obs.len() == pred.len(), "observed and predicted faces differ in size");
        let Some(k) = grid.bin(head) else { bail!("a training frame has a non-finite head pose {head:?}") };
        let maps = face_maps(obs, pred, w, pool, copies, &mut rng);
        all.add_maps(&maps)?;
        acc[k].add_maps(&maps)?;
    }
    let (mut mu, mut sigma, mut frames) = (Vec::new(), Vec::new(), Vec::new());
    for (k, a) in acc.into_iter().enumerate() {
        let n = a.faces;
        let s = a.finish().with_context(|| format!("pose cell {k} of {:?}", grid.bins))?;
        mu.push(s.mu);
        sigma.push(s.sigma);
        frames.push(n);
    }
    let mut stats = all.finish()?;
    stats.pose = Some(PoseErrorStats { grid, mu, sigma, frames });
    Ok(stats)
}

/// The error maps of one training face and of its light copies ([`LightCopies`]), face first,
/// each with its spread ([`error_map_floor`] against a reference of 0).
fn face_maps(obs: &[f32], pred: &[f32], w: usize, pool: u8, copies: &LightCopies, rng: &mut ChaCha8Rng) -> Vec<(Vec<f64>, f64)> {
    std::iter::once(obs.to_vec())
        .chain(copies.of(obs, w, rng))
        .map(|o| {
            let (map, [spread, _]) = error_map_floor(&o, pred, w, pool, Some(0.0));
            (map, spread)
        })
        .collect()
}

/// The model's reference from the spreads of its statistics' frames: their
/// [`SPREAD_QUANTILE`] (by [`percentile`]); 0 without frames.
pub fn spread_reference(spreads: &[f64]) -> f64 {
    percentile(spreads, 100.0 * SPREAD_QUANTILE).unwrap_or(0.0)
}

/// `e = |v(I) - 255 I_hat|` per pixel (censored where clipped: [`pipeline::censored_error`]), or pooled over the model's window
/// ([`crate::detect::pipeline::pooled_error`]); `w` is the face's width; `v` is the frame's
/// photometric fit ([`pipeline::light_fit`], the board's), so that the statistics measure what
/// the fit leaves. `observed` is grey/255 (whole grey levels).
pub fn error_map(observed: &[f32], predicted: &[f32], w: usize, pool: u8) -> Vec<f64> {
    error_map_floor(observed, predicted, w, pool, None).0
}

/// [`error_map`], and through the same photometric fit the frame's spread and the floor its
/// sigmas are widened by for a model whose reference is `spread_ref`, grey levels (the board's
/// rules, [`pipeline::frame_floor`]; 0 and 0 without a reference).
pub fn error_map_floor(observed: &[f32], predicted: &[f32], w: usize, pool: u8, spread_ref: Option<f64>) -> (Vec<f64>, [f64; 2]) {
    let grey: Vec<u8> = observed.iter().map(|&i| (i * 255.0).round().clamp(0.0, 255.0) as u8).collect();
    let fit = pipeline::light_fit(&grey, predicted, w);
    let v = pipeline::fitted_values(&fit);
    let signed: Vec<f64> = grey.iter().zip(predicted).map(|(&i, &p)| pipeline::censored_error(&v, fit.clip, i, 255.0 * p as f64)).collect();
    let floor = pipeline::frame_floor(&grey, predicted, w, pool, &fit, spread_ref.map(|r| r as f32));
    (pipeline::pooled_error(&signed, w, pool), floor.map(f64::from))
}

/// Accumulates error maps one at a time (Welford's update: stable, one pass, no frame kept).
#[derive(Clone, Debug)]
pub struct StatsAccumulator {
    h: usize,
    w: usize,
    n: usize,
    /// Faces added with their copies' maps (the copies not counted).
    faces: usize,
    mean: Vec<f64>,
    m2: Vec<f64>,
    spreads: Vec<f64>,
}

impl StatsAccumulator {
    /// An empty accumulator for `h x w` error maps.
    pub fn new(h: usize, w: usize) -> Self {
        StatsAccumulator { h, w, n: 0, faces: 0, mean: vec![0.0; h * w], m2: vec![0.0; h * w], spreads: Vec::new() }
    }

    /// One training face's error maps: its own and its light copies' ([`face_maps`]).
    fn add_maps(&mut self, maps: &[(Vec<f64>, f64)]) -> Result<()> {
        for (e, spread) in maps {
            self.add(e)?;
            self.spreads.push(*spread);
        }
        self.faces += 1;
        Ok(())
    }

    /// Adds one error map (`h x w`, finite), counted as one frame.
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

    /// The statistics; at least 2 frames (faces, when they came with their light copies' maps:
    /// one face's copies are not frames of their own). `frames` counts the faces so added, else
    /// the maps.
    pub fn finish(self) -> Result<ErrorStats> {
        let frames = if self.faces > 0 { self.faces } else { self.n };
        ensure!(frames >= 2, "error statistics need at least 2 frames, got {frames}");
        let d = (self.n - 1) as f64;
        Ok(ErrorStats {
            h: self.h,
            w: self.w,
            sigma: self.m2.iter().map(|v| (v / d).max(0.0).sqrt()).collect(),
            mu: self.mean,
            frames,
            pose: None,
            spreads: self.spreads,
        })
    }
}

/// Statistics of the error ([`error_map`] with `pool`) over (observed, predicted) pairs, each
/// observed face with its light copies ([`LightCopies`]; [`LightCopies::NONE`]: the faces alone).
pub fn error_stats<'a>(
    h: usize,
    w: usize,
    pool: u8,
    copies: &LightCopies,
    pairs: impl IntoIterator<Item = (&'a [f32], &'a [f32])>,
) -> Result<ErrorStats> {
    let mut acc = StatsAccumulator::new(h, w);
    let mut rng = copies.rng();
    for (obs, pred) in pairs {
        ensure!(obs.len() == pred.len(), "observed and predicted faces differ in size");
        acc.add_maps(&face_maps(obs, pred, w, pool, copies, &mut rng))?;
    }
    acc.finish()
}

/// How error becomes a detection. Stored in the model's JSON and the blob header.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoveltyParams {
    /// What the error above the mean is divided by: sigma or sigma squared.
    pub normalisation: Normalisation,
    /// One-sided `(e - mu) / n` or two-sided `|e - mu| / n` saliency.
    pub sided: Sided,
    /// Saliency above which a pixel is salient, saliency units.
    pub threshold: f64,
    /// Floor on sigma before normalising, grey levels.
    pub sigma_floor: f64,
    /// Smallest blob that counts as a detection, pixels.
    pub min_area: u16,
    /// Fragment merge before the area test; off (the paper) by default and in older files.
    #[serde(default)]
    pub merge: Merge,
    /// A threshold and merge of their own near one head pose (the observe posture), as the
    /// calibrated policy sets them; none by default and in older files.
    #[serde(default)]
    pub region: Option<PoseRegion>,
    /// Radius of the window the signed error is averaged over (the blob's `Novelty::pool`);
    /// 0, per pixel (the paper), in older files and in `NoveltyParams::default()`, which
    /// describes a stored model; what `msr train` makes is [`DEFAULT_POOL`].
    #[serde(default)]
    pub pool: u8,
    /// Error statistics per cell of this grid over the head pose (the blob's flag bit 5); none
    /// (one set for all poses, the paper) in older files and in `NoveltyParams::default()`;
    /// `msr train` makes a [`DEFAULT_POSE_BINS`] grid.
    #[serde(default)]
    pub pose_grid: Option<PoseGrid>,
    /// The spread of the error over the statistics' frames, grey levels (the blob's
    /// `Novelty::spread_ref`, [`spread_reference`]): a frame's sigma is widened by what its
    /// own error spreads beyond it. None (the statistics alone) in older files and in
    /// `NoveltyParams::default()`; `msr train` measures it.
    #[serde(default)]
    pub spread_ref: Option<f64>,
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
            pool: 0,
            pose_grid: None,
            spread_ref: None,
        }
    }
}

impl NoveltyParams {
    /// Refuses settings the detection cannot use: a threshold that is not positive, a negative
    /// floor, a zero area, and a pool, merge or pose region outside what the blob holds.
    pub fn check(&self) -> Result<()> {
        ensure!(self.threshold.is_finite() && self.threshold > 0.0, "threshold must be positive, got {}", self.threshold);
        ensure!(self.sigma_floor.is_finite() && self.sigma_floor >= 0.0, "sigma floor must be >= 0, got {}", self.sigma_floor);
        ensure!(self.min_area >= 1, "minimum blob area must be at least 1");
        ensure!(self.pool <= msr_shared::blob::MAX_POOL, "error pool radius must be 0..={}, got {}", msr_shared::blob::MAX_POOL, self.pool);
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
        if !self.region.is_some_and(|g| g.contains(head)) {
            // Outside the region: the f64 threshold as it is.
            return *self;
        }
        let s = self.settings().in_region(self.region, 1.0, head);
        NoveltyParams { threshold: s.threshold as f64, merge: s.merge, ..*self }
    }

    /// These settings as the board holds them (f32 threshold).
    pub fn settings(&self) -> Settings {
        Settings {
            threshold: self.threshold as f32,
            normalisation: self.normalisation,
            sided: self.sided,
            min_area: self.min_area,
            merge: self.merge,
        }
    }
}

/// Saliency per pixel from an error map: the one float saliency
/// ([`crate::detect::pipeline::saliency`]) with this model's floor and its pose-independent
/// statistics, no frame floor.
pub fn saliency(e: &[f64], stats: &ErrorStats, p: &NoveltyParams) -> Vec<f64> {
    pipeline::saliency(e.iter().copied(), &stats.mu, &stats.sigma, p.sigma_floor, 0.0, p.normalisation, p.sided)
}

/// [`saliency`] of a face seen with the head at `head`, with the statistics of its pose cell
/// when the model has them ([`ErrorStats::at`]) and the frame's floor `f` ([`error_map_floor`]).
pub fn saliency_at(e: &[f64], stats: &ErrorStats, p: &NoveltyParams, head: [f32; 2], f: f64) -> Vec<f64> {
    if !pipeline::floor_holds(f as f32) {
        // No face, as the board says of it: nothing salient.
        return vec![0.0; e.len()];
    }
    let (mu, sigma) = stats.at(head);
    pipeline::saliency(e.iter().copied(), mu, sigma, p.sigma_floor, f, p.normalisation, p.sided)
}

/// The float detection: saliency above the threshold, then the board's blob stage
/// ([`crate::detect::blobs::pick`]: with `p.merge` the merge of nearby fragments, the largest
/// blob of at least `min_area`, first in raster order on ties). Blob coordinates are face-crop
/// pixels.
pub fn detect(sal: &[f64], h: usize, w: usize, p: &NoveltyParams) -> Option<Blob> {
    let mask: Vec<bool> = sal.iter().map(|&s| s > p.threshold).collect();
    blobs::pick(&mask, w, h, p.min_area, p.merge).ok().flatten()
}

/// A frame's detection score: the one definition ([`crate::eval::metrics::detection_score`]).
pub fn detection_score(sal: &[f64], h: usize, w: usize, min_area: u16) -> f64 {
    debug_assert_eq!(sal.len(), h * w);
    metrics::detection_score(sal, w, min_area)
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

pub use crate::data::npy::{read as read_npy, write as write_npy};

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn approx(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn stats_by_hand() {
        // One pixel, errors 255*|0.1|, 255*|0.3|, 255*|0.2| = 25.5, 76.5, 51: mean 51, std (N-1) 25.5.
        // The observed grey is a whole grey level (102 = 0.4 x 255), as a camera gives it; a
        // single pixel is too few samples for a light fit, which leaves it as it is.
        let obs = [[0.4f32], [0.4], [0.4]];
        let pred = [[0.3f32], [0.7], [0.2]];
        let s = error_stats(1, 1, 0, &LightCopies::NONE, obs.iter().zip(&pred).map(|(o, p)| (&o[..], &p[..]))).unwrap();
        assert!((s.mu[0] - 51.0).abs() < 1e-4, "{}", s.mu[0]);
        assert!((s.sigma[0] - 25.5).abs() < 1e-4, "{}", s.sigma[0]);
        assert_eq!(s.frames, 3);
        // Fewer than 2 frames is an error, not a NaN.
        assert!(error_stats(1, 1, 0, &LightCopies::NONE, obs.iter().zip(&pred).take(1).map(|(o, p)| (&o[..], &p[..]))).is_err());
    }

    /// A shaded 30 x 24 face (grey/255) with noise of about `sd` grey levels from `seed`.
    fn noisy_face(sd: f32, seed: u32) -> (Vec<f32>, Vec<f32>) {
        let (w, h) = (30usize, 24usize);
        let clean: Vec<f32> = (0..w * h).map(|i| (60.0 + 3.0 * (i % w) as f32 + 2.0 * (i / w) as f32) / 255.0).collect();
        let mut x = seed.wrapping_mul(2_654_435_761) | 1;
        let seen = clean
            .iter()
            .map(|&c| {
                // A sum of three uniforms, sd about `sd`.
                let n: f32 = (0..3)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 17;
                        x ^= x << 5;
                        (x % 1000) as f32 / 1000.0 - 0.5
                    })
                    .sum::<f32>()
                    * sd * 2.0;
                ((c * 255.0 + n).round().clamp(0.0, 255.0)) / 255.0
            })
            .collect();
        (seen, clean)
    }

    /// Each error map the statistics take, the light copies' too, gives its spread; the
    /// reference is their 99th percentile; a frame that spreads beyond it gets a floor.
    #[test]
    fn the_statistics_frames_spreads_make_the_reference() {
        let faces: Vec<(Vec<f32>, Vec<f32>)> = (0..20).map(|k| noisy_face(2.0, k)).collect();
        let pairs = || faces.iter().map(|(o, p)| (&o[..], &p[..]));
        let s = error_stats(24, 30, 0, &LightCopies::NONE, pairs()).unwrap();
        assert_eq!(s.spreads.len(), 20);
        let copies = LightCopies { copies: 2, ..LightCopies::default() };
        assert_eq!(error_stats(24, 30, 0, &copies, pairs()).unwrap().spreads.len(), 60);
        for (sp, (o, p)) in s.spreads.iter().zip(&faces) {
            assert_eq!(*sp, error_map_floor(o, p, 30, 0, Some(0.0)).1[0]);
            assert!((1.0..4.0).contains(sp), "noise of sd 2: spread {sp}");
        }
        let r = spread_reference(&s.spreads);
        assert_eq!(r, percentile(&s.spreads, 99.0).unwrap());
        assert_eq!(spread_reference(&[]), 0.0);
        // A frame like them keeps the statistics alone; a noisier one gets a floor.
        let (o, p) = noisy_face(2.0, 99);
        assert!(error_map_floor(&o, &p, 30, 0, Some(r)).1[1] < 1.5);
        let (o, p) = noisy_face(8.0, 99);
        let (map, [spread, f]) = error_map_floor(&o, &p, 30, 0, Some(r));
        assert_eq!(map, error_map(&o, &p, 30, 0));
        let exact = (spread * spread - r * r).sqrt();
        assert!(spread > 6.0 && f <= exact && f > exact - 0.26, "spread {spread} ref {r} floor {f}: a quarter level under {exact}");
        assert_eq!(error_map_floor(&o, &p, 30, 0, None).1, [0.0, 0.0], "no reference, no floor");
    }

    /// A recording under one light: a shaded face with a little sensor noise. A lamp the
    /// recording never saw (a tone curve and a gradient within the copies' amplitudes) fires
    /// with the faces' statistics alone and not with their light copies.
    #[test]
    fn light_copies_cover_a_lamp_that_the_recording_never_saw() {
        let (w, h) = (30, 24);
        let clean: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
                0.15 + 0.7 * (1.0 - (x - 0.4).powi(2) - (y - 0.5).powi(2)).max(0.0)
            })
            .collect();
        // Noise of up to 2 grey levels, the same on every run.
        let noisy = |n: usize| -> Vec<f32> {
            clean.iter().enumerate().map(|(i, &v)| (v * 255.0 + ((i * 7919 + n * 104_729) % 5) as f32 - 2.0).round() / 255.0).collect()
        };
        let faces: Vec<Vec<f32>> = (0..40).map(noisy).collect();
        let pairs = || faces.iter().map(|f| (&f[..], &clean[..]));
        let lamp: Vec<f32> = clean
            .iter()
            .enumerate()
            .map(|(i, &v)| (v.powf(1.15) * (1.0 + 0.05 * (2.0 * (i % w) as f32 / (w - 1) as f32 - 1.0)) * 255.0).round() / 255.0)
            .collect();
        let p = NoveltyParams { pool: 2, ..Default::default() };
        let salient = |stats: &ErrorStats| saliency(&error_map(&lamp, &clean, w, 2), stats, &p).iter().filter(|&&s| s > p.threshold).count();
        let alone = error_stats(h, w, 2, &LightCopies::NONE, pairs()).unwrap();
        let copied = error_stats(h, w, 2, &LightCopies::DEFAULT, pairs()).unwrap();
        assert_eq!((alone.frames, copied.frames), (40, 40), "copies are not frames of their own");
        let (fired, quiet) = (salient(&alone), salient(&copied));
        eprintln!("salient pixels under the lamp: {fired} without copies, {quiet} with");
        assert!(fired > 30, "the lamp fires without copies: {fired} salient pixels");
        assert_eq!(quiet, 0, "and not with them");
        // The unlit recording itself stays quiet either way.
        let seen = noisy(99);
        assert_eq!(saliency(&error_map(&seen, &clean, w, 2), &copied, &p).iter().filter(|&&s| s > p.threshold).count(), 0);
    }

    #[test]
    fn saliency_both_normalisations_and_sides() {
        let stats = ErrorStats { h: 1, w: 3, mu: vec![10.0, 10.0, 10.0], sigma: vec![2.0, 0.0, 4.0], frames: 5, pose: None, spreads: Vec::new() };
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
