//! Importing the published model (safetensors decoder and reach network, .npy error
//! statistics, face template, threshold) -> a fixed-point model blob the firmware runs.
//!
//! The manifest (`shared/data/nao-red-real/manifest.json`) names every file and tensor; nothing is
//! assumed beyond it. Weights are PyTorch `Linear` (`W` is `[out, in]`), which is the blob's Dense
//! layout, so they go in without transposing.
use crate::data::crop::load_grey;
use crate::data::npy;
use crate::models::predictor::FacePredictor;
use crate::models::FloatLayer;
pub use crate::models::dense::{Dense, DenseDecoder};
use crate::quant::quantize::{out_shift_for, q8_8, quantize_stack, ShiftPolicy};
use anyhow::{bail, ensure, Context, Result};
use image::GrayImage;
use msr_shared::blob::{
    Activation, CropMode, LayerSpec, ModelSpec, Normalisation, Novelty, Reach, Shape, Sided,
    REACH_HIDDEN, REACH_IN, REACH_OUT,
};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// What [`import`] reads and writes: `ImportConfig::new(manifest, out)` keeps the manifest's
/// threshold and the published code's two-sided saliency.
#[derive(burn::config::Config, Debug)]
pub struct ImportConfig {
    /// The published manifest.json.
    pub manifest: PathBuf,
    /// Where to write the model blob.
    pub out: PathBuf,
    /// Threshold on the saliency (sigma units); default: the manifest's training threshold (4.59).
    pub threshold: Option<f32>,
    /// Saliency |e - mu| / sigma (two, the published code) or (e - mu) / sigma (one).
    #[config(default = "Sided::Two")]
    pub sided: Sided,
}

/// What [`import`] wrote and how close its fixed point is to the float decoder.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ImportReport {
    /// Size of the blob written, bytes.
    pub blob_bytes: usize,
    /// The decoder's layer widths, input first (`2-12-64-128-4350`).
    pub arch: String,
    /// Layers of the decoder.
    pub layers: usize,
    /// Per layer `w_shift.in_shift->out_shift`.
    pub shifts: Vec<String>,
    /// Face width, pixels.
    pub face_w: usize,
    /// Face height, pixels.
    pub face_h: usize,
    /// The blob's saliency threshold, sigma units.
    pub threshold: f32,
    /// The blob's smallest detection, pixels.
    pub min_area: u16,
    /// Head poses the fidelity was measured over.
    pub poses: usize,
    /// PSNR of the fixed-point decoder against the float one (peak 255), dB.
    pub psnr_db: f64,
    /// Largest absolute difference between the two decoders' faces, grey levels.
    pub max_abs_grey: f64,
}

/// Imports the published model into a blob at `out`.
pub fn import(args: &ImportConfig) -> Result<ImportReport> {
    let mut model = Published::load(&args.manifest)?;
    if let Some(t) = args.threshold {
        ensure!(
            t.is_finite() && t > 0.0,
            "threshold {t} must be a positive number"
        );
        model.threshold = t;
    }
    model.sided = args.sided;
    let spec = model.to_spec()?;
    let bytes = spec
        .to_bytes()
        .map_err(|e| anyhow::anyhow!("the blob does not validate: {e}"))?;
    crate::fsio::write(&args.out, &bytes)?;
    let shifts: Vec<String> = spec
        .layers
        .iter()
        .map(|l| format!("{}.{}->{}", l.w_shift, l.in_shift, l.out_shift))
        .collect();
    let heads = model.head_angles.clone().unwrap_or_else(grid_heads);
    let (psnr, max_abs) = fidelity(&bytes, &model.decoder, &heads)?;
    Ok(ImportReport {
        blob_bytes: bytes.len(),
        arch: model.decoder.arch().to_string(),
        layers: spec.layers.len(),
        shifts,
        face_w: model.decoder.face_w as usize,
        face_h: model.decoder.face_h as usize,
        threshold: model.threshold,
        min_area: model.min_area,
        poses: heads.len(),
        psnr_db: psnr,
        max_abs_grey: max_abs,
    })
}

