use super::*;
use crate::testkit::Lcg;

#[test]
fn kth_is_the_sorted_order_statistic() {
    let mut rng = Lcg(7);
    for n in [1usize, 2, 3, 17, 208, 256] {
        for spread in [4u32, 300, 65536] {
            let v: heapless::Vec<u16, 256> = (0..n).map(|_| (rng.next_u32() % spread) as u16).collect();
            let mut sorted = v.clone();
            sorted.sort_unstable();
            for k in [0, n / 2, n - 1, n + 5] {
                assert_eq!(kth(&v, k), sorted[k.min(n - 1)], "n {n} spread {spread} k {k}");
            }
        }
    }
    assert_eq!(kth(&[], 3), 0);
}

#[test]
fn floor_is_the_variance_beyond_the_reference() {
    // 5^2 - 3^2 = 4^2, in Q8.8.
    assert_eq!(floor(5 * 256, 3 * 256), 4 * 256);
    assert_eq!(floor(3 * 256, 3 * 256), 0);
    assert_eq!(floor(2 * 256, 3 * 256), 0);
    assert_eq!(floor(7 * 256, 0), 7 * 256);
    assert_eq!(floor(u16::MAX, 0), u16::MAX & !63);
    // Rounded down to a quarter grey level: sqrt(1000^2 - 600^2) = 800 -> 768.
    assert_eq!(floor(1000, 600), 768);
    assert_eq!(floor(1000, 999), 0, "sqrt(1999) = 44, under a quarter level");
}

#[test]
fn widen_adds_variances_and_rounds() {
    assert_eq!(widen(3 * 256, 4 * 256), 5 * 256);
    assert_eq!(widen(777, 0), 777);
    assert_eq!(widen(0, 1000), 1000);
    assert_eq!(widen(u16::MAX, u16::MAX), u16::MAX);
    // sqrt(1 + 1) = 1.414..: rounds to 1.
    assert_eq!(widen(1, 1), 1);
    assert_eq!(widen(2, 2), 3);
}

/// A face of width `w` whose every error is `e` grey levels (frame one level, the prediction
/// `e` below), with `mark` pixels of error 60 in a block at the top left.
fn face(w: usize, h: usize, e: u8, mark: usize) -> (heapless::Vec<u8, 4096>, heapless::Vec<u16, 4096>) {
    let mut frame = heapless::Vec::new();
    let mut pred = heapless::Vec::new();
    for i in 0..w * h {
        let (x, y) = (i % w, i / w);
        let marked = x < mark && y < mark;
        frame.push(if marked { 160 } else { 100 + e }).unwrap();
        pred.push(100 << 8).unwrap();
    }
    (frame, pred)
}

#[test]
fn spread_of_a_uniform_error_is_1_4826_times_it() {
    for pool in 0..=MAX_POOL {
        let (frame, pred) = face(60, 40, 4, 0);
        // 4 x 1.4826 = 5.93 grey levels.
        let s = spread(&frame, &pred, &Lut::IDENTITY, 60, pool);
        assert!((s as i32 - (4.0 * 1.4826 * 256.0) as i32).abs() <= 2, "pool {pool}: {s}");
    }
}

#[test]
fn a_mark_on_fewer_than_half_the_samples_leaves_the_spread() {
    let (clean, pred) = face(60, 40, 3, 0);
    let (marked, _) = face(60, 40, 3, 25);
    let a = spread(&clean, &pred, &Lut::IDENTITY, 60, 2);
    let b = spread(&marked, &pred, &Lut::IDENTITY, 60, 2);
    assert_eq!(a, b, "the median does not see a mark on a quarter of the face");
}

