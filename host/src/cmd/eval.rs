//! `msr eval`: [`eval::evaluate_with`] on the flags' blob and dataset, printed.
use crate::eval;
use anyhow::Result;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model blob (.msrm)
    #[arg(long)]
    pub model: PathBuf,
    /// Dataset folder (sim layout or the published manifest layout)
    #[arg(long)]
    pub data: PathBuf,
    /// The published manifest the blob was imported from: its float decoder and float64
    /// statistics make the float decoder rows (instead of the blob's dequantized decoder)
    #[arg(long)]
    pub manifest: Option<PathBuf>,
    /// Print JSON instead of markdown
    #[arg(long)]
    pub json: bool,
    /// Multiply every test face by this exposure factor first (0.05..=20; rounded, clipped to
    /// 0..=255): detection under a camera exposure the model was not calibrated at
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// Add Gaussian noise of this many grey levels to every test face after the exposure
    /// (0..=64, rounded, clipped; the same draws on every run): a noisier sensor than the model
    /// was calibrated with
    #[arg(long, default_value_t = 0.0)]
    pub noise: f32,
    /// Code every test face in this grey range after the exposure and the noise: a camera whose
    /// video coding the model was not calibrated at
    #[arg(long, value_enum, default_value_t = eval::Range::Full)]
    pub range: eval::Range,
}

pub fn run(args: Args) -> Result<()> {
    let camera = eval::Camera { exposure: args.exposure, noise: args.noise, range: args.range };
    let report = eval::evaluate_lit(&args.model, &args.data, args.manifest.as_deref(), &camera)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", eval::markdown(&report));
    }
    Ok(())
}
