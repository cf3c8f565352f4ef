//! `msr train-reach`: train the 2-10-5 reach network from mark positions to joint angles.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr train-reach` is not implemented yet")
}
