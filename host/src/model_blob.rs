//! A model blob from a training folder and a reach network, for the demo and the end-to-end
//! tests, until `msr quantize` covers every decoder: fully connected decoders (`--arch mlp`, the
//! published architecture) go through the importer's quantizer (`crate::import::Published`), the
//! same path the published model takes; the sigma floor and novelty settings come from the
//! model's JSON.
use crate::import::{Dense, DenseDecoder, Published};
use crate::train_reach::{self, ReachModel};
use anyhow::{bail, ensure, Context, Result};
use msr_shared::blob::{LayerKind, Normalisation};
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
        &train_reach::Opts {
            seed,
            restarts: 3,
            ..Default::default()
        },
    )
}

/// The blob of decoder `name` in training folder `dir` with `reach`.
pub fn blob_from_training(dir: &Path, name: &str, reach: &ReachModel) -> Result<Vec<u8>> {
    let model = crate::train::load(dir, name)?;
    let info = model.info()?.clone();
    let layers = model.decoder_layers()?;
    let mut dense = Vec::new();
    for l in &layers {
        if l.kind != LayerKind::Dense {
            bail!("decoder layer {:?}: only fully connected decoders (--arch mlp) can be turned into a blob here", l.kind);
        }
        dense.push(Dense {
            n_in: l.input.len(),
            n_out: l.output.len(),
            w: l.weights.clone(),
            b: l.bias.clone(),
            act: l.activation,
        });
    }
    if info.novelty.normalisation != Normalisation::StdDev {
        bail!("only the standard-deviation normalisation is supported here");
    }
    let stats = crate::train::load_stats(dir, &info)?;
    let floor = info.novelty.sigma_floor;
    let template = crate::crop::load_grey(&dir.join(&info.files.template))
        .context("the model's face template")?;
    let p = Published {
        decoder: DenseDecoder {
            layers: dense,
            face_h: info.face_h,
            face_w: info.face_w,
        },
        mu: stats.mu.clone(),
        sigma: stats.sigma.iter().map(|s| s.max(floor)).collect(),
        template,
        reach: reach.to_blob()?,
        threshold: info.novelty.threshold as f32,
        sided: info.novelty.sided,
        min_area: info.novelty.min_area,
        head_angles: None,
    };
    p.to_spec()?
        .to_bytes()
        .map_err(|e| anyhow::anyhow!("model blob: {e}"))
}
