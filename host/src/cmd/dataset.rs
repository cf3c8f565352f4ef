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
    /// Share of frames in the test split (the only ones that get marks)
    #[arg(long, default_value_t = 0.2)]
    pub test_fraction: f64,
    /// Share of test frames left unmarked, for false-alarm rates and image AUROC
    #[arg(long, default_value_t = 0.2)]
    pub unmarked_test_fraction: f64,
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
        unmarked_test_fraction: args.unmarked_test_fraction,
    };
    let t = std::time::Instant::now();
    let index = write_dataset(&cfg, &args.out)?;
    let test = index.split(msr_sim::layout::Split::Test).count();
    let marked = index.frames.iter().filter(|f| f.mark.is_some()).count();
    println!(
        "wrote {} frames ({} train, {} test of which {} marked) of robot {} to {} in {:.1} s",
        index.frames.len(),
        index.frames.len() - test,
        test,
        marked,
        index.robot,
        args.out.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    #[test]
    fn writes_a_dataset_from_the_command_line() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ds");
        let cli = Cli::try_parse_from([
            "msr", "--robot", "skin", "--count", "10", "--seed", "4", "--reach-pairs", "3", "--out",
            out.to_str().unwrap(),
        ])
        .unwrap();
        run(cli.args).unwrap();
        let index: msr_sim::layout::DatasetIndex =
            serde_json::from_slice(&std::fs::read(out.join(msr_sim::layout::INDEX_FILE)).unwrap()).unwrap();
        assert_eq!((index.robot.as_str(), index.seed, index.frames.len()), ("skin", 4, 10));
        assert_eq!(index.split(msr_sim::layout::Split::Test).count(), 2);
        let pairs = std::fs::read_to_string(out.join(msr_sim::layout::REACH_JOINTS_FILE)).unwrap();
        assert_eq!(pairs.lines().count(), 3);
    }

    #[test]
    fn bad_arguments_are_refused_with_a_message() {
        assert!(Cli::try_parse_from(["msr", "--robot", "blue", "--out", "x"]).is_err());
        assert!(Cli::try_parse_from(["msr", "--count", "-3", "--out", "x"]).is_err());
        assert!(Cli::try_parse_from(["msr", "--robot", "red"]).is_err(), "--out is required");
        let dir = tempfile::tempdir().unwrap();
        let cli = Cli::try_parse_from(["msr", "--max-angle-deg", "90", "--out", dir.path().to_str().unwrap()]).unwrap();
        let e = run(cli.args).unwrap_err().to_string();
        assert!(e.contains("head angle range"), "{e}");
    }
}
