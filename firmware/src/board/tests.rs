//! The board driven through its two byte streams, as the sim and QEMU drive it.

use super::*;
use crate::model::{RamStore, UploadError};
use crate::testkit::mlp_spec;
use msr_shared::blob::{Model, CRC32};
use msr_shared::frame::{encode_message, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::joints::{HOME_POSTURE, REACH_JOINTS};
use msr_shared::msg::{
    BoardToServo, ChunkSet, Config, FrameAck, FrameHeader, FrameState, JointState, RoomCommand,
    ServoBusKind, CHUNK,
};
use proptest::prelude::*;
use std::collections::VecDeque;

#[derive(Default)]
struct Pipe {
    rx: VecDeque<u8>,
    tx: Vec<u8>,
}

impl embedded_io::ErrorType for Pipe {
    type Error = core::convert::Infallible;
}
impl Read for Pipe {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.rx.len());
        for b in buf.iter_mut().take(n) {
            *b = self.rx.pop_front().unwrap();
        }
        Ok(n)
    }
}
impl ReadReady for Pipe {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.rx.is_empty())
    }
}
impl Write for Pipe {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.tx.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

const STORE: usize = 32 * 1024;
const FACE: (u16, u16) = (20, 24);

/// A board, a host and a servo bus whose servos follow targets at once.
struct Rig<S: ModelStore = RamStore<STORE>> {
    board: Box<Board<S>>,
    host: Pipe,
    servo: Pipe,
    now: u64,
    seq: u16,
    host_acc: FrameAccumulator<MAX_WIRE_FRAME>,
    servo_acc: FrameAccumulator<MAX_WIRE_FRAME>,
    replies: Vec<BoardToHost>,
    /// (time, targets) as sent.
    targets: Vec<(u64, [f32; 5])>,
    stiffness: bool,
    servos_on: bool,
    /// The servos take no targets (a jammed joint).
    jammed: bool,
    /// Where each servo holds against its target (a pitch servo sagging under its load).
    sag: [f32; 5],
    position: [f32; 5],
}

impl Rig {
    fn new(builtin: Option<&'static [u8]>) -> Rig {
        Rig::with_store(RamStore::new(builtin))
    }
}

impl<S: ModelStore> Rig<S> {
    fn with_store(store: S) -> Rig<S> {
        Rig {
            board: Box::new(Board::new(store)),
            host: Pipe::default(),
            servo: Pipe::default(),
            now: 1_000_000,
            seq: 0,
            host_acc: FrameAccumulator::new(),
            servo_acc: FrameAccumulator::new(),
            replies: Vec::new(),
            targets: Vec::new(),
            stiffness: false,
            servos_on: true,
            jammed: false,
            sag: [0.0; 5],
            position: [0.1, -0.1, 1.0, 0.2, -0.5],
        }
    }

    fn wire<T: serde::Serialize>(&mut self, msg: &T) -> Vec<u8> {
        let mut w = [0u8; MAX_WIRE_FRAME];
        self.seq = self.seq.wrapping_add(1);
        let n = encode_message(self.seq, msg, &mut w).unwrap();
        w[..n].to_vec()
    }

    fn host_send(&mut self, msg: &HostToBoard) {
        let w = self.wire(msg);
        self.host.rx.extend(w);
    }

    fn states(&mut self) {
        let mut states = heapless::Vec::new();
        for (j, p) in REACH_JOINTS.iter().zip(self.position) {
            states
                .push(JointState {
                    joint: *j,
                    position: p,
                    stiffness: self.stiffness,
                    faults: 0,
                })
                .unwrap();
        }
        let w = self.wire(&ServoToBoard::States {
            time_ms: (self.now / 1000) as u32,
            states,
        });
        self.servo.rx.extend(w);
    }

    /// Runs `ms` milliseconds in 1 ms polls; servos report every 10 ms.
    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.now += 1000;
            if self.servos_on && (self.now / 1000).is_multiple_of(10) {
                self.states();
            }
            self.board.poll(self.now, &mut self.host, &mut self.servo);
            for b in std::mem::take(&mut self.host.tx) {
                if let Some(Ok(f)) = self.host_acc.push(b) {
                    self.replies.push(f.message::<BoardToHost>().unwrap());
                }
            }
            for b in std::mem::take(&mut self.servo.tx) {
                if let Some(Ok(f)) = self.servo_acc.push(b) {
                    match f.message::<BoardToServo>().unwrap() {
                        BoardToServo::Targets { targets, .. } => {
                            let mut t = [0f32; 5];
                            for (i, jt) in targets.iter().enumerate() {
                                assert_eq!(jt.joint, REACH_JOINTS[i]);
                                t[i] = jt.position;
                            }
                            assert_eq!(targets.len(), 5);
                            self.targets.push((self.now, t));
                            if self.stiffness && !self.jammed {
                                self.position = core::array::from_fn(|i| t[i] + self.sag[i]);
                            }
                        }
                        BoardToServo::Stiffness { on } => self.stiffness = on,
                        BoardToServo::StateRequest => {}
                    }
                }
            }
        }
    }

    fn upload(&mut self, blob: &[u8], announced_crc: u32) {
        self.host_send(&HostToBoard::ModelBegin {
            len: blob.len() as u32,
            crc32: announced_crc,
        });
        for (i, c) in blob.chunks(CHUNK).enumerate() {
            self.host_send(&HostToBoard::ModelChunk {
                offset: (i * CHUNK) as u32,
                data: c,
            });
            self.run(1);
        }
        self.host_send(&HostToBoard::ModelCommit);
        self.run(1);
    }

    fn frame(&mut self, id: u16, pixels: &[u8]) {
        let h = header(id, pixels);
        self.host_send(&HostToBoard::FrameStart(h));
        for (i, c) in pixels.chunks(CHUNK).enumerate() {
            self.host_send(&HostToBoard::FrameChunk {
                frame: id,
                offset: (i * CHUNK) as u16,
                data: c,
            });
        }
    }

    fn errors(&self) -> Vec<(ErrorCode, u32)> {
        self.replies
            .iter()
            .filter_map(|r| match r {
                BoardToHost::Error { code, detail } => Some((*code, *detail)),
                _ => None,
            })
            .collect()
    }

    fn detections(&self) -> Vec<Detection> {
        self.replies
            .iter()
            .filter_map(|r| match r {
                BoardToHost::Detection(d) => Some(*d),
                _ => None,
            })
            .collect()
    }

    /// Every target sent was inside the limits, and consecutive ones within the velocity limit
    /// at `speed` (restarts after a servo outage excepted: they start from the measured posture).
    fn check_targets(&self, speed: f32) {
        for (_, t) in &self.targets {
            for (j, a) in REACH_JOINTS.iter().zip(t) {
                assert!(j.validate(*a).is_ok(), "{j} {a}");
            }
        }
        for w in self.targets.windows(2) {
            let ((t0, a), (t1, b)) = (w[0], w[1]);
            if t1 - t0 > 10_000 {
                continue;
            }
            for i in 0..5 {
                let lim = REACH_JOINTS[i].limits().unwrap().max_velocity * speed * 0.01 * 1.0001;
                assert!(
                    (b[i] - a[i]).abs() <= lim,
                    "joint {i} at {t1}: {} -> {}",
                    a[i],
                    b[i]
                );
            }
        }
    }
}

