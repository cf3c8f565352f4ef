//! `msr train`: flags to a [`TrainConfig`], then [`crate::train::run`].
use crate::models::ArchKind;
use crate::train::light_copies::LightCopies;
use crate::train::{calibrate, DeviceArg, ModelKind, NormArg, TrainConfig};
use anyhow::Result;
use msr_shared::blob::CropMode;
use std::path::PathBuf;

/// `msr train`'s flags: the dataset, the model, the training recipe and the calibration.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Dataset folder (sim layout or the published manifest layout)
    #[arg(long)]
    pub data: PathBuf,
    /// What to train: a decoder (head angles to face) or an autoencoder (face to face)
    #[arg(long, value_enum, default_value_t = ModelKind::Decoder)]
    pub model: ModelKind,
    /// The network: a small conv decoder or the published fully connected one
    #[arg(long, value_enum, default_value_t = ArchKind::Conv)]
    pub arch: ArchKind,
    /// Conv decoder only: dense units after the input (default 32)
    #[arg(long)]
    pub conv_hidden: Option<usize>,
    /// Conv decoder only: feature maps at half size (default 4)
    #[arg(long)]
    pub conv_channels: Option<usize>,
    /// Face crop: subpixel (refined and resampled; see `crop`) or pixel (the published code)
    #[arg(long, default_value_t = CropMode::Subpixel)]
    pub crop: CropMode,
    /// Output folder
    #[arg(long)]
    pub out: PathBuf,
    /// Passes over the training frames
    #[arg(long, default_value_t = 50)]
    pub epochs: usize,
    /// Frames per minibatch
    #[arg(long, default_value_t = 128)]
    pub batch: usize,
    /// Adam's learning rate before any decay
    #[arg(long, default_value_t = 0.005)]
    pub lr: f64,
    /// Multiply the learning rate by --lr-decay every this many epochs
    #[arg(long, default_value_t = 10)]
    pub lr_step: usize,
    /// The factor the learning rate is multiplied by every --lr-step epochs
    #[arg(long, default_value_t = 0.5)]
    pub lr_decay: f64,
    /// Seed of the initial weights, the minibatch shuffle and the light copies
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Saliency normaliser
    #[arg(long, value_enum, default_value_t = NormArg::Std)]
    pub normalisation: NormArg,
    /// Two-sided saliency |e - mu| / n (the published code); default one-sided (e - mu) / n
    #[arg(long)]
    pub two_sided: bool,
    /// Floor on sigma in grey levels before normalising
    #[arg(long, default_value_t = calibrate::DEFAULT_SIGMA_FLOOR)]
    pub sigma_floor: f64,
    /// Fixed threshold in saliency units (the paper's 0.018 * 255)
    #[arg(long, default_value_t = calibrate::DEFAULT_THRESHOLD, conflicts_with = "threshold_percentile")]
    pub threshold: f64,
    /// Pick the threshold as this percentile of the detection scores of the unmarked test frames
    #[arg(long)]
    pub threshold_percentile: Option<f64>,
    /// Average the signed error over a (2 N + 1)^2 window before its magnitude (0: per pixel,
    /// the paper; see `detect::pipeline::pooled_error`)
    #[arg(long, default_value_t = calibrate::DEFAULT_POOL)]
    pub pool: u8,
    /// Error statistics (mu, sigma) per cell of an N x N grid over the training head poses,
    /// 2..=4; the board takes the cell of the reported head pose (0: one set for all poses, the
    /// paper; each cell needs at least 2 training frames)
    #[arg(long, default_value_t = calibrate::DEFAULT_POSE_BINS)]
    pub pose_bins: u8,
    /// Smallest blob that counts as a detection, pixels
    #[arg(long, default_value_t = calibrate::DEFAULT_MIN_AREA)]
    pub min_area: u16,
    /// Copies of each training face under other lights (a tone curve, a shading gradient) in
    /// the error statistics, so that a recording made under one light does not fire when a lamp
    /// changes (decoders only; 0: the faces alone)
    #[arg(long, default_value_t = LightCopies::DEFAULT.copies)]
    pub light_copies: u8,
    /// The light copies' largest shading gradient, a share of the grey level from the face's
    /// centre to its edge (0..0.5)
    #[arg(long, default_value_t = LightCopies::DEFAULT.gradient)]
    pub light_gradient: f32,
    /// The light copies' largest change of the tone curve's exponent (0..0.5)
    #[arg(long, default_value_t = LightCopies::DEFAULT.gamma)]
    pub light_gamma: f32,
    /// Where burn trains
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    pub device: DeviceArg,
    /// No progress bars
    #[arg(long)]
    pub quiet: bool,
}

impl Args {
    /// The library's configuration for these flags.
    pub fn config(&self) -> TrainConfig {
        let mut c = TrainConfig::new(self.data.clone(), self.out.clone())
            .with_model(self.model)
            .with_arch(self.arch)
            .with_crop(self.crop)
            .with_epochs(self.epochs)
            .with_batch(self.batch)
            .with_lr(self.lr)
            .with_lr_step(self.lr_step)
            .with_lr_decay(self.lr_decay)
            .with_seed(self.seed)
            .with_normalisation(self.normalisation)
            .with_two_sided(self.two_sided)
            .with_sigma_floor(self.sigma_floor)
            .with_threshold(self.threshold)
            .with_pool(self.pool)
            .with_pose_bins(self.pose_bins)
            .with_min_area(self.min_area)
            .with_device(self.device)
            .with_light_copies(self.light_copies)
            .with_light_gradient(self.light_gradient)
            .with_light_gamma(self.light_gamma)
            .with_quiet(self.quiet);
        c.threshold_percentile = self.threshold_percentile;
        c.conv_hidden = self.conv_hidden;
        c.conv_channels = self.conv_channels;
        c
    }
}

