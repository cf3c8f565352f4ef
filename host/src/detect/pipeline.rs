//! The detection pipeline on the host, stage by stage: predicted face -> saliency -> blobs ->
//! winner -> reach. The float engine lives here; the fixed engine is the firmware's code
//! (`crate::detect::fixed`). Both give a [`Detection`] so that `detect` and `eval` treat them alike.
use crate::data::crop::CropBox;
use msr_shared::blob::{Merge, Normalisation, PoseRegion, Reach, Sided, REACH_HIDDEN, REACH_OUT};
use serde::Serialize;

/// A connected component of salient pixels. Coordinates are in whatever frame it was found in
/// (face or full frame; see [`Blob::offset`]); boxes are inclusive.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Blob {
    pub area: u32,
    pub box_xyxy: [u32; 4],
    /// Mean of the pixel coordinates (x, y).
    pub centroid: [f64; 2],
}

impl Blob {
    pub fn offset(&self, dx: u32, dy: u32) -> Blob {
        let [x0, y0, x1, y1] = self.box_xyxy;
        Blob {
            area: self.area,
            box_xyxy: [x0 + dx, y0 + dy, x1 + dx, y1 + dy],
            centroid: [self.centroid[0] + dx as f64, self.centroid[1] + dy as f64],
        }
    }
}

/// The largest blob with at least `min_area` pixels; the first found wins a tie.
pub fn winner(blobs: &[Blob], min_area: u32) -> Option<Blob> {
    let mut best: Option<Blob> = None;
    for b in blobs.iter().filter(|b| b.area >= min_area) {
        if best.is_none_or(|w| b.area > w.area) {
            best = Some(*b);
        }
    }
    best
}

/// The winner of `blobs` (in raster order of their first pixels, as [`label_blobs`] gives
/// them): with `merge` on, fragments of at least `merge.fragment` pixels whose boxes come within
/// `merge.margin` are merged first (the firmware's `blobs::merge`, in float); a frame with more
/// than `MAX_FRAGMENTS` fragments is not merged. Largest area wins, the earlier first pixel on
/// ties.
pub fn pick(blobs: &[Blob], min_area: u32, merge: Merge) -> Option<Blob> {
    use msr_firmware::blobs::merge::MAX_FRAGMENTS;
    if !merge.is_on() {
        return winner(blobs, min_area);
    }
    // (area, box, sum x, sum y, rank of the first pixel)
    let mut g: Vec<(u32, [u32; 4], f64, f64, usize)> = blobs
        .iter()
        .enumerate()
        .filter(|(_, b)| b.area >= merge.fragment as u32)
        .map(|(i, b)| {
            let n = b.area as f64;
            (b.area, b.box_xyxy, (b.centroid[0] * n).round(), (b.centroid[1] * n).round(), i)
        })
        .collect();
    if g.len() > MAX_FRAGMENTS {
        return winner(blobs, min_area);
    }
    let m = merge.margin as u32;
    let near = |a: &[u32; 4], b: &[u32; 4]| {
        a[0] <= b[2] + m && b[0] <= a[2] + m && a[1] <= b[3] + m && b[1] <= a[3] + m
    };
    let mut changed = true;
    while changed {
        changed = false;
        let mut i = 0;
        while i < g.len() {
            let mut j = i + 1;
            while j < g.len() {
                if near(&g[i].1, &g[j].1) {
                    let b = g.swap_remove(j);
                    let a = &mut g[i];
                    a.0 += b.0;
                    a.1 = [a.1[0].min(b.1[0]), a.1[1].min(b.1[1]), a.1[2].max(b.1[2]), a.1[3].max(b.1[3])];
                    a.2 += b.2;
                    a.3 += b.3;
                    a.4 = a.4.min(b.4);
                    changed = true;
                } else {
                    j += 1;
                }
            }
            i += 1;
        }
    }
    g.into_iter()
        .filter(|b| b.0 >= min_area)
        .min_by_key(|b| (std::cmp::Reverse(b.0), b.4))
        .map(|(area, box_xyxy, sx, sy, _)| Blob {
            area,
            box_xyxy,
            centroid: [sx / area as f64, sy / area as f64],
        })
}

/// Novelty settings of one evaluation row or one detection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub threshold: f32,
    pub normalisation: Normalisation,
    pub sided: Sided,
    pub min_area: u16,
    pub merge: Merge,
}

