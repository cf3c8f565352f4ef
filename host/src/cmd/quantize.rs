//! `msr quantize`: flags to a [`QuantizeConfig`], then [`quantize::quantize`], the face's colour
//! (`train::chroma`) unless `--no-colour`, the self gate ([`self_gate::gate_quantized`]) unless
//! `--no-self-gate`, then the report.
use crate::quant::quantize::{self, QuantizeConfig, WeightArg};
use crate::train::self_gate::{self, GateCalibration, GatedReport};
use anyhow::{Context, Result};
use std::path::PathBuf;

/// The flags of `msr quantize`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder of `msr train` (its decoder is quantized)
    #[arg(long)]
    pub train: PathBuf,
    /// Reach network from `msr train-reach` (safetensors with its .json scaling beside it)
    #[arg(long)]
    pub reach: PathBuf,
    /// Threshold in saliency units (default: the one chosen at training)
    #[arg(long)]
    pub threshold: Option<f64>,
    /// The weights' integer type in the blob
    #[arg(long, value_enum, default_value_t = WeightArg::Auto)]
    pub weights: WeightArg,
    /// Dataset for the float-vs-fixed report (default: the one the model was trained on)
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// The model blob to write
    #[arg(long)]
    pub out: PathBuf,
    /// Print the report as JSON
    #[arg(long)]
    pub json: bool,
    /// Leave out the self gate: a confirmed mark is reached at once, as the paper (by default
    /// the blob carries a gate calibrated on the dataset's robot, see `train::self_gate`)
    #[arg(long)]
    pub no_self_gate: bool,
    /// Leave out the face's colour: the blob sees grey only, as the paper (by default it learns
    /// each 2 x 2 block's colour per pose cell from the dataset's training frames, see
    /// `train::chroma`)
    #[arg(long)]
    pub no_colour: bool,
}

impl Args {
    /// The library's configuration for these flags.
    pub fn config(&self) -> QuantizeConfig {
        let mut c = QuantizeConfig::new(self.train.clone(), self.reach.clone(), self.out.clone())
            .with_weights(self.weights);
        c.threshold = self.threshold;
        c.data = self.data.clone();
        c
    }
}

/// Quantizes, gates (unless `--no-self-gate`) and prints the report, as one line or as JSON.
pub fn run(args: Args) -> Result<()> {
    let mut quantized = quantize::quantize(&args.config())?;
    if !args.no_colour {
        let cal = crate::train::chroma::colour_quantized(&mut quantized)
            .context("learning the face's colour (--no-colour leaves it out)")?;
        match cal {
            Some(c) => eprintln!(
                "the face's colour from {} training frames over {} pose cells: threshold {:.1} spreads",
                c.frames, c.cells, c.threshold
            ),
            None => eprintln!("{}: grey frames, so the model stays grey (no colour stage)", quantized.data),
        }
    }
    let gated = if args.no_self_gate {
        GatedReport::ungated(quantized)
    } else {
        self_gate::gate_quantized(quantized, &GateCalibration::default())
            .context("calibrating the self gate (--no-self-gate leaves it out)")?
    };
    gated.write()?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&gated)?);
    } else {
        let report = &gated.quantized;
        println!(
            "wrote {} ({} bytes, {} weights, {} MACs): PSNR {:.1} dB over {} poses{}; detection agreement {:.1} % on {} test frames (float {}, fixed {} detections), centroid difference max {} px",
            report.blob,
            report.blob_bytes,
            report.weights,
            report.decoder_macs,
            report.psnr_db,
            report.psnr_poses,
            report.psnr_i8_db.map(|p| format!(" (i8: {p:.1} dB)")).unwrap_or_default(),
            100.0 * report.detection_agreement,
            report.test_frames,
            report.float_detections,
            report.fixed_detections,
            report.centroid_diff_px_max.map(|d| format!("{d:.2}")).unwrap_or("-".into()),
        );
    }
    Ok(())
}
