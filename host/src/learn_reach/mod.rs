//! The reach the robot teaches itself in the mirror: no hand-taught pair, no model of its arm.
//!
//! The robot stands before the mirror with its head at rest and, as numbered rules:
//!
//! 1. **Rest.** It puts its arm at home and takes two frames; how much they differ is its camera's
//!    noise, and a pixel has *changed* where a channel differs from the first by more than
//!    [`threshold`] of that noise.
//! 2. **Its face.** The face check (the board's own pipeline on the rest frame) must find the
//!    face; without it the robot refuses to start. The face's crop box is where a touch counts.
//! 3. **Sweeps.** For each shoulder posture on a grid over the shoulder's limits (LShoulderPitch,
//!    LShoulderRoll), the arm goes there with the elbow open and takes a frame, then bends the
//!    elbow slowly towards its limit, feeling for the face, and stops at the first touch.
//! 4. **The fingertip.** At a touch it takes a frame; the fingertip is the end of what the elbow
//!    moved ([`tip`]). A fingertip inside the face's box makes a pair: that pixel, and the five
//!    joint angles the servos report. The elbow opens again.
//! 5. **Where the face was met, closer.** Around each shoulder posture that made a pair, the
//!    shoulder postures half a grid step away are swept too, down to [`LearnConfig::refine`]
//!    halvings: the face is a small part of what the arm can reach.
//! 6. **Stop safely.** Any error of the body (a servo that does not answer, a posture outside
//!    the limits) ends the teaching with the arm sent home; pairs so far are kept.
//!
//! The head is held at rest throughout, so the pairs hold HeadYaw and HeadPitch at 0: the network
//! learns to reach with the head looking at the mirror, where the robot sees its hand. Training
//! ([`consistent_pairs`]) drops pairs that the rest contradict: a touch made with the wrist before
//! the fingertip shows the fingertip where it did not touch.
pub mod sim;
pub mod tip;

use crate::data::crop::CropBox;
use crate::train::reach as train_reach;
use anyhow::{ensure, Result};
use image::RgbImage;
use msr_sim::kin::{self, Reach};
use serde::{Deserialize, Serialize};

/// The head at rest while teaching: looking straight at the mirror.
pub const REST_HEAD: [f64; 2] = [0.0, 0.0];
/// The largest head angle taught at, radians (where the face still shows for the face check).
pub const MAX_HEAD: f64 = 0.35;
/// A pair taught at another head pose within this many pixels of a pair of the rest pose is left
/// out: the rest pose reaches there, and one posture per place keeps the network's map single.
pub const COVERED_PX: f64 = 3.0;
/// A changed pixel differs by more than this many times the camera noise's standard deviation.
pub const NOISE_SIGMAS: f64 = 6.0;
/// The least threshold, grey levels (a noise-free camera still has its rounding).
pub const MIN_THRESHOLD: u8 = 10;
/// A pair is dropped when its scaled error exceeds the median by this many robust deviations.
pub const OUTLIER_SIGMAS: f64 = 4.0;

/// A robot's body as the teaching sees it: joints it can move and feel with, and a camera.
pub trait Body {
    /// Moves the five reach joints towards `to` at the servos' speed, stopping where it touches
    /// anything.
    fn move_to(&mut self, to: Reach) -> Result<Approach>;
    /// Moves towards `to` slowly, feeling for a touch, and stops at the first.
    fn approach(&mut self, to: Reach) -> Result<Approach>;
    /// A camera frame, the body held still.
    fn frame(&mut self) -> Result<RgbImage>;
    /// The joint angles the servos report now.
    fn posture(&self) -> Reach;
    /// Robot time spent so far, seconds.
    fn robot_seconds(&self) -> f64;
}

/// Where a move ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Approach {
    /// The posture reached (where it stopped, if it touched).
    pub posture: Reach,
    /// Whether it stopped at a touch.
    pub touched: bool,
}

/// How the robot teaches itself. `LearnConfig::default()`: the head at rest, a 16 x 16 shoulder
/// grid, two refinements.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LearnConfig {
    /// Head poses to teach at (HeadYaw, HeadPitch), the rest pose first. At a later pose only
    /// the face the rest pose did not reach is taught.
    pub heads: Vec<[f64; 2]>,
    /// Shoulder postures per axis of the first grid.
    pub grid: usize,
    /// Halvings of the grid step around the postures that made a pair.
    pub refine: usize,
    /// Stop once this many pairs are taught.
    pub max_pairs: usize,
}

