//! `msr dataset`: render a mirror dataset (frames, head angles, splits, marks) for one robot.
use anyhow::Result;
use msr_sim::dataset::{write_dataset, DatasetConfig};
use msr_sim::Robot;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Which robot: red (the real red Nao's look) or skin (grey covers with skin taxels)
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// Number of frames
    #[arg(long, default_value_t = 1300)]
    pub count: usize,
    /// Seed; the same seed gives the same bytes
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder (created if missing)
    #[arg(long)]
    pub out: PathBuf,
    /// Head angles are uniform in +-this many degrees
    #[arg(long, default_value_t = 5.0)]
    pub max_angle_deg: f64,
    /// Share of frames in the test split (the marked ones)
    #[arg(long, default_value_t = 0.2)]
    pub test_fraction: f64,
    /// Reach training pairs made by the IK (reach_centroids.csv, reach_joints.csv)
    #[arg(long, default_value_t = 100)]
    pub reach_pairs: usize,
}

pub fn run(args: Args) -> Result<()> {
    let cfg = DatasetConfig {
        robot: args.robot,
        count: args.count,
        seed: args.seed,
        max_head_angle: args.max_angle_deg.to_radians(),
        test_fraction: args.test_fraction,
        reach_pairs: args.reach_pairs,
    };
    let t = std::time::Instant::now();
    let index = write_dataset(&cfg, &args.out)?;
    let test = index.split(msr_sim::layout::Split::Test).count();
    println!(
        "wrote {} frames ({} train, {} test with marks) of robot {} to {} in {:.1} s",
        index.frames.len(),
        index.frames.len() - test,
        test,
        index.robot,
        args.out.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