/// Trains and calibrates the model the flags describe.
pub fn run(a: Args) -> Result<()> {
    crate::train::run(a.config())
}

/// A [`ConfigError`](crate::train::ConfigError) in the words of the flags that set the fields.
pub(crate) fn flag_text(e: &crate::train::ConfigError) -> String {
    use crate::train::ConfigError as E;
    match e {
        E::MinArea => "--min-area must be at least 1".into(),
        E::Percentile(p) => format!("--threshold-percentile must be within 0..=100, got {p}"),
        E::PoseBins { got, most } => format!("--pose-bins must be 0 (off) or 2..={most}, got {got}"),
        E::ConvSizesWithoutConv => "--conv-hidden and --conv-channels are for --arch conv".into(),
        E::NoNormalTestFrames { data } => format!(
            "--threshold-percentile needs normal held-out frames, but the test split of {} has no unmarked frame",
            data.display()
        ),
        E::FewFramesPerPoseCell { pose_bins, default, cells, data, fewest, total } => format!(
            "--pose-bins {pose_bins} (the default is {default}) needs at least 2 unmarked training frames in each of \
             the {cells} head-pose cells, but dataset {} has {fewest} in one ({total} in all); pass --pose-bins 0 (one \
             set of statistics for all poses) or fewer cells, or render more frames",
            data.display()
        ),
        E::LightGradient(g) => format!("--light-gradient must be in 0..0.5 (a share of the grey level), got {g}"),
        E::LightGamma(g) => format!("--light-gamma must be in 0..0.5, got {g}"),
    }
}

/// Whether the error is a flag given where it has no meaning (exit code 2, like clap's).
pub(crate) fn is_usage(e: &crate::train::ConfigError) -> bool {
    matches!(e, crate::train::ConfigError::ConvSizesWithoutConv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cmd::parse_args;

    #[test]
    fn config_errors_are_worded_with_the_flags() {
        use crate::train::ConfigError;
        let e = anyhow::Error::new(ConfigError::ConvSizesWithoutConv).context("training");
        assert_eq!(crate::cmd::one_line(&e), "training: --conv-hidden and --conv-channels are for --arch conv");
        assert_eq!(crate::cmd::exit_code(&e), 2);
        let e = anyhow::Error::new(ConfigError::PoseBins { got: 1, most: 5 });
        assert_eq!(crate::cmd::one_line(&e), "--pose-bins must be 0 (off) or 2..=5, got 1");
        assert_eq!(crate::cmd::exit_code(&e), 1);
        // The library's own words name the configuration's fields, not flags.
        assert!(!ConfigError::ConvSizesWithoutConv.to_string().contains("--"));
    }

    #[test]
    fn flag_defaults_are_the_library_defaults() {
        let args: Args = parse_args(&["msr", "--data", "d", "--out", "o"]).unwrap();
        let from_flags = args.config();
        let lib = TrainConfig::new("d".into(), "o".into());
        assert_eq!(format!("{from_flags}"), format!("{lib}"));
    }

    #[test]
    fn every_flag_reaches_the_config() {
        let args: Args = parse_args(&[
            "msr", "--data", "d", "--out", "o", "--model", "autoencoder", "--arch", "mlp", "--crop",
            "pixel", "--epochs", "3", "--batch", "7", "--lr", "0.1", "--lr-step", "2",
            "--lr-decay", "0.9", "--seed", "5", "--normalisation", "variance", "--two-sided",
            "--sigma-floor", "2", "--threshold-percentile", "99", "--min-area", "4", "--quiet",
            "--pool", "1", "--pose-bins", "2", "--conv-hidden", "16", "--conv-channels", "3",
            "--light-copies", "2", "--light-gradient", "0.1", "--light-gamma", "0.15",
        ])
        .unwrap();
        let c = args.config();
        assert_eq!(c.model, ModelKind::Autoencoder);
        assert_eq!(c.arch, ArchKind::Mlp);
        assert_eq!(c.crop, CropMode::Pixel);
        assert_eq!((c.epochs, c.batch, c.lr_step, c.seed, c.min_area), (3, 7, 2, 5, 4));
        assert_eq!((c.lr, c.lr_decay, c.sigma_floor), (0.1, 0.9, 2.0));
        assert_eq!(c.normalisation, NormArg::Variance);
        assert!(c.two_sided && c.quiet);
        assert_eq!(c.threshold_percentile, Some(99.0));
        assert_eq!((c.light_copies, c.light_gradient, c.light_gamma), (2, 0.1, 0.15));
        assert_eq!((c.pool, c.pose_bins, c.conv_hidden, c.conv_channels), (1, 2, Some(16), Some(3)));
    }
}