impl Default for LearnConfig {
    fn default() -> Self {
        LearnConfig { heads: vec![REST_HEAD], grid: 16, refine: 2, max_pairs: 400 }
    }
}

/// One pair the robot taught itself.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pair {
    /// The fingertip in the mirror, full-frame pixels.
    pub pixel: [f64; 2],
    /// The five reach joints' angles the servos reported at the touch.
    pub joints: Reach,
}

/// What a teaching run gives.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Taught {
    /// The pairs, in the order they were taught.
    pub pairs: Vec<Pair>,
    /// Shoulder postures swept.
    pub sweeps: usize,
    /// Sweeps that ended in a touch.
    pub touches: usize,
    /// Touches whose fingertip was not found or was off the face.
    pub off_face: usize,
    /// Why those touches made no pair, and how many each.
    pub refused: std::collections::BTreeMap<String, usize>,
    /// The change threshold used, grey levels.
    pub threshold: u8,
    /// The face's crop box in the rest frame.
    pub face: [u32; 4],
    /// Robot time, seconds.
    pub robot_seconds: f64,
    /// Why the teaching stopped early, if it did.
    pub stopped: Option<String>,
}

impl Taught {
    /// Share of the face box's cells (a 4 x 3 grid over it) that hold a pair.
    pub fn coverage(&self) -> f64 {
        coverage(&self.pairs, self.face)
    }
}

/// Share of a 4 x 3 grid over `face` ([x, y, width, height]) whose cells hold a pair.
pub fn coverage(pairs: &[Pair], face: [u32; 4]) -> f64 {
    let (cols, rows) = (4usize, 3usize);
    let mut hit = [[false; 4]; 3];
    for p in pairs {
        let u = (p.pixel[0] - face[0] as f64) / face[2].max(1) as f64;
        let v = (p.pixel[1] - face[1] as f64) / face[3].max(1) as f64;
        if (0.0..1.0).contains(&u) && (0.0..1.0).contains(&v) {
            hit[(v * rows as f64) as usize][(u * cols as f64) as usize] = true;
        }
    }
    hit.iter().flatten().filter(|h| **h).count() as f64 / (cols * rows) as f64
}

/// The change threshold for two frames of the same still scene: [`NOISE_SIGMAS`] times the
/// noise's standard deviation (from the median absolute difference), at least
/// [`MIN_THRESHOLD`].
pub fn threshold(a: &RgbImage, b: &RgbImage) -> u8 {
    let mut hist = [0u64; 256];
    for (x, y) in a.as_raw().iter().zip(b.as_raw()) {
        hist[x.abs_diff(*y) as usize] += 1;
    }
    let total: u64 = hist.iter().sum();
    let (mut seen, mut median) = (0u64, 0usize);
    for (d, n) in hist.iter().enumerate() {
        seen += n;
        if 2 * seen >= total {
            median = d;
            break;
        }
    }
    // a - b of two draws of N(0, s^2) is N(0, 2 s^2), whose absolute value has the median
    // 0.6745 sqrt(2) s.
    let sd = 1.4826 * median as f64 / std::f64::consts::SQRT_2;
    (NOISE_SIGMAS * sd).ceil().clamp(MIN_THRESHOLD as f64, 255.0) as u8
}

/// What the teaching reports as it goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    /// Sweeps done.
    pub sweeps: usize,
    /// Sweeps planned so far (the refinements add to it).
    pub planned: usize,
    /// Pairs so far.
    pub pairs: usize,
    /// Share of the face covered so far.
    pub coverage: f64,
}

