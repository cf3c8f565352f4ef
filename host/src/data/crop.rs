//! The face crop, as the published code does it: grey frame, OpenCV `TM_CCOEFF` template matching
//! (not normalised), crop = the best-scoring window at template size, no resize.
//!
//! `TM_CCOEFF(x, y) = sum (T - mean T) * I(window) = (n CC(x, y) - sum(T) sum(I(window))) / n`.
//! The cross-correlation `CC` comes from FFTs in f64 (rustfft), rounded to the exact integers (see
//! [`cross_correlation`]), the window sums from an integral image (imageproc), so the scores are
//! exact integers: the winner is the true `TM_CCOEFF` argmax, first in row-major order on ties (as
//! OpenCV's `minMaxLoc`). imageproc's own `match_template` sums 4350 products one by one in f32
//! (rounding, and far slower); the tests check against it, against a brute-force reference and
//! against a plain f32 matrix product of the same correlation on a whole dataset and the real
//! frames.
//!
//! [`CropMode::Subpixel`] (our default for trained models; the published model keeps whole
//! pixels) refines the winner to a fraction of a pixel: per axis, the vertex of the parabola
//! through the scores at the winner and its two neighbours, clamped to +-0.5. The face is then
//! cut at that position by bilinear interpolation. Why: the camera sits in the head, so turning
//! the head by 1 deg moves the face about 5 px across the frame; a whole-pixel crop jumps
//! between neighbouring windows, and what a decoder of head angles must predict becomes a
//! sawtooth of head angle that no smooth network follows. On a fine texture (the skin robot's
//! taxels) a half-pixel jump is most of the error: with whole-pixel crops the skin decoder's test
//! MSE is about twice what it is with sub-pixel crops (0.0106 against 0.0049; red 0.0098 against
//! 0.0049).
mod correlate;

use anyhow::{bail, Context, Result};
use image::{DynamicImage, GrayImage, RgbImage};
use imageproc::integral_image::{integral_image, sum_image_pixels};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub use correlate::cross_correlation;
pub use msr_shared::blob::CropMode;

/// Where the face was cut from the frame, in full-frame pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CropBox {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Width, the template's.
    pub width: u32,
    /// Height, the template's.
    pub height: u32,
}

impl CropBox {
    /// Top-left `[x, y]` in the frame.
    pub fn origin(&self) -> [u32; 2] {
        [self.x, self.y]
    }

    /// `[width, height]`.
    pub fn size(&self) -> [u32; 2] {
        [self.width, self.height]
    }
}

/// A grey face crop.
#[derive(Clone, Debug, PartialEq)]
pub struct Face {
    /// The best whole-pixel window: the crop offset the board is told.
    pub crop: CropBox,
    /// Where the face was cut relative to `crop`, `[x, y]` pixels within +-0.5 (zero for a
    /// whole-pixel crop): face pixel `(r, c)` is frame point `(crop.x + c + shift[0],
    /// crop.y + r + shift[1])`.
    pub shift: [f32; 2],
    /// Where the face lies relative to `crop`, `[x, y]` pixels within +-1: `shift` refined
    /// against the template ([`align`]), the position the frame header gives the self gate.
    /// The crop stays cut at `shift`, as every model was trained on it. Zero for a whole-pixel
    /// crop.
    pub at: [f32; 2],
    /// Grey levels 0..=255, row-major, `crop.height x crop.width`.
    pub grey: Vec<u8>,
    /// The face's chroma planes, cut where the grey was ([`chroma_planes`]): `Cb` then `Cr`,
    /// one byte a 2 x 2 block (`msr_shared::blob::chroma`). Empty for a grey source.
    pub chroma: Vec<u8>,
    /// The `TM_CCOEFF` score of the chosen window.
    pub score: f64,
}

impl Face {
    /// The image the board is sent: the grey bytes, then the chroma planes when the face has
    /// them.
    pub fn image(&self) -> Vec<u8> {
        [&self.grey[..], &self.chroma[..]].concat()
    }

    /// The crop as grey/255, row-major (what the models take).
    pub fn unit(&self) -> Vec<f32> {
        self.grey.iter().map(|&g| g as f32 / 255.0).collect()
    }
}

/// OpenCV's `RGB2GRAY` for 8-bit images (OpenCV 4 fixed point: 0.299, 0.587, 0.114 in 15 bits,
/// rounded), so crops match the published pipeline bit for bit.
pub fn grey_of_rgb(r: u8, g: u8, b: u8) -> u8 {
    const RY: u32 = 9798;
    const GY: u32 = 19235;
    const BY: u32 = 3735;
    ((r as u32 * RY + g as u32 * GY + b as u32 * BY + (1 << 14)) >> 15) as u8
}

/// The grey of a colour frame, as [`to_grey`] makes it, read in place.
pub fn grey_of(rgb: &RgbImage) -> GrayImage {
    grey_of_rgb_bytes(rgb.width(), rgb.height(), rgb.as_raw())
}

/// [`grey_of_rgb`] of packed RGB bytes, `w x h`.
fn grey_of_rgb_bytes(w: u32, h: u32, rgb: &[u8]) -> GrayImage {
    let grey = rgb.chunks_exact(3).map(|p| grey_of_rgb(p[0], p[1], p[2])).collect();
    GrayImage::from_raw(w, h, grey).expect("an RGB image has three bytes a pixel")
}