/// The header of a face frame in chunks of [`CHUNK`].
fn header(id: u16, pixels: &[u8]) -> FrameHeader {
    msr_shared::deliver::face_header(id, [140, 95], [FACE.1, FACE.0], CHUNK as u16, pixels)
}

fn blob() -> &'static [u8] {
    static BLOB: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BLOB.get_or_init(|| mlp_spec(3, FACE.0, FACE.1).to_bytes().unwrap())
}

/// The face the model predicts at `head`, grey bytes, optionally with a 4 x 4 mark.
fn face(head: [f32; 2], mark: bool) -> Vec<u8> {
    let m = Model::parse(blob()).unwrap();
    let mut d = Box::new(crate::decoder::Decoder::new());
    let mut f: Vec<u8> = d
        .predict(&m, head)
        .unwrap()
        .iter()
        .map(|&p| ((p as u32 + 128) >> 8) as u8)
        .collect();
    if mark {
        for y in 5..9 {
            for x in 10..14 {
                let i = y * FACE.1 as usize + x;
                f[i] = if f[i] > 128 { 10 } else { 245 };
            }
        }
    }
    f
}

/// As [`blob`], with the default test (pooled error, one-sided): the one that learns the room.
fn pooled_blob() -> &'static [u8] {
    static BLOB: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BLOB.get_or_init(|| {
        let mut s = mlp_spec(3, FACE.0, FACE.1);
        s.novelty.pool = 2;
        s.novelty.sided = msr_shared::blob::Sided::One;
        s.to_bytes().unwrap()
    })
}

fn head_answers(rig: &Rig) -> Vec<BoardToHost> {
    rig.replies
        .iter()
        .filter(|r| {
            matches!(
                r,
                BoardToHost::HeadAt { .. }
                    | BoardToHost::Error { code: ErrorCode::HeadRefused | ErrorCode::HeadNotSettled, .. }
            )
        })
        .cloned()
        .collect()
}

#[test]
fn a_head_pose_is_answered_with_the_settled_angles_or_refused() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(3000); // home
    let arm = rig.position[2..].to_vec();
    rig.host_send(&HostToBoard::MoveHead { yaw: 0.08, pitch: -0.05 });
    let t0 = rig.now;
    let mut answered = None;
    for _ in 0..500 {
        rig.run(1);
        if !head_answers(&rig).is_empty() {
            answered = Some(rig.now - t0);
            break;
        }
    }
    // 0.08 rad of HeadYaw at 0.1 * 8.26797 rad/s: 97 ms, then 3 settled periods.
    let t = answered.expect("an answer");
    assert!((100_000..=150_000).contains(&t), "{t} us");
    assert_eq!(head_answers(&rig), vec![BoardToHost::HeadAt { head: [0.08, -0.05] }]);
    assert_eq!(rig.position[2..], arm[..], "the arm stayed");
    rig.check_targets(0.1);
    assert_eq!(rig.board.status().face_watchdog_trips, 0, "babbling sends no frames");
    // Refused: outside the limits (HeadPitch max 0.514872), not finite.
    rig.replies.clear();
    rig.host_send(&HostToBoard::MoveHead { yaw: 0.0, pitch: 0.6 });
    rig.host_send(&HostToBoard::MoveHead { yaw: f32::NAN, pitch: 0.0 });
    rig.run(50);
    let refused = BoardToHost::Error { code: ErrorCode::HeadRefused, detail: 0 };
    assert_eq!(head_answers(&rig), vec![refused.clone(), refused]);
    assert_eq!(rig.position[..2], [0.08, -0.05], "the head did not move");
    // A jammed head: no answer but a timeout after the move's time and a second.
    rig.replies.clear();
    rig.jammed = true;
    rig.host_send(&HostToBoard::MoveHead { yaw: -0.08, pitch: 0.0 });
    rig.run(1500);
    match head_answers(&rig)[..] {
        [BoardToHost::Error { code: ErrorCode::HeadNotSettled, detail }] => {
            assert!((1190..=1220).contains(&detail), "{detail} ms")
        }
        ref other => panic!("{other:?}"),
    }
    // No servos: refused at once.
    rig.replies.clear();
    rig.jammed = false;
    rig.servos_on = false;
    rig.run(300);
    rig.host_send(&HostToBoard::MoveHead { yaw: 0.0, pitch: 0.0 });
    rig.run(20);
    assert!(
        head_answers(&rig).contains(&BoardToHost::Error { code: ErrorCode::HeadRefused, detail: 1 }),
        "{:?}",
        rig.replies
    );
    rig.check_targets(0.1);
}

#[test]
fn streams_from_the_measured_posture_to_home_before_any_model() {
    let mut rig = Rig::new(None);
    rig.run(50);
    assert_eq!(rig.board.status().mode, Mode::NoModel);
    assert!(rig.stiffness);
    // The first target is one velocity-limited step from where the arm was.
    let first = rig.targets[0].1;
    for (i, (a, b)) in first.iter().zip([0.1, -0.1, 1.0, 0.2, -0.5]).enumerate() {
        let step = REACH_JOINTS[i].limits().unwrap().max_velocity * 0.1 * 0.01;
        assert!(
            (a - b).abs() <= step * 1.0001 && (a - b).abs() > 0.0,
            "joint {i}: {a} from {b}"
        );
    }
    rig.run(3000);
    assert_eq!(rig.targets.last().unwrap().1, HOME_POSTURE);
    rig.check_targets(0.1);
    // Frames without a model are refused.
    rig.frame(1, &face([0.0, 0.0], false));
    rig.run(5);
    assert!(rig.errors().contains(&(ErrorCode::NoModel, 0)));
}

