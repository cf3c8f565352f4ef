//! `msr import`: import the published model (safetensors, npy, template) into a model blob.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr import` is not implemented yet")
}
