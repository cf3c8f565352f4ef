//! The host talking to a simulated board through a pseudo-terminal with `serialport`, exactly as
//! it opens a real board: `msr run --port PATH`.
mod common;

use msr_host::cmd::run as run_board;
use msr_host::session::Session;
use msr_host::episode::sim_board::SimBoard;
use msr_shared::msg::{BoardToHost, Mode};
use msr_sim::link::FaultConfig;
use msr_sim::Robot;
use std::time::Duration;

const T: Duration = Duration::from_secs(3);

#[test]
fn frames_from_the_sim_over_a_pty_come_back_as_detections_and_a_reach() {
    let blob = common::trained_model(Robot::Red);
    let board = SimBoard::start(Some(blob.clone())).unwrap();
    let model = msr_shared::blob::Model::parse(&blob).unwrap();
    let cropper = msr_host::detect::cropper_of(&model).unwrap();
    let mut s = Session::open(board.path(), 921_600).unwrap();
    // Three frames without a mark, then five with one.
    let frames = run_board::sim_frames(Robot::Red, 8, 4);
    let mut dets = Vec::new();
    for (name, frame) in &frames {
        let face = cropper.crop(frame).unwrap();
        let msgs = s.send_face(&face, Duration::from_millis(150)).unwrap();
        let d = msgs.iter().find_map(|m| {
            if let BoardToHost::Detection(d) = m {
                Some(*d)
            } else {
                None
            }
        });
        eprintln!(
            "{name}: {:?}",
            msgs.iter().map(run_board::describe).collect::<Vec<_>>()
        );
        if let Some(d) = d {
            dets.push(d);
        }
    }
    // Detection pauses once the arm goes up, so answers stop at the confirming frame.
    assert!(dets.len() >= 6, "{dets:?}");
    assert!(
        dets[..3].iter().all(|d| d.blob.is_none()),
        "no mark yet: {dets:?}"
    );
    assert!(
        dets.iter().any(|d| d.confirmed && d.reach.is_some()),
        "a reach: {dets:?}"
    );
    let st = s.status(T).unwrap();
    assert_eq!(st.model_crc, model.crc32);
    assert!(matches!(st.mode, Mode::Reach | Mode::Hold), "{st:?}");
    assert_eq!(st.host_link.crc_errors, 0);
    drop(s);
    let served = board.stop().unwrap();
    assert_eq!(served.limit_violations, 0);
    assert!(served.to_board_bytes > 8 * 4350);
}

#[test]
fn msr_run_streams_a_frame_folder_and_uploads_over_the_pty() {
    // A board without a model: `msr run --upload` gives it one, then streams a folder of frames.
    let blob = common::trained_model(Robot::Red);
    let dir = std::env::temp_dir().join(format!("msr-pty-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let model_path = dir.join("model.msrm");
    std::fs::write(&model_path, &blob).unwrap();
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for (i, (_, f)) in run_board::sim_frames(Robot::Red, 4, 9).iter().enumerate() {
        f.save(frames.join(format!("{i:03}.png"))).unwrap();
    }
    let board = SimBoard::start(None).unwrap();
    let args = msr_host::cmd::run::Args {
        line: msr_host::cmd::BoardLine { port: board.path().to_string(), baud: 921_600 },
        model: model_path.clone(),
        upload: true,
        frames: Some(frames.clone()),
        camera: None,
        hold: Default::default(),
        sim: None,
        count: 0,
        seed: 0,
        fps: 10.0,
        timeout_ms: 3000,
        frame_timeout_ms: 5000,
        json: true,
        mcap: None,
        light: msr_host::cmd::light::RunLight::Fixed,
        imperfect: Default::default(),
        live: Default::default(),
    };
    msr_host::cmd::run::run(args).unwrap();
    let served = board.stop().unwrap();
    let model = msr_shared::blob::Model::parse(&blob).unwrap();
    assert_eq!(
        served.status.model_crc, model.crc32,
        "the upload went through the PTY"
    );
    assert_eq!(served.status.frames, 4);
    assert_eq!(served.status.host_link.crc_errors, 0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_upload_over_the_pty_is_refused() {
    let blob = common::trained_model(Robot::Red);
    let board = SimBoard::start(Some(blob.clone())).unwrap();
    let mut s = Session::open(board.path(), 921_600).unwrap();
    let garbage: Vec<u8> = (0..2000u32).map(|i| (i * 31) as u8).collect();
    let err = s.upload(&garbage, T).unwrap_err().to_string();
    assert!(err.contains("refused"), "{err}");
    let st = s.status(T).unwrap();
    assert_eq!(
        st.model_crc,
        msr_shared::blob::Model::parse(&blob).unwrap().crc32,
        "old model kept"
    );
    drop(s);
    board.stop().unwrap();
}

#[test]
fn an_upload_over_a_noisy_pty_resumes_until_it_is_through() {
    // Bit errors and two dead spells on the host link while a 300 KB model goes up: after each
    // loss the upload resumes from where the board stands, and the board runs exactly that blob.
    let blob = msr_host::bench::synthetic(msr_host::models::ArchKind::Conv).unwrap().blob;
    let faults = FaultConfig {
        bit_error_rate: 2e-6,
        disconnects: vec![(700_000, 60_000), (1_500_000, 60_000)],
        ..FaultConfig::default()
    };
    let board = SimBoard::start_with(None, faults, 3).unwrap();
    let mut s = Session::open(board.path(), 921_600).unwrap();
    let want = msr_shared::blob::Model::parse(&blob).unwrap().crc32;
    assert_eq!(s.upload(&blob, T).unwrap(), want);
    assert!(s.upload_resent > 0, "no loss made the upload resume");
    drop(s);
    let served = board.stop().unwrap();
    assert_eq!(served.status.model_crc, want);
    assert!(served.status.host_link.resyncs() > 0, "the board saw no damaged frame");
}

#[test]
fn a_missing_port_is_a_clear_error() {
    let e = Session::open("/dev/msr-no-such-port", 921_600)
        .err()
        .expect("no such port")
        .to_string();
    assert!(e.contains("/dev/msr-no-such-port"), "{e}");
}
