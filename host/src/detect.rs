//! `msr detect`: find a mark in one camera frame with a model blob.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr detect` is not implemented yet")
}
