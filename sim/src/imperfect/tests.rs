use super::*;
use rand::Rng;

/// A frame with texture in the middle and a flat border wider than any kernel here, so that
/// what the edges do does not enter the means.
fn textured(seed: u64) -> RgbImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    RgbImage::from_fn(120, 90, |x, y| {
        if (30..90).contains(&x) && (30..60).contains(&y) {
            image::Rgb([rng.gen_range(40..200), rng.gen_range(40..200), rng.gen_range(40..200)])
        } else {
            image::Rgb([120, 110, 100])
        }
    })
}

fn mean(img: &RgbImage) -> f64 {
    img.as_raw().iter().map(|&v| v as f64).sum::<f64>() / img.as_raw().len() as f64
}

fn grey(img: &RgbImage) -> Vec<f64> {
    crate::render::to_grey(img).as_raw().iter().map(|&v| v as f64).collect()
}

#[test]
fn none_gives_the_same_bytes() {
    let f = textured(1);
    assert!(Imperfections::NONE.is_none() && Imperfections::default().with_seed(9).is_none());
    assert_eq!(Imperfections::NONE.apply(&f, 3), f);
}

#[test]
fn the_tone_curve_maps_mid_grey_as_its_exponent_says() {
    let mid = RgbImage::from_pixel(8, 8, image::Rgb([128, 128, 128]));
    for (gamma, want) in [(0.8f32, 146.9f32), (1.25, 107.74)] {
        let got = Imperfections::NONE.with_gamma(gamma).apply(&mid, 0).get_pixel(3, 3).0;
        let exact = 255.0 * (128f32 / 255.0).powf(gamma);
        assert!((exact - want).abs() < 0.1, "{exact}");
        assert_eq!(got, [exact.round() as u8; 3], "gamma {gamma}");
    }
    // Black and white stay where they are.
    let ends = RgbImage::from_fn(2, 1, |x, _| image::Rgb([255 * x as u8; 3]));
    assert_eq!(Imperfections::NONE.with_gamma(0.5).apply(&ends, 0), ends);
}

#[test]
fn exposure_and_white_balance_scale_the_channels_and_clip() {
    let p = RgbImage::from_pixel(2, 2, image::Rgb([100, 200, 50]));
    let e = Imperfections::NONE.with_exposure(1.3).apply(&p, 0);
    assert_eq!(e.get_pixel(0, 0).0, [130, 255, 65]);
    let wb = Imperfections::NONE.with_white_balance([1.2, 1.0, 0.5]).apply(&p, 0);
    assert_eq!(wb.get_pixel(1, 1).0, [120, 200, 25]);
    // 5500 K is the camera's balance; a warmer light takes green and blue down.
    assert!(Imperfections::NONE.with_colour_temperature(5500.0).is_none());
    let warm = Imperfections::NONE.with_colour_temperature(4675.0).white_balance;
    assert!(warm[0] == 1.0 && warm[1] < 0.95 && warm[2] < warm[1], "{warm:?}");
}

#[test]
fn blur_keeps_the_mean_and_softens() {
    let f = textured(2);
    let sd = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt()
    };
    for cam in [
        Imperfections::NONE.with_defocus(1.0),
        Imperfections::NONE.with_motion(5.0, 0.0),
        Imperfections::NONE.with_motion(5.0, 90.0),
        Imperfections::NONE.with_motion(7.5, 30.0),
    ] {
        let b = cam.apply(&f, 0);
        assert!((mean(&b) - mean(&f)).abs() < 0.2, "{cam:?}: {} against {}", mean(&b), mean(&f));
        assert!(sd(&grey(&b)) < 0.8 * sd(&grey(&f)), "{cam:?}");
    }
    // Horizontal motion leaves a horizontal edge as it is, and smears a vertical one over
    // its length.
    let edge = RgbImage::from_fn(40, 40, |x, y| image::Rgb([if x < 20 { 0 } else { 200 }, if y < 20 { 0 } else { 200 }, 0]));
    let m = Imperfections::NONE.with_motion(5.0, 0.0).apply(&edge, 0);
    for y in 0..40 {
        assert_eq!(m.get_pixel(30, y).0[1], edge.get_pixel(30, y).0[1]);
    }
    let row: Vec<u8> = (15..25).map(|x| m.get_pixel(x, 5).0[0]).collect();
    // The 5-tap box: the edge takes five pixels to climb.
    assert_eq!(row, [0, 0, 0, 40, 80, 120, 160, 200, 200, 200], "{row:?}");
}

