//! Where a trained decoder's error comes from, per head pose and per pixel.
//!
//! `cargo run --release -p msr-host --example pose_error -- DATASET TRAIN_DIR [K]`
//!
//! Float engine, the paper's settings (4.59, min area 30, no merge, no pose region), the
//! statistics saved beside the model. Prints, by distance of the head from (0, 0):
//! the mean error, the share of pixels over threshold on unmarked frames, and the outcome of the
//! marked test frames (hit, nothing found, another blob won); the same with mu and sigma taken
//! from the K training frames nearest in head pose (an oracle of a pose-dependent sigma); and
//! per-pixel figures (error against the mean face's gradient, against the sub-pixel crop shift).
use anyhow::Result;
use msr_host::data::{Dataset, Sample};
use msr_host::models::predictor::FacePredictor;
use msr_host::train::calibrate::{self, ErrorStats, NoveltyParams};
use msr_sim::layout::Split;
use std::path::PathBuf;

const BINS: [f64; 5] = [1.0, 2.0, 3.0, 4.0, f64::INFINITY];

fn radius_deg(h: [f32; 2]) -> f64 {
    ((h[0] as f64).hypot(h[1] as f64)).to_degrees()
}

fn bin(h: [f32; 2]) -> usize {
    let r = radius_deg(h);
    BINS.iter().position(|&b| r < b).unwrap_or(BINS.len() - 1)
}

#[derive(Default, Clone, Copy)]
struct Tally {
    hit: usize,
    none: usize,
    wrong: usize,
    unmarked: usize,
    alarms: usize,
}

fn outcome(s: &Sample, sal: &[f64], w: usize, h: usize, p: &NoveltyParams, t: &mut Tally) {
    let blob = calibrate::detect(sal, h, w, p);
    match &s.mark {
        None => {
            t.unmarked += 1;
            t.alarms += blob.is_some() as usize;
        }
        Some(m) => match blob {
            None => t.none += 1,
            Some(b) => {
                let (cx, cy) = (b.centroid[0].round() as usize, b.centroid[1].round() as usize);
                if cx < w && cy < h && m.face_mask[cy * w + cx] {
                    t.hit += 1
                } else {
                    t.wrong += 1
                }
            }
        },
    }
}

