//! `msr demo`: flags to a [`DemoConfig`], then [`demo::run`] (or only the page again).
use crate::demo::{self, DemoConfig};
use crate::episode::ServoBus;
use anyhow::Result;
use msr_shared::blob::CropMode;
use msr_sim::Robot;
use std::path::PathBuf;

/// The flags of `msr demo`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder
    #[arg(long, default_value = "demo-out")]
    pub out: PathBuf,
    /// The sim robot the demo trains and tests
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// Face crop of the trained models: subpixel, or pixel (the published code)
    #[arg(long, default_value_t = CropMode::Subpixel)]
    pub crop: CropMode,
    /// Frames rendered (the paper's 1300)
    #[arg(long, default_value_t = 1300)]
    pub frames: usize,
    /// Training epochs (the paper's 50)
    #[arg(long, default_value_t = 50)]
    pub epochs: usize,
    /// Mirror-test trials in-process (and under QEMU when it is installed)
    #[arg(long, default_value_t = 40)]
    pub trials: usize,
    /// Of those, how many also run under QEMU (a few seconds each; capped at 90 s in all)
    #[arg(long, default_value_t = 5)]
    pub qemu_trials: usize,
    /// Folder of real frames in the published layout, for the real-frame check
    #[arg(long)]
    pub real: Option<PathBuf>,
    /// Seed of everything the demo draws (frames, marks, training, trials)
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The servo bus of the episodes
    #[arg(long, value_enum, default_value_t = ServoBus::Dynamixel)]
    pub servo_bus: ServoBus,
    /// Trials in each scene (mirror, another robot, a delayed picture) with a self gate
    /// calibrated on the spot (0: none)
    #[arg(long, default_value_t = 6)]
    pub gate_trials: usize,
    /// Average the decoder's signed error over a (2 N + 1)^2 window before its magnitude
    /// (0: per pixel, the paper), as `msr train --pool`
    #[arg(long, default_value_t = crate::train::calibrate::DEFAULT_POOL)]
    pub pool: u8,
    /// Error statistics per cell of an N x N grid over the training head poses (0: one set for
    /// all poses, the paper), as `msr train --pose-bins`
    #[arg(long, default_value_t = crate::train::calibrate::DEFAULT_POSE_BINS)]
    pub pose_bins: u8,
    /// Leave out the self gate: the model reaches for a confirmed mark at once, as the paper
    /// (by default it carries a gate calibrated for --robot, as `msr quantize`'s)
    #[arg(long)]
    pub no_self_gate: bool,
    /// Leave out the face's colour: the model sees grey only, as the paper (by default it
    /// learns each block's colour from the training frames and finds marks only colour shows)
    #[arg(long)]
    pub no_colour: bool,
    /// Only rewrite index.html from an earlier run's report.json, model.msrm and dataset in --out
    #[arg(long)]
    pub html_only: bool,
    /// How the dataset is lit: varied-train (half the training frames each under a light of
    /// its own, so that the error statistics cover what the photometric fit leaves; test frames
    /// under the fixed light), fixed, varied, lamp
    #[arg(long, value_enum, default_value_t = super::light::DatasetLight::VariedTrain)]
    pub light: super::light::DatasetLight,
}

impl Args {
    /// The library's configuration for these flags.
    pub fn config(&self) -> DemoConfig {
        let mut c = DemoConfig::new(self.out.clone())
            .with_robot(self.robot)
            .with_crop(self.crop)
            .with_frames(self.frames)
            .with_epochs(self.epochs)
            .with_trials(self.trials)
            .with_qemu_trials(self.qemu_trials)
            .with_seed(self.seed)
            .with_servo_bus(self.servo_bus)
            .with_gate_trials(self.gate_trials)
            .with_pool(self.pool)
            .with_pose_bins(self.pose_bins)
            .with_self_gate(!self.no_self_gate)
            .with_colour(!self.no_colour)
            .with_light(self.light.into());
        c.real = self.real.clone();
        c
    }
}

/// Runs the demo, or with `--html-only` writes its page again from the results in its folder.
pub fn run(a: Args) -> Result<()> {
    if a.html_only {
        demo::rewrite_html(&a.out)?;
        eprintln!("wrote {}", a.out.join("index.html").display());
        return Ok(());
    }
    demo::run(&a.config()).map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmd::parse_args;

    #[test]
    fn flag_defaults_are_the_library_defaults() {
        let args: Args = parse_args(&["msr"]).unwrap();
        assert_eq!(format!("{}", args.config()), format!("{}", DemoConfig::new("demo-out".into())));
    }

    #[test]
    fn the_paper_per_pixel_error_is_a_flag_away() {
        let c = parse_args::<Args>(&["msr"]).unwrap().config();
        let d = (crate::train::calibrate::DEFAULT_POOL, crate::train::calibrate::DEFAULT_POSE_BINS);
        assert_eq!((c.pool, c.pose_bins), d);
        assert_eq!(d, (2, 3));
        let c = parse_args::<Args>(&["msr", "--pool", "0", "--pose-bins", "0"]).unwrap().config();
        assert_eq!((c.pool, c.pose_bins), (0, 0));
    }
}
