//! `msr blobs`: list the 8-connected blobs of a binary mask with the firmware's blob stage.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr blobs` is not implemented yet")
}