#[test]
fn detects_confirms_reaches_holds_and_returns() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(3000); // settle at home
    assert_eq!(rig.board.status().mode, Mode::Observe);
    let home = [HOME_POSTURE[0], HOME_POSTURE[1]];
    // Clean frames: no detection, no reach.
    for i in 0..5 {
        rig.frame(i, &face(home, false));
        rig.run(40);
    }
    let d = rig.detections();
    assert_eq!(d.len(), 5);
    assert!(d.iter().all(|d| d.blob.is_none() && !d.confirmed));
    assert_eq!(d[0].head, home);
    // Marked frames: confirmed on the third (3 of 5).
    for i in 5..8 {
        rig.frame(i, &face(home, true));
        rig.run(40);
    }
    let d = rig.detections();
    assert_eq!(d.len(), 8);
    let b = d[7].blob.unwrap();
    assert_eq!((b.area, b.box_xyxy), (16, [150, 100, 153, 103]));
    assert_eq!(b.centroid, [151.5, 101.5]);
    assert!(!d[5].confirmed && !d[6].confirmed && d[7].confirmed);
    let target = d[7].reach.unwrap();
    assert_eq!(rig.board.phase(), Phase::Reach);
    // While the arm is up, frames are not processed.
    for i in 8..12 {
        rig.frame(i, &face(home, true));
        rig.run(100);
    }
    let again = rig.detections();
    assert!(
        again.len() > 8 && again[8..].iter().all(|x| *x == d[7]),
        "only the reach is reported again, unchanged: {again:?}"
    );
    // Keep frames coming (the face watchdog) until the cycle ends.
    let mut t = 0;
    while rig.board.phase() != Phase::Observe {
        rig.frame(100 + t, &face(home, false));
        rig.run(100);
        t += 1;
        assert!(t < 200, "stuck in {:?}", rig.board.phase());
    }
    assert!(
        rig.targets.iter().any(|(_, p)| *p == target),
        "reached the target"
    );
    let held = rig.targets.iter().filter(|(_, p)| *p == target).count();
    assert!((500..=502).contains(&held), "held {held} periods");
    assert_eq!(rig.targets.last().unwrap().1, HOME_POSTURE);
    assert_eq!(rig.board.status().reaches, 1);
    assert_eq!(rig.board.status().servo_link.crc_errors, 0);
    rig.check_targets(0.1);
}

#[test]
fn bad_uploads_keep_the_running_model() {
    let mut rig = Rig::new(None);
    rig.run(20);
    let good = blob();
    rig.upload(good, CRC32.checksum(good));
    let crc = Model::parse(good).unwrap().crc32;
    assert!(rig
        .replies
        .contains(&BoardToHost::ModelAccepted { crc32: crc }));
    assert_eq!(rig.board.status().model_crc, crc);

    // Corrupted in transit: the announced CRC does not match.
    let other = mlp_spec(4, FACE.0, FACE.1).to_bytes().unwrap();
    let mut bad = other.clone();
    bad[100] ^= 0x40;
    rig.upload(&bad, CRC32.checksum(&other));
    assert!(rig
        .errors()
        .contains(&(ErrorCode::BadUpload, UploadError::Crc.detail())));
    // Intact transfer of an invalid blob (bad magic): refused with the blob error code.
    let mut invalid = other.clone();
    invalid[0] = b'X';
    rig.upload(&invalid, CRC32.checksum(&invalid));
    assert!(rig.errors().contains(&(
        ErrorCode::BadModel,
        msr_shared::blob::BlobError::BadMagic.code()
    )));
    // Truncated upload: commit before all bytes.
    rig.host_send(&HostToBoard::ModelBegin {
        len: other.len() as u32,
        crc32: CRC32.checksum(&other),
    });
    rig.host_send(&HostToBoard::ModelChunk {
        offset: 0,
        data: &other[..CHUNK],
    });
    rig.host_send(&HostToBoard::ModelChunk {
        offset: 2 * CHUNK as u32,
        data: &other[..CHUNK],
    });
    rig.host_send(&HostToBoard::ModelCommit);
    rig.run(2);
    // The chunk after the gap and the early commit both ask for the missing chunk.
    let next = BoardToHost::UploadAck { next: CHUNK as u32 };
    assert_eq!(rig.replies.iter().filter(|r| **r == next).count(), 2);
    // Too large, and a commit with nothing begun.
    rig.host_send(&HostToBoard::ModelBegin {
        len: STORE as u32 + 1,
        crc32: 0,
    });
    rig.host_send(&HostToBoard::ModelCommit);
    rig.run(5);
    let errs = rig.errors();
    assert!(errs.contains(&(ErrorCode::BadUpload, UploadError::Sequence.detail())));
    assert!(errs.contains(&(ErrorCode::BadUpload, UploadError::TooLarge.detail())));
    assert_eq!(
        rig.board.status().model_crc,
        crc,
        "the old model still runs"
    );
    rig.frame(1, &face([0.0, 0.0], true));
    rig.run(30);
    assert!(rig.detections().last().unwrap().blob.is_some());
    // And a good upload after all that is accepted.
    rig.upload(&other, CRC32.checksum(&other));
    let crc2 = Model::parse(&other).unwrap().crc32;
    assert_eq!(rig.board.status().model_crc, crc2);
}

fn acks(rig: &Rig) -> Vec<FrameAck> {
    rig.replies
        .iter()
        .filter_map(|r| match r {
            BoardToHost::FrameAck(a) => Some(*a),
            _ => None,
        })
        .collect()
}

