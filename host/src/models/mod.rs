//! The face models in burn: decoders (head angles -> face) and the autoencoder (face -> 2-d code ->
//! face), plus their export to plain float layers in the model blob's layouts.
//!
//! A decoder is described by a [`DecoderSpec`] (stored in the model's JSON), so a saved record can
//! be rebuilt and every layer maps one-to-one onto a blob layer kind: Dense, ConvTranspose2d, Crop.
//! Activations: tanh inside, sigmoid on the last layer (as the paper and the published code).
pub mod act;
pub mod dense;
pub mod predictor;
use anyhow::{bail, ensure, Result};
use burn::module::Param;
use burn::nn::conv::{ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use msr_shared::blob::{Activation, LayerKind, Shape, MAX_ACTIVATION_LEN};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Which decoder family.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ArchKind {
    /// Small convolutional decoder (dense, then transposed convolutions), cheap on a Cortex-M4.
    Conv,
    /// The published fully connected 2-12-64-128-(h*w) decoder.
    Mlp,
}

/// Transposed-convolution stack of a conv decoder.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConvStack {
    /// Shape `[c, h, w]` the last dense layer's output is reshaped to.
    pub base: [usize; 3],
    /// Output channels of each ConvTranspose2d stage (the last is 1).
    pub channels: Vec<usize>,
    /// Side of every stage's square kernel, pixels.
    pub kernel: usize,
    /// Upsampling step of every stage, pixels.
    pub stride: usize,
    /// Pixels every stage trims from each side of its output (PyTorch's `padding`).
    pub padding: usize,
    /// Top-left corner of the face window cut from the last stage's output.
    pub crop: [usize; 2],
}

/// Everything needed to rebuild a decoder's layers.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DecoderSpec {
    /// Height of the predicted face, pixels.
    pub face_h: usize,
    /// Width of the predicted face, pixels.
    pub face_w: usize,
    /// Widths of the dense layers after the 2 inputs. Without a conv stack the last is h*w.
    pub dense: Vec<usize>,
    /// The transposed convolutions after the dense layers; `None` for an MLP decoder.
    pub conv: Option<ConvStack>,
}

/// Output size of a ConvTranspose2d along one axis.
pub fn deconv_out(n: usize, kernel: usize, stride: usize, padding: usize) -> usize {
    ((n - 1) * stride + kernel).saturating_sub(2 * padding)
}

impl DecoderSpec {
    /// The published decoder: 2-12-64-128-(h*w), tanh x3, sigmoid.
    pub fn mlp(face_h: usize, face_w: usize) -> Self {
        DecoderSpec { face_h, face_w, dense: vec![12, 64, 128, face_h * face_w], conv: None }
    }

    /// The default conv decoder: 2-32 dense (tanh), 32-(4 x h/2 x w/2) dense (tanh), then a
    /// ConvTranspose2d (kernel 4, stride 2, padding 1) to one channel at full size (sigmoid) and
    /// a centred crop. About 0.21 M multiply-accumulates for a 58 x 75 face (the published MLP
    /// needs 0.57 M). Measured on a 1300-frame sim dataset against deeper stacks within the same
    /// budget (three transposed convolutions 8-6-4-1 from 8 x h/8 x w/8: 0.29 M MACs), it reached
    /// a lower training MSE (0.0096 against 0.0126) and trained about twice as fast.
    pub fn conv(face_h: usize, face_w: usize) -> Self {
        Self::conv_with(face_h, face_w, 32, 4)
    }

    /// The conv family: `hidden` dense units, `channels` feature maps at half size.
    pub fn conv_with(face_h: usize, face_w: usize, hidden: usize, channels: usize) -> Self {
        let (bh, bw) = (face_h.div_ceil(2), face_w.div_ceil(2));
        let base = [channels, bh, bw];
        DecoderSpec {
            face_h,
            face_w,
            dense: vec![hidden, base.iter().product()],
            conv: Some(ConvStack {
                base,
                channels: vec![1],
                kernel: 4,
                stride: 2,
                padding: 1,
                crop: [(2 * bh - face_h) / 2, (2 * bw - face_w) / 2],
            }),
        }
    }

