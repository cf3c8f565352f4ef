//! The fingertip in the mirror: the end of what the elbow moves.
//!
//! Three frames of one head pose and one light: the arm at rest (`rest`), the arm with the
//! shoulder in its reaching posture and the elbow open (`open`), and the same with the elbow
//! bent until the hand met the face (`touch`). A pixel is *changed* where a channel differs from
//! `rest` by more than the threshold. The forearm at `touch` is what changed in `touch` and not
//! in `open` (the upper arm, which the elbow does not move, changed in both), the largest
//! connected region of them; its long axis is
//! the principal axis of those pixels, pointing away from the upper arm; the fingertip is the
//! mean of the forearm pixels within [`END_BAND`] pixels of its far end along that axis.
use image::RgbImage;

/// Forearm pixels this close (pixels, along the axis) to the far end make the fingertip.
pub const END_BAND: f64 = 1.5;
/// A forearm whose end (its pixels within [`END_BAND`], per pixel of length) is wider than this
/// share of its median width does not end in a hand: something in front cuts it off.
pub const CUT_OFF_WIDTH: f64 = 0.6;
/// Fewer forearm pixels than this is no forearm (a hand that the face or the frame hides).
pub const MIN_FOREARM_PIXELS: usize = 60;

/// Why no fingertip was found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TipError {
    /// The three frames differ in size.
    Size,
    /// Too little of the forearm shows.
    NoForearm(usize),
    /// No upper arm shows, so which end of the forearm is the hand is unknown.
    NoUpperArm,
    /// The forearm ends as wide as it is: cut off by the head's outline, its hand behind the head.
    CutOff,
}

impl std::fmt::Display for TipError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TipError::Size => write!(f, "the frames differ in size"),
            TipError::NoForearm(n) => write!(f, "only {n} forearm pixels show (at least {MIN_FOREARM_PIXELS} needed)"),
            TipError::NoUpperArm => write!(f, "no upper arm shows beside the forearm"),
            TipError::CutOff => write!(f, "the forearm ends cut off, as wide as it is: the hand is behind the head"),
        }
    }
}

impl std::error::Error for TipError {}

impl TipError {
    /// The kind of refusal, without its figures (for counting).
    pub fn kind(&self) -> &'static str {
        match self {
            TipError::Size => "frames of different sizes",
            TipError::NoForearm(_) => "too little forearm shows",
            TipError::NoUpperArm => "no upper arm shows",
            TipError::CutOff => "the hand is behind the head",
        }
    }
}

/// Largest channel difference between two pixels.
fn differs(a: &[u8], b: &[u8], threshold: u8) -> bool {
    a.iter().zip(b).any(|(x, y)| x.abs_diff(*y) > threshold)
}

/// The largest 8-connected region of `pixels` (whole-pixel positions in a `w` x `h` frame): the
/// forearm, not the specks of noise or shading elsewhere that also passed the threshold.
fn largest_region(pixels: &[[f64; 2]], w: usize, h: usize) -> Vec<[f64; 2]> {
    let mut on = vec![false; w * h];
    for p in pixels {
        on[p[1] as usize * w + p[0] as usize] = true;
    }
    let mut best: Vec<usize> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !on[start] {
            continue;
        }
        on[start] = false;
        stack.push(start);
        let mut region = Vec::new();
        while let Some(i) = stack.pop() {
            region.push(i);
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (nx, ny) = (x + dx, y + dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h && on[ny as usize * w + nx as usize] {
                    on[ny as usize * w + nx as usize] = false;
                    stack.push(ny as usize * w + nx as usize);
                }
            }
        }
        if region.len() > best.len() {
            best = region;
        }
    }
    best.sort_unstable();
    best.into_iter().map(|i| [(i % w) as f64, (i / w) as f64]).collect()
}