#[test]
fn lost_chunks_are_asked_for_and_the_frame_completes() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(100);
    let px = face([HOME_POSTURE[0], HOME_POSTURE[1]], true);
    // 480 pixels in chunks of 24: 20 chunks; 3, 7 and the last one are lost.
    let h = msr_shared::deliver::face_header(5, [140, 95], [FACE.1, FACE.0], 24, &px);
    assert_eq!(h.chunks(), 20);
    rig.host_send(&HostToBoard::FrameStart(h));
    for i in (0..19).filter(|i| ![3, 7].contains(i)) {
        let r = h.chunk_range(i);
        rig.host_send(&HostToBoard::FrameChunk { frame: 5, offset: r.start as u16, data: &px[r] });
    }
    rig.run(5);
    assert!(acks(&rig).is_empty(), "no ack before the last chunk or a poll");
    rig.host_send(&HostToBoard::FramePoll { header: h, round: 0 });
    rig.run(2);
    let mut missing = ChunkSet::EMPTY;
    for i in [3, 7, 19] {
        missing.insert(i);
    }
    assert_eq!(acks(&rig), vec![FrameAck { frame: 5, round: 0, state: FrameState::Missing(missing) }]);
    // Duplicates of stored chunks change nothing; a chunk with a corrupted byte that passed
    // the CRC-16 makes the image fail its CRC-32: every chunk is asked for again.
    let r = h.chunk_range(0);
    rig.host_send(&HostToBoard::FrameChunk { frame: 5, offset: 0, data: &px[r] });
    for i in [3, 7] {
        let r = h.chunk_range(i);
        rig.host_send(&HostToBoard::FrameChunk { frame: 5, offset: r.start as u16, data: &px[r] });
    }
    let r = h.chunk_range(19);
    let mut bad = px[r.clone()].to_vec();
    bad[2] ^= 4;
    rig.host_send(&HostToBoard::FrameChunk { frame: 5, offset: r.start as u16, data: &bad });
    rig.run(5);
    let a = acks(&rig);
    assert_eq!(a.last().unwrap().state, FrameState::Missing(ChunkSet::first(20)));
    assert!(rig.detections().is_empty(), "the pipeline never saw the damaged image");
    let s = rig.board.status();
    assert_eq!((s.frame_crc_errors, s.chunks_ignored, s.frames), (1, 1, 0));
    // Sent again whole, in reverse order: complete, acked once, processed once.
    for i in (0..20).rev() {
        let r = h.chunk_range(i);
        rig.host_send(&HostToBoard::FrameChunk { frame: 5, offset: r.start as u16, data: &px[r] });
    }
    rig.run(5);
    assert_eq!(acks(&rig).last().unwrap().state, FrameState::Complete);
    assert_eq!(rig.detections().len(), 1);
    assert!(rig.detections()[0].blob.is_some());
    // A late poll or duplicate chunk of the finished frame: Complete again, no second run.
    rig.host_send(&HostToBoard::FramePoll { header: h, round: 2 });
    rig.host_send(&HostToBoard::FrameChunk { frame: 5, offset: 0, data: &px[..24] });
    rig.run(5);
    assert_eq!(acks(&rig).last(), Some(&FrameAck { frame: 5, round: 2, state: FrameState::Complete }));
    assert_eq!(rig.detections().len(), 1);
    assert_eq!(rig.board.status().frames, 1);
    // A poll for a frame whose start was lost starts it; an older one is stale.
    let h7 = FrameHeader { frame: 7, ..h };
    rig.host_send(&HostToBoard::FramePoll { header: h7, round: 0 });
    rig.host_send(&HostToBoard::FramePoll { header: FrameHeader { frame: 4, ..h }, round: 0 });
    rig.run(2);
    let a = acks(&rig);
    assert_eq!(a[a.len() - 2].state, FrameState::Missing(ChunkSet::first(20)));
    assert_eq!(a[a.len() - 1], FrameAck { frame: 4, round: 0, state: FrameState::Stale });
    // A newer frame supersedes the unfinished 7; 7's chunks are then ignored.
    rig.frame(8, &px);
    rig.host_send(&HostToBoard::FrameChunk { frame: 7, offset: 0, data: &px[..24] });
    rig.run(5);
    assert_eq!(rig.detections().len(), 2);
    assert_eq!(rig.detections()[1].frame, 8);
    assert_eq!(rig.board.status().frames_superseded, 1);
}

#[test]
fn an_upload_resumes_from_the_last_good_chunk() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(20);
    let other = mlp_spec(4, FACE.0, FACE.1).to_bytes().unwrap();
    let crc32 = CRC32.checksum(&other);
    let begin = HostToBoard::ModelBegin { len: other.len() as u32, crc32 };
    rig.host_send(&begin);
    let chunks: Vec<&[u8]> = other.chunks(CHUNK).collect();
    assert!(chunks.len() > 4);
    // Chunk 2 is lost: chunks 3 and 4 are past a gap; the board says where to go back once.
    for i in [0, 1, 3, 4] {
        rig.host_send(&HostToBoard::ModelChunk { offset: (i * CHUNK) as u32, data: chunks[i] });
    }
    rig.run(3);
    let want = |n: usize| BoardToHost::UploadAck { next: (n * CHUNK) as u32 };
    assert_eq!(rig.replies.iter().filter(|r| **r == want(2)).count(), 1);
    assert!(rig.replies.contains(&want(0)), "a new upload starts at 0");
    // The host restarts: the same begin resumes at chunk 2, not 0.
    rig.host_send(&begin);
    rig.run(2);
    assert_eq!(rig.replies.iter().filter(|r| **r == want(2)).count(), 2);
    // A duplicate of a stored chunk is harmless.
    rig.host_send(&HostToBoard::ModelChunk { offset: 0, data: chunks[0] });
    for (i, c) in chunks.iter().enumerate().skip(2) {
        rig.host_send(&HostToBoard::ModelChunk { offset: (i * CHUNK) as u32, data: c });
        rig.run(1);
    }
    rig.host_send(&HostToBoard::ModelCommit);
    rig.run(2);
    let crc = Model::parse(&other).unwrap().crc32;
    assert!(rig.replies.contains(&BoardToHost::ModelAccepted { crc32: crc }), "{:?}", rig.errors());
    // Another blob's begin starts over.
    rig.host_send(&HostToBoard::ModelBegin { len: 100, crc32: 1 });
    rig.run(2);
    assert_eq!(rig.replies.last(), Some(&want(0)));
}

