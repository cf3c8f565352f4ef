//! The camera path with a real tool: sim frames encoded into a video by ffmpeg (lossless FFV1,
//! grey), played back as a Y4M stream into `msr run --frames -` against a simulated board on a
//! PTY; the board's detections equal those of the same frames streamed from a folder.
//!
//! Needs `ffmpeg` (`cargo xtask test` installs it); without it these tests fail and say so.
#[path = "../../tests/tests/common/mod.rs"]
mod common;

use msr_host::episode::sim_board::SimBoard;
use msr_sim::Robot;
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output, Stdio};

fn ffmpeg(args: &[&str]) -> Output {
    let out = Command::new("ffmpeg")
        .args(["-hide_banner", "-v", "error", "-y"])
        .args(args)
        .output()
        .unwrap_or_else(|e| {
            panic!("ffmpeg is not installed ({e}): `cargo xtask test` installs it (Debian: apt-get install ffmpeg)")
        });
    assert!(out.status.success(), "ffmpeg {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn p(x: &Path) -> &str {
    x.to_str().unwrap()
}

/// `msr run --json` against a fresh simulated board, with `stdin` as its standard input.
fn msr_run(model: &Path, frames: &str, stdin: Stdio) -> (Output, Vec<Value>) {
    let board = SimBoard::start(Some(std::fs::read(model).unwrap())).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["run", "--port", board.path(), "--model", p(model), "--frames", frames])
        .args(["--json", "--fps", "10", "--frame-timeout-ms", "20000"])
        .stdin(stdin)
        .output()
        .unwrap();
    drop(board);
    let dets = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter_map(|v| v.get("Detection").cloned())
        // Each session numbers its frames from its own start: compare the rest.
        .map(|mut d| {
            d.as_object_mut().map(|o| o.remove("frame"));
            d
        })
        .collect();
    (out, dets)
}

struct Fixture {
    _tmp: tempfile::TempDir,
    model: std::path::PathBuf,
    frames: std::path::PathBuf,
    video: std::path::PathBuf,
}

/// 8 grey sim frames (3 unmarked, then a mark), a PNG folder and an FFV1 video of them.
fn fixture() -> Fixture {
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("model.msrm");
    std::fs::write(&model, common::trained_model(Robot::Red)).unwrap();
    let frames = tmp.path().join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for (i, (_, f)) in msr_host::cmd::run::sim_frames(Robot::Red, 8, 4).iter().enumerate() {
        f.save(frames.join(format!("{i:03}.png"))).unwrap();
    }
    let video = tmp.path().join("frames.mkv");
    let pattern = frames.join("%03d.png");
    ffmpeg(&["-framerate", "10", "-i", p(&pattern), "-c:v", "ffv1", "-pix_fmt", "gray", p(&video)]);
    Fixture { _tmp: tmp, model, frames, video }
}

#[test]
fn a_video_played_into_msr_run_gives_the_detections_of_the_frame_folder() {
    let f = fixture();
    let (out, from_folder) = msr_run(&f.model, p(&f.frames), Stdio::null());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut player = Command::new("ffmpeg")
        .args(["-hide_banner", "-v", "error", "-i", p(&f.video), "-f", "yuv4mpegpipe", "-pix_fmt", "gray", "-"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("ffmpeg is not installed: `cargo xtask test` installs it (Debian: apt-get install ffmpeg)");
    let stream = player.stdout.take().expect("piped");
    let (out, from_video) = msr_run(&f.model, "-", Stdio::from(stream));
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // The player wrote the whole video: a stream that stopped early would also end `msr run`.
    assert!(player.wait().expect("ffmpeg ran").success(), "ffmpeg failed to play the video");
    eprintln!("{from_video:?}");
    // The board pauses detection once the arm goes up: at least the unmarked frames and the
    // confirming ones are answered, a mark is found and a reach starts.
    assert!(from_folder.len() >= 6, "{from_folder:?}");
    assert!(from_folder[..3].iter().all(|d| d["blob"].is_null()), "{from_folder:?}");
    assert!(from_folder.iter().any(|d| !d["blob"].is_null()), "{from_folder:?}");
    assert_eq!(from_video, from_folder, "the same frames, the same detections");
}

#[test]
fn a_cut_stream_and_a_wrong_colour_space_are_one_line_errors() {
    let f = fixture();
    let y4m = f.frames.join("stream.y4m");
    ffmpeg(&["-i", p(&f.video), "-f", "yuv4mpegpipe", "-pix_fmt", "gray", p(&y4m)]);
    let bytes = std::fs::read(&y4m).unwrap();
    // Two frames and a half: two frames are sent, then the cut is reported.
    let header = bytes.iter().position(|&b| b == b'\n').unwrap() + 1;
    let frame = 6 + 320 * 240;
    let cut = f.frames.join("cut.y4m");
    std::fs::write(&cut, &bytes[..header + 2 * frame + frame / 2]).unwrap();
    let (out, dets) = msr_run(&f.model, "-", Stdio::from(std::fs::File::open(&cut).unwrap()));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("ended in the middle of frame 2"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert_eq!(dets.len(), 2, "the whole frames went through");

    let deep = f.frames.join("deep.y4m");
    ffmpeg(&["-i", p(&f.video), "-f", "yuv4mpegpipe", "-strict", "-1", "-pix_fmt", "yuv420p10le", p(&deep)]);
    let (out, dets) = msr_run(&f.model, "-", Stdio::from(std::fs::File::open(&deep).unwrap()));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("10-bit") && err.contains("-pix_fmt gray"), "{err}");
    assert!(dets.is_empty());
}
