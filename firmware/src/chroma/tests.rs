use super::*;
use crate::pipeline::{detect, detect_colour, Workspace};
use crate::testkit::{mlp_spec, Lcg};
use crate::Settings;
use msr_shared::blob::{set_chroma, ChromaSpec, Model};

const H: usize = 20;
const W: usize = 24;

/// A grey face of `H x W` and its planes: a reddish left half, a neutral right half.
fn face() -> (Vec<u8>, Vec<u8>) {
    let grey = (0..H * W).map(|i| 90 + (i % 7) as u8 * 5).collect();
    let (bh, bw) = (H / 2, W / 2);
    let mut planes = vec![128u8; 2 * bh * bw];
    for b in 0..bh * bw {
        if b % bw < bw / 2 {
            planes[b] = 118;
            planes[bh * bw + b] = 150;
        }
    }
    (grey, planes)
}

/// The model's chroma: each block's normalised chroma of [`face`], spread `s` sixteenths.
fn spec(s: u8) -> ChromaSpec {
    let (grey, planes) = face();
    let n = chroma::blocks(H, W);
    let mu = (0..n)
        .map(|b| {
            let (by, bx) = (b / (W / 2), b % (W / 2));
            let sum: u32 = (0..4).map(|k| grey[(2 * by + k / 2) * W + 2 * bx + k % 2] as u32).sum();
            [chroma::normalise(planes[b], sum, 4), chroma::normalise(planes[n + b], sum, 4)]
        })
        .collect();
    ChromaSpec { threshold: 6.0, spread_ref: 1.4, cells: vec![(mu, vec![s; n])] }
}

fn model_bytes(s: u8) -> Vec<u8> {
    let grey = mlp_spec(3, H as u16, W as u16).to_bytes().unwrap();
    set_chroma(&grey, Some(&spec(s))).unwrap()
}

fn run(bytes: &[u8], grey: &[u8], planes: &[u8]) -> (Frame, Vec<u8>, u32) {
    let m = Model::parse(bytes).unwrap();
    let c = m.chroma_at([0.0, 0.0]).unwrap();
    let mut e = vec![[0i16; 2]; chroma::blocks(H, W)];
    let f = errors(&c, grey, planes, H, W, &mut e).unwrap();
    let mut mask = vec![0u8; H * W];
    let (f, added) = mark(&c, f, &e, H, W, &mut mask, None);
    (f, mask, added)
}

/// Paints the 3 x 2 blocks at block row 2, columns 3..6 green with the grey unchanged.
fn green_patch(planes: &mut [u8]) {
    let (bh, bw) = (H / 2, W / 2);
    for by in 2..4 {
        for bx in 3..6 {
            planes[by * bw + bx] = 90;
            planes[bh * bw + by * bw + bx] = 80;
        }
    }
}

#[test]
fn the_face_as_the_model_knows_it_has_no_salient_block() {
    let bytes = model_bytes(16);
    let (grey, planes) = face();
    let (f, mask, added) = run(&bytes, &grey, &planes);
    assert_eq!((f.shift, f.median_q, f.widen, f.blocks, added), ([0, 0], 0, WIDEN_ONE, 0, 0));
    assert!(mask.iter().all(|&m| m == 0));
}

#[test]
fn a_patch_of_another_hue_and_the_same_grey_is_salient_where_it_is() {
    let bytes = model_bytes(16);
    let (grey, mut planes) = face();
    green_patch(&mut planes);
    let (f, mask, added) = run(&bytes, &grey, &planes);
    assert_eq!((f.blocks, added), (6, 24));
    for y in 0..H {
        for x in 0..W {
            let inside = (4..8).contains(&y) && (6..12).contains(&x);
            assert_eq!(mask[y * W + x] == 1, inside, "pixel ({x}, {y})");
        }
    }
    // The grey stage's pixels stay, and are counted once.
    let m = Model::parse(&bytes).unwrap();
    let c = m.chroma_at([0.0, 0.0]).unwrap();
    let mut e = vec![[0i16; 2]; chroma::blocks(H, W)];
    let f = errors(&c, &grey, &planes, H, W, &mut e).unwrap();
    let mut mask = vec![0u8; H * W];
    mask[4 * W + 6] = 1;
    mask[5 * W + 7] = crate::extent::SPREAD;
    let mut rows = [0u16; H];
    rows[4] = 1;
    rows[5] = 1;
    let (_, added) = mark(&c, f, &e, H, W, &mut mask, Some(&mut rows));
    assert_eq!(added, 22);
    assert_eq!(mask[5 * W + 7], 1);
    assert_eq!(&rows[3..9], &[0, 6, 6, 6, 6, 0]);
}

