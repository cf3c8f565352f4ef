//! The blob's tables read in place: decoder layers and shapes, the reach network, the template.

use super::{BLOCK, REACH_FLOATS, REACH_HIDDEN, REACH_IN, REACH_OUT};
use core::fmt;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// What a decoder layer computes (descriptor byte 0).
pub enum LayerKind {
    /// Fully connected over the flattened CHW input (kind 0).
    Dense,
    /// PyTorch `ConvTranspose2d`: out = (in - 1) * stride - 2 * padding + kernel (kind 1).
    ConvTranspose2d,
    /// Nearest-neighbour upsampling by `stride`, then a stride-1 convolution.
    UpConv,
    /// Takes an `output`-sized window at (`crop_top`, `crop_left`) of the input; no weights (kind 3).
    Crop,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The function applied to a layer's output (descriptor byte 1).
pub enum Activation {
    /// No function (0); the only one a Crop layer may have.
    Identity,
    /// Hyperbolic tangent (1).
    Tanh,
    /// Logistic sigmoid (2); the last layer's, so the face comes out as grey/255.
    Sigmoid,
    /// `max(0, x)` (3).
    Relu,
}

/// How a layer's weights are ordered in the blob (see the module notes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightOrder {
    /// PyTorch's order.
    Torch,
    /// Dense only: `[y][x][g][c][BLOCK]` over the output pixels, input blocks and channels.
    Blocked,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The integer type of a layer's weights (descriptor byte 2).
pub enum WeightType {
    /// `i8` weights (code 1).
    I8,
    /// Little-endian `i16` weights (code 2).
    I16,
}

impl WeightType {
    /// Bytes per weight.
    pub const fn size(self) -> usize {
        match self {
            WeightType::I8 => 1,
            WeightType::I16 => 2,
        }
    }
}

/// A channels x height x width shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Channels.
    pub c: u16,
    /// Height, pixels.
    pub h: u16,
    /// Width, pixels.
    pub w: u16,
}

impl Shape {
    /// Elements, `c * h * w`.
    pub const fn len(&self) -> usize {
        self.c as usize * self.h as usize * self.w as usize
    }
    /// Whether any dimension is zero.
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// One decoder layer, its tables borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Layer<'a> {
    /// What the layer computes.
    pub kind: LayerKind,
    /// Applied to the output before requantising.
    pub activation: Activation,
    /// `i8` or `i16` weights.
    pub weight_type: WeightType,
    /// Order of the stored weights (see the module notes); [`Layer::weight`] hides it.
    pub order: WeightOrder,
    /// Input shape; the previous layer's output.
    pub input: Shape,
    /// Output shape.
    pub output: Shape,
    /// Kernel size (square), convolutions only.
    pub kernel: u8,
    /// Convolution stride, or the upsampling factor of an UpConv.
    pub stride: u8,
    /// PyTorch-style padding of the convolution.
    pub padding: u8,
    /// First input row a Crop layer keeps.
    pub crop_top: u16,
    /// First input column a Crop layer keeps.
    pub crop_left: u16,
    /// Fraction bits of the weights.
    pub w_shift: i8,
    /// Fraction bits of the i16 input.
    pub in_shift: i8,
    /// Fraction bits of the i16 output.
    pub out_shift: i8,
    /// Raw little-endian weights; see [`Layer::weight`].
    pub weights: &'a [u8],
    /// Raw little-endian i32 biases; see [`Layer::bias`].
    pub bias: &'a [u8],
}

impl<'a> Layer<'a> {
    /// Number of weights.
    pub fn weight_count(&self) -> usize {
        self.weights.len() / self.weight_type.size()
    }

    /// Weight `i` (PyTorch index) as an integer. Panics if out of range, like slice indexing.
    #[inline]
    pub fn weight(&self, i: usize) -> i32 {
        let i = self.stored_index(i);
        match self.weight_type {
            WeightType::I8 => self.weights[i] as i8 as i32,
            WeightType::I16 => {
                i16::from_le_bytes([self.weights[2 * i], self.weights[2 * i + 1]]) as i32
            }
        }
    }