/// Grey version of any decoded image. Alpha is dropped (as `cv2.imread` does by default); grey
/// images are taken as they are.
pub fn to_grey(img: &DynamicImage) -> GrayImage {
    match img {
        DynamicImage::ImageLuma8(g) => g.clone(),
        // A camera's or the sim's frame: straight from its bytes, with no copy of the frame and
        // no bounds check a pixel (0.12 ms for a 320 x 240 frame, against 0.28 ms with them).
        DynamicImage::ImageRgb8(rgb) => grey_of_rgb_bytes(rgb.width(), rgb.height(), rgb.as_raw()),
        _ => {
            let rgb = img.to_rgb8();
            grey_of_rgb_bytes(rgb.width(), rgb.height(), rgb.as_raw())
        }
    }
}

/// Reads an image file and converts it to grey; errors name the file.
pub fn load_grey(path: &Path) -> Result<GrayImage> {
    let img = image::open(path).with_context(|| format!("cannot read image {}", path.display()))?;
    Ok(to_grey(&img))
}

/// Reads an image file, takes a colour one through `camera` (frame number `frame` for its
/// noise), and returns its grey and, for a colour file, its colour; errors name the file.
pub fn load_colour(path: &Path, camera: &msr_sim::imperfect::Imperfections, frame: u64) -> Result<(GrayImage, Option<RgbImage>)> {
    let img = image::open(path).with_context(|| format!("cannot read image {}", path.display()))?;
    let grey_source = matches!(img, DynamicImage::ImageLuma8(_) | DynamicImage::ImageLuma16(_) | DynamicImage::ImageLumaA8(_) | DynamicImage::ImageLumaA16(_));
    if grey_source && camera.is_none() {
        return Ok((to_grey(&img), None));
    }
    let rgb = img.to_rgb8();
    let rgb = if camera.is_none() { rgb } else { camera.apply(&rgb, frame) };
    Ok((grey_of(&rgb), if grey_source { None } else { Some(rgb) }))
}

