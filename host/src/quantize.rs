//! `msr quantize`: turn a trained model into a fixed-point model blob and compare it with float.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr quantize` is not implemented yet")
}