    /// Where weight `i` (PyTorch index) is stored in [`Layer::weights`].
    #[inline]
    pub fn stored_index(&self, i: usize) -> usize {
        match self.order {
            WeightOrder::Torch => i,
            WeightOrder::Blocked => {
                let n_in = self.input.len();
                let (c_n, hw) = (self.output.c as usize, self.output.h as usize * self.output.w as usize);
                let (o, j) = (i / n_in, i % n_in);
                let (c, px) = (o / hw, o % hw);
                ((px * (n_in / BLOCK) + j / BLOCK) * c_n + c) * BLOCK + j % BLOCK
            }
        }
    }

    /// The raw tables ([`Layer::weights_i16`], [`Layer::weights_i8`]) are in PyTorch order.
    pub fn torch_order(&self) -> bool {
        self.order == WeightOrder::Torch
    }

    /// Number of biases (per output element for Dense, per output channel for convolutions).
    pub fn bias_count(&self) -> usize {
        self.bias.len() / 4
    }

    /// Bias `i` (PyTorch index).
    #[inline]
    pub fn bias(&self, i: usize) -> i32 {
        let i = match self.order {
            WeightOrder::Torch => i,
            WeightOrder::Blocked => {
                let hw = self.output.h as usize * self.output.w as usize;
                (i % hw) * self.output.c as usize + i / hw
            }
        };
        let b = &self.bias[4 * i..4 * i + 4];
        i32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// The i16 weights as a slice, when the blob sits 2-byte aligned in memory, in the stored
    /// order (see [`Layer::torch_order`]).
    #[cfg(target_endian = "little")]
    pub fn weights_i16(&self) -> Option<&'a [i16]> {
        match self.weight_type {
            WeightType::I16 => bytemuck::try_cast_slice(self.weights).ok(),
            WeightType::I8 => None,
        }
    }

    /// The i8 weights as a slice, in the stored order.
    pub fn weights_i8(&self) -> Option<&'a [i8]> {
        match self.weight_type {
            WeightType::I8 => Some(bytemuck::cast_slice(self.weights)),
            WeightType::I16 => None,
        }
    }

    /// The biases as a slice, when the blob sits 4-byte aligned in memory, in the stored order.
    #[cfg(target_endian = "little")]
    pub fn bias_i32(&self) -> Option<&'a [i32]> {
        bytemuck::try_cast_slice(self.bias).ok()
    }

    /// Multiply-accumulates of one inference of this layer.
    pub fn macs(&self) -> u64 {
        let k2 = self.kernel as u64 * self.kernel as u64;
        match self.kind {
            LayerKind::Dense => self.input.len() as u64 * self.output.len() as u64,
            LayerKind::ConvTranspose2d => self.input.len() as u64 * self.output.c as u64 * k2,
            LayerKind::UpConv => self.output.len() as u64 * self.input.c as u64 * k2,
            LayerKind::Crop => 0,
        }
    }
}

/// A table of u16 values borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct U16Table<'a>(pub &'a [u8]);

impl<'a> U16Table<'a> {
    /// Number of values.
    pub fn len(&self) -> usize {
        self.0.len() / 2
    }
    /// Whether the table holds no values.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    #[inline]
    /// Value `i`. Panics if out of range, like slice indexing.
    pub fn get(&self, i: usize) -> u16 {
        u16::from_le_bytes([self.0[2 * i], self.0[2 * i + 1]])
    }
    /// The values in order.
    pub fn iter(&self) -> impl Iterator<Item = u16> + 'a {
        self.0.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]]))
    }
}

/// The reach network 2-10-5 (sigmoid, sigmoid) with min-max scaling on both sides. Copied out of
/// the blob: it is small and the firmware runs it in f32.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// Hidden layer weights, `[hidden][input]`.
    pub w1: [[f32; REACH_IN]; REACH_HIDDEN],
    /// Hidden layer biases.
    pub b1: [f32; REACH_HIDDEN],
    /// Output layer weights, `[output][hidden]`.
    pub w2: [[f32; REACH_HIDDEN]; REACH_OUT],
    /// Output layer biases.
    pub b2: [f32; REACH_OUT],
    /// Input value mapped to 0: `u = (v - in_min) / (in_max - in_min)`; pixels.
    pub in_min: [f32; REACH_IN],
    /// Input value mapped to 1; pixels. Each `in_min < in_max`.
    pub in_max: [f32; REACH_IN],
    /// Joint angle for output 0: `angle = o * (out_max - out_min) + out_min`; radians.
    pub out_min: [f32; REACH_OUT],
    /// Joint angle for output 1, radians. Each `out_min < out_max`.
    pub out_max: [f32; REACH_OUT],
}