/// A 21 x 21 grid over +-5 degrees, when the manifest lists no head angles.
fn grid_heads() -> Vec<[f32; 2]> {
    let d = 5f32.to_radians();
    (0..21 * 21)
        .map(|i| {
            [
                -d + d * (i % 21) as f32 / 10.0,
                -d + d * (i / 21) as f32 / 10.0,
            ]
        })
        .collect()
}

/// How far the firmware's fixed-point decoder is from the float one: PSNR (peak 255) and the
/// largest absolute difference, in grey levels, over `heads`.
pub fn fidelity(blob: &[u8], float: &DenseDecoder, heads: &[[f32; 2]]) -> Result<(f64, f64)> {
    let model = msr_shared::blob::Model::parse(blob).map_err(|e| anyhow::anyhow!("blob: {e}"))?;
    let mut dec = Box::new(msr_firmware::decoder::Decoder::new());
    let (mut se, mut n, mut max_abs) = (0f64, 0usize, 0f64);
    for &h in heads {
        let want = float.predict(h, &[]);
        let got = dec
            .predict_uncached(&model, h)
            .map_err(|e| anyhow::anyhow!("firmware decoder: {e}"))?;
        for (g, w) in got.iter().zip(&want) {
            let d = *g as f64 / 256.0 - *w as f64 * 255.0;
            se += d * d;
            max_abs = max_abs.max(d.abs());
            n += 1;
        }
    }
    ensure!(n > 0, "no head poses to compare");
    let mse = se / n as f64;
    Ok((10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10(), max_abs))
}

// ---------------------------------------------------------------------------------------------
// The manifest (only what import needs).

#[derive(Deserialize, Debug)]
struct Manifest {
    face_crop: ManifestCrop,
    decoder: ManifestDecoder,
    error_statistics: ManifestStats,
    novelty: ManifestNovelty,
    reach: ManifestReach,
    head_angles: Option<ManifestAngles>,
}

#[derive(Deserialize, Debug)]
struct ManifestAngles {
    file: String,
}

/// "HeadYaw,HeadPitch" rows, radians, no header.
fn read_angles(path: &Path) -> Result<Vec<[f32; 2]>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let v: Vec<f32> = line
            .split(',')
            .map(|x| x.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .ok()
            .filter(|v: &Vec<f32>| v.len() == 2 && v.iter().all(|a| a.is_finite()))
            .with_context(|| {
                format!(
                    "{} line {}: expected two finite angles",
                    path.display(),
                    i + 1
                )
            })?;
        out.push([v[0], v[1]]);
    }
    Ok(out)
}

#[derive(Deserialize, Debug)]
struct ManifestCrop {
    template: String,
    width: u32,
    height: u32,
}

#[derive(Deserialize, Debug)]
struct ManifestDecoder {
    weights: String,
    layers: Vec<ManifestLayer>,
}

#[derive(Deserialize, Debug)]
struct ManifestLayer {
    weight: String,
    bias: String,
    shape: [usize; 2],
    activation: String,
}

#[derive(Deserialize, Debug)]
struct ManifestStats {
    mu: String,
    sigma: String,
    shape: [usize; 2],
}

#[derive(Deserialize, Debug)]
struct ManifestNovelty {
    threshold_training: f32,
    min_blob_area: u16,
}

#[derive(Deserialize, Debug)]
struct ManifestReach {
    weights: String,
    layers: Vec<ManifestLayer>,
    input_min: [f32; REACH_IN],
    input_max: [f32; REACH_IN],
    output_min: [f32; REACH_OUT],
    output_max: [f32; REACH_OUT],
}

/// The published model, as float.
#[derive(Clone, Debug)]
pub struct Published {
    /// The decoder's dense layers.
    pub decoder: DenseDecoder,
    /// Mean error per pixel, grey levels, row-major.
    pub mu: Vec<f64>,
    /// Standard deviation of the error per pixel, grey levels, row-major.
    pub sigma: Vec<f64>,
    /// The face template the crops are matched against.
    pub template: GrayImage,
    /// The reach network with its scaling.
    pub reach: Reach,
    /// Saliency threshold, sigma units (the manifest's training threshold unless overridden).
    pub threshold: f32,
    /// Two-sided (the published code) or one-sided saliency.
    pub sided: Sided,
    /// Smallest blob that counts as a detection, pixels.
    pub min_area: u16,
    /// The recorded head angles of the training frames, when the manifest lists them.
    pub head_angles: Option<Vec<[f32; 2]>>,
}

