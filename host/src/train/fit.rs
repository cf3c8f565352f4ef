//! The training loop: Adam, step-decayed learning rate, shuffled minibatches, MSE, per-epoch
//! train and test loss. Shared by the decoder and the autoencoder.
use crate::models::{Autoencoder, Decoder};
use anyhow::{ensure, Result};
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Keeps freed tensor buffers in the process for reuse. glibc serves each buffer of a few MB
/// (a batch's activations, gradients) with a fresh `mmap` and unmaps it when freed, so without
/// this every step of the loop page-faults its memory in again: a third of the single-thread
/// training time goes to the kernel, and the conv decoder's probe takes 11.3 s instead of 6.7 s
/// (15 epochs, `timing_probe`; the same losses to the bit). Buffers under 32 MiB come from
/// the heap, and up to 1 GiB of free heap stays mapped. Once per process; other allocators and
/// libcs are left as they are.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        static ONCE: std::sync::Once = std::sync::Once::new();
        // SAFETY: mallopt only sets allocator parameters; both values are within glibc's bounds
        // (the mmap threshold's maximum is 32 MiB on 64-bit), and a refused value changes nothing.
        ONCE.call_once(|| unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
            libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        });
    }
}

/// Hyper-parameters; the defaults are the paper's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HyperParams {
    /// Passes over the training frames.
    pub epochs: usize,
    /// Frames per minibatch.
    pub batch: usize,
    /// Adam's learning rate before any decay.
    pub lr: f64,
    /// The learning rate is multiplied by `lr_decay` every `lr_step` epochs.
    pub lr_step: usize,
    /// The factor the learning rate is multiplied by every `lr_step` epochs.
    pub lr_decay: f64,
    /// Adam's epsilon (PyTorch's default, which the published code used).
    pub adam_eps: f32,
    /// Seed of the minibatch shuffle (the training `run` also draws the initial weights from it).
    pub seed: u64,
}

impl Default for HyperParams {
    fn default() -> Self {
        HyperParams { epochs: 50, batch: 128, lr: 0.005, lr_step: 10, lr_decay: 0.5, adam_eps: 1e-8, seed: 0 }
    }
}

impl HyperParams {
    /// The learning rate of epoch `epoch` (counted from 0), after its step decays.
    pub fn lr_at(&self, epoch: usize) -> f64 {
        self.lr * self.lr_decay.powi((epoch / self.lr_step.max(1)) as i32)
    }

    /// Refuses values the loop cannot train with (zero counts, a learning rate or decay that is
    /// not positive and finite).
    pub fn check(&self) -> Result<()> {
        ensure!(self.epochs > 0, "epochs must be at least 1");
        ensure!(self.batch > 0, "batch size must be at least 1");
        ensure!(self.lr.is_finite() && self.lr > 0.0, "learning rate must be positive");
        ensure!(self.lr_decay.is_finite() && self.lr_decay > 0.0, "learning-rate decay must be positive");
        ensure!(self.lr_step > 0, "learning-rate step must be at least 1 epoch");
        Ok(())
    }
}

/// Per-epoch mean squared error (grey/255 units): train is the running mean over the epoch's
/// minibatches (as PyTorch loops report it), test is the whole test split after the epoch.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    /// Training loss of each epoch.
    pub train_loss: Vec<f64>,
    /// Test loss after each epoch (NaN without test frames).
    pub test_loss: Vec<f64>,
    /// Wall-clock seconds the whole training took.
    pub seconds: f64,
}

/// Training pairs: head angles and face crops (grey/255, row-major, all the same length).
#[derive(Clone, Debug, Default)]
pub struct Samples {
    /// Head angles (yaw, pitch) of each frame, radians.
    pub heads: Vec<[f32; 2]>,
    /// Face crop of each frame, grey/255, row-major.
    pub faces: Vec<Vec<f32>>,
    /// Per-pixel loss weights (0 on mark pixels, 1 elsewhere), for test frames that carry a mark:
    /// the test loss measures how well the face is predicted, not the mark. None: all 1.
    pub weights: Option<Vec<Vec<f32>>>,
}

impl Samples {
    /// The number of frames.
    pub fn len(&self) -> usize {
        self.heads.len()
    }
    /// Whether there are no frames.
    pub fn is_empty(&self) -> bool {
        self.heads.is_empty()
    }
    /// The head angles as an `[n, 2]` tensor on `device`.
    pub fn heads_tensor(&self, device: &Device) -> Tensor<2> {
        let v: Vec<f32> = self.heads.iter().flatten().copied().collect();
        Tensor::from_data(TensorData::new(v, [self.len(), 2]), device)
    }
    /// The faces as an `[n, h w]` tensor on `device`.
    pub fn faces_tensor(&self, device: &Device) -> Tensor<2> {
        rows_tensor(&self.faces, device)
    }
}

