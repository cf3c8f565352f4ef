//! Bad input to import, detect and eval: one clear line on stderr, non-zero exit, never a panic.
//! Manifests are edited copies of the published one, pointing at the published files.
mod common;
/// The end-to-end tests' model trained on the sim's robot, for the tests that run episodes.
#[path = "../../tests/tests/common/mod.rs"]
mod trained;

use common::{msr, msr_code, real_dir};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn fails_with(args: &[&str], want: &str) {
    let (ok, out, err) = msr(args);
    assert!(!ok, "{args:?} succeeded: {out}");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    assert_eq!(
        err.trim().lines().count(),
        1,
        "{args:?}: not one line: {err}"
    );
    assert!(err.contains(want), "{args:?}: expected `{want}` in: {err}");
}

/// The published manifest with absolute file paths, edited by `f`, written to `tmp`.
fn manifest(dir: &Path, tmp: &Path, name: &str, f: impl FnOnce(&mut Value)) -> PathBuf {
    let mut m: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
    let abs =
        |v: &mut Value| *v = Value::String(dir.join(v.as_str().unwrap()).display().to_string());
    abs(&mut m["face_crop"]["template"]);
    abs(&mut m["decoder"]["weights"]);
    abs(&mut m["error_statistics"]["mu"]);
    abs(&mut m["error_statistics"]["sigma"]);
    abs(&mut m["reach"]["weights"]);
    abs(&mut m["head_angles"]["file"]);
    f(&mut m);
    let p = tmp.join(name);
    std::fs::write(&p, serde_json::to_string(&m).unwrap()).unwrap();
    p
}

#[test]
fn import_refuses_bad_manifests() {
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("x.msrm");
    let o = out.to_str().unwrap();

    let good = manifest(&dir, tmp.path(), "good.json", |_| {});
    let (ok, _, err) = msr(&["import", good.to_str().unwrap(), "--out", o]);
    assert!(ok, "{err}");

    let m = manifest(&dir, tmp.path(), "missing.json", |m| {
        m["decoder"]["layers"][2]["weight"] = "decoder.9.weight".into()
    });
    fails_with(
        &["import", m.to_str().unwrap(), "--out", o],
        "tensor `decoder.9.weight` is missing",
    );

    let m = manifest(&dir, tmp.path(), "shape.json", |m| {
        m["decoder"]["layers"][1]["shape"] = serde_json::json!([64, 13])
    });
    fails_with(
        &["import", m.to_str().unwrap(), "--out", o],
        "has shape [64, 12], the manifest says [64, 13]",
    );

    let m = manifest(&dir, tmp.path(), "stats.json", |m| {
        m["error_statistics"]["shape"] = serde_json::json!([75, 58])
    });
    fails_with(&["import", m.to_str().unwrap(), "--out", o], "disagree");

    let m = manifest(&dir, tmp.path(), "nofile.json", |m| {
        m["error_statistics"]["mu"] = "/nonexistent/mu.npy".into()
    });
    fails_with(
        &["import", m.to_str().unwrap(), "--out", o],
        "cannot read /nonexistent/mu.npy",
    );

    // A corrupt npy and a corrupt safetensors file.
    let junk = tmp.path().join("junk.bin");
    std::fs::write(&junk, b"\x93NUMPY garbage").unwrap();
    let j = junk.display().to_string();
    let m = manifest(&dir, tmp.path(), "badnpy.json", |m| {
        m["error_statistics"]["sigma"] = j.clone().into()
    });
    fails_with(
        &["import", m.to_str().unwrap(), "--out", o],
        "not a valid .npy file",
    );
    let m = manifest(&dir, tmp.path(), "badst.json", |m| {
        m["decoder"]["weights"] = j.clone().into()
    });
    fails_with(
        &["import", m.to_str().unwrap(), "--out", o],
        "not a valid safetensors file",
    );

    let not_json = tmp.path().join("not.json");
    std::fs::write(&not_json, "{ nope").unwrap();
    fails_with(
        &["import", not_json.to_str().unwrap(), "--out", o],
        "not a valid model manifest",
    );
    fails_with(
        &["import", "/nonexistent/manifest.json", "--out", o],
        "cannot read manifest",
    );
}

