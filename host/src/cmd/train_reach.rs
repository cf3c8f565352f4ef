//! `msr train-reach`: flags to a [`ReachConfig`], then [`reach::run`], then the report.
use crate::train::reach::{self, fmt_rms, ReachConfig, PUBLISHED_FIT_RMS};
use anyhow::Result;
use std::path::PathBuf;

/// `msr train-reach`'s flags: the pairs, the output and the training recipe.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// CSV of mark positions, one `x,y` row per pair (full-frame pixels)
    #[arg(long)]
    pub inputs: PathBuf,
    /// CSV of joint angles, one row of 5 per pair (radians), same order as --inputs
    #[arg(long)]
    pub targets: PathBuf,
    /// Output safetensors file; the scaling and report go to the same name with .json
    #[arg(long)]
    pub out: PathBuf,
    /// Full-batch Adam iterations (the published recipe: 10000 with --weight-decay 0)
    #[arg(long, default_value_t = reach::DEFAULT_ITERATIONS)]
    pub iterations: usize,
    /// Adam's learning rate
    #[arg(long, default_value_t = 0.01)]
    pub lr: f64,
    /// Seed of the initial weights (restart r uses seed + r)
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Train from this many seeds and keep the lowest (penalised) training loss (1: the
    /// paper's single run)
    #[arg(long, default_value_t = reach::DEFAULT_RESTARTS)]
    pub restarts: usize,
    /// Skip the leave-one-out report (one training per pair)
    #[arg(long)]
    pub no_loo: bool,
    /// L2 penalty on the weights (0: the published recipe); default: chosen by 5-fold
    /// cross-validation over 0, 3e-6, 1e-5, 3e-5, 1e-4 on the pairs (inside every
    /// leave-one-out fold from that fold's pairs alone)
    #[arg(long)]
    pub weight_decay: Option<f64>,
}

impl Args {
    /// The library's configuration for these flags.
    pub fn config(&self) -> ReachConfig {
        ReachConfig::new(self.inputs.clone(), self.targets.clone(), self.out.clone())
            .with_iterations(self.iterations)
            .with_lr(self.lr)
            .with_seed(self.seed)
            .with_restarts(self.restarts)
            .with_leave_one_out(!self.no_loo)
            .with_weight_decay(self.weight_decay)
    }
}

/// Trains the reach network and prints its fit (and leave-one-out) RMS beside the published one.
pub fn run(a: Args) -> Result<()> {
    let side = reach::run(&a.config())?;
    let how = match side.weight_decay_choice {
        Some(reach::DecayChoice::CrossValidated) => format!("chosen by {}-fold cross-validation", reach::FOLDS),
        Some(reach::DecayChoice::TooFewPairs) => format!("too few pairs for {}-fold cross-validation", reach::FOLDS),
        _ => "given".into(),
    };
    println!(
        "reach: {} pairs, {} iterations, weight decay {} ({how}), in {:.2} s",
        side.pairs, side.iterations, side.weight_decay, side.training_seconds
    );
    println!("fit RMS (rad):           {}", fmt_rms(&side.fit_rms_rad));
    if let Some(l) = &side.loo_rms_rad {
        println!("leave-one-out RMS (rad): {}", fmt_rms(l));
    }
    println!("published fit RMS (rad): {}", fmt_rms(&PUBLISHED_FIT_RMS));
    println!("wrote {} and {}", a.out.display(), reach::sidecar_path(&a.out).display());
    Ok(())
}
