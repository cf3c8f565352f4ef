//! Argument parsing and dispatch for `msr`. Each command lives in its own module.
pub mod dataset;
pub mod blobs;
pub mod mirror_test;
pub mod demo;
pub mod run;

use crate::{train, detect, eval, bench};
use crate::train::reach as train_reach;
use crate::quant::{quantize, import};
use self::run as run_board;
use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "msr",
    version,
    about = "Mirror self-recognition: a robot learns its face in a mirror, finds a mark, reaches for it"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a mirror dataset (frames, head angles, splits, marks) for one robot
    Dataset(dataset::Args),
    /// Train a decoder or autoencoder on a dataset and calibrate its error statistics
    Train(train::Args),
    /// Train the 2-10-5 reach network from mark positions to joint angles
    TrainReach(train_reach::Args),
    /// Turn a trained model into a fixed-point model blob and compare it with float
    Quantize(quantize::Args),
    /// Import the published model (safetensors, npy, template) into a model blob
    Import(import::Args),
    /// Find a mark in one camera frame with a model blob
    Detect(detect::Args),
    /// List the 8-connected blobs of a binary mask with the firmware's blob stage
    Blobs(blobs::Args),
    /// Evaluate detection on a dataset's test split (the paper's table)
    Eval(eval::Args),
    /// Instruction counts, memory and code size of the firmware pipeline
    Bench(bench::Args),
    /// Run mirror-test episodes: sim world, emulated links, firmware in-process or in QEMU
    MirrorTest(mirror_test::Args),
    /// Stream frames to a board over a serial port and print what it reports
    #[command(name = "run")]
    Run(run_board::Args),
    /// From nothing to a report: dataset, training, reach, quantization, evaluation, episodes
    Demo(demo::Args),
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Dataset(a) => dataset::run(a),
        Command::Train(a) => train::run(a),
        Command::TrainReach(a) => train_reach::run(a),
        Command::Quantize(a) => quantize::run(a),
        Command::Import(a) => import::run(a),
        Command::Detect(a) => detect::run(a),
        Command::Blobs(a) => blobs::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Bench(a) => bench::run(a),
        Command::MirrorTest(a) => mirror_test::run(a),
        Command::Run(a) => run_board::run(a),
        Command::Demo(a) => demo::run(a),
    }
}
