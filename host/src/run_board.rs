//! `msr run`: stream frames to a board over a serial port and print what it reports.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr run` is not implemented yet")
}
