//! Training: a decoder or autoencoder fitted to a dataset, and its error statistics calibrated.
//!
//! Output folder (other commands rely on it):
//! - `{name}.mpk`: the burn record in burn's burnpack format (the `.mpk` name is what the other
//!   commands look for), `name` = `decoder` or `autoencoder`;
//! - `{name}.json`: [`ModelInfo`] (architecture, face size, hyper-parameters, per-epoch losses,
//!   training seconds, novelty parameters and how the threshold was chosen);
//! - `{name}_mu.npy`, `{name}_sigma.npy`: float64 `h x w` error statistics in grey levels, like the
//!   published ones (sigma not floored; the floor is in the JSON), over all training poses; with
//!   pose cells (`--pose-bins`, by default 3) also `{name}_pose_stats.npy`: each cell's mu then
//!   sigma in turn, `2 cells h x w`;
//! - `{name}_loss.png`: loss curves; `template.png`: the face template the crops were made with.
//!
//! The error is by default pooled and its statistics measured per head-pose cell
//! ([`calibrate::DEFAULT_POOL`], [`calibrate::DEFAULT_POSE_BINS`]); `--pool 0 --pose-bins 0` is the
//! paper's per-pixel error with one set of statistics.
//!
//! Frames: the training split's unmarked frames train the model and make the statistics; the test
//! split gives the per-epoch test loss (mark pixels excluded) and, for `--threshold-percentile`,
//! its unmarked frames are the normal held-out frames (see `crate::train::calibrate`). `msr demo` then
//! applies the calibrated novelty policy (`policy`), which may lower the threshold and turn on the
//! fragment merge, and rewrites `{name}.json`.
use self::calibrate::NoveltyParams;
pub use self::error::ConfigError;
use crate::data::{Dataset, Sample};
use crate::models::{ArchKind, Autoencoder, Decoder, DecoderSpec};
use crate::models::predictor::FacePredictor;
use anyhow::{bail, ensure, Context, Result};
use burn::prelude::*;
use fit::{HyperParams, Samples};
use msr_shared::blob::{CropMode, Normalisation, Sided};
use msr_sim::layout::Split;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub mod error;
pub mod fit;
pub mod plot;
pub mod policy;
pub mod calibrate;
pub mod chroma;
pub mod light_copies;
pub mod reach;
pub mod self_gate;
pub mod trained;
pub use self::trained::{load, load_on, load_stats, Trained, TrainedModel};
#[cfg(test)]
pub(crate) mod synthetic;

/// What to train.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Head angles -> face.
    Decoder,
    /// Face -> 2-d code -> face.
    Autoencoder,
}

impl ModelKind {
    /// The stem of the model's files in a training folder (`decoder`, `autoencoder`).
    pub fn name(self) -> &'static str {
        match self {
            ModelKind::Decoder => "decoder",
            ModelKind::Autoencoder => "autoencoder",
        }
    }
}

/// The saliency's normaliser.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum NormArg {
    /// (e - mu) / sigma, the published code
    Std,
    /// (e - mu) / sigma^2, the paper's text
    Variance,
}

/// Where burn trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DeviceArg {
    /// burn's pure-Rust CPU backend (flex)
    Cpu,
    /// CUDA GPU 0 (build with --features cuda)
    Cuda,
    /// wgpu default adapter (build with --features wgpu)
    Wgpu,
}

