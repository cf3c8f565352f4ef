//! `msr mirror-test`: run mirror-test episodes: sim world, emulated links, firmware in-process or in QEMU.
use anyhow::{bail, Result};

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args) -> Result<()> {
    bail!("`msr mirror-test` is not implemented yet")
}
