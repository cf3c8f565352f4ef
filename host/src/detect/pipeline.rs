//! The detection pipeline on the host, stage by stage: predicted face -> saliency -> blobs ->
//! winner -> reach. The float engine lives here; the fixed engine is the firmware's code
//! (`crate::detect::fixed`). Both give a [`Detection`] so that `detect` and `eval` treat them alike.
use crate::data::crop::CropBox;
pub use crate::detect::blobs::Blob;
use msr_shared::blob::{Normalisation, PoseGrid, PoseRegion, Reach, Sided, REACH_HIDDEN, REACH_OUT};
use num_traits::Float;
pub use msr_firmware::light::{LightFit, Verdict};

/// Novelty settings of one evaluation row or one detection: the firmware's own type, and its
/// [`Settings::in_region`] is the one rule for "the settings at this head pose".
pub use msr_firmware::Settings;

/// The published code's last-resort epsilon: no normaliser is smaller, whatever the floor.
pub const MIN_SIGMA: f64 = 1e-5;

/// The normaliser of one pixel: `s = max(sigma, floor, 1e-5)` ([`MIN_SIGMA`], so a floor of 0
/// never divides by zero) widened by the frame's floor `f` ([`frame_floor`]: `sqrt(s^2 +
/// f^2)`), or its square with [`Normalisation::Variance`].
pub fn normaliser<T: Float>(sigma: T, floor: T, f: T, normalisation: Normalisation) -> T {
    let s = sigma.max(floor).max(T::from(MIN_SIGMA).unwrap_or_else(T::epsilon));
    let s = if f > T::zero() { (s * s + f * f).sqrt() } else { s };
    match normalisation {
        Normalisation::StdDev => s,
        Normalisation::Variance => s * s,
    }
}

/// Per-pixel saliency in threshold units, the float definition every host step uses: `(e - mu)
/// / n` (one-sided) or `|e - mu| / n`, with the error `e` in grey levels and `n` =
/// [`normaliser`]`(sigma, floor, f)` (`f` the frame's floor, [`frame_floor`]; 0: the
/// statistics alone). A pixel is salient when its score exceeds the threshold. f32 for the
/// detection engines, f64 for calibration.
#[allow(clippy::too_many_arguments)]
pub fn saliency<T: Float>(
    e: impl IntoIterator<Item = T>,
    mu: &[T],
    sigma: &[T],
    floor: T,
    f: T,
    normalisation: Normalisation,
    sided: Sided,
) -> Vec<T> {
    e.into_iter()
        .zip(mu.iter().zip(sigma))
        .map(|(e, (&m, &s))| {
            let d = match sided {
                Sided::One => e - m,
                Sided::Two => (e - m).abs(),
            };
            d / normaliser(s, floor, f, normalisation)
        })
        .collect()
}

/// The error of a face against its prediction, grey levels: `e = |v(I) - 255 I_hat|` with `I`
/// in grey levels, `v` the frame's photometric fit ([`light_fit`]) and `I_hat` (the
/// prediction) in 0..1, pooled over the model's window ([`pooled_error`]; `pool` 0: per pixel).
/// `w` is the face's width.
pub fn face_error(face: &[u8], predicted: &[f32], w: usize, pool: u8) -> Vec<f32> {
    face_error_fitted(face, predicted, w, pool).0
}

/// [`face_error`] and the fit it used.
pub fn face_error_fitted(face: &[u8], predicted: &[f32], w: usize, pool: u8) -> (Vec<f32>, LightFit) {
    let fit = light_fit(face, predicted, w);
    let v = fitted_values(&fit);
    let signed: Vec<f32> = face.iter().zip(predicted).map(|(&i, &p)| censored_error(&v, fit.clip, i, 255.0 * p)).collect();
    (pooled_error(&signed, w, pool), fit)
}

/// `v(i) - p` in grey levels, censored where the camera clipped, as the board's
/// [`msr_firmware::light::error`]: a pixel at or over the fit's top clip level (255, or a
/// plateau's: [`LightFit::clip`]) is at least `v(i)`, one at or under the bottom one at most.
pub fn censored_error<T: Float>(v: &[f32; 256], clip: [u8; 2], i: u8, p: T) -> T {
    let e = T::from(v[i as usize]).unwrap_or_else(T::zero) - p;
    if i >= clip[1] {
        e.max(T::zero())
    } else if i <= clip[0] {
        e.min(T::zero())
    } else {
        e
    }
}

