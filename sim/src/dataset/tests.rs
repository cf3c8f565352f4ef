use super::*;

fn small(robot: Robot, seed: u64) -> DatasetConfig {
    DatasetConfig { count: 20, reach_pairs: 6, ..DatasetConfig::paper(robot, seed) }
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    for sub in ["", "frames", "masks"] {
        let mut names: Vec<_> = std::fs::read_dir(dir.join(sub))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .collect();
        names.sort();
        for p in names {
            out.push((p.strip_prefix(dir).unwrap().display().to_string(), std::fs::read(&p).unwrap()));
        }
    }
    out
}

#[test]
fn same_seed_same_bytes_other_seed_other_bytes() {
    let (a, b, c) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    write_dataset(&small(Robot::Skin, 5), a.path()).unwrap();
    write_dataset(&small(Robot::Skin, 5), b.path()).unwrap();
    write_dataset(&small(Robot::Skin, 6), c.path()).unwrap();
    let (fa, fb, fc) = (files(a.path()), files(b.path()), files(c.path()));
    assert!(fa.len() > 20);
    assert_eq!(fa, fb);
    assert_ne!(fa, fc);
}

#[test]
fn layout_is_the_published_one() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = small(Robot::Red, 1);
    let written = write_dataset(&cfg, dir.path()).unwrap();
    let index: DatasetIndex =
        serde_json::from_slice(&std::fs::read(dir.path().join(layout::INDEX_FILE)).unwrap()).unwrap();
    assert_eq!(index, written);
    assert_eq!((index.robot.as_str(), index.width, index.height), ("red", 320, 240));
    assert_eq!(index.frames.len(), 20);
    assert_eq!(index.split(Split::Test).count(), 4);
    let angles = std::fs::read_to_string(dir.path().join(layout::ANGLES_FILE)).unwrap();
    let rows: Vec<Vec<f64>> = angles
        .lines()
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 20);
    let a = 5f64.to_radians();
    for (f, row) in index.frames.iter().zip(&rows) {
        assert!((row[0] - f.head_yaw).abs() < 1e-9 && (row[1] - f.head_pitch).abs() < 1e-9);
        assert!(f.head_yaw.abs() <= a && f.head_pitch.abs() <= a);
        let img = image::open(dir.path().join(&f.file)).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (320, 240));
        // Marks on the test split only, with ground truth that matches the mask file.
        assert!(f.mark.is_none() || f.split == Split::Test);
        if let Some(m) = &f.mark {
            let mask = image::open(dir.path().join(&m.mask)).unwrap().to_luma8();
            let n = mask.pixels().filter(|p| p.0[0] == 255).count() as u32;
            assert!(mask.pixels().all(|p| p.0[0] == 0 || p.0[0] == 255));
            assert_eq!(n, m.pixels);
            assert!(n > 20, "{m:?}");
            assert!(crate::marks::KINDS.contains(&m.shape.as_str()));
            let [x0, y0, x1, y1] = m.box_xyxy_inclusive;
            assert!(x0 <= x1 && y0 <= y1 && x1 < 320 && y1 < 240);
            // 3-D point: on the head surface, and the torso point is it moved by the head pose.
            let ph = Point3::from(m.point_head_m);
            let pt = kin::head_to_torso(&ph, f.head_yaw, f.head_pitch);
            assert!((pt.coords - Vector3::from(m.point_torso_m)).norm() < 1e-12);
            let px = body::project_head(&ph, f.head_yaw, f.head_pitch).unwrap();
            assert!(px[0] >= x0 as f64 - 1.0 && px[0] <= x1 as f64 + 1.0);
            assert!(px[1] >= y0 as f64 - 1.0 && px[1] <= y1 as f64 + 1.0);
        }
    }
    let t = image::open(dir.path().join(&index.template)).unwrap();
    assert_eq!((t.width(), t.height()), (75, 58));
    assert!(matches!(t, image::DynamicImage::ImageLuma8(_)));
}

use nalgebra::{Point3, Vector3};

