//! Every candidate of the calibrated novelty policy (`train::policy`), scored on the policy's own
//! frames, over the training poses and near the observe posture, for a trained model.
//!
//! `cargo run --release -p msr-host --example policy_scores -- TRAIN_DIR ROBOT [MAX_HEAD_DEG] [SEED]`
//!
//! `msr demo` keeps only the winner, and nothing when no candidate is admissible (no normal
//! frame detected at the threshold or at threshold / 1.25); this prints each candidate's hits
//! and normal detections, and the least number of normal detections per threshold, so that one
//! sees how far from admissible the candidates are and whether a pose region buys any hit.
use anyhow::{Context, Result};
use msr_host::train::{self, policy};
use msr_sim::Robot;
use std::path::PathBuf;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.first().context("TRAIN_DIR")?);
    let robot: Robot = args.get(1).context("ROBOT")?.parse().map_err(|e| anyhow::anyhow!("robot: {e}"))?;
    let max_head = args.get(2).map_or(Ok(5.0), |s| s.parse::<f32>())?.to_radians();
    let seed: u64 = args.get(3).map_or(Ok(0), |s| s.parse())?;
    let model = train::load(&dir, "decoder")?;
    let info = model.info()?.clone();
    let stats = train::load_stats(&dir, &info)?;
    let template = image::open(dir.join(&info.files.template))?.to_luma8();
    let cropper = msr_host::data::crop::Cropper::new(template, info.crop);
    // The model's own settings without its region: what the policy calibrates from.
    let base = msr_host::train::calibrate::NoveltyParams { region: None, ..info.novelty };
    println!("{}: pool {}, pose grid {:?}", dir.display(), base.pool, base.pose_grid.map(|g| g.bins));
    for poses in [policy::Poses::Range(max_head), policy::Poses::Observe] {
        let f = policy::frames(robot, &cropper, &model, &stats, &base, (policy::NORMAL_FRAMES, policy::MARKED_FRAMES), seed, poses)?;
        // Every candidate, admissible or not: calibrate with a base whose scores we recompute.
        let (h, w) = (info.face_h, info.face_w);
        println!("{} ({} normal, {} marked frames):", poses.describe(), policy::NORMAL_FRAMES, policy::MARKED_FRAMES);
        println!("  threshold merge(margin,fragment): hits / normal detections");
        for merge in policy::MERGES {
            let mut line = format!("  merge ({},{}):", merge.margin, merge.fragment);
            for t in policy::THRESHOLDS {
                let p = msr_host::train::calibrate::NoveltyParams { threshold: t, merge, ..base };
                let q = msr_host::train::calibrate::NoveltyParams { threshold: t / policy::SAFETY, ..p };
                let normal = f
                    .iter()
                    .filter(|x| x.mark_box.is_none())
                    .filter(|x| {
                        msr_host::train::calibrate::detect(&x.saliency, h, w, &p).is_some()
                            || msr_host::train::calibrate::detect(&x.saliency, h, w, &q).is_some()
                    })
                    .count();
                let normal_at_t = f.iter().filter(|x| x.mark_box.is_none() && msr_host::train::calibrate::detect(&x.saliency, h, w, &p).is_some()).count();
                let hits = f
                    .iter()
                    .filter(|x| {
                        x.mark_box.is_some_and(|[x0, y0, x1, y1]| {
                            msr_host::train::calibrate::detect(&x.saliency, h, w, &p).is_some_and(|b| {
                                let [cx, cy] = b.centroid;
                                cx >= x0 && cx <= x1 && cy >= y0 && cy <= y1
                            })
                        })
                    })
                    .count();
                line += &format!(" {t:.2}: {hits}/{normal} ({normal_at_t} at t);");
            }
            println!("{line}");
        }
        let chosen = policy::calibrate(&f, h, w, &base, poses)?;
        println!("  chosen: {:?}", chosen.map(|c| (c.threshold, c.merge)));
    }
    Ok(())
}
