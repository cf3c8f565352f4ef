//! `msr train`, `train-reach` and `quantize` from the command line on a tiny sim dataset: the
//! output layout others rely on, the threshold policy, and bad input (one clear line, non-zero
//! exit, no panic). Plumbing, not quality: 1-2 epochs.
use msr_host::models::predictor::FacePredictor;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_msr")).args(args).output().unwrap()
}

fn ok(args: &[&str]) -> String {
    let out = run(args);
    assert!(out.status.success(), "msr {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Fails with exactly one line on stderr that mentions `what`, and no panic.
fn fails(args: &[&str], what: &str) {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "msr {args:?} succeeded");
    assert!(!err.contains("panicked"), "msr {args:?} panicked: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "msr {args:?}: expected one line, got {err}");
    assert!(err.contains(what), "msr {args:?}: `{err}` does not mention `{what}`");
}

fn p(x: &Path) -> &str {
    x.to_str().unwrap()
}

#[test]
fn train_writes_the_layout_and_quantize_matches_float() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, out) = (tmp.path().join("data"), tmp.path().join("out"));
    // 80 training frames: enough for 2 in each of the default 3 x 3 pose cells.
    ok(&["dataset", "--count", "100", "--seed", "3", "--unmarked-test-fraction", "0", "--out", p(&data)]);
    // Unmark a few test frames so that there are normal held-out frames for the percentile.
    let ix_path = data.join("dataset.json");
    let mut ix: Value = serde_json::from_str(&std::fs::read_to_string(&ix_path).unwrap()).unwrap();
    let mut unmarked = 0;
    for f in ix["frames"].as_array_mut().unwrap() {
        if f["split"] == "test" && unmarked < 4 {
            f["mark"] = Value::Null;
            unmarked += 1;
        }
    }
    assert_eq!(unmarked, 4);
    std::fs::write(&ix_path, serde_json::to_string(&ix).unwrap()).unwrap();

    ok(&["train", "--data", p(&data), "--epochs", "2", "--quiet", "--threshold-percentile", "100", "--out", p(&out)]);
    for f in ["decoder.mpk", "decoder.json", "decoder_mu.npy", "decoder_sigma.npy", "decoder_pose_stats.npy", "decoder_loss.png", "template.png"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let info: Value = serde_json::from_str(&std::fs::read_to_string(out.join("decoder.json")).unwrap()).unwrap();
    assert_eq!(info["arch"], "conv");
    // The defaults: the error pooled over 5 x 5, statistics per cell of a 3 x 3 pose grid.
    assert_eq!((&info["novelty"]["pool"], &info["novelty"]["pose_grid"]["bins"]), (&Value::from(2), &Value::from(vec![3, 3])));
    assert_eq!(info["train_loss"].as_array().unwrap().len(), 2);
    assert_eq!(info["threshold_policy"]["kind"], "percentile");
    assert_eq!(info["threshold_policy"]["n_frames"], 4);
    assert!(info["training_seconds"].as_f64().unwrap() > 0.0);

    // The saved model loads and predicts faces of the template's size, in (0, 1).
    let m = msr_host::train::load(&out, "decoder").unwrap();
    let (h, w) = m.face_size();
    assert_eq!((h as u64, w as u64), (info["face_h"].as_u64().unwrap(), info["face_w"].as_u64().unwrap()));
    let f = m.predict([0.01, -0.02], &[]);
    assert_eq!(f.len(), h * w);
    assert!(f.iter().all(|v| *v > 0.0 && *v < 1.0));

    // The loaded weights are the trained ones: the saved statistics come back from them.
    let info_t = m.info().unwrap().clone();
    let stats = msr_host::train::load_stats(&out, &info_t).unwrap();
    // Trained on sub-pixel crops (the default); the statistics hold for crops made that way.
    assert_eq!(info["crop"], "subpixel");
    assert_eq!(info_t.crop, msr_host::data::crop::CropMode::Subpixel);
    let ds = msr_host::data::Dataset::load(&data, info_t.crop).unwrap();
    let (heads, faces): (Vec<[f32; 2]>, Vec<Vec<f32>>) = ds
        .split(msr_sim::layout::Split::Train)
        .filter(|s| s.mark.is_none())
        .map(|s| (s.head, s.face_unit()))
        .unzip();
    let preds = m.predict_batch(&heads, &faces);
    let again = msr_host::train::calibrate::error_stats(h, w, info_t.novelty.pool, &info_t.light_copies, faces.iter().map(|f| &f[..]).zip(preds.iter().map(|p| &p[..]))).unwrap();
    assert_eq!(again.frames, stats.frames);
    let worst = again.mu.iter().zip(&stats.mu).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(worst < 1e-3, "mu from the loaded model differs by {worst} grey levels");

    let reach = tmp.path().join("reach.safetensors");
    ok(&[
        "train-reach",
        "--inputs",
        p(&data.join("reach_centroids.csv")),
        "--targets",
        p(&data.join("reach_joints.csv")),
        "--iterations",
        "300",
        "--no-loo",
        "--out",
        p(&reach),
    ]);
    let blob = out.join("model.msrm");
    let report = ok(&["quantize", "--train", p(&out), "--reach", p(&reach), "--json", "--out", p(&blob)]);
    let r: Value = serde_json::from_str(&report).unwrap();
    // The report beside the blob is the one printed, the gate's calibration included.
    let beside: Value = serde_json::from_str(&std::fs::read_to_string(out.join("model.msrm.json")).unwrap()).unwrap();
    assert_eq!(beside, r);
    assert!(r["psnr_db"].as_f64().unwrap() >= 40.0, "{report}");
    assert!(r["detection_agreement"].as_f64().unwrap() >= 0.9, "{report}");
    let bytes = std::fs::read(&blob).unwrap();
    let gate = msr_shared::blob::Model::parse(&bytes).unwrap().self_gate;
    // The gate by default, calibrated on the dataset's robot and reported; --no-self-gate is
    // the same blob without it, byte for byte.
    assert!(gate.is_some() && r["self_gate"]["gate"]["gain_px_per_rad"].is_number(), "{report}");
    // Each of the rest, hold, level and (return stage) line statistics has its own tolerance: 4
    // times its root mean square over the calibration's draws, at least two 1/64 px steps; the
    // joint bound is 14 over 4^2; the blob stores them.
    let g = gate.unwrap();
    let sg = &r["self_gate"];
    for (stat, tol, stored) in [("rest_px", "rest_tol_px", g.rest_tol), ("hold_px", "hold_tol_px", g.hold_tol), ("level_px", "level_tol_px", g.level_tol), ("line_px", "line_tol_px", g.line_tol.unwrap())] {
        let v: Vec<f64> = sg[stat].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        let want = (4.0 * rms).max(2.0 / 64.0) as f32;
        assert_eq!(sg["gate"][tol].as_f64().unwrap() as f32, want, "{stat}: {report}");
        assert_eq!(stored, want, "{stat}");
    }
    assert_eq!(g.joint_tol, Some(14.0 / 16.0));
    assert_eq!(sg["gate"]["joint_tol"].as_f64().unwrap() as f32, 14.0 / 16.0);
    // The draws' joints under that gate: the own image, mostly well inside the bound.
    let joints: Vec<f64> = sg["joint"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert_eq!(joints.len(), sg["rest_px"].as_array().unwrap().len());
    let inside = joints.iter().filter(|j| **j <= 14.0 / 16.0).count();
    assert!(inside * 10 >= joints.len() * 9, "{joints:?}");
    let plain = out.join("plain.msrm");
    let report = ok(&["quantize", "--train", p(&out), "--reach", p(&reach), "--json", "--no-self-gate", "--out", p(&plain)]);
    assert!(serde_json::from_str::<Value>(&report).unwrap()["self_gate"].is_null());
    let beside: Value = serde_json::from_str(&std::fs::read_to_string(out.join("plain.msrm.json")).unwrap()).unwrap();
    assert_eq!(beside, serde_json::from_str::<Value>(&report).unwrap());
    let plain = std::fs::read(&plain).unwrap();
    assert_eq!(msr_shared::blob::Model::parse(&plain).unwrap().self_gate, None);
    assert_eq!(msr_shared::blob::set_self_gate(&bytes, None).unwrap(), plain);

    // A folder whose parts come from two runs is refused when read (each part's
    // CRC-32 is in decoder.json), and a folder in use by another run is refused.
    let mixed = tmp.path().join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    for e in std::fs::read_dir(&out).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_file() {
            std::fs::copy(e.path(), mixed.join(e.file_name())).unwrap();
        }
    }
    assert!(info["parts"]["decoder_mu.npy"].is_u64(), "{info}");
    msr_host::train::calibrate::write_npy(&mixed.join("decoder_mu.npy"), h, w, &vec![1.0; h * w]).unwrap();
    fails(&["quantize", "--train", p(&mixed), "--reach", p(&reach), "--out", p(&mixed.join("m.msrm"))], "another run wrote into");
    std::fs::copy(out.join("decoder_mu.npy"), mixed.join("decoder_mu.npy")).unwrap();
    std::fs::write(mixed.join("decoder.mpk"), b"weights of another run").unwrap();
    let e = msr_host::train::load(&mixed, "decoder").unwrap_err().to_string();
    assert!(e.contains("decoder.mpk is not the file"), "{e}");
    let held = msr_host::train::lock_out(&out).unwrap();
    fails(&["train", "--data", p(&data), "--epochs", "1", "--quiet", "--out", p(&out)], "in use by another msr run");
    drop(held);

    // Bad input, on the real outputs above.
    fails(&["quantize", "--train", p(&out), "--reach", p(&tmp.path().join("nope.safetensors")), "--out", p(&blob)], "nope");
    fails(&["quantize", "--train", p(&tmp.path().join("none")), "--reach", p(&reach), "--out", p(&blob)], "decoder");
    fails(&["quantize", "--train", p(&out), "--reach", p(&reach), "--threshold=-1", "--out", p(&blob)], "threshold");
    // This model, trained on 80 frames for one epoch, does not know the face well enough for the
    // face check: the robot refuses to teach itself its reach in one line and writes no model.
    let taught = tmp.path().join("taught.msrm");
    fails(
        &["learn-reach", "--model", p(&blob), "--grid", "4", "--refine", "0", "--no-loo", "--out", p(&tmp.path().join("lr")), "--model-out", p(&taught)],
        "no face in view",
    );
    assert!(!taught.exists());
    fails(&["learn-reach", "--model", p(&blob), "--grid", "1", "--out", p(&tmp.path().join("lr"))], "--grid");
    fails(&["learn-reach", "--model", p(&blob), "--head-pose", "0.5,0", "--out", p(&tmp.path().join("lr"))], "YAW,PITCH");
    // All test frames marked: no normal frames to take a percentile of.
    let data2 = tmp.path().join("data2");
    ok(&["dataset", "--count", "20", "--seed", "4", "--out", p(&data2)]);
    fails(
        &["train", "--data", p(&data2), "--epochs", "1", "--quiet", "--threshold-percentile", "99", "--out", p(&tmp.path().join("o2"))],
        "unmarked",
    );
    // Frames of another robot (`--scene other`) are not the robot's own face in the mirror.
    let data3 = tmp.path().join("data3");
    ok(&["dataset", "--count", "10", "--seed", "4", "--reach-pairs", "0", "--scene", "other", "--out", p(&data3)]);
    fails(&["train", "--data", p(&data3), "--epochs", "1", "--quiet", "--out", p(&tmp.path().join("o3"))], "shows another robot");
}

#[test]
fn bad_arguments_are_one_clear_line() {
    let tmp = tempfile::tempdir().unwrap();
    let o = tmp.path().join("o");
    fails(&["train", "--data", p(&tmp.path().join("missing")), "--out", p(&o)], "missing");
    fails(&["train", "--data", p(tmp.path()), "--epochs", "0", "--out", p(&o)], "epochs");
    fails(&["train", "--data", p(tmp.path()), "--threshold-percentile", "120", "--out", p(&o)], "percentile");
    fails(&["train", "--data", p(tmp.path()), "--sigma-floor", "NaN", "--out", p(&o)], "--sigma-floor must be a number in 0..=255 grey levels");
    fails(&["train", "--data", p(tmp.path()), "--pool", "4", "--out", p(&o)], "--pool must be in 0..=3");
    fails(&["train", "--data", p(tmp.path()), "--pose-bins", "1", "--out", p(&o)], "--pose-bins must be 0");
    fails(&["demo", "--pose-bins", "5", "--out", p(&o)], "--pose-bins must be 0");
    fails(&["train", "--data", p(tmp.path()), "--light-gamma", "0.7", "--out", p(&o)], "--light-gamma must be in 0..0.5");
    fails(&["train", "--data", p(tmp.path()), "--light-gradient", "NaN", "--out", p(&o)], "--light-gradient must be in 0..0.5");

    let (a, b) = (tmp.path().join("a.csv"), tmp.path().join("b.csv"));
    std::fs::write(&a, "1,2\n3,4\n5,6\n").unwrap();
    std::fs::write(&b, "0,0,0,0,0\n1,1,1,1,1\n").unwrap();
    fails(&["train-reach", "--inputs", p(&a), "--targets", p(&b), "--out", p(&o)], "rows");
    std::fs::write(&b, "0,0,0,0,0\n1,1,1,1,1\n2,2,NaN,2,2\n").unwrap();
    fails(&["train-reach", "--inputs", p(&a), "--targets", p(&b), "--out", p(&o)], "non-finite");
    std::fs::write(&b, "0,0,0,0\n1,1,1,1\n2,2,2,2\n").unwrap();
    fails(&["train-reach", "--inputs", p(&a), "--targets", p(&b), "--out", p(&o)], "expected 5");
    fails(&["train-reach", "--inputs", p(&tmp.path().join("x.csv")), "--targets", p(&b), "--out", p(&o)], "x.csv");
}
