//! `msr demo`: from nothing to a report: dataset, training, reach, quantization, evaluation, episodes.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr demo` is not implemented yet")
}
