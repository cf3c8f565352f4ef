//! The calibrated novelty policy (`msr demo` applies it; `msr train` alone keeps the paper's
//! settings): per robot, the threshold and the fragment merge are chosen from a fixed list of
//! candidates on frames rendered at the observe posture, where the robot looks for marks
//! ([`observe_frames`]: normal frames, and frames with random marks drawn as in the episodes,
//! from a seed of their own).
//!
//! 1. A candidate `(t, merge)` is admissible when no normal frame gives a detection at
//!    `t / SAFETY` (a margin of [`SAFETY`] over the worst normal frame), nor at `t` itself:
//!    with a merge, detection is not monotone in the threshold (a frame with more fragments
//!    than the board's merge table holds is not merged), so quiet at `t / SAFETY` alone does
//!    not promise quiet at `t`.
//! 2. Of the admissible candidates, the one that finds most marked test frames (winner centroid
//!    inside the mark's box) wins; ties go to the larger threshold, then to the earlier merge in
//!    [`MERGES`] (no merge first), i.e. to the setting closest to the paper's.
//! 3. Without an admissible candidate, or without normal or marked frames, the paper's settings
//!    stay.
//!
//! Why: the paper's 4.59 was set for the red Nao's error statistics; a robot whose decoder
//! predicts its face worse (the skin robot's taxel grid) needs a lower one, and marks that the
//! saliency breaks up along a texture need the merge. Both are checked against normal frames
//! with a margin, so a lower threshold is only taken where the normal frames allow it.
//! The settings hold for the observe posture: at other head poses the decoder errs more (the
//! red robot's unmarked test frames at +-5 deg score up to about 3.9, against about 1.8 at
//! the observe posture), so there a lowered threshold gives false alarms (the evaluation table
//! shows them).
use crate::calibrate::{self, ErrorStats, NoveltyParams};
use crate::data::Sample;
use crate::predictor::FacePredictor;
use anyhow::{Context, Result};
use msr_sim::body::BodyPose;
use msr_sim::render::{Renderer, Variation};
use msr_sim::Robot;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;
use msr_shared::blob::Merge;
use serde::{Deserialize, Serialize};

/// Thresholds tried, largest (the paper's) first.
pub const THRESHOLDS: [f64; 7] = [calibrate::DEFAULT_THRESHOLD, 4.0, 3.5, 3.0, 2.5, 2.25, 2.0];
/// Merges tried, no merge (the paper's) first, then by how far they reach.
pub const MERGES: [Merge; 7] = [
    Merge::OFF,
    Merge { margin: 2, fragment: 3 },
    Merge { margin: 3, fragment: 3 },
    Merge { margin: 4, fragment: 3 },
    Merge { margin: 5, fragment: 3 },
    Merge { margin: 4, fragment: 2 },
    Merge { margin: 5, fragment: 2 },
];
/// Normal frames must stay undetected at the threshold divided by this.
pub const SAFETY: f64 = 1.25;

/// One candidate's result on the held-out frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scored {
    pub threshold: f64,
    pub merge: Merge,
    /// Marked frames found (centroid inside the mark's box).
    pub hits: usize,
    /// Normal frames detected at `threshold / SAFETY` or at `threshold`.
    pub normal_detections: usize,
}

/// What the policy chose and from what.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Choice {
    pub threshold: f64,
    pub merge: Merge,
    pub marked_frames: usize,
    pub normal_frames: usize,
    pub safety: f64,
    pub candidates: Vec<Scored>,
}

/// A held-out frame's saliency and, for a marked frame, the mark's box in face pixels.
pub struct Frame {
    pub saliency: Vec<f64>,
    pub mark_box: Option<[f64; 4]>,
}

/// The frame in the policy's terms: saliency from the error map and the statistics.
pub fn frame(s: &Sample, predicted: &[f32], stats: &ErrorStats, p: &NoveltyParams) -> Frame {
    let sal = calibrate::saliency(&calibrate::error_map(&s.face_unit(), predicted), stats, p);
    let c = s.crop();
    let mark_box = s.mark.as_ref().map(|m| {
        let [x0, y0, x1, y1] = m.box_xyxy.map(|v| v as f64);
        [x0 - c.x as f64, y0 - c.y as f64, x1 - c.x as f64, y1 - c.y as f64]
    });
    Frame { saliency: sal, mark_box }
}