/// The photometric fit of a face to a prediction in 0..1: the board's fit
/// ([`msr_firmware::light::fit`]) on the prediction in Q8.8, as the board holds it. The one
/// definition the float engine, calibration and evaluation share with the board.
pub fn light_fit(face: &[u8], predicted: &[f32], w: usize) -> LightFit {
    msr_firmware::light::fit(face, &q88(predicted), w)
}

/// A prediction in 0..1 as the board holds it, Q8.8 grey levels.
fn q88(predicted: &[f32]) -> Vec<u16> {
    predicted.iter().map(|&p| (p * 65280.0).round().clamp(0.0, 65535.0) as u16).collect()
}

/// Whether a frame's floor (grey levels) is one a camera explains: past
/// `msr_firmware::floor::MAX_FLOOR` the board calls the frame no face (its rule 5).
pub fn floor_holds(f: f32) -> bool {
    f * 256.0 <= msr_firmware::floor::MAX_FLOOR as f32
}

/// The frame's spread and its floor, grey levels: the board's rules
/// ([`msr_firmware::floor`]) on `face` against the prediction (0..1) through the fit `fit`,
/// for a model whose reference is `spread_ref`; `[0, 0]` without one (the statistics alone)
/// or for a face the fit refused.
pub fn frame_floor(face: &[u8], predicted: &[f32], w: usize, pool: u8, fit: &LightFit, spread_ref: Option<f32>) -> [f32; 2] {
    let Some(r) = spread_ref else { return [0.0; 2] };
    if fit.verdict != Verdict::Face {
        return [0.0; 2];
    }
    let mut lut = msr_firmware::light::Lut::IDENTITY;
    fit.lut(&mut lut);
    let s = msr_firmware::floor::spread(face, &q88(predicted), &lut, w, pool);
    let f = msr_firmware::floor::floor(s, msr_firmware::floor::reference_q88(r));
    [s as f32 / 256.0, f as f32 / 256.0]
}

/// `v(I)` of a fit in grey levels, for each grey level `I` (the board's table over 256).
pub fn fitted_values(fit: &LightFit) -> [f32; 256] {
    let mut t = [0u16; 256];
    fit.table(&mut t);
    t.map(|v| v as f32 / 256.0)
}

/// `|mean of the signed error over the (2 pool + 1)^2 window|`, the window clipped at the
/// border (the blob's flag bit 4; the firmware's `saliency::pooled`). Why: the decoder cannot
/// follow fine texture (the skin robot's taxels) at every sub-pixel phase of the crop, and its
/// error there is of either sign from pixel to pixel; a mark's is of one sign over its whole
/// area, so the mean keeps the mark and cancels the texture. `pool` 0: `|e|` per pixel.
pub fn pooled_error<T: Float>(signed: &[T], w: usize, pool: u8) -> Vec<T> {
    let r = pool as usize;
    if r == 0 || w == 0 {
        return signed.iter().map(|v| v.abs()).collect();
    }
    let h = signed.len() / w;
    let mut out = Vec::with_capacity(signed.len());
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
            let mut sum = T::zero();
            for row in signed[y0 * w..(y1 + 1) * w].chunks_exact(w) {
                sum = row[x0..=x1].iter().fold(sum, |a, &v| a + v);
            }
            let n = T::from((y1 - y0 + 1) * (x1 - x0 + 1)).unwrap_or_else(T::one);
            out.push((sum / n).abs());
        }
    }
    out
}

/// Everything one run of the pipeline on one frame produced.
#[derive(Clone, Debug)]
pub struct Detection {
    /// Where the face was cut from the frame, full-frame pixels.
    pub crop: CropBox,
    /// The predicted face, grey/255, row-major.
    pub predicted: Vec<f32>,
    /// Saliency in threshold units (for pictures and AUROC).
    pub saliency: Vec<f32>,
    /// Salient pixels: with the pooled one-sided test, those whose own error passes too (the
    /// extent; the blob is the pooled mask's).
    pub mask: Vec<bool>,
    /// The winning blob in full-frame pixels.
    pub blob: Option<Blob>,
    /// HeadYaw, HeadPitch, LShoulderPitch, LShoulderRoll, LElbowRoll (radians).
    pub joints: Option<[f32; REACH_OUT]>,
    /// The frame's photometric fit; a verdict other than [`Verdict::Face`] detects nothing.
    pub light: LightFit,
    /// The frame's spread and the floor its sigmas were widened by, grey levels
    /// ([`frame_floor`]; 0 and 0 for a model without a reference).
    pub spread: [f32; 2],
    /// The colour stage's saliency in threshold units (`detect::colour`), for a model with
    /// chroma and a face with its planes, run by the firmware's engine; `None` otherwise.
    pub colour: Option<Vec<f32>>,
}

