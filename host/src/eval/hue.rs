//! Marks that only colour shows: a patch with each pixel's grey level kept and a strong hue,
//! pasted on a dataset's unmarked test frames, then found (or not) by the firmware pipeline.
//!
//! Per unmarked test frame: the frame as it is (a detection is a false alarm), then one patch
//! of each [`HUES`] at a seeded place on the face, each in a copy of the frame. A patch pixel
//! `p` becomes `p + k (h - grey(h))` for the hue `h`: grey is linear, so the pixel keeps its
//! grey level (to the byte's rounding), and `k` is the largest up to 1 that keeps every channel
//! in range. A patch is found when the winning blob's box meets the patch's box.
use crate::data::crop::{grey_of_rgb, load_colour, CropBox};
use crate::data::Dataset;
use crate::detect::cropper_of;
use crate::detect::fixed::detect_with;
use anyhow::{anyhow, ensure, Result};
use image::RgbImage;
use msr_shared::blob::Model;
use msr_sim::imperfect::Imperfections;
use msr_sim::layout::Split;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The hues pasted, by name and full-strength colour.
pub const HUES: [(&str, [u8; 3]); 4] = [("red", [255, 0, 0]), ("green", [0, 255, 0]), ("blue", [0, 0, 255]), ("yellow", [255, 255, 0])];
/// A patch's mean chroma change (`Cb`, `Cr` distance, levels) from which its hue counts as
/// strong.
pub const STRONG: f64 = 20.0;
/// Side of a patch, pixels (chosen per patch within it, inclusive).
pub const SIDE: [u32; 2] = [7, 11];

/// What the pasted patches gave.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HueMarks {
    /// Unmarked test frames used.
    pub frames: usize,
    /// Those with a detection as they are.
    pub false_alarms: usize,
    /// Patches pasted (frames x hues).
    pub marks: usize,
    /// Patches found.
    pub found: usize,
    /// Found and pasted per hue, in [`HUES`]' order.
    pub per_hue: Vec<(String, usize, usize)>,
    /// Patches whose pixels took a strong hue (a mean chroma change of at least [`STRONG`]):
    /// a patch on pixels already of its hue, or too dark or bright to take one at their grey
    /// level, barely changes them.
    pub strong: usize,
    /// Of those, found.
    pub strong_found: usize,
    /// The mean grey change a patch made on its pixels (rounding only), grey levels.
    pub grey_change: f64,
    /// The patches not found.
    pub missed: Vec<Missed>,
}

/// A patch that was not found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Missed {
    /// The frame's file.
    pub frame: String,
    /// The hue's name.
    pub hue: String,
    /// The patch's box in the frame, `[x0, y0, x1, y1]` inclusive.
    pub box_xyxy: [u32; 4],
    /// The mean chroma change the patch made on its pixels (`Cb`, `Cr` distance, 0..=255
    /// levels): how strong a hue the face's own grey levels let it take.
    pub chroma_change: f64,
    /// Whether anything was detected elsewhere on the frame.
    pub detected_elsewhere: bool,
}

/// A model's colour: how it was calibrated and what it finds that grey cannot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ColourCheck {
    /// The chroma section's calibration (`train::chroma`).
    pub calibration: crate::train::chroma::ChromaCalibration,
    /// The hue patches on the unmarked test frames, with the model.
    pub hue_marks: HueMarks,
    /// The same patches with the model's grey stage alone (its chroma section taken off).
    pub hue_marks_grey: HueMarks,
}

/// `pixel` with the hue `h` at the largest strength up to 1 that keeps the grey level.
pub fn with_hue(pixel: [u8; 3], h: [u8; 3]) -> [u8; 3] {
    let p = pixel.map(f64::from);
    let gh = 0.299 * h[0] as f64 + 0.587 * h[1] as f64 + 0.114 * h[2] as f64;
    let d = h.map(|c| c as f64 - gh);
    let mut k = 1f64;
    for c in 0..3 {
        if d[c] > 0.0 {
            k = k.min((255.0 - p[c]) / d[c]);
        } else if d[c] < 0.0 {
            k = k.min(p[c] / -d[c]);
        }
    }
    [0, 1, 2].map(|c| (p[c] + k * d[c]).round().clamp(0.0, 255.0) as u8)
}

/// `Cb`, `Cr` of a pixel (BT.601 full range, unrounded).
fn cbcr(p: [u8; 3]) -> [f64; 2] {
    let [r, g, b] = p.map(f64::from);
    [128.0 - 0.168736 * r - 0.331264 * g + 0.5 * b, 128.0 + 0.5 * r - 0.418688 * g - 0.081312 * b]
}

