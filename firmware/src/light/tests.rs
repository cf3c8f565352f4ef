use super::*;

const W: usize = 75;
const H: usize = 58;

/// A face-like prediction (Q8.8): smooth shading and some texture, grey 40..230.
fn face() -> Vec<u16> {
    (0..W * H)
        .map(|i| {
            let (x, y) = ((i % W) as f32, (i / W) as f32);
            let g = 135.0 + 55.0 * (x / 9.0).sin() + 35.0 * (y / 6.0).cos() + 5.0 * ((x * 3.0 + y) / 2.0).sin();
            (g * 256.0) as u16
        })
        .collect()
}

/// The prediction seen under gain `a` and offset `b`, with a little noise.
fn seen(pred: &[u16], a: f32, b: f32) -> Vec<u8> {
    pred.iter()
        .enumerate()
        .map(|(i, &p)| {
            let noise = ((i * 7919) % 5) as f32 - 2.0;
            (a * p as f32 / 256.0 + b + noise).round().clamp(0.0, 255.0) as u8
        })
        .collect()
}

fn mark(frame: &mut [u8], x0: usize, y0: usize, side: usize, grey: u8) {
    for y in y0..y0 + side {
        frame[y * W + x0..y * W + x0 + side].fill(grey);
    }
}

#[test]
fn the_fit_undoes_gain_and_offset() {
    let p = face();
    for (a, b) in [(1.0, 0.0), (0.7, 0.0), (1.1, 5.0), (0.8, -10.0), (1.25, -20.0)] {
        let f = fit(&seen(&p, a, b), &p, W);
        assert_eq!(f.verdict, Verdict::Face, "{a} {b}: {f:?}");
        // A pure exposure change is a pure gain; with an offset the anchored fit trades a
        // little of the offset for gain (checked below by what it leaves).
        let want = 1.0 / a;
        if b == 0.0 {
            assert!((f.gain_f32() - want).abs() < 0.02 * want, "{a} {b}: gain {}", f.gain_f32());
        }
        // v(I) lands on the prediction within a grey level or so.
        let t = {
            let mut t = [0; 256];
            f.table(&mut t);
            t
        };
        let frame = seen(&p, a, b);
        let err: f64 = frame.iter().zip(&p).filter(|(&i, _)| i > 0 && i < 255).map(|(&i, &q)| (t[i as usize] as f64 - q as f64).abs() / 256.0).sum::<f64>() / p.len() as f64;
        assert!(err < if b == 0.0 { 2.5 } else { 4.0 }, "{a} {b}: mean error {err}");
    }
}

#[test]
fn a_mark_does_not_pull_the_fit() {
    let p = face();
    let clean = fit(&seen(&p, 0.8, 0.0), &p, W);
    for grey in [20u8, 240] {
        let mut f = seen(&p, 0.8, 0.0);
        mark(&mut f, 30, 20, 15, grey);
        let m = fit(&f, &p, W);
        assert_eq!(m.verdict, Verdict::Face);
        assert!((m.gain - clean.gain).abs() < clean.gain / 100, "grey {grey}: {} vs {}", m.gain, clean.gain);
        assert!(m.inliers < clean.inliers, "the mark's samples are trimmed");
    }
}

#[test]
fn frames_without_the_face_are_refused() {
    let p = face();
    let verdict = |f: &[u8]| fit(f, &p, W).verdict;
    assert_eq!(verdict(&[0; W * H]), Verdict::NoFace, "black");
    assert_eq!(verdict(&[255; W * H]), Verdict::NoFace, "white");
    assert_eq!(verdict(&[128; W * H]), Verdict::NoFace, "covered");
    let noise: Vec<u8> = (0..W * H).map(|i| ((i * 2_654_435_761usize) >> 7) as u8).collect();
    assert_eq!(verdict(&noise), Verdict::NoFace, "no structure");
    // Another face: the prediction upside down.
    let flipped: Vec<u16> = p.chunks(W).rev().flatten().copied().collect();
    assert_eq!(verdict(&seen(&flipped, 1.0, 0.0)), Verdict::NoFace, "someone else");
}

#[test]
fn a_lamp_switching_mid_frame_or_a_wild_gain_is_a_changed_scene() {
    let p = face();
    let top = seen(&p, 1.0, 0.0);
    let bottom = seen(&p, 1.4, 0.0);
    let mut f = top.clone();
    f[W * H / 2..].copy_from_slice(&bottom[W * H / 2..]);
    let fit_ = fit(&f, &p, W);
    assert_eq!(fit_.verdict, Verdict::SceneChanged, "{fit_:?}");
    let dim = fit(&seen(&p, 0.3, 0.0), &p, W);
    assert_eq!(dim.verdict, Verdict::SceneChanged, "gain {}", dim.gain_f32());
}