/// Per-pixel saliency in threshold units: `(e - mu) / n` (one-sided) or `|e - mu| / n`, with
/// `e = |255 (I - I_hat)|` in grey levels and `n` = sigma or sigma^2. A pixel is salient when its
/// score exceeds the threshold. `sigma` already carries its floor.
pub fn saliency(
    face: &[u8],
    predicted: &[f32],
    mu: &[f32],
    sigma: &[f32],
    normalisation: Normalisation,
    sided: Sided,
) -> Vec<f32> {
    face.iter()
        .zip(predicted)
        .zip(mu.iter().zip(sigma))
        .map(|((&i, &p), (&m, &s))| {
            let e = (i as f32 - 255.0 * p).abs();
            let n = match normalisation {
                Normalisation::StdDev => s,
                Normalisation::Variance => s * s,
            };
            let d = match sided {
                Sided::One => e - m,
                Sided::Two => (e - m).abs(),
            };
            if n > 0.0 {
                d / n
            } else if d > 0.0 {
                f32::INFINITY
            } else {
                0.0
            }
        })
        .collect()
}

/// Everything one run of the pipeline on one frame produced.
#[derive(Clone, Debug)]
pub struct Detection {
    pub crop: CropBox,
    /// The predicted face, grey/255, row-major.
    pub predicted: Vec<f32>,
    /// Saliency in threshold units (for pictures and AUROC).
    pub saliency: Vec<f32>,
    /// Salient pixels.
    pub mask: Vec<bool>,
    /// The winning blob in full-frame pixels.
    pub blob: Option<Blob>,
    /// HeadYaw, HeadPitch, LShoulderPitch, LShoulderRoll, LElbowRoll (radians).
    pub joints: Option<[f32; REACH_OUT]>,
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

/// Blobs of a mask by imageproc's 8-connected labelling, in label order (row-major scan order
/// of each component's first pixel). The float engine's blob stage.
pub fn label_blobs(mask: &[bool], w: usize, h: usize) -> Vec<Blob> {
    use imageproc::region_labelling::{connected_components, Connectivity};
    let img = image::GrayImage::from_fn(w as u32, h as u32, |x, y| {
        image::Luma([if mask[y as usize * w + x as usize] {
            255
        } else {
            0
        }])
    });
    let labels = connected_components(&img, Connectivity::Eight, image::Luma([0u8]));
    let mut acc: Vec<(u32, [u32; 4], u64, u64)> = Vec::new();
    for (x, y, l) in labels.enumerate_pixels() {
        let l = l[0] as usize;
        if l == 0 {
            continue;
        }
        if acc.len() < l {
            acc.resize(l, (0, [u32::MAX, u32::MAX, 0, 0], 0, 0));
        }
        let a = &mut acc[l - 1];
        a.0 += 1;
        a.1 = [a.1[0].min(x), a.1[1].min(y), a.1[2].max(x), a.1[3].max(y)];
        a.2 += x as u64;
        a.3 += y as u64;
    }
    acc.into_iter()
        .filter(|a| a.0 > 0)
        .map(|(n, b, sx, sy)| Blob {
            area: n,
            box_xyxy: b,
            centroid: [sx as f64 / n as f64, sy as f64 / n as f64],
        })
        .collect()
}

/// The float pipeline for one face, given the model's prediction.
pub struct FloatEngine {
    /// Grey levels, row-major, face size.
    pub mu: Vec<f32>,
    /// Grey levels, floor applied.
    pub sigma: Vec<f32>,
    pub settings: Settings,
    /// Settings of their own near one head pose (the blob's `PoseRegion`).
    pub region: Option<PoseRegion>,
    pub reach: Option<Reach>,
    pub face_w: usize,
}

impl FloatEngine {
    /// The settings for a frame seen with the head at `head` (as the firmware's `Settings::at`).
    pub fn settings_at(&self, head: [f32; 2]) -> Settings {
        match self.region {
            Some(g) if g.contains(head) => Settings { threshold: g.threshold, merge: g.merge, ..self.settings },
            _ => self.settings,
        }
    }

    /// One face seen with the head at `head`, given the model's prediction for it.
    pub fn detect(&self, crop: CropBox, face: &[u8], predicted: Vec<f32>, head: [f32; 2]) -> Detection {
        let s = &self.settings_at(head);
        let saliency = saliency(
            face,
            &predicted,
            &self.mu,
            &self.sigma,
            s.normalisation,
            s.sided,
        );
        let mask: Vec<bool> = saliency.iter().map(|&v| v > s.threshold).collect();
        let h = mask.len() / self.face_w.max(1);
        let blobs = label_blobs(&mask, self.face_w, h);
        let blob = pick(&blobs, s.min_area as u32, s.merge).map(|b| b.offset(crop.x, crop.y));
        let joints = match (&self.reach, blob) {
            (Some(r), Some(b)) => Some(reach_float(r, b.centroid[0] as f32, b.centroid[1] as f32)),
            _ => None,
        };
        Detection {
            crop,
            predicted,
            saliency,
            mask,
            blob,
            joints,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use msr_firmware::blobs::{merge, FaceLabeller};

    fn xorshift_mask(w: usize, h: usize, density: u64, seed: u64) -> Vec<bool> {
        let mut s = seed | 1;
        (0..w * h)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s % 100 < density
            })
            .collect()
    }

