//! `msr import`: flags to an [`ImportConfig`], then [`import::import`], then what it wrote.
use crate::quant::import::{self, ImportConfig};
use anyhow::Result;
use msr_shared::blob::Sided;
use std::path::PathBuf;

/// `msr import`'s flags: the published manifest, the output blob and the novelty settings.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The published manifest.json
    pub manifest: PathBuf,
    /// Where to write the model blob
    #[arg(long)]
    pub out: PathBuf,
    /// Threshold on the saliency (sigma units); default: the manifest's training threshold (4.59)
    #[arg(long)]
    pub threshold: Option<f32>,
    /// Saliency |e - mu| / sigma (two, the published code) or (e - mu) / sigma (one)
    #[arg(long, value_enum, default_value_t = SidedArg::Two)]
    pub sided: SidedArg,
}

/// Which saliency `--sided` asks for.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SidedArg {
    /// (e - mu) / sigma: only an error above the mean counts
    One,
    /// |e - mu| / sigma, the published code: an error on either side of the mean counts
    Two,
}

impl Args {
    /// The library's configuration for these flags.
    pub fn config(&self) -> ImportConfig {
        let mut c = ImportConfig::new(self.manifest.clone(), self.out.clone()).with_sided(match self.sided {
            SidedArg::One => Sided::One,
            SidedArg::Two => Sided::Two,
        });
        c.threshold = self.threshold;
        c
    }
}

/// Imports the published model into a blob and prints what it wrote and how close the fixed
/// point comes to float.
pub fn run(args: Args) -> Result<()> {
    let r = import::import(&args.config())?;
    println!(
        "wrote {} ({} bytes): decoder {} ({} layers, i16 weights, shifts w.in->out {}), face {}x{}, \
         threshold {}, min area {}",
        args.out.display(),
        r.blob_bytes,
        r.arch,
        r.layers,
        r.shifts.join(" "),
        r.face_w,
        r.face_h,
        r.threshold,
        r.min_area
    );
    println!(
        "fixed point (firmware decoder) vs float over {} head poses: PSNR {:.1} dB, largest \
         difference {:.2} grey levels",
        r.poses, r.psnr_db, r.max_abs_grey
    );
    Ok(())
}