#[test]
fn a_host_of_another_protocol_version_is_told() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(5);
    // A version-1 host's GetStatus: version 1, seq 0, payload [0x07], CRC-16/UMTS, COBS.
    let raw = [1u8, 0, 0, 7];
    let crc = msr_shared::frame::CRC16.checksum(&raw).to_le_bytes();
    assert!(!crc.contains(&0), "the literal assumes a CRC without zero bytes");
    // COBS of 01 00 00 07 c0 c1: runs [01] [] [07 c0 c1], then the delimiter.
    let frame = [0x02, 0x01, 0x01, 0x04, 0x07, crc[0], crc[1], 0x00];
    rig.host.rx.extend(frame);
    rig.run(2);
    assert_eq!(rig.errors(), vec![(ErrorCode::Version, 1)]);
    assert!(!rig.replies.iter().any(|r| matches!(r, BoardToHost::Status(_))));
}

#[test]
fn face_watchdog_holds_still_and_servo_watchdog_stops_streaming() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(100);
    rig.frame(1, &face([0.0, 0.0], false));
    rig.run(20);
    assert!(rig.errors().is_empty());
    rig.run(520);
    assert_eq!(rig.errors(), vec![(ErrorCode::FaceTimeout, 0)]);
    assert_eq!(rig.board.status().mode, Mode::Halted);
    assert_eq!(rig.board.status().face_watchdog_trips, 1);
    let n = rig.targets.len();
    rig.run(200);
    // Still streaming (servos keep their position), but not moving.
    assert!(rig.targets.len() >= n + 19);
    assert!(rig.targets[n..]
        .iter()
        .all(|(_, t)| *t == rig.targets[n - 1].1));
    // Frames again: back to observing.
    rig.frame(2, &face([0.0, 0.0], false));
    rig.run(20);
    assert_eq!(rig.board.status().mode, Mode::Observe);

    // Servos go quiet: within 100 ms the board reports and stops streaming.
    rig.servos_on = false;
    let t0 = rig.now;
    rig.run(150);
    assert!(rig.errors().contains(&(ErrorCode::ServoTimeout, 0)));
    let last = rig.targets.last().unwrap().0;
    assert!(
        last <= t0 + 110_000,
        "targets until {} after the last state",
        last - t0
    );
    rig.run(300);
    assert_eq!(
        rig.targets.last().unwrap().0,
        last,
        "nothing streamed while the servos are silent"
    );
    assert_eq!(rig.board.status().servo_watchdog_trips, 1);
    // They come back somewhere else: streaming resumes from there.
    rig.position = [0.3, 0.2, 0.5, 0.1, -1.0];
    rig.servos_on = true;
    rig.run(30);
    let resumed = rig.targets.iter().find(|(t, _)| *t > last).unwrap().1;
    for i in 0..5 {
        assert!((resumed[i] - rig.position[i]).abs() < 0.1);
    }
    rig.check_targets(0.1);
}

#[test]
fn truncated_oversized_and_garbled_frames_are_counted_and_survived() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(20);
    let ping = rig.wire(&HostToBoard::Ping { nonce: 7 });
    // Truncated: half a frame, then a delimiter.
    rig.host.rx.extend(&ping[..ping.len() / 2]);
    rig.host.rx.push_back(0);
    // Oversized: a run of non-zero bytes longer than any frame.
    rig.host
        .rx
        .extend(std::iter::repeat_n(0x55, 3 * MAX_WIRE_FRAME));
    rig.host.rx.push_back(0);
    // A flipped bit.
    let mut flipped = ping.clone();
    flipped[2] ^= 0x10;
    rig.host.rx.extend(flipped);
    rig.host.rx.extend(ping);
    rig.run(5);
    let s = rig.board.status();
    assert_eq!(s.host_link.oversized, 1);
    assert!(s.host_link.resyncs() >= 3, "{:?}", s.host_link);
    assert!(rig.replies.contains(&BoardToHost::Pong { nonce: 7 }));
    // Face frames of the wrong size, chunks out of order or past the end.
    let h = FrameHeader {
        width: 10,
        height: 10,
        ..header(9, &[0; 100])
    };
    rig.host_send(&HostToBoard::FrameStart(h));
    rig.host_send(&HostToBoard::FrameStart(header(9, &face([0.0, 0.0], false))));
    rig.host_send(&HostToBoard::FrameChunk {
        frame: 9,
        offset: 100,
        data: &[1, 2, 3],
    });
    rig.host_send(&HostToBoard::FrameChunk {
        frame: 3,
        offset: 0,
        data: &[1, 2, 3],
    });
    rig.run(5);
    // The wrong size and the chunk off a chunk boundary are refused; the chunk of another
    // frame is ignored (a reordered or stale chunk is no error).
    assert_eq!(
        rig.errors()
            .iter()
            .filter(|e| e.0 == ErrorCode::BadFrame)
            .count(),
        2
    );
    assert_eq!(rig.board.status().chunks_ignored, 1);
    rig.frame(10, &face([0.0, 0.0], false));
    rig.run(20);
    assert_eq!(rig.detections().len(), 1);
    assert_eq!(rig.board.status().frames_superseded, 1, "frame 9 never finished");
    rig.host_send(&HostToBoard::GetStatus);
    rig.run(2);
    assert!(matches!(rig.replies.last(), Some(BoardToHost::Status(s)) if s.frames == 1));
}

#[test]
fn configuration_is_checked_and_applied() {
    let mut rig = Rig::new(Some(blob()));
    rig.run(20);
    let good = Config {
        threshold: 3.0,
        normalisation: msr_shared::blob::Normalisation::Variance,
        sided: msr_shared::blob::Sided::One,
        min_area: 10,
        confirm_k: 1,
        confirm_n: 1,
        speed_fraction: 0.5,
        hold_ms: 100,
    };
    for bad in [
        Config {
            threshold: f32::NAN,
            ..good
        },
        Config {
            threshold: -1.0,
            ..good
        },
        Config {
            min_area: 0,
            ..good
        },
        Config {
            confirm_k: 3,
            confirm_n: 2,
            ..good
        },
        Config {
            speed_fraction: 1.5,
            ..good
        },
        Config {
            hold_ms: 3_600_000,
            ..good
        },
    ] {
        rig.host_send(&HostToBoard::Configure(bad));
    }
    rig.run(2);
    assert_eq!(rig.errors().len(), 6);
    assert!(rig.errors().iter().all(|e| e.0 == ErrorCode::BadConfig));
    rig.host_send(&HostToBoard::Configure(good));
    rig.run(2);
    assert_eq!(rig.errors().len(), 6);
    let s = rig.board.settings().unwrap();
    assert_eq!((s.threshold, s.min_area), (3.0, 10));
}