impl Published {
    /// Reads everything the manifest names; every missing file, tensor or mismatched shape is an
    /// error that says which.
    pub fn load(manifest: &Path) -> Result<Published> {
        let text = std::fs::read_to_string(manifest)
            .with_context(|| format!("cannot read manifest {}", manifest.display()))?;
        let m: Manifest = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a valid model manifest", manifest.display()))?;
        let dir = manifest.parent().unwrap_or(Path::new("."));

        let tensors = Tensors::open(&dir.join(&m.decoder.weights))?;
        let layers = dense_stack(&tensors, &m.decoder.layers)?;
        let (h, w) = (m.error_statistics.shape[0], m.error_statistics.shape[1]);
        let out = layers.last().map(|l| l.n_out).unwrap_or(0);
        ensure!(
            out == h * w,
            "decoder output has {out} values, the face ({h}x{w}) has {}",
            h * w
        );
        ensure!(
            layers[0].n_in == 2,
            "decoder input has {} values, expected 2 head angles",
            layers[0].n_in
        );
        ensure!(
            (m.face_crop.height as usize, m.face_crop.width as usize) == (h, w),
            "face crop {}x{} and error statistics {w}x{h} disagree",
            m.face_crop.width,
            m.face_crop.height
        );
        let decoder = DenseDecoder {
            layers,
            face_h: h,
            face_w: w,
        };

        let mu = npy::read_shaped(&dir.join(&m.error_statistics.mu), (h, w))?;
        let sigma = npy::read_shaped(&dir.join(&m.error_statistics.sigma), (h, w))?;
        ensure!(
            mu.iter().chain(&sigma).all(|v| v.is_finite() && *v >= 0.0),
            "error statistics hold negative or non-finite values"
        );
        // The blob holds sigma in Q8.8: anything under one step would be stored as one step, and a
        // zero sigma makes every error at that pixel a mark (the published code divides by
        // sigma + 1e-5). Real statistics sit far above it (the published sigma's least is 0.14).
        let spath = dir.join(&m.error_statistics.sigma);
        let tiny = sigma.iter().filter(|&&v| v < SIGMA_FLOOR as f64).count();
        ensure!(
            tiny == 0,
            "sigma {}: {tiny} of {} values are below 1/256 grey level (one Q8.8 step, the \
             least the blob holds); a zero sigma would mark every pixel with any error",
            spath.display(),
            sigma.len()
        );

        let tpath = dir.join(&m.face_crop.template);
        let template = load_grey(&tpath)?;
        ensure!(
            template.dimensions() == (w as u32, h as u32),
            "template {} is {}x{}, the face is {w}x{h}",
            tpath.display(),
            template.width(),
            template.height()
        );

        let rt = Tensors::open(&dir.join(&m.reach.weights))?;
        let r = dense_stack(&rt, &m.reach.layers)?;
        ensure!(
            r.len() == 2
                && (r[0].n_in, r[0].n_out, r[1].n_out) == (REACH_IN, REACH_HIDDEN, REACH_OUT),
            "reach network must be {REACH_IN}-{REACH_HIDDEN}-{REACH_OUT}"
        );
        ensure!(
            r.iter().all(|l| l.act == Activation::Sigmoid),
            "reach network layers must be sigmoid"
        );
        let reach = Reach::from_parts(
            &r[0].w,
            &r[0].b,
            &r[1].w,
            &r[1].b,
            m.reach.input_min,
            m.reach.input_max,
            m.reach.output_min,
            m.reach.output_max,
        )
        .map_err(|e| anyhow::anyhow!("reach network: {e}"))?;
        ensure!(
            m.novelty.min_blob_area > 0,
            "min_blob_area must be at least 1"
        );

        Ok(Published {
            decoder,
            mu,
            sigma,
            template,
            reach,
            threshold: m.novelty.threshold_training,
            sided: Sided::Two,
            min_area: m.novelty.min_blob_area,
            head_angles: match &m.head_angles {
                Some(h) => Some(read_angles(&dir.join(&h.file))?),
                None => None,
            },
        })
    }

