//! The float dense layers of the published model and of a blob's dequantized weights: a fully
//! connected layer in PyTorch's `Linear` layout and a decoder made of them.
use super::predictor::FacePredictor;
use super::FloatLayer;
use msr_shared::blob::{Activation, LayerKind, Shape};

/// A fully connected layer, PyTorch `Linear` layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    /// Inputs.
    pub n_in: usize,
    /// Outputs.
    pub n_out: usize,
    /// `[out][in]`, row-major.
    pub w: Vec<f32>,
    /// One bias per output.
    pub b: Vec<f32>,
    /// The function applied to each output.
    pub act: Activation,
}

impl Dense {
    /// The layer in the quantizer's form, writing `output` (a vector, or the face for the
    /// last layer).
    pub fn to_float_layer(&self, output: Shape) -> FloatLayer {
        FloatLayer {
            kind: LayerKind::Dense,
            activation: self.act,
            input: Shape { c: self.n_in as u16, h: 1, w: 1 },
            output,
            kernel: 0,
            stride: 0,
            padding: 0,
            crop: [0, 0],
            weights: self.w.clone(),
            bias: self.b.clone(),
        }
    }

    /// The layer's `n_out` outputs for the `n_in` inputs `x`, activated.
    pub fn forward(&self, x: &[f32]) -> Vec<f32> {
        (0..self.n_out)
            .map(|o| {
                let row = &self.w[o * self.n_in..(o + 1) * self.n_in];
                let z = self.b[o] + row.iter().zip(x).map(|(w, x)| w * x).sum::<f32>();
                super::activate(self.act, z)
            })
            .collect()
    }
}


/// A fully connected decoder from [HeadYaw, HeadPitch] to a face (the published 2-12-64-128-4350).
#[derive(Clone, Debug, PartialEq)]
pub struct DenseDecoder {
    /// The layers, first to last; the last gives the face's `face_h * face_w` pixels.
    pub layers: Vec<Dense>,
    /// Height of the predicted face, pixels.
    pub face_h: usize,
    /// Width of the predicted face, pixels.
    pub face_w: usize,
}

impl DenseDecoder {
    /// The layer widths from input to output, e.g. `2-12-64-128-4350`.
    pub fn arch(&self) -> String {
        let mut s = self
            .layers
            .first()
            .map(|l| l.n_in.to_string())
            .unwrap_or_default();
        for l in &self.layers {
            s += &format!("-{}", l.n_out);
        }
        s
    }
}

impl FacePredictor for DenseDecoder {
    fn face_size(&self) -> (usize, usize) {
        (self.face_h, self.face_w)
    }
    fn predict(&self, head: [f32; 2], _face: &[f32]) -> Vec<f32> {
        self.layers.iter().fold(head.to_vec(), |x, l| l.forward(&x))
    }
}
