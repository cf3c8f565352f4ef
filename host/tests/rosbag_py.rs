//! ROS 2 recordings against implementations that are not msr's: the Python `rosbags` package
//! writes bags (MCAP and SQLite3, every image encoding `msr import-bag` reads) from sim frames,
//! and reads back every message of `msr`'s MCAP output with its own CDR decoder; the Python `mcap`
//! package checks that file's summary and index (host/tests/rosbag/*.py).
//!
//! Needs the venv `target/pyenv` that `cargo xtask setup` (and `cargo xtask test`) makes; without
//! it these tests fail and say so.
mod common;
#[path = "../../tests/tests/common/mod.rs"]
mod models;

use image::GrayImage;
use msr_host::data::crop::to_grey;
use msr_sim::layout::DatasetIndex;
use msr_sim::Robot;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

fn python() -> PathBuf {
    let py = root().join("target/pyenv/bin/python");
    assert!(
        py.exists(),
        "{} is missing: run `cargo xtask setup` (it makes the venv with rosbags, mcap and pillow)",
        py.display()
    );
    py
}

/// Runs a script of host/tests/rosbag; its stdout, which must be JSON.
fn script(name: &str, args: &[&str]) -> Value {
    let out = Command::new(python())
        .arg(root().join("host/tests/rosbag").join(name))
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "{name} {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{name}: {e}: {}", String::from_utf8_lossy(&out.stdout)))
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn dataset(dir: &Path, count: &str) -> PathBuf {
    let ds = dir.join("ds");
    common::msr_ok(&["dataset", "--robot", "red", "--count", count, "--seed", "3", "--reach-pairs", "0", "--out", s(&ds)]);
    ds
}

fn index(ds: &Path) -> DatasetIndex {
    serde_json::from_slice(&std::fs::read(ds.join("dataset.json")).unwrap()).unwrap()
}

fn import(bag: &Path, ds: &Path, out: &Path, extra: &[&str]) -> (bool, Value, String) {
    let tpl = ds.join("template.png");
    let mut args = vec!["import-bag", s(bag), "--template", s(&tpl), "--out", s(out)];
    // The topics `write_bag.py` writes, unless `extra` names others.
    for (flag, topic) in [("--image-topic", "/camera/image_raw"), ("--joints-topic", "/joint_states")] {
        if !extra.contains(&flag) {
            args.extend([flag, topic]);
        }
    }
    args.extend(extra);
    let (ok, stdout, stderr) = common::msr(&args);
    (ok, serde_json::from_str(&stdout).unwrap_or(Value::Null), stderr)
}

#[test]
fn import_bag_reads_every_encoding_of_both_storages() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path(), "6");
    let src = index(&ds);
    let rgb: Vec<image::RgbImage> = src.frames.iter().map(|f| image::open(ds.join(&f.file)).unwrap().to_rgb8()).collect();
    for storage in ["mcap", "sqlite3"] {
        for enc in ["mono8", "rgb8", "bgr8", "yuv422", "yuyv", "jpeg", "png"] {
            let bag = tmp.path().join(format!("bag_{storage}_{enc}"));
            script("write_bag.py", &[s(&ds), s(&bag), "--storage", storage, "--encoding", enc]);
            let out = tmp.path().join(format!("out_{storage}_{enc}"));
            let (ok, r, err) = import(&bag, &ds, &out, &["--test-fraction", "0.5"]);
            assert!(ok, "{storage} {enc}: {err}");
            assert_eq!(r["frames"], 6, "{storage} {enc}: {r}");
            assert_eq!(r["joint_states"].as_u64().unwrap(), 28, "{storage} {enc}: {r}");
            let got = index(&out);
            assert_eq!(got.robot, "recorded");
            assert_eq!(got.frames.iter().filter(|f| f.split == msr_sim::layout::Split::Test).count(), 3);
            let mut worst_jpeg = 0f64;
            for (k, (f, g)) in src.frames.iter().zip(&got.frames).enumerate() {
                // The head's pose at an image's stamp is the frame's own (the head holds there).
                assert!((f.head_yaw - g.head_yaw).abs() < 1e-12 && (f.head_pitch - g.head_pitch).abs() < 1e-12, "{storage} {enc} frame {k}");
                let img = image::open(out.join(&g.file)).unwrap();
                match enc {
                    "rgb8" | "bgr8" | "png" => assert_eq!(img.to_rgb8(), rgb[k], "{storage} {enc} frame {k}"),
                    "mono8" | "yuv422" | "yuyv" => {
                        assert_eq!(img.color(), image::ColorType::L8);
                        assert_eq!(img.to_luma8(), to_grey(&image::DynamicImage::ImageRgb8(rgb[k].clone())), "{storage} {enc} frame {k}");
                    }
                    _ => {
                        let (a, b) = (to_grey(&img), to_grey(&image::DynamicImage::ImageRgb8(rgb[k].clone())));
                        let mad = a.iter().zip(b.iter()).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum::<f64>() / a.len() as f64;
                        worst_jpeg = worst_jpeg.max(mad);
                    }
                }
            }
            if enc == "jpeg" {
                eprintln!("{storage} jpeg (quality 95): mean absolute grey difference to the frames, worst frame {worst_jpeg:.3}");
                assert!(worst_jpeg < 2.0, "{worst_jpeg}");
            }
        }
    }
}