/// The reach network in float: mark position in full-frame pixels -> 5 joint angles.
pub fn reach_float(r: &Reach, x: f32, y: f32) -> [f32; REACH_OUT] {
    let sig = |z: f32| 1.0 / (1.0 + (-z).exp());
    let inp = [
        (x - r.in_min[0]) / (r.in_max[0] - r.in_min[0]),
        (y - r.in_min[1]) / (r.in_max[1] - r.in_min[1]),
    ];
    let mut h = [0f32; REACH_HIDDEN];
    for (j, hj) in h.iter_mut().enumerate() {
        *hj = sig(r.b1[j] + r.w1[j][0] * inp[0] + r.w1[j][1] * inp[1]);
    }
    let mut out = [0f32; REACH_OUT];
    for (k, o) in out.iter_mut().enumerate() {
        let z = r.b2[k] + r.w2[k].iter().zip(&h).map(|(w, h)| w * h).sum::<f32>();
        *o = sig(z) * (r.out_max[k] - r.out_min[k]) + r.out_min[k];
    }
    out
}

/// Joint names in the order of [`Detection::joints`].
pub const JOINTS: [&str; REACH_OUT] = [
    "HeadYaw",
    "HeadPitch",
    "LShoulderPitch",
    "LShoulderRoll",
    "LElbowRoll",
];

/// The float pipeline for one face, given the model's prediction.
pub struct FloatEngine {
    /// Grey levels, row-major, face size.
    pub mu: Vec<f32>,
    /// Grey levels, floor applied (the normaliser adds only [`MIN_SIGMA`]).
    pub sigma: Vec<f32>,
    /// Novelty settings (threshold, normaliser, sides, smallest blob, merge) away from `region`.
    pub settings: Settings,
    /// Settings of their own near one head pose (the blob's `PoseRegion`).
    pub region: Option<PoseRegion>,
    /// The reach network from a mark's centroid to joint angles; `None`: no joints reported.
    pub reach: Option<Reach>,
    /// The face's width, pixels (the row length of `mu`, `sigma` and the faces).
    pub face_w: usize,
    /// The error's pooling radius ([`pooled_error`]).
    pub pool: u8,
    /// Statistics per head-pose cell (the blob's `PoseStats`), used in place of `mu` and
    /// `sigma` where the head pose is finite.
    pub pose: Option<PoseTables>,
    /// The spread of the statistics' frames (the blob's `Novelty::spread_ref`): each frame's
    /// sigma is widened by its own floor ([`frame_floor`]); `None`: the statistics alone.
    pub spread_ref: Option<f32>,
}

/// mu and sigma (grey levels, floor applied) per cell of a head-pose grid.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseTables {
    /// The grid over (HeadYaw, HeadPitch) whose cells the tables follow.
    pub grid: PoseGrid,
    /// Mean error per cell, grey levels, row-major, face size.
    pub mu: Vec<Vec<f32>>,
    /// Error standard deviation per cell, grey levels, floor applied, row-major, face size.
    pub sigma: Vec<Vec<f32>>,
}

impl FloatEngine {
    /// The (mu, sigma) for a face seen with the head at `head`: the board's rule
    /// (`Model::stats_at`).
    pub fn stats_at(&self, head: [f32; 2]) -> (&[f32], &[f32]) {
        match self.pose.as_ref().and_then(|p| Some((p, p.grid.bin(head)?))) {
            Some((p, k)) => (&p.mu[k], &p.sigma[k]),
            None => (&self.mu, &self.sigma),
        }
    }

    /// The settings for a frame seen with the head at `head`: the firmware's rule, with the
    /// engine's own settings (scale 1).
    pub fn settings_at(&self, head: [f32; 2]) -> Settings {
        self.settings.in_region(self.region, 1.0, head)
    }

