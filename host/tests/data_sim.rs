//! Loading a sim dataset (written by `msr dataset`), and clear errors for broken ones.
use msr_host::data::crop::CropMode;
use msr_host::data::{Dataset, Layout};
use msr_sim::layout::Split;
use std::process::Command;

fn make(dir: &std::path::Path, count: u32) {
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args([
            "dataset",
            "--count",
            &count.to_string(),
            "--seed",
            "4",
            "--out",
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn loads_a_sim_dataset_with_exact_masks() {
    let tmp = tempfile::tempdir().unwrap();
    make(tmp.path(), 30);
    let ds = Dataset::load(tmp.path(), CropMode::Subpixel).unwrap();
    assert_eq!(ds.layout, Layout::Sim);
    assert_eq!(ds.crop, CropMode::Subpixel);
    assert_eq!(ds.samples.len(), 30);
    let (h, w) = ds.face_size();
    let test: Vec<_> = ds.split(Split::Test).collect();
    assert!(!test.is_empty() && test.len() < 30);
    for s in &ds.samples {
        assert!(s.head.iter().all(|a| a.abs() < 0.1), "{:?}", s.head);
        assert_eq!(s.face.grey.len(), h * w);
        let c = s.crop();
        assert!(c.x + c.width <= ds.frame_size.0 && c.y + c.height <= ds.frame_size.1);
        if let Some(m) = &s.mark {
            assert!(m.exact_mask);
            assert!(m.pixels_in_face() as u32 <= m.pixels);
            // Sim marks are put on the face: most of the mark must fall in the crop.
            assert!(
                m.pixels_in_face() as u32 * 2 > m.pixels,
                "{}: {} of {}",
                s.file.display(),
                m.pixels_in_face(),
                m.pixels
            );
        }
    }
    let (heads, faces) = ds.arrays(Split::Train);
    assert_eq!(heads.len(), 30 - test.len());
    assert!(faces
        .iter()
        .all(|f| f.len() == h * w && f.iter().all(|v| (0.0..=1.0).contains(v))));
    let only_test = Dataset::load_split(tmp.path(), Some(Split::Test), CropMode::Pixel).unwrap();
    assert_eq!(only_test.samples.len(), test.len());
    // Whole-pixel crops: the same windows, no shift, the frame's own pixels.
    for (p, s) in only_test.samples.iter().zip(test) {
        assert_eq!((p.file.as_path(), p.face.crop), (s.file.as_path(), s.face.crop));
        assert_eq!(p.face.shift, [0.0, 0.0]);
    }
    // Sub-pixel crops move by less than half a pixel, and do move: head angles are continuous.
    assert!(ds.samples.iter().all(|s| s.face.shift.iter().all(|d| d.abs() <= 0.5)));
    assert!(ds.samples.iter().filter(|s| s.face.shift != [0.0, 0.0]).count() * 2 > ds.samples.len());
}

#[test]
fn broken_datasets_say_what_is_wrong() {
    let tmp = tempfile::tempdir().unwrap();
    make(tmp.path(), 10);
    let index = std::fs::read_to_string(tmp.path().join("dataset.json")).unwrap();
    let first = serde_json::from_str::<serde_json::Value>(&index).unwrap()["frames"][0]["file"]
        .as_str()
        .unwrap()
        .to_string();
    std::fs::write(tmp.path().join(&first), b"corrupt").unwrap();
    let e = format!("{:#}", Dataset::load(tmp.path(), CropMode::Pixel).unwrap_err());
    assert!(e.contains("cannot read image") && e.contains(&first), "{e}");
    make(tmp.path(), 10);
    std::fs::write(
        tmp.path().join("dataset.json"),
        index.replacen("\"head_yaw\":", "\"head_yaw\":\"x\",\"y\":", 1),
    )
    .unwrap();
    let e = format!("{:#}", Dataset::load(tmp.path(), CropMode::Pixel).unwrap_err());
    assert!(e.contains("not a valid dataset.json"), "{e}");
    let e = format!(
        "{:#}",
        Dataset::load(&tmp.path().join("nowhere"), CropMode::Pixel).unwrap_err()
    );
    assert!(e.contains("does not exist"), "{e}");
    let empty = tempfile::tempdir().unwrap();
    let e = format!("{:#}", Dataset::load(empty.path(), CropMode::Pixel).unwrap_err());
    assert!(e.contains("neither dataset.json nor manifest.json"), "{e}");
}
