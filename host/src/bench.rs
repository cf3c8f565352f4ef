//! `msr bench`: instruction counts, memory and code size of the firmware pipeline.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr bench` is not implemented yet")
}