impl Reach {
    pub(super) fn to_floats(self) -> [f32; REACH_FLOATS] {
        let mut v = [0f32; REACH_FLOATS];
        let mut i = 0;
        let mut put = |x: f32| {
            v[i] = x;
            i += 1;
        };
        self.w1.iter().flatten().for_each(|&x| put(x));
        self.b1.iter().for_each(|&x| put(x));
        self.w2.iter().flatten().for_each(|&x| put(x));
        self.b2.iter().for_each(|&x| put(x));
        self.in_min.iter().for_each(|&x| put(x));
        self.in_max.iter().for_each(|&x| put(x));
        self.out_min.iter().for_each(|&x| put(x));
        self.out_max.iter().for_each(|&x| put(x));
        v
    }

    pub(super) fn from_floats(v: &[f32; REACH_FLOATS]) -> Reach {
        let mut it = v.iter().copied();
        let mut next = || it.next().unwrap_or(0.0);
        let mut r = Reach {
            w1: [[0.0; REACH_IN]; REACH_HIDDEN],
            b1: [0.0; REACH_HIDDEN],
            w2: [[0.0; REACH_HIDDEN]; REACH_OUT],
            b2: [0.0; REACH_OUT],
            in_min: [0.0; REACH_IN],
            in_max: [0.0; REACH_IN],
            out_min: [0.0; REACH_OUT],
            out_max: [0.0; REACH_OUT],
        };
        r.w1.iter_mut().flatten().for_each(|x| *x = next());
        r.b1.iter_mut().for_each(|x| *x = next());
        r.w2.iter_mut().flatten().for_each(|x| *x = next());
        r.b2.iter_mut().for_each(|x| *x = next());
        r.in_min.iter_mut().for_each(|x| *x = next());
        r.in_max.iter_mut().for_each(|x| *x = next());
        r.out_min.iter_mut().for_each(|x| *x = next());
        r.out_max.iter_mut().for_each(|x| *x = next());
        r
    }

    pub(super) fn is_valid(&self) -> bool {
        let v = self.to_floats();
        v.iter().all(|x| x.is_finite())
            && self.in_min.iter().zip(&self.in_max).all(|(a, b)| a < b)
            && self.out_min.iter().zip(&self.out_max).all(|(a, b)| a < b)
    }
}

/// How the host cuts the face out of a camera frame with the model's template.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CropMode {
    /// The published code: the best `TM_CCOEFF` window, in whole pixels.
    #[default]
    Pixel,
    /// The best window refined to a fraction of a pixel and resampled, so that the face does
    /// not jump by a whole pixel between neighbouring head poses.
    Subpixel,
}

impl CropMode {
    /// The name used on the command line and in reports: `"pixel"` or `"subpixel"`.
    pub fn name(self) -> &'static str {
        match self {
            CropMode::Pixel => "pixel",
            CropMode::Subpixel => "subpixel",
        }
    }
}

impl fmt::Display for CropMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl core::str::FromStr for CropMode {
    type Err = &'static str;
    fn from_str(s: &str) -> Result<CropMode, &'static str> {
        match s {
            "pixel" => Ok(CropMode::Pixel),
            "subpixel" => Ok(CropMode::Subpixel),
            _ => Err("expected pixel or subpixel"),
        }
    }
}

/// The face template the host crops with, borrowed from the blob.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Template<'a> {
    /// Template height, pixels.
    pub h: u16,
    /// Template width, pixels.
    pub w: u16,
    /// `h * w` grey bytes, row-major.
    pub pixels: &'a [u8],
    /// How the host crops with it (flag bit 1).
    pub crop: CropMode,
}