#[test]
fn a_white_balance_moves_every_block_and_is_taken_out() {
    let bytes = model_bytes(16);
    let (grey, mut planes) = face();
    let n = planes.len() / 2;
    for p in &mut planes[..n] {
        *p += 12;
    }
    for p in &mut planes[n..] {
        *p -= 9;
    }
    let (f, _, added) = run(&bytes, &grey, &planes);
    assert!(f.shift[0] > 0 && f.shift[1] < 0, "{f:?}");
    assert_eq!((f.blocks, added), (0, 0));
    // And the patch is still found under it.
    green_patch(&mut planes);
    assert_eq!(run(&bytes, &grey, &planes).0.blocks, 6);
}

#[test]
fn a_noisier_camera_widens_the_spreads_and_finds_the_patch_still() {
    let bytes = model_bytes(16);
    let (grey, mut planes) = face();
    let mut r = Lcg(7);
    for p in planes.iter_mut() {
        *p = (*p as f64 + r.unit() * 6.0).round() as u8;
    }
    let (f, _, _) = run(&bytes, &grey, &planes);
    assert!(f.widen > WIDEN_ONE, "{f:?}");
    assert!(f.blocks <= 2, "{f:?}");
    green_patch(&mut planes);
    let (f, _, _) = run(&bytes, &grey, &planes);
    assert!(f.blocks >= 5, "{f:?}");
}

#[test]
fn sizes_that_disagree_are_refused() {
    let bytes = model_bytes(16);
    let m = Model::parse(&bytes).unwrap();
    let c = m.chroma_at([0.0, 0.0]).unwrap();
    let (grey, planes) = face();
    let mut e = vec![[0i16; 2]; chroma::blocks(H, W)];
    assert!(errors(&c, &grey[1..], &planes, H, W, &mut e).is_none());
    assert!(errors(&c, &grey, &planes[1..], H, W, &mut e).is_none());
    assert!(errors(&c, &grey, &planes, H, W, &mut e[1..]).is_none());
    assert!(errors(&c, &grey, &planes, H, W - 2, &mut e).is_none());
}

#[test]
fn q_and_the_test_are_exact_at_the_threshold() {
    // An error of exactly one spread is q = 16.
    assert_eq!(q16([1, 0], 16), Q_ONE);
    assert_eq!(q16([3, 4], 16), 25 * Q_ONE);
    let bytes = model_bytes(16);
    let m = Model::parse(&bytes).unwrap();
    let c = m.chroma_at([0.0, 0.0]).unwrap();
    let f = Frame { widen: WIDEN_ONE, ..Frame::default() };
    // threshold 6: an error of 6 spreads is not over it, 6.1 is.
    assert!(!salient(&c, &f, [6, 0], 16));
    assert!(salient(&c, &f, [6, 1], 16));
    // Widened 4 times (2 x in spread), 12 is not over, 13 is.
    let f4 = Frame { widen: 4 * WIDEN_ONE, ..f };
    assert!(!salient(&c, &f4, [12, 0], 16));
    assert!(salient(&c, &f4, [13, 0], 16));
}

