use super::*;
use crate::testkit::{conv_spec, float_decoder, float_layer, mlp_spec, Lcg};
use msr_shared::blob::{LayerKind, Model};

#[test]
fn tables_match_f64() {
    for (j, &v) in TANH_Q15.iter().enumerate() {
        let x = (j as f64 - 4096.0 + 0.5) / 512.0;
        let want = (x.tanh() * 32768.0).round().clamp(-32767.0, 32767.0);
        assert_eq!(v as f64, want, "tanh entry {j}");
    }
}

/// Error bounds of the tables (midpoint of a cell, slope at most 1 for tanh, 1/4 for sigmoid),
/// in units of the output: tanh 2^-10 + rounding, sigmoid 2^-11 + rounding, grey 0.13 grey
/// levels.
const TANH_ERR: f64 = 1.0 / 1024.0 + 1.0 / 65536.0;

#[test]
fn tanh_and_sigmoid_by_table_are_within_their_bounds() {
    let mut r = Lcg(7);
    for bits in [0u32, 3, 8, 9, 14, 15, 20, 26, 31, 40] {
        for out_bits in [10u32, 14, 15] {
            let tanh = Requant::new(Activation::Tanh, bits, out_bits);
            let sig = Requant::new(Activation::Sigmoid, bits, out_bits);
            let grey = Requant::new(Activation::Sigmoid, bits, out_bits).last();
            let step = 2f64.powi(out_bits as i32);
            for _ in 0..4000 {
                let acc = (r.unit() * 2f64.powi(bits as i32 + 4))
                    .clamp(i32::MIN as f64, i32::MAX as f64) as i32;
                let x = acc as f64 / 2f64.powi(bits as i32);
                let got = tanh.apply(acc) as f64 / step;
                assert!(
                    (got - x.tanh()).abs() <= TANH_ERR + 0.5 / step,
                    "tanh {x}: {got}"
                );
                let s = 1.0 / (1.0 + (-x).exp());
                let got = sig.apply(acc) as f64 / step;
                assert!(
                    (got - s).abs() <= TANH_ERR / 2.0 + 0.5 / step,
                    "sigmoid {x}: {got}"
                );
                let got = grey.apply(acc) as u16 as f64 / 256.0;
                assert!((got - 255.0 * s).abs() <= 0.13, "grey {x}: {got}");
            }
        }
    }
    // Extremes saturate instead of wrapping.
    let rq = Requant::new(Activation::Sigmoid, 20, 15);
    assert_eq!(rq.apply(i32::MAX), 32767);
    // The table's tanh stops at -32767 / 2^15: sigmoid's floor is one Q16 step.
    assert!(rq.apply(i32::MIN) <= 1);
    assert_eq!(rq.last().apply(i32::MAX) as u16, 65280);
    assert!(rq.last().apply(i32::MIN) <= 1);
    let rq = Requant::new(Activation::Identity, 0, 31);
    assert_eq!(rq.apply(-5), i16::MIN);
    let rq = Requant::new(Activation::Identity, 62, 0);
    assert_eq!(rq.apply(i32::MAX), 0);
}

/// Each layer against its float definition, fed the same fixed-point input: identity, ReLU and
/// crop must agree exactly, tanh and sigmoid within one output step.
fn layers_match_float(bytes: &[u8]) {
    let m = Model::parse(bytes).unwrap();
    let mut r = Lcg(99);
    for (li, l) in m.layers.iter().enumerate() {
        for _ in 0..3 {
            let n_in = l.input.len();
            let amp = if li == 0 { 0.1 } else { 0.9 };
            let x: Vec<i16> = (0..n_in)
                .map(|_| (r.unit() * amp * 2f64.powi(l.in_shift as i32)).round() as i16)
                .collect();
            let mut y = vec![0i16; l.output.len()];
            run_layer(l, &x, &mut y).unwrap();
            let xf: Vec<f64> = x
                .iter()
                .map(|&v| v as f64 / 2f64.powi(l.in_shift as i32))
                .collect();
            let yf = float_layer(l, &xf);
            // The tables' bound in output steps, plus one for rounding.
            let tol = match l.activation {
                Activation::Tanh | Activation::Sigmoid => {
                    (TANH_ERR * 2f64.powi(l.out_shift as i32)).ceil() + 1.0
                }
                _ => 0.0,
            };
            for (i, (&a, &b)) in y.iter().zip(&yf).enumerate() {
                let want = (b * 2f64.powi(l.out_shift as i32) + 0.5)
                    .floor()
                    .clamp(-32768.0, 32767.0);
                assert!(
                    (a as f64 - want).abs() <= tol,
                    "layer {li} ({:?}) element {i}: fixed {a}, float {want}",
                    l.kind
                );
            }
        }
    }
}

