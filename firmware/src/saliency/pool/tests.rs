//! Tests of the pooled test: its row routine against the window written out, and the extent
//! ([`crate::extent`]) of what it marks.
use super::*;
use crate::extent::{mark_spread, SPREAD};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The row routine's steps against the window written out, on random faces of every
/// width from 1 to 24 (narrower than the window too), heights 1 to 9, radii 0 to 3, with
/// thresholds from 0 to the saturated 65535 and predictions over the whole u16 range.
#[test]
fn rows_match_the_plain_window() {
    let mut rng = ChaCha8Rng::seed_from_u64(19);
    for w in 1..=24usize {
        for h in 1..=9usize {
            for pool in 0..=MAX_POOL {
                let n = w * h;
                let frame: Vec<u8> = (0..n).map(|_| rng.gen()).collect();
                let pred: Vec<u16> = (0..n).map(|_| rng.gen()).collect();
                let thr: Vec<u16> = (0..n)
                    .map(|_| match rng.gen_range(0..8) {
                        0 => 0,
                        1 => u16::MAX,
                        _ => rng.gen_range(0..24_000),
                    })
                    .collect();
                // Half the faces through a random photometric fit, half unfitted.
                // Half of those clipped at a plateau's levels besides 0 and 255.
                let mut lut = crate::light::Lut::IDENTITY;
                if rng.gen_bool(0.5) {
                    let lo = if rng.gen_bool(0.5) { rng.gen_range(0..60) } else { 0 };
                    let fit = crate::light::LightFit {
                        gain: rng.gen_range(20_000..200_000),
                        offset: rng.gen_range(-3_000_000..3_000_000),
                        clip: [lo, if rng.gen_bool(0.5) { rng.gen_range(150..=255) } else { 255 }],
                        ..crate::light::LightFit::IDENTITY
                    };
                    fit.lut(&mut lut);
                }
                let mut want = vec![0u8; n];
                let count = reference(&frame, &pred, &lut, &thr, &mut want, w, pool);
                // Leftovers from another frame in the mask and the ring change nothing.
                let mut mask = vec![9u8; n];
                let mut ring = vec![-5i32; 7 * w];
                let mut rows = [0u16; 16];
                let got = pooled_one_sided(&frame, &pred, &lut, &thr, &mut mask, &mut ring, w, pool, &mut rows, false);
                assert_eq!(mask, want, "{w} x {h}, pool {pool}");
                assert_eq!(got, count);
                for y in 0..h {
                    let c = want[y * w..y * w + w].iter().filter(|&&m| m == 1).count();
                    assert_eq!(rows[y] as usize, c, "row {y} of {w} x {h}, pool {pool}");
                }
                // The extent done row by row from the ring is the extent done after.
                let mut spread = want.clone();
                crate::extent::mark_spread(&frame, &pred, &lut, &thr, &mut spread, w, &[]);
                let mut mask = vec![9u8; n];
                let mut ring = vec![-5i32; 7 * w];
                let got = pooled_one_sided(&frame, &pred, &lut, &thr, &mut mask, &mut ring, w, pool, &mut rows, true);
                assert_eq!(mask, spread, "{w} x {h}, pool {pool}, with the extent");
                assert_eq!(got, count);
            }
        }
    }
}

/// Salient exactly when the window mean exceeds `T` (not rounded); a saturated `T` never
/// fires, not even at the largest error a u16 prediction allows.
const ID: crate::light::Lut = crate::light::Lut::IDENTITY;

