//! `msr run` loses no answer: every face the board got whole is answered on stdout, also when the
//! answers come faster than one a frame period (several in one read) or after the last frame.
#[path = "../../tests/tests/common/mod.rs"]
mod common;

use msr_host::episode::sim_board::SimBoard;
use msr_sim::Robot;
use serde_json::Value;
use std::process::Command;

#[test]
fn every_face_that_got_through_is_answered_on_stdout_at_a_high_frame_rate() {
    let tmp = tempfile::tempdir().unwrap();
    let model = tmp.path().join("model.msrm");
    std::fs::write(&model, common::trained_model(Robot::Red)).unwrap();
    let board = SimBoard::start(Some(std::fs::read(&model).unwrap())).unwrap();
    // 300 frames a second over a (pseudo-terminal) line of 20 Mbaud: answers pile up.
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["run", "--port", board.path(), "--model", model.to_str().unwrap()])
        .args(["--sim", "red", "--count", "12", "--fps", "300", "--baud", "20000000", "--json"])
        .output()
        .unwrap();
    drop(board);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let lines: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    let dets = lines.iter().filter(|v| v.get("Detection").is_some()).count();
    let status = lines.iter().find_map(|v| v.get("Status")).expect("the board's status line");
    let whole = status["frames"].as_u64().unwrap() as usize;
    assert!(whole >= 1, "{status}");
    // The board answers every whole face (with the reach in progress while the arm is up);
    // the host's link may count a face as superseded whose ack came after the next one began.
    assert_eq!(dets, whole, "one answer a face the board got whole: {status}");
}
