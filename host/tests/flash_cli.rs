//! `msr serve --flash FILE`: what the emulated board learns, it keeps. An uploaded model is there
//! after the server is killed and started again (`msr status` shows it), and a server killed at
//! any moment of an upload comes back with the old model or the new one, never none (the new
//! one whenever the board had accepted it). The same for the firmware image under QEMU, whose
//! flash file either board reads.
mod common;

use msr_host::session::Session;
use rand::{Rng, SeedableRng};
use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const T: Duration = Duration::from_secs(3);

/// `msr serve --flash flash` as a child process, and the PTY path it printed.
fn serve(flash: &Path) -> (Child, String) {
    serve_on("inproc", flash)
}

/// `msr serve --backend backend --flash flash`, as [`serve`].
fn serve_on(backend: &str, flash: &Path) -> (Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["serve", "--backend", backend, "--flash", flash.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let path = line.trim().to_string();
    assert!(path.starts_with("/dev/"), "msr serve printed {line:?}");
    (child, path)
}

/// `msr status --json` on `port`: the store's part.
fn store(port: &str) -> Value {
    let out = Command::new(env!("CARGO_BIN_EXE_msr"))
        .args(["status", "--port", port, "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "msr status: {}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["store"]["model_crc"], v["status"]["model_crc"], "{v}");
    v["store"].clone()
}

fn crc(blob: &[u8]) -> u64 {
    msr_shared::blob::Model::parse(blob).unwrap().crc32 as u64
}

fn kill(mut c: Child) {
    c.kill().unwrap();
    c.wait().unwrap();
}

#[test]
fn an_upload_survives_a_killed_server_and_a_killed_upload_leaves_the_old_or_the_new_model() {
    let tmp = tempfile::tempdir().unwrap();
    let flash = tmp.path().join("board.flash");
    // Two models: the conv decoder with i16 weights, and with i8 weights.
    let first = msr_host::bench::synthetic_with(msr_host::models::ArchKind::Conv, false).unwrap().blob;
    let second = msr_host::bench::synthetic_with(msr_host::models::ArchKind::Conv, true).unwrap().blob;
    assert_ne!(crc(&first), crc(&second));

    // A new file: no model. Upload the first, kill the server, start it again: still there.
    let (server, port) = serve(&flash);
    assert_eq!(store(&port)["source"], "None");
    let mut s = Session::open(&port, 921_600).unwrap();
    let line = Duration::from_secs_f64(first.len() as f64 * 11.0 / 921_600.0);
    assert_eq!(s.upload(&first, T + line).unwrap() as u64, crc(&first));
    drop(s);
    kill(server);
    let (server, port) = serve(&flash);
    let st = store(&port);
    assert_eq!(st["model_crc"], crc(&first), "{st}");
    assert_eq!(st["source"]["Flash"]["slot"], 0, "{st}");
    kill(server);

    // Five uploads, the server killed at a random moment of each: of the second model, and
    // whenever the second one came through, of the first again (so each upload goes over the
    // slot of the model before).
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(27);
    let line = Duration::from_secs_f64(second.len() as f64 * 11.0 / 921_600.0);
    let mut seen = [0; 2];
    let mut running = crc(&first);
    for i in 0..5 {
        let (server, port) = serve(&flash);
        let next = if running == crc(&first) { &second } else { &first };
        let blob = next.clone();
        let uploader = std::thread::spawn(move || {
            let mut s = Session::open(&port, 921_600).ok()?;
            s.upload(&blob, T + line).ok()
        });
        let at = Duration::from_secs_f64(rng.gen_range(0.2..2.5) * line.as_secs_f64());
        std::thread::sleep(at);
        kill(server);
        let finished = uploader.join().unwrap().is_some();
        let (server, port) = serve(&flash);
        let st = store(&port);
        let got = st["model_crc"].as_u64().unwrap();
        eprintln!(
            "upload {i} of {:08x}: killed after {:.2} s (finished: {finished}): runs {got:08x}",
            crc(next),
            at.as_secs_f64()
        );
        assert!(got == crc(&first) || got == crc(&second), "upload {i}: {st}");
        if finished {
            assert_eq!(got, crc(next), "upload {i}: accepted, then lost: {st}");
        }
        seen[usize::from(got == crc(&second))] += 1;
        running = got;
        kill(server);
    }
    eprintln!("after the five kills: {} times the first model ran, {} times the second", seen[0], seen[1]);
}

#[test]
fn a_flash_file_of_the_wrong_size_is_refused_in_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let flash = tmp.path().join("small.flash");
    std::fs::write(&flash, [0xFFu8; 100]).unwrap();
    let (ok, _, err) = common::msr(&["serve", "--flash", flash.to_str().unwrap(), "--seconds", "1"]);
    assert!(!ok);
    assert!(err.contains("is 100 bytes, an emulated board's flash is"), "{err}");
    assert_eq!(std::fs::read(&flash).unwrap(), [0xFFu8; 100], "the file is left alone");
}

/// The QEMU board's flash is the file too: it reads what the in-process board wrote, keeps an
/// upload across a killed server (SIGKILL to `msr serve`; QEMU dies with it), and a server killed
/// at random moments of five uploads comes back with the old model or the new one. The
/// in-process board then reads what the QEMU board wrote.
#[test]
fn the_qemu_board_keeps_its_flash_in_the_same_file() {
    if !common::qemu_board_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let flash = tmp.path().join("board.flash");
    let first = msr_host::bench::synthetic_with(msr_host::models::ArchKind::Conv, false).unwrap().blob;
    let second = msr_host::bench::synthetic_with(msr_host::models::ArchKind::Conv, true).unwrap().blob;

    // The in-process board writes the first model.
    let (server, port) = serve(&flash);
    let line = |b: &[u8]| Duration::from_secs_f64(b.len() as f64 * 11.0 / 921_600.0);
    let mut s = Session::open(&port, 921_600).unwrap();
    assert_eq!(s.upload(&first, T + line(&first)).unwrap() as u64, crc(&first));
    drop(s);
    kill(server);

    // The QEMU board finds it, takes the second, and keeps it across a kill.
    let (server, port) = serve_on("qemu", &flash);
    let st = store(&port);
    assert_eq!((st["model_crc"].as_u64(), &st["source"]["Flash"]["slot"]), (Some(crc(&first)), &Value::from(0)), "{st}");
    // QEMU's emulated UART carries tens of KB/s against the line's 92: the board is slower
    // than real time, and the upload may take it a minute.
    let slow = Duration::from_secs(120);
    let t0 = std::time::Instant::now();
    let mut s = Session::open(&port, 921_600).unwrap();
    assert_eq!(s.upload(&second, slow).unwrap() as u64, crc(&second));
    let took = t0.elapsed();
    drop(s);
    eprintln!("upload of {} bytes to the QEMU board: {:.1} s", second.len(), took.as_secs_f64());
    kill(server);
    let (server, port) = serve_on("qemu", &flash);
    let st = store(&port);
    assert_eq!((st["model_crc"].as_u64(), &st["source"]["Flash"]["slot"]), (Some(crc(&second)), &Value::from(1)), "{st}");
    kill(server);

    // Five uploads, each killed at a moment of its expected time.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
    let mut running = crc(&second);
    let mut seen = [0; 2];
    for i in 0..5 {
        let (server, port) = serve_on("qemu", &flash);
        let next = if running == crc(&first) { &second } else { &first };
        let blob = next.clone();
        let uploader = std::thread::spawn(move || {
            let mut s = Session::open(&port, 921_600).ok()?;
            s.upload(&blob, slow).ok()
        });
        // Spread over the upload and past its end (so that some kills come after the commit),
        // each moved at random by up to a tenth of the upload.
        let at = took.mul_f64([0.3, 0.6, 0.9, 1.4, 2.0][i] + rng.gen_range(-0.1..0.1));
        std::thread::sleep(at);
        kill(server);
        let finished = uploader.join().unwrap().is_some();
        let (server, port) = serve_on("qemu", &flash);
        let st = store(&port);
        let got = st["model_crc"].as_u64().unwrap();
        eprintln!("QEMU upload {i} of {:08x}: killed after {:.1} s (finished: {finished}): runs {got:08x}", crc(next), at.as_secs_f64());
        assert!(got == crc(&first) || got == crc(&second), "upload {i}: {st}");
        if finished {
            assert_eq!(got, crc(next), "upload {i}: accepted, then lost: {st}");
        }
        seen[usize::from(got == crc(&second))] += 1;
        running = got;
        kill(server);
    }
    eprintln!("after the five kills: {} times the first model ran, {} times the second", seen[0], seen[1]);

    // And the in-process board reads what the QEMU board wrote.
    let (server, port) = serve(&flash);
    assert_eq!(store(&port)["model_crc"].as_u64(), Some(running));
    kill(server);
}

#[test]
fn a_killed_qemu_board_leaves_nothing_in_the_temp_directory() {
    if !common::qemu_board_ready() {
        return;
    }
    // `msr serve` stops on Ctrl-C, which runs no destructor: what QEMU needed in the temp
    // directory (its UART sockets, the preload) must be gone once the board runs.
    let tmp = tempfile::tempdir().unwrap();
    let (server, port) = serve_on("qemu", &tmp.path().join("board.flash"));
    let run_dir = std::env::temp_dir().join(format!("msr-qemu-{}-0", server.id()));
    assert_eq!(store(&port)["source"], "None");
    kill(server);
    assert!(!run_dir.exists(), "{} is left behind", run_dir.display());
}

#[test]
fn a_second_server_on_the_same_flash_file_is_refused_in_one_line() {
    // Two boards on one flash would each take an upload and write over what the other saved.
    let tmp = tempfile::tempdir().unwrap();
    let flash = tmp.path().join("board.flash");
    let (server, port) = serve(&flash);
    let before = std::fs::read(&flash).unwrap();
    for backend in ["inproc", "qemu"] {
        let (ok, _, err) = common::msr(&["serve", "--backend", backend, "--flash", flash.to_str().unwrap(), "--seconds", "1"]);
        assert!(!ok, "{backend}: a second server started");
        assert_eq!(err.trim().lines().count(), 1, "{backend}: {err}");
        assert!(err.contains("is in use by another board"), "{backend}: {err}");
    }
    assert_eq!(std::fs::read(&flash).unwrap(), before, "the refused servers wrote the file");
    assert_eq!(store(&port)["source"], "None");
    kill(server);
    // Once the first is gone (killed: the lock goes with the process), the file is free.
    let (server, port) = serve(&flash);
    assert_eq!(store(&port)["source"], "None");
    kill(server);
}

#[test]
fn a_flash_file_removed_while_serving_stops_the_server_with_an_error() {
    // Was: the board went on, took an upload "into flash slot 0", and saved it nowhere.
    for how in ["removed", "replaced by another file"] {
        let tmp = tempfile::tempdir().unwrap();
        let flash = tmp.path().join("board.flash");
        let mut child = Command::new(env!("CARGO_BIN_EXE_msr"))
            .args(["serve", "--flash", flash.to_str().unwrap()])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        if how == "removed" {
            std::fs::remove_file(&flash).unwrap();
        } else {
            let other = tmp.path().join("other");
            std::fs::write(&other, b"another file").unwrap();
            std::fs::rename(&other, &flash).unwrap();
        }
        // The server stops by itself (waited for as an event: its exit).
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{how}: {err}");
        let last = err.trim_end().lines().last().unwrap_or("");
        assert!(last.starts_with("msr: error:") && last.contains(&format!("was {how}")), "{how}: {err}");
    }
}
