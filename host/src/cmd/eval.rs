//! `msr eval`: [`eval::evaluate_with`] on the flags' blob and dataset, printed.
use crate::eval;
use anyhow::Result;
use std::path::PathBuf;

/// `msr eval`'s flags: the model, the dataset, the published manifest, the camera and the format.
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
    /// The camera's imperfections, on every test frame (its colour frame, before grey and the
    /// crop; the noise the same draws on every run)
    #[command(flatten)]
    pub imperfect: super::imperfect::CameraFlags,
    /// Code every test face in this grey range after the camera's imperfections: a camera whose
    /// video coding the model was not calibrated at
    #[arg(long, value_enum, default_value_t = eval::Range::Full)]
    pub range: eval::Range,
}

/// Evaluates the blob on the dataset's test split and prints the table (markdown or JSON).
pub fn run(args: Args) -> Result<()> {
    let camera = eval::Camera { imperfect: args.imperfect.imperfections(0), range: args.range };
    let report = eval::evaluate_lit(&args.model, &args.data, args.manifest.as_deref(), &camera)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", eval::markdown(&report));
    }
    Ok(())
}