/// What [`run`] trains, on what, and how: `TrainConfig::new(data, out)` gives the defaults of
/// `msr train` (the published conv decoder's recipe); `with_*` changes one. The command line
/// builds it from its flags; the demo and the tests build it in code.
#[derive(burn::config::Config, Debug)]
pub struct TrainConfig {
    /// Dataset folder (sim layout or the published manifest layout).
    pub data: PathBuf,
    /// Output folder.
    pub out: PathBuf,
    /// What to train: the decoder or the autoencoder.
    #[config(default = "ModelKind::Decoder")]
    pub model: ModelKind,
    /// The decoder family: convolutional or the published dense (MLP) one.
    #[config(default = "ArchKind::Conv")]
    pub arch: ArchKind,
    /// Conv decoder only: dense units after the input (default 32).
    pub conv_hidden: Option<usize>,
    /// Conv decoder only: feature maps at half size (default 4).
    pub conv_channels: Option<usize>,
    /// Face crop: sub-pixel (refined and resampled) or pixel (the published code).
    #[config(default = "CropMode::Subpixel")]
    pub crop: CropMode,
    /// Passes over the training frames.
    #[config(default = 50)]
    pub epochs: usize,
    /// Frames per minibatch.
    #[config(default = 128)]
    pub batch: usize,
    /// Adam's learning rate before any decay.
    #[config(default = 0.005)]
    pub lr: f64,
    /// Multiply the learning rate by `lr_decay` every this many epochs.
    #[config(default = 10)]
    pub lr_step: usize,
    /// The factor the learning rate is multiplied by every `lr_step` epochs.
    #[config(default = 0.5)]
    pub lr_decay: f64,
    /// Seed of the initial weights, the minibatch shuffle and the light copies.
    #[config(default = 0)]
    pub seed: u64,
    /// What the saliency divides the error above the mean by.
    #[config(default = "NormArg::Std")]
    pub normalisation: NormArg,
    /// Two-sided saliency |e - mu| / n (the published code); default one-sided (e - mu) / n.
    #[config(default = false)]
    pub two_sided: bool,
    /// Floor on sigma in grey levels before normalising.
    #[config(default = "calibrate::DEFAULT_SIGMA_FLOOR")]
    pub sigma_floor: f64,
    /// Fixed threshold in saliency units (the paper's 0.018 * 255).
    #[config(default = "calibrate::DEFAULT_THRESHOLD")]
    pub threshold: f64,
    /// Pick the threshold as this percentile of the detection scores of the unmarked test frames.
    pub threshold_percentile: Option<f64>,
    /// Average the signed error over a (2 N + 1)^2 window before its magnitude (default
    /// [`calibrate::DEFAULT_POOL`]; 0: per pixel, the paper; see `detect::pipeline::pooled_error`).
    #[config(default = "calibrate::DEFAULT_POOL")]
    pub pool: u8,
    /// Error statistics per cell of an N x N grid over the training head poses (default
    /// [`calibrate::DEFAULT_POSE_BINS`]; 0: one set for all poses, the paper; see
    /// `calibrate::error_stats_by_pose`).
    #[config(default = "calibrate::DEFAULT_POSE_BINS")]
    pub pose_bins: u8,
    /// Smallest blob that counts as a detection, pixels.
    #[config(default = "calibrate::DEFAULT_MIN_AREA")]
    pub min_area: u16,
    /// Copies of each training face under other lights in the error statistics (decoders only;
    /// `light_copies::LightCopies`; 0: the faces alone, as `msr demo`, whose frames are rendered
    /// under varied light).
    #[config(default = "light_copies::LightCopies::DEFAULT.copies")]
    pub light_copies: u8,
    /// The copies' largest shading gradient (a share of the grey level, centre to edge).
    #[config(default = "light_copies::LightCopies::DEFAULT.gradient")]
    pub light_gradient: f32,
    /// The copies' largest change of the tone curve's exponent.
    #[config(default = "light_copies::LightCopies::DEFAULT.gamma")]
    pub light_gamma: f32,
    /// Where burn trains.
    #[config(default = "DeviceArg::Cpu")]
    pub device: DeviceArg,
    /// No progress bars.
    #[config(default = false)]
    pub quiet: bool,
}

/// How the threshold was chosen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThresholdPolicy {
    /// "fixed", "percentile", or "calibrated" (`policy::apply`, which `msr demo` runs).
    pub kind: String,
    /// The percentile of the unmarked test frames' detection scores (percentile only).
    pub percentile: Option<f64>,
    /// The frames whose detection scores were used (percentile only).
    pub frames: Option<String>,
    /// How many frames the threshold was chosen from (0 for a fixed threshold).
    pub n_frames: usize,
}