    /// The default decoder of family `kind` for a `face_h` x `face_w` face.
    pub fn new(kind: ArchKind, face_h: usize, face_w: usize) -> Self {
        match kind {
            ArchKind::Conv => Self::conv(face_h, face_w),
            ArchKind::Mlp => Self::mlp(face_h, face_w),
        }
    }

    /// The family: conv when the spec has a conv stack.
    pub fn kind(&self) -> ArchKind {
        if self.conv.is_some() {
            ArchKind::Conv
        } else {
            ArchKind::Mlp
        }
    }

    /// The blob layers this spec becomes (shapes only), checked against the blob's limits.
    pub fn layer_shapes(&self) -> Result<Vec<(LayerKind, Activation, Shape, Shape)>> {
        let sh = |c: usize, h: usize, w: usize| -> Result<Shape> {
            ensure!(
                c <= u16::MAX as usize && h <= u16::MAX as usize && w <= u16::MAX as usize,
                "layer size {c}x{h}x{w} does not fit the blob"
            );
            Ok(Shape { c: c as u16, h: h as u16, w: w as u16 })
        };
        ensure!(self.face_h > 0 && self.face_w > 0, "face size must not be zero");
        ensure!(!self.dense.is_empty(), "a decoder needs at least one dense layer");
        let mut out = Vec::new();
        let mut prev = sh(2, 1, 1)?;
        let n_deconv = self.conv.as_ref().map_or(0, |c| c.channels.len());
        for (i, &width) in self.dense.iter().enumerate() {
            let last = i + 1 == self.dense.len() && n_deconv == 0;
            let o = if i + 1 == self.dense.len() {
                match &self.conv {
                    Some(c) => {
                        ensure!(
                            c.base.iter().product::<usize>() == width,
                            "last dense width {width} is not the conv base {:?}",
                            c.base
                        );
                        sh(c.base[0], c.base[1], c.base[2])?
                    }
                    None => {
                        ensure!(
                            width == self.face_h * self.face_w,
                            "last dense width {width} is not the face size {}x{}",
                            self.face_h,
                            self.face_w
                        );
                        sh(1, self.face_h, self.face_w)?
                    }
                }
            } else {
                sh(width, 1, 1)?
            };
            let act = if last { Activation::Sigmoid } else { Activation::Tanh };
            out.push((LayerKind::Dense, act, prev, o));
            prev = o;
        }
        if let Some(c) = &self.conv {
            ensure!(c.kernel > 0 && c.stride > 0, "conv kernel and stride must be positive");
            ensure!(c.channels.last() == Some(&1), "the last conv stage must have 1 channel");
            for (i, &ch) in c.channels.iter().enumerate() {
                let h = deconv_out(prev.h as usize, c.kernel, c.stride, c.padding);
                let w = deconv_out(prev.w as usize, c.kernel, c.stride, c.padding);
                let last = i + 1 == c.channels.len();
                let act = if last { Activation::Sigmoid } else { Activation::Tanh };
                let o = sh(ch, h, w)?;
                out.push((LayerKind::ConvTranspose2d, act, prev, o));
                prev = o;
            }
            ensure!(
                c.crop[0] + self.face_h <= prev.h as usize && c.crop[1] + self.face_w <= prev.w as usize,
                "conv output {}x{} is too small for the face {}x{} at crop {:?}",
                prev.h,
                prev.w,
                self.face_h,
                self.face_w,
                c.crop
            );
            let o = sh(1, self.face_h, self.face_w)?;
            out.push((LayerKind::Crop, Activation::Identity, prev, o));
        }
        for (i, (_, _, _, o)) in out.iter().enumerate() {
            ensure!(
                i + 1 == out.len() || o.len() <= MAX_ACTIVATION_LEN,
                "layer {i} output has {} elements, the board's limit is {MAX_ACTIVATION_LEN}",
                o.len()
            );
        }
        Ok(out)
    }