    /// The blob contents: decoder in fixed point, statistics in Q8.8, reach and template as they are.
    pub fn to_spec(&self) -> Result<ModelSpec> {
        let (h, w) = (self.decoder.face_h, self.decoder.face_w);
        Ok(ModelSpec {
            face_h: h as u16,
            face_w: w as u16,
            novelty: Novelty {
                threshold: self.threshold,
                normalisation: Normalisation::StdDev,
                sided: self.sided,
                min_area: self.min_area,
                sigma_floor: SIGMA_FLOOR,
                merge: msr_shared::blob::Merge::OFF,
                pool: 0,
                // The published statistics' frames are not known: a frame's whole spread counts.
                spread_ref: Some(0.0),
            },
            layers: quantize_dense_stack(&self.decoder.layers, (h, w))?,
            mu: self.mu.iter().map(|&v| q8_8(v)).collect(),
            // The published code divides by sigma + 1e-5; the floor keeps it off zero in Q8.8.
            sigma: self.sigma.iter().map(|&v| q8_8(v + 1e-5).max(1)).collect(),
            reach: self.reach,
            region: None,
            template: Some((h as u16, w as u16, self.template.as_raw().clone())),
            // The published statistics were measured on whole-pixel crops.
            crop: CropMode::Pixel,
            pose: None,
        })
    }
}

/// One Q8.8 step: the smallest sigma the blob can hold.
pub const SIGMA_FLOOR: f32 = 1.0 / 256.0;

/// The safetensors file of one network.
struct Tensors {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl Tensors {
    fn open(path: &Path) -> Result<Tensors> {
        let bytes = std::fs::read(path)
            .with_context(|| format!("cannot read weights {}", path.display()))?;
        safetensors::SafeTensors::deserialize(&bytes)
            .with_context(|| format!("{} is not a valid safetensors file", path.display()))?;
        Ok(Tensors {
            path: path.to_path_buf(),
            bytes,
        })
    }

    /// A tensor as f32 with its shape; f64 and f16-free files only.
    fn get(&self, name: &str) -> Result<(Vec<usize>, Vec<f32>)> {
        let st = safetensors::SafeTensors::deserialize(&self.bytes)?;
        let t = st
            .tensor(name)
            .map_err(|_| anyhow::anyhow!("{}: tensor `{name}` is missing", self.path.display()))?;
        let data = t.data();
        let v: Vec<f32> = match t.dtype() {
            safetensors::Dtype::F32 => data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            safetensors::Dtype::F64 => data
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32)
                .collect(),
            d => bail!(
                "{}: tensor `{name}` is {d}, expected F32 or F64",
                self.path.display()
            ),
        };
        ensure!(
            v.iter().all(|x| x.is_finite()),
            "{}: tensor `{name}` holds non-finite values",
            self.path.display()
        );
        Ok((t.shape().to_vec(), v))
    }
}

