//! Acceptance: the imported published model on the 15 published real frames finds all 9 marks
//! (centroid inside the mark's box) and nothing on the 6 unmarked frames, as the published method
//! does at threshold 4.59. Runs the `msr` binary end to end: import, then detect.
mod common;

use common::{msr, real_dir};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn import(dir: &Path, tmp: &Path) -> PathBuf {
    let blob = tmp.join("published.msrm");
    let (ok, out, err) = msr(&[
        "import",
        dir.join("manifest.json").to_str().unwrap(),
        "--out",
        blob.to_str().unwrap(),
    ]);
    assert!(ok, "import failed: {out}{err}");
    blob
}

fn check_engine(dir: &Path, blob: &Path, engine: &str) {
    let manifest: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
    let images = manifest["images"].as_array().unwrap();
    assert_eq!(images.len(), 15);
    let (mut found, mut false_alarms) = (0, 0);
    for im in images {
        let file = dir.join(im["file"].as_str().unwrap());
        let yaw = im["head_yaw"].as_f64().unwrap().to_string();
        let pitch = im["head_pitch"].as_f64().unwrap().to_string();
        let (ok, out, err) = msr(&[
            "detect",
            "--model",
            blob.to_str().unwrap(),
            "--image",
            file.to_str().unwrap(),
            "--head-yaw",
            &yaw,
            "--head-pitch",
            &pitch,
            "--engine",
            engine,
            "--json",
        ]);
        assert!(ok, "{engine} detect {} failed: {err}", file.display());
        let v: Value = serde_json::from_str(out.trim()).unwrap();
        assert_eq!(v["crop"]["width"], 75);
        assert_eq!(v["crop"]["height"], 58);
        eprintln!("{engine} {}: {}", im["file"], out.trim());
        match im["mark"].as_object() {
            None => {
                if !v["blob"].is_null() {
                    false_alarms += 1;
                }
                assert!(v["blob"].is_null() == v["joints"].is_null());
            }
            Some(mark) => {
                let b: Vec<f64> = mark["box_xyxy_inclusive"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect();
                let blob = &v["blob"];
                if blob.is_null() {
                    continue;
                }
                let (cx, cy) = (
                    blob["centroid"][0].as_f64().unwrap(),
                    blob["centroid"][1].as_f64().unwrap(),
                );
                assert!(blob["area"].as_u64().unwrap() >= 30);
                if cx >= b[0] && cx <= b[2] && cy >= b[1] && cy <= b[3] {
                    found += 1;
                }
                let joints = v["joints"].as_object().expect("a mark found gives joints");
                for name in [
                    "HeadYaw",
                    "HeadPitch",
                    "LShoulderPitch",
                    "LShoulderRoll",
                    "LElbowRoll",
                ] {
                    assert!(joints[name].as_f64().unwrap().is_finite(), "{name}");
                }
            }
        }
    }
    assert_eq!(
        found, 9,
        "{engine}: marks found with the centroid in the box"
    );
    assert_eq!(false_alarms, 0, "{engine}: detections on unmarked frames");
}

#[test]
fn published_model_finds_all_real_marks_and_nothing_else() {
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let blob = import(&dir, tmp.path());
    check_engine(&dir, &blob, "float");
    check_engine(&dir, &blob, "fixed");
}

#[test]
fn readable_line_and_picture() {
    let Some(dir) = real_dir() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let blob = import(&dir, tmp.path());
    let png = tmp.path().join("det.png");
    let (ok, out, err) = msr(&[
        "detect",
        "--model",
        blob.to_str().unwrap(),
        "--image",
        dir.join("test2_green2.png").to_str().unwrap(),
        "--head-yaw",
        "0.0779905144",
        "--head-pitch",
        "0.0801204423",
        "--png",
        png.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.starts_with("face at (139, 79) 75x58: mark of"), "{out}");
    assert!(out.contains("reach: HeadYaw"), "{out}");
    let img = image::open(&png).unwrap();
    // Frame, then two columns of 2x face panels.
    assert_eq!((img.width(), img.height()), (320 + 4 * 75 + 8, 240));
}
