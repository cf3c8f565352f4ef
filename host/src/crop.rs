//! The face crop, as the published code does it: grey frame, OpenCV `TM_CCOEFF` template matching
//! (not normalised), crop = the best-scoring window at template size, no resize.
//!
//! `TM_CCOEFF(x, y) = sum (T - mean T) * I(window) = (n CC(x, y) - sum(T) sum(I(window))) / n`.
//! The cross-correlation `CC` is one matrix product (each template row against every stretch of the
//! frame, `matrixmultiply`), the window sums come from an integral image (imageproc). Each row dot
//! product is an integer below 2^24, so f32 holds it exactly and the scores are exact integers: the
//! winner is the true `TM_CCOEFF` argmax, first in row-major order on ties (as OpenCV's
//! `minMaxLoc`). imageproc's own `match_template` sums 4350 products one by one in f32 (rounding,
//! and about 30x slower); the tests check against it and against a brute-force reference.
use anyhow::{bail, Context, Result};
use image::{DynamicImage, GrayImage};
use imageproc::integral_image::{integral_image, sum_image_pixels};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Where the face was cut from the frame, in full-frame pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CropBox {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

/// A grey face crop.
#[derive(Clone, Debug, PartialEq)]
pub struct Face {
    pub crop: CropBox,
    /// Grey levels 0..=255, row-major, `crop.height x crop.width`.
    pub grey: Vec<u8>,
    /// The `TM_CCOEFF` score of the chosen window.
    pub score: f64,
}

impl Face {
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

/// Grey version of any decoded image. Alpha is dropped (as `cv2.imread` does by default); grey
/// images are taken as they are.
pub fn to_grey(img: &DynamicImage) -> GrayImage {
    match img {
        DynamicImage::ImageLuma8(g) => g.clone(),
        _ => {
            let rgb = img.to_rgb8();
            GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
                let p = rgb.get_pixel(x, y).0;
                image::Luma([grey_of_rgb(p[0], p[1], p[2])])
            })
        }
    }
}

/// Reads an image file and converts it to grey; errors name the file.
pub fn load_grey(path: &Path) -> Result<GrayImage> {
    let img = image::open(path).with_context(|| format!("cannot read image {}", path.display()))?;
    Ok(to_grey(&img))
}

/// Cross-correlation of `tpl` over every window of `frame` (row-major, `(fh-th+1) x (fw-tw+1)`),
/// exact.
pub fn cross_correlation(frame: &GrayImage, tpl: &GrayImage) -> Vec<i64> {
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

/// The best `TM_CCOEFF` window of `tpl` in `frame` and its score. Errors when the frame is smaller
/// than the template or either is empty.
pub fn match_face(frame: &GrayImage, tpl: &GrayImage) -> Result<(CropBox, f64)> {
    let (fw, fh, tw, th) = (frame.width(), frame.height(), tpl.width(), tpl.height());
    if tw == 0 || th == 0 {
        bail!("face template is empty");
    }
    if fw < tw || fh < th {
        bail!("frame {fw}x{fh} is smaller than the face template {tw}x{th}");
    }
    let n = (tw * th) as i64;
    let t_sum: i64 = tpl.as_raw().iter().map(|&v| v as i64).sum();
    let cc = cross_correlation(frame, tpl);
    let integral = integral_image::<_, u32>(frame);
    let ow = fw - tw + 1;
    let mut best: Option<(i64, u32, u32)> = None;
    for (i, &c) in cc.iter().enumerate() {
        let (x, y) = (i as u32 % ow, i as u32 / ow);
        let s = sum_image_pixels(&integral, x, y, x + tw - 1, y + th - 1)[0] as i64;
        let score = n * c - t_sum * s;
        if best.is_none_or(|(b, _, _)| score > b) {
            best = Some((score, x, y));
        }
    }
    let (score, x, y) = best.context("template matching found no window")?;
    Ok((
        CropBox {
            x,
            y,
            width: tw,
            height: th,
        },
        score as f64 / n as f64,
    ))
}

/// Crops the face out of a grey frame.
pub fn crop_face(frame: &GrayImage, tpl: &GrayImage) -> Result<Face> {
    let (crop, score) = match_face(frame, tpl)?;
    let grey = cut(frame, crop);
    Ok(Face { crop, grey, score })
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

    #[test]
    fn grey_matches_opencv_weights() {
        assert_eq!(grey_of_rgb(255, 255, 255), 255);
        assert_eq!(grey_of_rgb(0, 0, 0), 0);
        assert_eq!(grey_of_rgb(255, 0, 0), 76); // 0.299 * 255 = 76.2
        assert_eq!(grey_of_rgb(0, 255, 0), 150); // 0.587 * 255 = 149.7
        assert_eq!(grey_of_rgb(0, 0, 255), 29); // 0.114 * 255 = 29.1
    }
}
