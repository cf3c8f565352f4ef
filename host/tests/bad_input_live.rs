//! Bad input on the live paths (`msr run` against an emulated board),
//! the files around the outputs, and figures that were silently wrong. Each test names the case
//! it was found with and checks its class.
mod common;

use common::{msr, msr_code, real_dir};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// Fails with exit `code`, one line on stderr that says `want`, no panic.
fn fails_with_code(args: &[&str], code: i32, want: &str) -> String {
    let (got, out, err) = msr_code(args);
    assert_eq!(got, code, "{args:?}: exit {got}: {err} {out}");
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    assert_eq!(err.trim().lines().count(), 1, "{args:?}: not one line: {err}");
    assert!(err.starts_with("msr: error: "), "{args:?}: {err}");
    assert!(err.contains(want), "{args:?}: expected `{want}` in: {err}");
    err
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn grey_png(path: &Path, w: u32, h: u32) {
    image::GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 7 + y * 3) % 251) as u8])).save(path).unwrap();
}

/// The published model imported into a blob in `dir`, or `None` without the real data.
fn published_blob(dir: &Path) -> Option<PathBuf> {
    let real = real_dir()?;
    let blob = dir.join("p.msrm");
    let (ok, _, err) = msr(&["import", s(&real.join("manifest.json")), "--out", s(&blob)]);
    assert!(ok, "{err}");
    Some(blob)
}

#[test]
fn flag_values_that_do_not_parse_exit_2() {
    // Was: --box a,b,c,d and --box 1,2,3 exited 1, --box -1,0,10,10 exited 2.
    let tmp = tempfile::tempdir().unwrap();
    let frame = tmp.path().join("f.png");
    grey_png(&frame, 320, 240);
    let out = tmp.path().join("t.png");
    for (b, want) in [
        ("a,b,c,d", "x0,y0,x1,y1"),
        ("1,2,3", "four numbers"),
        ("-1,0,10,10", "x0,y0,x1,y1"),
        ("5,5,1,1", "x1 must not be left of x0"),
        ("", "x0,y0,x1,y1"),
    ] {
        fails_with_code(&["template", "--frame", s(&frame), "--box", b, "--out", s(&out)], 2, want);
    }
    // Range errors of every command are usage errors too.
    fails_with_code(&["run", "--port", "/nonexistent", "--model", "m", "--sim", "red", "--fps", "0"], 2, "--fps");
    fails_with_code(&["record", "--port", "/nonexistent", "--count", "1", "--out", s(&tmp.path().join("r")), "--frames", "x"], 2, "--frames takes `-`");
    fails_with_code(&["detect", "--model", "m", "--image", "i", "--head-yaw", "3", "--head-pitch", "0"], 2, "HeadYaw");
    // A box in range for its syntax but past the frame is about the file: exit 1.
    fails_with_code(&["template", "--frame", s(&frame), "--box", "0,0,400,10", "--out", s(&out)], 1, "leaves the 320x240 frame");
    assert!(!out.exists());
}

#[test]
fn a_bus_log_is_not_touched_by_a_run_that_fails_and_links_are_not_followed() {
    // Was: msr servos --bus-log L truncated L before opening the port, and followed a link.
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("bus.log");
    std::fs::write(&log, b"yesterday's log").unwrap();
    let model = tmp.path().join("model.msrm");
    std::fs::write(&model, b"a model").unwrap();
    let link = tmp.path().join("link.log");
    std::os::unix::fs::symlink(&model, &link).unwrap();
    for l in [&log, &link] {
        let (code, _, err) = msr_code(&["servos", "--port", "/nonexistent/tty", "--bus-log", s(l)]);
        assert_eq!(code, 1, "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    assert_eq!(std::fs::read(&log).unwrap(), b"yesterday's log");
    assert_eq!(std::fs::read(&model).unwrap(), b"a model");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
    // Written when bytes come: through a new file renamed over the name (the link itself).
    let mut w = msr_host::fsio::LazyLog::new(&link).unwrap();
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "nothing before the first byte");
    w.write_all(b"bytes").unwrap();
    drop(w);
    assert_eq!(std::fs::read(&link).unwrap(), b"bytes");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_file());
    assert_eq!(std::fs::read(&model).unwrap(), b"a model");
}