#[test]
fn the_table_is_the_value_and_the_identity_is_a_shift() {
    let mut t = [0u16; 256];
    LightFit::IDENTITY.table(&mut t);
    assert_eq!(t, IDENTITY_TABLE);
    // The last four: the ends of what a fit gives, and past them (the i64 loop).
    for (gain, offset) in [
        (65536, 0),
        (93_000, -1_234_567),
        (40_000, 9_000_000),
        (300_000, 5),
        (1 << 20, 1 << 28),
        (-(1 << 20), -(1 << 28)),
        (i32::MAX, i32::MIN),
        (5_000_000, 2_000_000_000),
    ] {
        let f = LightFit { gain, offset, ..LightFit::IDENTITY };
        f.table(&mut t);
        for i in 0..=255u8 {
            assert_eq!(t[i as usize], f.value(i), "{gain} {offset} at {i}");
        }
    }
}

#[test]
fn odd_sizes_do_not_panic() {
    let p = face();
    for w in [0, 1, 3, W, MAX_FACE_W + 1] {
        let _ = fit(&seen(&p, 1.0, 0.0)[..100], &p[..100], w);
    }
    assert_eq!(fit(&[], &[], W).verdict, Verdict::NoFace);
}

/// The word-at-a-time test agrees with the plain one on every position of a 0 or a 255 and on
/// rows of every length, and finds nothing in rows of 1 ..= 254.
#[test]
fn any_clipped_finds_every_clipped_byte() {
    for len in 0..20usize {
        let quiet: Vec<u8> = (0..len).map(|i| [1u8, 254, 127, 128, 0x80, 0x7f, 0x01][i % 7]).collect();
        assert!(!super::any_clipped(&quiet), "{quiet:?}");
        for at in 0..len {
            for v in [0u8, 255] {
                let mut r = quiet.clone();
                r[at] = v;
                assert!(super::any_clipped(&r), "{r:?}");
            }
        }
    }
}

/// The censored error: a clipped pixel differs from the prediction only past the fit's
/// bound, and a row's censored prediction gives the same errors through `lut[f] - p`.
#[test]
fn clipped_pixels_are_censored() {
    let fit = LightFit { gain: 52429, offset: 0, ..LightFit::IDENTITY }; // gain 0.8
    let mut lut = [0u16; 256];
    fit.table(&mut lut);
    // v(255) = 204 grey: a prediction of 230 is consistent with a clipped pixel, 150 is not.
    assert_eq!(super::error(&lut, 255, 230 << 8), 0);
    assert_eq!(super::error(&lut, 255, 150 << 8), lut[255] as i32 - (150 << 8));
    assert_eq!(super::error(&lut, 0, 20 << 8), -(20 << 8));
    let frame = [255u8, 100, 0, 255];
    let pred = [230u16 << 8, 90 << 8, 20 << 8, 150 << 8];
    let mut out = [0u16; 4];
    assert!(super::censor_row(&frame, &pred, &lut, &mut out));
    for i in 0..4 {
        assert_eq!(lut[frame[i] as usize] as i32 - out[i] as i32, super::error(&lut, frame[i], pred[i]), "{i}");
    }
    assert!(!super::censor_row(&[1, 2, 3], &pred[..3], &lut, &mut out));
}

/// The last pass's test without squares is the squared test: `isqrt` is the floor of the root
/// at and around every square, and the samples kept (with their sums) are the same for cuts
/// at, under and over each residual, the saturated ones included.
#[test]
fn the_cut_without_squares_keeps_the_same_samples() {
    for r in (0u64..=65535).step_by(97).chain([1, 2, 3, 255, 256, 65534, 65535]) {
        for n in [r * r, (r * r).saturating_sub(1), r * r + 1, r * r + 2 * r] {
            if n > u32::MAX as u64 {
                continue;
            }
            let s = isqrt(n as u32) as u64;
            assert!(s * s <= n && (s + 1) * (s + 1) > n, "isqrt({n}) = {s}");
        }
    }
    assert_eq!(isqrt(u32::MAX), 65535);
    let mut rng = 0x2545_f491u32;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 17;
        rng ^= rng << 5;
        rng
    };
    let xs: Vec<u8> = (0..256).map(|_| (next() % 254 + 1) as u8).collect();
    let ys: Vec<u16> = (0..256).map(|_| next() as u16).collect();
    for (g, k) in [(65536, 0), (-(1 << 20), 1 << 28), (1 << 20, -(1 << 28)), (90_000, -3_000_000)] {
        let mut cuts: Vec<u32> = vec![0, 1, 65534 * 65534, 65535 * 65535 - 1, 65535 * 65535, u32::MAX];
        for (&x, &y) in xs.iter().zip(&ys).take(40) {
            let r = residual(x as u32, y as u32, g, k).unsigned_abs().min(65535);
            cuts.extend([r * r, (r * r).saturating_sub(1), r * r + 1]);
        }
        for cut2 in cuts {
            let (want, _) = kept(&xs, &ys, g, k, cut2);
            let got = kept_sums(&xs, &ys, g, k, cut2);
            assert_eq!((got.n, got.x, got.y, got.xx, got.xy), (want.n, want.x, want.y, want.xx, want.xy), "{g} {k} {cut2}");
            let yy: u64 = xs.iter().zip(&ys).filter(|&(&x, &y)| {
                let r = residual(x as u32, y as u32, g, k).unsigned_abs().min(65535);
                r * r <= cut2
            }).map(|(_, &y)| y as u64 * y as u64).sum();
            assert_eq!(got.yy, yy);
        }
    }
}