/// The fingertip at `touch` in full-frame pixels (x right, y down, pixel centres at integers).
pub fn fingertip(rest: &RgbImage, open: &RgbImage, touch: &RgbImage, threshold: u8) -> Result<[f64; 2], TipError> {
    if rest.dimensions() != open.dimensions() || rest.dimensions() != touch.dimensions() {
        return Err(TipError::Size);
    }
    let w = rest.width() as usize;
    let mut fore = Vec::new();
    let (mut upper, mut upper_n) = ([0.0f64; 2], 0usize);
    for (i, ((r, o), t)) in rest.as_raw().chunks_exact(3).zip(open.as_raw().chunks_exact(3)).zip(touch.as_raw().chunks_exact(3)).enumerate() {
        if !differs(r, t, threshold) {
            continue;
        }
        let p = [(i % w) as f64, (i / w) as f64];
        if differs(r, o, threshold) {
            upper[0] += p[0];
            upper[1] += p[1];
            upper_n += 1;
        } else {
            fore.push(p);
        }
    }
    let fore = largest_region(&fore, w, rest.height() as usize);
    if fore.len() < MIN_FOREARM_PIXELS {
        return Err(TipError::NoForearm(fore.len()));
    }
    if upper_n == 0 {
        return Err(TipError::NoUpperArm);
    }
    let n = fore.len() as f64;
    let c = [fore.iter().map(|p| p[0]).sum::<f64>() / n, fore.iter().map(|p| p[1]).sum::<f64>() / n];
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for p in &fore {
        let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    let th = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let mut u = [th.cos(), th.sin()];
    let up = [upper[0] / upper_n as f64, upper[1] / upper_n as f64];
    if (up[0] - c[0]) * u[0] + (up[1] - c[1]) * u[1] > 0.0 {
        u = [-u[0], -u[1]];
    }
    let along = |p: &[f64; 2]| (p[0] - c[0]) * u[0] + (p[1] - c[1]) * u[1];
    let end = fore.iter().map(along).fold(f64::NEG_INFINITY, f64::max);
    let (mut s, mut k) = ([0.0; 2], 0.0);
    for p in fore.iter().filter(|p| along(p) >= end - END_BAND) {
        s[0] += p[0];
        s[1] += p[1];
        k += 1.0;
    }
    // The forearm's width: pixels per one-pixel slice across its axis, the median slice.
    let start = fore.iter().map(along).fold(f64::INFINITY, f64::min);
    let n_slices = (end - start) as usize + 1;
    let mut slices = vec![0usize; n_slices];
    for p in &fore {
        slices[((along(p) - start) as usize).min(n_slices - 1)] += 1;
    }
    slices.sort_unstable();
    let width = slices[slices.len() / 2] as f64;
    if k / (END_BAND + 0.5) > CUT_OFF_WIDTH * width {
        return Err(TipError::CutOff);
    }
    Ok([s[0] / k, s[1] / k])
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    /// A frame of grey with filled discs painted on it.
    fn frame(discs: &[([f64; 2], f64)]) -> RgbImage {
        RgbImage::from_fn(120, 90, |x, y| {
            let on = discs.iter().any(|(c, r)| (x as f64 - c[0]).powi(2) + (y as f64 - c[1]).powi(2) <= r * r);
            if on {
                Rgb([230, 230, 225])
            } else {
                Rgb([90, 60, 50])
            }
        })
    }

    /// A stroke of discs from `a` to `b`, each `r` wide.
    fn stroke(a: [f64; 2], b: [f64; 2], r: f64) -> Vec<([f64; 2], f64)> {
        (0..=40).map(|i| {
            let t = i as f64 / 40.0;
            ([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], r)
        }).collect()
    }

    /// An upper arm up from the bottom edge, a forearm bent from its end towards the upper left:
    /// the tip is found within a pixel of the forearm's end (less the round end's radius).
    #[test]
    fn the_tip_is_the_forearms_far_end() {
        let rest = frame(&[]);
        let upper = stroke([80.0, 89.0], [70.0, 50.0], 5.0);
        let elbow = [70.0, 50.0];
        let open = frame(&[upper.clone(), stroke(elbow, [100.0, 20.0], 4.0)].concat());
        let end = [30.0, 35.0];
        let touch = frame(&[upper, stroke(elbow, end, 4.0)].concat());
        let tip = fingertip(&rest, &open, &touch, 10).unwrap();
        // The discs reach 4 px past the end along the stroke's direction.
        let d = [end[0] - elbow[0], end[1] - elbow[1]];
        let l = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let want = [end[0] + 4.0 * d[0] / l, end[1] + 4.0 * d[1] / l];
        let err = ((tip[0] - want[0]).powi(2) + (tip[1] - want[1]).powi(2)).sqrt();
        assert!(err < 1.5, "tip {tip:?}, the stroke ends at {want:?}");
    }

    /// A speck that changed elsewhere (a reflection, a shadow) is not the forearm's end.
    #[test]
    fn a_speck_elsewhere_is_not_the_forearm() {
        let rest = frame(&[]);
        let upper = stroke([80.0, 89.0], [70.0, 50.0], 5.0);
        let open = frame(&[upper.clone(), stroke([70.0, 50.0], [100.0, 20.0], 4.0)].concat());
        let arm = [upper, stroke([70.0, 50.0], [30.0, 35.0], 4.0)].concat();
        let clean = fingertip(&rest, &open, &frame(&arm), 10).unwrap();
        let specked = frame(&[arm, vec![([5.0, 5.0], 2.0), ([115.0, 85.0], 1.0)]].concat());
        assert_eq!(fingertip(&rest, &open, &specked, 10).unwrap(), clean);
    }

    #[test]
    fn a_hidden_forearm_or_a_lone_one_is_no_tip() {
        let rest = frame(&[]);
        let upper = stroke([80.0, 89.0], [70.0, 50.0], 5.0);
        let open = frame(&upper);
        assert_eq!(fingertip(&rest, &open, &open, 10), Err(TipError::NoForearm(0)));
        // A forearm with no upper arm beside it.
        let lone = frame(&stroke([70.0, 50.0], [30.0, 35.0], 4.0));
        assert_eq!(fingertip(&rest, &rest, &lone, 10), Err(TipError::NoUpperArm));
        assert_eq!(fingertip(&rest, &open, &RgbImage::new(10, 10), 10), Err(TipError::Size));
    }

    /// A textured scene, shifted by whole pixels: the patch is found where it went; a flat one
    /// is not matched at all.
    #[test]
    fn a_face_point_is_found_where_it_moved() {
        let tex = |x: i64, y: i64| -> u8 {
            let h = (x.wrapping_mul(73_856_093) ^ y.wrapping_mul(19_349_663)) as u64;
            let smooth = ((x as f64 * 0.45).sin() * (y as f64 * 0.3).cos() * 60.0) as i64;
            (120 + smooth + (h % 40) as i64) as u8
        };
        let from = RgbImage::from_fn(120, 90, |x, y| { let v = tex(x as i64, y as i64); Rgb([v, v, v]) });
        let to = RgbImage::from_fn(120, 90, |x, y| { let v = tex(x as i64 - 5, y as i64 + 3); Rgb([v, v, v]) });
        let q = corresponding(&from, &to, [50.3, 40.0], [3.0, -1.0]).unwrap();
        assert!((q[0] - 55.3).abs() < 0.2 && (q[1] - 37.0).abs() < 0.2, "{q:?}");
        let flat = RgbImage::from_pixel(120, 90, Rgb([128, 128, 128]));
        assert_eq!(corresponding(&flat, &flat, [50.0, 40.0], [0.0, 0.0]), None);
        // A patch that leaves the frame is no match.
        assert_eq!(corresponding(&from, &to, [2.0, 40.0], [0.0, 0.0]), None);
    }

    /// Noise below the threshold changes nothing: the same tip.
    #[test]
    fn noise_under_the_threshold_is_not_motion() {
        let rest = frame(&[]);
        let upper = stroke([80.0, 89.0], [70.0, 50.0], 5.0);
        let open = frame(&[upper.clone(), stroke([70.0, 50.0], [100.0, 20.0], 4.0)].concat());
        let touch = frame(&[upper, stroke([70.0, 50.0], [30.0, 35.0], 4.0)].concat());
        let clean = fingertip(&rest, &open, &touch, 10).unwrap();
        let jitter = |f: &RgbImage, s: u32| {
            let mut g = f.clone();
            for (i, p) in g.pixels_mut().enumerate() {
                let d = ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(s) >> 29) as u8; // 0..7
                p.0 = p.0.map(|v| v.saturating_add(d));
            }
            g
        };
        assert_eq!(fingertip(&jitter(&rest, 1), &jitter(&open, 2), &jitter(&touch, 3), 10).unwrap(), clean);
    }
}

