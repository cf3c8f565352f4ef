use super::*;
use proptest::prelude::*;

fn reach() -> Reach {
    let w1: Vec<f32> = (0..20).map(|i| i as f32 * 0.1 - 1.0).collect();
    let b1 = vec![0.5; 10];
    let w2: Vec<f32> = (0..50).map(|i| (i as f32 * 0.37).sin()).collect();
    let b2 = vec![-0.25; 5];
    Reach::from_parts(
        &w1,
        &b1,
        &w2,
        &b2,
        [130.0, 88.0],
        [203.0, 138.0],
        [-1.0, -0.4, -0.5, -0.3, -1.5],
        [0.9, 0.4, 0.6, 0.3, -1.1],
    )
    .unwrap()
}

fn dense(input: Shape, output: Shape, act: Activation, i16w: bool) -> LayerSpec {
    let n = input.len() * output.len();
    LayerSpec {
        kind: LayerKind::Dense,
        activation: act,
        input,
        output,
        kernel: 0,
        stride: 0,
        padding: 0,
        crop_top: 0,
        crop_left: 0,
        w_shift: 12,
        in_shift: 13,
        out_shift: 14,
        weights: if i16w {
            Weights::I16((0..n).map(|i| (i as i16).wrapping_mul(77)).collect())
        } else {
            Weights::I8((0..n).map(|i| (i as i8).wrapping_mul(3)).collect())
        },
        bias: (0..output.len() as i32).map(|i| i * 1000 - 7).collect(),
    }
}

fn sh(c: u16, h: u16, w: u16) -> Shape {
    Shape { c, h, w }
}

/// 2 -> 5 (tanh) -> 1x3x4 (sigmoid): an MLP decoder for a 3 x 4 face.
fn mlp_spec() -> ModelSpec {
    ModelSpec {
        face_h: 3,
        face_w: 4,
        novelty: Novelty {
            threshold: 4.59,
            normalisation: Normalisation::StdDev,
            sided: Sided::One,
            min_area: 30,
            sigma_floor: 1.0,
            merge: Merge::OFF,
            pool: 0,
            spread_ref: None,
        },
        layers: vec![
            dense(sh(2, 1, 1), sh(5, 1, 1), Activation::Tanh, false),
            dense(sh(5, 1, 1), sh(1, 3, 4), Activation::Sigmoid, true),
        ],
        mu: (0..12).map(|i| i * 300).collect(),
        sigma: (0..12).map(|i| 256 + i).collect(),
        reach: reach(),
        region: None,
        template: Some((2, 3, vec![1, 2, 3, 4, 5, 6])),
        crop: CropMode::Pixel,
        pose: None,
    }
}

/// 2 -> 2x2x2 (tanh) -> convT k4 s2 p1 -> 1x4x4 -> upconv x2 k3 p1 -> 1x8x8 -> crop 3x4 at (1,2).
fn conv_spec() -> ModelSpec {
    let mut s = mlp_spec();
    s.template = None;
    let mut convt = dense(sh(2, 2, 2), sh(1, 4, 4), Activation::Tanh, true);
    convt.kind = LayerKind::ConvTranspose2d;
    convt.kernel = 4;
    convt.stride = 2;
    convt.padding = 1;
    convt.weights = Weights::I16((0..2 * 16).map(|i| i as i16 - 9).collect());
    convt.bias = vec![3];
    let mut up = convt.clone();
    up.kind = LayerKind::UpConv;
    up.activation = Activation::Sigmoid;
    up.input = sh(1, 4, 4);
    up.output = sh(1, 8, 8);
    up.kernel = 3;
    up.stride = 2;
    up.weights = Weights::I8((0..9).collect());
    up.bias = vec![-5];
    let crop = LayerSpec {
        kind: LayerKind::Crop,
        activation: Activation::Identity,
        input: sh(1, 8, 8),
        output: sh(1, 3, 4),
        crop_top: 1,
        crop_left: 2,
        weights: Weights::I16(vec![]),
        bias: vec![],
        ..up.clone()
    };
    s.layers = vec![
        dense(sh(2, 1, 1), sh(2, 2, 2), Activation::Tanh, true),
        convt,
        up,
        crop,
    ];
    s
}