/// A model the loop can train: predicts faces from head angles and/or faces.
pub trait FaceNet: Module + Sized {
    /// Predicted faces `[n, h w]` from head angles `[n, 2]` and observed faces `[n, h w]`
    /// (each model reads the input it needs).
    fn predict(&self, heads: Tensor<2>, faces: Tensor<2>) -> Tensor<2>;
}

impl FaceNet for Decoder {
    fn predict(&self, heads: Tensor<2>, _faces: Tensor<2>) -> Tensor<2> {
        self.forward(heads)
    }
}

impl FaceNet for Autoencoder {
    fn predict(&self, _heads: Tensor<2>, faces: Tensor<2>) -> Tensor<2> {
        self.forward(faces)
    }
}

fn rows_tensor(rows: &[Vec<f32>], device: &Device) -> Tensor<2> {
    let n = rows.first().map_or(0, |f| f.len());
    let v: Vec<f32> = rows.iter().flatten().copied().collect();
    Tensor::from_data(TensorData::new(v, [rows.len(), n]), device)
}

fn index_tensor(idx: &[usize], device: &Device) -> Tensor<1, Int> {
    let v: Vec<i64> = idx.iter().map(|&i| i as i64).collect();
    Tensor::from_data(TensorData::new(v, [idx.len()]), device)
}

fn scalar(t: Tensor<1>) -> f64 {
    t.into_scalar::<f32>() as f64
}

/// Mean squared error of `model` over `data` (weighted by `data.weights` when given), in
/// batches, without gradients.
pub fn evaluate<M: FaceNet>(model: &M, data: &Samples, batch: usize, device: &Device) -> f64 {
    if data.is_empty() {
        return f64::NAN;
    }
    let model = model.valid();
    let dev = device.clone().without_autodiff();
    let (heads, faces) = (data.heads_tensor(&dev), data.faces_tensor(&dev));
    let weights = data.weights.as_ref().map(|w| rows_tensor(w, &dev));
    let idx: Vec<usize> = (0..data.len()).collect();
    let (mut sum, mut count) = (0.0, 0.0);
    for chunk in idx.chunks(batch.max(1)) {
        let it = index_tensor(chunk, &dev);
        let y = faces.clone().select(0, it.clone());
        let pred = model.predict(heads.clone().select(0, it.clone()), y.clone());
        let sq = (pred - y).square();
        match &weights {
            Some(w) => {
                let w = w.clone().select(0, it);
                sum += scalar((sq * w.clone()).sum());
                count += scalar(w.sum());
            }
            None => {
                let [b, n] = sq.dims();
                sum += scalar(sq.sum());
                count += (b * n) as f64;
            }
        }
    }
    sum / count
}

/// Trains `model` on `train`, reporting the test loss after every epoch. `device` must have
/// autodiff enabled. `label` names the progress bar.
pub fn fit<M: FaceNet>(
    mut model: M,
    train: &Samples,
    test: &Samples,
    hp: &HyperParams,
    device: &Device,
    label: &str,
    progress: bool,
) -> Result<(M, History)> {
    hp.check()?;
    keep_freed_memory();
    ensure!(!train.is_empty(), "no training samples");
    ensure!(train.weights.is_none(), "training frames must not carry marks");
    ensure!(device.is_autodiff(), "training needs an autodiff device");
    let started = Instant::now();
    let mut optim = AdamConfig::new().with_epsilon(hp.adam_eps).init();
    let mut rng = ChaCha8Rng::seed_from_u64(hp.seed ^ 0x7a11);
    let (heads, faces) = (train.heads_tensor(device), train.faces_tensor(device));
    let n = train.len();
    let batches = n.div_ceil(hp.batch);
    let bar = if progress { ProgressBar::new((hp.epochs * batches) as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_prefix(label.to_string());
    let mut history = History::default();
    let mut order: Vec<usize> = (0..n).collect();
    for epoch in 0..hp.epochs {
        let lr = hp.lr_at(epoch);
        order.shuffle(&mut rng);
        let mut sum = 0.0;
        for chunk in order.chunks(hp.batch) {
            let it = index_tensor(chunk, device);
            let y = faces.clone().select(0, it.clone());
            let pred = model.predict(heads.clone().select(0, it), y.clone());
            let loss = (pred - y).square().mean();
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            sum += scalar(loss.detach()) * chunk.len() as f64;
            model = optim.step(lr, model, grads);
            bar.inc(1);
        }
        let train_loss = sum / n as f64;
        ensure!(train_loss.is_finite(), "training diverged at epoch {} (loss {train_loss})", epoch + 1);
        let test_loss = evaluate(&model, test, 512, device);
        bar.set_message(format!("epoch {} train {train_loss:.5} test {test_loss:.5}", epoch + 1));
        history.train_loss.push(train_loss);
        history.test_loss.push(test_loss);
    }
    bar.finish();
    history.seconds = started.elapsed().as_secs_f64();
    Ok((model, history))
}
