//! The board image under QEMU keeps the robot moving while it writes its flash: emulated servos
//! answer on UART1 while a model goes up on UART0, and the servo targets the board sends carry
//! its clock (`Targets::time_ms`, the image's SysTick: emulated instructions under
//! `-icount shift=0`). The longest gap between two of them during the upload (erases of the
//! slot's sectors in steps, programming, the read-back CRC and the commit) is printed and must
//! stay within two control periods. Then a reset comes back with the uploaded model.

use msr_shared::frame::{encode_message_vec, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::host_port::HostPort;
use msr_shared::joints::{HOME_POSTURE, REACH_JOINTS};
use msr_shared::msg::{BoardToHost, BoardToServo, HostToBoard, JointState, ModelSource, ServoBusKind, ServoToBoard};
use msr_sim::qemu::{self, Lockstep};
use std::io::{ErrorKind, Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Servos that report the home posture every 5 ms (and on request) and log the targets' times.
fn servos(mut link: UnixStream, stop: Arc<AtomicBool>, times: Arc<Mutex<Vec<u32>>>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let mut states = heapless::Vec::new();
        for (j, a) in REACH_JOINTS.iter().zip(HOME_POSTURE) {
            states.push(JointState { joint: *j, position: a, stiffness: true, faults: 0 }).unwrap();
        }
        let mut seq = 0u16;
        let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
        link.set_read_timeout(Some(Duration::from_millis(5))).unwrap();
        let mut buf = [0u8; 4096];
        while !stop.load(Ordering::SeqCst) {
            let msg = ServoToBoard::States { time_ms: 0, states: states.clone() };
            if link.write_all(&encode_message_vec(seq, &msg).unwrap()).is_err() {
                return;
            }
            seq = seq.wrapping_add(1);
            let n = match link.read(&mut buf) {
                Ok(0) => return,
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => 0,
                Err(_) => return,
            };
            for &b in &buf[..n] {
                if let Some(Ok(f)) = acc.push(b) {
                    if let Ok(BoardToServo::Targets { time_ms, .. }) = f.message::<BoardToServo>() {
                        times.lock().unwrap().push(time_ms);
                    }
                }
            }
        }
    })
}

/// The first message from the board that `want` takes; `None` when the board's UART closes
/// first. QEMU runs in `-icount` mode, slower or faster than the wall clock with the machine's
/// load, so there is no time limit: a board that never answers is a hang, which the test runner
/// stops.
fn wait_for(host: &mut UnixStream, port: &mut HostPort, want: impl Fn(&BoardToHost) -> bool) -> Option<BoardToHost> {
    host.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
    let mut buf = [0u8; 1024];
    loop {
        let n = match host.read(&mut buf) {
            Ok(0) => return None,
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => continue,
            Err(e) => panic!("UART0: {e}"),
        };
        if let Some(m) = port.receive(&buf[..n]).into_iter().find(|m| want(m)) {
            return Some(m);
        }
    }
}

#[test]
fn servo_targets_keep_their_period_while_a_model_is_written_to_flash() {
    if !qemu::qemu_available() {
        eprintln!("SKIPPED: {} not found; install qemu-system-arm to run the QEMU tests", qemu::qemu_binary());
        return;
    }
    let image = qemu::find_image(qemu::BOARD_IMAGE).unwrap_or_else(|e| panic!("{e:#}"));
    let blob = msr_host::bench::synthetic(msr_host::models::ArchKind::Conv).unwrap().blob;
    let want = msr_shared::blob::Model::parse(&blob).unwrap().crc32;
    let (mut ls, crc) = Lockstep::start(&image).unwrap();
    assert_eq!(crc, 0, "a fresh board has no model");
    let stop = Arc::new(AtomicBool::new(false));
    let times = Arc::new(Mutex::new(Vec::new()));
    let t = servos(ls.servo_link().try_clone().unwrap(), stop.clone(), times.clone());
    // The image waits for the host to choose its servo bus.
    let mut host = ls.host_link().try_clone().unwrap();
    let mut port = HostPort::default();
    host.write_all(&port.encode(&HostToBoard::UseServoBus(ServoBusKind::Framed))).unwrap();
    // Streaming first.
    while times.lock().unwrap().len() < 20 {
        assert!(!t.is_finished(), "the servo link closed before 20 servo targets");
        std::thread::sleep(Duration::from_millis(10));
    }
    let before = times.lock().unwrap().len();
    // The upload, as `msr run --upload` sends it: begin, wait for the ack (after the erase),
    // the chunks and the commit.
    let crc32 = msr_shared::blob::CRC32.checksum(&blob);
    host.write_all(&port.encode(&HostToBoard::ModelBegin { len: blob.len() as u32, crc32 })).unwrap();
    let ack = wait_for(&mut host, &mut port, |m| matches!(m, BoardToHost::UploadAck { .. }));
    assert_eq!(ack, Some(BoardToHost::UploadAck { next: 0 }));
    let mut bytes = Vec::new();
    for (i, data) in blob.chunks(msr_shared::msg::CHUNK).enumerate() {
        bytes.extend(port.encode(&HostToBoard::ModelChunk { offset: (i * msr_shared::msg::CHUNK) as u32, data }));
    }
    bytes.extend(port.encode(&HostToBoard::ModelCommit));
    let mut w = host.try_clone().unwrap();
    let writer = std::thread::spawn(move || w.write_all(&bytes));
    let verdict = wait_for(&mut host, &mut port, |m| {
        matches!(m, BoardToHost::ModelAccepted { .. } | BoardToHost::Error { .. })
    });
    writer.join().unwrap().unwrap();
    assert_eq!(verdict, Some(BoardToHost::ModelAccepted { crc32: want }));
    std::thread::sleep(Duration::from_millis(100));
    let during: Vec<u32> = times.lock().unwrap()[before.saturating_sub(1)..].to_vec();
    stop.store(true, Ordering::SeqCst);
    t.join().unwrap();
    let gaps: Vec<u32> = during.windows(2).map(|w| w[1].wrapping_sub(w[0])).collect();
    let longest = gaps.iter().copied().max().unwrap_or(u32::MAX);
    let span = during.last().unwrap().wrapping_sub(during[0]);
    println!(
        "upload of {} bytes under QEMU: {} servo periods over {span} ms of board time, longest gap {longest} ms",
        blob.len(),
        gaps.len(),
    );
    // The upload takes some 500 ms of board time (49 periods on CI, 60 here): 20 periods are
    // enough to see a stall of the erase or the programming, which would last longer than that.
    assert!(gaps.len() >= 20, "too few periods to tell: {during:?}");
    assert!(longest <= 20, "servo targets stopped for {longest} ms during the upload");
    // The store: uploaded into a slot, and still there after a reset.
    host.write_all(&port.encode(&HostToBoard::GetStore)).unwrap();
    let r = wait_for(&mut host, &mut port, |m| matches!(m, BoardToHost::Store(_)));
    let Some(BoardToHost::Store(r)) = r else { panic!("no store report: {r:?}") };
    assert_eq!(r.model_crc, want, "{r:?}");
    assert!(matches!(r.source, ModelSource::Flash { slot: 0, .. }), "{r:?}");
    assert_eq!(ls.reset(None).unwrap(), want, "the model after a reset");
    let exit = ls.exit(Duration::from_secs(10)).unwrap();
    exit.success().unwrap();
}