#[derive(Clone, Debug)]
enum Event {
    Garbage(Vec<u8>),
    ServoGarbage(Vec<u8>),
    Frame(bool, f32, f32),
    Config(f32, u16, u8, u8, f32, u32),
    Chunk(u32, Vec<u8>),
    Begin(u32),
    Commit,
    Wait(u8),
}

fn event() -> impl Strategy<Value = Event> {
    prop_oneof![
        proptest::collection::vec(any::<u8>(), 0..300).prop_map(Event::Garbage),
        proptest::collection::vec(any::<u8>(), 0..100).prop_map(Event::ServoGarbage),
        (any::<bool>(), -0.1f32..0.1, -0.1f32..0.1).prop_map(|(m, y, p)| Event::Frame(m, y, p)),
        (
            any::<f32>(),
            any::<u16>(),
            any::<u8>(),
            any::<u8>(),
            any::<f32>(),
            any::<u32>()
        )
            .prop_map(|(t, a, k, n, s, h)| Event::Config(t, a, k, n, s, h % 2000)),
        (
            any::<u32>(),
            proptest::collection::vec(any::<u8>(), 0..CHUNK)
        )
            .prop_map(|(o, d)| Event::Chunk(o % 40000, d)),
        any::<u32>().prop_map(|l| Event::Begin(l % 40000)),
        Just(Event::Commit),
        any::<u8>().prop_map(Event::Wait),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Whatever arrives on either link, every target is inside the limits and within the
    /// velocity limit, and nothing panics.
    #[test]
    fn garbage_never_makes_an_unsafe_command(events in proptest::collection::vec(event(), 1..60)) {
        let mut rig = Rig::new(Some(blob()));
        rig.run(20);
        let mut id = 0u16;
        for e in events {
            match e {
                Event::Garbage(g) => { rig.host.rx.extend(g); rig.host.rx.push_back(0); }
                Event::ServoGarbage(g) => { rig.servo.rx.push_back(0); rig.servo.rx.extend(g); rig.servo.rx.push_back(0); }
                Event::Frame(m, y, p) => { id = id.wrapping_add(1); rig.frame(id, &face([y, p], m)); }
                Event::Config(t, a, k, n, s, h) => rig.host_send(&HostToBoard::Configure(Config {
                    threshold: t, normalisation: msr_shared::blob::Normalisation::StdDev, sided: msr_shared::blob::Sided::Two,
                    min_area: a, confirm_k: k, confirm_n: n, speed_fraction: s, hold_ms: h,
                })),
                Event::Chunk(o, d) => rig.host_send(&HostToBoard::ModelChunk { offset: o, data: &d }),
                Event::Begin(l) => rig.host_send(&HostToBoard::ModelBegin { len: l, crc32: 0 }),
                Event::Commit => rig.host_send(&HostToBoard::ModelCommit),
                Event::Wait(ms) => rig.run(ms as u64),
            }
            rig.run(3);
        }
        rig.run(100);
        // The speed fraction may have been configured up to 1.
        rig.check_targets(1.0);
        prop_assert!(!rig.targets.is_empty());
        prop_assert_eq!(rig.board.status().model_crc, Model::parse(blob()).unwrap().crc32);
    }
}

/// The room's report in the newest `Status` the board sent.
fn last_room(replies: &[BoardToHost]) -> Option<RoomReport> {
    replies.iter().rev().find_map(|r| match r {
        BoardToHost::Status(s) => Some(s.room),
        _ => None,
    })
}

#[test]
fn the_room_is_learnt_from_clean_frames_only_and_the_host_controls_it() {
    let home = [HOME_POSTURE[0], HOME_POSTURE[1]];
    // No model: off.
    let mut rig = Rig::new(None);
    rig.run(100);
    assert_eq!(rig.board.status().room.state, RoomState::Off);

    let mut rig = Rig::new(Some(pooled_blob()));
    rig.run(3000);
    assert_eq!(rig.board.status().room.state, RoomState::Learning);
    // Clean frames every 100 ms for 2 s: one learnt per 400 ms.
    for i in 0..20 {
        rig.frame(i, &face(home, false));
        rig.run(100);
    }
    let learnt = rig.board.status().room.frames;
    assert!((4..=6).contains(&learnt), "{learnt} frames learnt");
    // A candidate in the confirmation window: nothing learnt while it is there.
    for i in 20..22 {
        rig.frame(i, &face(home, true));
        rig.run(500);
    }
    assert!(rig.detections().iter().any(|d| d.blob.is_some()));
    assert_eq!(rig.board.status().room.frames, learnt, "learnt from a frame with a mark");
    // Freeze: a Status says so, and nothing more is learnt.
    rig.host_send(&HostToBoard::Room(RoomCommand::Freeze));
    rig.run(1);
    assert_eq!(last_room(&rig.replies).map(|r| r.state), Some(RoomState::Frozen));
    for i in 22..40 {
        rig.frame(i, &face(home, false));
        rig.run(250);
    }
    assert_eq!(rig.board.status().room.frames, learnt);
    // Resume, then reset: back to nothing learnt, still learning.
    rig.host_send(&HostToBoard::Room(RoomCommand::Resume));
    rig.run(1);
    for i in 40..60 {
        rig.frame(i, &face(home, false));
        rig.run(250);
    }
    let r = rig.board.status().room;
    assert!(r.frames > learnt + 5 && r.updates >= 1, "{r:?}");
    rig.host_send(&HostToBoard::Room(RoomCommand::Reset));
    rig.run(1);
    let r = last_room(&rig.replies).unwrap();
    assert_eq!((r.state, r.frames, r.updates, r.largest_q88), (RoomState::Learning, 0, 0, 0));
    // A RAM store keeps nothing: a save is refused as the store being unable.
    rig.host_send(&HostToBoard::Room(RoomCommand::Save));
    rig.run(1);
    assert!(rig.errors().contains(&(ErrorCode::StoreBusy, 0)));
    assert_eq!(rig.board.status().mode, Mode::Observe);
}

/// A frame that made a new prediction is not learnt from (room rule 1: its budget has paid
/// for the network): a head whose reported yaw alternates between two poses from frame to frame
/// teaches the room nothing, the same head held still learns.
#[test]
fn the_room_learns_only_on_frames_with_the_prediction_cached() {
    let mut rig = Rig::new(Some(pooled_blob()));
    rig.run(3000);
    // The rig's servos stay where the test puts them.
    rig.jammed = true;
    let home = [rig.position[0], rig.position[1]];
    let other = [home[0] + 0.01, home[1]];
    for i in 0..20 {
        let head = if i % 2 == 0 { home } else { other };
        rig.position[0] = head[0];
        rig.run(10);
        rig.frame(i, &face(head, false));
        rig.run(90);
    }
    let d = rig.detections();
    assert!(d.len() >= 18 && d.iter().all(|d| d.blob.is_none()), "{d:?}");
    assert_eq!(rig.board.status().room.frames, 0, "learnt from a frame with a new prediction");
    rig.position[0] = home[0];
    for i in 20..40 {
        rig.frame(i, &face(home, false));
        rig.run(100);
    }
    let learnt = rig.board.status().room.frames;
    assert!((4..=6).contains(&learnt), "{learnt} frames learnt with the head still");
}

/// A pitch servo without an integral term holds off its goal by what its load takes back: a
/// head move settles where the servos hold still within [`HOLD_RAD`] (eight counts) of the
/// pose asked for, and the answer gives the angles they report; farther off is not settled.
#[test]
fn a_head_move_settles_where_a_sagging_pitch_servo_holds() {
    let count = core::f32::consts::TAU / 4096.0;
    let answer = |sag_counts: f32| {
        let mut rig = Rig::new(Some(blob()));
        rig.run(3000);
        rig.sag[1] = sag_counts * count;
        rig.host_send(&HostToBoard::MoveHead { yaw: 0.08, pitch: -0.05 });
        rig.run(1500);
        head_answers(&rig)
    };
    assert_eq!(answer(0.0), vec![BoardToHost::HeadAt { head: [0.08, -0.05] }]);
    for c in [3.0, -5.0, 7.5] {
        assert_eq!(answer(c), vec![BoardToHost::HeadAt { head: [0.08, -0.05 + c * count] }], "{c} counts");
    }
    assert!(
        matches!(answer(9.0)[..], [BoardToHost::Error { code: ErrorCode::HeadNotSettled, .. }]),
        "nine counts off"
    );
}

/// A head servo holding still may read the counts around its position by turns: within
/// two counts ([`SETTLE_RAD`]) the pipeline keeps the pose it has, so the decoder runs once and
/// the room learns as with a still reading; three counts away is a new pose.
#[test]
fn a_head_reading_that_flickers_by_a_count_or_two_keeps_its_prediction() {
    let count = core::f32::consts::TAU / 4096.0;
    // Yaw and pitch each on one of the counts from -1 to +1 around home, by turns; or still.
    let run = |flicker: bool| {
        let mut rig = Rig::new(Some(pooled_blob()));
        rig.run(3000);
        rig.jammed = true;
        let home = [rig.position[0], rig.position[1]];
        let runs = rig.board.ws.decoder.runs();
        for i in 0..40 {
            let step = [(i % 3) as f32 - 1.0, ((i / 3) % 3) as f32 - 1.0];
            if flicker {
                rig.position[0] = home[0] + step[0] * count;
                rig.position[1] = home[1] + step[1] * count;
            }
            rig.run(10);
            rig.frame(i, &face(home, false));
            rig.run(90);
        }
        let d = rig.detections();
        assert!(d.len() >= 38 && d.iter().all(|d| d.blob.is_none()), "{d:?}");
        // The reports keep the servos' readings.
        assert_eq!(d.iter().any(|d| d.head[0] != home[0]), flicker, "{d:?}");
        let ran = rig.board.ws.decoder.runs() - runs;
        (rig, home, ran)
    };
    let (still, _, still_runs) = run(false);
    let (mut rig, home, runs) = run(true);
    // Once for the pose, once more after each update of the room's offsets.
    let updates = still.board.status().room.updates;
    assert_eq!(still_runs, 1 + updates, "{updates} updates");
    assert_eq!(runs, still_runs, "the decoder ran again on a flicker");
    let learnt = rig.board.status().room.frames;
    assert!(learnt >= 4, "{learnt} frames learnt");
    assert_eq!(learnt, still.board.status().room.frames, "the room learnt less from a flickering reading");
    // Three counts from the pose the pipeline holds (yaw -1 count, from the first frame) is a
    // new pose, and so is three counts back.
    for (i, yaw) in [(40, 2.0), (41, -1.0)] {
        let before = rig.board.ws.decoder.runs();
        rig.position[0] = home[0] + yaw * count;
        rig.run(10);
        rig.frame(i, &face(home, false));
        rig.run(90);
        assert_eq!(rig.board.ws.decoder.runs(), before + 1, "three counts away kept the old pose");
    }
}

#[test]
fn what_was_learnt_of_the_room_survives_a_reset_in_flash() {
    use crate::store::emu::EmuFlash;
    use crate::store::{FlashStore, F429_BANK2, F429_BANK_SECTORS};
    let home = [HOME_POSTURE[0], HOME_POSTURE[1]];
    let flash = EmuFlash::<Vec<u8>, 1>::new(vec![0xFF; F429_BANK2.len() as usize], &F429_BANK_SECTORS);
    let mut rig = Rig::with_store(FlashStore::new(flash, F429_BANK2, Some(pooled_blob())));
    rig.run(3000);
    // Frames 2 grey levels brighter on the left than the model predicts.
    let mut f = face(home, false);
    for (i, p) in f.iter_mut().enumerate() {
        if i % (FACE.1 as usize) < 12 {
            *p = p.saturating_add(2);
        }
    }
    for i in 0..200 {
        rig.frame(i, &f);
        rig.run(100);
    }
    let before = rig.board.status().room;
    assert!(before.updates >= 5 && before.largest_q88 > 0, "{before:?}");
    rig.host_send(&HostToBoard::Room(RoomCommand::Save));
    rig.run(1);
    let saved = rig.replies.iter().rev().find_map(|r| match r {
        BoardToHost::Store(s) => Some(*s),
        _ => None,
    });
    assert!(saved.and_then(|s| s.stats).is_some(), "{saved:?}");
    // Power cycle: a new board on the same flash finds the offsets.
    let flash = EmuFlash::<Vec<u8>, 1>::new(rig.board.store().flash().cells().clone(), &F429_BANK_SECTORS);
    let mut again = Rig::with_store(FlashStore::new(flash, F429_BANK2, Some(pooled_blob())));
    again.run(10);
    let after = again.board.status().room;
    assert_eq!(after.largest_q88, before.largest_q88, "{after:?}");
    // Reset drops them, in flash too.
    again.host_send(&HostToBoard::Room(RoomCommand::Reset));
    again.run(10);
    let flash = EmuFlash::<Vec<u8>, 1>::new(again.board.store().flash().cells().clone(), &F429_BANK_SECTORS);
    let mut third = Rig::with_store(FlashStore::new(flash, F429_BANK2, Some(pooled_blob())));
    third.run(10);
    assert_eq!(third.board.status().room.largest_q88, 0);
}

#[test]
fn the_self_gate_hears_each_servo_report_once_however_often_the_board_polls() {
    // The board polls every millisecond, the servos report every 10 ms: the gate averages
    // reports, so each must reach it once, not the last one kept at every poll.
    let mut rig = Rig::new(None);
    rig.run(1);
    rig.board.core.gate = Some(crate::self_gate::Gate::new(crate::self_gate::tests::params()));
    rig.run(95);
    assert_eq!(rig.board.core.gate.as_ref().map(|g| g.pending_reports()), Some(9));
}

#[test]
fn the_big_state_fits_the_ram_budget() {
    // Everything but the model store (a built-in blob stays in flash), within the 96 KiB of
    // static RAM the bench holds the board image to, leaving room for the stack, the link
    // buffers and the image's own statics.
    let board = core::mem::size_of::<Board<RamStore<0>>>();
    let ws = core::mem::size_of::<Workspace>();
    println!("Board {board} bytes, of which Workspace {ws}");
    assert!(board <= 72 * 1024, "Board takes {board} bytes");
}

/// Polls `ms` milliseconds (framed servo states arriving unasked every 10 ms); returns what the
/// board wrote on the servo bus.
fn run_raw(rig: &mut Rig, ms: u64) -> Vec<u8> {
    for _ in 0..ms {
        rig.now += 1000;
        if (rig.now / 1000).is_multiple_of(10) {
            rig.states();
        }
        rig.board.poll(rig.now, &mut rig.host, &mut rig.servo);
        for b in std::mem::take(&mut rig.host.tx) {
            if let Some(Ok(f)) = rig.host_acc.push(b) {
                rig.replies.push(f.message::<BoardToHost>().unwrap());
            }
        }
    }
    std::mem::take(&mut rig.servo.tx)
}

#[test]
fn a_board_waiting_for_its_bus_says_nothing_on_it_then_speaks_only_dynamixel() {
    let mut rig = Rig::new(Some(blob()));
    rig.board.await_servo_bus();
    // Queries choose nothing: still silent, and the bytes heard meanwhile count as nothing.
    rig.host_send(&HostToBoard::Ping { nonce: 1 });
    rig.host_send(&HostToBoard::GetServoBus);
    let before = run_raw(&mut rig, 300);
    assert_eq!(before, [], "bytes on a bus of unknown protocol");
    let s = rig.board.status();
    assert_eq!((s.servo_watchdog_trips, s.servo_link.crc_errors, s.servo_link.resyncs()), (0, 0, 0), "{s:?}");
    assert!(rig.errors().is_empty(), "{:?}", rig.errors());
    // The host's choice: from the first byte on, Protocol 2.0 packets and nothing else; first
    // the e-Manual's Ping of ID 1 (no servo answers here, so the start-up pings again each
    // second).
    rig.host_send(&HostToBoard::UseServoBus(ServoBusKind::Dynamixel));
    let after = run_raw(&mut rig, 3000);
    let ping = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E];
    assert_eq!(after[..ping.len()], ping, "{:02x?}", &after[..after.len().min(16)]);
    let mut rx = msr_shared::dynamixel::Receiver::<256>::new();
    let mut packets = 0;
    for &b in &after {
        rx.push(b);
        while rx.next_packet().is_some() {
            packets += 1;
        }
    }
    let c = rx.counters();
    assert_eq!((c.noise_bytes, c.errors(), rx.buffered()), (0, 0, 0), "{c:?}");
    assert!(packets >= 3, "{packets} packets in 3 s");
    assert_eq!(rig.board.status().servo_watchdog_trips, 0);
}