/// `{name}.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    /// What was trained.
    pub model: ModelKind,
    /// The network's architecture.
    pub arch: ArchKind,
    /// Face crop height, pixels.
    pub face_h: usize,
    /// Face crop width, pixels.
    pub face_w: usize,
    /// How the training faces were cropped (and so how the host must crop for this model);
    /// a file without the field was cropped to whole pixels.
    #[serde(default)]
    pub crop: CropMode,
    /// The decoder's layers: face size, dense widths and conv stack.
    pub spec: DecoderSpec,
    /// Multiply-accumulates of one decoder inference.
    pub decoder_macs: u64,
    /// The training loop's hyper-parameters.
    pub hyper: HyperParams,
    /// The burn backend it trained on (`cpu`, `cuda`, `wgpu`).
    pub device: String,
    /// The dataset folder it trained on.
    pub data: String,
    /// Unmarked training frames the model was fitted to.
    pub train_frames: usize,
    /// Test frames the test loss was measured on (marked ones included, their mark pixels not).
    pub test_frames: usize,
    /// Training loss of each epoch (MSE of grey/255 values).
    pub train_loss: Vec<f64>,
    /// NaN (JSON null) for each epoch when the dataset has no test frames.
    #[serde(deserialize_with = "nan_if_null::vec")]
    pub test_loss: Vec<f64>,
    /// The last epoch's training loss.
    pub final_train_mse: f64,
    /// The last epoch's test loss (NaN, JSON null, without test frames).
    #[serde(deserialize_with = "nan_if_null::one")]
    pub final_test_mse: f64,
    /// Wall-clock seconds of the training loop.
    pub training_seconds: f64,
    /// How the error becomes a detection: normaliser, threshold, floor, area, pool, pose grid.
    pub novelty: NoveltyParams,
    /// How the threshold was chosen.
    pub threshold_policy: ThresholdPolicy,
    /// The calibrated novelty policy's choice near the observe posture (`policy::apply`), when
    /// it was applied.
    #[serde(default)]
    pub novelty_policy: Option<policy::Choice>,
    /// Its choice over the training poses.
    #[serde(default)]
    pub general_policy: Option<policy::Choice>,
    /// Frames the error statistics were made from (their light copies not counted).
    pub stats_frames: usize,
    /// The light copies the statistics took in; none in a file without the field.
    #[serde(default = "light_copies::LightCopies::none")]
    pub light_copies: light_copies::LightCopies,
    /// The names of the files beside this description.
    pub files: Files,
    /// CRC-32 of every part this run wrote (file name -> checksum): a folder whose parts come
    /// from two runs is refused when it is read. A file without the field checks nothing.
    #[serde(default)]
    pub parts: std::collections::BTreeMap<String, u32>,
}

impl ModelInfo {
    /// The parts' file names.
    fn part_names(&self) -> Vec<&str> {
        let f = &self.files;
        [Some(&f.record), Some(&f.mu), Some(&f.sigma), Some(&f.template), f.pose_stats.as_ref()]
            .into_iter()
            .flatten()
            .map(String::as_str)
            .collect()
    }

    /// Refuses a part of `dir` that is not the one this description's run wrote.
    pub fn check_part(&self, dir: &Path, name: &str) -> Result<()> {
        let Some(&want) = self.parts.get(name) else { return Ok(()) };
        let p = dir.join(name);
        let got = msr_shared::blob::CRC32.checksum(&crate::fsio::read(&p)?);
        ensure!(
            got == want,
            "{} is not the file the run that wrote {}.json made (CRC-32 {got:08x}, it says {want:08x}): \
             another run wrote into {}; train again",
            p.display(),
            self.model.name(),
            dir.display()
        );
        Ok(())
    }
}