fn print_tallies(title: &str, t: &[Tally]) {
    println!("{title}");
    println!("| head radius | marked | hit | none found | other blob won | hit rate | unmarked | false alarms |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut all = Tally::default();
    for (i, x) in t.iter().enumerate() {
        let lo = if i == 0 { 0.0 } else { BINS[i - 1] };
        let m = x.hit + x.none + x.wrong;
        println!(
            "| {lo:.0}-{} deg | {m} | {} | {} | {} | {:.3} | {} | {} |",
            BINS[i], x.hit, x.none, x.wrong, x.hit as f64 / m.max(1) as f64, x.unmarked, x.alarms
        );
        all.hit += x.hit;
        all.none += x.none;
        all.wrong += x.wrong;
        all.unmarked += x.unmarked;
        all.alarms += x.alarms;
    }
    let m = all.hit + all.none + all.wrong;
    println!(
        "| all | {m} | {} | {} | {} | {:.3} | {} | {} ({:.3}) |\n",
        all.hit,
        all.none,
        all.wrong,
        all.hit as f64 / m.max(1) as f64,
        all.unmarked,
        all.alarms,
        all.alarms as f64 / all.unmarked.max(1) as f64
    );
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() >= 3, "usage: pose_error DATASET TRAIN_DIR [K]");
    let data = PathBuf::from(&args[1]);
    let dir = PathBuf::from(&args[2]);
    let k: usize = args.get(3).map_or(Ok(150), |s| s.parse())?;
    let model = msr_host::train::load(&dir, "decoder")?;
    let info = model.info()?.clone();
    let stats = msr_host::train::load_stats(&dir, &info)?;
    let ds = Dataset::load(&data, info.crop)?;
    let (h, w) = ds.face_size();
    let n = h * w;
    let p = NoveltyParams::default();
    let train: Vec<&Sample> = ds.split(Split::Train).filter(|s| s.mark.is_none()).collect();
    let test: Vec<&Sample> = ds.split(Split::Test).collect();
    let err_of = |ss: &[&Sample]| -> Vec<Vec<f64>> {
        let heads: Vec<[f32; 2]> = ss.iter().map(|s| s.head).collect();
        let faces: Vec<Vec<f32>> = ss.iter().map(|s| s.face_unit()).collect();
        let pred = model.predict_batch(&heads, &faces);
        faces.iter().zip(&pred).map(|(f, q)| calibrate::error_map(f, q, w, 0)).collect()
    };
    let e_train = err_of(&train);
    let e_test = err_of(&test);

    // Per pose: mean error and over-threshold share, training frames.
    println!("model {} (test MSE {:.4}), {} train, {} test frames, face {h}x{w}\n", dir.display(), info.final_test_mse, train.len(), test.len());
    println!("| head radius | train frames | mean error (grey) | px over 4.59 (global sigma) |");
    println!("|---|---|---|---|");
    let mut acc = vec![(0usize, 0f64, 0f64); BINS.len()];
    for (s, e) in train.iter().zip(&e_train) {
        let sal = calibrate::saliency(e, &stats, &p);
        let a = &mut acc[bin(s.head)];
        a.0 += 1;
        a.1 += e.iter().sum::<f64>() / n as f64;
        a.2 += sal.iter().filter(|&&v| v > p.threshold).count() as f64 / n as f64;
    }
    for (i, a) in acc.iter().enumerate() {
        let c = a.0.max(1) as f64;
        println!("| <{} deg | {} | {:.2} | {:.4} |", BINS[i], a.0, a.1 / c, a.2 / c);
    }
    println!();

    // Outcomes with the global statistics.
    let mut t = vec![Tally::default(); BINS.len()];
    let mut pos_sal_test = Vec::new();
    for (s, e) in test.iter().zip(&e_test) {
        let sal = calibrate::saliency(e, &stats, &p);
        outcome(s, &sal, w, h, &p, &mut t[bin(s.head)]);
        pos_sal_test.push(sal);
    }
    print_tallies("Global mu, sigma (the model's statistics):", &t);

    // Off-mark saliency of marked frames: how much of the face is over threshold.
    let mut off = vec![(0usize, 0f64, 0f64); BINS.len()];
    for ((s, sal), _) in test.iter().zip(&pos_sal_test).zip(&e_test) {
        if let Some(m) = &s.mark {
            let over = sal.iter().zip(&m.face_mask).filter(|(&v, &mk)| !mk && v > p.threshold).count();
            let on = sal.iter().zip(&m.face_mask).filter(|(_, &mk)| mk).map(|(&v, _)| v).sum::<f64>()
                / m.pixels_in_face().max(1) as f64;
            let a = &mut off[bin(s.head)];
            a.0 += 1;
            a.1 += over as f64;
            a.2 += on;
        }
    }
    println!("| head radius | marked | off-mark px over threshold (mean) | mean saliency on the mark |");
    println!("|---|---|---|---|");
    for (i, a) in off.iter().enumerate() {
        let c = a.0.max(1) as f64;
        println!("| <{} deg | {} | {:.1} | {:.2} |", BINS[i], a.0, a.1 / c, a.2 / c);
    }
    println!();

    // Oracle: mu and sigma of the K training frames nearest in head pose.
    for (label, local_mu) in [("local sigma, global mu", false), ("local mu and sigma", true)] {
        let mut t = vec![Tally::default(); BINS.len()];
        for (s, e) in test.iter().zip(&e_test) {
            let mut idx: Vec<usize> = (0..train.len()).collect();
            let d = |j: usize| {
                let (a, b) = (train[j].head[0] - s.head[0], train[j].head[1] - s.head[1]);
                a * a + b * b
            };
            idx.sort_by(|&a, &b| d(a).total_cmp(&d(b)));
            let mut acc = calibrate::StatsAccumulator::new(h, w);
            for &j in idx.iter().take(k) {
                acc.add(&e_train[j])?;
            }
            let loc = acc.finish()?;
            let st = ErrorStats { mu: if local_mu { loc.mu } else { stats.mu.clone() }, sigma: loc.sigma, ..stats.clone() };
            let sal = calibrate::saliency(e, &st, &p);
            outcome(s, &sal, w, h, &p, &mut t[bin(s.head)]);
        }
        print_tallies(&format!("Oracle, K = {k} nearest training poses ({label}):"), &t);
    }

    // Per pixel: where the error is. Mean face gradient vs mu; columns/rows of largest mu.
    let mean_face: Vec<f64> = (0..n).map(|i| train.iter().map(|s| s.face.grey[i] as f64).sum::<f64>() / train.len() as f64).collect();
    let grad: Vec<f64> = (0..n)
        .map(|i| {
            let (r, c) = (i / w, i % w);
            let gx = if c + 1 < w && c > 0 { (mean_face[i + 1] - mean_face[i - 1]) / 2.0 } else { 0.0 };
            let gy = if r + 1 < h && r > 0 { (mean_face[i + w] - mean_face[i - w]) / 2.0 } else { 0.0 };
            gx.hypot(gy)
        })
        .collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| grad[a].total_cmp(&grad[b]));
    println!("| mean-face gradient quintile | mean gradient | mean mu | mean sigma |");
    println!("|---|---|---|---|");
    for q in 0..5 {
        let sl = &order[q * n / 5..(q + 1) * n / 5];
        let m = |v: &[f64]| sl.iter().map(|&i| v[i]).sum::<f64>() / sl.len() as f64;
        println!("| {} | {:.1} | {:.2} | {:.2} |", q + 1, m(&grad), m(&stats.mu), m(&stats.sigma));
    }
    // Crop shift: per-frame mean error against |sub-pixel shift|.
    let mut sh = vec![(0usize, 0f64); 5];
    for (s, e) in train.iter().zip(&e_train) {
        let m = s.face.shift[0].abs().max(s.face.shift[1].abs()) as f64;
        let b = ((m / 0.1) as usize).min(4);
        sh[b].0 += 1;
        sh[b].1 += e.iter().sum::<f64>() / n as f64;
    }
    println!("\n| max abs crop shift (px) | frames | mean error |");
    println!("|---|---|---|");
    for (i, (c, v)) in sh.iter().enumerate() {
        println!("| {:.1}-{:.1} | {c} | {:.2} |", i as f64 * 0.1, (i + 1) as f64 * 0.1, v / (*c).max(1) as f64);
    }

    // Lever: the signed residual averaged over a (2r+1)^2 box before its magnitude is taken. The
    // taxel texture's residual is high-frequency and of either sign; a mark's is one-signed over
    // 15 x 15 px.
    let signed_of = |ss: &[&Sample]| -> Vec<Vec<f64>> {
        let heads: Vec<[f32; 2]> = ss.iter().map(|s| s.head).collect();
        let faces: Vec<Vec<f32>> = ss.iter().map(|s| s.face_unit()).collect();
        let pred = model.predict_batch(&heads, &faces);
        faces.iter().zip(&pred).map(|(f, q)| f.iter().zip(q).map(|(&a, &b)| 255.0 * (a as f64 - b as f64)).collect()).collect()
    };
    let (r_train, r_test) = (signed_of(&train), signed_of(&test));
    for rad in [1usize, 2, 3] {
        let abs_box = |r: &Vec<f64>| -> Vec<f64> { box_mean(r, w, h, rad).iter().map(|v| v.abs()).collect() };
        let mut acc = calibrate::StatsAccumulator::new(h, w);
        for r in &r_train {
            acc.add(&abs_box(r))?;
        }
        let st = acc.finish()?;
        let mut t = vec![Tally::default(); BINS.len()];
        for (s, r) in test.iter().zip(&r_test) {
            let sal = calibrate::saliency(&abs_box(r), &st, &p);
            outcome(s, &sal, w, h, &p, &mut t[bin(s.head)]);
        }
        for (s, r) in test.iter().zip(&r_test) {
            let sal = calibrate::saliency(&abs_box(r), &st, &p);
            if s.mark.is_none() && calibrate::detect(&sal, h, w, &p).is_some() {
                let score = calibrate::detection_score(&sal, h, w, p.min_area);
                println!("  false alarm: head ({:.2}, {:.2}) deg, detection score {score:.2}", s.head[0].to_degrees(), s.head[1].to_degrees());
            }
        }
        let mut scores: Vec<f64> = test
            .iter()
            .zip(&r_test)
            .filter(|(s, _)| s.mark.is_some())
            .map(|(_, r)| calibrate::detection_score(&calibrate::saliency(&abs_box(r), &st, &p), h, w, p.min_area))
            .collect();
        // Hit rate and false alarms against the threshold (the global statistics).
        let sals: Vec<Vec<f64>> = r_test.iter().map(|r| calibrate::saliency(&abs_box(r), &st, &p)).collect();
        let mut line = String::from("  threshold: hit rate / false alarms:");
        for t in [4.59, 5.0, 5.5, 6.0, 6.5, 7.0, 7.5, 8.0] {
            let q = NoveltyParams { threshold: t, ..p };
            let mut tt = Tally::default();
            for (s, sal) in test.iter().zip(&sals) {
                outcome(s, sal, w, h, &q, &mut tt);
            }
            line += &format!(" {t}: {:.3}/{}", tt.hit as f64 / (tt.hit + tt.none + tt.wrong) as f64, tt.alarms);
        }
        println!("{line}");
        scores.sort_by(f64::total_cmp);
        println!("  marked frames' detection scores: 5th percentile {:.2}, median {:.2}", scores[scores.len() / 20], scores[scores.len() / 2]);
        // Pooled, with the K nearest training poses' statistics.
        let mut t2 = vec![Tally::default(); BINS.len()];
        for (s, r) in test.iter().zip(&r_test) {
            let mut idx: Vec<usize> = (0..train.len()).collect();
            let d = |j: usize| {
                let (a, b) = (train[j].head[0] - s.head[0], train[j].head[1] - s.head[1]);
                a * a + b * b
            };
            idx.sort_by(|&a, &b| d(a).total_cmp(&d(b)));
            let mut acc = calibrate::StatsAccumulator::new(h, w);
            for &j in idx.iter().take(k) {
                acc.add(&abs_box(&r_train[j]))?;
            }
            let loc = acc.finish()?;
            let sal = calibrate::saliency(&abs_box(r), &loc, &p);
            outcome(s, &sal, w, h, &p, &mut t2[bin(s.head)]);
        }
        let a = t2.iter().fold((0, 0, 0, 0), |a, x| (a.0 + x.hit, a.1 + x.hit + x.none + x.wrong, a.2 + x.alarms, a.3 + x.unmarked));
        println!("  with the K nearest poses' statistics too: hit rate {:.3} ({}/{}), false alarms {}/{}", a.0 as f64 / a.1 as f64, a.0, a.1, a.2, a.3);
        // Pooled, global maps scaled by one gain per pose: the K nearest poses' mean sigma (and
        // mu) over the global mean. A cheap pose-dependent sigma.
        for scale_mu in [false, true] {
            let mut t3 = vec![Tally::default(); BINS.len()];
            let (gm, gs) = (st.mu.iter().sum::<f64>(), st.sigma.iter().sum::<f64>());
            for (s, r) in test.iter().zip(&r_test) {
                let mut idx: Vec<usize> = (0..train.len()).collect();
                let d = |j: usize| {
                    let (a, b) = (train[j].head[0] - s.head[0], train[j].head[1] - s.head[1]);
                    a * a + b * b
                };
                idx.sort_by(|&a, &b| d(a).total_cmp(&d(b)));
                let mut acc = calibrate::StatsAccumulator::new(h, w);
                for &j in idx.iter().take(k) {
                    acc.add(&abs_box(&r_train[j]))?;
                }
                let loc = acc.finish()?;
                let ks = loc.sigma.iter().sum::<f64>() / gs;
                let km = if scale_mu { loc.mu.iter().sum::<f64>() / gm } else { 1.0 };
                let sc = ErrorStats { mu: st.mu.iter().map(|v| v * km).collect(), sigma: st.sigma.iter().map(|v| v * ks).collect(), ..st.clone() };
                let sal = calibrate::saliency(&abs_box(r), &sc, &p);
                outcome(s, &sal, w, h, &p, &mut t3[bin(s.head)]);
            }
            let a = t3.iter().fold((0, 0, 0, 0), |a, x| (a.0 + x.hit, a.1 + x.hit + x.none + x.wrong, a.2 + x.alarms, a.3 + x.unmarked));
            println!("  global maps, one gain per pose (sigma{}): hit rate {:.3} ({}/{}), false alarms {}/{}", if scale_mu { " and mu" } else { "" }, a.0 as f64 / a.1 as f64, a.0, a.1, a.2, a.3);
        }
        let a = t2.iter().fold((0, 0, 0, 0), |a, x| (a.0 + x.hit, a.1 + x.hit + x.none + x.wrong, a.2 + x.alarms, a.3 + x.unmarked));
        println!("  with the K nearest poses' statistics too: hit rate {:.3} ({}/{}), false alarms {}/{}", a.0 as f64 / a.1 as f64, a.0, a.1, a.2, a.3);
        let ms = st.mu.iter().sum::<f64>() / n as f64;
        let ss = st.sigma.iter().sum::<f64>() / n as f64;
        print_tallies(&format!("Residual box-averaged over {0}x{0} (mean mu {ms:.2}, mean sigma {ss:.2}):", 2 * rad + 1), &t);
    }
    Ok(())
}

/// Mean over the (2r+1)^2 window, clipped at the borders.
fn box_mean(v: &[f64], w: usize, h: usize, r: usize) -> Vec<f64> {
    let mut out = vec![0.0; v.len()];
    for y in 0..h {
        for x in 0..w {
            let (y0, y1, x0, x1) = (y.saturating_sub(r), (y + r).min(h - 1), x.saturating_sub(r), (x + r).min(w - 1));
            let mut s = 0.0;
            for yy in y0..=y1 {
                s += v[yy * w + x0..=yy * w + x1].iter().sum::<f64>();
            }
            out[y * w + x] = s / ((y1 - y0 + 1) * (x1 - x0 + 1)) as f64;
        }
    }
    out
}