/// Teaches the robot `body` its reach by the rules of this module. `face` finds the face's crop
/// box in a frame of the robot with its arm at home and its head at the pose given (`None`: no
/// face there).
pub fn learn(
    body: &mut dyn Body,
    face: &dyn Fn(&RgbImage, [f64; 2]) -> Result<Option<CropBox>>,
    cfg: &LearnConfig,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Taught> {
    ensure!(cfg.grid >= 2, "the shoulder grid needs at least 2 postures an axis, got {}", cfg.grid);
    ensure!(cfg.refine <= 6, "at most 6 refinements, got {}", cfg.refine);
    ensure!(cfg.heads.first() == Some(&REST_HEAD), "the first head pose must be the rest pose {REST_HEAD:?}");
    for h in &cfg.heads {
        ensure!(h.iter().all(|a| a.is_finite() && a.abs() <= MAX_HEAD), "head pose {h:?} is past {MAX_HEAD} rad");
    }
    let home = kin::home();
    let at_rest = |h: [f64; 2]| -> Reach { [h[0], h[1], home[2], home[3], home[4]] };
    // Rule 1.
    body.move_to(at_rest(REST_HEAD))?;
    let rest_frame = body.frame()?;
    let threshold = threshold(&rest_frame, &body.frame()?);
    // Rule 2.
    let Some(fb) = face(&rest_frame, REST_HEAD)? else {
        anyhow::bail!("no face in view: the robot must stand before the mirror with its face in the frame");
    };
    let mut t = Taught {
        pairs: Vec::new(),
        sweeps: 0,
        touches: 0,
        off_face: 0,
        refused: Default::default(),
        threshold,
        face: [fb.x, fb.y, fb.width, fb.height],
        robot_seconds: 0.0,
        stopped: None,
    };
    let mut r = Ok(());
    for (k, &h) in cfg.heads.iter().enumerate() {
        r = (|| -> Result<()> {
            let turned;
            let (frame, b) = if k == 0 {
                (&rest_frame, fb)
            } else {
                body.move_to(at_rest(h))?;
                turned = body.frame()?;
                match face(&turned, h)? {
                    Some(b) => (&turned, b),
                    // The face left the view at this pose: nothing to learn here.
                    None => return Ok(()),
                }
            };
            let view = View { head: h, rest: frame, face: [b.x, b.y, b.width, b.height], first: k == 0, rest_view: &rest_frame };
            sweep_all(body, &view, cfg, &mut t, progress)
        })();
        if r.is_err() {
            break;
        }
    }
    // Rule 6: home whatever happened.
    let home_again = body.move_to(at_rest(REST_HEAD));
    t.robot_seconds = body.robot_seconds();
    if let Err(e) = r.and(home_again.map(|_| ())) {
        t.stopped = Some(format!("{e:#}"));
    }
    Ok(t)
}

/// The robot's view at one head pose.
struct View<'a> {
    head: [f64; 2],
    /// The frame with the arm at home.
    rest: &'a RgbImage,
    /// The face's crop box here.
    face: [u32; 4],
    /// Whether this is the rest pose, whose frame the pairs' pixels are in.
    first: bool,
    /// The rest pose's frame with the arm at home.
    rest_view: &'a RgbImage,
}

/// Rules 3 to 5 at one head pose.
fn sweep_all(body: &mut dyn Body, view: &View<'_>, cfg: &LearnConfig, t: &mut Taught, progress: &mut dyn FnMut(&Progress)) -> Result<()> {
    let lim = kin::reach_limits();
    let (sp, sr, er) = (lim[2], lim[3], lim[4]);
    let step = [(sp[1] - sp[0]) / (cfg.grid - 1) as f64, (sr[1] - sr[0]) / (cfg.grid - 1) as f64];
    // Grid coordinates in units of the finest step, so that refinements meet exactly.
    let fine = 1i64 << cfg.refine;
    let mut seen = std::collections::HashSet::new();
    let mut queue = std::collections::VecDeque::new();
    for i in 0..cfg.grid as i64 {
        // Serpentine: neighbouring sweeps start near each other.
        for jj in 0..cfg.grid as i64 {
            let j = if i % 2 == 0 { jj } else { cfg.grid as i64 - 1 - jj };
            let key = (i * fine, j * fine);
            seen.insert(key);
            queue.push_back((key, 0usize));
        }
    }
    let at = |k: (i64, i64)| [sp[0] + k.0 as f64 * step[0] / fine as f64, sr[0] + k.1 as f64 * step[1] / fine as f64];
    while let Some((key, level)) = queue.pop_front() {
        if t.pairs.len() >= cfg.max_pairs {
            break;
        }
        let s = at(key);
        if s[0] < sp[0] || s[0] > sp[1] || s[1] < sr[0] || s[1] > sr[1] {
            continue;
        }
        t.sweeps += 1;
        let made = sweep(body, view, [s[0], s[1], er[1], er[0]], t)?;
        if made && level < cfg.refine {
            let d = fine >> (level + 1);
            for (di, dj) in [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)] {
                let k = (key.0 + di * d, key.1 + dj * d);
                if seen.insert(k) {
                    queue.push_back((k, level + 1));
                }
            }
        }
        progress(&Progress { sweeps: t.sweeps, planned: t.sweeps + queue.len(), pairs: t.pairs.len(), coverage: t.coverage() });
    }
    Ok(())
}