#[test]
fn every_layer_kind_matches_its_float_definition() {
    for seed in 1..6 {
        layers_match_float(&conv_spec(seed, false).to_bytes().unwrap());
        layers_match_float(&conv_spec(seed, true).to_bytes().unwrap());
        layers_match_float(&mlp_spec(seed, 6, 7).to_bytes().unwrap());
    }
}

fn max_face_error(bytes: &[u8], head: [f32; 2]) -> f64 {
    let m = Model::parse(bytes).unwrap();
    let mut d = Box::new(Decoder::new());
    let face = d.predict(&m, head).unwrap().to_vec();
    let q = quantise_input(&m, head).unwrap();
    let s = 2f64.powi(m.layers[0].in_shift as i32);
    let want = float_decoder(&m, [q[0] as f64 / s, q[1] as f64 / s]);
    assert_eq!(face.len(), want.len());
    face.iter()
        .zip(&want)
        .map(|(&g, &f)| (g as f64 / 65280.0 - f).abs())
        .fold(0.0, f64::max)
}

#[test]
/// The face stays within 0.77 grey levels of float (the tables' errors through the layers).
fn whole_decoder_is_close_to_float() {
    for seed in 1..6 {
        for head in [[0.0, 0.0], [0.08, -0.05], [-0.087, 0.087]] {
            let e = max_face_error(&conv_spec(seed, false).to_bytes().unwrap(), head);
            assert!(e < 3e-3, "conv seed {seed}: max error {e}");
            let e = max_face_error(&conv_spec(seed, true).to_bytes().unwrap(), head);
            assert!(e < 3e-3, "conv i8 seed {seed}: max error {e}");
            let e = max_face_error(&mlp_spec(seed, 8, 9).to_bytes().unwrap(), head);
            assert!(e < 3e-3, "mlp seed {seed}: max error {e}");
        }
    }
}

#[test]
fn unaligned_blob_gives_the_same_face() {
    let bytes = conv_spec(3, false).to_bytes().unwrap();
    let mut shifted = vec![0u8; 1];
    shifted.extend_from_slice(&bytes);
    let a = Model::parse(&bytes).unwrap();
    let b = Model::parse(&shifted[1..]).unwrap();
    let mut d = Box::new(Decoder::new());
    let fa = d.predict(&a, [0.03, -0.02]).unwrap().to_vec();
    let fb = d.predict_uncached(&b, [0.03, -0.02]).unwrap().to_vec();
    assert_eq!(fa, fb);
}

#[test]
fn cache_follows_pose_and_model() {
    let b1 = conv_spec(1, false).to_bytes().unwrap();
    let b2 = conv_spec(2, false).to_bytes().unwrap();
    let (m1, m2) = (Model::parse(&b1).unwrap(), Model::parse(&b2).unwrap());
    let mut d = Box::new(Decoder::new());
    let f1 = d.predict(&m1, [0.0, 0.0]).unwrap().to_vec();
    // A change below the input resolution is the same pose.
    let same = d.predict(&m1, [1e-7, 0.0]).unwrap().to_vec();
    assert_eq!(f1, same);
    let f2 = d.predict(&m2, [0.0, 0.0]).unwrap().to_vec();
    assert_ne!(f1, f2);
    let f3 = d.predict(&m1, [0.05, 0.0]).unwrap().to_vec();
    assert_ne!(f1, f3);
    assert_eq!(d.predict(&m1, [f32::NAN, 0.0]), Err(DecodeError::BadInput));
    assert_eq!(
        d.predict(&m1, [0.0, f32::INFINITY]),
        Err(DecodeError::BadInput)
    );
}