/// The chroma planes of `face` in the colour `frame` it was cut from: each pixel's BT.601
/// full-range `Cb` and `Cr` (128 neutral, as a webcam's YCbCr), resampled at the face's crop
/// and shift as its grey was, averaged over each 2 x 2 block (one row or column at an odd
/// edge) and rounded. `Cb` plane then `Cr` plane, `ceil(h / 2) x ceil(w / 2)` each.
pub fn chroma_planes(frame: &RgbImage, face: &Face) -> Vec<u8> {
    let c = face.crop;
    // The planes of a window around the crop with room for the shift's neighbours.
    let (x0, y0) = (c.x.saturating_sub(2), c.y.saturating_sub(2));
    let (x1, y1) = ((c.x + c.width + 2).min(frame.width()), (c.y + c.height + 2).min(frame.height()));
    let (ww, wh) = (x1.saturating_sub(x0), y1.saturating_sub(y0));
    let (mut cb, mut cr) = (GrayImage::new(ww, wh), GrayImage::new(ww, wh));
    for y in 0..wh {
        for x in 0..ww {
            let [r, g, b] = frame.get_pixel(x0 + x, y0 + y).0.map(f32::from);
            cb.put_pixel(x, y, image::Luma([(128.0 - 0.168736 * r - 0.331264 * g + 0.5 * b).round().clamp(0.0, 255.0) as u8]));
            cr.put_pixel(x, y, image::Luma([(128.0 + 0.5 * r - 0.418688 * g - 0.081312 * b).round().clamp(0.0, 255.0) as u8]));
        }
    }
    let local = CropBox { x: c.x - x0, y: c.y - y0, ..c };
    let (h, w) = (c.height as usize, c.width as usize);
    let (bh, bw) = (h.div_ceil(2), w.div_ceil(2));
    let mut out = vec![0u8; 2 * bh * bw];
    for (k, plane) in [cb, cr].iter().enumerate() {
        let v = if ww == 0 || wh == 0 { vec![128.0; h * w] } else { resample(plane, local, face.shift) };
        for by in 0..bh {
            for bx in 0..bw {
                let (mut sum, mut n) = (0f32, 0f32);
                for y in 2 * by..(2 * by + 2).min(h) {
                    for x in 2 * bx..(2 * bx + 2).min(w) {
                        sum += v[y * w + x];
                        n += 1.0;
                    }
                }
                out[k * bh * bw + by * bw + bx] = (sum / n).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

/// Widest template whose row sums stay exact in f32 (255 * 255 * 258 < 2^24).
pub const MAX_TEMPLATE_W: u32 = 258;
/// Largest frame the face crop takes (1920 x 1080 and then some; the Nao camera gives at most
/// 1280 x 960): the match holds `pixels x template rows` floats.
pub const MAX_FRAME_PIXELS: u64 = 2_500_000;

/// `TM_CCOEFF * n` of every window of `tpl` in `frame`, row-major, `(fh-th+1) x (fw-tw+1)`.
struct Scores {
    s: Vec<i64>,
    ow: u32,
    oh: u32,
}

impl Scores {
    fn of(frame: &GrayImage, tpl: &GrayImage) -> Result<Scores> {
        Self::of_with(frame, tpl, cross_correlation)
    }

    /// The scores with a given cross-correlation (the tests pass the matrix-product oracle).
    fn of_with(frame: &GrayImage, tpl: &GrayImage, cc: fn(&GrayImage, &GrayImage) -> Vec<i64>) -> Result<Scores> {
        let (fw, fh, tw, th) = (frame.width(), frame.height(), tpl.width(), tpl.height());
        if tw == 0 || th == 0 {
            bail!("face template is empty");
        }
        if fw < tw || fh < th {
            bail!("frame {fw}x{fh} is smaller than the face template {tw}x{th}");
        }
        // The match sums a template row in f32: exact while a row's sum stays under 2^24
        // (tw * 255 * 255), and it holds a float per frame pixel and template row.
        if tw > MAX_TEMPLATE_W {
            bail!("face template {tw}x{th} is wider than the {MAX_TEMPLATE_W} px the face crop sums exactly");
        }
        if fw as u64 * fh as u64 > MAX_FRAME_PIXELS {
            bail!("frame {fw}x{fh} has more than the {MAX_FRAME_PIXELS} pixels the face crop takes");
        }
        let n = (tw * th) as i64;
        let t_sum: i64 = tpl.as_raw().iter().map(|&v| v as i64).sum();
        let cc = cc(frame, tpl);
        let integral = integral_image::<_, u32>(frame);
        let (ow, oh) = (fw - tw + 1, fh - th + 1);
        let s = cc
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let (x, y) = (i as u32 % ow, i as u32 / ow);
                let sum = sum_image_pixels(&integral, x, y, x + tw - 1, y + th - 1)[0] as i64;
                n * c - t_sum * sum
            })
            .collect();
        Ok(Scores { s, ow, oh })
    }

    fn at(&self, x: u32, y: u32) -> i64 {
        self.s[(y * self.ow + x) as usize]
    }

    /// The best window of `tpl` ([`Scores::best`]) as a crop box, and its `TM_CCOEFF` score.
    fn window(&self, tpl: &GrayImage) -> Result<(CropBox, f64)> {
        let (x, y) = self.best()?;
        let crop = CropBox { x, y, width: tpl.width(), height: tpl.height() };
        Ok((crop, self.at(x, y) as f64 / (tpl.width() * tpl.height()) as f64))
    }

    /// The best window, first in row-major order on ties (OpenCV's `minMaxLoc`).
    fn best(&self) -> Result<(u32, u32)> {
        let mut best: Option<(i64, usize)> = None;
        for (i, &v) in self.s.iter().enumerate() {
            if best.is_none_or(|(b, _)| v > b) {
                best = Some((v, i));
            }
        }
        let (_, i) = best.context("template matching found no window")?;
        Ok((i as u32 % self.ow, i as u32 / self.ow))
    }

    /// The peak's offset from the whole-pixel winner `(x, y)`, per axis the vertex of the
    /// parabola through the winner and its two neighbours; 0 at the border or on a flat ridge.
    fn refine(&self, x: u32, y: u32) -> [f32; 2] {
        let vertex = |a: i64, b: i64, c: i64| {
            let (a, b, c) = (a as f64, b as f64, c as f64);
            let curv = a - 2.0 * b + c;
            // b is the maximum, so curv <= 0; 0 means three equal scores.
            if curv < 0.0 {
                (0.5 * (a - c) / curv).clamp(-0.5, 0.5) as f32
            } else {
                0.0
            }
        };
        let dx = if x > 0 && x + 1 < self.ow {
            vertex(self.at(x - 1, y), self.at(x, y), self.at(x + 1, y))
        } else {
            0.0
        };
        let dy = if y > 0 && y + 1 < self.oh {
            vertex(self.at(x, y - 1), self.at(x, y), self.at(x, y + 1))
        } else {
            0.0
        };
        [dx, dy]
    }
}

/// The best `TM_CCOEFF` window of `tpl` in `frame` and its score. Errors when the frame is smaller
/// than the template or either is empty.
pub fn match_face(frame: &GrayImage, tpl: &GrayImage) -> Result<(CropBox, f64)> {
    Scores::of(frame, tpl)?.window(tpl)
}

/// Crops the face out of a grey frame, as the published code does (whole pixels).
pub fn crop_face(frame: &GrayImage, tpl: &GrayImage) -> Result<Face> {
    crop_face_with(frame, tpl, CropMode::Pixel)
}

/// Crops the face out of a grey frame in the given mode (see the module notes).
pub fn crop_face_with(frame: &GrayImage, tpl: &GrayImage, mode: CropMode) -> Result<Face> {
    crop_from(frame, tpl, mode, Scores::of(frame, tpl)?)
}

fn crop_from(frame: &GrayImage, tpl: &GrayImage, mode: CropMode, scores: Scores) -> Result<Face> {
    let (crop, score) = scores.window(tpl)?;
    let (grey, shift, at) = match mode {
        CropMode::Pixel => (cut(frame, crop), [0.0; 2], [0.0; 2]),
        CropMode::Subpixel => {
            let shift = scores.refine(crop.x, crop.y);
            (cut_shifted(frame, crop, shift), shift, align(frame, tpl, crop, shift))
        }
    };
    Ok(Face { crop, shift, at, grey, chroma: Vec::new(), score })
}

/// Gauss-Newton steps of [`align`] (each moves by under a hundredth of a pixel by the fourth).
const ALIGN_STEPS: usize = 4;

/// Where `tpl` lies in `frame` relative to the window `crop`, `[x, y]` pixels, starting from
/// `start` (the parabola's vertex): Lucas-Kanade, each step cutting the window at the estimate
/// by bilinear interpolation, both it and the template brought to zero mean and unit spread
/// (blind to the exposure), and moving by the least-squares step along the window's
/// gradient. Why: the parabola through three `TM_CCOEFF` scores is off by up to a tenth of a
/// pixel, by an amount that cycles with the face's sub-pixel phase (pixel locking), and on a
/// fine texture (the skin robot's taxels) it jitters at some phases: a servo that friction stops
/// one count short moved the face half a pixel and the self gate saw the skin robot's own image
/// turn 1 % slower, hold 2.5 times less still, and refused it in 16 of 160 probes. Here the
/// gain stays within 0.2 % at every phase. `start` whenever the steps do not converge within
/// half a pixel of it (a flat window, a face mostly off the frame).
pub fn align(frame: &GrayImage, tpl: &GrayImage, crop: CropBox, start: [f32; 2]) -> [f32; 2] {
    let (w, h) = (tpl.width() as usize, tpl.height() as usize);
    if w < 3 || h < 3 || (crop.width as usize, crop.height as usize) != (w, h) {
        return start;
    }
    let standardise = |v: &mut [f64]| {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n).sqrt();
        v.iter_mut().for_each(|x| *x = (*x - mean) / sd);
    };
    let mut t: Vec<f64> = tpl.as_raw().iter().map(|&v| v as f64).collect();
    standardise(&mut t);
    let mut d = start.map(|v| v as f64);
    for _ in 0..ALIGN_STEPS {
        let mut win: Vec<f64> = resample(frame, crop, d.map(|v| v as f32)).into_iter().map(f64::from).collect();
        standardise(&mut win);
        // Normal equations of the step: A [dx dy] = -b, over the pixels with both neighbours.
        let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for r in 1..h - 1 {
            let (up, mid, down, tr) = (&win[(r - 1) * w..r * w], &win[r * w..(r + 1) * w], &win[(r + 1) * w..(r + 2) * w], &t[r * w..(r + 1) * w]);
            for c in 1..w - 1 {
                let gx = (mid[c + 1] - mid[c - 1]) / 2.0;
                let gy = (down[c] - up[c]) / 2.0;
                let e = mid[c] - tr[c];
                (a11, a12, a22, b1, b2) = (a11 + gx * gx, a12 + gx * gy, a22 + gy * gy, b1 + gx * e, b2 + gy * e);
            }
        }
        let det = a11 * a22 - a12 * a12;
        d[0] -= (a22 * b1 - a12 * b2) / det;
        d[1] -= (a11 * b2 - a12 * b1) / det;
        if !(0..2).all(|i| d[i].is_finite() && (d[i] - start[i] as f64).abs() <= 0.5) {
            return start;
        }
    }
    d.map(|v| v as f32)
}

/// A face template and how to crop with it: what the host needs to make a model's crops.
#[derive(Clone, Debug, PartialEq)]
pub struct Cropper {
    /// The grey face template matched against each frame.
    pub template: GrayImage,
    /// Whole-pixel or sub-pixel crops.
    pub mode: CropMode,
    /// The model reads colour: a face cut from a colour frame carries its chroma planes
    /// ([`Cropper::crop_colour`]).
    pub colour: bool,
}

impl Cropper {
    /// Crops with `template` in `mode`, grey only.
    pub fn new(template: GrayImage, mode: CropMode) -> Cropper {
        Cropper { template, mode, colour: false }
    }

    /// The same, with the face's chroma planes when `colour`.
    pub fn with_colour(self, colour: bool) -> Cropper {
        Cropper { colour, ..self }
    }

    /// The face in a colour frame whose grey is `grey`: [`Cropper::crop`], with its chroma
    /// planes when the model reads colour.
    pub fn crop_colour(&self, grey: &GrayImage, rgb: &RgbImage) -> Result<Face> {
        let mut face = self.crop(grey)?;
        if self.colour {
            face.chroma = chroma_planes(rgb, &face);
        }
        Ok(face)
    }

    /// The face in the grey `frame`: the best `TM_CCOEFF` window, cut as the mode says.
    pub fn crop(&self, frame: &GrayImage) -> Result<Face> {
        crop_face_with(frame, &self.template, self.mode)
    }
}

/// `crop` moved by `shift` (each within +-0.5 px), by bilinear interpolation, rounded to grey
/// levels. Samples beyond the frame take the nearest edge pixel.
pub fn cut_shifted(frame: &GrayImage, crop: CropBox, shift: [f32; 2]) -> Vec<u8> {
    resample(frame, crop, shift).into_iter().map(|v| v.round().clamp(0.0, 255.0) as u8).collect()
}

/// `crop` moved by any `shift`, by bilinear interpolation, row-major; samples beyond the frame
/// take the nearest edge pixel.
fn resample(frame: &GrayImage, crop: CropBox, shift: [f32; 2]) -> Vec<f32> {
    let (fw, fh) = (frame.width() as i64, frame.height() as i64);
    let raw = frame.as_raw();
    let px = |x: i64, y: i64| raw[(y.clamp(0, fh - 1) * fw + x.clamp(0, fw - 1)) as usize] as f32;
    // Sample point c + d = (c + base) + frac, with frac in [0, 1).
    let split = |d: f32| {
        let base = d.floor();
        (base as i64, d - base)
    };
    let ((bx, fx), (by, fy)) = (split(shift[0]), split(shift[1]));
    let mut out = Vec::with_capacity((crop.width * crop.height) as usize);
    let (x0, y0) = (crop.x as i64 + bx, crop.y as i64 + by);
    if x0 >= 0 && y0 >= 0 && x0 + crop.width as i64 + 1 <= fw && y0 + crop.height as i64 + 1 <= fh {
        // Every sample and its right and lower neighbours inside the frame (the usual case): the
        // same arithmetic on rows of the frame, without a clamp a read (the alignment takes 0.13
        // ms so, 0.16 ms with the clamps).
        let w = crop.width as usize;
        for r in 0..crop.height as usize {
            let at = (y0 as usize + r) * fw as usize + x0 as usize;
            let (row, below) = (&raw[at..at + w + 1], &raw[at + fw as usize..at + fw as usize + w + 1]);
            for c in 0..w {
                out.push(bilerp([row[c], row[c + 1], below[c], below[c + 1]].map(f32::from), fx, fy));
            }
        }
        return out;
    }
    for r in 0..crop.height as i64 {
        let y = crop.y as i64 + r + by;
        for c in 0..crop.width as i64 {
            let x = crop.x as i64 + c + bx;
            out.push(bilerp([px(x, y), px(x + 1, y), px(x, y + 1), px(x + 1, y + 1)], fx, fy));
        }
    }
    out
}

/// Bilinear interpolation between a pixel, its right, lower and lower-right neighbours (`q`),
/// `fx` of the way right and `fy` down: the one formula both of [`resample`]'s loops use.
#[inline(always)]
fn bilerp(q: [f32; 4], fx: f32, fy: f32) -> f32 {
    let top = q[0] + fx * (q[1] - q[0]);
    let bottom = q[2] + fx * (q[3] - q[2]);
    top + fy * (bottom - top)
}

/// The pixels of `frame` inside `crop`, row-major. `crop` must lie inside the frame.
pub fn cut(frame: &GrayImage, crop: CropBox) -> Vec<u8> {
    let w = frame.width() as usize;
    let raw = frame.as_raw();
    let mut out = Vec::with_capacity((crop.width * crop.height) as usize);
    for y in crop.y..crop.y + crop.height {
        let start = y as usize * w + crop.x as usize;
        out.extend_from_slice(&raw[start..start + crop.width as usize]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The correlation as one matrix product (`matrixmultiply`), the oracle the
    /// FFT one must agree with exactly.
    pub fn cross_correlation_gemm(frame: &GrayImage, tpl: &GrayImage) -> Vec<i64> {
        let (fw, fh) = (frame.width() as usize, frame.height() as usize);
        let (tw, th) = (tpl.width() as usize, tpl.height() as usize);
        let f: Vec<f32> = frame.as_raw().iter().map(|&v| v as f32).collect();
        let t: Vec<f32> = tpl.as_raw().iter().map(|&v| v as f32).collect();
        // A[i][k] = f[i + k] (every stretch of tw pixels of the flat frame), B[k][r] = t[r][k]:
        // C[i][r] = template row r against the stretch starting at flat index i.
        let m = fw * fh - tw + 1;
        let mut c = vec![0f32; m * th];
        // SAFETY: A reads f[i + k] for i < m, k < tw, i.e. up to fw*fh - 1; B reads t[r*tw + k] for
        // r < th, k < tw; C is m x th, column-major (C[i][r] at r*m + i), written without aliasing.
        unsafe {
            matrixmultiply::sgemm(
                m,
                tw,
                th,
                1.0,
                f.as_ptr(),
                1,
                1,
                t.as_ptr(),
                1,
                tw as isize,
                0.0,
                c.as_mut_ptr(),
                1,
                m as isize,
            );
        }
        let (ow, oh) = (fw - tw + 1, fh - th + 1);
        let mut out = vec![0i64; ow * oh];
        for y in 0..oh {
            let dst = &mut out[y * ow..(y + 1) * ow];
            for r in 0..th {
                let src = &c[r * m + (y + r) * fw..][..ow];
                for (o, &v) in dst.iter_mut().zip(src) {
                    *o += v as i64;
                }
            }
        }
        out
    }

    /// Exact `TM_CCOEFF * n` at one window: `sum (n T - sum T) * I`, in integers.
    fn ccoeff_exact(frame: &GrayImage, tpl: &GrayImage, t_sum: i64, x: u32, y: u32) -> i64 {
        let n = (tpl.width() * tpl.height()) as i64;
        let fw = frame.width() as usize;
        let tw = tpl.width() as usize;
        let (f, t) = (frame.as_raw(), tpl.as_raw());
        let mut acc = 0i64;
        for dy in 0..tpl.height() as usize {
            let row = (y as usize + dy) * fw + x as usize;
            let fr = &f[row..row + tw];
            let tr = &t[dy * tw..dy * tw + tw];
            let dot: i64 = fr.iter().zip(tr).map(|(&a, &b)| a as i64 * b as i64).sum();
            let s: i64 = fr.iter().map(|&a| a as i64).sum();
            acc += n * dot - t_sum * s;
        }
        acc
    }

    fn brute(frame: &GrayImage, tpl: &GrayImage) -> (u32, u32) {
        let t_sum: i64 = tpl.as_raw().iter().map(|&v| v as i64).sum();
        let mut best = (i64::MIN, 0, 0);
        for y in 0..=frame.height() - tpl.height() {
            for x in 0..=frame.width() - tpl.width() {
                let s = ccoeff_exact(frame, tpl, t_sum, x, y);
                if s > best.0 {
                    best = (s, x, y);
                }
            }
        }
        (best.1, best.2)
    }

    #[test]
    fn fft_correlation_equals_the_gemm_oracle() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Odd and even sizes, a template as large as the frame, and saturated pixels.
        for (fw, fh, tw, th) in [(40, 30, 9, 7), (41, 33, 10, 5), (64, 48, 64, 48), (75, 58, 75, 1), (320, 240, 75, 58)] {
            for fill in [None, Some(255u8)] {
                let frame = GrayImage::from_fn(fw, fh, |_, _| image::Luma([fill.unwrap_or_else(|| rng.gen())]));
                let tpl = GrayImage::from_fn(tw, th, |_, _| image::Luma([fill.unwrap_or_else(|| rng.gen())]));
                assert_eq!(cross_correlation(&frame, &tpl), cross_correlation_gemm(&frame, &tpl), "{fw}x{fh} / {tw}x{th}");
            }
        }
    }

    /// Both crop modes, by the FFT scores and by the matrix-product oracle's, on every frame.
    fn assert_same_crops(frames: &[GrayImage], tpl: &GrayImage) {
        crate::data::parallel_map(frames, |f| {
            let old = Scores::of_with(f, tpl, cross_correlation_gemm).unwrap();
            for mode in [CropMode::Pixel, CropMode::Subpixel] {
                let want = crop_from(f, tpl, mode, Scores { s: old.s.clone(), ow: old.ow, oh: old.oh }).unwrap();
                assert_eq!(crop_face_with(f, tpl, mode).unwrap(), want, "{mode:?}");
            }
            Ok(())
        })
        .unwrap();
    }

    #[test]
    fn crops_of_a_whole_dataset_equal_the_matrix_product_oracles() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = msr_sim::dataset::DatasetConfig::paper(msr_sim::Robot::Red, 0);
        let index = msr_sim::dataset::write_dataset(&cfg, dir.path()).unwrap();
        assert_eq!(index.frames.len(), 1300);
        let tpl = load_grey(&dir.path().join(&index.template)).unwrap();
        let frames: Vec<GrayImage> = index.frames.iter().map(|f| load_grey(&dir.path().join(&f.file)).unwrap()).collect();
        assert_same_crops(&frames, &tpl);
    }

    #[test]
    fn crops_of_the_real_frames_equal_the_matrix_product_oracles() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nao-red-real");
        if !dir.exists() {
            eprintln!("skipping: {} not found", dir.display());
            return;
        }
        let mut names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .filter(|n| n.starts_with("test") && n.ends_with(".png"))
            .collect();
        names.sort();
        assert_eq!(names.len(), 15, "{names:?}");
        let frames: Vec<GrayImage> = names.iter().map(|n| load_grey(&dir.join(n)).unwrap()).collect();
        assert_same_crops(&frames, &load_grey(&dir.join("head_filter.png")).unwrap());
    }

    #[test]
    fn finds_the_planted_template_and_agrees_with_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for trial in 0..20 {
            let frame = GrayImage::from_fn(40, 30, |_, _| image::Luma([rng.gen()]));
            let (tx, ty) = (rng.gen_range(0..30), rng.gen_range(0..20));
            let tpl = image::imageops::crop_imm(&frame, tx, ty, 9, 7).to_image();
            let (b, _) = match_face(&frame, &tpl).unwrap();
            assert_eq!((b.x, b.y), brute(&frame, &tpl), "trial {trial}");
            assert_eq!((b.x, b.y), (tx, ty), "trial {trial}");
            assert_eq!((b.width, b.height), (9, 7));
        }
    }

    #[test]
    fn grey_conversion_weighs_each_channel_of_each_pixel() {
        // Every byte distinct along a row, so a channel or a pixel taken out of turn shows.
        let rgb = image::RgbImage::from_fn(7, 5, |x, y| image::Rgb([(x * 37 + y) as u8, (x * 11 + 90 * y) as u8, (200 - 13 * x - y) as u8]));
        let want = GrayImage::from_fn(7, 5, |x, y| {
            let p = rgb.get_pixel(x, y).0;
            image::Luma([grey_of_rgb(p[0], p[1], p[2])])
        });
        assert_eq!(grey_of_rgb(255, 0, 0), 76);
        assert_eq!(grey_of_rgb(0, 255, 0), 150);
        assert_eq!(grey_of_rgb(0, 0, 255), 29);
        assert_eq!(to_grey(&DynamicImage::ImageRgb8(rgb.clone())), want);
        let rgba = DynamicImage::ImageRgb8(rgb).to_rgba8();
        assert_eq!(to_grey(&DynamicImage::ImageRgba8(rgba)), want, "alpha dropped");
    }

    #[test]
    fn ccoeff_is_blind_to_a_brightness_offset() {
        // TM_CCOEFF subtracts the template mean: lifting the whole frame changes no decision.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for _ in 0..10 {
            let frame = GrayImage::from_fn(36, 28, |_, _| image::Luma([rng.gen_range(0..200)]));
            let tpl = GrayImage::from_fn(8, 6, |_, _| image::Luma([rng.gen()]));
            let lifted =
                GrayImage::from_fn(36, 28, |x, y| image::Luma([frame.get_pixel(x, y)[0] + 55]));
            let (a, _) = match_face(&frame, &tpl).unwrap();
            let (b, _) = match_face(&lifted, &tpl).unwrap();
            assert_eq!(a, b);
            assert_eq!((a.x, a.y), brute(&frame, &tpl));
        }
    }

    #[test]
    fn cross_correlation_agrees_with_imageproc() {
        use imageproc::template_matching::{match_template, MatchTemplateMethod};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let frame = GrayImage::from_fn(120, 90, |_, _| image::Luma([rng.gen()]));
        let tpl = GrayImage::from_fn(31, 23, |_, _| image::Luma([rng.gen()]));
        let ours = cross_correlation(&frame, &tpl);
        let theirs = match_template(&frame, &tpl, MatchTemplateMethod::CrossCorrelation);
        assert_eq!(ours.len() as u32, theirs.width() * theirs.height());
        for (a, b) in ours.iter().zip(theirs.pixels()) {
            // imageproc rounds its f32 running sum; ours is exact.
            assert!(
                (*a as f64 - b[0] as f64).abs() <= 1e-6 * *a as f64 + 1.0,
                "{a} vs {}",
                b[0]
            );
        }
    }

    #[test]
    fn same_size_frame_and_template_is_the_only_window() {
        let f = GrayImage::from_fn(5, 4, |x, y| image::Luma([(x * 10 + y) as u8]));
        let (b, _) = match_face(&f, &f).unwrap();
        assert_eq!(
            b,
            CropBox {
                x: 0,
                y: 0,
                width: 5,
                height: 4
            }
        );
    }

    #[test]
    fn frame_smaller_than_template_is_an_error() {
        let f = GrayImage::new(10, 10);
        let t = GrayImage::new(11, 5);
        let e = match_face(&f, &t).unwrap_err().to_string();
        assert!(e.contains("smaller than the face template"), "{e}");
        assert!(match_face(&f, &GrayImage::new(0, 0)).is_err());
    }

    /// A smooth bump of radius ~6 px centred at `(cx, cy)` on a 60 x 50 frame.
    fn bump(cx: f32, cy: f32) -> GrayImage {
        GrayImage::from_fn(60, 50, |x, y| {
            let d2 = (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2);
            image::Luma([(40.0 + 180.0 * (-d2 / 40.0).exp()).round() as u8])
        })
    }

    #[test]
    fn subpixel_crop_follows_a_fractional_move_that_a_pixel_crop_rounds() {
        let tpl = image::imageops::crop_imm(&bump(30.0, 25.0), 18, 15, 25, 21).to_image();
        for (dx, dy) in [(0.0, 0.0), (0.3, -0.2), (-0.45, 0.4), (0.25, 0.25), (-0.1, -0.35)] {
            let frame = bump(33.0 + dx, 22.0 + dy);
            let px = crop_face_with(&frame, &tpl, CropMode::Pixel).unwrap();
            let sub = crop_face_with(&frame, &tpl, CropMode::Subpixel).unwrap();
            // Both find the same whole-pixel window (moved by 3, -3); only the sub-pixel one moves on.
            assert_eq!((px.crop.x, px.crop.y), (21, 12));
            assert_eq!(sub.crop, px.crop);
            assert_eq!(px.shift, [0.0, 0.0]);
            assert_eq!(px.grey, cut(&frame, px.crop));
            assert!((sub.shift[0] - dx).abs() < 0.08 && (sub.shift[1] - dy).abs() < 0.08, "{dx} {dy}: {:?}", sub.shift);
            // The resampled face is closer to the template than the whole-pixel one.
            let err = |g: &[u8]| -> f64 {
                g.iter().zip(tpl.as_raw()).map(|(&a, &b)| (a as f64 - b as f64).powi(2)).sum::<f64>() / g.len() as f64
            };
            let (e_px, e_sub) = (err(&px.grey), err(&sub.grey));
            assert!(e_sub <= 1.0, "{dx} {dy}: sub-pixel crop MSE {e_sub}");
            if dx.abs() + dy.abs() > 0.3 {
                assert!(e_sub * 4.0 < e_px, "{dx} {dy}: {e_sub} vs {e_px}");
            }
        }
    }

    /// The face crop's x over head yaws a quarter of an encoder count apart (five counts, about
    /// two pixels), for each robot's clean rendered face: its largest distance from the
    /// least-squares line, by the parabola's vertex (`shift`) and by [`align`] (`at`).
    fn off_the_line(robot: msr_sim::Robot) -> (f64, f64) {
        use msr_sim::body::BodyPose;
        use msr_sim::render::{Renderer, Variation};
        let r = Renderer::new(robot);
        let cropper = Cropper::new(r.template(), CropMode::Subpixel);
        let count = std::f64::consts::TAU / 4096.0;
        let (mut yaws, mut by_shift, mut by_at) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..=20 {
            let yaw = 0.25 * k as f64 * count;
            let frame = r.render(&BodyPose::head(yaw, 0.0), None, &Variation::CLEAN);
            let face = cropper.crop(&to_grey(&DynamicImage::ImageRgb8(frame.rgb))).unwrap();
            yaws.push(yaw);
            by_shift.push(face.crop.x as f64 + face.shift[0] as f64);
            by_at.push(face.crop.x as f64 + face.at[0] as f64);
        }
        let worst = |x: &[f64]| {
            let n = x.len() as f64;
            let (my, mx) = (yaws.iter().sum::<f64>() / n, x.iter().sum::<f64>() / n);
            let b = yaws.iter().zip(x).map(|(y, x)| (y - my) * (x - mx)).sum::<f64>()
                / yaws.iter().map(|y| (y - my) * (y - my)).sum::<f64>();
            yaws.iter().zip(x).map(|(y, x)| (x - mx - b * (y - my)).abs()).fold(0.0, f64::max)
        };
        (worst(&by_shift), worst(&by_at))
    }

    /// Pixel locking: the parabola's vertex cycles about the face's true position with its
    /// sub-pixel phase, which the self gate read as a skin robot turning 1 % slow once friction
    /// held the head a count short. The aligned position follows the head.
    #[test]
    fn the_aligned_face_position_follows_the_head_where_the_parabola_locks_to_pixels() {
        for robot in [msr_sim::Robot::Red, msr_sim::Robot::Skin] {
            let (shift, at) = off_the_line(robot);
            assert!(shift > 0.08, "{robot}: the parabola off the line by only {shift} px: the test tests nothing");
            assert!(at < 0.06, "{robot}: the aligned position off the line by {at} px (the parabola: {shift})");
        }
        // A flat frame has no gradient: the parabola's vertex stays.
        let flat = GrayImage::from_pixel(40, 30, image::Luma([90]));
        let tpl = GrayImage::from_fn(30, 20, |x, y| image::Luma([(3 * x + 5 * y) as u8]));
        assert_eq!(align(&flat, &tpl, CropBox { x: 5, y: 4, width: 30, height: 20 }, [0.25, -0.1]), [0.25, -0.1]);
    }

    #[test]
    fn shifted_cut_interpolates_and_holds_the_edges() {
        // Bilinear interpolation is exact on a plane.
        let ramp = GrayImage::from_fn(20, 16, |x, y| image::Luma([(3 * x + 7 * y) as u8]));
        let crop = CropBox { x: 4, y: 3, width: 8, height: 6 };
        assert_eq!(cut_shifted(&ramp, crop, [0.0, 0.0]), cut(&ramp, crop));
        for shift in [[0.5, 0.0], [-0.5, 0.25], [0.2, -0.4]] {
            let got = cut_shifted(&ramp, crop, shift);
            for r in 0..6 {
                for c in 0..8 {
                    let want = 3.0 * (4.0 + c as f32 + shift[0]) + 7.0 * (3.0 + r as f32 + shift[1]);
                    assert_eq!(got[r * 8 + c], want.round() as u8, "{shift:?} at {r},{c}");
                }
            }
        }
        // At the frame's edge the missing neighbour is the edge pixel itself.
        let edge = CropBox { x: 12, y: 10, width: 8, height: 6 };
        let got = cut_shifted(&ramp, edge, [0.5, 0.5]);
        assert_eq!(got[6 * 8 - 1], ramp.get_pixel(19, 15)[0]);
        assert_eq!(got[0], ((3.0 * 12.5 + 7.0 * 10.5) as f32).round() as u8);
    }

    #[test]
    fn subpixel_refinement_stays_put_at_the_border() {
        // The template is the whole frame: one window, no neighbours to fit.
        let f = bump(30.0, 25.0);
        let face = crop_face_with(&f, &f, CropMode::Subpixel).unwrap();
        assert_eq!(face.shift, [0.0, 0.0]);
        assert_eq!(face.grey, f.as_raw().clone());
        let c = Cropper::new(f.clone(), CropMode::Subpixel);
        assert_eq!(c.crop(&f).unwrap(), face);
    }

    #[test]
    fn grey_matches_opencv_weights() {
        assert_eq!(grey_of_rgb(255, 255, 255), 255);
        assert_eq!(grey_of_rgb(0, 0, 0), 0);
        assert_eq!(grey_of_rgb(255, 0, 0), 76); // 0.299 * 255 = 76.2
        assert_eq!(grey_of_rgb(0, 255, 0), 150); // 0.587 * 255 = 149.7
        assert_eq!(grey_of_rgb(0, 0, 255), 29); // 0.114 * 255 = 29.1
    }
}