/// One sweep at shoulder posture (`q[0]`, `q[1]`), the elbow from `q[2]` towards `q[3]`; whether
/// it made a pair.
fn sweep(body: &mut dyn Body, view: &View<'_>, q: [f64; 4], t: &mut Taught) -> Result<bool> {
    let h = view.head;
    let open: Reach = [h[0], h[1], q[0], q[1], q[2]];
    if body.move_to(open)?.touched {
        // The arm meets the head with the elbow open: nothing to bend towards.
        return Ok(false);
    }
    let open_frame = body.frame()?;
    let a = body.approach([h[0], h[1], q[0], q[1], q[3]])?;
    let mut made = false;
    if a.touched {
        t.touches += 1;
        let touch_frame = body.frame()?;
        let f = view.face;
        let refused = match tip::fingertip(view.rest, &open_frame, &touch_frame, t.threshold) {
            Ok(p) if p[0] >= f[0] as f64 && p[0] < (f[0] + f[2]) as f64 && p[1] >= f[1] as f64 && p[1] < (f[1] + f[3]) as f64 => {
                // Where on the face, in the rest pose's frame: the face around the fingertip found
                // there (first guess: the face box's shift).
                let shift = [t.face[0] as f64 - f[0] as f64, t.face[1] as f64 - f[1] as f64];
                let pixel = if view.first { Some(p) } else { tip::corresponding(view.rest, view.rest_view, p, shift) };
                let covered = |px: [f64; 2]| {
                    t.pairs.iter().any(|o| [o.joints[0], o.joints[1]] == REST_HEAD && (o.pixel[0] - px[0]).hypot(o.pixel[1] - px[1]) < COVERED_PX)
                };
                match pixel {
                    None => Some("the face there is not found at rest"),
                    Some(px) if !view.first && covered(px) => Some("the rest pose reaches there"),
                    Some(px) => {
                        t.pairs.push(Pair { pixel: px, joints: body.posture() });
                        made = true;
                        None
                    }
                }
            }
            Ok(_) => Some("the fingertip is off the face"),
            Err(e) => Some(e.kind()),
        };
        if let Some(why) = refused {
            t.off_face += 1;
            *t.refused.entry(why.to_string()).or_default() += 1;
        }
    }
    body.move_to(open)?;
    Ok(made)
}

/// The pairs the rest do not contradict, by index: the reach network trained on all of them as
/// `msr train-reach` trains it, each pair's error (joint angles, scaled to the pairs' ranges, the
/// largest over the joints) within [`OUTLIER_SIGMAS`] robust deviations of the median. The network
/// is then trained on these (`msr learn-reach` does it with `train_reach::run`, which writes it).
pub fn consistent_pairs(pairs: &[Pair], opts: &train_reach::Opts) -> Result<Vec<usize>> {
    ensure!(pairs.len() >= 10, "{} pairs taught; the reach network needs at least 10", pairs.len());
    let xs: Vec<[f64; 2]> = pairs.iter().map(|p| p.pixel).collect();
    let ys: Vec<[f64; 5]> = pairs.iter().map(|p| p.joints).collect();
    let (first, _, _) = train_reach::train_chosen(&xs, &ys, opts)?;
    let s = &first.scaling;
    let err: Vec<f64> = xs
        .iter()
        .zip(&ys)
        .map(|(x, y)| {
            let p = first.predict(*x);
            (0..5).map(|k| ((p[k] - y[k]) / (s.output_max[k] - s.output_min[k])).abs()).fold(0.0, f64::max)
        })
        .collect();
    let med = median(&err);
    let mad = 1.4826 * median(&err.iter().map(|e| (e - med).abs()).collect::<Vec<_>>());
    Ok((0..pairs.len()).filter(|&i| err[i] <= med + OUTLIER_SIGMAS * mad.max(1e-9)).collect())
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    if s.is_empty() {
        0.0
    } else {
        s[s.len() / 2]
    }
}

/// Writes `pairs` as `msr train-reach` reads them: `reach_centroids.csv` (x,y) and
/// `reach_joints.csv` (five angles) in `dir`.
pub fn write_pairs(dir: &std::path::Path, pairs: &[Pair]) -> Result<()> {
    let mut c = String::new();
    let mut j = String::new();
    for p in pairs {
        c.push_str(&format!("{:.3},{:.3}\n", p.pixel[0], p.pixel[1]));
        let q = p.joints;
        j.push_str(&format!("{:.10},{:.10},{:.10},{:.10},{:.10}\n", q[0], q[1], q[2], q[3], q[4]));
    }
    crate::fsio::write(&dir.join(msr_sim::layout::REACH_CENTROIDS_FILE), c)?;
    crate::fsio::write(&dir.join(msr_sim::layout::REACH_JOINTS_FILE), j)?;
    Ok(())
}

#[cfg(test)]
mod tests;
