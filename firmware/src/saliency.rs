//! Saliency: which pixels differ from the prediction more than the face normally does.
//!
//! Per pixel, with `e = |255 (I - I_hat)|` in grey levels and the model's statistics mu, sigma:
//! salient when `(e - mu) / n > t` (one-sided) or `|e - mu| / n > t` (two-sided), where `n` is
//! sigma ([`Normalisation::StdDev`]) or sigma^2 ([`Normalisation::Variance`]).
//!
//! No division per pixel: `t * n` is a per-pixel table in Q8.8 grey levels ([`Thresholds`]),
//! made once per model and setting, so the test is `e - mu > tn` (or `|e - mu| > tn`) in
//! integers. `tn = round(t * n * 256)` saturates at 65535, which no error reaches.
//! `n = 0` gives `tn = 0`: any error different from mu is salient, as a division by 0 would say.

use msr_shared::blob::{Merge, Model, Normalisation, Novelty, PoseRegion, Sided, U16Table, MAX_FACE_PIXELS};

/// Novelty settings in force: the model's defaults, or what the host configured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Saliency threshold `t`, in units of the normalisation (finite, > 0).
    pub threshold: f32,
    /// Whether `n` is sigma or sigma^2.
    pub normalisation: Normalisation,
    /// One-sided (`e - mu > tn`) or two-sided (`|e - mu| > tn`) test.
    pub sided: Sided,
    /// Smallest blob, pixels, that counts as a mark.
    pub min_area: u16,
    /// Fragment merge before the area test (the model's; the host cannot change it).
    pub merge: Merge,
}

impl Settings {
    /// The settings stored in the model blob.
    pub fn of(model: &Model) -> Settings {
        Settings::of_novelty(&model.novelty)
    }

    /// The settings for a frame seen with the head at `head`: inside the model's pose region
    /// (`blob::PoseRegion`), the region's threshold and merge; elsewhere these. A threshold the
    /// host configured scales the region's by the same factor (region threshold x configured /
    /// model threshold), so one knob moves both.
    pub fn at(&self, model: &Model, head: [f32; 2]) -> Settings {
        self.in_region(model.region, self.threshold / model.novelty.threshold, head)
    }

    /// The one rule behind [`Settings::at`], for callers that hold a region without a blob (the
    /// host's float engine and calibration): inside `region`, its threshold times `scale` (the
    /// configured threshold over the model's; 1 for the model's own settings) and its merge;
    /// elsewhere (or without a region, or at a non-finite head pose) these.
    pub fn in_region(&self, region: Option<PoseRegion>, scale: f32, head: [f32; 2]) -> Settings {
        match region {
            Some(g) if g.contains(head) => Settings {
                threshold: g.threshold * scale,
                merge: g.merge,
                ..*self
            },
            _ => *self,
        }
    }

    /// The settings a model's novelty block stores.
    pub fn of_novelty(n: &Novelty) -> Settings {
        Settings {
            threshold: n.threshold,
            normalisation: n.normalisation,
            sided: n.sided,
            min_area: n.min_area,
            merge: n.merge,
        }
    }

    /// Finite positive threshold, min area at least 1, a merge valid for it.
    pub fn is_valid(&self) -> bool {
        self.threshold.is_finite()
            && self.threshold > 0.0
            && self.min_area >= 1
            && self.merge.is_valid(self.min_area)
    }
}

/// `t * n` per pixel, Q8.8 grey levels.
pub struct Thresholds {
    tn: [u16; MAX_FACE_PIXELS],
    len: usize,
    /// (model CRC, threshold bits, normalisation) the table was made for.
    key: Option<(u32, u32, Normalisation)>,
}

impl Default for Thresholds {
    fn default() -> Self {
        Self::new()
    }
}

/// One pixel's `t * n` in Q8.8, saturating.
pub fn threshold_q88(sigma_q88: u16, threshold: f32, normalisation: Normalisation) -> u16 {
    let s = sigma_q88 as f32 / 256.0;
    let n = match normalisation {
        Normalisation::StdDev => s,
        Normalisation::Variance => s * s,
    };
    let v = threshold * n * 256.0;
    if v.is_nan() || v < 0.0 {
        0
    } else if v >= 65534.5 {
        u16::MAX
    } else {
        (v + 0.5) as u16
    }
}

impl Thresholds {
    /// An empty table; the first [`Thresholds::prepare`] fills it.
    pub const fn new() -> Self {
        Thresholds {
            tn: [0; MAX_FACE_PIXELS],
            len: 0,
            key: None,
        }
    }