/// Holds an output folder for one writer (`msr train`): the lock goes with the process, so a run
/// that is killed leaves no stale lock.
pub struct OutLock(#[allow(dead_code)] std::fs::File);

/// Locks `dir` (created if missing) for writing, or says that another run holds it.
pub fn lock_out(dir: &Path) -> Result<OutLock> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let p = dir.join(".msr-train.lock");
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&p)
        .with_context(|| format!("cannot open {}", p.display()))?;
    match f.try_lock() {
        Ok(()) => Ok(OutLock(f)),
        Err(std::fs::TryLockError::WouldBlock) => {
            bail!("{} is in use by another msr run (it holds {}): wait for it, or give another output folder", dir.display(), p.display())
        }
        Err(std::fs::TryLockError::Error(e)) => Err(e).with_context(|| format!("cannot lock {}", p.display())),
    }
}

/// The file names of a training output folder's parts (see the module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Files {
    /// The burn record (`{name}.mpk`).
    pub record: String,
    /// Mean error per pixel, `.npy` (`{name}_mu.npy`).
    pub mu: String,
    /// Standard deviation of the error per pixel, `.npy` (`{name}_sigma.npy`).
    pub sigma: String,
    /// The loss curves (`{name}_loss.png`).
    pub loss_png: String,
    /// The face template the crops were made with (`template.png`).
    pub template: String,
    /// Per-pose-cell statistics (`novelty.pose_grid`): `2 K` tables of `h x w` stacked, cell
    /// `k`'s mu then sigma; absent without a grid.
    #[serde(default)]
    pub pose_stats: Option<String>,
}

impl Files {
    fn of(name: &str) -> Files {
        Files {
            record: format!("{name}.mpk"),
            mu: format!("{name}_mu.npy"),
            sigma: format!("{name}_sigma.npy"),
            loss_png: format!("{name}_loss.png"),
            template: "template.png".into(),
            pose_stats: None,
        }
    }
}

/// serde_json writes a NaN as null: read null back as NaN (a dataset without test frames, e.g. a
/// recording imported with `--test-fraction 0`, has no test loss).
mod nan_if_null {
    use serde::{Deserialize, Deserializer};
    pub fn one<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
    pub fn vec<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Ok(Vec::<Option<f64>>::deserialize(d)?.into_iter().map(|v| v.unwrap_or(f64::NAN)).collect())
    }
}

/// The burn device for `d`; a backend this build was compiled without is an error that names its
/// cargo feature.
pub fn device(d: DeviceArg) -> Result<Device> {
    match d {
        DeviceArg::Cpu => Ok(Device::flex()),
        #[cfg(feature = "cuda")]
        DeviceArg::Cuda => Ok(Device::cuda(0)),
        #[cfg(feature = "wgpu")]
        DeviceArg::Wgpu => Ok(Device::wgpu(Default::default())),
        #[allow(unreachable_patterns)]
        other => bail!("this build has no {other:?} backend; rebuild with `--features {}`", format!("{other:?}").to_lowercase()),
    }
}

/// The unmarked frames of a split, and the marked ones with their mark pixels weighted 0.
fn samples<'a>(it: impl Iterator<Item = &'a Sample>, keep_marked: bool) -> Samples {
    let mut s = Samples::default();
    let mut weights = Vec::new();
    for x in it {
        if x.mark.is_some() && !keep_marked {
            continue;
        }
        s.heads.push(x.head);
        s.faces.push(x.face_unit());
        let n = s.faces.last().map_or(0, |f| f.len());
        weights.push(match &x.mark {
            Some(m) => m.face_mask.iter().map(|&b| if b { 0.0 } else { 1.0 }).collect(),
            None => vec![1.0; n],
        });
    }
    if weights.iter().any(|w: &Vec<f32>| w.contains(&0.0)) {
        s.weights = Some(weights);
    }
    s
}

