//! `msr eval` on a sim dataset with trained float models next to a quantized blob: every row the
//! pipeline can make is there, with its source; the autoencoder's fixed rows are absent with a
//! reason. Small and short on purpose (a plumbing test, not a quality one).
mod common;

use common::msr_ok as msr;
use serde_json::Value;
use std::path::Path;

fn p(x: &Path) -> &str {
    x.to_str().unwrap()
}

#[test]
fn eval_reports_trained_float_and_firmware_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, model) = (tmp.path().join("data"), tmp.path().join("model"));
    msr(&["dataset", "--count", "60", "--seed", "2", "--out", p(&data)]);
    for kind in ["decoder", "autoencoder"] {
        msr(&[
            "train",
            "--data",
            p(&data),
            "--model",
            kind,
            "--epochs",
            "2",
            "--out",
            p(&model),
        ]);
    }
    let reach = tmp.path().join("reach.safetensors");
    msr(&[
        "train-reach",
        "--inputs",
        p(&data.join("reach_centroids.csv")),
        "--targets",
        p(&data.join("reach_joints.csv")),
        "--iterations",
        "200",
        "--out",
        p(&reach),
    ]);
    let blob = model.join("model.msrm");
    msr(&[
        "quantize",
        "--train",
        p(&model),
        "--reach",
        p(&reach),
        "--out",
        p(&blob),
    ]);
    let v: Value = serde_json::from_str(&msr(&[
        "eval",
        "--model",
        p(&blob),
        "--data",
        p(&data),
        "--json",
    ]))
    .unwrap();
    let rows = v["rows"].as_array().unwrap();
    let has = |m: &str, w: &str, e: &str| {
        rows.iter()
            .find(|r| r["model"] == m && r["weighting"] == w && r["engine"] == e)
            .cloned()
    };
    for w in ["sigma", "none"] {
        for m in ["decoder", "autoencoder"] {
            let r = has(m, w, "float").unwrap_or_else(|| panic!("{m}/{w}/float missing: {v}"));
            assert!(r["source"].as_str().unwrap().contains("trained"), "{r}");
            let hit = r["hit_rate"].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&hit));
        }
        // The frames each row got wrong are listed, as many as its rates say.
        for r in rows.iter().filter(|r| r["weighting"] == w) {
            let (marked, unmarked) = (v["marked"].as_f64().unwrap(), v["unmarked"].as_f64().unwrap());
            let wrong = r["wrong"].as_array().unwrap();
            let missed = marked * (1.0 - r["hit_rate"].as_f64().unwrap());
            let fired = unmarked * r["false_alarm_rate"].as_f64().unwrap();
            assert_eq!(wrong.len(), (missed + fired).round() as usize, "{r}");
            let n_fired = wrong.iter().filter(|x| x["what"] == "fired").count();
            assert_eq!(n_fired, fired.round() as usize, "{r}");
            for x in wrong {
                assert!(["no blob", "off the mark", "fired"].contains(&x["what"].as_str().unwrap()), "{x}");
                assert!(Path::new(x["file"].as_str().unwrap()).is_file(), "{x}");
                assert_eq!(x["blob"].is_null(), x["what"] == "no blob", "{x}");
                assert_eq!(x["mark_pixels"].is_null(), x["what"] == "fired", "{x}");
            }
        }
        assert!(has("decoder", w, "fixed").is_some());
        assert!(has("autoencoder", w, "fixed").is_none());
    }
    let absent = v["absent"].as_array().unwrap();
    assert_eq!(
        absent
            .iter()
            .filter(|a| a["model"] == "autoencoder" && a["engine"] == "fixed")
            .count(),
        2
    );
    assert!(v["quantized_agreement"].as_f64().unwrap() >= 0.0);
    // Markdown for humans.
    let md = msr(&["eval", "--model", p(&blob), "--data", p(&data)]);
    assert!(
        md.contains("| decoder | sigma | fixed |") && md.contains("| autoencoder | none | float |"),
        "{md}"
    );
}