#[test]
fn the_test_is_the_window_mean() {
    // 3 x 3 face, radius 1, every frame pixel 10 grey, prediction 0: the mean is 2560 (Q8.8).
    let frame = [10u8; 9];
    let pred = [0u16; 9];
    for (t, salient) in [(2559u16, true), (2560, false)] {
        let mut mask = [0u8; 9];
        reference(&frame, &pred, &ID, &[t; 9], &mut mask, 3, 1);
        assert_eq!(mask, [salient as u8; 9], "T = {t}");
    }
    // One Q8.8 step over 9 pixels: a mean of 1/9 exceeds T = 0, not T = 1.
    let mut pred = [0u16; 9];
    pred[4] = 1;
    let mut mask = [7u8; 9];
    assert_eq!(reference(&[0; 9], &pred, &ID, &[0; 9], &mut mask, 3, 1), 9);
    assert_eq!(reference(&[0; 9], &pred, &ID, &[1; 9], &mut mask, 3, 1), 0);
    let frame = [0u8; 25];
    let mut mask = [0u8; 25];
    let mut ring = [0i32; 25];
    let mut rows = [0u16; 5];
    assert_eq!(pooled_one_sided(&frame, &[u16::MAX; 25], &ID, &[u16::MAX; 25], &mut mask, &mut ring, 5, 2, &mut rows, false), 0);
    assert_eq!(pooled_one_sided(&frame, &[65280; 25], &ID, &[65279; 25], &mut mask, &mut ring, 5, 2, &mut rows, false), 25);
}

/// The table is `mu + t sigma` rounded down (within one Q8.8 step of the exact value, give
/// or take sigma / 2^17 from rounding t) for every sigma at thresholds from tiny to huge, and saturates where the
/// exact value passes 65535; odd lengths and sigmas of 2^15 and more included (the board's
/// routine, which takes only a bounded sigma, is checked against [`Combine::at`] by the
/// benchmark image).
/// The board's short form of `T` is `at` itself for every sigma the bound lets through.
#[test]
fn packed_thresholds_are_at() {
    for t in [1e-3f32, 0.5, 1.0, 2.7, 4.59, 9.9, 255.9] {
        let c = Combine::new(t, Normalisation::StdDev);
        let bound = ((65535.0 / t) as u32).min(32767) as u16;
        assert!(c.packs(bound), "t {t}");
        for s in 0..=bound {
            for mu in [0u16, 1, 700, 65535 - s, 65535] {
                assert_eq!(c.at_packed(s, mu), c.at(s, mu), "t {t} sigma {s} mu {mu}");
            }
        }
    }
}

#[test]
fn combined_table_is_mu_plus_t_sigma() {
    let sigma: Vec<u16> = (0..=u16::MAX).collect();
    for t in [4.59f32, 1.0, 0.5, 2.7, 3.3, 6.0, 9.9, 1e-3, 1e-6, 1e-30, 255.9, 16383.9, 32767.0, 1e5, 1e30] {
        for mu in [0u16, 700, 65535] {
            for n in [sigma.len(), 32767, 4351] {
                let mus = vec![mu; n];
                let mut out = vec![0u16; n];
                let c = Combine::new(t, Normalisation::StdDev);
                combined_table(&sigma[..n], &mus, &c, u16::MAX, &mut out);
                for (&s, &o) in sigma.iter().zip(&out) {
                    let exact = mu as f64 + t as f64 * s as f64;
                    if exact >= 65536.0 {
                        assert_eq!(o, u16::MAX, "t {t} sigma {s} mu {mu}");
                    } else {
                        // tq's rounding moves t sigma by at most sigma / 2^17.
                        let slack = s as f64 / 131072.0 + 1e-6;
                        assert!(o as f64 <= exact + slack && o as f64 > exact - 1.0 - slack, "t {t} sigma {s} mu {mu}: {o} vs {exact}");
                    }
                    assert_eq!(o, c.at(s, mu));
                }
            }
        }
        // Variance keeps the float rule.
        let c = Combine::new(t, Normalisation::Variance);
        for s in [0u16, 1, 255, 256, 4096, 65535] {
            let want = (threshold_q88(s, t, Normalisation::Variance) as u32 + 7).min(0xFFFF) as u16;
            assert_eq!(c.at(s, 7), want, "variance t {t} sigma {s}");
        }
    }
}