/// Pastes `hue` over the box `[x0, y0, x1, y1]` (inclusive) of `frame`; returns the mean
/// absolute grey change and the mean chroma change.
fn paste(frame: &mut RgbImage, b: [u32; 4], hue: [u8; 3]) -> (f64, f64) {
    let (mut change, mut chroma, mut n) = (0f64, 0f64, 0f64);
    for y in b[1]..=b[3] {
        for x in b[0]..=b[2] {
            let p = frame.get_pixel(x, y).0;
            let q = with_hue(p, hue);
            change += (grey_of_rgb(q[0], q[1], q[2]) as f64 - grey_of_rgb(p[0], p[1], p[2]) as f64).abs();
            let (a, c) = (cbcr(p), cbcr(q));
            chroma += ((a[0] - c[0]).powi(2) + (a[1] - c[1]).powi(2)).sqrt();
            n += 1.0;
            frame.put_pixel(x, y, image::Rgb(q));
        }
    }
    (change / n, chroma / n)
}

/// Where a patch of side `s` goes: its box inside the middle half of the face crop `c`.
fn place(rng: &mut ChaCha8Rng, c: CropBox, s: u32) -> [u32; 4] {
    let (x_lo, y_lo) = (c.x + c.width / 4, c.y + c.height / 4);
    let (x_hi, y_hi) = ((c.x + 3 * c.width / 4).saturating_sub(s).max(x_lo), (c.y + 3 * c.height / 4).saturating_sub(s).max(y_lo));
    let (x, y) = (rng.gen_range(x_lo..=x_hi), rng.gen_range(y_lo..=y_hi));
    [x, y, x + s - 1, y + s - 1]
}

/// The patches on the unmarked test frames of `data` (each through `camera`), with `model`.
pub fn hue_marks(blob: &[u8], data: &Path, camera: &Imperfections, seed: u64) -> Result<HueMarks> {
    let model = Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let cropper = cropper_of(&model)?;
    let ds = Dataset::load_split(data, Some(Split::Test), cropper.mode)?;
    let clean: Vec<_> = ds.samples.iter().enumerate().filter(|(_, s)| s.mark.is_none()).collect();
    ensure!(!clean.is_empty(), "dataset {} has no unmarked test frame", data.display());
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut ws = Box::new(msr_firmware::Workspace::new());
    let mut out = HueMarks { frames: clean.len(), false_alarms: 0, marks: 0, found: 0, per_hue: HUES.iter().map(|(n, _)| (n.to_string(), 0, 0)).collect(), grey_change: 0.0, missed: Vec::new(), strong: 0, strong_found: 0 };
    for (i, s) in clean {
        let (_, rgb) = load_colour(&s.file, &Imperfections::NONE, i as u64)?;
        let rgb = rgb.ok_or_else(|| anyhow!("{} is a grey frame: colour marks need colour", s.file.display()))?;
        let rgb = if camera.is_none() { rgb } else { camera.apply(&rgb, i as u64) };
        let mut detect = |frame: &RgbImage| -> Result<Option<[u32; 4]>> {
            let grey = crate::data::crop::grey_of(frame);
            let face = cropper.crop_colour(&grey, frame)?;
            let d = detect_with(&mut ws, &model, &face, s.head)?;
            Ok(d.blob.map(|b| b.box_xyxy))
        };
        out.false_alarms += detect(&rgb)?.is_some() as usize;
        for (k, (_, hue)) in HUES.iter().enumerate() {
            let side = rng.gen_range(SIDE[0]..=SIDE[1]);
            let b = place(&mut rng, s.face.crop, side);
            let mut marked = rgb.clone();
            let (grey_change, chroma_change) = paste(&mut marked, b, *hue);
            out.grey_change += grey_change;
            let seen = detect(&marked)?;
            let hit = seen.is_some_and(|d| d[0] <= b[2] && b[0] <= d[2] && d[1] <= b[3] && b[1] <= d[3]);
            if !hit {
                out.missed.push(Missed { frame: s.file.display().to_string(), hue: HUES[k].0.into(), box_xyxy: b, chroma_change, detected_elsewhere: seen.is_some() });
            }
            out.marks += 1;
            out.found += hit as usize;
            if chroma_change >= STRONG {
                out.strong += 1;
                out.strong_found += hit as usize;
            }
            out.per_hue[k].1 += hit as usize;
            out.per_hue[k].2 += 1;
        }
    }
    out.grey_change /= out.marks as f64;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hue_keeps_the_grey_level() {
        for p in [[120, 120, 120], [200, 90, 60], [30, 40, 50], [250, 250, 250]] {
            for (_, h) in HUES {
                let q = with_hue(p, h);
                let (gp, gq) = (grey_of_rgb(p[0], p[1], p[2]) as i32, grey_of_rgb(q[0], q[1], q[2]) as i32);
                assert!((gp - gq).abs() <= 1, "{p:?} -> {q:?}");
            }
        }
        // Mid-grey takes a strong hue: red goes up, green and blue down.
        let q = with_hue([120, 120, 120], [255, 0, 0]);
        assert!(q[0] > 200 && q[1] < 100 && q[2] < 100, "{q:?}");
    }
}