    /// The float blob stage (imageproc labels, `pick`) and the firmware's (its labeller,
    /// `blobs::merge::pick`) give the same winner, merged or not, to the last bit.
    #[test]
    fn float_and_firmware_winners_agree_with_and_without_merge() {
        let mut lab = Box::new(FaceLabeller::new());
        let merges = [
            Merge::OFF,
            Merge { margin: 1, fragment: 1 },
            Merge { margin: 3, fragment: 3 },
            Merge { margin: 5, fragment: 3 },
            Merge { margin: 8, fragment: 10 },
        ];
        let mut merged_differs = 0;
        for seed in 0..300u64 {
            let (w, h) = (75, 58);
            let density = [2, 5, 10, 20, 40][seed as usize % 5];
            let mask = xorshift_mask(w, h, density, seed);
            let bytes: Vec<u8> = mask.iter().map(|&m| m as u8).collect();
            let blobs = label_blobs(&mask, w, h);
            for (k, &m) in merges.iter().enumerate() {
                let min_area = [30u16, 12, 8][(seed as usize + k) % 3].max(m.fragment);
                let host = pick(&blobs, min_area as u32, m);
                let (fw, _) = merge::pick(&mut lab, &bytes, w, h, min_area, m);
                let fw = fw.map(|b| {
                    let a = b.area as f64;
                    Blob {
                        area: b.area,
                        box_xyxy: [b.x0 as u32, b.y0 as u32, b.x1 as u32, b.y1 as u32],
                        centroid: [b.sum_x as f64 / a, b.sum_y as f64 / a],
                    }
                });
                assert_eq!(host, fw, "seed {seed}, {m:?}, min area {min_area}");
                if m.is_on() && host != pick(&blobs, min_area as u32, Merge::OFF) {
                    merged_differs += 1;
                }
            }
        }
        // The masks exercise the merge, not only the plain winner.
        assert!(merged_differs > 100, "{merged_differs}");
    }

    /// The float engine switches to the pose region's settings where the firmware does.
    #[test]
    fn float_engine_takes_the_region_settings_near_its_centre() {
        let (w, h) = (10, 6);
        let region = PoseRegion { centre: [0.0, 0.0], radius: 0.01, threshold: 1.5, merge: Merge { margin: 2, fragment: 2 } };
        let own = Settings { threshold: 4.0, normalisation: Normalisation::StdDev, sided: Sided::One, min_area: 4, merge: Merge::OFF };
        let eng = FloatEngine { mu: vec![0.0; w * h], sigma: vec![1.0; w * h], settings: own, region: Some(region), reach: None, face_w: w };
        assert_eq!(eng.settings_at([0.005, -0.005]), Settings { threshold: 1.5, merge: region.merge, ..own });
        assert_eq!(eng.settings_at([0.0, 0.02]), own);
        // A 2 x 2 patch 3 grey levels off the prediction: salient at 1.5, not at 4.0.
        let mut face = vec![100u8; w * h];
        for (y, x) in [(2, 3), (2, 4), (3, 3), (3, 4)] {
            face[y * w + x] = 103;
        }
        let pred = vec![100.0 / 255.0; w * h];
        let crop = CropBox { x: 0, y: 0, width: w as u32, height: h as u32 };
        assert_eq!(eng.detect(crop, &face, pred.clone(), [0.0, 0.0]).blob.map(|b| b.area), Some(4));
        assert_eq!(eng.detect(crop, &face, pred, [0.0, 0.02]).blob, None);
    }

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
        let blobs = label_blobs(&mask, w, h);
        assert_eq!(pick(&blobs, 30, Merge::OFF), None);
        assert_eq!(pick(&blobs, 30, Merge { margin: 2, fragment: 3 }), None, "gaps of 2 need margin 3");
        let b = pick(&blobs, 30, Merge { margin: 3, fragment: 3 }).unwrap();
        assert_eq!((b.area, b.box_xyxy), (36, [6, 4, 15, 13]));
        assert_eq!(b.centroid, [10.5, 8.5]);
    }
}