#[test]
fn spread_of_noise_follows_its_standard_deviation() {
    // Gaussian-ish noise (a sum of four uniforms) of sd 6 grey levels, per pixel (pool 0).
    let mut rng = Lcg(3);
    let (w, h) = (90, 60);
    let mut frame: heapless::Vec<u8, 5400> = heapless::Vec::new();
    let mut pred: heapless::Vec<u16, 5400> = heapless::Vec::new();
    for _ in 0..w * h {
        let u: i32 = (0..4).map(|_| (rng.next_u32() % 21) as i32 - 10).sum();
        // sd of the sum: sqrt(4 * (21^2 - 1) / 12) = 12.1; halved: about 6.
        frame.push((128 + u / 2) as u8).unwrap();
        pred.push(128 << 8).unwrap();
    }
    let s = spread(&frame, &pred, &Lut::IDENTITY, w, 0) as f32 / 256.0;
    assert!((5.0..7.5).contains(&s), "{s}");
    // Pooled over a 5 x 5 window, independent noise averages down about five times.
    let s = spread(&frame, &pred, &Lut::IDENTITY, w, 2) as f32 / 256.0;
    assert!((0.8..1.8).contains(&s), "{s}");
}

#[test]
fn bad_shapes_give_no_spread() {
    let (frame, pred) = face(60, 40, 4, 0);
    assert_eq!(spread(&frame, &pred, &Lut::IDENTITY, 0, 2), 0);
    assert_eq!(spread(&frame, &pred, &Lut::IDENTITY, MAX_FACE_W + 1, 2), 0);
    assert_eq!(spread(&frame, &pred, &Lut::IDENTITY, 60, MAX_POOL + 1), 0);
    assert_eq!(spread(&frame[..30], &pred, &Lut::IDENTITY, 60, 2), 0);
    assert_eq!(spread(&[], &[], &Lut::IDENTITY, 60, 2), 0);
}

#[test]
fn reference_rounds_to_q88() {
    assert_eq!(reference_q88(0.0), 0);
    assert_eq!(reference_q88(4.5), 1152);
    assert_eq!(reference_q88(1.0 / 512.0), 1);
    assert_eq!(reference_q88(f32::NAN), 0);
    assert_eq!(reference_q88(1e9), u16::MAX);
}

/// Rule 1 by its definition: every window's mean of the censored error, then the median.
fn spread_reference(frame: &[u8], pred: &[u16], lut: &Lut, w: usize, pool: u8) -> u16 {
    let h = frame.len().min(pred.len()) / w;
    let (sx, sy) = light::steps(w, h);
    let r = pool as i64;
    let mut v = std::vec::Vec::new();
    for y in (sy / 2..h).step_by(ROW_STEP * sy) {
        for x in (sx / 2..w).step_by(sx) {
            let (mut sum, mut k) = (0i32, 0i32);
            for yy in (y as i64 - r).max(0)..=(y as i64 + r).min(h as i64 - 1) {
                for xx in (x as i64 - r).max(0)..=(x as i64 + r).min(w as i64 - 1) {
                    let i = yy as usize * w + xx as usize;
                    sum += light::error(lut, frame[i], pred[i]);
                    k += 1;
                }
            }
            v.push((sum / k).unsigned_abs() as u16);
        }
    }
    v.sort_unstable();
    let med = v[v.len() / 2] as u64;
    ((med * MAD_Q10 + 512) >> 10) as u16
}

#[test]
fn spread_is_its_definition_with_clipped_pixels_censored() {
    let mut rng = Lcg(21);
    let (w, h) = (75, 58);
    for case in 0..40u32 {
        let frame: std::vec::Vec<u8> = (0..w * h).map(|_| (rng.next_u32() % 256) as u8).collect();
        let pred: std::vec::Vec<u16> = frame.iter().map(|&f| ((f as u32 * 256 + rng.next_u32() % 4096) as u16).saturating_sub(2048)).collect();
        let mut lut = Lut::IDENTITY;
        // Clip levels of every kind: none, a plateau's, none left between them.
        let (lo, hi) = match case % 4 {
            0 => (0, 255),
            1 => (20 + (case % 30) as u8, 200 + (case % 50) as u8),
            2 => (100, 101),
            _ => (128, 128),
        };
        (lut.lo, lut.hi) = (lo, hi);
        for (i, v) in lut.v.iter_mut().enumerate() {
            *v = ((i as u32 * 250 + case * 97) as u16).min(255 << 8);
        }
        for pool in 0..=MAX_POOL {
            assert_eq!(spread(&frame, &pred, &lut, w, pool), spread_reference(&frame, &pred, &lut, w, pool), "case {case} pool {pool}");
        }
    }
}
