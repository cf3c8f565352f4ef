use super::*;
use crate::testkit::{conv_spec, mlp_spec, reach_net, Lcg};
use msr_shared::blob::{Merge, Model, Normalisation, PoseRegion, Sided};

#[test]
fn saliency_matches_the_float_definition() {
    let bytes = conv_spec(5, false).to_bytes().unwrap();
    let m = Model::parse(&bytes).unwrap();
    let mut ws = Box::new(Workspace::new());
    let mut r = Lcg(11);
    let mut checked = 0;
    for norm in [Normalisation::StdDev, Normalisation::Variance] {
        for sided in [Sided::One, Sided::Two] {
            for t in [0.7f32, 2.0, 4.59] {
                let s = Settings {
                    threshold: t,
                    normalisation: norm,
                    sided,
                    min_area: 1,
                    merge: Merge::OFF,
                };
                let pred = ws.decode(&m, [0.02, -0.01]).unwrap().to_vec();
                let crop: Vec<u8> = pred
                    .iter()
                    .map(|&p| {
                        ((p as f64 / 256.0) + r.unit() * 8.0)
                            .round()
                            .clamp(0.0, 255.0) as u8
                    })
                    .collect();
                let n = ws.saliency(&m, &s, &crop).unwrap();
                let mask = ws.mask(crop.len()).to_vec();
                assert_eq!(n as usize, mask.iter().filter(|&&v| v == 1).count());
                // The crop brought to the prediction's light by the frame's fit.
                let fit = ws.light();
                let (lo, hi) = (pred.iter().min().unwrap() / 256, pred.iter().max().unwrap() / 256);
                assert_eq!(fit.verdict, crate::light::Verdict::Face, "{fit:?} pred {lo}..{hi}");
                for i in 0..crop.len() {
                    let e = (fit.value(crop[i]) as f64 / 256.0 - pred[i] as f64 / 256.0).abs();
                    let mu = m.mu.get(i) as f64 / 256.0;
                    let sigma = m.sigma.get(i) as f64 / 256.0;
                    let nn = match norm {
                        Normalisation::StdDev => sigma,
                        Normalisation::Variance => sigma * sigma,
                    };
                    let d = match sided {
                        Sided::One => e - mu,
                        Sided::Two => (e - mu).abs(),
                    };
                    let want = d / nn > t as f64;
                    if want != (mask[i] == 1) {
                        // Only the rounding of t * n to 1/256 grey may flip a pixel.
                        assert!(
                            (d - t as f64 * nn).abs() <= 0.5 / 256.0 + 1e-9,
                            "pixel {i}: d {d} t*n {}",
                            t as f64 * nn
                        );
                    }
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 1000);
}

#[test]
fn reach_matches_f64() {
    for seed in 1..5 {
        let net = reach_net(&mut Lcg(seed));
        let mut r = Lcg(seed + 100);
        for _ in 0..200 {
            let c = [
                (166.0 + r.unit() * 45.0) as f32,
                (113.0 + r.unit() * 30.0) as f32,
            ];
            let got = reach::infer(&net, c).unwrap();
            let u = [0, 1].map(|i| {
                (c[i] as f64 - net.in_min[i] as f64) / (net.in_max[i] as f64 - net.in_min[i] as f64)
            });
            let sig = |x: f64| 1.0 / (1.0 + (-x).exp());
            let h: Vec<f64> = (0..10)
                .map(|j| {
                    sig(net.b1[j] as f64 + net.w1[j][0] as f64 * u[0] + net.w1[j][1] as f64 * u[1])
                })
                .collect();
            for k in 0..5 {
                let a = net.b2[k] as f64 + (0..10).map(|j| net.w2[k][j] as f64 * h[j]).sum::<f64>();
                let want = sig(a) * (net.out_max[k] as f64 - net.out_min[k] as f64)
                    + net.out_min[k] as f64;
                assert!(
                    (got[k] as f64 - want).abs() < 2e-5,
                    "joint {k}: {} vs {want}",
                    got[k]
                );
            }
        }
    }
    let net = reach_net(&mut Lcg(1));
    assert_eq!(reach::infer(&net, [f32::NAN, 100.0]), None);
    // Whatever comes out is clamped into the limits before use.
    let (a, _) = reach::targets(&net, [1e30, -1e30]).unwrap();
    for (j, v) in msr_shared::joints::REACH_JOINTS.iter().zip(a) {
        assert!(j.validate(v).is_ok());
    }
}

fn face_of(ws: &mut Workspace, m: &Model, head: [f32; 2]) -> Vec<u8> {
    ws.decode(m, head)
        .unwrap()
        .iter()
        .map(|&p| ((p as u32 + 128) >> 8).min(255) as u8)
        .collect()
}

#[test]
fn a_mark_is_found_where_it_is_and_nothing_without() {
    let bytes = mlp_spec(3, 20, 24).to_bytes().unwrap();
    let m = Model::parse(&bytes).unwrap();
    let s = Settings::of(&m);
    let mut ws = Box::new(Workspace::new());
    let head = [0.03, 0.01];
    let clean = face_of(&mut ws, &m, head);
    let d = detect(&mut ws, &m, &s, &clean, [150, 90], head).unwrap();
    assert_eq!((d.blob, d.reach, d.salient_pixels), (None, None, 0));

    let marked = with_mark(&clean);
    let d = detect(&mut ws, &m, &s, &marked, [150, 90], head).unwrap();
    let b = d.blob.expect("the mark");
    assert_eq!((b.area, b.x0, b.y0, b.x1, b.y1), (16, 10, 5, 13, 8));
    assert_eq!(d.centroid, Some([150.0 + 11.5, 90.0 + 6.5]));
    assert_eq!(
        d.reach,
        reach::targets(&m.reach, [161.5, 96.5]).map(|r| r.0)
    );
    // A blob under the minimum area is not a mark.
    let small = Settings { min_area: 17, ..s };
    assert_eq!(
        detect(&mut ws, &m, &small, &marked, [150, 90], head)
            .unwrap()
            .blob,
        None
    );
    // Wrong crop size and bad settings are errors, not panics.
    assert_eq!(
        detect(&mut ws, &m, &s, &marked[1..], [0, 0], head),
        Err(DetectError::CropSize)
    );
    let bad = Settings {
        threshold: f32::NAN,
        ..s
    };
    assert_eq!(
        detect(&mut ws, &m, &bad, &marked, [0, 0], head),
        Err(DetectError::Settings)
    );
    assert!(detect(&mut ws, &m, &s, &marked, [0, 0], [f32::NAN, 0.0]).is_err());
}

/// `face` with a 4 x 4 mark at (10..14, 5..9), dark on light and light on dark.
fn with_mark(face: &[u8]) -> Vec<u8> {
    let mut marked = face.to_vec();
    for y in 5..9 {
        for x in 10..14 {
            marked[y * 24 + x] = if face[y * 24 + x] > 128 { 10 } else { 245 };
        }
    }
    marked
}

#[test]
fn the_pose_region_settings_hold_near_its_centre_only() {
    let mut spec = mlp_spec(3, 20, 24);
    let inside = [0.03, 0.01];
    let region = PoseRegion {
        centre: inside,
        radius: 0.01,
        threshold: 5000.0,
        merge: Merge { margin: 3, fragment: 2 },
    };
    spec.region = Some(region);
    let bytes = spec.to_bytes().unwrap();
    let m = Model::parse(&bytes).unwrap();
    let s = Settings::of(&m);
    assert_eq!(s.at(&m, inside), Settings { threshold: 5000.0, merge: region.merge, ..s });
    assert_eq!(s.at(&m, [0.037, 0.017]), Settings { threshold: 5000.0, merge: region.merge, ..s });
    let outside = [0.045, 0.01];
    assert_eq!(s.at(&m, outside), s);
    assert_eq!(s.at(&m, [f32::NAN, 0.01]), s);
    // A configured threshold scales the region's too.
    let twice = Settings { threshold: 2.0 * s.threshold, ..s };
    assert_eq!(twice.at(&m, inside).threshold, 10000.0);

    // The mark the model's own threshold finds is below the region's.
    let mut ws = Box::new(Workspace::new());
    let marked = with_mark(&face_of(&mut ws, &m, inside));
    let d = detect(&mut ws, &m, &s, &marked, [150, 90], inside).unwrap();
    assert_eq!(d.blob, None, "inside the region its threshold holds");
    let marked = with_mark(&face_of(&mut ws, &m, outside));
    let d = detect(&mut ws, &m, &s, &marked, [150, 90], outside).unwrap();
    assert_eq!(d.blob.map(|b| b.area), Some(16), "outside, the model's own");
    // Back inside: the threshold table follows the pose.
    let marked = with_mark(&face_of(&mut ws, &m, inside));
    assert_eq!(detect(&mut ws, &m, &s, &marked, [150, 90], inside).unwrap().blob, None);
    let plain_bytes = mlp_spec(3, 20, 24).to_bytes().unwrap();
    let plain = Model::parse(&plain_bytes).unwrap();
    let d = detect(&mut ws, &plain, &Settings::of(&plain), &marked, [150, 90], inside).unwrap();
    assert_eq!(d.blob.map(|b| b.area), Some(16), "the same frame without a region");
}

#[test]
fn golden_vectors_are_deterministic_and_model_specific() {
    let b1 = conv_spec(1, false).to_bytes().unwrap();
    let b2 = mlp_spec(2, 20, 24).to_bytes().unwrap();
    let (m1, m2) = (Model::parse(&b1).unwrap(), Model::parse(&b2).unwrap());
    let mut crop = vec![0u8; 64 * 96];
    let mut ws = Box::new(Workspace::new());
    let r1 = crate::golden::run(&mut ws, &m1, &mut crop).unwrap();
    let r2 = crate::golden::run(&mut ws, &m2, &mut crop).unwrap();
    let again = crate::golden::run(&mut Box::new(Workspace::new()), &m1, &mut crop).unwrap();
    assert_eq!(r1, again);
    assert_ne!(r1.digest, r2.digest);
    assert!(r2.detections >= 4, "{r2:?}");
    assert!(crate::golden::run(&mut ws, &m1, &mut crop[..10]).is_err());
}

/// With pose statistics the saliency takes the tables of the decoded head pose's cell: a crop
/// 4 grey levels over the prediction everywhere is salient in a cell whose mu and sigma say
/// 1 +- 0.5 grey, not in one that says 3 +- 2 (nor with the header's 12.9 +- 1 at a NaN pose,
/// which the decoder refuses anyway), and the threshold table follows the cell.
#[test]
fn saliency_takes_the_pose_cells_statistics() {
    use msr_shared::blob::PoseGrid;
    let mut spec = conv_spec(5, false);
    let n = spec.mu.len();
    let cells = vec![(vec![256u16; n], vec![128u16; n]), (vec![3 * 256u16; n], vec![512u16; n])];
    spec.pose = Some((PoseGrid { bins: [2, 1], lo: [-0.1, -0.1], hi: [0.1, 0.1] }, cells));
    let bytes = spec.to_bytes().unwrap();
    let m = Model::parse(&bytes).unwrap();
    let s = Settings { threshold: 4.59, normalisation: Normalisation::StdDev, sided: Sided::One, min_area: 1, merge: Merge::OFF };
    let mut ws = Box::new(Workspace::new());
    // A uniform offset is what the photometric fit takes away: this test is of the statistics.
    ws.fit_light = false;
    for (head, want) in [([-0.05f32, 0.0], n as u32), ([0.05, 0.0], 0), ([-0.02, 0.09], n as u32)] {
        let pred = ws.decode(&m, head).unwrap().to_vec();
        // 4 grey levels over the prediction (rounded down to whole grey levels, 3.5..4.5).
        let crop: Vec<u8> = pred.iter().map(|&p| ((p as u32 + 128) / 256 + 4).min(255) as u8).collect();
        let got = ws.saliency(&m, &s, &crop).unwrap();
        // Pixels clipped at 255 may fall short; none are here for this decoder.
        assert_eq!(got, want, "head {head:?}");
        let (_, sigma, cell) = m.stats_at(head);
        assert_eq!(ws.thresholds.table()[0], crate::saliency::threshold_q88(sigma.get(0), 4.59, Normalisation::StdDev), "cell {cell}");
    }
}

/// A model that carries a spread reference widens each sigma by the frame's own floor: its
/// masks are those of the same model with every sigma widened by that floor and no reference,
/// for every test (per pixel and pooled, one- and two-sided); a frame within the reference
/// keeps the statistics alone.
#[test]
fn the_frame_floor_acts_as_widened_statistics() {
    let mut checked = 0;
    for (pool, sided) in [(0, Sided::Two), (0, Sided::One), (2, Sided::One), (2, Sided::Two)] {
        for spread_ref in [0.0f32, 0.5, 40.0] {
            let mut spec = conv_spec(5, false);
            spec.novelty.pool = pool;
            spec.novelty.sided = sided;
            spec.novelty.spread_ref = Some(spread_ref);
            let bytes = spec.to_bytes().unwrap();
            let m = Model::parse(&bytes).unwrap();
            let s = Settings::of(&m);
            let mut ws = Box::new(Workspace::new());
            let head = [0.02, -0.01];
            let mut r = Lcg(5);
            let crop: Vec<u8> = face_of(&mut ws, &m, head)
                .iter()
                .map(|&p| (p as f64 + r.unit() * 8.0).round().clamp(0.0, 255.0) as u8)
                .collect();
            let n = ws.saliency(&m, &s, &crop).unwrap();
            let mask = ws.mask(crop.len()).to_vec();
            let [spread, f] = ws.spread();
            assert_eq!(ws.light().verdict, crate::light::Verdict::Face);
            assert!(spread > 0, "a noisy frame spreads");
            assert_eq!(f, crate::floor::floor(spread, crate::floor::reference_q88(spread_ref)));
            assert_eq!(f == 0, spread_ref >= 40.0, "pool {pool}: spread {spread}, floor {f}");

            let mut widened = spec.clone();
            widened.novelty.spread_ref = None;
            widened.sigma = spec.sigma.iter().map(|&sg| crate::floor::widen(sg, f)).collect();
            let wb = widened.to_bytes().unwrap();
            let wm = Model::parse(&wb).unwrap();
            let mut wws = Box::new(Workspace::new());
            wws.decode(&wm, head).unwrap();
            assert_eq!(wws.saliency(&wm, &s, &crop).unwrap(), n);
            assert_eq!(wws.mask(crop.len()), &mask[..], "pool {pool} {sided:?} ref {spread_ref}");
            assert_eq!(wws.spread(), [0, 0], "no reference, no floor");
            checked += 1;
        }
    }
    assert_eq!(checked, 12);
}
