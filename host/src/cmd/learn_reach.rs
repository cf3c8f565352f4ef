//! `msr learn-reach`: the sim's robot teaches itself its reach in the mirror
//! ([`crate::learn_reach`]), then the network is trained on its pairs as `msr train-reach` does.
use crate::data::crop::grey_of;
use crate::detect::{cropper_of, detect_face, parse_blob, reason, EngineArg};
use crate::learn_reach::{self, sim::SimBody, LearnConfig};
use crate::train::reach::{self as train_reach, fmt_rms, ReachConfig};
use anyhow::{Context, Result};
use msr_sim::Robot;
use serde_json::json;
use std::path::PathBuf;

/// `msr learn-reach`'s flags.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model blob of this robot: its face check finds the face before the robot moves, and
    /// --model-out is this blob with the reach taught
    #[arg(long)]
    pub model: PathBuf,
    /// Which robot: red or skin
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// The sim's arm against its drawing
    #[command(flatten)]
    pub arm: super::ArmFlags,
    /// Seed of the arm's draw (as `msr mirror-test --seed`) and of the camera noise
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Folder for the pairs (reach_centroids.csv, reach_joints.csv: those the network was
    /// trained on), all pairs taught (taught.json) and the network (reach.safetensors and its .json)
    #[arg(long)]
    pub out: PathBuf,
    /// Also write --model with the taught reach in place of its own
    #[arg(long)]
    pub model_out: Option<PathBuf>,
    /// Shoulder postures per axis of the first grid
    #[arg(long, default_value_t = LearnConfig::default().grid)]
    pub grid: usize,
    /// Also teach with the head at this pose (HeadYaw,HeadPitch in radians, within 0.35; may be
    /// given again): only where the rest pose did not reach, the fingertip's place carried to the
    /// rest pose's frame by the face around it
    #[arg(long, value_name = "YAW,PITCH", value_parser = head_pose)]
    pub head_pose: Vec<[f64; 2]>,
    /// Halvings of the grid step around the postures that met the face
    #[arg(long, default_value_t = LearnConfig::default().refine)]
    pub refine: usize,
    /// Stop teaching at this many pairs
    #[arg(long, default_value_t = LearnConfig::default().max_pairs)]
    pub max_pairs: usize,
    /// Skip the leave-one-out report (one training per pair)
    #[arg(long)]
    pub no_loo: bool,
    /// Also the leave-one-out error of the same network on as many pairs from the sim's
    /// inverse kinematics (the comparison)
    #[arg(long)]
    pub compare_ik: bool,
    /// Print the summary as JSON
    #[arg(long)]
    pub json: bool,
}

/// A head pose `YAW,PITCH` in radians within [`learn_reach::MAX_HEAD`] (a clap value parser).
fn head_pose(s: &str) -> Result<[f64; 2], String> {
    let bad = || format!("a head pose is YAW,PITCH in radians, each within {}", learn_reach::MAX_HEAD);
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|_| bad())?;
    match v[..] {
        [y, p] if [y, p].iter().all(|a| a.is_finite() && a.abs() <= learn_reach::MAX_HEAD) => Ok([y, p]),
        _ => Err(bad()),
    }
}

