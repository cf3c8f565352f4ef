//! `msr train`: train a decoder or autoencoder on a dataset and calibrate its error statistics.
use anyhow::{bail, Result};

pub mod fit;
#[cfg(test)]
pub(crate) mod synthetic;

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr train` is not implemented yet")
}