/// Applies the policy to `base` (whose normalisation, sides, floor and min area stay).
pub fn choose(frames: &[Frame], h: usize, w: usize, base: &NoveltyParams) -> Result<(NoveltyParams, Option<Choice>)> {
    base.check()?;
    let marked = frames.iter().filter(|f| f.mark_box.is_some()).count();
    let normal = frames.len() - marked;
    if marked == 0 || normal == 0 {
        return Ok((*base, None));
    }
    let detect = |f: &Frame, t: f64, merge: Merge| {
        let p = NoveltyParams { threshold: t, merge, ..*base };
        calibrate::detect(&f.saliency, h, w, &p)
    };
    let mut candidates = Vec::new();
    for &merge in &MERGES {
        for &t in &THRESHOLDS {
            let normal_detections = frames
                .iter()
                .filter(|f| {
                    f.mark_box.is_none()
                        && (detect(f, t / SAFETY, merge).is_some() || detect(f, t, merge).is_some())
                })
                .count();
            let hits = frames
                .iter()
                .filter(|f| {
                    f.mark_box.is_some_and(|[x0, y0, x1, y1]| {
                        detect(f, t, merge).is_some_and(|b| {
                            let [cx, cy] = b.centroid;
                            cx >= x0 && cx <= x1 && cy >= y0 && cy <= y1
                        })
                    })
                })
                .count();
            candidates.push(Scored { threshold: t, merge, hits, normal_detections });
        }
    }
    let best = best_of(&candidates);
    let mut p = *base;
    if let Some(b) = best {
        p.threshold = b.threshold;
        p.merge = b.merge;
        p.check()?;
    }
    Ok((p, best.map(|b| Choice {
        threshold: b.threshold,
        merge: b.merge,
        marked_frames: marked,
        normal_frames: normal,
        safety: SAFETY,
        candidates: candidates.clone(),
    })))
}

/// Normal and marked frames the policy calibrates on.
pub const OBSERVE_NORMAL_FRAMES: usize = 64;
pub const OBSERVE_MARKED_FRAMES: usize = 160;

/// Frames at the observe posture (head (0, 0), arms at home), where the robot looks for marks:
/// `normal` without a mark and `marked` with a random mark each (drawn as the datasets and the
/// mirror-test episodes draw them), with the camera's usual variation (exposure, eye LEDs,
/// noise), cropped by `cropper` (the model's template and crop mode). Deterministic for `seed`.
pub fn observe_frames(
    robot: Robot,
    cropper: &crate::crop::Cropper,
    model: &dyn FacePredictor,
    stats: &ErrorStats,
    p: &NoveltyParams,
    (normal, marked): (usize, usize),
    seed: u64,
) -> Result<Vec<Frame>> {
    let renderer = Renderer::new(robot);
    let pose = BodyPose::head(0.0, 0.0);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0B5E_C0A1_1B2A_7E00);
    let mut faces = Vec::with_capacity(normal + marked);
    for i in 0..normal + marked {
        let mark = (i >= normal).then(|| msr_sim::dataset::render_marked(&renderer, &pose, &Variation::CLEAN, &mut rng).0);
        let r = renderer.render(&pose, mark.as_ref(), &Variation::random(&mut rng));
        let grey = crate::crop::to_grey(&image::DynamicImage::ImageRgb8(r.rgb));
        let face = cropper.crop(&grey)?;
        let mark_box = r.mark.filter(|m| m.pixels > 0).map(|m| {
            let [x0, y0, x1, y1] = m.box_xyxy.map(|v| v as f64);
            let (cx, cy) = (face.crop.x as f64, face.crop.y as f64);
            [x0 - cx, y0 - cy, x1 - cx, y1 - cy]
        });
        faces.push((face, mark_box));
    }
    let units: Vec<Vec<f32>> = faces.iter().map(|(f, _)| f.unit()).collect();
    let preds = model.predict_batch(&vec![[0.0, 0.0]; units.len()], &units);
    Ok(units
        .iter()
        .zip(&preds)
        .zip(faces)
        .map(|((u, pr), (_, mark_box))| Frame {
            saliency: calibrate::saliency(&calibrate::error_map(u, pr), stats, p),
            mark_box,
        })
        .collect())
}