/// Half the side of the patch [`corresponding`] matches, pixels.
pub const PATCH_HALF: i64 = 7;
/// How far from its first guess [`corresponding`] searches, pixels.
pub const SEARCH: i64 = 12;
/// The least normalised correlation a match needs.
pub const MIN_CORRELATION: f64 = 0.8;

/// Where the face point at `p` of frame `from` shows in frame `to` (two frames of the resting
/// robot at two head poses): the patch around it, found in `to` by normalised correlation within
/// [`SEARCH`] pixels of `p + guess`, to a tenth of a pixel by a parabola through the best
/// correlation and its neighbours. `None` if the patch leaves a frame, has no texture, or no
/// place correlates to [`MIN_CORRELATION`].
pub fn corresponding(from: &RgbImage, to: &RgbImage, p: [f64; 2], guess: [f64; 2]) -> Option<[f64; 2]> {
    let grey = |f: &RgbImage, x: i64, y: i64| -> Option<f64> {
        if x < 0 || y < 0 || x >= f.width() as i64 || y >= f.height() as i64 {
            return None;
        }
        let c = f.get_pixel(x as u32, y as u32).0;
        Some(crate::data::crop::grey_of_rgb(c[0], c[1], c[2]) as f64)
    };
    let (cx, cy) = (p[0].round() as i64, p[1].round() as i64);
    let mut patch = Vec::new();
    for dy in -PATCH_HALF..=PATCH_HALF {
        for dx in -PATCH_HALF..=PATCH_HALF {
            patch.push(grey(from, cx + dx, cy + dy)?);
        }
    }
    let n = patch.len() as f64;
    let mean = patch.iter().sum::<f64>() / n;
    let centred: Vec<f64> = patch.iter().map(|v| v - mean).collect();
    let norm = centred.iter().map(|v| v * v).sum::<f64>().sqrt();
    if norm < 1e-6 * n || norm / n.sqrt() < 2.0 {
        return None;
    }
    let ncc = |ox: i64, oy: i64| -> Option<f64> {
        let mut vals = Vec::with_capacity(patch.len());
        for dy in -PATCH_HALF..=PATCH_HALF {
            for dx in -PATCH_HALF..=PATCH_HALF {
                vals.push(grey(to, ox + dx, oy + dy)?);
            }
        }
        let m = vals.iter().sum::<f64>() / n;
        let (mut s, mut q) = (0.0, 0.0);
        for (v, c) in vals.iter().zip(&centred) {
            s += (v - m) * c;
            q += (v - m) * (v - m);
        }
        (q > 0.0).then(|| s / (q.sqrt() * norm))
    };
    let (gx, gy) = ((p[0] + guess[0]).round() as i64, (p[1] + guess[1]).round() as i64);
    let mut best: Option<(f64, i64, i64)> = None;
    for oy in gy - SEARCH..=gy + SEARCH {
        for ox in gx - SEARCH..=gx + SEARCH {
            if let Some(c) = ncc(ox, oy) {
                if best.is_none_or(|b| c > b.0) {
                    best = Some((c, ox, oy));
                }
            }
        }
    }
    let (c, bx, by) = best?;
    if c < MIN_CORRELATION {
        return None;
    }
    // A parabola through the best and its two neighbours along each axis.
    let vertex = |a: Option<f64>, b: f64, d: Option<f64>| match (a, d) {
        (Some(a), Some(d)) if a - 2.0 * b + d < 0.0 => (0.5 * (a - d) / (a - 2.0 * b + d)).clamp(-0.5, 0.5),
        _ => 0.0,
    };
    let sx = vertex(ncc(bx - 1, by), c, ncc(bx + 1, by));
    let sy = vertex(ncc(bx, by - 1), c, ncc(bx, by + 1));
    Some([bx as f64 + sx + (p[0] - cx as f64), by as f64 + sy + (p[1] - cy as f64)])
}