#[test]
fn a_board_waiting_for_its_bus_takes_framed_from_a_host_that_does_not_choose() {
    let mut rig = Rig::new(None);
    rig.board.await_servo_bus();
    rig.host_send(&HostToBoard::GetStatus);
    rig.run(100);
    assert!(rig.targets.is_empty() && !rig.stiffness, "streamed before the bus was known");
    // Half a state report is heard before the choice: the board joins the bus at the next
    // frame, without counting the rest as an error.
    rig.states();
    let report: Vec<u8> = rig.servo.rx.drain(..).collect();
    rig.servo.rx.extend(&report[..report.len() / 2]);
    rig.run(1);
    // Anything but a choice or a query: the framed bus, the protocol's default.
    rig.frame(1, &face([0.0, 0.0], false));
    rig.run(1);
    rig.servo.rx.extend(&report[report.len() / 2..]);
    rig.run(100);
    let s = rig.board.status();
    assert_eq!((s.servo_link.resyncs(), s.servo_link.crc_errors), (0, 0), "{:?}", s.servo_link);
    assert!(rig.errors().contains(&(ErrorCode::NoModel, 0)));
    assert!(rig.stiffness && rig.targets.len() >= 8, "{} targets", rig.targets.len());
    assert_eq!(rig.board.status().servo_watchdog_trips, 0);
}