/// Applies the policy to the trained model `name` in `dir` (`msr train` output) with frames of
/// `robot` at the observe posture ([`observe_frames`]), and rewrites its `{name}.json` with the
/// chosen settings.
pub fn apply(dir: &Path, name: &str, robot: Robot, seed: u64) -> Result<Option<Choice>> {
    let model = super::load(dir, name)?;
    let mut info = model.info()?.clone();
    let stats = super::load_stats(dir, &info)?;
    let tpl_path = dir.join(&info.files.template);
    let template = image::open(&tpl_path)
        .with_context(|| format!("reading {}", tpl_path.display()))?
        .to_luma8();
    let cropper = crate::crop::Cropper::new(template, info.crop);
    let frames = observe_frames(
        robot,
        &cropper,
        &model,
        &stats,
        &info.novelty,
        (OBSERVE_NORMAL_FRAMES, OBSERVE_MARKED_FRAMES),
        seed,
    )?;
    let (p, choice) = choose(&frames, info.face_h, info.face_w, &info.novelty)?;
    if let Some(c) = &choice {
        info.novelty = p;
        info.threshold_policy = super::ThresholdPolicy {
            kind: "calibrated".into(),
            percentile: None,
            frames: Some(format!(
                "observe posture: {} marked frames (hits), {} without a mark (none may fire at threshold / {SAFETY})",
                c.marked_frames, c.normal_frames
            )),
            n_frames: c.marked_frames + c.normal_frames,
        };
        info.novelty_policy = Some(c.clone());
        let json = dir.join(format!("{name}.json"));
        std::fs::write(&json, serde_json::to_string_pretty(&info)?)
            .with_context(|| format!("writing {}", json.display()))?;
    }
    Ok(choice)
}