#[test]
fn import_bag_skips_moving_and_unstated_poses_and_takes_joint_names() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path(), "6");
    // Joints named otherwise: refused until --joint-names names them.
    let bag = tmp.path().join("named");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "mono8", "--names", "neck_yaw,neck_pitch"]);
    let out = tmp.path().join("o1");
    let (ok, _, err) = import(&bag, &ds, &out, &[]);
    assert!(!ok && err.contains("--joint-names") && err.contains("neck_yaw"), "{err}");
    assert!(!out.exists());
    let (ok, r, err) = import(&bag, &ds, &out, &["--joint-names", "neck_yaw,neck_pitch"]);
    assert!(ok && r["frames"] == 6, "{err} {r}");
    // The head moving through every stamp: skipped at 5 deg/s, kept at 1000 deg/s.
    let bag = tmp.path().join("moving");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "sqlite3", "--encoding", "mono8", "--hold-ms", "0"]);
    let (ok, r, err) = import(&bag, &ds, &tmp.path().join("o2"), &["--max-head-speed-deg-s", "1000"]);
    assert!(ok && r["frames"] == 6, "{err} {r}");
    let (ok, _, err) = import(&bag, &ds, &tmp.path().join("o3"), &[]);
    assert!(!ok && err.contains("no image kept of 6: 6 while the head moved"), "{err}");
    // Joint states at 4 Hz: images more than 50 ms from both neighbours are skipped.
    let bag = tmp.path().join("sparse");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "mono8", "--joint-hz", "4"]);
    let (ok, r, err) = import(&bag, &ds, &tmp.path().join("o4"), &["--max-joint-gap-ms", "50", "--max-head-speed-deg-s", "1000"]);
    let skipped = r["skipped_no_joint_state"].as_u64().unwrap_or(0);
    assert!(ok && skipped > 0 && r["frames"].as_u64().unwrap() + skipped == 6, "{err} {r}");
}

/// The error line of a refused import, checking that nothing was written beside `out`.
fn refused(bag: &Path, ds: &Path, out: &Path, extra: &[&str]) -> String {
    let before: Vec<_> = std::fs::read_dir(out.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
    let (ok, _, err) = import(bag, ds, out, extra);
    assert!(!ok, "accepted: {}", bag.display());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(!out.exists(), "{err}");
    let after: Vec<_> = std::fs::read_dir(out.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(before, after, "something was left beside --out");
    err
}

#[test]
fn bad_bags_are_refused_in_one_line_and_nothing_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path(), "4");
    let outs = tmp.path().join("outs");
    std::fs::create_dir(&outs).unwrap();
    let out = outs.join("o");
    let bag = tmp.path().join("rgb16");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "rgb16"]);
    let e = refused(&bag, &ds, &out, &[]);
    assert!(e.contains("\"rgb16\" is not read"), "{e}");
    let good = tmp.path().join("good");
    script("write_bag.py", &[s(&ds), s(&good), "--storage", "mcap", "--encoding", "rgb8"]);
    let e = refused(&good, &ds, &out, &["--image-topic", "/camera/nope"]);
    assert!(e.contains("no topic /camera/nope") && e.contains("/camera/image_raw"), "{e}");
    let e = refused(&good, &ds, &out, &["--joints-topic", "/camera/image_raw"]);
    assert!(e.contains("not a sensor_msgs/msg/JointState"), "{e}");
    // Cut files: the MCAP at 60 % of its length, the SQLite3 database likewise.
    let mcap = good.join("good.mcap");
    let bytes = std::fs::read(&mcap).unwrap();
    std::fs::write(&mcap, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let e = refused(&good, &ds, &out, &[]);
    assert!(e.contains("truncated"), "{e}");
    let db = tmp.path().join("db");
    script("write_bag.py", &[s(&ds), s(&db), "--storage", "sqlite3", "--encoding", "rgb8"]);
    let f = db.join("db.db3");
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let e = refused(&db, &ds, &out, &[]);
    assert!(e.contains("db.db3"), "{e}");
    let e = refused(&tmp.path().join("nothing"), &ds, &out, &[]);
    assert!(e.contains("does not exist"), "{e}");
}