#[test]
fn detect_and_eval_refuse_bad_input() {
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let blob = tmp.path().join("p.msrm");
    let b = blob.to_str().unwrap();
    let (ok, _, err) = msr(&[
        "import",
        dir.join("manifest.json").to_str().unwrap(),
        "--out",
        b,
    ]);
    assert!(ok, "{err}");
    let frame = dir.join("test1.png");
    let f = frame.to_str().unwrap();

    fails_with(
        &[
            "detect",
            "--model",
            b,
            "--image",
            f,
            "--head-yaw",
            "NaN",
            "--head-pitch",
            "0",
        ],
        "finite",
    );
    fails_with(
        &[
            "detect",
            "--model",
            b,
            "--image",
            f,
            "--head-yaw",
            "0",
            "--head-pitch",
            "inf",
        ],
        "finite",
    );
    fails_with(
        &[
            "detect",
            "--model",
            b,
            "--image",
            "/nonexistent.png",
            "--head-yaw",
            "0",
            "--head-pitch",
            "0",
        ],
        "cannot read image",
    );

    let small = tmp.path().join("small.png");
    image::GrayImage::new(60, 40).save(&small).unwrap();
    fails_with(
        &[
            "detect",
            "--model",
            b,
            "--image",
            small.to_str().unwrap(),
            "--head-yaw",
            "0",
            "--head-pitch",
            "0",
        ],
        // One rule for every path, the model's frame size or larger.
        "60x40, smaller than the 320x240",
    );

    // A flipped byte in the blob: the CRC catches it.
    let mut bytes = std::fs::read(&blob).unwrap();
    let n = bytes.len();
    bytes[n / 2] ^= 0x40;
    let bad = tmp.path().join("bad.msrm");
    std::fs::write(&bad, &bytes).unwrap();
    fails_with(
        &[
            "detect",
            "--model",
            bad.to_str().unwrap(),
            "--image",
            f,
            "--head-yaw",
            "0",
            "--head-pitch",
            "0",
        ],
        "CRC",
    );
    std::fs::write(&bad, &bytes[..100]).unwrap();
    fails_with(
        &[
            "detect",
            "--model",
            bad.to_str().unwrap(),
            "--image",
            f,
            "--head-yaw",
            "0",
            "--head-pitch",
            "0",
        ],
        "truncated",
    );

    fails_with(
        &["eval", "--model", b, "--data", "/nonexistent/dir"],
        "does not exist",
    );
    fails_with(
        &[
            "eval",
            "--model",
            bad.to_str().unwrap(),
            "--data",
            dir.to_str().unwrap(),
        ],
        "truncated",
    );
}