    /// Multiply-accumulates of one inference.
    pub fn macs(&self) -> Result<u64> {
        let mut k2 = 1u64;
        if let Some(c) = &self.conv {
            k2 = (c.kernel * c.kernel) as u64;
        }
        Ok(self
            .layer_shapes()?
            .iter()
            .map(|(kind, _, i, o)| match kind {
                LayerKind::Dense => (i.len() * o.len()) as u64,
                LayerKind::ConvTranspose2d => i.len() as u64 * o.c as u64 * k2,
                _ => 0,
            })
            .sum())
    }
}

/// PyTorch's default initialisation, U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for weights and biases,
/// drawn from a seeded ChaCha stream so training is reproducible whatever the backend.
fn uniform(rng: &mut ChaCha8Rng, n: usize, fan_in: usize) -> Vec<f32> {
    let b = 1.0 / (fan_in as f32).sqrt();
    (0..n).map(|_| rng.gen_range(-b..b)).collect()
}

fn linear(rng: &mut ChaCha8Rng, d_in: usize, d_out: usize, device: &Device) -> Linear {
    let mut l = LinearConfig::new(d_in, d_out).init(device);
    // burn stores Linear weights as [in, out].
    let w = Tensor::<2>::from_data(TensorData::new(uniform(rng, d_in * d_out, d_in), [d_in, d_out]), device);
    let b = Tensor::<1>::from_data(TensorData::new(uniform(rng, d_out, d_in), [d_out]), device);
    l.weight = Param::from_tensor(w);
    l.bias = Some(Param::from_tensor(b));
    l
}

fn deconv(rng: &mut ChaCha8Rng, c_in: usize, c_out: usize, s: &ConvStack, device: &Device) -> ConvTranspose2d {
    let k = s.kernel;
    let mut d = ConvTranspose2dConfig::new([c_in, c_out], [k, k])
        .with_stride([s.stride, s.stride])
        .with_padding([s.padding, s.padding])
        .init(device);
    // PyTorch's fan_in for ConvTranspose2d weights [in, out, k, k] is out * k * k.
    let fan_in = c_out * k * k;
    let w = Tensor::<4>::from_data(
        TensorData::new(uniform(rng, c_in * c_out * k * k, fan_in), [c_in, c_out, k, k]),
        device,
    );
    let b = Tensor::<1>::from_data(TensorData::new(uniform(rng, c_out, fan_in), [c_out]), device);
    d.weight = Param::from_tensor(w);
    d.bias = Some(Param::from_tensor(b));
    d
}

/// A decoder: head angles `[B, 2]` -> faces `[B, h*w]` in (0, 1).
#[derive(Module, Debug)]
pub struct Decoder {
    /// The dense layers, first to last.
    pub dense: Vec<Linear>,
    /// The transposed convolutions after them (empty for an MLP).
    pub deconv: Vec<ConvTranspose2d>,
    /// The spec the layers were built from.
    #[module(skip)]
    pub spec: DecoderSpec,
}

impl Decoder {
    /// The layers `spec` describes, initialised as PyTorch does from a stream seeded `seed`.
    pub fn new(spec: &DecoderSpec, seed: u64, device: &Device) -> Result<Self> {
        spec.layer_shapes()?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut dense = Vec::new();
        let mut d_in = 2;
        for &w in &spec.dense {
            dense.push(linear(&mut rng, d_in, w, device));
            d_in = w;
        }
        let mut deconvs = Vec::new();
        if let Some(c) = &spec.conv {
            let mut c_in = c.base[0];
            for &ch in &c.channels {
                deconvs.push(deconv(&mut rng, c_in, ch, c, device));
                c_in = ch;
            }
        }
        Ok(Decoder { dense, deconv: deconvs, spec: spec.clone() })
    }

