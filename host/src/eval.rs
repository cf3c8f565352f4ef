//! `msr eval`: evaluate detection on a dataset's test split (the paper's table).
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr eval` is not implemented yet")
}