#[test]
fn special_files_are_refused_as_outputs_and_never_replaced() {
    // Was: the rename replaced /dev/full or a FIFO with a regular file.
    let tmp = tempfile::tempdir().unwrap();
    let fifo = tmp.path().join("fifo");
    let ok = Command::new("mkfifo").arg(&fifo).status().unwrap().success();
    assert!(ok, "mkfifo");
    let model = tmp.path().join("m.msrm");
    std::fs::write(&model, b"x").unwrap();
    let link_to_null = tmp.path().join("null.json");
    std::os::unix::fs::symlink("/dev/null", &link_to_null).unwrap();
    // Through the binary only paths whose loss would be the test's own (a regression run as
    // root would replace /dev/full itself).
    for p in [fifo.as_path(), link_to_null.as_path()] {
        fails_with_code(&["mirror-test", "--model", s(&model), "--trials-out", s(p)], 1, "special file");
        fails_with_code(&["servos", "--port", "/nonexistent", "--bus-log", s(p)], 1, "special file");
    }
    use std::os::unix::fs::FileTypeExt;
    assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
    assert!(std::fs::symlink_metadata(&link_to_null).unwrap().file_type().is_symlink());
    // The devices themselves: refused by the check every output passes, nothing written.
    for dev in ["/dev/full", "/dev/null"] {
        let e = msr_host::fsio::refuse_special(Path::new(dev)).unwrap_err().to_string();
        assert!(e.contains("special file"), "{e}");
        assert!(std::fs::metadata(dev).unwrap().file_type().is_char_device());
    }
    // The library's writer refuses them too (an output that no check saw).
    let e = msr_host::fsio::write(&fifo, b"x").unwrap_err().to_string();
    assert!(e.contains("special file"), "{e}");
}

#[test]
fn an_error_names_the_users_path_never_the_temporary_file() {
    // Was: `--png out/pic` said `."tmp27784" was not recognized`.
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("pic");
    let img = image::GrayImage::new(4, 4);
    let e = msr_host::fsio::write_with(&p, |t| Ok(img.save(t)?)).unwrap_err();
    let m = msr_host::cmd::one_line(&e);
    assert!(m.contains(s(&p)) && !m.contains(&format!("tmp{}", std::process::id())), "{m}");
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0, "a temporary file left");
    fails_with_code(
        &["detect", "--model", "m", "--image", "i", "--head-yaw", "0", "--head-pitch", "0", "--png", s(&p)],
        2,
        "must end in .png",
    );
}

#[test]
fn banners_come_after_the_checks() {
    // Was: "recording N frames ..." and "N frames of 320x240 to ..." before the error.
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("a-file");
    std::fs::write(&file, b"x").unwrap();
    fails_with_code(&["dataset", "--count", "2", "--out", s(&file)], 1, "is a file, not a folder");
    fails_with_code(&["dataset", "--count", "2", "--out", s(&file.join("sub"))], 1, "not a folder");
    fails_with_code(&["record", "--port", "/nonexistent", "--sim", "red", "--count", "2", "--out", s(&file)], 1, "is a file, not a folder");
    let out = tmp.path().join("rec");
    std::fs::create_dir_all(out.join("frames")).unwrap();
    std::fs::write(out.join("recording.csv"), "frame,frames/000000.png,NaN,0\n").unwrap();
    fails_with_code(&["record", "--port", "/nonexistent", "--sim", "red", "--count", "2", "--resume", "--out", s(&out)], 1, "not finite");
    // A port that does not open: also one line, and the recording left as it was.
    fails_with_code(&["record", "--port", "/nonexistent", "--sim", "red", "--count", "2", "--force", "--out", s(&out)], 1, "/nonexistent");
    assert!(out.join("recording.csv").is_file(), "--force removed the old recording before the port opened");
}