fn model(dir: &Path) -> PathBuf {
    let m = dir.join("model.msrm");
    std::fs::write(&m, models::trained_model(Robot::Red)).unwrap();
    m
}

#[test]
fn mirror_test_mcap_reads_whole_with_one_image_and_annotation_per_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    let (mcap, trials) = (tmp.path().join("run.mcap"), tmp.path().join("trials.json"));
    common::msr_ok(&["mirror-test", "--model", s(&m), "--trials", "2", "--parallel", "1", "--mcap", s(&mcap), "--trials-out", s(&trials)]);
    let trials: Vec<Value> = serde_json::from_slice(&std::fs::read(&trials).unwrap()).unwrap();
    let sent: u64 = trials.iter().map(|t| t["frames_sent"].as_u64().unwrap()).sum();
    let r = script("read_mcap.py", &[s(&mcap)]);
    let count = |t: &str| r["topics"][t]["count"].as_u64().unwrap_or(0);
    assert_eq!(count("/camera/image"), sent, "{}", r["topics"]);
    assert_eq!(count("/camera/annotations"), sent);
    assert_eq!(count("/face/image"), sent);
    assert_eq!(count("/face/predicted"), sent);
    assert_eq!(count("/face/saliency"), sent);
    assert_eq!(count("/msr/trial"), 2);
    assert!(count("/board/status") >= 2);
    assert!(count("/joint_states") > 100 && count("/joint_states") == count("/joint_commands"));
    assert_eq!(r["topics"]["/camera/annotations"]["type"], "foxglove_msgs/msg/ImageAnnotations");
    assert_eq!(r["mcap"]["profile"], "ros2");
    assert_eq!(r["mcap"]["compression"], serde_json::json!(["zstd"]));
    // Every annotation is stamped with its frame's stamp.
    let stamps: std::collections::BTreeSet<u64> = r["images"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|i| i["topic"] == "/camera/image")
        .map(|i| i["stamp"].as_u64().unwrap())
        .collect();
    for a in r["annotations"].as_array().unwrap() {
        let st = a["stamps"].as_array().unwrap();
        assert!(st.len() == 1 && stamps.contains(&st[0].as_u64().unwrap()), "{a}");
    }
    let j = r["joints"].as_array().unwrap().iter().find(|j| j["topic"] == "/joint_states").unwrap();
    assert!(j["name"].as_array().unwrap().iter().any(|n| n == "HeadYaw"), "{j}");
    for i in r["images"].as_array().unwrap() {
        assert_eq!(i["encoding"], "mono8");
        assert_eq!(i["bytes"], i["width"].as_u64().unwrap() * i["height"].as_u64().unwrap());
    }
}

