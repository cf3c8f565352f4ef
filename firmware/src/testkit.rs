//! Test fixtures: small model blobs built with `ModelSpec`, and float references.

use msr_shared::blob::{
    Activation, CropMode, LayerKind, LayerSpec, ModelSpec, Normalisation, Novelty, Reach, Shape, Sided,
    Weights,
};

/// A tiny deterministic generator (tests must not depend on `rand` versions).
pub struct Lcg(pub u64);

impl Lcg {
    pub fn next_u32(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 32) as u32
    }
    /// Uniform in [-1, 1).
    pub fn unit(&mut self) -> f64 {
        self.next_u32() as f64 / (1u64 << 31) as f64 - 1.0
    }
}

pub fn shape(c: u16, h: u16, w: u16) -> Shape {
    Shape { c, h, w }
}

/// A layer with random weights of magnitude up to `scale`, i16 unless `i8`.
#[allow(clippy::too_many_arguments)]
pub fn layer(
    rng: &mut Lcg,
    kind: LayerKind,
    activation: Activation,
    input: Shape,
    output: Shape,
    (kernel, stride, padding): (u8, u8, u8),
    (w_shift, in_shift, out_shift): (i8, i8, i8),
    scale: f64,
    i8w: bool,
) -> LayerSpec {
    let k2 = kernel as usize * kernel as usize;
    let (nw, nb) = match kind {
        LayerKind::Dense => (input.len() * output.len(), output.len()),
        LayerKind::Crop => (0, 0),
        _ => (input.c as usize * output.c as usize * k2, output.c as usize),
    };
    let wq = |v: f64| (v * (1i64 << w_shift) as f64).round();
    let weights = if i8w {
        Weights::I8(
            (0..nw)
                .map(|_| wq(rng.unit() * scale).clamp(-127.0, 127.0) as i8)
                .collect(),
        )
    } else {
        Weights::I16((0..nw).map(|_| wq(rng.unit() * scale) as i16).collect())
    };
    let bias = (0..nb)
        .map(|_| {
            (rng.unit() * 0.3 * (1i64 << (w_shift + in_shift)) as f64)
                .round()
                .clamp(-1e9, 1e9) as i32
        })
        .collect();
    LayerSpec {
        kind,
        activation,
        input,
        output,
        kernel,
        stride,
        padding,
        crop_top: 0,
        crop_left: 0,
        w_shift,
        in_shift,
        out_shift,
        weights,
        bias,
    }
}

pub fn reach_net(rng: &mut Lcg) -> Reach {
    let w1: Vec<f32> = (0..20).map(|_| (rng.unit() * 3.0) as f32).collect();
    let b1: Vec<f32> = (0..10).map(|_| rng.unit() as f32).collect();
    let w2: Vec<f32> = (0..50).map(|_| (rng.unit() * 3.0) as f32).collect();
    let b2: Vec<f32> = (0..5).map(|_| rng.unit() as f32).collect();
    Reach::from_parts(
        &w1,
        &b1,
        &w2,
        &b2,
        [130.0, 88.0],
        [203.0, 138.0],
        [-1.0891819, -0.4302188, -0.5001259, -0.3141593, -1.5446163],
        [0.8774061, 0.4095361, 0.6258302, 0.3052239, -1.112108],
    )
    .unwrap()
}

fn spec(face_h: u16, face_w: u16, layers: Vec<LayerSpec>, rng: &mut Lcg) -> ModelSpec {
    let n = face_h as usize * face_w as usize;
    ModelSpec {
        face_h,
        face_w,
        novelty: Novelty {
            threshold: 4.59,
            normalisation: Normalisation::StdDev,
            sided: Sided::Two,
            min_area: 6,
            sigma_floor: 0.5,
            merge: msr_shared::blob::Merge::OFF,
            pool: 0,
            spread_ref: None,
        },
        layers,
        mu: (0..n)
            .map(|_| (2.0 + rng.unit().abs() * 2.0) as u16 * 256)
            .collect(),
        sigma: (0..n)
            .map(|_| ((1.0 + rng.unit().abs()) * 256.0) as u16)
            .collect(),
        reach: reach_net(rng),
        region: None,
        template: None,
        crop: CropMode::Pixel,
        pose: None,
    }
}

/// A small convolutional decoder with every layer kind: face 10 x 12.
pub fn conv_spec(seed: u64, i8w: bool) -> ModelSpec {
    let mut r = Lcg(seed);
    let ws = if i8w { 6 } else { 12 };
    let layers = vec![
        layer(
            &mut r,
            LayerKind::Dense,
            Activation::Tanh,
            shape(2, 1, 1),
            shape(4, 3, 4),
            (0, 0, 0),
            (ws, 12, 14),
            1.5,
            i8w,
        ),
        layer(
            &mut r,
            LayerKind::ConvTranspose2d,
            Activation::Tanh,
            shape(4, 3, 4),
            shape(3, 6, 8),
            (4, 2, 1),
            (ws, 14, 14),
            0.4,
            i8w,
        ),
        layer(
            &mut r,
            LayerKind::UpConv,
            Activation::Relu,
            shape(3, 6, 8),
            shape(2, 12, 16),
            (3, 2, 1),
            (ws, 14, 13),
            0.4,
            i8w,
        ),
        layer(
            &mut r,
            LayerKind::UpConv,
            Activation::Sigmoid,
            shape(2, 12, 16),
            shape(1, 12, 16),
            (3, 1, 1),
            (ws, 13, 15),
            0.5,
            i8w,
        ),
        LayerSpec {
            crop_top: 1,
            crop_left: 2,
            ..layer(
                &mut r,
                LayerKind::Crop,
                Activation::Identity,
                shape(1, 12, 16),
                shape(1, 10, 12),
                (0, 0, 0),
                (0, 15, 15),
                0.0,
                i8w,
            )
        },
    ];
    spec(10, 12, layers, &mut r)
}

