//! A model blob from a training folder and a reach network, quantized with `quantize::choose`
//! and without a report.
use crate::quant::quantize;
use crate::train::reach::{self as train_reach, ReachModel};
use anyhow::{ensure, Result};
use std::path::Path;

/// Reach pairs made by the sim's IK: (mark pixel at head (0, 0), five joint angles).
pub fn sim_reach_pairs(n: usize, seed: u64) -> (Vec<[f64; 2]>, Vec<[f64; 5]>) {
    let pairs = msr_sim::dataset::reach_pairs(n, seed);
    (
        pairs.iter().map(|p| p.pixel).collect(),
        pairs.iter().map(|p| p.joints).collect(),
    )
}

/// Trains the 2-10-5 reach network on `n` sim IK pairs (the paper's 10^4 Adam iterations).
pub fn train_sim_reach(n: usize, seed: u64) -> Result<ReachModel> {
    let (xs, ys) = sim_reach_pairs(n, seed);
    ensure!(xs.len() >= 10, "the IK gave only {} reach pairs", xs.len());
    train_reach::train(
        &xs,
        &ys,
        // The published recipe: these pairs are the sim's exact IK, without the hand-guiding
        // noise that makes it over-fit the real ones (`train_reach`'s default).
        &train_reach::Opts {
            seed,
            restarts: 3,
            ..train_reach::Opts::paper()
        },
    )
}

/// The blob of decoder `name` in training folder `dir` with `reach`, quantized as `msr quantize`
/// does (per-layer shifts searched against the firmware's own decoder, i8 weights when they keep
/// 40 dB), calibrated on a grid of head poses over the paper's +-5 degrees.
pub fn blob_from_training(dir: &Path, name: &str, reach: &ReachModel) -> Result<Vec<u8>> {
    let model = crate::train::load(dir, name)?;
    let info = model.info()?.clone();
    let x = quantize::extras_of(dir, &info, reach.to_blob()?)?;
    let a = 5f32.to_radians();
    let grid = |i: usize| -a + 2.0 * a * i as f32 / 8.0;
    let heads: Vec<[f32; 2]> = (0..9).flat_map(|i| (0..9).map(move |j| [grid(i), grid(j)])).collect();
    let layers = model.decoder_layers()?;
    Ok(quantize::choose(&layers, &x, &heads, quantize::WeightArg::Auto)?.blob)
}
