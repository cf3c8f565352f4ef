//! The blob `msr demo` makes from a training folder (its step 4: the sim's 70 IK reach pairs and
//! the 2-10-5 reach network for `SEED`, then `quant::model_blob::blob_from_training`), for a
//! folder whose `decoder.json` was edited, e.g. with the calibrated policy's pose region removed.
//!
//! `cargo run --release -p msr-host --example demo_blob -- TRAIN_DIR OUT.msrm [SEED]`
//!
//! On an unedited `DEMO_OUT/models` it writes `DEMO_OUT/model.msrm` byte for byte.
use anyhow::{Context, Result};
use std::path::PathBuf;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.first().context("TRAIN_DIR")?);
    let out = PathBuf::from(args.get(1).context("OUT.msrm")?);
    let seed: u64 = args.get(2).map_or(Ok(0), |s| s.parse())?;
    let reach = msr_host::quant::model_blob::train_sim_reach(70, seed)?;
    let blob = msr_host::quant::model_blob::blob_from_training(&dir, "decoder", &reach)?;
    std::fs::write(&out, &blob).with_context(|| format!("writing {}", out.display()))?;
    eprintln!("wrote {} ({} bytes)", out.display(), blob.len());
    Ok(())
}