    /// Head angles `[B, 2]` (radians) -> predicted faces `[B, h*w]`, grey levels in (0, 1).
    pub fn forward(&self, heads: Tensor<2>) -> Tensor<2> {
        let [b, _] = heads.dims();
        let n_dense = self.dense.len();
        let mut x = heads;
        for (i, l) in self.dense.iter().enumerate() {
            x = l.forward(x);
            x = if i + 1 == n_dense && self.deconv.is_empty() { act::sigmoid(x) } else { act::tanh(x) };
        }
        let Some(c) = &self.spec.conv else {
            return x;
        };
        let mut y: Tensor<4> = x.reshape([b, c.base[0], c.base[1], c.base[2]]);
        let n = self.deconv.len();
        for (i, l) in self.deconv.iter().enumerate() {
            y = l.forward(y);
            y = if i + 1 == n { act::sigmoid(y) } else { act::tanh(y) };
        }
        let (h, w) = (self.spec.face_h, self.spec.face_w);
        let [t, l] = c.crop;
        y.slice([0..b, 0..1, t..t + h, l..l + w]).reshape([b, h * w])
    }

    /// The layers as plain floats in the blob's layouts (see [`FloatLayer`]).
    pub fn float_layers(&self) -> Result<Vec<FloatLayer>> {
        let shapes = self.spec.layer_shapes()?;
        let mut out = Vec::new();
        let mut params = self
            .dense
            .iter()
            .map(|l| {
                // burn's [in, out] -> PyTorch's [out, in].
                let w = l.weight.val().transpose();
                (to_vec(w.into_data()), l.bias.as_ref().map(|b| to_vec(b.val().into_data())))
            })
            .chain(self.deconv.iter().map(|l| {
                (to_vec(l.weight.val().into_data()), l.bias.as_ref().map(|b| to_vec(b.val().into_data())))
            }));
        let c = self.spec.conv.as_ref();
        for (kind, activation, input, output) in shapes {
            let (kernel, stride, padding) = match (kind, c) {
                (LayerKind::ConvTranspose2d, Some(c)) => (c.kernel, c.stride, c.padding),
                _ => (0, 0, 0),
            };
            let (weights, bias, crop) = if kind == LayerKind::Crop {
                (vec![], vec![], c.map_or([0, 0], |c| c.crop))
            } else {
                let (w, b) = params.next().ok_or_else(|| anyhow::anyhow!("decoder has fewer layers than its spec"))?;
                let n_bias = if kind == LayerKind::Dense { output.len() } else { output.c as usize };
                (w?, b.transpose()?.unwrap_or_else(|| vec![0.0; n_bias]), [0, 0])
            };
            out.push(FloatLayer { kind, activation, input, output, kernel, stride, padding, crop, weights, bias });
        }
        Ok(out)
    }
}

/// A tensor's values as f32, row-major.
pub fn tensor_vec<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>> {
    to_vec(t.into_data())
}

fn to_vec(d: TensorData) -> Result<Vec<f32>> {
    d.convert::<f32>().try_into_vec::<f32>().map_err(|e| anyhow::anyhow!("tensor data: {e:?}"))
}

/// Encoder of the autoencoder: (h*w) -> 128 -> 64 -> 12 -> 2, tanh inside, no activation on the code.
pub const ENCODER_WIDTHS: [usize; 4] = [128, 64, 12, 2];

/// The autoencoder: faces -> 2-d codes -> faces, the decoder taking the code in place of the
/// head angles.
#[derive(Module, Debug)]
pub struct Autoencoder {
    /// The dense layers of [`ENCODER_WIDTHS`], first to last.
    pub encoder: Vec<Linear>,
    /// The decoder from the code back to the face.
    pub decoder: Decoder,
}