#[test]
fn record_resume_reads_back_only_what_a_recording_writes() {
    // Was: NaN, inf, 1e308 and 3.0 rad angles, paths outside the folder, missing or twice-listed
    // frames all went into dataset.json.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rec");
    std::fs::create_dir_all(out.join("frames")).unwrap();
    for i in 0..3 {
        grey_png(&out.join(format!("frames/{i:06}.png")), 320, 240);
    }
    grey_png(&tmp.path().join("outside.png"), 320, 240);
    let good = |i: usize| format!("frame,frames/{i:06}.png,0.01,-0.02\n");
    let cases: Vec<(String, &str)> = vec![
        (format!("{}frame,frames/000001.png,NaN,0\n", good(0)), "not finite"),
        (format!("{}frame,frames/000001.png,inf,0\n", good(0)), "not finite"),
        (format!("{}frame,frames/000001.png,1e308,0\n", good(0)), "not finite"),
        (format!("{}frame,frames/000001.png,3.0,0\n", good(0)), "outside [-2.08567, 2.08567]"),
        (format!("{}frame,frames/000001.png,0,-1.5\n", good(0)), "HeadPitch"),
        (format!("{}frame,../outside.png,0,0\n", good(0)), "outside the folder"),
        (format!("{}frame,/etc/passwd,0,0\n", good(0)), "outside the folder"),
        (format!("{}{}", good(0), good(2)), "a frame missing"),
        (format!("{}{}", good(0), good(0)), "twice"),
        (format!("{}skip,no-face,0,0\n{}{}", good(0), good(1), good(1)), "twice"),
        (format!("{}{}{}", good(0), good(1), good(2)), "more than --count 2"),
    ];
    for (log, want) in &cases {
        std::fs::write(out.join("recording.csv"), log).unwrap();
        fails_with_code(&["record", "--port", "/nonexistent", "--sim", "red", "--count", "2", "--resume", "--out", s(&out)], 1, want);
        assert_eq!(&std::fs::read_to_string(out.join("recording.csv")).unwrap(), log, "the log changed");
        assert!(!out.join("dataset.json").exists());
    }
    // A listed frame whose PNG is gone.
    std::fs::remove_file(out.join("frames/000001.png")).unwrap();
    std::fs::write(out.join("recording.csv"), format!("{}{}", good(0), good(1))).unwrap();
    fails_with_code(&["record", "--port", "/nonexistent", "--sim", "red", "--count", "2", "--resume", "--out", s(&out)], 1, "is missing");
    // A good log gets as far as the port.
    std::fs::write(out.join("recording.csv"), good(0)).unwrap();
    fails_with_code(&["record", "--port", "/nonexistent", "--sim", "red", "--count", "2", "--resume", "--out", s(&out)], 1, "/nonexistent");
}

/// A sim dataset of `n` frames in `dir`, its index edited by `f`.
fn dataset(dir: &Path, n: usize, f: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let (ok, _, err) = msr(&["dataset", "--count", &n.to_string(), "--reach-pairs", "0", "--seed", "2", "--out", s(dir)]);
    assert!(ok, "{err}");
    let ix = dir.join("dataset.json");
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&ix).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&ix, serde_json::to_vec(&v).unwrap()).unwrap();
    dir.to_path_buf()
}

#[test]
fn datasets_are_read_back_as_they_are_written() {
    // Was: msr eval counted a frame listed twice twice; msr train took angles outside the Nao's
    // joint range and robot names that --robot refuses, and printed "test MSE NaN" without test
    // frames.
    use msr_host::data::{crop::CropMode, Dataset};
    let tmp = tempfile::tempdir().unwrap();
    let load = |d: &Path| Dataset::load(d, CropMode::Pixel).map(|_| ()).map_err(|e| msr_host::cmd::one_line(&e));
    let d = dataset(&tmp.path().join("twice"), 6, |v| {
        let f = v["frames"][0].clone();
        v["frames"].as_array_mut().unwrap().push(f);
    });
    assert!(load(&d).unwrap_err().contains("listed twice"));
    let d = dataset(&tmp.path().join("angle"), 6, |v| v["frames"][2]["head_yaw"] = 3.0.into());
    assert!(load(&d).unwrap_err().contains("outside [-2.08567, 2.08567]"));
    let d = dataset(&tmp.path().join("pitch"), 6, |v| v["frames"][1]["head_pitch"] = 1e300.into());
    assert!(load(&d).unwrap_err().contains("HeadPitch"));
    let d = dataset(&tmp.path().join("robot"), 6, |v| v["robot"] = "blue".into());
    assert!(load(&d).unwrap_err().contains("robot \"blue\""));
    let d = dataset(&tmp.path().join("escape"), 6, |v| v["frames"][0]["file"] = "../twice/frames/000000.png".into());
    assert!(load(&d).unwrap_err().contains("outside the dataset folder"));
    let d = dataset(&tmp.path().join("ok"), 6, |_| {});
    load(&d).unwrap();
    // The commands say it in one line.
    fails_with_code(&["train", "--data", s(&tmp.path().join("twice")), "--out", s(&tmp.path().join("o")), "--epochs", "1", "--quiet"], 1, "listed twice");
    fails_with_code(&["train", "--data", s(&tmp.path().join("robot")), "--out", s(&tmp.path().join("o")), "--epochs", "1", "--quiet"], 1, "robot \"blue\"");
    let no_test = dataset(&tmp.path().join("notest"), 6, |v| {
        for f in v["frames"].as_array_mut().unwrap() {
            f["split"] = "train".into();
            f["mark"] = serde_json::Value::Null;
        }
    });
    fails_with_code(
        &["train", "--data", s(&no_test), "--out", s(&tmp.path().join("o")), "--epochs", "1", "--quiet", "--pose-bins", "0"],
        1,
        "no test frames",
    );
    assert!(!tmp.path().join("o").join("decoder.json").exists());
    if let Some(blob) = published_blob(tmp.path()) {
        fails_with_code(&["eval", "--model", s(&blob), "--data", s(&tmp.path().join("twice"))], 1, "listed twice");
    }
}