#[test]
fn run_mcap_holds_the_frames_and_the_boards_answers() {
    use msr_host::episode::sim_board::SimBoard;
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    let frames = tmp.path().join("frames");
    std::fs::create_dir(&frames).unwrap();
    let sim: Vec<(String, GrayImage)> = msr_host::cmd::run::sim_frames(Robot::Red, 6, 2);
    for (i, (_, g)) in sim.iter().enumerate() {
        g.save(frames.join(format!("{i:03}.png"))).unwrap();
    }
    let mcap = tmp.path().join("run.mcap");
    let board = SimBoard::start(Some(std::fs::read(&m).unwrap())).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["run", "--port", board.path(), "--model", s(&m), "--frames", s(&frames), "--json", "--fps", "10"])
        .args(["--mcap", s(&mcap)])
        .output()
        .unwrap();
    drop(board);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let heads: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter_map(|v| v.get("Detection").map(|d| d["head"].clone()))
        .collect();
    let dump = tmp.path().join("dump");
    let r = script("read_mcap.py", &[s(&mcap), "--dump", s(&dump)]);
    assert_eq!(r["topics"]["/camera/image"]["count"], 6, "{}", r["topics"]);
    assert_eq!(r["topics"]["/camera/annotations"]["count"], 6);
    for (i, (_, g)) in sim.iter().enumerate() {
        let raw = std::fs::read(dump.join(format!("camera_{i:04}.raw"))).unwrap();
        assert!(raw == g.as_raw().as_slice(), "frame {i}: the MCAP's image bytes differ from the frame");
    }
    let board_head: Vec<&Value> = r["joints"].as_array().unwrap().iter().filter(|j| j["topic"] == "/board/head").collect();
    assert_eq!(board_head.len(), heads.len());
    for (j, h) in board_head.iter().zip(&heads) {
        assert_eq!(j["name"], serde_json::json!(["HeadYaw", "HeadPitch"]));
        for k in 0..2 {
            assert_eq!(j["position"][k].as_f64().unwrap(), h[k].as_f64().unwrap() as f32 as f64);
        }
    }
    assert!(r["status"].as_array().unwrap().iter().any(|st| st["values"].get("frames").is_some()), "{}", r["status"]);
}

/// The frames of an import with their poses, by file.
fn poses(out: &Path) -> Vec<(f64, f64)> {
    index(out).frames.iter().map(|f| (f.head_yaw, f.head_pitch)).collect()
}

/// A dataset of 6 frames in `tmp`, and its poses.
fn six(tmp: &Path) -> (PathBuf, Vec<(f64, f64)>) {
    let ds = dataset(tmp, "6");
    let src = index(&ds).frames.iter().map(|f| (f.head_yaw, f.head_pitch)).collect();
    (ds, src)
}

#[test]
fn cut_jpegs_are_counted_damaged_never_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let (ds, src) = six(tmp.path());
    // JPEGs cut to 85 % and to a third: damaged, counted so, never a frame with grey rows or
    // "without a face".
    let bag = tmp.path().join("cut");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "jpeg", "--cut", "2:0.85", "--cut", "4:0.33"]);
    let (ok, r, err) = import(&bag, &ds, &tmp.path().join("o_cut"), &[]);
    assert!(ok, "{err}");
    assert_eq!((r["frames"].as_u64(), r["skipped_damaged"].as_u64(), r["skipped_no_face"].as_u64()), (Some(4), Some(2), Some(0)), "{r}");
    assert!(err.contains("2 damaged (the first: image 2 on /camera/image_raw"), "{err}");
    let kept: Vec<(f64, f64)> = [0, 1, 3, 5].iter().map(|&k| src[k]).collect();
    assert_eq!(poses(&tmp.path().join("o_cut")), kept);
}

#[test]
fn no_pose_is_interpolated_across_joint_states_that_are_not_numbers() {
    let tmp = tempfile::tempdir().unwrap();
    let (ds, src) = six(tmp.path());
    // Head angles NaN from 60 to 140 ms: the image at 100 ms would get a pose interpolated from
    // 40 and 160 ms, across them. It is skipped as such, not blamed on the head's speed.
    let bag = tmp.path().join("nan");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "mono8", "--nan-ms", "60:140"]);
    let (ok, r, err) = import(&bag, &ds, &tmp.path().join("o_nan"), &[]);
    assert!(ok, "{err}");
    assert_eq!(
        (r["frames"].as_u64(), r["skipped_invalid_joint_state"].as_u64(), r["skipped_moving"].as_u64()),
        (Some(5), Some(1), Some(0)),
        "{r}"
    );
    let kept: Vec<(f64, f64)> = [0, 2, 3, 4, 5].iter().map(|&k| src[k]).collect();
    for (g, w) in poses(&tmp.path().join("o_nan")).iter().zip(&kept) {
        assert!((g.0 - w.0).abs() < 1e-12 && (g.1 - w.1).abs() < 1e-12, "{g:?} against {w:?}");
    }
}

#[test]
fn a_joint_state_with_fewer_positions_than_names_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let (ds, _) = six(tmp.path());
    // A JointState with fewer positions than names: said so, naming the message.
    let outs = tmp.path().join("outs");
    std::fs::create_dir(&outs).unwrap();
    let bag = tmp.path().join("short");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "sqlite3", "--encoding", "mono8", "--short-positions", "5"]);
    let e = refused(&bag, &ds, &outs.join("o"), &[]);
    assert!(e.contains("joint state 6 on /joint_states") && e.contains("has 4 names and 3 positions"), "{e}");
}

