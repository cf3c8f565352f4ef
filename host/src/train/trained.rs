//! A trained model read back from its output folder: the network on a device, and its statistics.
use super::calibrate::{self, ErrorStats};
use super::{ModelInfo, ModelKind};
use crate::models::predictor::FacePredictor;
use crate::models::{Autoencoder, Decoder, DecoderSpec, FloatLayer};
use anyhow::{bail, ensure, Context, Result};
use burn::prelude::*;
use std::path::Path;

/// A trained network, on an inference device.
#[derive(Debug)]
pub enum Trained {
    /// A decoder: head angles to face.
    Decoder(Decoder),
    /// An autoencoder: face to face.
    Autoencoder(Autoencoder),
}

/// A trained model loaded for inference; a [`FacePredictor`].
#[derive(Debug)]
pub struct TrainedModel {
    /// None only while training.
    pub info: Option<ModelInfo>,
    /// The network.
    pub net: Trained,
    /// The device it runs on.
    pub device: Device,
}

impl TrainedModel {
    /// Its description, or an error for a model still in training.
    pub fn info(&self) -> Result<&ModelInfo> {
        self.info.as_ref().context("model has no info")
    }

    /// The decoder's layers in plain floats (the autoencoder's decoder for an autoencoder).
    pub fn decoder_layers(&self) -> Result<Vec<FloatLayer>> {
        match &self.net {
            Trained::Decoder(d) => d.float_layers(),
            Trained::Autoencoder(a) => a.decoder.float_layers(),
        }
    }

    fn spec(&self) -> &DecoderSpec {
        match &self.net {
            Trained::Decoder(d) => &d.spec,
            Trained::Autoencoder(a) => &a.decoder.spec,
        }
    }
}

impl FacePredictor for TrainedModel {
    fn face_size(&self) -> (usize, usize) {
        let s = self.spec();
        (s.face_h, s.face_w)
    }

    fn predict(&self, head: [f32; 2], face: &[f32]) -> Vec<f32> {
        self.predict_batch(&[head], &[face.to_vec()]).pop().unwrap_or_default()
    }

    /// Batches of 256. Faces are only read by the autoencoder; a face of the wrong size gives
    /// an all-NaN prediction rather than a panic.
    fn predict_batch(&self, heads: &[[f32; 2]], faces: &[Vec<f32>]) -> Vec<Vec<f32>> {
        let (h, w) = self.face_size();
        let n = h * w;
        let mut out = Vec::with_capacity(heads.len());
        for start in (0..heads.len()).step_by(256) {
            let end = (start + 256).min(heads.len());
            let b = end - start;
            let preds: Result<Vec<f32>> = match &self.net {
                Trained::Decoder(d) => {
                    let v: Vec<f32> = heads[start..end].iter().flatten().copied().collect();
                    let x = Tensor::<2>::from_data(TensorData::new(v, [b, 2]), &self.device);
                    crate::models::tensor_vec(d.forward(x))
                }
                Trained::Autoencoder(a) => {
                    let rows = &faces[start..end.min(faces.len())];
                    if rows.len() != b || rows.iter().any(|f| f.len() != n) {
                        Err(anyhow::anyhow!("faces missing or of the wrong size"))
                    } else {
                        let v: Vec<f32> = rows.iter().flatten().copied().collect();
                        let x = Tensor::<2>::from_data(TensorData::new(v, [b, n]), &self.device);
                        crate::models::tensor_vec(a.forward(x))
                    }
                }
            };
            match preds {
                Ok(p) if p.len() == b * n => out.extend(p.chunks(n).map(|c| c.to_vec())),
                _ => out.extend((0..b).map(|_| vec![f32::NAN; n])),
            }
        }
        out
    }
}

/// Loads `{name}.json` and `{name}.mpk` from a training output folder onto the CPU.
pub fn load(dir: &Path, name: &str) -> Result<TrainedModel> {
    load_on(dir, name, Device::flex())
}

/// [`load`] onto `device`.
pub fn load_on(dir: &Path, name: &str, device: Device) -> Result<TrainedModel> {
    let json = dir.join(format!("{name}.json"));
    let text = std::fs::read_to_string(&json).with_context(|| format!("cannot read {}", json.display()))?;
    let info: ModelInfo = serde_json::from_str(&text).with_context(|| format!("{} is not a model description", json.display()))?;
    ensure!(info.model.name() == name, "{} describes a {}, not a {name}", json.display(), info.model.name());
    ensure!(
        info.spec.face_h == info.face_h && info.spec.face_w == info.face_w,
        "{}: face size disagrees with the architecture",
        json.display()
    );
    let record_path = dir.join(&info.files.record);
    info.check_part(dir, &info.files.record)?;
    let record = burn::store::ModuleRecord::load(&record_path)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", record_path.display()))?;
    let net = match info.model {
        ModelKind::Decoder => Trained::Decoder(
            Decoder::new(&info.spec, 0, &device)?
                .try_load_record(record)
                .map_err(|e| anyhow::anyhow!("{} does not fit {}: {e}", record_path.display(), json.display()))?,
        ),
        ModelKind::Autoencoder => Trained::Autoencoder(
            Autoencoder::new(&info.spec, 0, &device)?
                .try_load_record(record)
                .map_err(|e| anyhow::anyhow!("{} does not fit {}: {e}", record_path.display(), json.display()))?,
        ),
    };
    Ok(TrainedModel { info: Some(info), net, device })
}

/// The error statistics saved beside a model.
pub fn load_stats(dir: &Path, info: &ModelInfo) -> Result<ErrorStats> {
    for name in info.part_names() {
        info.check_part(dir, name)?;
    }
    let (h, w, mu) = calibrate::read_npy(&dir.join(&info.files.mu))?;
    let (h2, w2, sigma) = calibrate::read_npy(&dir.join(&info.files.sigma))?;
    ensure!(
        (h, w) == (info.face_h, info.face_w) && (h2, w2) == (h, w),
        "statistics are {h}x{w} and {h2}x{w2}, the model's face is {}x{}",
        info.face_h,
        info.face_w
    );
    let pose = match (&info.novelty.pose_grid, &info.files.pose_stats) {
        (None, None) => None,
        (Some(grid), Some(file)) => {
            let (ph, pw, all) = calibrate::read_npy(&dir.join(file))?;
            let k = grid.len();
            ensure!(
                grid.is_valid() && (ph, pw) == (2 * k * h, w),
                "{file} is {ph}x{pw}, the pose grid {:?} needs {}x{w}",
                grid.bins,
                2 * k * h
            );
            let mut tables = all.chunks_exact(h * w).map(|t| t.to_vec());
            let (mut mu_k, mut sigma_k) = (Vec::new(), Vec::new());
            while let (Some(m), Some(s)) = (tables.next(), tables.next()) {
                mu_k.push(m);
                sigma_k.push(s);
            }
            Some(calibrate::PoseErrorStats { grid: *grid, mu: mu_k, sigma: sigma_k, frames: Vec::new() })
        }
        _ => bail!("{}: a pose grid needs its statistics file and the other way round", info.files.mu),
    };
    // The frames' spreads are not stored: the model's reference is in its novelty settings.
    Ok(ErrorStats { h, w, mu, sigma, frames: info.stats_frames, pose, spreads: Vec::new() })
}