#[test]
fn eval_refuses_a_manifest_the_blob_was_not_imported_from() {
    // Was: scored an unrelated model (hit 0.143, false alarms 1.000) without a word.
    let tmp = tempfile::tempdir().unwrap();
    let Some(blob) = published_blob(tmp.path()) else { return };
    let real = real_dir().unwrap();
    let other = tmp.path().join("other.msrm");
    std::fs::write(&other, msr_host::bench::synthetic_with(msr_host::models::ArchKind::Mlp, false).unwrap().blob).unwrap();
    let m = real.join("manifest.json");
    fails_with_code(&["eval", "--model", s(&other), "--data", s(&real), "--manifest", s(&m)], 1, "was not imported from --manifest");
    // Its own manifest still goes through.
    let (ok, out, err) = msr(&["eval", "--model", s(&blob), "--data", s(&real), "--manifest", s(&m), "--json"]);
    assert!(ok, "{err}");
    assert!(out.contains("published float decoder"), "{out}");
}

#[test]
fn bench_saves_two_models_of_one_kind_under_two_names() {
    // Was: both written to DIR/conv.msrm, the last one kept.
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a.msrm");
    let b = tmp.path().join("b.msrm");
    let conv = msr_host::bench::synthetic_with(msr_host::models::ArchKind::Conv, false).unwrap().blob;
    let conv8 = msr_host::bench::synthetic_with(msr_host::models::ArchKind::Conv, true).unwrap().blob;
    std::fs::write(&a, &conv).unwrap();
    std::fs::write(&b, &conv8).unwrap();
    let dir = tmp.path().join("saved");
    let (ok, _, err) = msr(&["bench", "--backend", "host", "--reps", "1", "--model", s(&a), "--model", s(&b), "--save-models", s(&dir), "--json"]);
    assert!(ok, "{err}");
    assert_eq!(std::fs::read(dir.join("conv-1.msrm")).unwrap(), conv);
    assert_eq!(std::fs::read(dir.join("conv-2.msrm")).unwrap(), conv8);
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2);
    // A --save-models that is not a folder is said so (was: "creating /dev/null: File exists").
    fails_with_code(&["bench", "--backend", "host", "--reps", "1", "--model", s(&a), "--save-models", s(&a)], 1, "is a file, not a folder");
}

#[test]
fn frames_smaller_than_the_models_are_refused_on_every_path() {
    // Was: msr run scaled a 40x30 PNG or a W40 H30 Y4M stream up and reported a "mark";
    // msr detect refused the same image.
    let tmp = tempfile::tempdir().unwrap();
    let Some(blob) = published_blob(tmp.path()) else { return };
    let small = tmp.path().join("small");
    std::fs::create_dir(&small).unwrap();
    grey_png(&small.join("f.png"), 40, 30);
    fails_with_code(
        &["detect", "--model", s(&blob), "--image", s(&small.join("f.png")), "--head-yaw", "0", "--head-pitch", "0"],
        1,
        "40x30, smaller than the 320x240",
    );
    let board = msr_host::episode::sim_board::SimBoard::start(Some(std::fs::read(&blob).unwrap())).unwrap();
    let base = ["run", "--port", board.path(), "--model", s(&blob), "--baud", "20000000"];
    let mut args = base.to_vec();
    args.extend(["--frames", s(&small)]);
    fails_with_code(&args, 1, "40x30, smaller than the 320x240");
    // The same frame as a Y4M stream on standard input.
    let mut y4m = b"YUV4MPEG2 W40 H30 F10:1 Ip A1:1 Cmono\n".to_vec();
    y4m.extend(b"FRAME\n");
    y4m.extend(vec![128u8; 40 * 30]);
    let mut args = base.to_vec();
    args.extend(["--frames", "-"]);
    let mut child = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(&args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(&y4m).unwrap();
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("40x30, smaller than the 320x240") && err.trim().lines().count() == 1, "{err}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("mark at"));
}
