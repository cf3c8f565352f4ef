//! `msr dataset`: render a mirror dataset (frames, head angles, splits, marks) for one robot.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr dataset` is not implemented yet")
}
