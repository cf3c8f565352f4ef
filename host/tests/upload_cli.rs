//! Uploads and status requests against boards that answer with something else, or not at all:
//! a watchdog's error queued during an upload is not the upload's answer, a port where no board
//! answers fails in one line after one try, and a client killed mid-frame does not spoil the
//! next client's first request.
mod common;

use msr_host::episode::sim_board::SimBoard;
use msr_shared::host_port::HostPort;
use msr_shared::msg::HostToBoard;
use serde_json::Value;
use std::path::Path;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Two blobs of the published model (its own threshold, and 5 sigma), written to `dir`; `None`
/// (said on stderr) without the published data.
fn two_models(dir: &Path) -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    let real = common::real_dir()?;
    let manifest = real.join("manifest.json");
    let (pa, pb) = (dir.join("a.msrm"), dir.join("b.msrm"));
    common::msr_ok(&["import", s(&manifest), "--out", s(&pa)]);
    common::msr_ok(&["import", s(&manifest), "--out", s(&pb), "--threshold", "5"]);
    assert_ne!(crc_of(&pa), crc_of(&pb));
    Some((pa, pb))
}

fn crc_of(p: &Path) -> u64 {
    msr_shared::blob::Model::parse(&std::fs::read(p).unwrap()).unwrap().crc32 as u64
}

fn status_json(port: &str) -> Value {
    let out = common::msr_ok(&["status", "--port", port, "--json"]);
    serde_json::from_str(&out).unwrap()
}

#[test]
fn a_watchdog_error_during_an_upload_is_not_its_answer() {
    // Frames, then an upload with none: the face watchdog trips (no whole frame for 500 ms)
    // while the second model's bytes cross the line, and its FaceTimeout error arrives before
    // the board's ModelAccepted.
    let tmp = tempfile::tempdir().unwrap();
    let Some((a, b)) = two_models(tmp.path()) else { return };
    let board = SimBoard::start(None).unwrap();
    let port = board.path().to_string();
    common::msr_ok(&["run", "--port", &port, "--model", s(&a), "--upload", "--sim", "red", "--count", "3"]);
    let (_, out, err) = common::msr(&["run", "--port", &port, "--model", s(&b), "--upload", "--sim", "red", "--count", "1"]);
    let st = status_json(&port);
    assert!(
        st["status"]["face_watchdog_trips"].as_u64().unwrap() > 0,
        "the watchdog never tripped, so nothing was tried: {st}"
    );
    // The run's exit says how its frames went (a board still returning its arm from the first
    // run's reach answers none); the upload's answer is the line on stdout.
    assert!(!err.contains("refused"), "{err}\n{out}");
    assert!(out.contains(&format!("model accepted, crc {:08x}", crc_of(&b))), "{out}");
    assert_eq!(st["status"]["model_crc"].as_u64(), Some(crc_of(&b)), "{st}");
}

#[test]
fn an_upload_to_a_port_where_nothing_answers_fails_after_one_try_in_one_line() {
    // A PTY nobody plays the board on (its other end is read, so that writes go through).
    let tmp = tempfile::tempdir().unwrap();
    let Some((a, _)) = two_models(tmp.path()) else { return };
    let mut pty = msr_sim::pty::Pty::open().unwrap();
    let port = pty.path().to_string();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop2 = stop.clone();
    let drain = std::thread::spawn(move || {
        while !stop2.load(std::sync::atomic::Ordering::SeqCst) {
            let _ = pty.read_available();
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
    });
    let (code, _, err) = common::msr_code(&["run", "--port", &port, "--model", s(&a), "--upload", "--sim", "red", "--count", "1", "--timeout-ms", "500"]);
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    drain.join().unwrap();
    assert_eq!(code, 1, "{err}");
    // The upload's time on stderr, then the one error line; never "8 tries" of the blob.
    let last: Vec<&str> = err.lines().filter(|l| l.starts_with("msr: error")).collect();
    assert_eq!(last.len(), 1, "{err}");
    assert!(last[0].contains("no answer from the board to the model upload's begin nor to a status request"), "{err}");
    // And `msr status` on it says there is no board, not that its firmware is old.
    let (ok, _, err) = {
        let mut pty = msr_sim::pty::Pty::open().unwrap();
        let port = pty.path().to_string();
        let r = common::msr(&["status", "--port", &port, "--timeout-ms", "300"]);
        let _ = pty.read_available();
        r
    };
    assert!(!ok);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("no answer from the board") && !err.contains("predate"), "{err}");
}

#[test]
fn a_client_killed_mid_frame_does_not_spoil_the_next_request() {
    let tmp = tempfile::tempdir().unwrap();
    let Some((a, _)) = two_models(tmp.path()) else { return };
    let board = SimBoard::start(Some(std::fs::read(&a).unwrap())).unwrap();
    let port = board.path().to_string();
    // What a client killed while writing leaves: the first half of a frame, no delimiter.
    let frame = HostPort::default().encode(&HostToBoard::GetStatus);
    {
        let mut p = serialport::new(&port, 921_600).open().unwrap();
        p.write_all(&frame[..frame.len() / 2]).unwrap();
        p.flush().unwrap();
    }
    let st = status_json(&port);
    assert_eq!(st["store"]["model_crc"].as_u64(), Some(crc_of(&a)), "{st}");
}

use std::io::Write;

#[test]
fn a_reader_that_stops_early_ends_msr_quietly() {
    // Was: `msr status | head -1` ended in a panic trace ("failed printing to stdout").
    let tmp = tempfile::tempdir().unwrap();
    let Some((a, _)) = two_models(tmp.path()) else { return };
    let board = SimBoard::start(Some(std::fs::read(&a).unwrap())).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["status", "--port", board.path()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before reading anything.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked") && err.trim().is_empty(), "{err}");
}