/// Recomputes the CRC after a deliberate edit, so that a validator behind the CRC is reached.
fn recrc(b: &mut [u8]) {
    let crc = CRC32.checksum(&b[16..]);
    b[12..16].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn mlp_round_trip() {
    let spec = mlp_spec();
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(bytes.len() % 4, 0);
    let m = Model::parse(&bytes).unwrap();
    assert_eq!((m.face_h, m.face_w, m.face_pixels()), (3, 4, 12));
    assert_eq!(m.novelty, spec.novelty);
    assert_eq!(m.layers.len(), 2);
    let l0 = &m.layers[0];
    assert_eq!((l0.weight_type, l0.weight_count(), l0.bias_count()), (WeightType::I8, 10, 5));
    assert_eq!(l0.weight(3), 9);
    assert_eq!(l0.weight(9), 27);
    assert_eq!(l0.bias(1), 993);
    let l1 = &m.layers[1];
    assert_eq!(l1.weight(59), (59i16).wrapping_mul(77) as i32);
    assert_eq!(l1.activation, Activation::Sigmoid);
    assert_eq!(m.mu.get(11), 3300);
    assert_eq!(m.sigma.iter().collect::<Vec<_>>(), spec.sigma);
    assert_eq!(m.reach, spec.reach);
    let t = m.template.unwrap();
    assert_eq!((t.h, t.w, t.pixels), (2, 3, &[1u8, 2, 3, 4, 5, 6][..]));
    assert_eq!(m.decoder_macs(), 10 + 60);
    assert_eq!(m.crc32, u32::from_le_bytes(bytes[12..16].try_into().unwrap()));
}

#[test]
fn conv_round_trip() {
    let bytes = conv_spec().to_bytes().unwrap();
    let m = Model::parse(&bytes).unwrap();
    let kinds: Vec<_> = m.layers.iter().map(|l| l.kind).collect();
    assert_eq!(
        kinds,
        [LayerKind::Dense, LayerKind::ConvTranspose2d, LayerKind::UpConv, LayerKind::Crop]
    );
    assert_eq!(m.layers[1].weight(0), -9);
    assert_eq!(m.layers[2].weight(8), 8);
    assert_eq!(m.layers[3].crop_left, 2);
    assert!(m.template.is_none());
    // 2*8 + 8*1*16 + 64*1*9.
    assert_eq!(m.decoder_macs(), 16 + 128 + 576);
}

#[test]
fn literal_header() {
    let bytes = mlp_spec().to_bytes().unwrap();
    assert_eq!(&bytes[0..8], &[b'M', b'S', b'R', b'M', 1, 0, 40, 0]);
    assert_eq!(&bytes[16..24], &[3, 0, 4, 0, 2, 0, 1, 0]);
    assert_eq!(&bytes[24..28], &4.59f32.to_le_bytes());
    assert_eq!(&bytes[28..32], &[0, 0, 30, 0]);
    // First layer descriptor: Dense, tanh, i8.
    assert_eq!(&bytes[40..44], &[0, 1, 1, 0]);
}

#[test]
fn aligned_views() {
    let bytes = conv_spec().to_bytes().unwrap();
    // A Vec<u8> from the allocator is at least 4-aligned in practice; copy into u32s to be sure.
    let words: Vec<u32> = bytes
        .chunks(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let aligned: &[u8] = bytemuck::cast_slice(&words);
    let m = Model::parse(aligned).unwrap();
    let w = m.layers[1].weights_i16().unwrap();
    assert_eq!(w[0], -9);
    assert_eq!(m.layers[1].bias_i32().unwrap(), &[3]);
    assert_eq!(m.layers[2].weights_i8().unwrap()[8], 8);
}

#[test]
fn every_truncation_is_refused() {
    let bytes = mlp_spec().to_bytes().unwrap();
    for n in 0..bytes.len() {
        assert!(Model::parse(&bytes[..n]).is_err(), "accepted {n} of {} bytes", bytes.len());
    }
    let mut long = bytes.clone();
    long.extend_from_slice(&[0; 4]);
    assert_eq!(Model::parse(&long), Err(BlobError::LengthMismatch));
}

#[test]
fn every_byte_flip_is_refused() {
    let bytes = conv_spec().to_bytes().unwrap();
    for i in 0..bytes.len() {
        for bit in [0, 3, 7] {
            let mut b = bytes.clone();
            b[i] ^= 1 << bit;
            assert!(Model::parse(&b).is_err(), "flip at {i}:{bit} accepted");
        }
    }
}

#[test]
fn header_checks() {
    let good = mlp_spec().to_bytes().unwrap();
    let edit = |at: usize, v: &[u8]| {
        let mut b = good.clone();
        b[at..at + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|_| ())
    };
    assert_eq!(edit(0, b"MSRX"), Err(BlobError::BadMagic));
    assert_eq!(edit(4, &[0, 0]), Err(BlobError::UnsupportedVersion(0)));
    assert_eq!(edit(4, &[8, 0]), Err(BlobError::UnsupportedVersion(8)));
    assert_eq!(edit(4, &[7, 0]), Err(BlobError::BadHeader), "version 7 carries chroma");
    assert_eq!(edit(4, &[6, 0]), Err(BlobError::BadHeader), "version 6 carries the frame spread");
    assert_eq!(edit(4, &[5, 0]), Err(BlobError::BadHeader), "version 5 carries a self gate or pooling");
    // Versions 2 to 4 read version 1's layout too.
    assert!(edit(4, &[2, 0]).is_ok());
    assert!(edit(4, &[3, 0]).is_ok());
    assert!(edit(4, &[4, 0]).is_ok());
    assert_eq!(edit(6, &[41, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(16, &[0, 0]), Err(BlobError::FaceSize));
    assert_eq!(edit(16, &[65, 0]), Err(BlobError::FaceSize));
    assert_eq!(edit(18, &[97, 0]), Err(BlobError::FaceSize));
    assert_eq!(edit(20, &[0, 0]), Err(BlobError::TooManyLayers));
    assert_eq!(edit(20, &[17, 0]), Err(BlobError::TooManyLayers));
    assert_eq!(edit(22, &[2, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(24, &f32::NAN.to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(24, &(-1.0f32).to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(28, &[2]), Err(BlobError::Novelty));
    assert_eq!(edit(29, &[9]), Err(BlobError::Novelty));
    assert_eq!(edit(30, &[0, 0]), Err(BlobError::Novelty));
    assert_eq!(edit(32, &f32::INFINITY.to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(36, &[1]), Err(BlobError::BadHeader));
    let mut b = good.clone();
    b[8..12].copy_from_slice(&(good.len() as u32 + 4).to_le_bytes());
    assert_eq!(Model::parse(&b), Err(BlobError::Truncated));
    let mut b = good.clone();
    b[100] ^= 0xFF;
    assert_eq!(Model::parse(&b), Err(BlobError::Crc));
}

#[test]
fn layer_checks() {
    let good = conv_spec().to_bytes().unwrap();
    let l0 = HEADER_LEN;
    let edit = |at: usize, v: &[u8]| {
        let mut b = good.clone();
        b[at..at + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|_| ())
    };
    assert_eq!(edit(l0, &[9]), Err(BlobError::BadLayer(0)));
    assert_eq!(edit(l0 + 1, &[4]), Err(BlobError::BadLayer(0)));
    assert_eq!(edit(l0 + 2, &[3]), Err(BlobError::BadLayer(0)));
    assert_eq!(edit(l0 + 3, &[1]), Err(BlobError::BadLayer(0)));
    assert_eq!(edit(l0 + 24, &[40]), Err(BlobError::BadLayer(0)));
    assert_eq!(edit(l0 + 25, &[0xFF]), Err(BlobError::BadLayer(0)));
    // The first layer must take the two head angles.
    assert_eq!(edit(l0 + 4, &[3, 0]), Err(BlobError::LayerShape(0)));
    // Changing the declared output without the weights is a size mismatch.
    assert_eq!(edit(l0 + 10, &[3, 0]), Err(BlobError::LayerShape(0)));
    // Second layer: ConvTranspose2d at l0 + 32 + 2*8*2 (i16 weights) + 8*4 (bias).
    let l1 = l0 + 32 + 32 + 32;
    assert_eq!(good[l1], 1, "layer 1 kind");
    // Input channels that do not chain: the weight count changes too, so claim stride 3.
    assert_eq!(edit(l1 + 17, &[3]), Err(BlobError::LayerShape(1)));
    assert_eq!(edit(l1 + 16, &[0]), Err(BlobError::LayerShape(1)));
    assert_eq!(edit(l1 + 8, &[3, 0]), Err(BlobError::LayerShape(1)));
    // A chain break: layer 1 says its input is 2x2x2 but with h and w swapped to 1x4 it
    // mismatches the weight count; instead break layer 2's input channel count below.
    let l2 = l1 + 32 + 64 + 4;
    assert_eq!(good[l2], 2, "layer 2 kind");
    // Layer 2 input 1x4x4 -> claim 1x4x4 but output 1x9x8: shape error.
    assert_eq!(edit(l2 + 12, &[9, 0]), Err(BlobError::LayerShape(2)));
    let l3 = l2 + 32 + 12 + 4;
    assert_eq!(good[l3], 3, "layer 3 kind");
    // Crop window past the input.
    assert_eq!(edit(l3 + 20, &[6, 0]), Err(BlobError::LayerShape(3)));
    // Crop with an activation.
    assert_eq!(edit(l3 + 1, &[1]), Err(BlobError::LayerShape(3)));
    // Crop to another size than the face.
    assert_eq!(edit(l3 + 12, &[2, 0]), Err(BlobError::ModelShape));
}

#[test]
fn chain_and_activation_limits() {
    let mut s = conv_spec();
    s.layers[2].input = sh(1, 2, 8);
    s.layers[2].output = sh(1, 4, 16);
    s.layers[3].input = sh(1, 4, 16);
    assert_eq!(s.to_bytes(), Err(BlobError::Chain(2)));

    let mut s = mlp_spec();
    s.layers[0] = dense(sh(2, 1, 1), sh(1, 1, MAX_ACTIVATION_LEN as u16 + 1), Activation::Tanh, false);
    s.layers[1] =
        dense(sh(1, 1, MAX_ACTIVATION_LEN as u16 + 1), sh(1, 3, 4), Activation::Sigmoid, false);
    assert_eq!(s.to_bytes(), Err(BlobError::ActivationTooLarge(0)));

    let mut s = mlp_spec();
    s.layers.pop();
    assert_eq!(s.to_bytes(), Err(BlobError::ModelShape));
}

#[test]
fn reach_checks() {
    let mut s = mlp_spec();
    s.reach.b2[0] = f32::NAN;
    assert_eq!(s.to_bytes(), Err(BlobError::Reach));
    let mut s = mlp_spec();
    s.reach.in_min[1] = s.reach.in_max[1];
    assert_eq!(s.to_bytes(), Err(BlobError::Reach));
    assert_eq!(
        Reach::from_parts(&[0.0; 19], &[0.0; 10], &[0.0; 50], &[0.0; 5], [0.0; 2], [1.0; 2], [0.0; 5], [1.0; 5]),
        Err(BlobError::Reach)
    );
}

#[test]
fn template_and_trailing_checks() {
    let mut s = mlp_spec();
    s.template = Some((0, 3, vec![]));
    assert_eq!(s.to_bytes(), Err(BlobError::Template));
    // Claim a template in the flags of a blob that has none: the reader runs off the end.
    let mut b = conv_spec().to_bytes().unwrap();
    b[22] = 1;
    recrc(&mut b);
    assert_eq!(Model::parse(&b), Err(BlobError::Truncated));
    // Extra bytes inside total_len.
    let mut b = conv_spec().to_bytes().unwrap();
    b.extend_from_slice(&[0; 4]);
    let n = b.len() as u32;
    b[8..12].copy_from_slice(&n.to_le_bytes());
    recrc(&mut b);
    assert_eq!(Model::parse(&b), Err(BlobError::TrailingBytes));
}

#[test]
fn error_codes_are_distinct() {
    let all = [
        BlobError::Truncated,
        BlobError::BadMagic,
        BlobError::UnsupportedVersion(2),
        BlobError::BadHeader,
        BlobError::LengthMismatch,
        BlobError::Crc,
        BlobError::FaceSize,
        BlobError::TooManyLayers,
        BlobError::BadLayer(1),
        BlobError::LayerShape(1),
        BlobError::Chain(1),
        BlobError::ActivationTooLarge(1),
        BlobError::ModelShape,
        BlobError::Novelty,
        BlobError::Reach,
        BlobError::Template,
        BlobError::TrailingBytes,
        BlobError::SelfGate,
        BlobError::PoseStats,
        BlobError::Chroma,
    ];
    let mut codes: Vec<u32> = all.iter().map(|e| e.code()).collect();
    codes.sort();
    codes.dedup();
    assert_eq!(codes.len(), all.len());
}

proptest! {
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = Model::parse(&bytes);
    }

    /// Random edits behind a fixed CRC reach every validator; none may panic, and whatever
    /// parses must have self-consistent tables.
    #[test]
    fn edits_behind_the_crc_never_panic(edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6)) {
        let mut b = conv_spec().to_bytes().unwrap();
        let n = b.len();
        for (at, v) in edits {
            let i = 16 + at.index(n - 16);
            b[i] = v;
        }
        recrc(&mut b);
        let parsed = Model::parse(&b);
        if let Ok(m) = parsed {
            for l in &m.layers {
                let _ = (0..l.weight_count()).map(|i| l.weight(i)).sum::<i32>();
                let _ = (0..l.bias_count()).map(|i| l.bias(i)).sum::<i32>();
            }
            prop_assert_eq!(m.mu.len(), m.face_pixels());
        }
    }

    #[test]
    fn novelty_round_trips(t in 0.01f32..100.0, area in 1u16.., var: bool, two: bool) {
        let mut s = mlp_spec();
        s.novelty.threshold = t;
        s.novelty.min_area = area;
        s.novelty.normalisation = if var { Normalisation::Variance } else { Normalisation::StdDev };
        s.novelty.sided = if two { Sided::Two } else { Sided::One };
        let b = s.to_bytes().unwrap();
        let m = Model::parse(&b).unwrap();
        prop_assert_eq!(m.novelty, s.novelty);
    }
}

/// 2 -> 8 -> 4x2x3 (i16, blocked) -> convT k4 s2 p1 -> 1x4x6.
fn blocked_spec() -> ModelSpec {
    let mut s = mlp_spec();
    s.template = None;
    s.face_h = 4;
    s.face_w = 6;
    s.mu = vec![0; 24];
    s.sigma = vec![256; 24];
    let mut convt = dense(sh(4, 2, 3), sh(1, 4, 6), Activation::Sigmoid, true);
    convt.kind = LayerKind::ConvTranspose2d;
    convt.kernel = 4;
    convt.stride = 2;
    convt.padding = 1;
    convt.weights = Weights::I16((0..4 * 16).map(|i| i as i16 - 30).collect());
    convt.bias = vec![3];
    s.layers = vec![
        dense(sh(2, 1, 1), sh(8, 1, 1), Activation::Tanh, true),
        dense(sh(8, 1, 1), sh(4, 2, 3), Activation::Tanh, true),
        convt,
    ];
    s
}

#[test]
fn blocked_order_round_trip() {
    let spec = blocked_spec();
    assert_eq!((0..3).map(|i| spec.blocked(i)).collect::<Vec<_>>(), [false, true, false]);
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[2, 0], "a blocked layer makes a version 2 blob");
    let m = Model::parse(&bytes).unwrap();
    let l = &m.layers[1];
    assert_eq!(l.order, WeightOrder::Blocked);
    assert!(!l.torch_order() && m.layers[0].torch_order());
    let Weights::I16(w) = &spec.layers[1].weights else { unreachable!() };
    for (i, &v) in w.iter().enumerate() {
        assert_eq!(l.weight(i), v as i32, "weight {i}");
    }
    for (i, &b) in spec.layers[1].bias.iter().enumerate() {
        assert_eq!(l.bias(i), b, "bias {i}");
    }
    // Stored per pixel: bias of (c 1, pixel 2) at 2 * 4 + 1.
    assert_eq!(l.bias[36..40], spec.layers[1].bias[8].to_le_bytes());
    // Output (c 1, y 0, x 2) = row 8, input 5: pixel 2, block 0, channel 1 -> (2*1*4 + 1)*8 + 5.
    assert_eq!(l.stored_index(8 * 8 + 5), 77);
    // Every stored place is used once.
    let mut seen = vec![false; w.len()];
    (0..w.len()).for_each(|i| seen[l.stored_index(i)] = true);
    assert!(seen.iter().all(|&s| s));
    // i8 weights too; without a convolution after it, PyTorch order (version 1).
    let mut s8 = spec.clone();
    s8.layers[1] = dense(sh(8, 1, 1), sh(4, 2, 3), Activation::Tanh, false);
    assert!(s8.blocked(1));
    let m8 = s8.to_bytes().unwrap();
    let l8 = &Model::parse(&m8).unwrap().layers[1];
    let Weights::I8(w8) = &s8.layers[1].weights else { unreachable!() };
    assert!(w8.iter().enumerate().all(|(i, &v)| l8.weight(i) == v as i32));
    let mut flat = s8.clone();
    flat.layers.truncate(2);
    flat.layers[1].output = sh(1, 4, 6);
    assert!(!flat.blocked(1));
    assert_eq!(&flat.to_bytes().unwrap()[4..6], &[1, 0]);
}

#[test]
fn blocked_order_checks() {
    let good = blocked_spec().to_bytes().unwrap();
    // Descriptor byte 3 of layer 1 (after layer 0: 32 + 16 weights*2 + 8 biases*4).
    let at = HEADER_LEN + LAYER_DESC_LEN + 32 + 32 + 3;
    assert_eq!(good[at], 1);
    let edit = |at: usize, v: &[u8]| {
        let mut b = good.clone();
        b[at..at + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|_| ())
    };
    assert_eq!(edit(at, &[0]), Ok(()), "PyTorch order is still a valid layout");
    assert_eq!(edit(at, &[2]), Err(BlobError::BadLayer(1)));
    assert_eq!(edit(4, &[1, 0]), Err(BlobError::BadLayer(1)), "version 1 has no order byte");
    // Blocked is for Dense layers only, and the first layer's 2 inputs are not a block.
    assert_eq!(edit(HEADER_LEN + 3, &[1]), Err(BlobError::BadLayer(0)));
}

#[test]
fn merge_fields_need_version_3_and_valid_values() {
    let mut spec = mlp_spec();
    let plain = spec.to_bytes().unwrap();
    assert_eq!(&plain[4..6], &[1, 0], "no merge: version 1");
    assert_eq!(&plain[36..40], &[0; 4]);
    spec.novelty.merge = Merge { margin: 4, fragment: 3 };
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[3, 0], "a merging blob is version 3");
    assert_eq!(&bytes[36..40], &[4, 0, 3, 0]);
    assert_eq!(Model::parse(&bytes).unwrap().novelty.merge, Merge { margin: 4, fragment: 3 });
    let edit = |at: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at..at + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.novelty.merge)
    };
    // Older versions have no merge fields: their bytes must stay zero.
    assert_eq!(edit(4, &[2, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(37, &[1]), Err(BlobError::BadHeader));
    // Margin without fragment size, fragment without margin, fragment above min_area (30),
    // margin above the limit.
    assert_eq!(edit(38, &[0, 0]), Err(BlobError::Novelty));
    assert_eq!(edit(36, &[0]), Err(BlobError::Novelty));
    assert_eq!(edit(38, &[31, 0]), Err(BlobError::Novelty));
    assert_eq!(edit(36, &[MAX_MERGE_MARGIN + 1]), Err(BlobError::Novelty));
    assert_eq!(edit(38, &[30, 0]), Ok(Merge { margin: 4, fragment: 30 }));
    assert_eq!(edit(36, &[0, 0, 0, 0]), Ok(Merge::OFF), "version 3 may also not merge");
    // The writer refuses what the parser refuses.
    spec.novelty.merge = Merge { margin: 2, fragment: 0 };
    assert_eq!(spec.to_bytes(), Err(BlobError::Novelty));
}

#[test]
fn subpixel_crop_flag_needs_version_4_and_a_template() {
    let mut spec = mlp_spec();
    let plain = spec.to_bytes().unwrap();
    assert_eq!(Model::parse(&plain).unwrap().template.map(|t| t.crop), Some(CropMode::Pixel));
    spec.crop = CropMode::Subpixel;
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[4, 0], "a sub-pixel blob is version 4");
    assert_eq!(&bytes[22..24], &[3, 0], "template and sub-pixel flags");
    let t = Model::parse(&bytes).unwrap().template.unwrap();
    assert_eq!((t.h, t.w, t.pixels, t.crop), (2, 3, &[1u8, 2, 3, 4, 5, 6][..], CropMode::Subpixel));
    let edit = |at: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at..at + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.template.map(|t| t.crop))
    };
    // Version 3 has no sub-pixel flag; the flag needs the template; unknown flags are refused.
    assert_eq!(edit(4, &[3, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(22, &[2, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(22, &[11, 0]), Err(BlobError::BadHeader));
    // Version 4 may also crop whole pixels.
    assert_eq!(edit(22, &[1, 0]), Ok(Some(CropMode::Pixel)));
    // The writer refuses a sub-pixel crop without a template to crop with.
    spec.template = None;
    assert_eq!(spec.to_bytes(), Err(BlobError::Template));
}

#[test]
fn error_pool_needs_version_5_flag_bit_4_and_a_radius_in_range() {
    let mut spec = mlp_spec();
    let plain = spec.to_bytes().unwrap();
    assert_eq!(Model::parse(&plain).unwrap().novelty.pool, 0);
    assert_eq!(plain[37], 0);
    spec.novelty.pool = 2;
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[5, 0], "a pooling blob is version 5");
    assert_eq!(&bytes[22..24], &[17, 0], "template and pool flags");
    assert_eq!(bytes[37], 2);
    assert_eq!(Model::parse(&bytes).unwrap().novelty.pool, 2);
    // Only header bytes differ from the blob that does not pool.
    let differ: Vec<usize> = (0..plain.len()).filter(|&i| plain[i] != bytes[i]).collect();
    assert!(differ.iter().all(|&i| [4, 12, 13, 14, 15, 22, 37].contains(&i)), "{differ:?}");
    let edit = |at: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at..at + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.novelty.pool)
    };
    // Version 4 has no pool; a radius without the flag, 0 or over the limit with it, an unknown
    // bit (6), and bit 3 (the self gate) without its section are refused.
    assert_eq!(edit(4, &[4, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(22, &[1, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(37, &[0]), Err(BlobError::Novelty));
    assert_eq!(edit(37, &[MAX_POOL + 1]), Err(BlobError::Novelty));
    assert_eq!(edit(37, &[MAX_POOL]), Ok(MAX_POOL));
    assert_eq!(edit(22, &[81, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(22, &[25, 0]), Err(BlobError::Truncated));
    // Version 5 carries a self gate or pooling: the plain blob as version 5 is refused.
    let mut b = plain.clone();
    b[4] = 5;
    recrc(&mut b);
    assert_eq!(Model::parse(&b).map(|m| m.novelty.pool), Err(BlobError::BadHeader));
    // The writer refuses what the parser refuses.
    spec.novelty.pool = MAX_POOL + 1;
    assert_eq!(spec.to_bytes(), Err(BlobError::Novelty));
}

#[test]
fn crop_mode_names_round_trip() {
    for m in [CropMode::Pixel, CropMode::Subpixel] {
        assert_eq!(m.name().parse::<CropMode>(), Ok(m));
    }
    assert!("bilinear".parse::<CropMode>().is_err());
}

fn region() -> PoseRegion {
    PoseRegion { centre: [0.0, -0.01], radius: 0.01, threshold: 2.5, merge: Merge { margin: 4, fragment: 2 } }
}

#[test]
fn pose_region_round_trips_and_needs_version_4() {
    let mut spec = mlp_spec();
    spec.region = Some(region());
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[4, 0], "a blob with a region is version 4");
    assert_eq!(&bytes[22..24], &[5, 0], "template and region flags");
    let m = Model::parse(&bytes).unwrap();
    assert_eq!(m.region, Some(region()));
    assert_eq!(m.template.map(|t| t.crop), Some(CropMode::Pixel));
    // Without a template it still carries the region.
    spec.template = None;
    assert_eq!(Model::parse(&spec.to_bytes().unwrap()).unwrap().region, Some(region()));
    // The region's 20 bytes sit right after the reach floats, before the template.
    let tail = 2 * 12 + 2 * 12 + 4 * REACH_FLOATS;
    let at = bytes.len() - 12 - 20;
    assert!(at > tail);
    let edit = |at_: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at_..at_ + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.region)
    };
    assert_eq!(edit(at, &0.0f32.to_le_bytes()), Ok(Some(PoseRegion { centre: [0.0, -0.01], ..region() })));
    assert_eq!(edit(at + 8, &0.5f32.to_le_bytes()), Ok(Some(PoseRegion { radius: 0.5, ..region() })));
    // Version 3 has no region; bad values are refused.
    assert_eq!(edit(4, &[3, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(at, &f32::NAN.to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(at + 8, &0.0f32.to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(at + 8, &0.51f32.to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(at + 12, &(-1.0f32).to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(at + 12, &f32::INFINITY.to_le_bytes()), Err(BlobError::Novelty));
    assert_eq!(edit(at + 16, &[4, 1]), Err(BlobError::BadHeader));
    assert_eq!(edit(at + 18, &[31, 0]), Err(BlobError::Novelty), "fragment above min_area 30");
    assert_eq!(edit(at + 16, &[0, 0, 0, 0]), Ok(Some(PoseRegion { merge: Merge::OFF, ..region() })));
    // Cut short inside the region.
    let mut short = bytes[..at + 10].to_vec();
    let n = short.len() as u32;
    short[8..12].copy_from_slice(&n.to_le_bytes());
    recrc(&mut short);
    assert_eq!(Model::parse(&short), Err(BlobError::Truncated));
    // The writer refuses what the parser refuses.
    spec.region = Some(PoseRegion { radius: -1.0, ..region() });
    assert_eq!(spec.to_bytes(), Err(BlobError::Novelty));
}

#[test]
fn pose_region_contains_the_disc_around_its_centre() {
    let g = region();
    assert!(g.contains([0.0, -0.01]));
    assert!(g.contains([0.006, -0.017]), "distance 0.0092");
    assert!(!g.contains([0.0075, -0.0175]));
    assert!(!g.contains([0.0, 0.001]));
    assert!(!g.contains([f32::NAN, -0.01]));
}

fn gate() -> SelfGate {
    SelfGate {
        amplitude: 0.07,
        gain: -271.5,
        gain_tol: 0.06,
        rest_tol: 1.5,
        hold_tol: 0.5,
        level_tol: 0.25,
        line_tol: None,
        joint_tol: None,
        latency_ms: 100,
        timeout_ms: 2000,
        min_frames: 2,
    }
}

#[test]
fn self_gate_section_is_literal_last_and_removable() {
    for spec in [mlp_spec(), { let mut s = mlp_spec(); s.region = Some(region()); s }, conv_spec()] {
        let plain = spec.to_bytes().unwrap();
        let gated = set_self_gate(&plain, Some(gate())).unwrap();
        assert_eq!(&gated[4..6], &[5, 0]);
        let flags = u16::from_le_bytes([plain[22], plain[23]]);
        assert_eq!(u16::from_le_bytes([gated[22], gated[23]]), flags | 8);
        assert_eq!(gated.len(), plain.len() + SELF_GATE_LEN);
        // Everything but the header's version, length, CRC and flags is unchanged.
        assert_eq!(&gated[24..plain.len()], &plain[24..]);
        let mut lit = Vec::new();
        for f in [0.07f32, -271.5, 0.06, 1.5] {
            lit.extend_from_slice(&f.to_le_bytes());
        }
        // Layout 1: the hold and level tolerances follow.
        lit.extend_from_slice(&[100, 0, 0xD0, 0x07, 2, 1, 0, 0]);
        lit.extend_from_slice(&[0, 0, 0, 0x3F, 0, 0, 0x80, 0x3E]);
        assert_eq!(&gated[plain.len()..], &lit[..]);
        let m = Model::parse(&gated).unwrap();
        assert_eq!(m.self_gate, Some(gate()));
        assert_eq!(m.region, spec.region);
        // Taking it off gives back the writer's bytes exactly; replacing it is idempotent.
        assert_eq!(set_self_gate(&gated, None).unwrap(), plain);
        assert_eq!(set_self_gate(&plain, None).unwrap(), plain);
        assert_eq!(set_self_gate(&gated, Some(gate())).unwrap(), gated);
    }
}

#[test]
fn self_gate_values_are_checked() {
    let plain = mlp_spec().to_bytes().unwrap();
    let gated = set_self_gate(&plain, Some(gate())).unwrap();
    let at = plain.len();
    let edit = |at_: usize, v: &[u8]| {
        let mut b = gated.clone();
        b[at_..at_ + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.self_gate)
    };
    assert_eq!(edit(at, &0.1f32.to_le_bytes()), Ok(Some(SelfGate { amplitude: 0.1, ..gate() })));
    for (off, bad) in [
        (0, f32::NAN),
        (0, 0.0),
        (0, 0.11),
        (4, f32::INFINITY),
        (4, 0.5),
        (8, 0.0),
        (8, 1.0),
        (12, -1.0),
        (12, 65.0),
        (24, 0.0),
        (24, f32::NAN),
        (28, -0.25),
        (28, 65.0),
    ] {
        assert_eq!(edit(at + off, &bad.to_le_bytes()), Err(BlobError::SelfGate), "{off} {bad}");
    }
    assert_eq!(edit(at + 16, &[0, 0]), Err(BlobError::SelfGate), "latency 0");
    assert_eq!(edit(at + 18, &[99, 0]), Err(BlobError::SelfGate), "timeout under 100 ms");
    assert_eq!(edit(at + 18, &[0xB9, 0x0B]), Err(BlobError::SelfGate), "timeout 3001 ms");
    assert_eq!(edit(at + 20, &[0]), Err(BlobError::SelfGate), "no frames");
    assert_eq!(edit(at + 20, &[9]), Err(BlobError::SelfGate), "9 frames");
    assert_eq!(edit(at + 21, &[4]), Err(BlobError::BadHeader), "layout 4");
    assert_eq!(edit(at + 22, &[1]), Err(BlobError::BadHeader), "reserved");
    assert_eq!(edit(at + 23, &[1]), Err(BlobError::BadHeader), "reserved");
    // Layout 0 says the section ends at 24 bytes: 8 bytes too many.
    assert_eq!(edit(at + 21, &[0]), Err(BlobError::TrailingBytes), "layout 0, 32 bytes");
    // The flag needs version 5, and version 5 the flag.
    assert_eq!(edit(4, &[4, 0]), Err(BlobError::BadHeader));
    // Cut short inside the section.
    let mut short = gated[..at + 10].to_vec();
    let n = short.len() as u32;
    short[8..12].copy_from_slice(&n.to_le_bytes());
    recrc(&mut short);
    assert_eq!(Model::parse(&short), Err(BlobError::Truncated));
    for cut in at..gated.len() {
        assert!(Model::parse(&gated[..cut]).is_err());
    }
    assert_eq!(set_self_gate(&plain, Some(SelfGate { min_frames: 0, ..gate() })), Err(BlobError::SelfGate));
}

fn grid() -> PoseGrid {
    PoseGrid { bins: [2, 3], lo: [-0.1, -0.09], hi: [0.1, 0.09] }
}

/// mlp_spec (3 x 4 face) with pose statistics on `grid()`: cell k's mu is 100 k + pixel,
/// its sigma 1000 + 100 k + pixel.
fn pose_spec() -> ModelSpec {
    let mut s = mlp_spec();
    let cells = (0..6u16)
        .map(|k| ((0..12).map(|i| 100 * k + i).collect(), (0..12).map(|i| 1000 + 100 * k + i).collect()))
        .collect();
    s.pose = Some((grid(), cells));
    s
}

#[test]
fn pose_grid_cells_clamp_and_refuse_non_finite_poses() {
    let g = grid();
    assert_eq!(g.len(), 6);
    // Yaw cells split at 0, pitch cells at -0.03 and 0.03; pitch-major.
    assert_eq!(g.bin([-0.05, -0.05]), Some(0));
    assert_eq!(g.bin([0.05, -0.05]), Some(1));
    assert_eq!(g.bin([-0.05, 0.0]), Some(2));
    assert_eq!(g.bin([0.0, 0.0]), Some(3));
    assert_eq!(g.bin([0.05, 0.08]), Some(5));
    // Outside the grid: the nearest cell.
    assert_eq!(g.bin([-3.0, -3.0]), Some(0));
    assert_eq!(g.bin([3.0, 3.0]), Some(5));
    assert_eq!(g.bin([0.1, 0.09]), Some(5));
    assert_eq!(g.bin([f32::NAN, 0.0]), None);
    assert_eq!(g.bin([0.0, f32::INFINITY]), None);
    assert!(g.is_valid());
    for bad in [
        PoseGrid { bins: [1, 1], ..g },
        PoseGrid { bins: [0, 3], ..g },
        PoseGrid { bins: [MAX_POSE_BINS + 1, 2], ..g },
        PoseGrid { lo: [0.1, -0.09], ..g },
        PoseGrid { hi: [0.1, f32::NAN], ..g },
        PoseGrid { lo: [-3.3, -0.09], ..g },
    ] {
        assert!(!bad.is_valid(), "{bad:?}");
    }
}

#[test]
fn pose_stats_round_trip_as_a_literal_section_before_the_self_gate() {
    let plain = mlp_spec().to_bytes().unwrap();
    let spec = pose_spec();
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[5, 0], "pose statistics are version 5");
    assert_eq!(&bytes[22..24], &[33, 0], "template and pose flags");
    // The plain blob, then the section: 20 bytes of grid, 12 tables of 12 u16 (24 bytes each).
    assert_eq!(bytes.len(), plain.len() + 20 + 12 * 24);
    assert_eq!(&bytes[24..plain.len()], &plain[24..]);
    let at = plain.len();
    assert_eq!(&bytes[at..at + 4], &[2, 3, 0, 0]);
    assert_eq!(&bytes[at + 4..at + 8], &(-0.1f32).to_le_bytes());
    assert_eq!(&bytes[at + 16..at + 20], &0.09f32.to_le_bytes());
    // Cell 1's sigma (the fourth table), pixel 2: 1102.
    assert_eq!(&bytes[at + 20 + 3 * 24 + 4..at + 20 + 3 * 24 + 6], &1102u16.to_le_bytes());
    let m = Model::parse(&bytes).unwrap();
    let p = m.pose.unwrap();
    assert_eq!(p.grid, grid());
    for k in 0..6 {
        let (mu, sigma) = p.tables(k).unwrap();
        assert_eq!(mu.iter().collect::<Vec<_>>(), spec.pose.as_ref().unwrap().1[k].0);
        assert_eq!(sigma.get(11), 1000 + 100 * k as u16 + 11);
    }
    assert!(p.tables(6).is_none());
    // stats_at: the cell's tables, the header's for a non-finite pose.
    let (mu, sigma, cell) = m.stats_at([0.05, 0.08]);
    assert_eq!((mu.get(0), sigma.get(0), cell), (500, 1500, 6));
    let (mu, _, cell) = m.stats_at([f32::NAN, 0.0]);
    assert_eq!((mu.get(11), cell), (3300, 0));
    assert_eq!(Model::parse(&plain).unwrap().stats_at([0.0, 0.0]).2, 0);
    // A self gate goes after it, and comes off again.
    let gated = set_self_gate(&bytes, Some(gate())).unwrap();
    assert_eq!(&gated[24..bytes.len()], &bytes[24..]);
    assert_eq!(Model::parse(&gated).unwrap().pose, Model::parse(&bytes).unwrap().pose);
    assert_eq!(set_self_gate(&gated, None).unwrap(), bytes);
}

#[test]
fn pose_stats_are_checked_and_every_truncation_refused() {
    let bytes = pose_spec().to_bytes().unwrap();
    let at = mlp_spec().to_bytes().unwrap().len();
    let edit = |at_: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at_..at_ + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.pose.map(|p| p.grid))
    };
    assert_eq!(edit(at, &[3, 2]), Ok(Some(PoseGrid { bins: [3, 2], ..grid() })));
    assert_eq!(edit(at, &[1, 1]), Err(BlobError::PoseStats));
    assert_eq!(edit(at, &[5, 1]), Err(BlobError::PoseStats));
    assert_eq!(edit(at, &[4, 3]), Err(BlobError::Truncated), "more cells than tables");
    assert_eq!(edit(at, &[1, 3]), Err(BlobError::TrailingBytes), "fewer cells than tables");
    assert_eq!(edit(at + 2, &[1]), Err(BlobError::BadHeader), "reserved");
    assert_eq!(edit(at + 4, &0.2f32.to_le_bytes()), Err(BlobError::PoseStats), "lo above hi");
    assert_eq!(edit(at + 8, &f32::NAN.to_le_bytes()), Err(BlobError::PoseStats));
    // The flag needs version 5; without the flag the section is trailing bytes.
    assert_eq!(edit(4, &[4, 0]), Err(BlobError::BadHeader));
    assert_eq!(edit(22, &[1, 0]), Err(BlobError::BadHeader), "version 5 without a bit of its own");
    for cut in 0..bytes.len() {
        assert!(Model::parse(&bytes[..cut]).is_err(), "accepted {cut} of {}", bytes.len());
    }
    // The writer refuses what the parser refuses: a cell count or table size off the grid.
    let mut spec = pose_spec();
    spec.pose.as_mut().unwrap().1.pop();
    assert_eq!(spec.to_bytes(), Err(BlobError::PoseStats));
    let mut spec = pose_spec();
    spec.pose.as_mut().unwrap().1[2].1.push(7);
    assert_eq!(spec.to_bytes(), Err(BlobError::PoseStats));
    let mut spec = pose_spec();
    spec.pose.as_mut().unwrap().0.bins = [1, 1];
    assert!(spec.to_bytes().is_err());
}

/// `plain` with a layout-0 self-gate section (24 bytes, one tolerance), as blobs were written
/// before the hold and level tolerances: amplitude 0.07, gain -271.5, gain_tol 0.06,
/// rest_tol 1.5, latency 100 ms, timeout 2000 ms, 2 frames.
fn layout0(plain: &[u8]) -> Vec<u8> {
    let mut b = plain.to_vec();
    for f in [0.07f32, -271.5, 0.06, 1.5] {
        b.extend_from_slice(&f.to_le_bytes());
    }
    b.extend_from_slice(&[100, 0, 0xD0, 0x07, 2, 0, 0, 0]);
    b[4..6].copy_from_slice(&[5, 0]);
    let flags = u16::from_le_bytes([b[22], b[23]]) | 8;
    b[22..24].copy_from_slice(&flags.to_le_bytes());
    let n = b.len() as u32;
    b[8..12].copy_from_slice(&n.to_le_bytes());
    recrc(&mut b);
    b
}

#[test]
fn a_layout_0_self_gate_has_one_tolerance_and_is_replaced_whole() {
    for spec in [mlp_spec(), conv_spec()] {
        let plain = spec.to_bytes().unwrap();
        let old = layout0(&plain);
        assert_eq!(old.len(), plain.len() + SELF_GATE_LEN_V0);
        let m = Model::parse(&old).unwrap();
        let one = SelfGate { hold_tol: 1.5, level_tol: 1.5, ..gate() };
        assert_eq!(m.self_gate, Some(one));
        // Removing or replacing it takes its 24 bytes, not the writer's 32.
        assert_eq!(set_self_gate(&old, None).unwrap(), plain);
        let new = set_self_gate(&old, Some(gate())).unwrap();
        assert_eq!(new, set_self_gate(&plain, Some(gate())).unwrap());
        assert_eq!(new.len(), plain.len() + SELF_GATE_LEN);
        // Layout 1 with only 24 bytes: the tolerances it promises are missing.
        let mut short = old.clone();
        short[plain.len() + 21] = 1;
        recrc(&mut short);
        assert_eq!(Model::parse(&short), Err(BlobError::Truncated));
        for cut in plain.len()..old.len() {
            assert!(Model::parse(&old[..cut]).is_err());
        }
    }
}

#[test]
fn a_layout_2_self_gate_carries_the_line_tolerance_and_older_layouts_still_read() {
    let plain = mlp_spec().to_bytes().unwrap();
    let three = SelfGate { line_tol: Some(0.25), ..gate() };
    let gated = set_self_gate(&plain, Some(three)).unwrap();
    assert_eq!(gated.len(), plain.len() + SELF_GATE_LEN_V2);
    // The layout byte says 2 and the line tolerance (0.25 = 0x3E800000) follows the others.
    assert_eq!(gated[plain.len() + 21], 2);
    assert_eq!(&gated[plain.len() + 24..], &[0, 0, 0, 0x3F, 0, 0, 0x80, 0x3E, 0, 0, 0x80, 0x3E]);
    assert_eq!(Model::parse(&gated).unwrap().self_gate, Some(three));
    assert_eq!(set_self_gate(&gated, None).unwrap(), plain);
    // A two-stage gate is still written as layout 1, and a layout 1 or 0 blob reads as before.
    let one = set_self_gate(&plain, Some(gate())).unwrap();
    assert_eq!((one.len(), one[plain.len() + 21]), (plain.len() + SELF_GATE_LEN, 1));
    assert_eq!(Model::parse(&one).unwrap().self_gate.unwrap().line_tol, None);
    assert_eq!(Model::parse(&layout0(&plain)).unwrap().self_gate.unwrap().line_tol, None);
    // Replacing a layout-1 gate with a layout-2 one gives the same bytes as adding it.
    assert_eq!(set_self_gate(&one, Some(three)).unwrap(), gated);
    // Out of range or not finite: refused.
    for bad in [0.0f32, -0.5, 65.0, f32::NAN, f32::INFINITY] {
        let mut b = gated.clone();
        let at = plain.len() + 32;
        b[at..at + 4].copy_from_slice(&bad.to_le_bytes());
        recrc(&mut b);
        assert_eq!(Model::parse(&b).map(|m| m.self_gate), Err(BlobError::SelfGate), "{bad}");
    }
    assert_eq!(set_self_gate(&plain, Some(SelfGate { line_tol: Some(f32::NAN), ..gate() })), Err(BlobError::SelfGate));
    // Layout 2 with only layout 1's 32 bytes: the line tolerance is missing.
    let mut short = one.clone();
    short[plain.len() + 21] = 2;
    recrc(&mut short);
    assert_eq!(Model::parse(&short), Err(BlobError::Truncated));
    for cut in plain.len()..gated.len() {
        assert!(Model::parse(&gated[..cut]).is_err());
    }
}

#[test]
fn a_layout_3_self_gate_carries_the_joint_bound_after_the_line_tolerance() {
    let plain = mlp_spec().to_bytes().unwrap();
    let three = SelfGate { line_tol: Some(0.25), ..gate() };
    let joint = SelfGate { joint_tol: Some(0.875), ..three };
    let gated = set_self_gate(&plain, Some(joint)).unwrap();
    assert_eq!(gated.len(), plain.len() + SELF_GATE_LEN_V3);
    // The layout byte says 3; hold 0.5, level 0.25, line 0.25, then the joint bound (0.875 =
    // 0x3F600000).
    assert_eq!(gated[plain.len() + 21], 3);
    assert_eq!(&gated[plain.len() + 24..], &[0, 0, 0, 0x3F, 0, 0, 0x80, 0x3E, 0, 0, 0x80, 0x3E, 0, 0, 0x60, 0x3F]);
    assert_eq!(Model::parse(&gated).unwrap().self_gate, Some(joint));
    assert_eq!(set_self_gate(&gated, None).unwrap(), plain);
    // Without a joint bound the writer still makes layout 2, byte for byte as before.
    let two = set_self_gate(&plain, Some(three)).unwrap();
    assert_eq!((two.len(), two[plain.len() + 21]), (plain.len() + SELF_GATE_LEN_V2, 2));
    assert_eq!(Model::parse(&two).unwrap().self_gate.unwrap().joint_tol, None);
    assert_eq!(set_self_gate(&two, Some(joint)).unwrap(), gated);
    // Out of range or not finite: refused, when read and when written; and a joint bound needs
    // the return stage's line (a two-stage gate has no layout for it).
    for bad in [0.0f32, -0.5, 65.0, f32::NAN, f32::INFINITY] {
        let mut b = gated.clone();
        let at = plain.len() + 36;
        b[at..at + 4].copy_from_slice(&bad.to_le_bytes());
        recrc(&mut b);
        assert_eq!(Model::parse(&b).map(|m| m.self_gate), Err(BlobError::SelfGate), "{bad}");
        assert_eq!(set_self_gate(&plain, Some(SelfGate { joint_tol: Some(bad), ..three })), Err(BlobError::SelfGate), "{bad}");
    }
    assert_eq!(set_self_gate(&plain, Some(SelfGate { joint_tol: Some(0.875), ..gate() })), Err(BlobError::SelfGate));
    // Layout 3 with only layout 2's 36 bytes: the joint bound is missing.
    let mut short = two.clone();
    short[plain.len() + 21] = 3;
    recrc(&mut short);
    assert_eq!(Model::parse(&short), Err(BlobError::Truncated));
    for cut in plain.len()..gated.len() {
        assert!(Model::parse(&gated[..cut]).is_err());
    }
}

#[test]
fn frame_spread_is_a_literal_section_after_the_pose_statistics_and_before_the_self_gate() {
    let posed = pose_spec().to_bytes().unwrap();
    let mut spec = pose_spec();
    spec.novelty.spread_ref = Some(4.75);
    let bytes = spec.to_bytes().unwrap();
    assert_eq!(&bytes[4..6], &[6, 0], "the frame spread is version 6");
    assert_eq!(&bytes[22..24], &[33 | 64, 0], "template, pose and spread flags");
    assert_eq!(bytes.len(), posed.len() + 4);
    assert_eq!(&bytes[24..posed.len()], &posed[24..]);
    assert_eq!(&bytes[posed.len()..], &4.75f32.to_le_bytes());
    let m = Model::parse(&bytes).unwrap();
    assert_eq!(m.novelty.spread_ref, Some(4.75));
    assert_eq!(m.pose, Model::parse(&posed).unwrap().pose);
    assert_eq!(Model::parse(&posed).unwrap().novelty.spread_ref, None);
    // Alone on a plain blob, too.
    let mut plain = mlp_spec();
    plain.novelty.spread_ref = Some(0.0);
    let p = plain.to_bytes().unwrap();
    assert_eq!((&p[4..6], Model::parse(&p).unwrap().novelty.spread_ref), (&[6u8, 0][..], Some(0.0)));
    // A self gate goes after it and comes off again; the version stays 6.
    let gated = set_self_gate(&bytes, Some(gate())).unwrap();
    assert_eq!(&gated[4..6], &[6, 0]);
    assert_eq!(&gated[24..bytes.len()], &bytes[24..]);
    let g = Model::parse(&gated).unwrap();
    assert_eq!((g.novelty.spread_ref, g.self_gate), (Some(4.75), Some(gate())));
    assert_eq!(set_self_gate(&gated, None).unwrap(), bytes);
}

#[test]
fn frame_spread_is_checked_and_needs_version_6() {
    let mut spec = mlp_spec();
    spec.novelty.spread_ref = Some(2.5);
    let bytes = spec.to_bytes().unwrap();
    let at = bytes.len() - 4;
    let edit = |at_: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at_..at_ + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.novelty.spread_ref)
    };
    assert_eq!(edit(at, &255.0f32.to_le_bytes()), Ok(Some(255.0)));
    for bad in [-0.5f32, 255.5, f32::NAN, f32::INFINITY] {
        assert_eq!(edit(at, &bad.to_le_bytes()), Err(BlobError::Novelty), "{bad}");
    }
    assert_eq!(edit(4, &[5, 0]), Err(BlobError::BadHeader), "the flag needs version 6");
    assert_eq!(edit(22, &[1, 0]), Err(BlobError::BadHeader), "version 6 needs the flag");
    for cut in 0..bytes.len() {
        assert!(Model::parse(&bytes[..cut]).is_err(), "accepted {cut} of {}", bytes.len());
    }
    for bad in [-1.0f32, 300.0, f32::NAN] {
        spec.novelty.spread_ref = Some(bad);
        assert_eq!(spec.to_bytes(), Err(BlobError::Novelty), "the writer refuses {bad} too");
    }
}

fn chroma_of(h: usize, w: usize, cells: usize) -> ChromaSpec {
    let n = super::chroma::blocks(h, w);
    ChromaSpec {
        threshold: 6.0,
        spread_ref: 1.5,
        cells: (0..cells)
            .map(|k| {
                let mu = (0..n).map(|b| [((b + k) % 200) as i8 - 100, -((b % 90) as i8)]).collect();
                (mu, (0..n).map(|b| 1 + ((b + 3 * k) % 250) as u8).collect())
            })
            .collect(),
    }
}

#[test]
fn chroma_is_a_literal_section_before_the_self_gate_and_comes_off_again() {
    let mut spec = pose_spec();
    spec.novelty.spread_ref = Some(4.75);
    let grey = set_self_gate(&spec.to_bytes().unwrap(), Some(gate())).unwrap();
    let m = Model::parse(&grey).unwrap();
    let (h, w) = (m.face_h as usize, m.face_w as usize);
    let cells = m.pose.unwrap().grid.len();
    let c = chroma_of(h, w, cells);
    let bytes = set_chroma(&grey, Some(&c)).unwrap();
    assert_eq!(&bytes[4..6], &[7, 0], "chroma is version 7");
    assert_eq!(bytes[22] & 128, 128);
    // Its bytes as the module's layout says, between the frame spread and the self gate.
    let at = m.gate_at;
    let n = c.cells[0].0.len();
    let padded = n.div_ceil(4) * 4;
    assert_eq!(&bytes[24..at], &grey[24..at]);
    assert_eq!(&bytes[at..at + 4], &6.0f32.to_le_bytes());
    assert_eq!(&bytes[at + 4..at + 8], &1.5f32.to_le_bytes());
    assert_eq!(&bytes[at + 8..at + 12], &[cells as u8, 0, 0, 0]);
    let t = at + 12 + 3 * padded; // the second cell's tables
    assert_eq!(bytes[t + 3], c.cells[1].0[3][0] as u8);
    assert_eq!(bytes[t + padded + 3], c.cells[1].0[3][1] as u8);
    assert_eq!(bytes[t + 2 * padded + 3], c.cells[1].1[3]);
    assert_eq!(&bytes[at + 12 + 3 * padded * cells..], &grey[at..], "the self gate follows unchanged");
    let p = Model::parse(&bytes).unwrap();
    let k = p.chroma.unwrap();
    assert_eq!((k.threshold, k.spread_ref, k.cells()), (6.0, 1.5, cells));
    for cell in 0..cells {
        let kc = k.cell(cell).unwrap();
        assert_eq!(kc.blocks(), n);
        for b in [0, 1, n / 2, n - 1] {
            assert_eq!(kc.at(b), Some((c.cells[cell].0[b], c.cells[cell].1[b])));
        }
        assert_eq!(kc.at(n), None);
    }
    assert_eq!(k.cell(cells), None);
    // A frame takes its pose cell's tables, the same rule as the grey statistics'.
    let grid = p.pose.unwrap().grid;
    for head in [[0.0f32, 0.0], [-0.3, 0.2], [0.3, -0.2]] {
        assert_eq!(p.chroma_at(head), k.cell(grid.bin(head).unwrap()));
    }
    assert_eq!(p.chroma_at([f32::NAN, 0.0]), k.cell(0));
    assert_eq!(p.self_gate, Some(gate()));
    // Replaced, then removed: the grey blob's bytes again.
    let mut c2 = c.clone();
    c2.threshold = 3.0;
    let twice = set_chroma(&bytes, Some(&c2)).unwrap();
    assert_eq!(Model::parse(&twice).unwrap().chroma.unwrap().threshold, 3.0);
    assert_eq!(set_chroma(&twice, None).unwrap(), grey);
    // The self gate comes off and goes on around it.
    let ungated = set_self_gate(&bytes, None).unwrap();
    assert_eq!(Model::parse(&ungated).unwrap().chroma, Some(k));
    assert_eq!(set_self_gate(&ungated, Some(gate())).unwrap(), bytes);
    // On a version-1 blob too; taking it off gives version 1 back.
    let plain = mlp_spec().to_bytes().unwrap();
    let pm = Model::parse(&plain).unwrap();
    let pc = set_chroma(&plain, Some(&chroma_of(pm.face_h as usize, pm.face_w as usize, 1))).unwrap();
    assert_eq!(&pc[4..6], &[7, 0]);
    assert_eq!(Model::parse(&pc).unwrap().chroma_at([0.1, 0.0]), Model::parse(&pc).unwrap().chroma.unwrap().cell(0));
    // Cells must be one or the pose grid's: none here.
    assert_eq!(set_chroma(&plain, Some(&chroma_of(pm.face_h as usize, pm.face_w as usize, 2))), Err(BlobError::Chroma));
    assert_eq!(set_chroma(&pc, None).unwrap(), plain);
}

#[test]
fn chroma_is_checked_and_needs_version_7() {
    let plain = mlp_spec().to_bytes().unwrap();
    let pm = Model::parse(&plain).unwrap();
    let (h, w) = (pm.face_h as usize, pm.face_w as usize);
    let c = chroma_of(h, w, 1);
    let bytes = set_chroma(&plain, Some(&c)).unwrap();
    let at = pm.gate_at;
    let edit = |at_: usize, v: &[u8]| {
        let mut b = bytes.clone();
        b[at_..at_ + v.len()].copy_from_slice(v);
        recrc(&mut b);
        Model::parse(&b).map(|m| m.chroma.map(|c| c.threshold))
    };
    assert_eq!(edit(at, &64.0f32.to_le_bytes()), Ok(Some(64.0)));
    for bad in [0.0f32, -1.0, 64.5, f32::NAN, f32::INFINITY] {
        assert_eq!(edit(at, &bad.to_le_bytes()), Err(BlobError::Chroma), "threshold {bad}");
        assert_eq!(edit(at + 4, &bad.to_le_bytes()), Err(BlobError::Chroma), "reference {bad}");
    }
    let n = c.cells[0].0.len();
    let spread_at = at + 12 + 2 * n.div_ceil(4) * 4;
    assert_eq!(edit(spread_at + n - 1, &[0]), Err(BlobError::Chroma), "a zero spread divides by 0");
    assert_eq!(edit(at + 8, &[2]), Err(BlobError::Chroma), "two cells without a pose grid");
    assert_eq!(edit(at + 9, &[1]), Err(BlobError::BadHeader), "reserved bytes are zero");
    assert_eq!(edit(4, &[6, 0]), Err(BlobError::BadHeader), "the flag needs version 7");
    assert_eq!(edit(22, &[0, 0]), Err(BlobError::BadHeader), "version 7 needs the flag");
    for cut in plain.len()..bytes.len() {
        assert!(Model::parse(&bytes[..cut]).is_err(), "accepted {cut} of {}", bytes.len());
    }
    let mut short = c.clone();
    short.cells[0].1.pop();
    assert_eq!(set_chroma(&plain, Some(&short)), Err(BlobError::Chroma), "the writer checks sizes");
    let mut zero = c.clone();
    zero.cells[0].1[0] = 0;
    assert_eq!(set_chroma(&plain, Some(&zero)), Err(BlobError::Chroma));
}

#[test]
fn reach_is_replaced_in_place() {
    let plain = mlp_spec().to_bytes().unwrap();
    let gated = set_self_gate(&plain, Some(gate())).unwrap();
    let mut other = reach();
    other.b2 = [0.125; 5];
    other.in_max = [250.0, 190.0];
    let swapped = set_reach(&gated, &other).unwrap();
    assert_eq!(swapped.len(), gated.len());
    let (a, b) = (Model::parse(&gated).unwrap(), Model::parse(&swapped).unwrap());
    assert_eq!(b.reach, other);
    assert_eq!(b.self_gate, a.self_gate);
    assert_ne!(b.crc32, a.crc32);
    // Only the reach's 396 bytes and the header's CRC differ.
    let differ: Vec<usize> = (24..gated.len()).filter(|&i| gated[i] != swapped[i]).collect();
    assert!(differ.iter().all(|&i| (a.reach_at..a.reach_at + 4 * REACH_FLOATS).contains(&i)), "{differ:?}");
    // Back to the first reach: the first bytes.
    assert_eq!(set_reach(&swapped, &reach()).unwrap(), gated);
    // A reach that cannot scale is refused; a blob that does not parse is refused.
    let mut bad = reach();
    bad.in_max = bad.in_min;
    assert_eq!(set_reach(&gated, &bad), Err(BlobError::Reach));
    assert!(set_reach(&gated[..gated.len() - 3], &other).is_err());
}
