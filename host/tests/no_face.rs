//! No face, no detection: a black, a white and a covered frame and one of an empty room give no
//! detection and a stated reason, in `msr detect` and through `msr run` against `msr serve`
//! (the board's own refusal, counted in its `Status`). A frame of the face gives one, so the
//! refusal is not of everything.
mod common;

use common::{msr, msr_ok};
use image::{GrayImage, Luma};
use rand::{Rng, SeedableRng};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

/// The frames no model can explain, by name.
fn faceless(dir: &Path) -> Vec<(&'static str, std::path::PathBuf)> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let mut wall = GrayImage::new(320, 240);
    for (x, _, p) in wall.enumerate_pixels_mut() {
        // A lit wall: a gradient across the room and the camera's noise.
        *p = Luma([(90.0 + 70.0 * x as f32 / 319.0 + rng.gen_range(-4.0..4.0)) as u8]);
    }
    let frames = [
        ("black", GrayImage::from_pixel(320, 240, Luma([0]))),
        ("white", GrayImage::from_pixel(320, 240, Luma([255]))),
        ("covered", GrayImage::from_pixel(320, 240, Luma([40]))),
        ("empty room", wall),
    ];
    frames
        .into_iter()
        .enumerate()
        .map(|(i, (name, im))| {
            let p = dir.join(format!("{i:03}.png"));
            im.save(&p).unwrap();
            (name, p)
        })
        .collect()
}

/// A small red model trained on the spot (10 epochs: enough to predict the face).
fn model(dir: &Path) -> std::path::PathBuf {
    let d = |s: &str| dir.join(s).to_str().unwrap().to_string();
    msr_ok(&["dataset", "--robot", "red", "--count", "100", "--seed", "3", "--out", &d("data")]);
    msr_ok(&["train", "--data", &d("data"), "--epochs", "10", "--quiet", "--out", &d("model")]);
    let reach = d("reach.safetensors");
    msr_ok(&["train-reach", "--inputs", &d("data/reach_centroids.csv"), "--targets", &d("data/reach_joints.csv"), "--iterations", "300", "--no-loo", "--out", &reach]);
    msr_ok(&["quantize", "--train", &d("model"), "--reach", &reach, "--out", &d("model.msrm")]);
    dir.join("model.msrm")
}

#[test]
fn frames_without_a_face_detect_nothing_and_say_why() {
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    let m = m.to_str().unwrap();
    let frames = tmp.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let faceless = faceless(&frames);

    // msr detect: each refused, with its reason and the fit.
    for (name, p) in &faceless {
        let out = msr_ok(&["detect", "--model", m, "--image", p.to_str().unwrap(), "--head-yaw", "0", "--head-pitch", "0"]);
        assert!(out.starts_with("no detection: NoFace") || out.starts_with("no detection: SceneChanged"), "{name}: {out}");
        let (ok, json, err) = msr(&["detect", "--model", m, "--image", p.to_str().unwrap(), "--head-yaw", "0", "--head-pitch", "0", "--json"]);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert!(v["reason"].is_string(), "{name}: {v}");
        assert!(v["blob"].is_null() && v["joints"].is_null(), "{name}: no mark and no reach: {v}");
    }
    // The control: a frame of the face is looked at (a face, a mark or none).
    let yaw_pitch = std::fs::read_to_string(tmp.path().join("data/head_angles.csv")).unwrap();
    let (yaw, pitch) = yaw_pitch.lines().next().unwrap().split_once(',').unwrap();
    let face = tmp.path().join("data/frames/000000.png");
    let out = msr_ok(&["detect", "--model", m, "--image", face.to_str().unwrap(), "--head-yaw", yaw, "--head-pitch", pitch.split(',').next().unwrap()]);
    assert!(out.starts_with("face at"), "{out}");

    // msr run against msr serve: the board refuses the same frames and counts them.
    // The board starts with the model (an upload is tested elsewhere; here it would only add
    // 5.7 s of line time to wait through).
    let mut serve = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["serve", "--robot", "red", "--model", m, "--seconds", "600"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut port = String::new();
    BufReader::new(serve.stdout.take().unwrap()).read_line(&mut port).unwrap();
    let port = port.trim().to_string();
    let (ok, out, err) = msr(&["run", "--port", &port, "--model", m, "--frames", frames.to_str().unwrap(), "--fps", "5"]);
    serve.kill().unwrap();
    serve.wait().unwrap();
    assert!(ok, "msr run: {err}\n{out}");
    eprintln!("{out}");
    let refused = out.lines().filter(|l| l.contains("no detection: NoFace") || l.contains("no detection: SceneChanged")).count();
    assert_eq!(refused, faceless.len(), "{out}");
    assert!(!out.contains("REACH") && !out.contains("mark at"), "{out}");
    let status = out.lines().rfind(|l| l.starts_with("status:")).unwrap_or_else(|| panic!("no status: {out}"));
    let counted = |what: &str| -> u32 {
        let at = status.find(what).unwrap() + what.len();
        status[at..].split_whitespace().next().unwrap().trim_end_matches([',', ';']).parse().unwrap()
    };
    assert_eq!(counted("NoFace ") + counted("SceneChanged "), faceless.len() as u32, "{status}");
}