    /// Makes the table for `model` and `threshold`/`normalisation`, unless it is already made.
    /// Returns true when it was recomputed.
    pub fn prepare(&mut self, model: &Model, s: &Settings) -> bool {
        let key = (model.crc32, s.threshold.to_bits(), s.normalisation);
        let n = model
            .face_pixels()
            .min(MAX_FACE_PIXELS)
            .min(model.sigma.len());
        if self.key == Some(key) && self.len == n {
            return false;
        }
        for (t, sigma) in self.tn[..n].iter_mut().zip(model.sigma.iter()) {
            *t = threshold_q88(sigma, s.threshold, s.normalisation);
        }
        self.len = n;
        self.key = Some(key);
        true
    }

    /// Forgets the table, so that the next [`Thresholds::prepare`] recomputes it.
    pub fn invalidate(&mut self) {
        self.key = None;
    }

    /// The `tn` table, Q8.8 grey levels per pixel, row-major (empty before `prepare`).
    pub fn table(&self) -> &[u16] {
        &self.tn[..self.len]
    }
}

/// Writes `mask[i] = 1` for salient pixels, 0 otherwise, and returns how many are salient.
/// `frame` is grey 0..255, `pred` the predicted face in Q8.8 grey levels, `mu` the model's mean
/// error table; all of `frame.len()` pixels (the shortest input bounds the work).
pub fn saliency(
    frame: &[u8],
    pred: &[u16],
    mu: U16Table,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
) -> u32 {
    // Blobs in memory are 4-byte aligned, so mu is normally a u16 slice; else read bytes.
    match bytemuck::try_cast_slice::<u8, u16>(mu.0) {
        Ok(mu) => run(frame, pred, mu.iter().copied(), tn, sided, mask),
        Err(_) => run(frame, pred, mu.iter(), tn, sided, mask),
    }
}

#[inline(always)]
fn run(
    frame: &[u8],
    pred: &[u16],
    mu: impl Iterator<Item = u16>,
    tn: &[u16],
    sided: Sided,
    mask: &mut [u8],
) -> u32 {
    let mut count = 0u32;
    let px = frame.iter().zip(pred).zip(mu).zip(tn).zip(mask.iter_mut());
    match sided {
        Sided::One => {
            for ((((&i, &p), m), &t), out) in px {
                let e = (((i as i32) << 8) - p as i32).abs();
                let s = (e - m as i32 > t as i32) as u8;
                *out = s;
                count += s as u32;
            }
        }
        Sided::Two => {
            for ((((&i, &p), m), &t), out) in px {
                let e = (((i as i32) << 8) - p as i32).abs();
                let s = ((e - m as i32).abs() > t as i32) as u8;
                *out = s;
                count += s as u32;
            }
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threshold_table_values() {
        // sigma 2.0 grey, t 4.59: StdDev -> 9.18 grey = 2350.08 -> 2350.
        assert_eq!(threshold_q88(512, 4.59, Normalisation::StdDev), 2350);
        // Variance: 4.59 * 4 = 18.36 grey -> 4700.16 -> 4700.
        assert_eq!(threshold_q88(512, 4.59, Normalisation::Variance), 4700);
        assert_eq!(threshold_q88(0, 4.59, Normalisation::StdDev), 0);
        assert_eq!(
            threshold_q88(u16::MAX, 1e30, Normalisation::Variance),
            u16::MAX
        );
    }

    #[test]
    fn one_and_two_sided() {
        // Pixel 0: error 10 grey above mu 2 (t*n = 4): salient both ways.
        // Pixel 1: error 0, mu 8: e - mu = -8: salient two-sided only.
        // Pixel 2: error 3, mu 2: below t*n: never.
        let frame = [110u8, 50, 53];
        let pred = [100 * 256, 50 * 256, 50 * 256];
        let mu_bytes: Vec<u8> = [2u16 * 256, 8 * 256, 2 * 256]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let tn = [4 * 256u16; 3];
        let mut mask = [9u8; 3];
        let n = saliency(
            &frame,
            &pred,
            U16Table(&mu_bytes),
            &tn,
            Sided::One,
            &mut mask,
        );
        assert_eq!((n, mask), (1, [1, 0, 0]));
        let n = saliency(
            &frame,
            &pred,
            U16Table(&mu_bytes),
            &tn,
            Sided::Two,
            &mut mask,
        );
        assert_eq!((n, mask), (2, [1, 1, 0]));
        // Unaligned mu bytes take the other path and agree.
        let mut shifted = vec![0u8];
        shifted.extend_from_slice(&mu_bytes);
        let n = saliency(
            &frame,
            &pred,
            U16Table(&shifted[1..]),
            &tn,
            Sided::Two,
            &mut mask,
        );
        assert_eq!((n, mask), (2, [1, 1, 0]));
    }
}