/// Trains, calibrates and writes the output folder (see the module doc).
pub fn run(args: TrainConfig) -> Result<()> {
    ensure!(args.min_area >= 1, ConfigError::MinArea);
    if let Some(p) = args.threshold_percentile {
        ensure!((0.0..=100.0).contains(&p), ConfigError::Percentile(p));
    }
    let novelty = NoveltyParams {
        normalisation: match args.normalisation {
            NormArg::Std => Normalisation::StdDev,
            NormArg::Variance => Normalisation::Variance,
        },
        sided: if args.two_sided { Sided::Two } else { Sided::One },
        threshold: args.threshold,
        sigma_floor: args.sigma_floor,
        min_area: args.min_area,
        merge: msr_shared::blob::Merge::OFF,
        region: None,
        pool: args.pool,
        pose_grid: None,
        spread_ref: None,
    };
    novelty.check()?;
    ensure!(
        args.pose_bins == 0 || (2..=msr_shared::blob::MAX_POSE_BINS).contains(&args.pose_bins),
        ConfigError::PoseBins { got: args.pose_bins, most: msr_shared::blob::MAX_POSE_BINS }
    );
    let hp = HyperParams {
        epochs: args.epochs,
        batch: args.batch,
        lr: args.lr,
        lr_step: args.lr_step,
        lr_decay: args.lr_decay,
        seed: args.seed,
        ..Default::default()
    };
    hp.check()?;
    // Checked before the training, used after it (an autoencoder takes none: `light_copies`).
    let copies = light_copies::LightCopies { copies: args.light_copies, gradient: args.light_gradient, gamma: args.light_gamma, seed: args.seed };
    copies.check()?;
    let copies = match args.model {
        ModelKind::Decoder => copies,
        ModelKind::Autoencoder => light_copies::LightCopies::NONE,
    };
    let dev = device(args.device)?;

    let ds = Dataset::load(&args.data, args.crop).with_context(|| format!("loading dataset {}", args.data.display()))?;
    // The decoder learns the robot's own face as the mirror shows it at each head pose.
    ensure!(
        ds.other_robot_frames == 0,
        "dataset {} shows another robot in {} frames (a scene with another robot): the decoder \
         learns the robot's own face in the mirror; train on a mirror dataset",
        args.data.display(),
        ds.other_robot_frames
    );
    let (h, w) = ds.face_size();
    let train = samples(ds.split(Split::Train), false);
    let test = samples(ds.split(Split::Test), true);
    ensure!(train.len() >= 2, "dataset {} has {} unmarked training frames; need at least 2", args.data.display(), train.len());
    // The test MSE is the figure training reports; without test frames it would be NaN.
    ensure!(
        !test.is_empty(),
        "dataset {} has no test frames: the test MSE needs some (make it with a test fraction above 0)",
        args.data.display()
    );
    // Fail before training, not after, when the policy has nothing to work on.
    if args.threshold_percentile.is_some() {
        ensure!(
            ds.split(Split::Test).any(|s| s.mark.is_none()),
            ConfigError::NoNormalTestFrames { data: args.data.clone() }
        );
    }
    // The pose grid spans the training poses, so every cell holds about as many frames; each
    // needs at least 2 for a standard deviation. Fail before training, naming the flag.
    let pose_grid = if args.pose_bins > 0 {
        let max_head = train.heads.iter().flatten().fold(0f32, |m, a| m.max(a.abs()));
        let grid = calibrate::pose_grid(args.pose_bins, max_head)?;
        let mut per_cell = vec![0usize; grid.len()];
        for &hd in &train.heads {
            let Some(k) = grid.bin(hd) else { bail!("a training frame has a non-finite head pose {hd:?}") };
            per_cell[k] += 1;
        }
        let fewest = per_cell.iter().copied().min().unwrap_or(0);
        ensure!(
            fewest >= 2,
            ConfigError::FewFramesPerPoseCell {
                pose_bins: args.pose_bins,
                default: calibrate::DEFAULT_POSE_BINS,
                cells: grid.len(),
                data: args.data.clone(),
                fewest,
                total: train.len(),
            }
        );
        Some(grid)
    } else {
        None
    };
    let spec = match (args.arch, args.conv_hidden, args.conv_channels) {
        (ArchKind::Conv, hid, ch) => {
            let d = DecoderSpec::conv(h, w);
            let c = d.conv.as_ref().map_or(4, |c| c.base[0]);
            DecoderSpec::conv_with(h, w, hid.unwrap_or(d.dense[0]), ch.unwrap_or(c))
        }
        (ArchKind::Mlp, None, None) => DecoderSpec::mlp(h, w),
        (ArchKind::Mlp, _, _) => return Err(ConfigError::ConvSizesWithoutConv.into()),
    };
    if !args.quiet {
        eprintln!(
            "training {} ({:?}, {} MACs) on {} frames, testing on {}, face {h}x{w}",
            args.model.name(),
            args.arch,
            spec.macs()?,
            train.len(),
            test.len()
        );
    }
    let _lock = lock_out(&args.out)?;
    let out = Outputs { dir: &args.out, name: args.model.name() };
    let trained = match args.model {
        ModelKind::Decoder => {
            let m = Decoder::new(&spec, hp.seed, &dev.clone().autodiff())?;
            let (m, hist) = fit::fit(m, &train, &test, &hp, &dev.clone().autodiff(), "decoder", !args.quiet)?;
            let m = m.valid();
            out.save_record(m.clone())?;
            (Trained::Decoder(m), hist)
        }
        ModelKind::Autoencoder => {
            let m = Autoencoder::new(&spec, hp.seed, &dev.clone().autodiff())?;
            let (m, hist) = fit::fit(m, &train, &test, &hp, &dev.clone().autodiff(), "autoencoder", !args.quiet)?;
            let m = m.valid();
            out.save_record(m.clone())?;
            (Trained::Autoencoder(m), hist)
        }
    };
    let (model, hist) = trained;
    let net = TrainedModel { info: None, net: model, device: dev.clone() };

    // Statistics over the training frames, with the final model.
    let preds = net.predict_batch(&train.heads, &train.faces);
    let mut novelty = novelty;
    let stats = match pose_grid {
        Some(grid) => {
            let samples = train.heads.iter().zip(&train.faces).zip(&preds).map(|((&hd, f), p)| (hd, &f[..], &p[..]));
            novelty.pose_grid = Some(grid);
            calibrate::error_stats_by_pose(h, w, novelty.pool, &copies, grid, samples)?
        }
        None => calibrate::error_stats(h, w, novelty.pool, &copies, train.faces.iter().map(|f| &f[..]).zip(preds.iter().map(|p| &p[..])))?,
    };
    novelty.spread_ref = Some(calibrate::spread_reference(&stats.spreads));
    if !args.quiet {
        eprintln!(
            "spread reference {:.2} grey levels: the {}th percentile of the frame spreads of the statistics' {} error maps",
            novelty.spread_ref.unwrap_or(0.0),
            100.0 * calibrate::SPREAD_QUANTILE,
            stats.spreads.len()
        );
    }

    let policy = match args.threshold_percentile {
        None => ThresholdPolicy { kind: "fixed".into(), percentile: None, frames: None, n_frames: 0 },
        Some(p) => {
            let normal: Vec<&Sample> = ds.split(Split::Test).filter(|s| s.mark.is_none()).collect();
            ensure!(!normal.is_empty(), ConfigError::NoNormalTestFrames { data: args.data.clone() });
            let heads: Vec<[f32; 2]> = normal.iter().map(|s| s.head).collect();
            let faces: Vec<Vec<f32>> = normal.iter().map(|s| s.face_unit()).collect();
            let preds = net.predict_batch(&heads, &faces);
            let scores: Vec<f64> = faces
                .iter()
                .zip(&preds)
                .zip(&heads)
                .map(|((f, p), &head)| {
                    let (e, [_, floor]) = calibrate::error_map_floor(f, p, w, novelty.pool, novelty.spread_ref);
                    let sal = calibrate::saliency_at(&e, &stats, &novelty, head, floor);
                    calibrate::detection_score(&sal, h, w, novelty.min_area)
                })
                .collect();
            novelty.threshold = calibrate::threshold_from_normal(&scores, p)?;
            if !args.quiet {
                eprintln!("threshold {:.3}: percentile {p} of {} unmarked test frames' detection scores", novelty.threshold, scores.len());
            }
            ThresholdPolicy {
                kind: "percentile".into(),
                percentile: Some(p),
                frames: Some("test split, frames without a mark".into()),
                n_frames: scores.len(),
            }
        }
    };

    let mut files = Files::of(out.name);
    calibrate::write_npy(&args.out.join(&files.mu), h, w, &stats.mu)?;
    calibrate::write_npy(&args.out.join(&files.sigma), h, w, &stats.sigma)?;
    if let Some(p) = &stats.pose {
        let name = format!("{}_pose_stats.npy", out.name);
        let all: Vec<f64> = p.mu.iter().zip(&p.sigma).flat_map(|(m, s)| m.iter().chain(s)).copied().collect();
        calibrate::write_npy(&args.out.join(&name), 2 * p.grid.len() * h, w, &all)?;
        files.pose_stats = Some(name);
    }
    crate::fsio::write_with(&args.out.join(&files.template), |tmp| Ok(ds.template.save(tmp)?))?;
    plot::loss_png(&hist, &format!("{} ({:?})", out.name, args.arch), &args.out.join(&files.loss_png))?;
    let mut info = ModelInfo {
        model: args.model,
        arch: args.arch,
        face_h: h,
        face_w: w,
        crop: args.crop,
        decoder_macs: spec.macs()?,
        spec,
        hyper: hp,
        device: format!("{:?}", args.device).to_lowercase(),
        data: args.data.display().to_string(),
        train_frames: train.len(),
        test_frames: test.len(),
        final_train_mse: hist.train_loss.last().copied().unwrap_or(f64::NAN),
        final_test_mse: hist.test_loss.last().copied().unwrap_or(f64::NAN),
        train_loss: hist.train_loss.clone(),
        test_loss: hist.test_loss.clone(),
        training_seconds: hist.seconds,
        novelty,
        threshold_policy: policy,
        novelty_policy: None,
        general_policy: None,
        stats_frames: stats.frames,
        light_copies: copies,
        files,
        parts: Default::default(),
    };
    for name in info.part_names().into_iter().map(String::from).collect::<Vec<_>>() {
        let crc = msr_shared::blob::CRC32.checksum(&crate::fsio::read(&args.out.join(&name))?);
        info.parts.insert(name, crc);
    }
    let json = args.out.join(format!("{}.json", out.name));
    crate::fsio::write(&json, serde_json::to_string_pretty(&info)?)?;
    println!(
        "{}: {} epochs in {:.1} s, final train MSE {:.5}, test MSE {:.5}, threshold {:.3}; wrote {}",
        out.name,
        hist.train_loss.len(),
        hist.seconds,
        info.final_train_mse,
        info.final_test_mse,
        info.novelty.threshold,
        args.out.display()
    );
    Ok(())
}

struct Outputs<'a> {
    dir: &'a Path,
    name: &'static str,
}

impl Outputs<'_> {
    fn save_record<M: Module>(&self, m: M) -> Result<()> {
        let p = self.dir.join(format!("{}.mpk", self.name));
        crate::fsio::write_with(&p, |tmp| m.save_file(tmp).map_err(|e| anyhow::anyhow!("{e}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_backend_is_a_clear_error() {
        #[cfg(not(feature = "cuda"))]
        assert!(device(DeviceArg::Cuda).unwrap_err().to_string().contains("--features cuda"));
        device(DeviceArg::Cpu).unwrap();
    }

    #[test]
    fn load_refuses_missing_and_mismatched_files() {
        let dir = tempfile::tempdir().unwrap();
        assert!(load(dir.path(), "decoder").unwrap_err().to_string().contains("cannot read"));
        std::fs::write(dir.path().join("decoder.json"), "{}").unwrap();
        assert!(load(dir.path(), "decoder").is_err());
    }
}