#[test]
fn the_pipeline_finds_what_only_colour_shows() {
    let bytes = model_bytes(16);
    let m = Model::parse(&bytes).unwrap();
    let s = Settings::of(&m);
    let mut ws = Box::new(Workspace::new());
    let head = [0.03, 0.01];
    // The decoder's own face, so the grey stage finds nothing.
    let grey: Vec<u8> =
        ws.decode(&m, head).unwrap().iter().map(|&p| ((p as u32 + 128) >> 8).min(255) as u8).collect();
    // The model's chroma as this face's.
    let n = chroma::blocks(H, W);
    let c = m.chroma_at([0.0, 0.0]).unwrap();
    let mut planes = vec![0u8; 2 * n];
    for b in 0..n {
        let (by, bx) = (b / (W / 2), b % (W / 2));
        let sum: u32 = (0..4).map(|k| grey[(2 * by + k / 2) * W + 2 * bx + k % 2] as u32).sum();
        let (mu, _) = c.at(b).unwrap();
        // The chroma byte whose ratio is the mean: search the 256.
        for (k, want) in mu.iter().enumerate() {
            planes[k * n + b] = (0..=255u8)
                .min_by_key(|&p| (chroma::normalise(p, sum, 4) as i32 - *want as i32).abs())
                .unwrap();
        }
    }
    let d = detect_colour(&mut ws, &m, &s, &grey, Some(&planes), [0, 0], head).unwrap();
    assert_eq!((d.blob, d.chroma.map(|f| f.blocks)), (None, Some(0)));
    green_patch(&mut planes);
    let d = detect_colour(&mut ws, &m, &s, &grey, Some(&planes), [0, 0], head).unwrap();
    let b = d.blob.expect("the green patch");
    assert_eq!((b.x0, b.y0, b.x1, b.y1, b.area), (6, 4, 11, 7, 24));
    // Grey alone cannot see it.
    assert_eq!(detect(&mut ws, &m, &s, &grey, [0, 0], head).unwrap().blob, None);
    // Planes of the wrong size are refused; a grey model ignores planes.
    assert_eq!(
        detect_colour(&mut ws, &m, &s, &grey, Some(&planes[1..]), [0, 0], head).err(),
        Some(crate::DetectError::ChromaSize)
    );
    let grey_bytes = mlp_spec(3, H as u16, W as u16).to_bytes().unwrap();
    let g = Model::parse(&grey_bytes).unwrap();
    let d = detect_colour(&mut ws, &g, &s, &grey, Some(&planes[1..]), [0, 0], head).unwrap();
    assert_eq!((d.blob, d.chroma), (None, None));
}

#[test]
fn golden_frames_run_the_colour_stage() {
    let bytes = model_bytes(16);
    let m = Model::parse(&bytes).unwrap();
    let grey_bytes = set_chroma(&bytes, None).unwrap();
    let g = Model::parse(&grey_bytes).unwrap();
    let mut crop = vec![0u8; crate::golden::scratch_len(&m)];
    assert_eq!(crop.len(), H * W + 2 * chroma::blocks(H, W));
    let mut ws = Box::new(Workspace::new());
    let a = crate::golden::run(&mut ws, &m, &mut crop).unwrap();
    let b = crate::golden::run(&mut Box::new(Workspace::new()), &m, &mut crop).unwrap();
    let grey = crate::golden::run(&mut ws, &g, &mut crop).unwrap();
    assert_eq!(a, b, "the same frames give the same digest");
    assert_ne!(a.digest, grey.digest, "the colour stage's results are in the digest");
    assert!(a.detections > grey.detections, "the hue patches are found: {a:?} against {grey:?}");
    assert!(crate::golden::run(&mut ws, &m, &mut crop[..H * W]).is_err(), "scratch without room for the planes");
}

#[test]
fn a_tone_curve_scales_the_chroma_and_the_slope_takes_it_out() {
    // Spreads of half a unit: a chroma 0.6 times the model's leaves the reddish half 5 units
    // off, ten spreads, where a shift alone would take out only the other half's error.
    let bytes = model_bytes(8);
    let (grey, mut planes) = face();
    for p in planes.iter_mut() {
        *p = (128.0 + (*p as f64 - 128.0) * 0.6).round() as u8;
    }
    let (f, _, added) = run(&bytes, &grey, &planes);
    assert_eq!((f.blocks, added), (0, 0), "{f:?}");
    assert!(f.gain[1] < -64, "the slope of v: {f:?}");
    green_patch(&mut planes);
    assert_eq!(run(&bytes, &grey, &planes).0.blocks, 6);
}