#[test]
fn mismatched_scales_are_refused() {
    let mut spec = conv_spec(1, false);
    spec.layers[2].in_shift = 13;
    let bytes = spec.to_bytes().unwrap();
    let m = Model::parse(&bytes).unwrap();
    assert_eq!(check_scales(&m), Err(DecodeError::Scale(2)));
    let mut d = Box::new(Decoder::new());
    assert_eq!(d.predict(&m, [0.0, 0.0]), Err(DecodeError::Scale(2)));
    assert!(matches!(
        crate::model::validate(&bytes),
        Err(msr_shared::blob::BlobError::Chain(2))
    ));
}

mod shapes {
    use super::*;
    use crate::testkit::{layer, shape};
    use msr_shared::blob::{LayerKind, LayerSpec};
    use proptest::prelude::*;

    /// One layer alone (wrapped so the blob parses: 2 -> input, layer, -> 1 x h x w face is not
    /// needed here: the layer is built, serialised through a blob and run directly).
    fn check(spec: LayerSpec, seed: u64) -> Result<(), TestCaseError> {
        let mut r = Lcg(seed);
        // A blob needs a first layer with 2 inputs and a face at the end; run_layer only needs the
        // parsed Layer, so wrap: Dense 2 -> input shape, the layer, then nothing else is checked.
        let first = layer(
            &mut r,
            LayerKind::Dense,
            Activation::Identity,
            shape(2, 1, 1),
            spec.input,
            (0, 0, 0),
            (4, 4, spec.in_shift),
            0.5,
            false,
        );
        let out = spec.output;
        let face = if out.c == 1 {
            None
        } else {
            Some(layer(
                &mut r,
                LayerKind::UpConv,
                Activation::Identity,
                out,
                shape(1, out.h, out.w),
                (1, 1, 0),
                (4, spec.out_shift, 8),
                0.5,
                false,
            ))
        };
        let mut ms = crate::testkit::conv_spec(1, false);
        ms.face_h = out.h;
        ms.face_w = out.w;
        let n = out.h as usize * out.w as usize;
        ms.mu = vec![256; n];
        ms.sigma = vec![256; n];
        ms.layers = vec![first, spec];
        ms.layers.extend(face);
        let bytes = ms.to_bytes().unwrap();
        let m = Model::parse(&bytes).unwrap();
        let l = &m.layers[1];
        let x: Vec<i16> = (0..l.input.len())
            .map(|_| (r.unit() * 3000.0) as i16)
            .collect();
        let mut y = vec![0i16; l.output.len()];
        run_layer(l, &x, &mut y).unwrap();
        let xf: Vec<f64> = x
            .iter()
            .map(|&v| v as f64 / 2f64.powi(l.in_shift as i32))
            .collect();
        let yf = float_layer(l, &xf);
        for (i, (&a, &b)) in y.iter().zip(&yf).enumerate() {
            let want = (b * 2f64.powi(l.out_shift as i32) + 0.5)
                .floor()
                .clamp(-32768.0, 32767.0);
            prop_assert_eq!(a as f64, want, "element {}", i);
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

        #[test]
        fn conv_transpose_any_shape(ic in 1u16..6, oc in 1u16..4, ih in 1u16..9, iw in 1u16..13,
                                     k in 1u8..7, s in 1u8..4, p in 0u8..4, seed: u64, i8w: bool) {
            let (k_, s_, p_) = (k as u16, s as u16, p as u16);
            let oh = ((ih - 1) * s_ + k_).checked_sub(2 * p_);
            let ow = ((iw - 1) * s_ + k_).checked_sub(2 * p_);
            prop_assume!(matches!((oh, ow), (Some(a), Some(b)) if a > 0 && b > 0 && a as usize * b as usize * oc as usize <= 8192));
            let mut r = Lcg(seed);
            let spec = layer(&mut r, LayerKind::ConvTranspose2d, Activation::Identity, shape(ic, ih, iw),
                shape(oc, oh.unwrap(), ow.unwrap()), (k, s, p), (if i8w { 6 } else { 12 }, 12, 10), 0.5, i8w);
            check(spec, seed)?;
        }

        #[test]
        fn up_conv_any_shape(ic in 1u16..5, oc in 1u16..4, ih in 1u16..8, iw in 1u16..10,
                             k in 1u8..6, s in 1u8..4, p in 0u8..3, seed: u64) {
            let (k_, s_, p_) = (k as u16, s as u16, p as u16);
            let oh = (ih * s_ + 2 * p_ + 1).checked_sub(k_);
            let ow = (iw * s_ + 2 * p_ + 1).checked_sub(k_);
            prop_assume!(matches!((oh, ow), (Some(a), Some(b)) if a > 0 && b > 0));
            let mut r = Lcg(seed);
            let spec = layer(&mut r, LayerKind::UpConv, Activation::Identity, shape(ic, ih, iw),
                shape(oc, oh.unwrap(), ow.unwrap()), (k, s, p), (12, 12, 10), 0.5, false);
            check(spec, seed)?;
        }

        #[test]
        fn dense_any_shape(n_in in 1u16..40, n_out in 1u16..30, seed: u64, relu: bool) {
            let mut r = Lcg(seed);
            let act = if relu { Activation::Relu } else { Activation::Identity };
            let spec = layer(&mut r, LayerKind::Dense, act, shape(n_in, 1, 1), shape(1, 1, n_out), (0, 0, 0), (12, 12, 10), 0.5, false);
            check(spec, seed)?;
        }
    }
}

#[test]
fn fast_activation_path_equals_the_general_one() {
    let mut r = Lcg(5);
    for act in [Activation::Tanh, Activation::Sigmoid] {
        for acc_bits in 0..60 {
            for out_bits in 0..31 {
                for rq in [
                    Requant::new(act, acc_bits, out_bits),
                    Requant::new(act, acc_bits, out_bits).last(),
                ] {
                    let check = |acc: i32| {
                        let want = rq.apply(acc);
                        if let Some(t) = rq.tanh_act() {
                            assert_eq!(t.act(acc), want, "{act:?} {acc_bits} {out_bits} {acc}");
                        }
                        if let Some(g) = rq.grey_act() {
                            assert_eq!(g.act(acc), want, "grey {acc_bits} {acc}");
                        }
                    };
                    for _ in 0..40 {
                        check(r.next_u32() as i32 >> (r.next_u32() % 32));
                    }
                    for acc in [0, 1, -1, i32::MAX, i32::MIN] {
                        check(acc);
                    }
                }
            }
        }
    }
}

/// The paired kernels with the inlined table steps (what the M4 assembly does, in portable
/// Rust) give the generic loops' bits, layer by layer, including the last layer's grey step.
#[test]
fn fast_kernels_equal_the_generic_loops() {
    for seed in 1..5 {
        for bytes in [
            conv_spec(seed, false).to_bytes().unwrap(),
            mlp_spec(seed, 6, 7).to_bytes().unwrap(),
        ] {
            let m = Model::parse(&bytes).unwrap();
            let grey = grey_layer(&m);
            assert!(grey.is_some(), "the test models end in a sigmoid");
            let mut r = Lcg(seed);
            for (li, l) in m.layers.iter().enumerate() {
                if l.kind == LayerKind::Crop {
                    continue;
                }
                let rq = if grey == Some(li) {
                    Requant::of(l).last()
                } else {
                    Requant::of(l)
                };
                let x: Vec<i16> = (0..l.input.len())
                    .map(|_| (r.unit() * 2f64.powi(l.in_shift as i32)) as i16)
                    .collect();
                let mut fast = vec![0i16; l.output.len()];
                run_layer_as(l, rq, &x, &mut fast).unwrap();
                let mut slow = vec![0i16; l.output.len()];
                let (w, b) = (l.weights_i16().unwrap(), l.bias_i32().unwrap());
                kernels::layer(l, rq, &w, &b, &x, &mut slow).unwrap();
                assert_eq!(fast, slow, "seed {seed} layer {li} ({:?})", l.kind);
            }
        }
    }
}

/// The M4's fused Dense -> ConvTranspose2d k4 s2 (-> crop) path, run here with the Rust
/// stand-ins of its assembly routines, equals the layers run one by one through the generic
/// loops with PyTorch-order weights (the blob's accessors): borders, weight packing, phases,
/// the single first output and the groups' spill, crop windows at odd and even offsets, over
/// paddings 0..=3, odd and even sizes, i16 weights in the blocked order (1 to 16 input blocks)
/// and i8 ones.
#[test]
fn fused_dense_conv_transpose_equals_the_layers() {
    use crate::testkit::{layer, shape};
    use msr_shared::blob::{LayerSpec, WeightOrder, MAX_ACTIVATION_LEN};
    for seed in 0..96u64 {
        let mut r = Lcg(seed + 100);
        let i8w = seed % 3 == 2;
        let n_in = if i8w {
            [32, 64][(seed / 3 % 2) as usize]
        } else {
            [8, 16, 24, 32, 64, 128][(seed / 2 % 6) as usize]
        };
        let p = (seed / 4 % 4) as u8;
        // At least p input rows and columns (an output of at least 2).
        let h = (1 + (seed * 7 % 5) as u16).max(p as u16);
        // i8 weights also in PyTorch order (blobs written before the blocked order).
        let torch = i8w && seed % 2 == 0;
        let w = (1 + (seed * 5 % 9) as u16).max(p as u16);
        let (oh, ow) = (
            (h - 1) * 2 + 4 - 2 * p as u16,
            (w - 1) * 2 + 4 - 2 * p as u16,
        );
        let crop = seed % 4 != 0;
        let (top, left) = if crop {
            (seed as u16 % 3 % oh, (seed / 5) as u16 % 3 % ow)
        } else {
            (0, 0)
        };
        let (fh, fw) = if crop {
            (
                1 + (seed as u16 * 3) % (oh - top),
                1 + (seed as u16 * 11) % (ow - left),
            )
        } else {
            (oh, ow)
        };
        let ws = if i8w { 6 } else { 12 };
        let mut layers = vec![
            layer(
                &mut r,
                LayerKind::Dense,
                Activation::Tanh,
                shape(2, 1, 1),
                shape(n_in as u16, 1, 1),
                (0, 0, 0),
                (12, 12, 14),
                1.0,
                false,
            ),
            layer(
                &mut r,
                LayerKind::Dense,
                Activation::Tanh,
                shape(n_in as u16, 1, 1),
                shape(4, h, w),
                (0, 0, 0),
                // out_shift 14 takes the SHADD16 step, others the general one.
                (ws, 14, [14, 12, 15][(seed % 3) as usize]),
                0.4,
                i8w,
            ),
        ];
        let in_shift = layers[1].out_shift;
        layers.push(layer(
            &mut r,
            LayerKind::ConvTranspose2d,
            Activation::Sigmoid,
            shape(4, h, w),
            shape(1, oh, ow),
            (4, 2, p),
            (ws, in_shift, 15),
            0.5,
            i8w,
        ));
        if crop {
            layers.push(LayerSpec {
                crop_top: top,
                crop_left: left,
                ..layer(
                    &mut r,
                    LayerKind::Crop,
                    Activation::Identity,
                    shape(1, oh, ow),
                    shape(1, fh, fw),
                    (0, 0, 0),
                    (0, 15, 15),
                    0.0,
                    false,
                )
            });
        }
        let mut ms = conv_spec(1, false);
        (ms.face_h, ms.face_w) = (fh, fw);
        ms.mu = vec![256; fh as usize * fw as usize];
        ms.sigma = vec![256; fh as usize * fw as usize];
        ms.layers = layers;
        let mut bytes = ms.to_bytes().unwrap();
        if torch {
            unblock(&mut bytes, 1);
        }
        let m = Model::parse(&bytes).unwrap();
        assert_eq!(grey_layer(&m), Some(2));
        let (d, c) = (&m.layers[1], &m.layers[2]);
        assert_eq!(d.order == WeightOrder::Blocked, !torch);
        let (drq, crq) = (Requant::of(d), Requant::of(c).last());
        let x: Vec<i16> = (0..n_in)
            .map(|_| (r.unit() * 0.9 * 16384.0) as i16)
            .collect();
        // The layers one by one, weights by PyTorch index; the decoder's own Dense path too.
        let mut mid = vec![0i16; d.output.len()];
        kernels::layer(d, drq, &Weights::Raw(d), &Biases::Raw(d), &x, &mut mid).unwrap();
        let mut mid2 = vec![0i16; d.output.len()];
        run_layer_as(d, drq, &x, &mut mid2).unwrap();
        assert_eq!(mid, mid2, "seed {seed}: the decoder's Dense path");
        let mut want = vec![0i16; c.output.len()];
        run_layer_as(c, crq, &mid, &mut want).unwrap();
        if crop {
            let l = &m.layers[3];
            let mut cropped = vec![0i16; l.output.len()];
            run_layer_as(l, Requant::of(l), &want, &mut cropped).unwrap();
            want = cropped;
        }
        let what =
            format!("seed {seed}: p {p} {h}x{w} in {n_in} i8 {i8w} window {top},{left} {fh}x{fw}");
        // Fused, in word-aligned buffers as the decoder's.
        let Some(f) = fused::Fused::of(d, drq, c, crq) else {
            // Only the PyTorch-order i8 kernel's odd widths are refused.
            assert!(torch && w % 2 == 1, "{what}: not fused");
            continue;
        };
        let f = if crop {
            f.with_crop(&m.layers[3])
                .unwrap_or_else(|| panic!("{what}: crop not fused"))
        } else {
            f
        };
        let mut buf = vec![0u32; MAX_ACTIVATION_LEN / 2];
        let mut mid = vec![0x5a5a_5a5au32; MAX_ACTIVATION_LEN / 2];
        let b16: &mut [i16] = bytemuck::cast_slice_mut(&mut buf);
        b16[..n_in].copy_from_slice(&x);
        assert!(!f.run(b16, bytemuck::cast_slice_mut(&mut mid), None).unwrap());
        assert_eq!(&b16[..want.len()], &want[..], "{what}");
        // With the room's offsets: each output takes its half cell's entry (random entries, the
        // extremes among them), added where its group falls on the half cells.
        let mut halves = [Packed::ZERO; 2 * room::CELLS];
        for e in halves.iter_mut() {
            *e = Packed::of(match r.next_u32() % 5 {
                0 => i16::MIN,
                1 => i16::MAX,
                _ => (r.next_u32() % 8192) as i16 - 4096,
            });
        }
        let b16: &mut [i16] = bytemuck::cast_slice_mut(&mut buf);
        b16[..n_in].copy_from_slice(&x);
        let added = f.run(b16, bytemuck::cast_slice_mut(&mut mid), Some(&halves)).unwrap();
        assert_eq!(added, left % 2 == 1 - p as u16 % 2, "{what}: groups on the half cells");
        if added {
            let fw = fw as usize;
            let with: Vec<i16> = want
                .iter()
                .enumerate()
                .map(|(i, &v)| {
                    let (x, y) = (i % fw, i / fw);
                    let e = halves[(y / room::CELL) * 2 * room::COLS + x / room::HALF];
                    e.add_to(v as u16) as i16
                })
                .collect();
            assert_eq!(&b16[..want.len()], &with[..], "{what}: with the room");
        }
    }
}

/// Rewrites layer `li` of a blob from the blocked order to PyTorch's (byte 3 of its descriptor
/// 0, weights and biases moved back, CRC redone): a blob as written before the blocked order.
fn unblock(bytes: &mut [u8], li: usize) {
    let (w_at, b_at, size, n_w, n_b, perm_w, perm_b) = {
        let m = Model::parse(bytes).unwrap();
        let l = &m.layers[li];
        let at = |p: *const u8| p as usize - bytes.as_ptr() as usize;
        let size = l.weight_type.size();
        let n_w = l.weight_count();
        let hw = l.output.h as usize * l.output.w as usize;
        let c_n = l.output.c as usize;
        let perm_w: Vec<usize> = (0..n_w).map(|i| l.stored_index(i)).collect();
        let perm_b: Vec<usize> = (0..l.bias_count()).map(|i| (i % hw) * c_n + i / hw).collect();
        (at(l.weights.as_ptr()), at(l.bias.as_ptr()), size, n_w, l.bias_count(), perm_w, perm_b)
    };
    let (w, b) = (bytes[w_at..w_at + n_w * size].to_vec(), bytes[b_at..b_at + 4 * n_b].to_vec());
    for (i, &j) in perm_w.iter().enumerate() {
        bytes[w_at + i * size..w_at + (i + 1) * size].copy_from_slice(&w[j * size..(j + 1) * size]);
    }
    for (i, &j) in perm_b.iter().enumerate() {
        bytes[b_at + 4 * i..b_at + 4 * i + 4].copy_from_slice(&b[4 * j..4 * j + 4]);
    }
    bytes[w_at - 32 + 3] = 0;
    let crc = msr_shared::blob::CRC32.checksum(&bytes[16..]);
    bytes[12..16].copy_from_slice(&crc.to_le_bytes());
}