impl Autoencoder {
    /// The encoder and a decoder of `spec`, initialised as PyTorch does from `seed`.
    pub fn new(spec: &DecoderSpec, seed: u64, device: &Device) -> Result<Self> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_e4c0);
        let mut encoder = Vec::new();
        let mut d_in = spec.face_h * spec.face_w;
        for w in ENCODER_WIDTHS {
            encoder.push(linear(&mut rng, d_in, w, device));
            d_in = w;
        }
        Ok(Autoencoder { encoder, decoder: Decoder::new(spec, seed, device)? })
    }

    /// Faces `[B, h*w]` -> 2-d codes `[B, 2]`.
    pub fn encode(&self, faces: Tensor<2>) -> Tensor<2> {
        let n = self.encoder.len();
        let mut x = faces;
        for (i, l) in self.encoder.iter().enumerate() {
            x = l.forward(x);
            if i + 1 < n {
                x = act::tanh(x);
            }
        }
        x
    }

    /// Faces `[B, h*w]` -> their reconstructions `[B, h*w]`, grey levels in (0, 1).
    pub fn forward(&self, faces: Tensor<2>) -> Tensor<2> {
        self.decoder.forward(self.encode(faces))
    }
}

/// One layer in plain floats, in the model blob's layouts (PyTorch's): Dense `[out][in]`,
/// ConvTranspose2d `[in_c][out_c][k][k]`; bias per output element (Dense) or channel (conv).
#[derive(Clone, Debug, PartialEq)]
pub struct FloatLayer {
    /// What the layer computes: Dense, ConvTranspose2d, Crop...
    pub kind: LayerKind,
    /// The function applied to its output.
    pub activation: Activation,
    /// Shape of its input (channels, height, width).
    pub input: Shape,
    /// Shape of its output (channels, height, width).
    pub output: Shape,
    /// Convolutions only: side of the square kernel, pixels (0 otherwise).
    pub kernel: usize,
    /// Convolutions only: the upsampling factor (0 otherwise).
    pub stride: usize,
    /// Convolutions only: PyTorch's `padding`, pixels (0 otherwise).
    pub padding: usize,
    /// Crop only: top, left.
    pub crop: [usize; 2],
    /// The weights in the layout above (empty for a crop).
    pub weights: Vec<f32>,
    /// The biases, one per output element (Dense) or channel (conv); empty for a crop.
    pub bias: Vec<f32>,
}

impl FloatLayer {
    /// Checks the weight and bias counts against the shapes.
    pub fn check(&self) -> Result<()> {
        let (nw, nb) = match self.kind {
            LayerKind::Dense => (self.input.len() * self.output.len(), self.output.len()),
            LayerKind::ConvTranspose2d | LayerKind::UpConv => (
                self.input.c as usize * self.output.c as usize * self.kernel * self.kernel,
                self.output.c as usize,
            ),
            LayerKind::Crop => (0, 0),
        };
        if self.weights.len() != nw || self.bias.len() != nb {
            bail!(
                "{:?} layer {:?} -> {:?}: {} weights and {} biases, expected {nw} and {nb}",
                self.kind,
                self.input,
                self.output,
                self.weights.len(),
                self.bias.len()
            );
        }
        if self.weights.iter().chain(&self.bias).any(|v| !v.is_finite()) {
            bail!("{:?} layer has non-finite weights", self.kind);
        }
        Ok(())
    }