/// Reads the layers the manifest lists, checking shapes and that each takes the previous output.
fn dense_stack(t: &Tensors, layers: &[ManifestLayer]) -> Result<Vec<Dense>> {
    ensure!(
        !layers.is_empty(),
        "{}: the manifest lists no layers",
        t.path.display()
    );
    let mut out: Vec<Dense> = Vec::new();
    for (i, l) in layers.iter().enumerate() {
        let (ws, w) = t.get(&l.weight)?;
        let (bs, b) = t.get(&l.bias)?;
        let [n_out, n_in] = l.shape;
        ensure!(
            ws == [n_out, n_in],
            "{}: tensor `{}` has shape {ws:?}, the manifest says {:?}",
            t.path.display(),
            l.weight,
            l.shape
        );
        ensure!(
            bs == [n_out],
            "{}: tensor `{}` has shape {bs:?}, expected [{n_out}]",
            t.path.display(),
            l.bias
        );
        if let Some(prev) = out.last() {
            ensure!(
                prev.n_out == n_in,
                "layer {i} (`{}`) takes {n_in} inputs but layer {} gives {}",
                l.weight,
                i - 1,
                prev.n_out
            );
        }
        let act = match l.activation.as_str() {
            "tanh" => Activation::Tanh,
            "sigmoid" => Activation::Sigmoid,
            "relu" => Activation::Relu,
            "identity" | "linear" | "none" => Activation::Identity,
            a => bail!("layer {i}: unknown activation `{a}`"),
        };
        out.push(Dense {
            n_in,
            n_out,
            w,
            b,
            act,
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Fixed point for a stack of dense layers.

/// The published dense stack in fixed point: the one quantizer with
/// [`ShiftPolicy::Published`], i16 weights, each layer's output shift by its activation; the
/// last layer must produce `face` (h, w).
pub fn quantize_dense_stack(layers: &[Dense], face: (usize, usize)) -> Result<Vec<LayerSpec>> {
    let last = layers.last().context("no layers to quantize")?;
    ensure!(
        last.n_out == face.0 * face.1,
        "last layer gives {} values, the face has {}",
        last.n_out,
        face.0 * face.1
    );
    let float: Vec<FloatLayer> = layers
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let out = if i + 1 == layers.len() {
                Shape { c: 1, h: face.0 as u16, w: face.1 as u16 }
            } else {
                Shape { c: l.n_out as u16, h: 1, w: 1 }
            };
            l.to_float_layer(out)
        })
        .collect();
    let shifts: Vec<i8> = layers.iter().map(|l| out_shift_for(l.act)).collect();
    quantize_stack(&float, &shifts, false, ShiftPolicy::Published)
}

#[cfg(test)]
mod tests {
    use super::*;
    use msr_shared::blob::Weights;
    use rand::{Rng, SeedableRng};

    fn random_stack(rng: &mut impl Rng, sizes: &[usize], scale: f32) -> Vec<Dense> {
        sizes
            .windows(2)
            .enumerate()
            .map(|(i, p)| Dense {
                n_in: p[0],
                n_out: p[1],
                w: (0..p[0] * p[1])
                    .map(|_| rng.gen_range(-scale..scale))
                    .collect(),
                b: (0..p[1]).map(|_| rng.gen_range(-scale..scale)).collect(),
                act: if i + 2 == sizes.len() {
                    Activation::Sigmoid
                } else {
                    Activation::Tanh
                },
            })
            .collect()
    }

    #[test]
    fn shifts_keep_every_accumulator_in_i32_and_weights_close() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for scale in [0.05f32, 0.5, 3.0, 20.0] {
            let layers = random_stack(&mut rng, &[2, 12, 64, 128, 6 * 8], scale);
            let specs = quantize_dense_stack(&layers, (6, 8)).unwrap();
            for (i, (l, q)) in layers.iter().zip(&specs).enumerate() {
                let Weights::I16(wq) = &q.weights else {
                    panic!("i16 expected")
                };
                // Worst case over any i16 input: |bias| + sum |w| * 32768 must stay in i32.
                for o in 0..l.n_out {
                    let worst: i64 = q.bias[o].unsigned_abs() as i64
                        + wq[o * l.n_in..(o + 1) * l.n_in]
                            .iter()
                            .map(|&w| (w as i64).abs() * 32768)
                            .sum::<i64>();
                    assert!(
                        worst < i32::MAX as i64,
                        "scale {scale} layer {i} row {o}: {worst}"
                    );
                }
                let step = 2f32.powi(-(q.w_shift as i32));
                for (w, &k) in l.w.iter().zip(wq) {
                    assert!((w - k as f32 * step).abs() <= step / 2.0 + 1e-7);
                }
                if i > 0 {
                    assert_eq!(q.in_shift, specs[i - 1].out_shift);
                }
            }
            // The result is a blob the board accepts.
            assert!(specs.len() == 4 && specs[3].output == Shape { c: 1, h: 6, w: 8 });
        }
    }

    #[test]
    fn wrong_face_size_is_an_error() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let layers = random_stack(&mut rng, &[2, 4, 10], 0.5);
        assert!(quantize_dense_stack(&layers, (3, 4)).is_err());
    }

    #[test]
    fn q8_8_rounds_and_saturates() {
        assert_eq!(q8_8(1.0), 256);
        assert_eq!(q8_8(0.144), 37);
        assert_eq!(q8_8(-1.0), 0);
        assert_eq!(q8_8(1e9), u16::MAX);
    }
}
