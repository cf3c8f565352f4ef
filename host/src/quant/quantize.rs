//! A trained model into a fixed-point model blob, compared with float.
//!
//! `msr quantize --train DIR --reach FILE [--threshold T] [--weights auto|i8|i16] [--data DIR]
//! --out MODEL.msrm` reads the decoder of a `msr train` output folder (`decoder.json`, `.mpk`,
//! `_mu.npy`, `_sigma.npy`, `template.png`) and a `msr train-reach` network, and writes the blob
//! plus a report `MODEL.msrm.json` (written once the self gate is attached or left out, `train::self_gate::GatedReport`).
//!
//! Fixed point (semantics in `msr_shared::blob`):
//! - the head angles enter with [`HEAD_IN_SHIFT`] fraction bits;
//! - each layer's weight shift is the largest that (a) fits every weight in i16 (or i8) and (b)
//!   keeps the i32 accumulator from wrapping for ANY input the previous layer can produce
//!   (tanh/sigmoid outputs are within +-1, anything else within the i16 range): per output,
//!   `2^(w+in) (sum |W| X + |b|) + rounding slack < 2^31`, where the sum runs over the weights
//!   that can meet in one output (for a transposed convolution, one stride phase of the kernel);
//! - each hidden layer's output shift (15 for tanh/sigmoid unless the search lowers it) trades the
//!   activation's resolution against the next layer's weight bits: starting from 15 everywhere,
//!   one pass tries 10..=15 per hidden layer and keeps the shift with the best PSNR, measured by
//!   running the firmware's own decoder on the calibration head poses;
//! - `--weights auto` (default) takes i16 weights when the i16 blob fits [`AUTO_I16_MAX_BYTES`]
//!   (the board's upload slot): on the Cortex-M4 they are the fast ones (SMLAD takes i16 pairs
//!   directly; i8 needs SXTB16 first, about a third more instructions per MAC). A bigger model
//!   takes i8 when that keeps the PSNR at or above [`PSNR_TARGET_DB`], else i16;
//! - mu and sigma go to Q8.8 grey levels, sigma floored at the training floor (and one Q8.8 step).
//!
//! The report compares float against fixed point, the fixed side always being the firmware's code
//! (`msr_firmware`): PSNR of the predicted faces over the test split's head poses, and, on the test
//! frames, detection agreement (both find nothing, or both find a blob with centroids at most 1 px
//! apart) and the centroid difference. The float side is the trained model with the float
//! statistics and the same novelty settings (`crate::train::calibrate::detect`).
use crate::train::calibrate::{self, ErrorStats, NoveltyParams};
use crate::data::Dataset;
use crate::models::{FloatLayer, float_forward_all};
use crate::models::predictor::FacePredictor;
use crate::train::{self, reach as train_reach};
use anyhow::{bail, ensure, Context, Result};
use msr_shared::blob::{
    Activation, CropMode, LayerKind, LayerSpec, Model, ModelSpec, Novelty, Reach, Weights,
};
use msr_sim::layout::Split;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Head angles go in with 13 fraction bits: +-4 rad covers every Nao head joint limit (every
/// blob, trained or imported).
pub const HEAD_IN_SHIFT: i8 = 13;
/// What the fixed-point faces must keep against float.
pub const PSNR_TARGET_DB: f64 = 40.0;
/// Largest blob `--weights auto` writes with i16 weights: one NUCLEO-F429ZI upload slot
/// (`firmware/nucleo/src/store.rs`), about 6 s over the 921,600-baud host link.
pub const AUTO_I16_MAX_BYTES: usize = 512 * 1024;
/// Accumulator budget: the firmware accumulates in i32; keep headroom for rounding.
const ACC_LIMIT: f64 = 2147483648.0 - 1024.0;
/// Largest magnitude an i16 activation can have.
const I16_MAX_MAG: f64 = 32768.0;

/// How a layer's weight shift is chosen: the two policies the blobs are made with, side by side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShiftPolicy {
    /// `msr import` (the published dense decoder), dense layers only: any i16 value may come
    /// in, whatever the previous activation; per output `2^w (sum_i |W_oi| 2^15 + |b_o| 2^in) +
    /// n_in / 2 < ACC_LIMIT`; shifts 0..=15. Conservative, and what the published blob has
    /// always been made with.
    Published,
    /// `msr quantize` (models trained here, any layer kind): the input is bounded by the
    /// previous layer's activation (tanh/sigmoid within +-1), the sum runs over the weights that
    /// can meet in one output (for a transposed convolution one stride phase), `2^(w+in) (sum
    /// |W| X + max |b|) + slack < ACC_LIMIT`; shifts up to `min(31 - in, 24)`. More weight bits
    /// for the same safety.
    Trained,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
/// The weights' integer type in the blob.
pub enum WeightArg {
    /// i16 if the blob fits a board upload slot (faster on the M4), else i8 if it keeps the
    /// PSNR target, else i16
    Auto,
    /// i8 weights: half the bytes, about a third more instructions per MAC on the M4
    I8,
    /// i16 weights: the fast ones on the M4 (SMLAD takes i16 pairs directly)
    I16,
}

/// What [`quantize`] turns into a blob: `QuantizeConfig::new(train, reach, out)` keeps the
/// training's threshold, picks the weight type by [`WeightArg::Auto`] and reports on the
/// training's dataset.
#[derive(burn::config::Config, Debug)]
pub struct QuantizeConfig {
    /// Output folder of `msr train` (its decoder is quantized).
    pub train: PathBuf,
    /// Reach network from `msr train-reach` (safetensors with its .json scaling beside it).
    pub reach: PathBuf,
    /// The model blob to write (its report goes beside it, `.json` added).
    pub out: PathBuf,
    /// Threshold in saliency units (default: the one chosen at training).
    pub threshold: Option<f64>,
    /// The weights' integer type (default: [`WeightArg::Auto`]).
    #[config(default = "WeightArg::Auto")]
    pub weights: WeightArg,
    /// Dataset for the float-vs-fixed report (default: the one the model was trained on).
    pub data: Option<PathBuf>,
}

/// Largest magnitude of a layer's input that the previous layer can produce.
fn input_bound(prev: Option<Activation>, in_shift: i8) -> f64 {
    let sat = 2f64.powi(15 - in_shift as i32);
    match prev {
        Some(Activation::Tanh) | Some(Activation::Sigmoid) => sat.min(1.0),
        _ => sat,
    }
}

/// `(max |W|, worst sum of |W| meeting in one output, terms in that sum, max |b|)`.
fn weight_sums(l: &FloatLayer) -> (f64, f64, usize, f64) {
    let max_w = l.weights.iter().fold(0f64, |m, &v| m.max((v as f64).abs()));
    let max_b = l.bias.iter().fold(0f64, |m, &v| m.max((v as f64).abs()));
    match l.kind {
        LayerKind::Dense => {
            let n_in = l.input.len();
            let worst = l
                .weights
                .chunks(n_in.max(1))
                .map(|r| r.iter().map(|&v| (v as f64).abs()).sum::<f64>())
                .fold(0f64, f64::max);
            (max_w, worst, n_in, max_b)
        }
        LayerKind::ConvTranspose2d | LayerKind::UpConv => {
            let (ci, co, k) = (l.input.c as usize, l.output.c as usize, l.kernel);
            let s = if l.kind == LayerKind::ConvTranspose2d { l.stride.max(1) } else { 1 };
            let mut worst = 0f64;
            // For ConvTranspose2d, the taps meeting in one output share (kr, kc) modulo stride.
            for o in 0..co {
                for pr in 0..s {
                    for pc in 0..s {
                        let mut sum = 0.0;
                        for i in 0..ci {
                            for kr in (pr..k).step_by(s) {
                                for kc in (pc..k).step_by(s) {
                                    let idx = if l.kind == LayerKind::ConvTranspose2d {
                                        ((i * co + o) * k + kr) * k + kc
                                    } else {
                                        ((o * ci + i) * k + kr) * k + kc
                                    };
                                    sum += (l.weights[idx] as f64).abs();
                                }
                            }
                        }
                        worst = worst.max(sum);
                    }
                }
            }
            let taps = ci * k.div_ceil(s) * k.div_ceil(s);
            (max_w, worst, taps, max_b)
        }
        LayerKind::Crop => (0.0, 0.0, 0, 0.0),
    }
}

/// The largest weight shift that fits the weights and keeps the accumulator safe under `policy`.
fn weight_shift(l: &FloatLayer, in_shift: i8, x_bound: f64, i8w: bool, policy: ShiftPolicy) -> Option<i8> {
    match policy {
        ShiftPolicy::Published => published_shift(l, in_shift),
        ShiftPolicy::Trained => trained_shift(l, in_shift, x_bound, i8w),
    }
}

/// [`ShiftPolicy::Published`]: i16 weights of a dense layer.
fn published_shift(l: &FloatLayer, in_shift: i8) -> Option<i8> {
    if l.kind != LayerKind::Dense {
        return None;
    }
    let n_in = l.input.len();
    let max_w = l.weights.iter().fold(0f64, |m, &v| m.max((v as f64).abs()));
    let worst_row = l
        .weights
        .chunks(n_in.max(1))
        .zip(&l.bias)
        .map(|(row, &b)| {
            row.iter().map(|&v| (v as f64).abs()).sum::<f64>() * I16_MAX_MAG + (b as f64).abs() * 2f64.powi(in_shift as i32)
        })
        .fold(0f64, f64::max);
    (0..=15i8).rev().find(|&s| {
        let k = 2f64.powi(s as i32);
        max_w * k <= i16::MAX as f64 && worst_row * k + 0.5 * n_in as f64 <= ACC_LIMIT
    })
}

/// [`ShiftPolicy::Trained`].
fn trained_shift(l: &FloatLayer, in_shift: i8, x_bound: f64, i8w: bool) -> Option<i8> {
    let (max_w, worst, terms, max_b) = weight_sums(l);
    let w_max = if i8w { 127.0 } else { 32767.0 };
    (0..=(31 - in_shift).min(24)).rev().find(|&s| {
        let k = 2f64.powi(s as i32);
        let acc_scale = 2f64.powi(s as i32 + in_shift as i32);
        // Rounding each weight moves it by at most half a step: 0.5 * |x_q| <= 2^14 per term.
        let slack = terms as f64 * 0.5 * 2f64.powi(15) + 0.5;
        (max_w * k).round() <= w_max && acc_scale * (worst * x_bound + max_b) + slack <= ACC_LIMIT
    })
}

/// Quantizes one layer given its input shift, output shift, weight type and shift policy.
fn quantize_layer(l: &FloatLayer, in_shift: i8, out_shift: i8, x_bound: f64, i8w: bool, policy: ShiftPolicy) -> Result<LayerSpec> {
    l.check()?;
    let u8_of = |v: usize, what: &str| -> Result<u8> { u8::try_from(v).with_context(|| format!("{what} {v} does not fit the blob")) };
    let u16_of = |v: usize, what: &str| -> Result<u16> { u16::try_from(v).with_context(|| format!("{what} {v} does not fit the blob")) };
    let base = LayerSpec {
        kind: l.kind,
        activation: l.activation,
        input: l.input,
        output: l.output,
        kernel: u8_of(l.kernel, "kernel")?,
        stride: u8_of(l.stride, "stride")?,
        padding: u8_of(l.padding, "padding")?,
        crop_top: u16_of(l.crop[0], "crop top")?,
        crop_left: u16_of(l.crop[1], "crop left")?,
        w_shift: 0,
        in_shift,
        out_shift,
        weights: Weights::I16(vec![]),
        bias: vec![],
    };
    if l.kind == LayerKind::Crop {
        // Identity with the same scale on both sides: an exact copy.
        return Ok(LayerSpec { out_shift: in_shift, ..base });
    }
    let w_shift = weight_shift(l, in_shift, x_bound, i8w, policy)
        .with_context(|| format!("{:?} layer {:?} -> {:?}: weights too large for fixed point", l.kind, l.input, l.output))?;
    let kw = 2f64.powi(w_shift as i32);
    let kb = 2f64.powi(w_shift as i32 + in_shift as i32);
    let weights = if i8w {
        Weights::I8(l.weights.iter().map(|&v| (v as f64 * kw).round() as i8).collect())
    } else {
        Weights::I16(l.weights.iter().map(|&v| (v as f64 * kw).round() as i16).collect())
    };
    let bias = l
        .bias
        .iter()
        .map(|&v| {
            let q = (v as f64 * kb).round();
            ensure!(q.abs() < ACC_LIMIT, "bias {v} does not fit the accumulator");
            Ok(q as i32)
        })
        .collect::<Result<Vec<i32>>>()?;
    Ok(LayerSpec { w_shift, weights, bias, ..base })
}

/// Quantizes a trained layer stack ([`ShiftPolicy::Trained`]) with the given output shift per
/// layer (ignored for the last layer, which always writes 15 bits: the face in (0, 1)).
pub fn quantize_with(layers: &[FloatLayer], out_shifts: &[i8], i8w: bool) -> Result<Vec<LayerSpec>> {
    ensure!(!layers.is_empty() && out_shifts.len() == layers.len(), "one output shift per layer");
    let mut shifts = out_shifts.to_vec();
    shifts[layers.len() - 1] = 15;
    quantize_stack(layers, &shifts, i8w, ShiftPolicy::Trained)
}

/// Output fraction bits for an activation: tanh and sigmoid live in (-1, 1), so 15 bits (the
/// value 1.0 itself saturates to 32767/32768); unbounded activations get 8.
pub fn out_shift_for(a: Activation) -> i8 {
    match a {
        Activation::Tanh | Activation::Sigmoid => 15,
        Activation::Identity | Activation::Relu => 8,
    }
}

/// The one quantizer: a layer stack, head angles in with [`HEAD_IN_SHIFT`] fraction bits, each
/// layer with its output shift (`out_shifts`, one per layer), weight type and shift `policy`.
pub fn quantize_stack(layers: &[FloatLayer], out_shifts: &[i8], i8w: bool, policy: ShiftPolicy) -> Result<Vec<LayerSpec>> {
    ensure!(!layers.is_empty() && out_shifts.len() == layers.len(), "one output shift per layer");
    let mut specs = Vec::with_capacity(layers.len());
    let mut in_shift = HEAD_IN_SHIFT;
    let mut prev_act = None;
    for (i, l) in layers.iter().enumerate() {
        let out_shift = out_shifts[i];
        let spec = quantize_layer(l, in_shift, out_shift, input_bound(prev_act, in_shift), i8w, policy)
            .with_context(|| format!("layer {i}"))?;
        in_shift = spec.out_shift;
        if l.kind != LayerKind::Crop {
            prev_act = Some(l.activation);
        }
        specs.push(spec);
    }
    Ok(specs)
}

/// PSNR (dB, peak 255) between two sets of faces in grey levels.
pub fn psnr(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let (mut se, mut n) = (0.0, 0usize);
    for (x, y) in a.iter().zip(b) {
        for (p, q) in x.iter().zip(y) {
            se += (p - q).powi(2);
            n += 1;
        }
    }
    if se == 0.0 {
        return f64::INFINITY;
    }
    10.0 * (255.0f64.powi(2) / (se / n.max(1) as f64)).log10()
}

/// The firmware decoder's faces (grey levels) for the head poses.
pub fn fixed_faces(blob: &[u8], heads: &[[f32; 2]]) -> Result<Vec<Vec<f64>>> {
    let model = Model::parse(blob).map_err(|e| anyhow::anyhow!("blob refused: {e}"))?;
    let mut dec = Box::new(msr_firmware::decoder::Decoder::new());
    heads
        .iter()
        .map(|h| {
            let f = dec.predict_uncached(&model, *h).map_err(|e| anyhow::anyhow!("firmware decoder: {e}"))?;
            Ok(f.iter().map(|&v| v as f64 / 256.0).collect())
        })
        .collect()
}

/// Float faces (grey levels) from the layer stack.
pub fn float_faces(layers: &[FloatLayer], heads: &[[f32; 2]]) -> Vec<Vec<f64>> {
    heads
        .iter()
        .map(|h| float_forward_all(layers, *h).pop().unwrap_or_default().into_iter().map(|v| v * 255.0).collect())
        .collect()
}

/// Everything but the decoder layers.
pub struct Extras {
    /// The face's size in pixels, `(height, width)`.
    pub face: (usize, usize),
    /// The calibrated novelty settings: threshold, pooling, blob rules.
    pub novelty: NoveltyParams,
    /// The prediction error's statistics (mu, sigma per pixel and pose cell), in grey levels.
    pub stats: ErrorStats,
    /// The reach network and its scaling.
    pub reach: Reach,
    /// The face template `(width, height, grey pixels)` the board crops with, if the model has one.
    pub template: Option<(u16, u16, Vec<u8>)>,
    /// How the host crops with the template.
    pub crop: CropMode,
}

/// What goes into a blob beside the decoder, from a training folder: its statistics, novelty
/// settings and face template, with `reach`.
pub fn extras_of(dir: &Path, info: &train::ModelInfo, reach: Reach) -> Result<Extras> {
    let stats = train::load_stats(dir, info)?;
    let tpl_path = dir.join(&info.files.template);
    let tpl = image::open(&tpl_path).with_context(|| format!("cannot read {}", tpl_path.display()))?.to_luma8();
    Ok(Extras {
        face: (info.face_h, info.face_w),
        novelty: info.novelty,
        stats,
        reach,
        template: Some((tpl.height() as u16, tpl.width() as u16, tpl.into_raw())),
        crop: info.crop,
    })
}

/// Grey levels to Q8.8, rounded and saturated: how every blob stores mu and sigma.
pub fn q8_8(v: f64) -> u16 {
    (v * 256.0).round().clamp(0.0, u16::MAX as f64) as u16
}

/// The blob for a layer stack.
pub fn blob_of(layers: Vec<LayerSpec>, x: &Extras) -> Result<Vec<u8>> {
    let p = &x.novelty;
    p.check()?;
    let spec = ModelSpec {
        face_h: x.face.0 as u16,
        face_w: x.face.1 as u16,
        novelty: Novelty {
            threshold: p.threshold as f32,
            normalisation: p.normalisation,
            sided: p.sided,
            min_area: p.min_area,
            sigma_floor: p.sigma_floor as f32,
            merge: p.merge,
            pool: p.pool,
            spread_ref: p.spread_ref.map(|s| s as f32),
        },
        layers,
        mu: x.stats.mu.iter().map(|&v| q8_8(v)).collect(),
        sigma: x.stats.sigma.iter().map(|&v| q8_8(v.max(p.sigma_floor)).max(1)).collect(),
        reach: x.reach,
        region: p.region,
        template: x.template.clone(),
        crop: x.crop,
        pose: x.stats.pose.as_ref().map(|ps| {
            let cells = ps.mu.iter().zip(&ps.sigma).map(|(m, sg)| {
                (m.iter().map(|&v| q8_8(v)).collect(), sg.iter().map(|&v| q8_8(v.max(p.sigma_floor)).max(1)).collect())
            });
            (ps.grid, cells.collect())
        }),
    };
    spec.to_bytes().map_err(|e| anyhow::anyhow!("the quantized model does not make a valid blob: {e}"))
}

/// The chosen quantization and its PSNR on the calibration poses.
pub struct Chosen {
    /// The model blob's bytes.
    pub blob: Vec<u8>,
    /// Each layer's output shift (fraction bits of its output).
    pub out_shifts: Vec<i8>,
    /// Whether the weights are i8 (else i16).
    pub i8_weights: bool,
    /// PSNR (dB) of the fixed-point decoder's faces against float's on the calibration poses.
    pub psnr_db: f64,
    /// PSNR with i8 weights (when tried).
    pub psnr_i8_db: Option<f64>,
}

/// Searches output shifts (and weight type) as described in the module doc.
pub fn choose(layers: &[FloatLayer], x: &Extras, heads: &[[f32; 2]], weights: WeightArg) -> Result<Chosen> {
    choose_within(layers, x, heads, weights, AUTO_I16_MAX_BYTES)
}

/// [`choose`] with the size up to which `Auto` takes i16 weights.
fn choose_within(layers: &[FloatLayer], x: &Extras, heads: &[[f32; 2]], weights: WeightArg, i16_max_bytes: usize) -> Result<Chosen> {
    ensure!(!heads.is_empty(), "no head poses to calibrate on");
    let float = float_faces(layers, heads);
    let search = |i8w: bool| -> Result<(Vec<u8>, Vec<i8>, f64)> {
        let mut shifts = vec![15i8; layers.len()];
        let eval = |shifts: &[i8]| -> Result<(Vec<u8>, f64)> {
            let blob = blob_of(quantize_with(layers, shifts, i8w)?, x)?;
            let p = psnr(&float, &fixed_faces(&blob, heads)?);
            Ok((blob, p))
        };
        let (mut best_blob, mut best) = eval(&shifts)?;
        for i in 0..layers.len().saturating_sub(1) {
            if layers[i].kind == LayerKind::Crop || !matches!(layers[i].activation, Activation::Tanh | Activation::Sigmoid) {
                continue;
            }
            for s in 10..15 {
                let mut t = shifts.clone();
                t[i] = s;
                if let Ok((blob, p)) = eval(&t) {
                    if p > best {
                        (best_blob, best, shifts) = (blob, p, t);
                    }
                }
            }
        }
        Ok((best_blob, shifts, best))
    };
    let mut i16r = None;
    if weights == WeightArg::Auto {
        let (blob, shifts, p) = search(false)?;
        if blob.len() <= i16_max_bytes {
            return Ok(Chosen { blob, out_shifts: shifts, i8_weights: false, psnr_db: p, psnr_i8_db: None });
        }
        i16r = Some((blob, shifts, p));
    }
    let try_i8 = weights != WeightArg::I16;
    let i8r = if try_i8 { Some(search(true)) } else { None };
    if let Some(Ok((blob, shifts, p))) = &i8r {
        if weights == WeightArg::I8 || *p >= PSNR_TARGET_DB {
            return Ok(Chosen { blob: blob.clone(), out_shifts: shifts.clone(), i8_weights: true, psnr_db: *p, psnr_i8_db: Some(*p) });
        }
    }
    if weights == WeightArg::I8 {
        bail!("i8 weights: {}", i8r.map(|r| r.err().map(|e| format!("{e:#}")).unwrap_or_default()).unwrap_or_default());
    }
    let (blob, shifts, p) = match i16r {
        Some(r) => r,
        None => search(false)?,
    };
    let psnr_i8_db = i8r.and_then(|r| r.ok()).map(|r| r.2);
    Ok(Chosen { blob, out_shifts: shifts, i8_weights: false, psnr_db: p, psnr_i8_db })
}

/// The float model against the fixed-point blob: what `MODEL.msrm.json` reports.
#[derive(Serialize, Debug)]
pub struct Report {
    /// The blob's path.
    pub blob: String,
    /// The blob's size in bytes.
    pub blob_bytes: usize,
    /// The blob's CRC-32, hex, as the board reports it.
    pub crc32: String,
    /// The weights' type, `i8` or `i16`.
    pub weights: &'static str,
    /// Each layer's output shift (fraction bits).
    pub out_shifts: Vec<i8>,
    /// Multiply-accumulates of one decoder run.
    pub decoder_macs: u64,
    /// PSNR (dB) of the fixed-point faces against float's over the test split's head poses.
    pub psnr_db: f64,
    /// The same with i8 weights, where they were tried.
    pub psnr_i8_db: Option<f64>,
    /// Head poses the PSNR was measured over.
    pub psnr_poses: usize,
    /// Test frames of the detection comparison.
    pub test_frames: usize,
    /// Fraction of test frames where float and fixed agree (both nothing, or centroids within 1 px).
    pub detection_agreement: f64,
    /// Test frames where float detects a mark.
    pub float_detections: usize,
    /// Test frames where the fixed-point pipeline detects a mark.
    pub fixed_detections: usize,
    /// Largest centroid difference (px) where both detect; `None` if never both.
    pub centroid_diff_px_max: Option<f64>,
    /// Mean centroid difference (px) where both detect.
    pub centroid_diff_px_mean: Option<f64>,
    /// The detection threshold in the blob, in saliency units.
    pub threshold: f64,
    /// The PSNR (dB) that i8 weights must keep to be chosen by `auto`.
    pub psnr_target_db: f64,
    /// The robot of the dataset the report was measured on (`red`, `skin`, or a real robot's
    /// name): the self gate, a later step (`train::self_gate::gate_quantized`), is calibrated on it.
    pub robot: String,
    /// The dataset the report was measured on: the face's colour, a later step
    /// (`train::chroma::colour_quantized`), is learnt from its training frames.
    pub data: String,
}

/// Quantizes, writes the blob and returns the report; the report is written beside the blob
/// (`{out}.json`) once the self gate is attached or left out (`train::self_gate::GatedReport::write`).
pub fn quantize(args: &QuantizeConfig) -> Result<Report> {
    let model = train::load(&args.train, "decoder")
        .with_context(|| format!("loading the trained decoder from {}", args.train.display()))?;
    let info = model.info()?.clone();
    let reach = train_reach::load(&args.reach)?.to_blob()?;
    let mut x = extras_of(&args.train, &info, reach)?;
    if let Some(t) = args.threshold {
        x.novelty.threshold = t;
    }
    x.novelty.check()?;
    let (h, w) = x.face;
    let layers = model.decoder_layers()?;

    let data_path = args.data.clone().unwrap_or_else(|| PathBuf::from(&info.data));
    let ds = Dataset::load_split(&data_path, Some(Split::Test), info.crop)
        .with_context(|| format!("loading the test split of {} for the report", data_path.display()))?;
    ensure!(ds.face_size() == (h, w), "dataset faces are {:?}, the model's are {h}x{w}", ds.face_size());
    ensure!(!ds.samples.is_empty(), "dataset {} has no test frames", data_path.display());
    let heads: Vec<[f32; 2]> = ds.samples.iter().map(|s| s.head).collect();

    let chosen = choose(&layers, &x, &heads, args.weights)?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    crate::fsio::write(&args.out, &chosen.blob)?;

    // Detection, float against the firmware pipeline, on the test frames.
    let blob_model = Model::parse(&chosen.blob).map_err(|e| anyhow::anyhow!("blob refused: {e}"))?;
    let faces: Vec<Vec<f32>> = ds.samples.iter().map(|s| s.face_unit()).collect();
    let preds = model.predict_batch(&heads, &faces);
    let mut ws = Box::new(msr_firmware::Workspace::new());
    let (mut agree, mut nf, mut nq, mut diffs) = (0usize, 0usize, 0usize, Vec::new());
    for ((s, f), p) in ds.samples.iter().zip(&faces).zip(&preds) {
        let novelty = x.novelty.at(s.head);
        let (e, [_, floor]) = calibrate::error_map_floor(f, p, w, novelty.pool, novelty.spread_ref);
        let sal = calibrate::saliency_at(&e, &x.stats, &novelty, s.head, floor);
        let fl = calibrate::detect(&sal, h, w, &novelty);
        let fx = crate::detect::fixed::detect_with(&mut ws, &blob_model, &s.face, s.head)?;
        let fx = fx.blob.map(|b| [b.centroid[0] - s.face.crop.x as f64, b.centroid[1] - s.face.crop.y as f64]);
        nf += fl.is_some() as usize;
        nq += fx.is_some() as usize;
        match (fl, fx) {
            (None, None) => agree += 1,
            (Some(a), Some(b)) => {
                let d = ((a.centroid[0] - b[0]).powi(2) + (a.centroid[1] - b[1]).powi(2)).sqrt();
                agree += (d <= 1.0) as usize;
                diffs.push(d);
            }
            _ => {}
        }
    }
    let report = Report {
        blob: args.out.display().to_string(),
        blob_bytes: chosen.blob.len(),
        crc32: format!("{:08x}", blob_model.crc32),
        weights: if chosen.i8_weights { "i8" } else { "i16" },
        out_shifts: chosen.out_shifts.clone(),
        decoder_macs: blob_model.decoder_macs(),
        psnr_db: chosen.psnr_db,
        psnr_i8_db: chosen.psnr_i8_db,
        psnr_poses: heads.len(),
        test_frames: ds.samples.len(),
        detection_agreement: agree as f64 / ds.samples.len() as f64,
        float_detections: nf,
        fixed_detections: nq,
        centroid_diff_px_max: diffs.iter().copied().reduce(f64::max),
        centroid_diff_px_mean: (!diffs.is_empty()).then(|| diffs.iter().sum::<f64>() / diffs.len() as f64),
        threshold: x.novelty.threshold,
        psnr_target_db: PSNR_TARGET_DB,
        robot: ds.robot.clone(),
        data: data_path.display().to_string(),
    };
    Ok(report)
}

/// Used by tests and other tools: a blob straight from float layers with default shifts.
pub fn quantize_default(layers: &[FloatLayer], x: &Extras) -> Result<Vec<u8>> {
    blob_of(quantize_with(layers, &vec![15; layers.len()], false)?, x)
}


#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::{Decoder, DecoderSpec};
    use burn::prelude::*;
    use msr_shared::blob::{Merge, Normalisation, PoseRegion, Sided};

    fn extras(h: usize, w: usize) -> Extras {
        let reach = Reach::from_parts(&[0.1; 20], &[0.0; 10], &[0.1; 50], &[0.0; 5], [0.0; 2], [1.0; 2], [0.0; 5], [1.0; 5]).unwrap();
        Extras {
            face: (h, w),
            novelty: NoveltyParams { normalisation: Normalisation::StdDev, sided: Sided::One, ..Default::default() },
            stats: ErrorStats { h, w, mu: vec![3.0; h * w], sigma: vec![2.0; h * w], frames: 10, pose: None, spreads: Vec::new() },
            reach,
            template: None,
            crop: CropMode::Pixel,
        }
    }

    fn heads() -> Vec<[f32; 2]> {
        (0..25).map(|i| [((i % 5) as f32 - 2.0) * 0.04, ((i / 5) as f32 - 2.0) * 0.04]).collect()
    }

    #[test]
    fn conv_and_mlp_round_trip_through_the_firmware_decoder() {
        let dev = Device::flex();
        for spec in [DecoderSpec::conv(20, 27), DecoderSpec::mlp(20, 27)] {
            let layers = Decoder::new(&spec, 5, &dev).unwrap().float_layers().unwrap();
            let x = extras(20, 27);
            let c = choose(&layers, &x, &heads(), WeightArg::I16).unwrap();
            assert!(!c.i8_weights);
            assert!(c.psnr_db > 50.0, "{:?}: {:.1} dB", spec.kind(), c.psnr_db);
            let m = Model::parse(&c.blob).unwrap();
            assert_eq!(m.layers.len(), layers.len());
            assert_eq!((m.face_h, m.face_w), (20, 27));
            // The statistics went to Q8.8.
            assert_eq!(m.mu.get(0), 3 * 256);
            assert_eq!(m.sigma.get(0), 2 * 256);
        }
    }

    #[test]
    fn auto_takes_i16_when_the_blob_fits_a_slot() {
        let dev = Device::flex();
        let layers = Decoder::new(&DecoderSpec::conv(20, 27), 5, &dev).unwrap().float_layers().unwrap();
        let c = choose(&layers, &extras(20, 27), &heads(), WeightArg::Auto).unwrap();
        assert!(!c.i8_weights);
        assert!(c.blob.len() <= AUTO_I16_MAX_BYTES);
        let i16 = choose(&layers, &extras(20, 27), &heads(), WeightArg::I16).unwrap();
        assert_eq!(c.blob, i16.blob);
    }

    #[test]
    fn the_pose_region_and_crop_mode_reach_the_blob() {
        let dev = Device::flex();
        let layers = Decoder::new(&DecoderSpec::conv(20, 27), 5, &dev).unwrap().float_layers().unwrap();
        let mut x = extras(20, 27);
        let region = PoseRegion { centre: [0.0, 0.0], radius: 0.01, threshold: 2.5, merge: Merge { margin: 4, fragment: 2 } };
        x.novelty.region = Some(region);
        x.template = Some((2, 2, vec![9; 4]));
        x.crop = CropMode::Subpixel;
        let c = choose(&layers, &x, &heads(), WeightArg::I16).unwrap();
        let m = Model::parse(&c.blob).unwrap();
        assert_eq!(m.region, Some(region));
        assert_eq!(m.template.map(|t| t.crop), Some(CropMode::Subpixel));
        // A region the blob cannot hold is refused before any blob is written.
        x.novelty.region = Some(PoseRegion { radius: 0.0, ..region });
        assert!(choose(&layers, &x, &heads(), WeightArg::I16).is_err());
    }

    #[test]
    fn auto_takes_i8_for_a_big_blob_only_when_it_keeps_the_psnr() {
        let dev = Device::flex();
        let layers = Decoder::new(&DecoderSpec::conv(20, 27), 5, &dev).unwrap().float_layers().unwrap();
        // A slot smaller than the i16 blob: the old rule decides.
        let c = choose_within(&layers, &extras(20, 27), &heads(), WeightArg::Auto, 1000).unwrap();
        let p8 = c.psnr_i8_db.unwrap();
        assert_eq!(c.i8_weights, p8 >= PSNR_TARGET_DB, "i8 at {p8:.1} dB");
        if c.i8_weights {
            assert_eq!(c.blob, choose(&layers, &extras(20, 27), &heads(), WeightArg::I8).unwrap().blob);
        }
    }

    #[test]
    fn accumulator_bound_holds_for_worst_case_inputs() {
        // A dense layer whose row sums are large: the chosen shift must keep the worst input safe.
        let l = FloatLayer {
            kind: LayerKind::Dense,
            activation: Activation::Tanh,
            input: msr_shared::blob::Shape { c: 64, h: 1, w: 1 },
            output: msr_shared::blob::Shape { c: 2, h: 1, w: 1 },
            kernel: 0,
            stride: 0,
            padding: 0,
            crop: [0, 0],
            weights: (0..128).map(|i| if i % 2 == 0 { 3.0 } else { -3.0 }).collect(),
            bias: vec![5.0, -5.0],
        };
        let s = quantize_layer(&l, 15, 15, 1.0, false, ShiftPolicy::Trained).unwrap();
        let Weights::I16(w) = &s.weights else { panic!() };
        // Worst input: +-32767 matching each weight's sign.
        for o in 0..2 {
            let acc: i64 = s.bias[o] as i64 + w[o * 64..(o + 1) * 64].iter().map(|&v| v as i64 * 32767 * (v as i64).signum()).sum::<i64>();
            assert!(acc.abs() < i32::MAX as i64, "acc {acc}");
        }
        // Weights beyond i16 even at shift 0 are an error, not a wrap.
        let mut big = l.clone();
        big.weights[0] = 1e6;
        assert!(quantize_layer(&big, 15, 15, 1.0, false, ShiftPolicy::Trained).is_err());
    }

    #[test]
    fn psnr_by_hand() {
        let a = vec![vec![0.0, 0.0]];
        let b = vec![vec![2.55, 2.55]];
        assert!((psnr(&a, &b) - 40.0).abs() < 1e-9);
        assert_eq!(psnr(&a, &a), f64::INFINITY);
    }
}
