//! Bad input to import, detect and eval: one clear line on stderr, non-zero exit, never a panic.
//! Manifests are edited copies of the published one, pointing at the published files.
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn real_dir() -> Option<PathBuf> {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nao-red-real");
    if d.join("manifest.json").is_file() {
        Some(d.canonicalize().unwrap())
    } else {
        eprintln!("SKIP: real data folder {} is absent", d.display());
        None
    }
}

fn msr(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

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
        "smaller than the face template",
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