    /// Runs the layer in f64 on one CHW input (reference semantics for quantization).
    pub fn forward(&self, x: &[f64]) -> Vec<f64> {
        let pre = match self.kind {
            LayerKind::Dense => {
                let n_in = self.input.len();
                (0..self.output.len())
                    .map(|o| {
                        let row = &self.weights[o * n_in..(o + 1) * n_in];
                        self.bias[o] as f64 + row.iter().zip(x).map(|(&w, &v)| w as f64 * v).sum::<f64>()
                    })
                    .collect()
            }
            LayerKind::ConvTranspose2d => deconv_f64(self, x),
            LayerKind::UpConv => upconv_f64(self, x),
            LayerKind::Crop => {
                let (ih, iw) = (self.input.h as usize, self.input.w as usize);
                let (oh, ow) = (self.output.h as usize, self.output.w as usize);
                let mut y = Vec::with_capacity(self.output.len());
                for c in 0..self.output.c as usize {
                    for r in 0..oh {
                        let start = c * ih * iw + (r + self.crop[0]) * iw + self.crop[1];
                        y.extend_from_slice(&x[start..start + ow]);
                    }
                }
                y
            }
        };
        pre.into_iter().map(|v| activate(self.activation, v)).collect()
    }
}

/// A layer's activation in float, the one definition: f64 for the quantizer's reference, f32
/// for the imported published decoder.
pub fn activate<T: num_traits::Float>(a: Activation, v: T) -> T {
    match a {
        Activation::Identity => v,
        Activation::Tanh => v.tanh(),
        Activation::Sigmoid => T::one() / (T::one() + (-v).exp()),
        Activation::Relu => v.max(T::zero()),
    }
}