#[test]
fn reach_pairs_touch_their_marks() {
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(write_reach_pairs(dir.path(), 12, 3).unwrap(), 12);
    let read = |f: &str| -> Vec<Vec<f64>> {
        std::fs::read_to_string(dir.path().join(f))
            .unwrap()
            .lines()
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect()
    };
    let (c, j) = (read(layout::REACH_CENTROIDS_FILE), read(layout::REACH_JOINTS_FILE));
    assert_eq!((c.len(), j.len()), (12, 12));
    let lim = msr_shared::joints::REACH_JOINTS.map(|j| j.limits().unwrap());
    for (p, (cr, jr)) in reach_pairs(12, 3).iter().zip(c.iter().zip(&j)) {
        assert_eq!(cr.len(), 2);
        assert_eq!(jr.len(), 5);
        assert!((cr[0] - p.pixel[0]).abs() <= 0.5 && (cr[1] - p.pixel[1]).abs() <= 0.5);
        let q: kin::Reach = [jr[0], jr[1], jr[2], jr[3], jr[4]];
        assert!(kin::touch_distance(&q, &Point3::from(p.point_head)) < kin::IK_TOLERANCE_M + 1e-6);
        for (v, l) in jr.iter().zip(&lim) {
            assert!((*v as f32) >= l.min && (*v as f32) <= l.max && *v >= l.min as f64 - 1e-9);
        }
        // The pixel is where the mark's point shows at the observe posture.
        let px = body::project_head(&Point3::from(p.point_head), 0.0, 0.0).unwrap();
        assert_eq!(px, p.pixel);
    }
}

#[test]
fn bad_configs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    for cfg in [
        DatasetConfig { count: 0, ..small(Robot::Red, 0) },
        DatasetConfig { test_fraction: 1.5, ..small(Robot::Red, 0) },
        DatasetConfig { unmarked_test_fraction: -0.1, ..small(Robot::Red, 0) },
        DatasetConfig { max_head_angle: f64::NAN, ..small(Robot::Red, 0) },
        DatasetConfig { max_head_angle: 3.0, ..small(Robot::Red, 0) },
    ] {
        assert!(write_dataset(&cfg, dir.path()).is_err(), "{cfg:?}");
    }
    // An output path under a file cannot be created.
    let file = dir.path().join("plain-file");
    std::fs::write(&file, b"x").unwrap();
    assert!(write_dataset(&small(Robot::Red, 0), &file.join("sub")).is_err());
}

#[test]
fn unmarked_test_share_is_honoured_and_leaves_the_draws_alone() {
    let marked = |frac: f64| {
        let dir = tempfile::tempdir().unwrap();
        let cfg = DatasetConfig { count: 40, test_fraction: 0.5, reach_pairs: 0, unmarked_test_fraction: frac, ..small(Robot::Red, 3) };
        let index = write_dataset(&cfg, dir.path()).unwrap();
        assert!(index.frames.iter().all(|f| f.mark.is_none() || f.split == Split::Test));
        let angles: Vec<_> = index.frames.iter().map(|f| (f.head_yaw, f.head_pitch, f.split)).collect();
        (index.frames.iter().filter(|f| f.mark.is_some()).count(), angles)
    };
    let (all, a0) = marked(0.0);
    let (none, a1) = marked(1.0);
    let (some, a2) = marked(0.5);
    assert_eq!((all, none), (20, 0));
    assert!(some > 0 && some < 20, "{some} of 20 test frames marked");
    // Poses and splits do not depend on the share.
    assert!(a0 == a1 && a1 == a2);
}