/// Teaches, trains, writes, prints.
pub fn run(a: Args) -> Result<()> {
    let bytes = crate::fsio::read_blob(&a.model)?;
    let model = parse_blob(&bytes, &a.model)?;
    let cropper = cropper_of(&model)?;
    let face = |rgb: &image::RgbImage, head: [f64; 2]| -> Result<Option<crate::data::crop::CropBox>> {
        let f = cropper.crop(&grey_of(rgb))?;
        let d = detect_face(&model, &f, head.map(|a| a as f32), EngineArg::Fixed)?;
        Ok((reason(&d) != Some("NoFace")).then_some(f.crop))
    };
    let arm = a.arm.arm(a.robot, a.seed);
    let mut body = SimBody::new(a.robot, arm, Some(a.seed ^ 0x7EAC_4E11));
    let mut heads = vec![learn_reach::REST_HEAD];
    heads.extend(a.head_pose.iter().copied());
    let cfg = LearnConfig { heads, grid: a.grid, refine: a.refine, max_pairs: a.max_pairs };
    let bar = if a.json { indicatif::ProgressBar::hidden() } else { indicatif::ProgressBar::new(0) };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} sweeps  {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let taught = learn_reach::learn(&mut body, &face, &cfg, &mut |p| {
        bar.set_length(p.planned as u64);
        bar.set_position(p.sweeps as u64);
        bar.set_message(format!("{} pairs, {:.0} % of the face", p.pairs, 100.0 * p.coverage));
    })?;
    bar.finish_and_clear();
    if let Some(why) = &taught.stopped {
        eprintln!("warning: the teaching stopped early, the arm sent home: {why}");
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    crate::fsio::write(&a.out.join("taught.json"), serde_json::to_string_pretty(&taught)?)?;
    if taught.pairs.len() < 10 {
        let why: Vec<String> = taught.refused.iter().map(|(k, n)| format!("{n} {k}")).collect();
        anyhow::bail!(
            "{} pairs taught from {} sweeps and {} touches (refused: {}); the reach network needs at least 10",
            taught.pairs.len(),
            taught.sweeps,
            taught.touches,
            if why.is_empty() { "none".to_string() } else { why.join(", ") }
        );
    }
    let opts = train_reach::Opts { seed: a.seed, ..Default::default() };
    let keep = learn_reach::consistent_pairs(&taught.pairs, &opts)?;
    let kept: Vec<_> = keep.iter().map(|&i| taught.pairs[i]).collect();
    learn_reach::write_pairs(&a.out, &kept)?;
    let weights = a.out.join("reach.safetensors");
    let cfg = ReachConfig::new(
        a.out.join(msr_sim::layout::REACH_CENTROIDS_FILE),
        a.out.join(msr_sim::layout::REACH_JOINTS_FILE),
        weights.clone(),
    )
    .with_seed(a.seed)
    .with_leave_one_out(!a.no_loo);
    let side = train_reach::run(&cfg)?;
    let ik_loo = if a.compare_ik {
        let (xs, ys) = crate::quant::model_blob::sim_reach_pairs(kept.len(), a.seed);
        Some(train_reach::leave_one_out(&xs, &ys, &opts)?)
    } else {
        None
    };
    if let Some(out) = &a.model_out {
        let reach = train_reach::load(&weights)?.to_blob()?;
        let blob = msr_shared::blob::set_reach(&bytes, &reach).map_err(|e| anyhow::anyhow!("{}: {e}", a.model.display()))?;
        crate::fsio::write(out, blob)?;
    }
    if a.json {
        println!(
            "{}",
            json!({
                "robot": a.robot.name(), "arm_error": a.arm.arm_error, "seed": a.seed,
                "sweeps": taught.sweeps, "touches": taught.touches, "off_face": taught.off_face,
                "pairs": taught.pairs.len(), "pairs_kept": kept.len(), "coverage": taught.coverage(),
                "robot_seconds": taught.robot_seconds, "stopped": taught.stopped,
                "fit_rms_rad": side.fit_rms_rad, "loo_rms_rad": side.loo_rms_rad, "ik_loo_rms_rad": ik_loo,
            })
        );
        return Ok(());
    }
    println!(
        "taught: {} pairs ({} kept) from {} sweeps, {} touches, {} off the face; {:.0} % of the face; {:.0} s of robot time",
        taught.pairs.len(),
        kept.len(),
        taught.sweeps,
        taught.touches,
        taught.off_face,
        100.0 * taught.coverage(),
        taught.robot_seconds
    );
    println!("fit RMS (rad):                   {}", fmt_rms(&side.fit_rms_rad));
    if let Some(l) = &side.loo_rms_rad {
        println!("leave-one-out RMS (rad):         {}", fmt_rms(l));
    }
    if let Some(l) = &ik_loo {
        println!("the IK's pairs, leave-one-out:   {}", fmt_rms(l));
    }
    println!("wrote {}", a.out.display());
    if let Some(o) = &a.model_out {
        println!("wrote {} (the model with this reach)", o.display());
    }
    Ok(())
}