fn deconv_f64(l: &FloatLayer, x: &[f64]) -> Vec<f64> {
    let (ci, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (co, oh, ow) = (l.output.c as usize, l.output.h as usize, l.output.w as usize);
    let (k, s, p) = (l.kernel, l.stride, l.padding as isize);
    let mut y = vec![0.0; co * oh * ow];
    for o in 0..co {
        y[o * oh * ow..(o + 1) * oh * ow].fill(l.bias[o] as f64);
    }
    for i in 0..ci {
        for r in 0..ih {
            for c in 0..iw {
                let v = x[i * ih * iw + r * iw + c];
                for o in 0..co {
                    for kr in 0..k {
                        let yr = (r * s + kr) as isize - p;
                        if yr < 0 || yr >= oh as isize {
                            continue;
                        }
                        for kc in 0..k {
                            let yc = (c * s + kc) as isize - p;
                            if yc < 0 || yc >= ow as isize {
                                continue;
                            }
                            let w = l.weights[((i * co + o) * k + kr) * k + kc] as f64;
                            y[o * oh * ow + yr as usize * ow + yc as usize] += w * v;
                        }
                    }
                }
            }
        }
    }
    y
}

fn upconv_f64(l: &FloatLayer, x: &[f64]) -> Vec<f64> {
    let (ci, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (co, oh, ow) = (l.output.c as usize, l.output.h as usize, l.output.w as usize);
    let (k, s, p) = (l.kernel, l.stride, l.padding as isize);
    let (uh, uw) = (ih * s, iw * s);
    let mut y = vec![0.0; co * oh * ow];
    for o in 0..co {
        for r in 0..oh {
            for c in 0..ow {
                let mut acc = l.bias[o] as f64;
                for i in 0..ci {
                    for kr in 0..k {
                        let ur = r as isize + kr as isize - p;
                        if ur < 0 || ur >= uh as isize {
                            continue;
                        }
                        for kc in 0..k {
                            let uc = c as isize + kc as isize - p;
                            if uc < 0 || uc >= uw as isize {
                                continue;
                            }
                            let v = x[i * ih * iw + (ur as usize / s) * iw + uc as usize / s];
                            acc += l.weights[((o * ci + i) * k + kr) * k + kc] as f64 * v;
                        }
                    }
                }
                y[o * oh * ow + r * ow + c] = acc;
            }
        }
    }
    y
}

/// Runs a whole float layer list on one head pose; returns every layer's output.
pub fn float_forward_all(layers: &[FloatLayer], head: [f32; 2]) -> Vec<Vec<f64>> {
    let mut x = vec![head[0] as f64, head[1] as f64];
    let mut outs = Vec::with_capacity(layers.len());
    for l in layers {
        x = l.forward(&x);
        outs.push(x.clone());
    }
    outs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conv_spec_fits_the_board_and_is_cheaper_than_the_mlp() {
        let conv = DecoderSpec::conv(58, 75);
        let shapes = conv.layer_shapes().unwrap();
        assert_eq!(shapes.last().unwrap().3, Shape { c: 1, h: 58, w: 75 });
        assert_eq!(shapes.last().unwrap().0, LayerKind::Crop);
        let macs = conv.macs().unwrap();
        let mlp = DecoderSpec::mlp(58, 75).macs().unwrap();
        assert_eq!(mlp, 2 * 12 + 12 * 64 + 64 * 128 + 128 * 4350);
        assert!(macs < 300_000 && macs < mlp, "conv {macs} MACs, mlp {mlp}");
        assert_eq!(macs, 2 * 32 + 32 * 4 * 29 * 38 + 4 * 29 * 38 * 16);
        // Odd sizes still crop inside the last stage's output.
        DecoderSpec::conv(1, 1).layer_shapes().unwrap();
        DecoderSpec::conv(64, 96).layer_shapes().unwrap();
    }

    #[test]
    fn bad_specs_are_refused() {
        let mut s = DecoderSpec::conv(58, 75);
        s.dense[1] += 1;
        assert!(s.layer_shapes().is_err());
        let mut s = DecoderSpec::conv(58, 75);
        s.conv.as_mut().unwrap().crop = [10, 0];
        assert!(s.layer_shapes().is_err());
        let mut s = DecoderSpec::mlp(58, 75);
        s.dense[3] = 100;
        assert!(s.layer_shapes().is_err());
        // 8 x 29 x 38 is over the board's activation limit.
        assert!(DecoderSpec::conv_with(58, 75, 32, 8).layer_shapes().is_err());
    }

    #[test]
    fn burn_forward_matches_the_exported_float_layers() {
        let device = Device::flex();
        for spec in [DecoderSpec::conv(13, 21), DecoderSpec::mlp(13, 21)] {
            let dec = Decoder::new(&spec, 7, &device).unwrap();
            let heads = [[0.05f32, -0.03], [-0.08, 0.02]];
            let x = Tensor::<2>::from_data(TensorData::new(heads.concat(), [2, 2]), &device);
            let y = to_vec(dec.forward(x).into_data()).unwrap();
            assert_eq!(y.len(), 2 * 13 * 21);
            let layers = dec.float_layers().unwrap();
            layers.iter().for_each(|l| l.check().unwrap());
            for (b, h) in heads.iter().enumerate() {
                let r = float_forward_all(&layers, *h).pop().unwrap();
                let got = &y[b * 273..(b + 1) * 273];
                let err = r.iter().zip(got).map(|(a, &g)| (a - g as f64).abs()).fold(0.0, f64::max);
                assert!(err < 1e-5, "{:?}: burn and reference differ by {err}", spec.kind());
                assert!(r.iter().all(|v| *v > 0.0 && *v < 1.0));
            }
        }
    }

    #[test]
    fn same_seed_same_weights() {
        let device = Device::flex();
        let spec = DecoderSpec::conv(10, 10);
        let a = Decoder::new(&spec, 3, &device).unwrap().float_layers().unwrap();
        let b = Decoder::new(&spec, 3, &device).unwrap().float_layers().unwrap();
        let c = Decoder::new(&spec, 4, &device).unwrap().float_layers().unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn autoencoder_shapes() {
        let device = Device::flex();
        let ae = Autoencoder::new(&DecoderSpec::conv(12, 16), 1, &device).unwrap();
        let x = Tensor::<2>::zeros([3, 12 * 16], &device);
        assert_eq!(ae.encode(x.clone()).dims(), [3, 2]);
        assert_eq!(ae.forward(x).dims(), [3, 12 * 16]);
    }
}