#[test]
fn the_other_scene_keeps_the_mirror_draws_and_shows_a_face_that_does_not_follow() {
    let (m, o) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let cfg = DatasetConfig { count: 30, test_fraction: 0.5, reach_pairs: 0, ..small(Robot::Red, 7) };
    let mirror = write_dataset(&cfg, m.path()).unwrap();
    let other = write_dataset(&DatasetConfig { scene: DatasetScene::Other, ..cfg.clone() }, o.path()).unwrap();
    // The mirror dataset's JSON has no `seen_head`, as before the other scene.
    let json = std::fs::read_to_string(m.path().join(layout::INDEX_FILE)).unwrap();
    assert!(!json.contains("seen_head"));
    let a = 5f64.to_radians();
    let mut marked = 0;
    for (fm, fo) in mirror.frames.iter().zip(&other.frames) {
        // Our head, the split and which frames are marked (with which mark): the same draws.
        assert_eq!((fm.head_yaw, fm.head_pitch, fm.split), (fo.head_yaw, fo.head_pitch, fo.split));
        assert_eq!(fm.mark.as_ref().map(|k| (&k.shape, &k.colour)), fo.mark.as_ref().map(|k| (&k.shape, &k.colour)));
        assert_eq!(fm.seen_head, None);
        let [sy, sp] = fo.seen_head.expect("the other scene records the other's head");
        assert!(sy.abs() <= a && sp.abs() <= a);
        assert!((sy - fo.head_yaw).abs() + (sp - fo.head_pitch).abs() > 1e-6, "its own pose, not ours");
        let (im, io) = (std::fs::read(m.path().join(&fm.file)).unwrap(), std::fs::read(o.path().join(&fo.file)).unwrap());
        assert_ne!(im, io);
        if let Some(k) = &fo.mark {
            marked += 1;
            // The mark shows on the other's face, and its mask is the frame's.
            assert!(k.pixels > 0, "{k:?}");
            let mask = image::open(o.path().join(&k.mask)).unwrap().to_luma8();
            assert_eq!(mask.pixels().filter(|p| p.0[0] > 0).count() as u32, k.pixels);
        }
    }
    assert!(marked >= 5, "{marked}");
    // Same seed, same bytes.
    let again = tempfile::tempdir().unwrap();
    write_dataset(&DatasetConfig { scene: DatasetScene::Other, ..cfg }, again.path()).unwrap();
    assert_eq!(files(o.path()), files(again.path()));
}

/// FNV-1a 64 over every file of a dataset (names and bytes): a digest that does not depend
/// on the Rust version.
fn digest(dir: &Path) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for (name, bytes) in files(dir) {
        for b in name.bytes().chain(bytes) {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// A fixed-light dataset's bytes are fixed: a change to what the renderer draws shows here
/// (the face crops, which the models learn from, are checked byte for byte by the demo's
/// model; these frames also hold the hands at home, below the face).
#[test]
fn fixed_light_datasets_keep_their_bytes() {
    for (robot, want) in [(Robot::Red, FIXED_RED), (Robot::Skin, FIXED_SKIN)] {
        let d = tempfile::tempdir().unwrap();
        write_dataset(&DatasetConfig { count: 10, reach_pairs: 2, ..DatasetConfig::paper(robot, 11) }, d.path()).unwrap();
        assert_eq!(digest(d.path()), want, "{robot:?}: {:#x}", digest(d.path()));
    }
}
const FIXED_RED: u64 = 0x245c_dcc1_ee87_2f0a;
const FIXED_SKIN: u64 = 0x56d1_34de_8143_7aa2;

/// A varied-light dataset keeps the fixed one's poses, split and marks, and its frames differ
/// in brightness by up to about a third.
#[test]
fn varied_light_keeps_the_draws_and_changes_the_brightness() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let cfg = DatasetConfig { count: 12, reach_pairs: 0, ..DatasetConfig::paper(Robot::Red, 3) };
    let fa = write_dataset(&cfg, a.path()).unwrap();
    let fb = write_dataset(&DatasetConfig { light: LightMode::Varied, ..cfg }, b.path()).unwrap();
    let mean = |d: &Path, f: &str| {
        let g = image::open(d.join(f)).unwrap().to_luma8();
        g.as_raw().iter().map(|&v| v as f64).sum::<f64>() / g.as_raw().len() as f64
    };
    let mut ratios = Vec::new();
    for (x, y) in fa.frames.iter().zip(&fb.frames) {
        assert_eq!((x.head_yaw, x.head_pitch, x.split), (y.head_yaw, y.head_pitch, y.split));
        assert_eq!(x.mark.as_ref().map(|m| &m.shape), y.mark.as_ref().map(|m| &m.shape));
        ratios.push(mean(b.path(), &y.file) / mean(a.path(), &x.file));
    }
    let (lo, hi) = ratios.iter().fold((f64::MAX, 0f64), |(l, h), &r| (l.min(r), h.max(r)));
    assert!(lo < 0.9 && hi > 1.1 && lo > 0.4, "{ratios:?}");
}