#[test]
fn a_jpeg_round_trip_differs_but_stays_close() {
    let f = textured(3);
    let j = Imperfections::NONE.with_jpeg(Some(50)).apply(&f, 0);
    assert_ne!(j, f);
    let (a, b) = (grey(&f), grey(&j));
    let rms = (a.iter().zip(&b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64).sqrt();
    assert!(rms > 0.5 && rms < 25.0, "{rms}");
    assert!((mean(&j) - mean(&f)).abs() < 2.0);
    // Higher quality, closer.
    let j95 = grey(&Imperfections::NONE.with_jpeg(Some(95)).apply(&f, 0));
    let rms95 = (a.iter().zip(&j95).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64).sqrt();
    assert!(rms95 < rms, "{rms95} {rms}");
}

#[test]
fn noise_has_the_sd_asked_for_in_grey_and_a_seed_reproduces_it() {
    let flat = RgbImage::from_pixel(200, 150, image::Rgb([120, 130, 110]));
    let cam = Imperfections::NONE.with_noise(6.0).with_seed(11);
    let n = cam.apply(&flat, 4);
    let base = grey(&flat)[0];
    let d: Vec<f64> = grey(&n).iter().map(|g| g - base).collect();
    let m = d.iter().sum::<f64>() / d.len() as f64;
    let sd = (d.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / d.len() as f64).sqrt();
    assert!(m.abs() < 0.1 && (sd - 6.0).abs() < 0.15, "mean {m}, sd {sd}");
    assert_eq!(cam.apply(&flat, 4), n, "the same seed and frame, the same draws");
    assert_ne!(cam.apply(&flat, 5), n, "another frame, other draws");
    assert_ne!(cam.with_seed(12).apply(&flat, 4), n, "another seed, other draws");
}

#[test]
fn the_smear_follows_the_head() {
    let cam = Imperfections::NONE.with_motion(5.0, 0.0).with_noise(2.0);
    let v = Imperfections::reference_head_speed();
    assert!((v - 0.8268).abs() < 1e-3, "{v}");
    assert_eq!(cam.moving([0.0, 0.0]).motion, MotionBlur::NONE);
    assert_eq!(cam.moving([0.0, 0.0]).noise, 2.0);
    let m = cam.moving([v / 2.0, 0.0]).motion;
    assert!((m.length_px - 2.5).abs() < 1e-4 && m.angle_deg == 0.0, "{m:?}");
    let m = cam.moving([0.0, -2.0 * v]).motion;
    assert!((m.length_px - 10.0).abs() < 1e-3 && (m.angle_deg + 90.0).abs() < 1e-4, "{m:?}");
    assert_eq!(Imperfections::NONE.moving([1.0, 1.0]), Imperfections::NONE);
}

#[test]
fn out_of_range_is_refused_by_field() {
    assert!(Imperfections::NONE.check().is_ok());
    for (cam, field) in [
        (Imperfections::NONE.with_exposure(0.0), "exposure"),
        (Imperfections::NONE.with_exposure(f32::NAN), "exposure"),
        (Imperfections::NONE.with_gamma(f32::INFINITY), "gamma"),
        (Imperfections::NONE.with_noise(-1.0), "noise"),
        (Imperfections::NONE.with_defocus(11.0), "defocus"),
        (Imperfections::NONE.with_motion(60.0, 0.0), "motion blur"),
        (Imperfections::NONE.with_white_balance([1.0, 0.0, 1.0]), "white balance gain"),
        (Imperfections::NONE.with_jpeg(Some(0)), "JPEG quality"),
    ] {
        assert_eq!(cam.check().unwrap_err().field, field, "{cam:?}");
    }
}