/// A mark on a quiet face: pooled, its salient area is the mark grown by the radius; the
/// extent is the mark again, and the pooled decision (every non-zero pixel) is unchanged.
#[test]
fn the_extent_of_a_pooled_mark_is_the_mark() {
    let (w, h, r) = (30usize, 24usize, 2u8);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let pred: Vec<u16> = (0..w * h).map(|_| 100 << 8).collect();
    let mut frame: Vec<u8> = (0..w * h).map(|_| (100 + rng.gen_range(-2i32..=2)) as u8).collect();
    for y in 8..15 {
        frame[y * w + 10..y * w + 17].fill(160);
    }
    // T = 10 grey levels: noise never passes, the mark always does.
    let thr = vec![10u16 << 8; w * h];
    let mut mask = vec![0u8; w * h];
    let mut ring = vec![0i32; (2 * r as usize + 1) * w];
    let mut rows = [0u16; 24];
    let pooled = pooled_one_sided(&frame, &pred, &crate::light::Lut::IDENTITY, &thr, &mut mask, &mut ring, w, r, &mut rows, false);
    let before = mask.clone();
    assert!(pooled > 49, "the window spreads the 7 x 7 mark: {pooled}");
    let kept = mark_spread(&frame, &pred, &crate::light::Lut::IDENTITY, &thr, &mut mask, w, &rows);
    assert_eq!(kept, 49);
    for i in 0..w * h {
        let on = (8..15).contains(&(i / w)) && (10..17).contains(&(i % w));
        assert_eq!(mask[i] == 1, on, "pixel {i}");
        assert_eq!(mask[i] != 0, before[i] != 0, "pixel {i}: the decision's mask changed");
    }
}

/// On random faces and thresholds: a pixel is left at 1 exactly when it was salient and its
/// own error passes, whether the row counts are given or not.
#[test]
fn spread_is_salient_without_its_own_error() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for w in [1usize, 3, 7, 13, 75] {
        for h in [1usize, 5, 9] {
            let n = w * h;
            let frame: Vec<u8> = (0..n).map(|_| rng.gen()).collect();
            let pred: Vec<u16> = (0..n).map(|_| rng.gen()).collect();
            let thr: Vec<u16> = (0..n).map(|_| if rng.gen_range(0..6) == 0 { u16::MAX } else { rng.gen_range(0..30_000) }).collect();
            let mut mask = vec![0u8; n];
            reference(&frame, &pred, &crate::light::Lut::IDENTITY, &thr, &mut mask, w, 1);
            let counts: Vec<u16> = mask.chunks(w).map(|r| r.iter().filter(|&&m| m != 0).count() as u16).collect();
            for given in [&counts[..], &[][..]] {
                let mut m = mask.clone();
                let kept = mark_spread(&frame, &pred, &crate::light::Lut::IDENTITY, &thr, &mut m, w, given);
                let mut want = 0;
                for i in 0..n {
                    let own = (((frame[i] as i32) << 8) - pred[i] as i32).unsigned_abs() > thr[i] as u32;
                    let expect = match (mask[i], own) {
                        (0, _) => 0,
                        (_, true) => 1,
                        (_, false) => SPREAD,
                    };
                    assert_eq!(m[i], expect, "{w} x {h} pixel {i}");
                    want += (expect == 1) as u32;
                }
                assert_eq!(kept, want);
            }
        }
    }
}

/// The widened table's shortcut for the standard deviation is `Combine::at` of the widened
/// sigma, for every sigma, thresholds whose `tq` is under and over 32 bits, and both
/// normalisations.
#[test]
fn widened_table_is_combine_at_the_widened_sigma() {
    let sigma: Vec<u16> = (0..=u16::MAX).collect();
    for normalisation in [Normalisation::StdDev, Normalisation::Variance] {
        for t in [4.59f32, 0.5, 255.9, 65535.0, 1e5, 1e30] {
            for (mu, f) in [(0u16, 1u16), (700, 1024), (65535, 64), (3000, 65535)] {
                let c = Combine::new(t, normalisation);
                let mus = vec![mu; sigma.len()];
                let mut out = vec![0u16; sigma.len()];
                widened_table(&sigma, &mus, &c, f, &mut out);
                for (&s, &o) in sigma.iter().zip(&out) {
                    assert_eq!(o, c.at(crate::floor::widen(s, f), mu), "{normalisation:?} t {t} mu {mu} f {f} sigma {s}");
                }
            }
        }
    }
}