/// The published decoder's shape on a small face: 2-12-16-(h*w), tanh, tanh, sigmoid.
pub fn mlp_spec(seed: u64, face_h: u16, face_w: u16) -> ModelSpec {
    let mut r = Lcg(seed);
    let layers = vec![
        layer(
            &mut r,
            LayerKind::Dense,
            Activation::Tanh,
            shape(2, 1, 1),
            shape(12, 1, 1),
            (0, 0, 0),
            (12, 12, 14),
            3.0,
            false,
        ),
        layer(
            &mut r,
            LayerKind::Dense,
            Activation::Tanh,
            shape(12, 1, 1),
            shape(16, 1, 1),
            (0, 0, 0),
            (12, 14, 14),
            0.8,
            false,
        ),
        layer(
            &mut r,
            LayerKind::Dense,
            Activation::Sigmoid,
            shape(16, 1, 1),
            shape(1, face_h, face_w),
            (0, 0, 0),
            (12, 14, 15),
            0.8,
            false,
        ),
    ];
    spec(face_h, face_w, layers, &mut r)
}

/// PyTorch's definitions in f64, written independently of the kernels (scatter for the
/// transposed convolution, an explicit upsampled image for UpConv).
pub fn float_layer(l: &msr_shared::blob::Layer, x: &[f64]) -> Vec<f64> {
    let ws = (1i64 << l.w_shift) as f64;
    let bs = ws * (1i64 << l.in_shift) as f64;
    let w = |i: usize| l.weight(i) as f64 / ws;
    let b = |i: usize| l.bias(i) as f64 / bs;
    let (ic, ih, iw) = (l.input.c as usize, l.input.h as usize, l.input.w as usize);
    let (oc, oh, ow) = (
        l.output.c as usize,
        l.output.h as usize,
        l.output.w as usize,
    );
    let (k, s, p) = (l.kernel as usize, l.stride as usize, l.padding as usize);
    let pre: Vec<f64> = match l.kind {
        LayerKind::Dense => (0..l.output.len())
            .map(|o| b(o) + (0..x.len()).map(|i| w(o * x.len() + i) * x[i]).sum::<f64>())
            .collect(),
        LayerKind::ConvTranspose2d => {
            let mut y: Vec<f64> = (0..oc * oh * ow).map(|i| b(i / (oh * ow))).collect();
            for c in 0..ic {
                for iy in 0..ih {
                    for ix in 0..iw {
                        for o in 0..oc {
                            for ky in 0..k {
                                for kx in 0..k {
                                    let oy = (iy * s + ky) as isize - p as isize;
                                    let ox = (ix * s + kx) as isize - p as isize;
                                    if oy < 0 || ox < 0 || oy >= oh as isize || ox >= ow as isize {
                                        continue;
                                    }
                                    y[(o * oh + oy as usize) * ow + ox as usize] +=
                                        w(((c * oc + o) * k + ky) * k + kx)
                                            * x[(c * ih + iy) * iw + ix];
                                }
                            }
                        }
                    }
                }
            }
            y
        }
        LayerKind::UpConv => {
            let (uh, uw) = (ih * s, iw * s);
            let up = |c: usize, y: isize, xx: isize| -> f64 {
                if y < 0 || xx < 0 || y >= uh as isize || xx >= uw as isize {
                    0.0
                } else {
                    x[(c * ih + y as usize / s) * iw + xx as usize / s]
                }
            };
            let mut y = vec![0.0; oc * oh * ow];
            for o in 0..oc {
                for yy in 0..oh {
                    for xx in 0..ow {
                        let mut a = b(o);
                        for c in 0..ic {
                            for ky in 0..k {
                                for kx in 0..k {
                                    a += w(((o * ic + c) * k + ky) * k + kx)
                                        * up(
                                            c,
                                            (yy + ky) as isize - p as isize,
                                            (xx + kx) as isize - p as isize,
                                        );
                                }
                            }
                        }
                        y[(o * oh + yy) * ow + xx] = a;
                    }
                }
            }
            y
        }
        LayerKind::Crop => {
            let (t, le) = (l.crop_top as usize, l.crop_left as usize);
            let mut y = vec![0.0; oc * oh * ow];
            for c in 0..oc {
                for yy in 0..oh {
                    for xx in 0..ow {
                        y[(c * oh + yy) * ow + xx] = x[(c * ih + yy + t) * iw + xx + le];
                    }
                }
            }
            y
        }
    };
    pre.into_iter()
        .map(|v| match l.activation {
            Activation::Identity => v,
            Activation::Relu => v.max(0.0),
            Activation::Tanh => v.tanh(),
            Activation::Sigmoid => 1.0 / (1.0 + (-v).exp()),
        })
        .collect()
}

/// The whole decoder in f64 (no intermediate rounding): grey/255 per pixel.
pub fn float_decoder(m: &msr_shared::blob::Model, head: [f64; 2]) -> Vec<f64> {
    let mut x = head.to_vec();
    for l in &m.layers {
        x = float_layer(l, &x);
    }
    x
}
