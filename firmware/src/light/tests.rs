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

/// A plateau at the frame's brightest (darkest) level is where the camera clipped: those pixels
/// leave the fit and their error is censored there, as at 255 (0).
#[test]
fn a_plateau_at_the_frames_extreme_is_where_the_camera_clipped() {
    let p = face();
    assert_eq!(fit(&seen(&p, 1.0, 0.0), &p, W).clip, [0, 255], "nothing clipped");
    // Clipped at 255 by a bright exposure, then darkened after the clip (x 0.7): white at 179.
    let bright = seen(&p, 1.3, 0.0);
    assert!(bright.iter().filter(|&&v| v == 255).count() > W * H / 10);
    assert_eq!(fit(&bright, &p, W).clip, [0, 255], "clipped at the camera's own 255");
    let dark: Vec<u8> = bright.iter().map(|&v| (v as f32 * 0.7).round() as u8).collect();
    let f = fit(&dark, &p, W);
    assert_eq!(f.verdict, Verdict::Face, "{f:?}");
    assert_eq!(f.clip, [0, 179]);
    assert!((f.gain_f32() - 1.0 / 0.91).abs() < 0.02, "gain {}", f.gain_f32());
    // With the plateau taken as grey, the fit bends towards it (the white that should be
    // brighter than 179 counts as 179).
    let mut no_plateau = dark.clone();
    no_plateau.iter_mut().filter(|v| **v == 179).for_each(|v| *v = 255);
    assert!((fit(&no_plateau, &p, W).gain - f.gain).abs() < f.gain / 200, "the plateau is what 255 was");
    // Limited-range video: black at 16, white at 235, both clipped.
    let limited: Vec<u8> = seen(&p, 2.0, -150.0).iter().map(|&v| (16.0 + v as f32 * 219.0 / 255.0).round() as u8).collect();
    let f = fit(&limited, &p, W);
    assert_eq!(f.clip, [16, 235], "{f:?}");
    assert_eq!(f.verdict, Verdict::Face);
    // A level that fewer than a tenth of the samples share is not a plateau.
    let mut few = seen(&p, 1.0, 0.0);
    let top = *few.iter().max().unwrap() + 1;
    let (sx, sy) = steps(W, H);
    // The grid starts half a step in.
    let samples = (W - sx / 2).div_ceil(sx) * (H - sy / 2).div_ceil(sy);
    for k in 0..samples / PLATEAU_SHARE as usize - 1 {
        few[(sy / 2 + (k / 12) * sy) * W + sx / 2 + (k % 12) * sx] = top;
    }
    assert_eq!(fit(&few, &p, W).clip, [0, 255]);
    few[(sy / 2 + 3 * sy) * W + sx / 2 + 5 * sx] = top;
    few[(sy / 2 + 3 * sy) * W + sx / 2 + 6 * sx] = top;
    assert_eq!(fit(&few, &p, W).clip, [0, top], "a tenth and more is");
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

/// A mark large enough to move its half's mean residual past the bound (two fifths of the bottom
/// half, 55 grey levels darker, within the trimming's cut) is not a lamp: the halves' medians
/// stay together. The same darkening over the whole bottom half is one.
#[test]
fn a_large_mark_in_one_half_is_not_a_changed_scene() {
    let p = face();
    let mut f = seen(&p, 1.0, 0.0);
    for y in 30..H {
        for x in 0..31 {
            f[y * W + x] = f[y * W + x].saturating_sub(55).max(1);
        }
    }
    let m = fit(&f, &p, W);
    assert_eq!(m.verdict, Verdict::Face, "{m:?}");
    let mut lamp = seen(&p, 1.0, 0.0);
    for v in &mut lamp[W * H / 2..] {
        *v = v.saturating_sub(55).max(1);
    }
    let l = fit(&lamp, &p, W);
    assert_eq!(l.verdict, Verdict::SceneChanged, "{l:?}");
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

/// The word-at-a-time test agrees with the plain one on every position of a clipped byte and on
/// rows of every length, and finds nothing in rows strictly between the clip levels; for the
/// camera's 0 and 255 and for plateaus' levels (the board's routine takes both as constants).
#[test]
fn any_clipped_finds_every_clipped_byte() {
    for (lo, hi) in [(0u8, 255u8), (0, 178), (16, 235), (40, 255), (100, 102), (0, 1), (7, 7)] {
        let lut = Lut { lo, hi, ..Lut::IDENTITY };
        let inside: Vec<u8> = (lo as u16 + 1..hi as u16).map(|v| v as u8).collect();
        for len in 0..20usize {
            if inside.is_empty() {
                // No level between the clip levels: every byte is clipped.
                assert_eq!(super::any_clipped(&vec![lo; len], &lut), len > 0, "{lo} {hi} {len}");
                continue;
            }
            // Both ends of the open range and a middle, in every byte position of a word.
            let pick = [inside[0], *inside.last().unwrap(), inside[inside.len() / 2]];
            let quiet: Vec<u8> = (0..len).map(|i| pick[i % 3]).collect();
            assert!(!super::any_clipped(&quiet, &lut), "{lo} {hi} {quiet:?}");
            for at in 0..len {
                for v in [lo, hi, lo.saturating_sub(3), hi.saturating_add(3), 0, 255] {
                    let mut r = quiet.clone();
                    r[at] = v;
                    assert!(super::any_clipped(&r, &lut), "{lo} {hi} {r:?}");
                }
            }
        }
    }
}

/// The censored error: a clipped pixel differs from the prediction only past the fit's
/// bound, and a row's censored prediction gives the same errors through `v[f] - p`; at a
/// plateau's levels as at 0 and 255.
#[test]
fn clipped_pixels_are_censored() {
    let fit = LightFit { gain: 52429, offset: 0, ..LightFit::IDENTITY }; // gain 0.8
    let mut lut = Lut::IDENTITY;
    fit.lut(&mut lut);
    // v(255) = 204 grey: a prediction of 230 is consistent with a clipped pixel, 150 is not.
    assert_eq!(super::error(&lut, 255, 230 << 8), 0);
    assert_eq!(super::error(&lut, 255, 150 << 8), lut.v[255] as i32 - (150 << 8));
    assert_eq!(super::error(&lut, 0, 20 << 8), -(20 << 8));
    let frame = [255u8, 100, 0, 255];
    let pred = [230u16 << 8, 90 << 8, 20 << 8, 150 << 8];
    let mut out = [0u16; 4];
    assert!(super::censor_row(&frame, &pred, &lut, &mut out));
    for i in 0..4 {
        assert_eq!(lut.v[frame[i] as usize] as i32 - out[i] as i32, super::error(&lut, frame[i], pred[i]), "{i}");
    }
    assert!(!super::censor_row(&[1, 2, 3], &pred[..3], &lut, &mut out));
    // A camera that clipped at 178 and 12: v(178) = 142.4 grey.
    let plateau = LightFit { clip: [12, 178], ..fit };
    plateau.lut(&mut lut);
    assert_eq!((lut.lo, lut.hi), (12, 178));
    assert_eq!(super::error(&lut, 178, 200 << 8), 0);
    assert_eq!(super::error(&lut, 178, 100 << 8), lut.v[178] as i32 - (100 << 8));
    assert_eq!(super::error(&lut, 177, 200 << 8), lut.v[177] as i32 - (200 << 8));
    assert_eq!(super::error(&lut, 12, 5 << 8), 0);
    assert_eq!(super::error(&lut, 13, 5 << 8), lut.v[13] as i32 - (5 << 8));
    let frame = [178u8, 100, 12, 178, 13, 177];
    let pred = [200u16 << 8, 90 << 8, 5 << 8, 100 << 8, 5 << 8, 200 << 8];
    let mut out = [0u16; 6];
    assert!(super::censor_row(&frame, &pred, &lut, &mut out));
    for i in 0..6 {
        assert_eq!(lut.v[frame[i] as usize] as i32 - out[i] as i32, super::error(&lut, frame[i], pred[i]), "{i}");
    }
    assert!(!super::censor_row(&[13, 100, 177], &pred[..3], &lut, &mut out));
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

/// The fit's trimming takes the rejected samples out of the sums of all of them: the same
/// sums (and squared residuals) as adding up the kept ones, for cuts at, under and over each
/// residual, none and every sample rejected, and the saturated residuals.
#[test]
fn taking_the_rejected_out_is_adding_up_the_kept() {
    let mut rng = crate::testkit::Lcg(0x7F4A_7C15);
    let mut next = || rng.next_u32();
    for len in [0usize, 1, 2, 37, MAX_SAMPLES] {
        let xs: Vec<u8> = (0..len).map(|_| (next() % 254 + 1) as u8).collect();
        let ys: Vec<u16> = (0..len).map(|_| next() as u16).collect();
        let mut all = Sums::default();
        xs.iter().zip(&ys).for_each(|(&x, &y)| all.add::<true>(x as u32, y as u32));
        for (g, k) in [(65536, 0), (-(1 << 20), 1 << 28), (1 << 20, -(1 << 28)), (90_000, -3_000_000)] {
            let mut rs = [0u16; MAX_SAMPLES];
            let (sse_all, yy) = sse(&xs, &ys, g, k, &mut rs[..len]);
            assert_eq!(yy, all.yy);
            let mut cuts: Vec<u32> = vec![0, 1, 65534 * 65534, 65535 * 65535 - 1, 65535 * 65535, u32::MAX];
            for &r in rs.iter().take(len.min(40)) {
                let r = r as u32;
                cuts.extend([r * r, (r * r).saturating_sub(1), r * r + 1]);
            }
            for cut2 in cuts {
                let (want, want_sse) = kept(&xs, &ys, g, k, cut2);
                let (got, got_sse) = trim(all, sse_all, &xs, &ys, &rs[..len], cut2);
                assert_eq!((got.n, got.x, got.y, got.xx, got.xy), (want.n, want.x, want.y, want.xx, want.xy), "{len} {g} {k} {cut2}");
                assert_eq!(got_sse, want_sse, "{len} {g} {k} {cut2}");
                for half in [0, len / 3, len] {
                    let top = {
                        let mut t = Sums::default();
                        xs[..half].iter().zip(&ys[..half]).for_each(|(&x, &y)| t.add::<true>(x as u32, y as u32));
                        t
                    };
                    let got = [trim_again(top, &xs[..half], &ys[..half], g, k, cut2), trim_again(all.minus(&top), &xs[half..], &ys[half..], g, k, cut2)];
                    let want = [kept_sums(&xs[..half], &ys[..half], g, k, cut2), kept_sums(&xs[half..], &ys[half..], g, k, cut2)];
                    assert_eq!(got, want, "{len} {g} {k} {cut2} {half}");
                }
            }
        }
    }
}

/// The gather in two halves takes the samples of the one loop over the grid it replaced, and
/// splits them at the first grid row at or under `h / 2`, for every face size up to the
/// largest (clipped pixels, 0 and 255, left out).
#[test]
fn the_halves_gather_the_grid_and_split_it_where_the_one_loop_did() {
    for w in [1usize, 2, 5, 6, 7, 13, 58, MAX_FACE_W] {
        for h in 1..=MAX_FACE_H {
            let frame: Vec<u8> = (0..w * h).map(|k| (k * 37 % 256) as u8).collect();
            let pred: Vec<u16> = (0..w * h).map(|k| (k * 7919 % 65536) as u16).collect();
            let (mut xs, mut ys) = ([0u8; MAX_SAMPLES], [0u16; MAX_SAMPLES]);
            let (n, half, [top, bottom]) = gather(&frame, &pred, w, h, &mut xs, &mut ys);
            // The loop of before.
            let (step_x, step_y) = steps(w, h);
            let (mut want, mut want_half, mut want_top, mut want_all) = (Vec::new(), None, Sums::default(), Sums::default());
            let mut y = step_y / 2;
            while y < h {
                if want_half.is_none() && y >= h / 2 {
                    (want_half, want_top) = (Some(want.len()), want_all);
                }
                let mut x = step_x / 2;
                while x < w {
                    let i = frame[y * w + x];
                    if i != 0 && i != 255 && want.len() < MAX_SAMPLES {
                        want.push((i, pred[y * w + x]));
                        want_all.add::<false>(i as u32, pred[y * w + x] as u32);
                    }
                    x += step_x;
                }
                y += step_y;
            }
            let want_top = if want_half.is_some() { want_top } else { want_all };
            assert_eq!((n, half), (want.len(), want_half.unwrap_or(want.len())), "{w} x {h}");
            assert_eq!((top, top.plus(&bottom)), (want_top, want_all), "{w} x {h}");
            assert!(xs[..n].iter().zip(&ys[..n]).eq(want.iter().map(|(i, p)| (i, p))), "{w} x {h}");
        }
    }
}

/// The divisions the fit takes on 32-bit divides where it can: the same quotients as u64's
/// own, at the edges of each path (n or d at 2^32, a quotient just under 2^32) and at random.
#[test]
fn the_divisions_are_u64_division() {
    let mut cases = vec![(0u64, 1u64), (1, 1), (u32::MAX as u64, 1), (1 << 32, 1), (1 << 32, 2), (u64::MAX, 1), (u64::MAX, 1 << 32)];
    for d in [1u64, 2, 3, 0xFFFF, 0x1_0000, 0x1_0001, 0x8000_0000, 0xFFFF_FFFF, 0x1_0000_0000] {
        for n in [d * 0xFFFF_FFFF, d.wrapping_mul(0xFFFF_FFFF).wrapping_add(d - 1), (d << 32).wrapping_sub(1), d << 31, 0x1234_5678_9ABC] {
            cases.push((n, d));
        }
    }
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    for _ in 0..200_000 {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        let d = (rng >> (rng % 64)).max(1);
        let n = rng.rotate_left(17) >> (rng % 29);
        cases.push((n, d));
    }
    for (n, d) in cases {
        assert_eq!(div_u64(n, d), n / d, "{n} / {d}");
    }
    for a in [-5i64, -4, -3, 0, 3, 4, 5, i64::MAX / 2, -(i64::MAX / 2)] {
        for b in [1i64, 2, 7, 1 << 33] {
            let want = if a >= 0 { (a + b / 2) / b } else { -((-a + b / 2) / b) };
            assert_eq!(div_round(a, b), want, "{a} / {b}");
        }
    }
}

#[test]
fn isqrt_is_the_bisection() {
    for n in (0..=u32::MAX).step_by(9973).chain([0, 1, 2, 3, 4, 65535 * 65535 - 1, 65535 * 65535, u32::MAX]) {
        assert_eq!(isqrt(n), isqrt_bisection(n), "{n}");
    }
}
