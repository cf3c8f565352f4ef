use super::*;
use crate::world::{run, Flow, World, WorldConfig};
use msr_shared::frame::{encode_message_vec, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::msg::{BoardToHost, HostToBoard};
use std::time::Duration;

fn open_host(path: &str) -> Box<dyn serialport::SerialPort> {
    serialport::new(path, 921_600).timeout(Duration::from_millis(50)).open().expect("open the PTY as a serial port")
}

/// Reads until `n` bytes came; a wait that never ends is a hang, which the test runner stops.
fn read_until(port: &mut dyn serialport::SerialPort, n: usize) -> Vec<u8> {
    let mut got = Vec::new();
    let mut buf = [0u8; 512];
    while got.len() < n {
        match port.read(&mut buf) {
            Ok(k) => got.extend_from_slice(&buf[..k]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("{e}"),
        }
    }
    got
}

#[test]
fn every_byte_value_passes_both_ways_unchanged() {
    let mut pty = Pty::open().unwrap();
    let mut host = open_host(pty.path());
    let all: Vec<u8> = (0..=255u8).chain((0..=255u8).rev()).collect();
    host.write_all(&all).unwrap();
    host.flush().unwrap();
    let mut got = Vec::new();
    while got.len() < all.len() {
        got.extend(pty.read_available().unwrap());
    }
    assert_eq!(got, all);
    pty.write_all(&all).unwrap();
    assert_eq!(read_until(host.as_mut(), all.len()), all);
}

#[test]
fn host_code_talks_to_a_simulated_board_through_the_pty() {
    let pty = Pty::open().unwrap();
    let path = pty.path().to_string();
    let mut bridge = PtyBridge::new(pty);
    // The host: sends a ping as it would to a board, waits for the pong.
    let host = std::thread::spawn(move || {
        let mut port = open_host(&path);
        port.write_all(&encode_message_vec(3, &HostToBoard::Ping { nonce: 77 }).unwrap()).unwrap();
        // Byte by byte until the first whole message.
        let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
        loop {
            for b in read_until(port.as_mut(), 1) {
                if let Some(Ok(f)) = acc.push(b) {
                    return f.message::<BoardToHost>().ok();
                }
            }
        }
    });
    // The board: answers pings on the simulated host link.
    let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    let mut fw = move |_: u64, h: &mut LinkEnd, _: &mut LinkEnd| {
        for b in h.receive() {
            if let Some(Ok(f)) = acc.push(b) {
                if let Ok(HostToBoard::Ping { nonce }) = f.message() {
                    h.send(&encode_message_vec(0, &BoardToHost::Pong { nonce }).unwrap());
                }
            }
        }
    };
    let cfg = WorldConfig { pace: Some(1.0), ..WorldConfig::default() };
    let mut done_at = None;
    let (_, report) = run(
        &cfg,
        &mut fw,
        |w: &mut World| {
            bridge.pump(&mut w.host).unwrap();
            if bridge.to_pty > 0 && done_at.is_none() {
                done_at = Some(w.now_us);
            }
            match done_at {
                Some(t) if w.now_us > t + 300_000 => Flow::Stop,
                _ => Flow::Continue,
            }
        },
        4_000_000,
    )
    .unwrap();
    assert_eq!(host.join().unwrap(), Some(BoardToHost::Pong { nonce: 77 }));
    // Paced at real time: simulated time did not run ahead of the wall clock.
    assert!(report.speedup <= 1.01, "{report:?}");
}