/// Most hits among the admissible; ties to the larger threshold, then the earlier merge.
fn best_of(c: &[Scored]) -> Option<&Scored> {
    let rank = |s: &Scored| MERGES.iter().position(|m| *m == s.merge).unwrap_or(usize::MAX);
    c.iter().filter(|s| s.normal_detections == 0).min_by(|a, b| {
        b.hits
            .cmp(&a.hits)
            .then(b.threshold.total_cmp(&a.threshold))
            .then(rank(a).cmp(&rank(b)))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scored(threshold: f64, merge: Merge, hits: usize, normal: usize) -> Scored {
        Scored { threshold, merge, hits, normal_detections: normal }
    }

    #[test]
    fn best_is_most_hits_then_closest_to_the_paper() {
        let m2 = MERGES[1];
        let m4 = MERGES[3];
        let c = [
            scored(4.59, Merge::OFF, 10, 0),
            scored(3.0, Merge::OFF, 12, 0),
            scored(3.0, m2, 12, 0),
            scored(2.0, m4, 15, 0),
            // More hits, but a normal frame fires at 2.5 / SAFETY: not admissible.
            scored(2.5, m4, 20, 1),
        ];
        assert_eq!(best_of(&c), Some(&c[3]));
        // Equal hits: the larger threshold, then no merge before a merge.
        assert_eq!(best_of(&c[..3]), Some(&c[1]));
        assert_eq!(best_of(&c[2..3]), Some(&c[2]));
        assert_eq!(best_of(&c[4..]), None);
    }

    /// A 12 x 20 face: a mark broken into three 2 x 2 pieces two pixels apart, saliency 3.2;
    /// the normal frame has one lone pixel at 2.0.
    fn frames() -> (Vec<Frame>, usize, usize) {
        let (h, w) = (12, 20);
        let mut marked = vec![0.0; h * w];
        for x0 in [4, 8, 12] {
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                marked[(5 + dy) * w + x0 + dx] = 3.2;
            }
        }
        let mut normal = vec![0.0; h * w];
        normal[2 * w + 2] = 2.0;
        let f = vec![
            Frame { saliency: marked, mark_box: Some([4.0, 5.0, 13.0, 6.0]) },
            Frame { saliency: normal, mark_box: None },
        ];
        (f, h, w)
    }

    /// A normal frame that merges into a detection at 3.0 but not at 3.0 / SAFETY = 2.4, where
    /// 33 more pieces overflow the merge table (the frame is then not merged) must still count.
    #[test]
    fn a_normal_frame_that_fires_only_at_the_threshold_itself_counts() {
        let (h, w) = (30, 60);
        let mut normal = vec![0.0; h * w];
        let mut piece = |x0: usize, y0: usize, v: f64| {
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                normal[(y0 + dy) * w + x0 + dx] = v;
            }
        };
        for x0 in [4, 8, 12] {
            piece(x0, 2, 3.2);
        }
        for k in 0..33 {
            piece(22 + (k % 11) * 3, 12 + (k / 11) * 4, 2.5);
        }
        let (marked, _, _) = frames();
        let mut mark = vec![0.0; h * w];
        for (i, v) in marked[0].saliency.iter().enumerate() {
            mark[(i / 20) * w + i % 20] = *v;
        }
        let f = vec![
            Frame { saliency: mark, mark_box: Some([4.0, 5.0, 13.0, 6.0]) },
            Frame { saliency: normal, mark_box: None },
        ];
        let base = NoveltyParams { min_area: 12, ..Default::default() };
        let p = NoveltyParams { threshold: 2.4, merge: MERGES[2], ..base };
        assert!(calibrate::detect(&f[1].saliency, h, w, &p).is_none(), "overflow: not merged at 2.4");
        let p = NoveltyParams { threshold: 3.0, ..p };
        assert!(calibrate::detect(&f[1].saliency, h, w, &p).is_some(), "merged at 3.0");
        let (chosen, c) = choose(&f, h, w, &base).unwrap();
        let c = c.unwrap();
        let at = |t: f64, m: Merge| c.candidates.iter().find(|s| s.threshold == t && s.merge == m).unwrap().clone();
        assert_eq!(at(3.0, MERGES[2]).normal_detections, 1);
        assert_eq!(at(3.0, MERGES[2]).hits, 1);
        assert_ne!((chosen.threshold, chosen.merge), (3.0, MERGES[2]));
    }

    fn choice_hits(c: &Choice, t: f64, m: Merge) -> usize {
        c.candidates.iter().find(|s| s.threshold == t && s.merge == m).map_or(usize::MAX, |s| s.hits)
    }

    #[test]
    fn lowers_the_threshold_and_merges_only_when_the_normal_frames_allow() {
        let (f, h, w) = frames();
        let base = NoveltyParams { min_area: 12, ..Default::default() };
        // Pieces of 4 px (fragment 3), gaps of 2 px: margin 3 joins them into 12 px at t <= 3.0;
        // the normal frame's lone pixel never makes a blob, so every candidate is admissible.
        let (p, choice) = choose(&f, h, w, &base).unwrap();
        assert_eq!((p.threshold, p.merge), (3.0, MERGES[2]));
        let choice = choice.unwrap();
        assert_eq!(choice_hits(&choice, 3.0, MERGES[1]), 0, "margin 2 leaves 4 px pieces");
        assert_eq!((choice.marked_frames, choice.normal_frames), (1, 1));
        assert_eq!(choice.candidates.len(), THRESHOLDS.len() * MERGES.len());
        // A normal frame that fires at 3.0 / 1.25 and below rules that out: nothing is admissible that
        // finds the mark, so the best admissible (no hits) is the paper's.
        let (mut f, h, w) = frames();
        for dx in 0..12 {
            f[1].saliency[9 * w + 3 + dx] = 2.5;
        }
        let (p, _) = choose(&f, h, w, &base).unwrap();
        assert_eq!((p.threshold, p.merge), (calibrate::DEFAULT_THRESHOLD, Merge::OFF));
        // Without normal frames the policy does not apply.
        let (p, c) = choose(&f[..1], h, w, &base).unwrap();
        assert_eq!((p, c), (base, None));
    }
}
