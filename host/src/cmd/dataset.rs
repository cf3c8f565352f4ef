//! `msr dataset`: render a mirror dataset (frames, head angles, splits, marks) for one robot.
use crate::episode::Scene;
use anyhow::{bail, Context, Result};
use msr_sim::dataset::{write_dataset_with, DatasetConfig, DatasetScene};
use msr_sim::Robot;
use std::path::PathBuf;

/// `msr dataset`'s flags: the robot, the frames, the splits, the scene, the light and the camera.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Which robot: red (the real red Nao's look) or skin (grey covers with skin taxels)
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// Number of frames (1..=1000000)
    #[arg(long, default_value_t = 1300)]
    pub count: usize,
    /// Seed; the same seed gives the same bytes
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output folder (created if missing)
    #[arg(long)]
    pub out: PathBuf,
    /// Head angles are uniform in +-this many degrees (0..=20.05)
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
    /// What the camera sees: mirror (the own mirror image), other (another robot of the same
    /// look, its head at a pose of its own, marks on its face; not for training). delayed is
    /// refused: a delay needs a time series, and the frames are independent draws (use `msr
    /// mirror-test --scene delayed`)
    #[arg(long, value_enum, default_value_t = Scene::Mirror)]
    pub scene: Scene,
    /// How the frames are lit: fixed (the calibrated light) or varied (a light per frame)
    #[arg(long, value_enum, default_value_t = super::light::DatasetLight::Fixed)]
    pub light: super::light::DatasetLight,
    /// The camera's imperfections, on every frame
    #[command(flatten)]
    pub imperfect: super::imperfect::CameraFlags,
}

/// Renders the dataset into `--out` and says what it wrote.
pub fn run(args: Args) -> Result<()> {
    let scene = match args.scene {
        Scene::Mirror => DatasetScene::Mirror,
        Scene::Other => DatasetScene::Other,
        Scene::Delayed => bail!(
            "--scene delayed: a video delay shows an earlier pose, which needs a time series; the \
             dataset's frames are independent draws. Use `msr mirror-test --scene delayed`"
        ),
    };
    let cfg = DatasetConfig {
        robot: args.robot,
        count: args.count,
        seed: args.seed,
        max_head_angle: args.max_angle_deg.to_radians(),
        test_fraction: args.test_fraction,
        reach_pairs: args.reach_pairs,
        unmarked_test_fraction: args.unmarked_test_fraction,
        scene,
        light: args.light.into(),
        camera: args.imperfect.imperfections(args.seed),
    };
    // The folder before the banner: an --out that cannot be made is the one line said.
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create --out {}", args.out.display()))?;
    // The size first: a large --count runs for hours and fills a disk.
    let est = args.count as f64 * FRAME_BYTES_ESTIMATE;
    eprintln!(
        "msr dataset: {} frames of 320x240 to {}, about {} on disk (~{:.0} KB a frame)",
        args.count,
        args.out.display(),
        human_bytes(est),
        FRAME_BYTES_ESTIMATE / 1000.0
    );
    let bar = indicatif::ProgressBar::new(args.count as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} frames, {msg} written, ETA {eta}")
            .expect("a valid template"),
    );
    let t = std::time::Instant::now();
    let index = write_dataset_with(&cfg, &args.out, &mut |_, bytes| {
        bar.inc(1);
        bar.set_message(human_bytes(bytes as f64));
    });
    bar.finish_and_clear();
    let index = index?;
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

/// Bytes one frame adds on disk (its PNG, a share of mark masks): measured on `msr dataset
/// --count 20` (2.4 MB).
pub const FRAME_BYTES_ESTIMATE: f64 = 120_000.0;

fn human_bytes(b: f64) -> String {
    match b {
        b if b >= 1e9 => format!("{:.1} GB", b / 1e9),
        b if b >= 1e6 => format!("{:.1} MB", b / 1e6),
        b => format!("{:.0} KB", b / 1e3),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmd::parse_args;

    #[test]
    fn writes_a_dataset_from_the_command_line() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ds");
        let args: Args = parse_args(&[
            "msr", "--robot", "skin", "--count", "10", "--seed", "4", "--reach-pairs", "3", "--out",
            out.to_str().unwrap(),
        ])
        .unwrap();
        run(args).unwrap();
        let index: msr_sim::layout::DatasetIndex =
            serde_json::from_slice(&std::fs::read(out.join(msr_sim::layout::INDEX_FILE)).unwrap()).unwrap();
        assert_eq!((index.robot.as_str(), index.seed, index.frames.len()), ("skin", 4, 10));
        assert_eq!(index.split(msr_sim::layout::Split::Test).count(), 2);
        let pairs = std::fs::read_to_string(out.join(msr_sim::layout::REACH_JOINTS_FILE)).unwrap();
        assert_eq!(pairs.lines().count(), 3);
    }

    #[test]
    fn the_other_scene_records_the_other_robots_head_and_delayed_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ds");
        let o = out.to_str().unwrap();
        let args: Args = parse_args(&["msr", "--count", "5", "--reach-pairs", "0", "--scene", "other", "--out", o]).unwrap();
        run(args).unwrap();
        let index: msr_sim::layout::DatasetIndex =
            serde_json::from_slice(&std::fs::read(out.join(msr_sim::layout::INDEX_FILE)).unwrap()).unwrap();
        assert!(index.frames.iter().all(|f| f.seen_head.is_some()));
        let args: Args = parse_args(&["msr", "--count", "5", "--scene", "delayed", "--out", o]).unwrap();
        let e = run(args).unwrap_err().to_string();
        assert!(e.contains("--scene delayed") && e.contains("mirror-test"), "{e}");
        assert!(parse_args::<Args>(&["msr", "--scene", "mirrors", "--out", o]).is_err());
    }

    #[test]
    fn bad_arguments_are_refused_with_a_message() {
        assert!(parse_args::<Args>(&["msr", "--robot", "blue", "--out", "x"]).is_err());
        assert!(parse_args::<Args>(&["msr", "--count", "-3", "--out", "x"]).is_err());
        assert!(parse_args::<Args>(&["msr", "--robot", "red"]).is_err(), "--out is required");
        let dir = tempfile::tempdir().unwrap();
        let args: Args = parse_args(&["msr", "--max-angle-deg", "90", "--out", dir.path().to_str().unwrap()]).unwrap();
        let e = run(args).unwrap_err().to_string();
        assert!(e.contains("head angle range"), "{e}");
    }
}