#[test]
fn a_file_the_metadata_does_not_list_is_not_merged() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path(), "4");
    let bag = tmp.path().join("bag");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "mono8"]);
    let other = tmp.path().join("other");
    script("write_bag.py", &[s(&ds), s(&other), "--storage", "mcap", "--encoding", "mono8"]);
    // Another recording's file moved in: not merged (it would double every frame).
    std::fs::copy(other.join("other.mcap"), bag.join("zz_other.mcap")).unwrap();
    let (ok, r, err) = import(&bag, &ds, &tmp.path().join("o1"), &[]);
    assert!(ok, "{err}");
    assert_eq!((r["images"].as_u64(), r["frames"].as_u64()), (Some(4), Some(4)), "{r}");
    assert!(err.contains("not read: ") && err.contains("zz_other.mcap"), "{err}");
}

#[test]
fn garbage_metadata_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path(), "4");
    let outs = tmp.path().join("outs");
    std::fs::create_dir(&outs).unwrap();
    let bag = tmp.path().join("bag");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "mono8"]);
    // Garbage metadata, metadata that lists nothing, a listed file that is missing: refused.
    let meta = bag.join("metadata.yaml");
    let good = std::fs::read_to_string(&meta).unwrap();
    std::fs::write(&meta, b"\x00\x01garbage: [\n\xff").unwrap();
    let e = refused(&bag, &ds, &outs.join("o"), &[]);
    assert!(e.contains("is not rosbag2 metadata"), "{e}");
    std::fs::write(&meta, "hello: world\nrelative_file_paths: [bag.mcap]\n").unwrap();
    let e = refused(&bag, &ds, &outs.join("o"), &[]);
    assert!(e.contains("is not rosbag2 metadata (no rosbag2_bagfile_information"), "{e}");
    std::fs::write(&meta, good.replace("relative_file_paths:\n  - bag.mcap", "relative_file_paths: []")).unwrap();
    let e = refused(&bag, &ds, &outs.join("o"), &[]);
    assert!(e.contains("lists no storage files"), "{e}");
    std::fs::write(&meta, good.replace("- bag.mcap", "- gone.mcap")).unwrap();
    let e = refused(&bag, &ds, &outs.join("o"), &[]);
    assert!(e.contains("lists gone.mcap, which is missing"), "{e}");
}

#[test]
fn an_import_removes_the_temporary_folders_of_killed_imports() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path(), "4");
    let bag = tmp.path().join("bag");
    script("write_bag.py", &[s(&ds), s(&bag), "--storage", "mcap", "--encoding", "mono8"]);
    // What an import killed mid-way leaves: its hidden folder, named by its (dead) process.
    let mut dead = Command::new("true").spawn().unwrap();
    let dead_pid = dead.id();
    dead.wait().unwrap();
    let outs = tmp.path().join("outs");
    let stale = outs.join(format!(".o.tmp{dead_pid}"));
    std::fs::create_dir_all(stale.join("frames")).unwrap();
    std::fs::write(stale.join("frames/000000.png"), b"half").unwrap();
    // One of a running import (this test's process stands for it): left alone.
    let running = outs.join(format!(".o.tmp{}", std::process::id()));
    std::fs::create_dir_all(&running).unwrap();
    let (ok, r, err) = import(&bag, &ds, &outs.join("o"), &[]);
    assert!(ok && r["frames"] == 4, "{err}");
    assert!(!stale.exists(), "{} is left behind", stale.display());
    assert!(running.exists(), "a running import's folder was removed");
}

#[test]
fn an_mcap_output_in_a_new_folder_is_written_there() {
    // Was: every trial ran, then "cannot write nodir/x.mcap". Every other output's folder is
    // made (fsio); the MCAP's now is too.
    let tmp = tempfile::tempdir().unwrap();
    let m = model(tmp.path());
    let mcap = tmp.path().join("nodir/deeper/x.mcap");
    common::msr_ok(&["mirror-test", "--model", s(&m), "--trials", "1", "--parallel", "1", "--mcap", s(&mcap)]);
    let r = script("read_mcap.py", &[s(&mcap)]);
    assert!(r["topics"]["/camera/image"]["count"].as_u64().unwrap() > 0, "{}", r["topics"]);
}