    /// One face seen with the head at `head`, given the model's prediction for it.
    pub fn detect(&self, crop: CropBox, face: &[u8], predicted: Vec<f32>, head: [f32; 2]) -> Detection {
        let s = &self.settings_at(head);
        let (mu, sigma) = self.stats_at(head);
        let (e, light) = face_error_fitted(face, &predicted, self.face_w, self.pool);
        let spread = frame_floor(face, &predicted, self.face_w, self.pool, &light, self.spread_ref);
        let saliency = saliency(e, mu, sigma, 0.0, spread[1], s.normalisation, s.sided);
        let mut light = light;
        if !floor_holds(spread[1]) {
            light.verdict = Verdict::NoFace;
        }
        let face_seen = light.verdict == Verdict::Face;
        let mask: Vec<bool> = saliency.iter().map(|&v| face_seen && v > s.threshold).collect();
        let h = mask.len() / self.face_w.max(1);
        // A face the labeller refuses (none the blob format allows) finds nothing.
        let blob = crate::detect::blobs::pick(&mask, self.face_w, h, s.min_area, s.merge)
            .ok()
            .flatten()
            .map(|b| b.offset(crop.x, crop.y));
        let joints = match (&self.reach, blob) {
            (Some(r), Some(b)) => Some(reach_float(r, b.centroid[0] as f32, b.centroid[1] as f32)),
            _ => None,
        };
        // Pooled one-sided, as the board (`msr_firmware::extent`): the pooled mask decides, the
        // extent reported is the salient pixels whose own error passes too.
        let mask = if self.pool > 0 && s.sided == Sided::One {
            let own = self::saliency(face_error(face, &predicted, self.face_w, 0), mu, sigma, 0.0, spread[1], s.normalisation, s.sided);
            mask.iter().zip(own).map(|(&m, o)| m && o > s.threshold).collect()
        } else {
            mask
        };
        Detection {
            crop,
            predicted,
            saliency,
            mask,
            blob,
            joints,
            light,
            spread,
            colour: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msr_shared::blob::Merge;

    /// The float engine switches to the pose region's settings where the firmware does.
    #[test]
    fn float_engine_takes_the_region_settings_near_its_centre() {
        let (w, h) = (10, 6);
        let region = PoseRegion { centre: [0.0, 0.0], radius: 0.01, threshold: 1.5, merge: Merge { margin: 2, fragment: 2 } };
        let own = Settings { threshold: 4.0, normalisation: Normalisation::StdDev, sided: Sided::One, min_area: 4, merge: Merge::OFF };
        let eng = FloatEngine { mu: vec![0.0; w * h], sigma: vec![1.0; w * h], settings: own, region: Some(region), reach: None, face_w: w, pool: 0, pose: None, spread_ref: None };
        assert_eq!(eng.settings_at([0.005, -0.005]), Settings { threshold: 1.5, merge: region.merge, ..own });
        assert_eq!(eng.settings_at([0.0, 0.02]), own);
        // A 2 x 2 patch 3 grey levels off the prediction: salient at 1.5, not at 4.0. (A
        // shaded face: a flat one shows the photometric fit no face.)
        let shade = |i: usize| (60 + 12 * (i % w) + 7 * (i / w)) as u8;
        let mut face: Vec<u8> = (0..w * h).map(shade).collect();
        for (y, x) in [(2, 3), (2, 4), (3, 3), (3, 4)] {
            face[y * w + x] += 3;
        }
        let pred: Vec<f32> = (0..w * h).map(|i| shade(i) as f32 / 255.0).collect();
        let crop = CropBox { x: 0, y: 0, width: w as u32, height: h as u32 };
        assert_eq!(eng.detect(crop, &face, pred.clone(), [0.0, 0.0]).blob.map(|b| b.area), Some(4));
        assert_eq!(eng.detect(crop, &face, pred, [0.0, 0.02]).blob, None);
    }

    /// The pooled error against a sum written out by hand, at a corner, an edge and inside.
    #[test]
    fn pooled_error_is_the_clipped_window_mean() {
        let (w, h) = (5usize, 4usize);
        let e: Vec<f64> = (0..w * h).map(|i| if i % 2 == 0 { i as f64 } else { -(i as f64) }).collect();
        let p = pooled_error(&e, w, 1);
        // (0, 0): pixels 0, 1, 5, 6 -> 0 - 1 - 5 + 6 = 0.
        assert_eq!(p[0], 0.0);
        // (0, 2): pixels 1, 2, 3, 6, 7, 8 -> -1 + 2 - 3 + 6 - 7 + 8 = 5, over 6.
        assert!((p[2] - 5.0 / 6.0).abs() < 1e-12);
        // (2, 2): rows 1..=3, cols 1..=3: -6 + 7 - 8 + 11 - 12 + 13 - 16 + 17 - 18 = -12, over 9.
        assert!((p[2 * w + 2] - 12.0 / 9.0).abs() < 1e-12);
        assert_eq!(pooled_error(&e, w, 0), e.iter().map(|v| v.abs()).collect::<Vec<_>>());
        // Texture of alternating sign cancels; a one-signed patch stays.
        let tex: Vec<f64> = (0..64).map(|i| if (i + i / 8) % 2 == 0 { 20.0 } else { -20.0 }).collect();
        assert!(pooled_error(&tex, 8, 1)[9 + 8] < 2.5, "{}", pooled_error(&tex, 8, 1)[17]);
        assert_eq!(pooled_error(&vec![20.0; 64], 8, 2)[27], 20.0);
    }
}