#[test]
fn eval_on_the_real_frames_shows_sigma_weighting_matters() {
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let blob = tmp.path().join("p.msrm");
    let b = blob.to_str().unwrap();
    assert!(
        msr(&[
            "import",
            dir.join("manifest.json").to_str().unwrap(),
            "--out",
            b
        ])
        .0
    );
    let (ok, out, err) = msr(&[
        "eval",
        "--model",
        b,
        "--data",
        dir.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["test_frames"], 15);
    assert_eq!(v["marked"], 9);
    let rows = v["rows"].as_array().unwrap();
    let get = |w: &str, e: &str| {
        rows.iter()
            .find(|r| r["model"] == "decoder" && r["weighting"] == w && r["engine"] == e)
            .unwrap()
    };
    for e in ["float", "fixed"] {
        assert_eq!(get("sigma", e)["hit_rate"], 1.0);
        assert_eq!(get("sigma", e)["false_alarm_rate"], 0.0);
        // Sigma = I: face regions become salient on unmarked frames.
        assert!(get("none", e)["false_alarm_rate"].as_f64().unwrap() > 0.5);
    }
    assert_eq!(v["quantized_agreement"], 1.0);
    // With the manifest, the float rows are the published float decoder and statistics.
    let m = dir.join("manifest.json");
    let (ok, out, err) = msr(&[
        "eval",
        "--model",
        b,
        "--data",
        dir.to_str().unwrap(),
        "--manifest",
        m.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let w: Value = serde_json::from_str(&out).unwrap();
    let r = w["rows"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["engine"] == "float" && r["weighting"] == "sigma")
        .unwrap()
        .clone();
    assert!(
        r["source"]
            .as_str()
            .unwrap()
            .contains("published float decoder"),
        "{r}"
    );
    assert_eq!(r["hit_rate"], 1.0);
    assert_eq!(r["false_alarm_rate"], 0.0);
    let absent = v["absent"].as_array().unwrap();
    assert!(absent
        .iter()
        .any(|a| a["model"] == "autoencoder" && a["reason"].as_str().unwrap().len() > 10));
}

// ---------------------------------------------------------------------------------------------
// Every case found by trying `msr` as a new user with bad input. Each refusal happens
// before any work (no model, port or dataset is needed to reach it) and is one line.

/// Exit code, stdout, stderr.
fn file(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn mirror_test_refuses_trial_counts_it_cannot_hold() {
    // Was: a capacity-overflow panic, and an abort allocating 184 GB.
    fails_with(
        &["mirror-test", "--model", "m.msrm", "--trials", "18446744073709551615"],
        "--trials must be in 1..=100000, got 18446744073709551615",
    );
    fails_with(
        &["mirror-test", "--model", "m.msrm", "--trials", "1000000000"],
        "--trials must be in 1..=100000",
    );
    fails_with(&["mirror-test", "--model", "m.msrm", "--trials", "0"], "--trials must be in 1..=100000");
}

#[test]
fn mirror_test_refuses_arm_errors_and_touch_radii_it_does_not_know() {
    for level in ["3", "1.5", "x"] {
        fails_with(&["mirror-test", "--model", "m.msrm", "--arm-error", level], "--arm-error");
    }
    for r in ["0", "0.5", "101", "NaN", "inf"] {
        fails_with(&["mirror-test", "--model", "m.msrm", "--touch-radius-mm", r], "a touch radius between 1 and 100 mm");
    }
}

#[test]
fn run_refuses_frame_rates_and_line_rates_that_never_finish() {
    // Was: a panic (the frame period overflowed a Duration) and waits for ever.
    for fps in ["1e-20", "1e-9", "0", "-5", "inf", "NaN"] {
        fails_with(
            &["run", "--port", "/nonexistent/tty", "--model", "m.msrm", "--sim", "red", "--fps", fps],
            "--fps must be a number in 0.1..=1000 frames per second",
        );
    }
    fails_with(
        &["run", "--port", "/nonexistent/tty", "--model", "m.msrm", "--sim", "red", "--baud", "1"],
        "--baud must be in 1200..=20000000 baud, got 1",
    );
    // A line rate in range that cannot carry a face crop within a frame period: refused with
    // the figures, before the port is opened.
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let blob = tmp.path().join("p.msrm");
    let (ok, _, err) = msr(&["import", dir.join("manifest.json").to_str().unwrap(), "--out", blob.to_str().unwrap()]);
    assert!(ok, "{err}");
    fails_with(
        &["run", "--port", "/nonexistent/tty", "--model", blob.to_str().unwrap(), "--sim", "red", "--baud", "1200"],
        "longer than the frame period",
    );
}

#[test]
fn run_help_says_what_sim_takes() {
    let (code, out, _) = msr_code(&["run", "--help"]);
    assert_eq!(code, 0);
    // The flag's line and its description (on the same line, or the next ones in clap's long
    // layout) up to the next blank line.
    let at = out.find("--sim <").unwrap();
    let entry = out[at..].split("\n\n").next().unwrap();
    assert!(entry.contains("<ROBOT>") && entry.contains("red or skin"), "{entry}");
}

#[test]
fn blobs_centroid_is_right_on_a_large_all_foreground_mask() {
    // Was: centroid (209.9, 67.8) with "overflow": false, a 32-bit coordinate sum wrapping.
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("full.png");
    image::GrayImage::from_pixel(4000, 3000, image::Luma([255])).save(&p).unwrap();
    let (ok, out, err) = msr(&["blobs", "--mask", p.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["overflow"], false);
    let b = &v["blobs"].as_array().unwrap()[0];
    assert_eq!(b["area"], 12_000_000);
    assert_eq!(b["centroid"][0].as_f64().unwrap(), 1999.5, "{b}");
    assert_eq!(b["centroid"][1].as_f64().unwrap(), 1499.5, "{b}");
}

#[test]
fn import_refuses_an_all_zero_sigma() {
    // Was: accepted; the blob then marked the whole face on an unmarked real frame.
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let zero = tmp.path().join("zero_sigma.npy");
    let mut bytes = std::fs::read(dir.join("sigma_for_decoder.npy")).unwrap();
    let header = 10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    bytes[header..].fill(0);
    std::fs::write(&zero, &bytes).unwrap();
    let z = zero.display().to_string();
    let m = manifest(&dir, tmp.path(), "zero.json", |m| m["error_statistics"]["sigma"] = z.clone().into());
    let out = tmp.path().join("x.msrm");
    fails_with(
        &["import", m.to_str().unwrap(), "--out", out.to_str().unwrap()],
        "4350 of 4350 values are below 1/256 grey level",
    );
    assert!(!out.exists(), "no blob written");
}

#[test]
fn a_truncated_npy_names_its_file() {
    // Was: "failed to fill whole buffer", no file named.
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(dir.join("mu_for_decoder.npy")).unwrap();
    let cut = file(tmp.path(), "cut_mu.npy", &bytes[..bytes.len() / 2]);
    let c = cut.display().to_string();
    let m = manifest(&dir, tmp.path(), "cut.json", |m| m["error_statistics"]["mu"] = c.clone().into());
    let out = tmp.path().join("x.msrm");
    fails_with(
        &["import", m.to_str().unwrap(), "--out", out.to_str().unwrap()],
        &format!("{c} is truncated"),
    );
}

#[test]
fn outputs_never_overwrite_inputs() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let frame = file(d, "frame.png", b"frame bytes");
    let model = file(d, "m.msrm", b"model bytes");
    let weights = file(d, "w.safetensors", b"weights");
    let manifest = file(d, "manifest.json", br#"{"decoder": {"weights": "w.safetensors"}}"#);
    let csv = file(d, "in.csv", b"1,2\n");
    let targets = file(d, "t.csv", b"0,0,0,0,0\n");
    let reach = file(d, "reach.safetensors", b"reach");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["detect".into(), "--model".into(), s(&model), "--image".into(), s(&frame), "--head-yaw".into(),
                 "0".into(), "--head-pitch".into(), "0".into(), "--png".into(), s(&frame)],
            "--png",
        ),
        (
            vec!["mirror-test".into(), "--model".into(), s(&model), "--trials-out".into(), s(&model)],
            "--trials-out",
        ),
        (vec!["import".into(), s(&manifest), "--out".into(), s(&manifest)], "the manifest"),
        (vec!["import".into(), s(&manifest), "--out".into(), s(&weights)], "a file of the manifest"),
        (
            vec!["train-reach".into(), "--inputs".into(), s(&csv), "--targets".into(), s(&targets), "--out".into(), s(&csv)],
            "--inputs",
        ),
        (
            vec!["quantize".into(), "--train".into(), s(d), "--reach".into(), s(&reach), "--out".into(), s(&reach)],
            "--reach",
        ),
    ];
    for (args, which) in &cases {
        let a: Vec<&str> = args.iter().map(|x| x.as_str()).collect();
        fails_with(&a, "refusing to overwrite an input");
        let (_, _, err) = msr(&a);
        assert!(err.contains(which), "{a:?}: {err}");
    }
    for (p, want) in [
        (&frame, &b"frame bytes"[..]),
        (&model, b"model bytes"),
        (&weights, b"weights"),
        (&csv, b"1,2\n"),
        (&reach, b"reach"),
    ] {
        assert_eq!(std::fs::read(p).unwrap(), want, "{} changed", p.display());
    }
}

#[test]
fn an_unwritable_trials_out_is_refused_before_any_trial() {
    // Was: every trial ran, then a write error naming no path, and the summary was lost.
    let tmp = tempfile::tempdir().unwrap();
    // The model is not one: an error about the output, alone, says it was checked first.
    let model = file(tmp.path(), "m.msrm", b"not even a model");
    fails_with(
        &["mirror-test", "--model", model.to_str().unwrap(), "--trials-out", "/proc/t.json"],
        "--trials-out /proc/t.json: cannot write in /proc",
    );
    let under_a_file = model.join("t.json");
    fails_with(
        &["mirror-test", "--model", model.to_str().unwrap(), "--trials-out", under_a_file.to_str().unwrap()],
        "is not a folder",
    );
}

#[test]
fn flags_take_negative_numbers_and_check_them_in_their_own_unit() {
    // Was: "unexpected argument '-0'" for --ber -0.1, while --head-yaw -1e30 was a value.
    fails_with(&["mirror-test", "--model", "m.msrm", "--ber", "-0.1"], "--ber must be a number in 0..=1");
    fails_with(
        &["detect", "--model", "m", "--image", "i", "--head-yaw", "-1e30", "--head-pitch", "0"],
        "outside [-2.08567, 2.08567]",
    );
    // Was: a degrees flag refused in radians ("0..=0.35 rad").
    fails_with(
        &["dataset", "--out", "unused", "--max-angle-deg", "30"],
        "--max-angle-deg must be a number in 0..=20.05 deg, got 30",
    );
    fails_with(&["dataset", "--out", "unused", "--count", "-3"], "--count");
    assert!(!Path::new("unused").exists());
}

#[test]
fn an_image_error_is_said_once() {
    // Was: "Invalid PNG signature.: Invalid PNG signature."
    let tmp = tempfile::tempdir().unwrap();
    let p = file(tmp.path(), "bad.png", b"not a png");
    let (ok, _, err) = msr(&["blobs", "--mask", p.to_str().unwrap()]);
    assert!(!ok);
    assert_eq!(err.matches("Invalid PNG signature").count(), 1, "{err}");
    assert!(err.contains(p.to_str().unwrap()), "{err}");
}

#[test]
fn dataset_states_its_size_first() {
    // Was: --count 1000000 started writing 100 GB with no estimate and no progress.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("ds");
    let (code, _, err) = msr_code(&["dataset", "--count", "3", "--reach-pairs", "2", "--out", out.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let first = err.lines().next().unwrap();
    assert!(first.contains("3 frames") && first.contains("on disk"), "{first}");
    fails_with(
        &["dataset", "--count", "1000001", "--out", out.to_str().unwrap()],
        "--count must be in 1..=1000000 frames",
    );
}

/// A trial with only the fields that matter here set.
fn trial(index: usize, mark: Option<&str>, ended_before_mark: bool, touched: bool) -> msr_host::episode::Trial {
    msr_host::episode::Trial {
        index,
        scene: "mirror".into(),
        mark: mark.map(String::from),
        ended_before_mark,
        reached: touched || ended_before_mark,
        false_reach: ended_before_mark,
        touched,
        ..Default::default()
    }
}

#[test]
fn mirror_test_summary_counts_early_ends_apart_and_has_no_rate_without_marks() {
    use msr_host::episode::{summarise, Backend, ServoBus};
    // Was: a trial that ended before the mark appeared counted as a no-mark trial, and a touch
    // rate of 0.0 for 0 marked trials.
    let t = [trial(0, None, true, false), trial(1, None, false, false)];
    let s = summarise(Backend::Inproc, msr_sim::Robot::Red, ServoBus::Framed, &t);
    assert_eq!((s.marked_trials, s.no_mark_trials, s.ended_before_mark), (0, 1, 1));
    assert_eq!(s.touch_rate, None);
    let json = serde_json::to_value(&s).unwrap();
    assert!(json["touch_rate"].is_null(), "{json}");
    let text = msr_host::cmd::mirror_test::readable(&s);
    assert!(text.contains("touched 0/0 marked (- %)") && text.contains("1 ended before the mark appeared"), "{text}");
    let t = [trial(0, Some("red dot"), false, true), trial(1, Some("red dot"), false, false)];
    assert_eq!(summarise(Backend::Inproc, msr_sim::Robot::Red, ServoBus::Framed, &t).touch_rate, Some(0.5));
}

#[test]
fn link_losses_are_not_blamed_on_detection() {
    // Was: trials whose frames got no answer over the link at --ber 1e-4 were failed as
    // "detection: no blob in 0 frames with the mark". Since host-link protocol 2 repeats lost
    // chunks, frames get through at 1e-4; at 1e-2 (most chunks of every round damaged) none do.
    // A model of the sim's red robot: the published one is of the real robot's face, which the
    // board calls no face in the sim's frames.
    let tmp = tempfile::tempdir().unwrap();
    let blob = tmp.path().join("p.msrm");
    std::fs::write(&blob, trained::trained_model(msr_sim::Robot::Red)).unwrap();
    let trials = tmp.path().join("t.json");
    let (ok, _, err) = msr(&[
        "mirror-test", "--model", blob.to_str().unwrap(), "--trials", "2", "--ber", "1e-2", "--no-mark-share", "0",
        "--trials-out", trials.to_str().unwrap(), "--json",
    ]);
    assert!(ok, "{err}");
    let v: Value = serde_json::from_slice(&std::fs::read(&trials).unwrap()).unwrap();
    let failures: Vec<&str> = v.as_array().unwrap().iter().filter_map(|t| t["failure"].as_str()).collect();
    for f in &failures {
        assert!(!f.contains("no blob in 0 frames"), "{f}");
    }
    assert!(failures.iter().any(|f| f.contains("link:")), "{failures:?}");
}

#[test]
fn import_bag_joint_names_at_fault_exit_2() {
    // Was: exit 1, as if a file were at fault.
    for names in ["A,A", "A", ",B"] {
        let (code, _, err) = msr_code(&["import-bag", "bag", "--image-topic", "/i", "--joints-topic", "/j", "--template", "t.png", "--out", "o", "--joint-names", names]);
        assert_eq!(code, 2, "{names}: {err}");
        assert!(err.contains("--joint-names takes two different names"), "{err}");
    }
}
