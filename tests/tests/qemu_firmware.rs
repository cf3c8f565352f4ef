//! The firmware under QEMU (mps2-an386, Cortex-M4): the UART plumbing, the board image driven
//! over its two links, and exactness against the host build of the same pipeline.
//!
//! The images are built by `cargo xtask test` (or `cargo xtask images`) before the tests run;
//! a missing image fails with the command to build it. Only a missing `qemu-system-arm` skips.
//!
//! The board image runs in lockstep with the test ([`Lockstep`]): the test's ideal servos and
//! its host side answer within the board's own time base, one 1 ms tick at a time, so the
//! board's 100 ms servo watchdog sees what a board wired to real servos would, whatever the load
//! on this machine (with the board on its own clock and the servos on a thread, a busy machine
//! tripped it).

use std::io::{Read, Write};
use std::time::Duration;

use msr_sim::qemu::{self, Qemu};

/// `None` (with a message) when QEMU is not installed.
fn image(name: &str) -> Option<std::path::PathBuf> {
    if !qemu::qemu_available() {
        eprintln!("SKIPPED: {} not found; install qemu-system-arm to run the QEMU tests", qemu::qemu_binary());
        return None;
    }
    Some(qemu::find_image(name).unwrap_or_else(|e| panic!("{e:#}")))
}

#[test]
fn selftest_clock_and_uarts() {
    let Some(img) = image("msr-qemu-selftest") else { return };
    let mut q = Qemu::start(&img).unwrap();
    let msg: Vec<u8> = (1..=255u8).collect();
    q.host.write_all(&msg).unwrap();
    let mut got = vec![0u8; msg.len()];
    q.servo.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    q.servo.read_exact(&mut got).unwrap();
    assert_eq!(got, msg.iter().map(|b| b ^ 0x55).collect::<Vec<_>>());
    q.servo.write_all(b"servo->host").unwrap();
    let mut back = [0u8; 11];
    q.host.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    q.host.read_exact(&mut back).unwrap();
    assert_eq!(&back, b"servo->host");
    q.host.write_all(&[0]).unwrap();
    let exit = q.wait(Duration::from_secs(20)).unwrap();
    exit.success().unwrap();
    assert!(exit.output.contains("calibration: 4000000 loop instructions"), "{}", exit.output);
}

// ---------------------------------------------------------------------------------------------
// The board image, driven over its two links.

use msr_firmware::pipeline::{detect, Workspace};
use msr_firmware::saliency::Settings;
use msr_host::bench::{synthetic, BenchModel};
use msr_host::models::ArchKind;
use msr_shared::blob::{Model, CRC32};
use msr_shared::frame::{encode_message_vec, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::host_port::HostPort;
use msr_shared::joints::{HOME_POSTURE, REACH_JOINTS};
use msr_shared::msg::{
    BoardToHost, BoardToServo, Detection, ErrorCode, HostToBoard, JointState, ServoToBoard, CHUNK,
};
use msr_sim::qemu::Lockstep;
use std::collections::VecDeque;

/// Where the face crop sits in the 320 x 240 camera frame.
const CROP: [u16; 2] = [120, 60];
/// The board's tick, as the sim's world ticks.
const TICK_US: u32 = 1000;
/// Host bytes per tick: a fast link (the QEMU UART is the bottleneck, not this), within what
/// the board image buffers per tick (`msr_sim::qemu::LOCKSTEP_MAX_TICK_BYTES`).
const HOST_BYTES_PER_TICK: usize = 1024;

/// What the emulated servos saw.
#[derive(Default)]
struct ServoLog {
    targets: Vec<(u32, [f32; 5])>,
    state_requests: u32,
    bad_targets: Vec<String>,
}

/// Ideal servos on UART1: they answer every state request with their positions and move to each
/// target at once. Every target is checked against the joint limits.
/// `head`, when set, is what HeadYaw and HeadPitch report, whatever their targets.
struct Servos {
    acc: FrameAccumulator<MAX_WIRE_FRAME>,
    pos: [f32; 5],
    seq: u16,
    log: ServoLog,
    head: Option<[f32; 2]>,
}

impl Servos {
    fn new() -> Servos {
        Servos { acc: FrameAccumulator::new(), pos: HOME_POSTURE, seq: 0, log: ServoLog::default(), head: None }
    }

    /// What the board sent on the bus in; the replies out.
    fn feed(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        for &b in bytes {
            let Some(Ok(f)) = self.acc.push(b) else { continue };
            let Ok(msg) = f.message::<BoardToServo>() else { continue };
            match msg {
                BoardToServo::StateRequest => {
                    let mut report = self.pos;
                    if let Some(h) = self.head {
                        report[..2].copy_from_slice(&h);
                    }
                    let mut states = heapless::Vec::new();
                    for (j, p) in REACH_JOINTS.iter().zip(report) {
                        states.push(JointState { joint: *j, position: p, stiffness: true, faults: 0 }).unwrap();
                    }
                    out.extend(encode_message_vec(self.seq, &ServoToBoard::States { time_ms: 0, states }).unwrap());
                    self.seq = self.seq.wrapping_add(1);
                    self.log.state_requests += 1;
                }
                BoardToServo::Targets { time_ms, targets } => {
                    for t in &targets {
                        if let Err(e) = t.joint.validate(t.position) {
                            self.log.bad_targets.push(format!("{e}"));
                        }
                        if let Some(i) = REACH_JOINTS.iter().position(|j| *j == t.joint) {
                            self.pos[i] = t.position;
                        }
                    }
                    self.log.targets.push((time_ms, self.pos));
                }
                BoardToServo::Stiffness { .. } => {}
            }
        }
        out
    }
}

/// The board image in lockstep with the test's host side and servos.
struct Rig {
    ls: Lockstep,
    servos: Servos,
    /// Bytes for UART0 not sent yet.
    outbox: VecDeque<u8>,
    /// The servos' replies, for the next tick.
    servo_in: Vec<u8>,
    acc: FrameAccumulator<MAX_WIRE_FRAME>,
    /// The PC's encoder (sequence numbers, frames, uploads).
    port: HostPort,
    /// Board messages not yet taken.
    inbox: VecDeque<BoardToHost>,
}

impl Rig {
    /// Starts `img` and resets it into lockstep at time 0; returns the CRC of the model it
    /// runs.
    fn start(img: &std::path::Path) -> (Rig, u32) {
        Rig::start_with(img, None)
    }

    /// As [`Rig::start`], with `blob` preloaded into the board's PSRAM
    /// ([`qemu::preload_bytes`]): the board takes it through its upload's checks at start-up.
    fn start_with(img: &std::path::Path, blob: Option<&[u8]>) -> (Rig, u32) {
        let preload = blob.map(qemu::preload_bytes);
        let (mut ls, _) = Lockstep::start_with(img, preload.as_deref()).unwrap();
        let crc = ls.reset(Some(TICK_US)).unwrap();
        let mut rig = Rig {
            ls,
            servos: Servos::new(),
            outbox: VecDeque::new(),
            servo_in: Vec::new(),
            acc: FrameAccumulator::new(),
            port: HostPort::default(),
            inbox: VecDeque::new(),
        };
        // The image waits for the host to choose its servo bus; these servos are framed.
        rig.send(&HostToBoard::UseServoBus(msr_shared::msg::ServoBusKind::Framed));
        (rig, crc)
    }

    fn send(&mut self, msg: &HostToBoard) {
        let bytes = self.port.encode(msg);
        self.outbox.extend(bytes);
    }

    /// One millisecond of the board's time.
    fn tick(&mut self) {
        let n = self.outbox.len().min(HOST_BYTES_PER_TICK);
        let host: Vec<u8> = self.outbox.drain(..n).collect();
        let servo = std::mem::take(&mut self.servo_in);
        let (mut ho, mut so) = (Vec::new(), Vec::new());
        self.ls.tick(&host, &servo, &mut ho, &mut so).unwrap();
        self.servo_in = self.servos.feed(&so);
        for b in ho {
            if let Some(Ok(f)) = self.acc.push(b) {
                self.inbox.push_back(f.message::<BoardToHost>().expect("a valid BoardToHost message"));
            }
        }
    }

    /// Ticks until a message `pick` accepts, returning the others seen on the way; panics after
    /// `max_ms` of the board's time.
    fn until<T>(&mut self, max_ms: u64, mut pick: impl FnMut(&BoardToHost) -> Option<T>) -> (T, Vec<BoardToHost>) {
        let mut other = Vec::new();
        for _ in 0..max_ms {
            while let Some(m) = self.inbox.pop_front() {
                if let Some(t) = pick(&m) {
                    return (t, other);
                }
                other.push(m);
            }
            self.tick();
        }
        panic!("no awaited message from the board within {max_ms} ms of its time; others: {other:?}");
    }

    fn run_for(&mut self, ms: u64) {
        for _ in 0..ms {
            self.tick();
        }
    }

    /// An upload as the host link defines it: the board answers `ModelBegin` once its flash slot
    /// is erased, and drops chunks that arrive while its flash is busy, answering `UploadAck`
    /// with the offset it wants; the host goes back there (as `msr run --upload` does).
    fn upload(&mut self, blob: &[u8]) -> u32 {
        let ms = 3000 + (blob.len() / HOST_BYTES_PER_TICK) as u64;
        self.send(&HostToBoard::ModelBegin { len: blob.len() as u32, crc32: CRC32.checksum(blob) });
        let mut next = self.until(ms, |m| match m {
            BoardToHost::UploadAck { next } => Some(*next as usize),
            _ => None,
        })
        .0;
        for _ in 0..16 {
            for (i, c) in blob[next..].chunks(CHUNK).enumerate() {
                self.send(&HostToBoard::ModelChunk { offset: (next + i * CHUNK) as u32, data: c });
            }
            self.send(&HostToBoard::ModelCommit);
            let got = self.until(ms, |m| match m {
                BoardToHost::ModelAccepted { crc32 } => Some(Ok(*crc32)),
                BoardToHost::UploadAck { next } => Some(Err(*next as usize)),
                BoardToHost::Error { code: ErrorCode::BadUpload | ErrorCode::BadModel, detail } => {
                    panic!("upload refused: {m:?} ({detail})")
                }
                _ => None,
            });
            match got.0 {
                Ok(crc) => return crc,
                Err(n) => next = n,
            }
        }
        panic!("the upload got no further after 16 rounds");
    }

    /// Sends `ModelBegin` and waits for its answer (the board gives it once the slot is erased;
    /// chunks sent before it would be dropped).
    fn begin(&mut self, len: usize, crc32: u32) -> u32 {
        self.send(&HostToBoard::ModelBegin { len: len as u32, crc32 });
        self.until(3000, |m| match m {
            BoardToHost::UploadAck { next } => Some(*next),
            _ => None,
        })
        .0
    }

    fn frame(&mut self, id: u16, model: &Model, pixels: &[u8]) {
        let origin = CROP.map(u32::from);
        let bytes = self.port.encode_frame(id, origin, [model.face_w as u32, model.face_h as u32], pixels).unwrap();
        self.outbox.extend(bytes);
    }

    fn status(&mut self) -> msr_shared::msg::Status {
        self.send(&HostToBoard::GetStatus);
        self.until(1000, |m| match m {
            BoardToHost::Status(s) => Some(*s),
            _ => None,
        })
        .0
    }

    fn detection(&mut self, model: &Model, id: u16, pixels: &[u8]) -> Detection {
        self.frame(id, model, pixels);
        self.until(1000, |m| match m {
            BoardToHost::Detection(d) if d.frame == id => Some(*d),
            BoardToHost::Error { code: ErrorCode::NoModel | ErrorCode::BadFrame, detail } => {
                panic!("frame {id} refused ({detail})")
            }
            _ => None,
        })
        .0
    }

    /// Ends the run; the image's output (status, stack peak) and what the servos saw.
    fn exit(self) -> (msr_sim::qemu::QemuExit, ServoLog) {
        let exit = self.ls.exit(Duration::from_secs(60)).unwrap();
        (exit, self.servos.log)
    }
}

/// Frames for the head at `head`: the model's own prediction with +-2 grey levels of noise, and
/// a 15 x 15 mark of grey 226 at `mark` (crop pixels, top-left) when given.
fn make_frame(model: &Model, head: [f32; 2], mark: Option<(usize, usize)>, seed: u32) -> Vec<u8> {
    let mut ws = Box::new(Workspace::new());
    let face = ws.decode(model, head).unwrap();
    let mut rng = seed;
    let mut f: Vec<u8> = face
        .iter()
        .map(|&q| {
            rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (((q as i32 + 128) >> 8) + ((rng >> 24) % 5) as i32 - 2).clamp(0, 255) as u8
        })
        .collect();
    if let Some((y0, x0)) = mark {
        let w = model.face_w as usize;
        for y in y0..y0 + 15 {
            f[y * w + x0..y * w + x0 + 15].fill(226);
        }
    }
    f
}

struct Run {
    detections: Vec<(Detection, Vec<u8>)>,
    servo: ServoLog,
    exit: msr_sim::qemu::QemuExit,
    other: Vec<BoardToHost>,
}

/// Starts the board image with `m` preloaded, sends `n_frames` frames (each answered by a
/// Detection before the next goes out), then lets the motion run for `settle_ms` of the board's
/// time and ends the run. With `heads`, the servos report `heads[k]` as the head pose for frame
/// `k`. Preloaded, not uploaded: the emulated UART moves a byte per turn of QEMU's event loop,
/// and the upload took most of each run; uploads have their own tests here
/// ([`bad_upload_keeps_the_running_model`]) and in `qemu_flash` and `flash_cli`.
fn drive_board(
    m: &BenchModel,
    frames: impl Fn(&Model, [f32; 2], usize) -> Vec<u8>,
    n_frames: usize,
    heads: Option<&[[f32; 2]]>,
    settle_ms: u64,
) -> Option<Run> {
    let img = image(qemu::BOARD_IMAGE)?;
    let model = Model::parse(&m.blob).unwrap();
    let (mut rig, crc) = Rig::start_with(&img, Some(&m.blob));
    assert_eq!(crc, model.crc32, "the board does not run the preloaded model");
    rig.send(&HostToBoard::Ping { nonce: 7 });
    let (nonce, _) = rig.until(1000, |m| match m {
        BoardToHost::Pong { nonce } => Some(*nonce),
        _ => None,
    });
    assert_eq!(nonce, 7);
    let mut detections = Vec::new();
    let mut other = Vec::new();
    let mut head = [0.0f32, 0.0];
    for k in 0..n_frames {
        if let Some(hs) = heads {
            head = hs[k];
            rig.servos.head = Some(head);
            // Two more answered state requests: the board has the new pose.
            let asked = rig.servos.log.state_requests;
            let mut ms = 0;
            while rig.servos.log.state_requests < asked + 2 {
                assert!(ms < 1000, "the board stopped asking the servos");
                rig.tick();
                ms += 1;
            }
        }
        let pixels = frames(&model, head, k);
        rig.frame(k as u16, &model, &pixels);
        let (d, o) = rig.until(1000, |msg| match msg {
            BoardToHost::Detection(d) if d.frame == k as u16 => Some(*d),
            _ => None,
        });
        other.extend(o);
        head = d.head;
        detections.push((d, pixels));
    }
    rig.run_for(settle_ms);
    let (exit, servo) = rig.exit();
    Some(Run { detections, servo, exit, other })
}

/// The 15 x 15 mark, placed on frames 1.. (frame 0 is clean).
fn marked(model: &Model, head: [f32; 2], k: usize) -> Vec<u8> {
    let mark = (k > 0).then_some((20, 30));
    make_frame(model, head, mark, 0xC0FFEE + k as u32)
}

#[test]
fn board_image_detects_reaches_and_matches_the_host_build() {
    let m = synthetic(ArchKind::Conv).unwrap();
    // Frames 1, 2, 3 carry the mark: the third confirms and the arm goes up (detection pauses).
    let Some(run) = drive_board(&m, marked, 4, None, 3000) else { return };
    run.exit.success().unwrap();
    println!("{}", run.exit.output);
    // One clock for the board and its servos: the servo watchdog never trips.
    assert!(run.exit.output.contains("servo_watchdog_trips: 0"), "{}", run.exit.output);
    let model = Model::parse(&m.blob).unwrap();
    let settings = Settings::of(&model);

    // Frame 0 is the face itself: nothing; the marked ones: the mark.
    let (d0, _) = &run.detections[0];
    assert!(d0.blob.is_none(), "clean frame: {d0:?}");
    let mark_box = [CROP[0] + 30, CROP[1] + 20, CROP[0] + 44, CROP[1] + 34];
    let seen: Vec<&Detection> = run.detections.iter().map(|(d, _)| d).filter(|d| d.blob.is_some()).collect();
    assert!(seen.len() >= 3, "the mark must be found on the marked frames: {:?}", run.detections.iter().map(|d| d.0).collect::<Vec<_>>());
    for d in &seen {
        let b = d.blob.unwrap();
        assert_eq!(b.box_xyxy, mark_box, "{d:?}");
        assert_eq!(b.area, 225);
    }
    // Confirmation: K = 3 of the last N = 5 (the library's defaults) before the reach.
    let first_confirm = run.detections.iter().position(|(d, _)| d.confirmed).expect("a reach was confirmed");
    assert_eq!(first_confirm, 3, "{:?}", run.detections.iter().map(|d| d.0).collect::<Vec<_>>());

    // Targets streamed, every one inside the limits, moving towards the reach.
    let reach = run.detections[first_confirm].0.reach.unwrap();
    let servo = &run.servo;
    assert!(servo.bad_targets.is_empty(), "targets outside the limits: {:?}", servo.bad_targets);
    assert!(servo.targets.len() >= 20, "only {} target messages", servo.targets.len());
    assert!(servo.state_requests >= 1);
    let last = servo.targets.last().unwrap().1;
    let start = HOME_POSTURE;
    for i in 0..5 {
        let (from, to, now) = (start[i], reach[i], last[i]);
        assert!(
            (now - to).abs() <= (from - to).abs() + 1e-6,
            "joint {i} moved away from the reach: home {from} target {to} now {now}"
        );
    }
    // 10 ms apart in the board's (virtual) time.
    let times: Vec<u32> = servo.targets.iter().map(|t| t.0).collect();
    let steps: Vec<u32> = times.windows(2).map(|w| w[1].wrapping_sub(w[0])).collect();
    assert!(steps.iter().filter(|&&s| s == 10).count() * 10 >= steps.len() * 9, "target periods: {steps:?}");

    // Exactness: the host build of the same library on the same frames and head angles gives
    // the same bits.
    let mut ws = Box::new(Workspace::new());
    for (d, pixels) in &run.detections {
        let h = detect(&mut ws, &model, &settings, pixels, CROP, d.head).unwrap();
        let host_blob = h.blob.map(|b| (b.area, [b.x0 + CROP[0], b.y0 + CROP[1], b.x1 + CROP[0], b.y1 + CROP[1]]));
        assert_eq!(d.blob.map(|b| (b.area, b.box_xyxy)), host_blob, "frame {}", d.frame);
        assert_eq!(d.blob.map(|b| b.centroid.map(f32::to_bits)), h.centroid.map(|c| c.map(f32::to_bits)), "frame {}", d.frame);
        assert_eq!(d.reach.map(|r| r.map(f32::to_bits)), h.reach.map(|r| r.map(f32::to_bits)), "frame {}", d.frame);
    }
    let _ = run.other;
}

/// Host build and QEMU build, bit for bit, over head poses across the +-5 degree range and both
/// decoders; marks on every third frame only, so no reach interrupts detection.
#[test]
fn qemu_and_host_builds_agree_bit_for_bit() {
    let heads: Vec<[f32; 2]> = (0..9)
        .map(|k| {
            let a = k as f32 * 0.7;
            [0.087 * a.sin(), 0.06 * (1.3 * a).cos()]
        })
        .collect();
    let frames = |model: &Model, head: [f32; 2], k: usize| {
        let mark = (k % 3 == 1).then_some((5 + 4 * k, 50 - 5 * k));
        make_frame(model, head, mark, 77 + k as u32)
    };
    for kind in [ArchKind::Conv, ArchKind::Mlp] {
        let m = synthetic(kind).unwrap();
        let Some(run) = drive_board(&m, frames, heads.len(), Some(&heads), 0) else { return };
        run.exit.success().unwrap();
        let model = Model::parse(&m.blob).unwrap();
        let settings = Settings::of(&model);
        let mut ws = Box::new(Workspace::new());
        let mut found = 0;
        for ((d, pixels), want_head) in run.detections.iter().zip(&heads) {
            assert_eq!(d.head.map(f32::to_bits), want_head.map(f32::to_bits), "{kind:?} frame {}: head", d.frame);
            assert!(!d.confirmed, "{kind:?}: no reach expected");
            let h = detect(&mut ws, &model, &settings, pixels, CROP, d.head).unwrap();
            let host_blob = h.blob.map(|b| (b.area, [b.x0 + CROP[0], b.y0 + CROP[1], b.x1 + CROP[0], b.y1 + CROP[1]]));
            assert_eq!(d.blob.map(|b| (b.area, b.box_xyxy)), host_blob, "{kind:?} frame {}", d.frame);
            assert_eq!(d.blob.map(|b| b.centroid.map(f32::to_bits)), h.centroid.map(|c| c.map(f32::to_bits)), "{kind:?} frame {}", d.frame);
            assert_eq!(d.reach.map(|r| r.map(f32::to_bits)), h.reach.map(|r| r.map(f32::to_bits)), "{kind:?} frame {}", d.frame);
            found += d.blob.is_some() as usize;
        }
        // The marks were found (the comparison is not of empty results only).
        assert!(found >= 3, "{kind:?}: {found} marks found");
    }
}

/// The benchmark image's own checks (the board's pooled-saliency row routine and clip test
/// against their plain versions on random faces), then its predicted faces, golden frames and
/// online self-calibration against the host build's: `bench_qemu` fails on any difference.
/// With the pooled synthetic model (radius 2, the row routine's pair loop, pose cells).
#[test]
fn benchmark_image_checks_pass_and_match_the_host_build() {
    let Some(_) = image("msr-qemu-bench") else { return };
    let m = msr_host::bench::synthetic_pooled(ArchKind::Conv, false).unwrap();
    let v = msr_host::bench::bench_qemu(&m).unwrap();
    for k in ["faces_match_host", "golden_matches_host"] {
        assert_eq!(v[k], true, "{k}");
    }
    assert_eq!(v["room"]["matches_host"], true);
    // The stages ran: a decoder and a saliency of real size.
    assert!(v["stages"]["decoder"].as_u64().unwrap() > 100_000, "{v}");
    assert!(v["stages"]["saliency"].as_u64().unwrap() > 50_000, "{v}");
}

/// The benchmark image takes its model only as preloaded and whole: damaged bytes, a header
/// that claims more than a slot, and no preload at all are each one line and exit code 1.
#[test]
fn benchmark_image_refuses_a_damaged_or_missing_preload() {
    let Some(img) = image("msr-qemu-bench") else { return };
    let blob = synthetic(ArchKind::Conv).unwrap().blob;
    let mut flipped = qemu::preload_bytes(&blob);
    let last = flipped.len() - 1;
    flipped[last] ^= 0x40;
    // A header whose check word holds for a length past the 1.5 MiB slot.
    let len = 2u32 << 20;
    let crc = msr_shared::blob::CRC32.checksum(&blob);
    let mut long = Vec::new();
    for w in [0x4D53_5250u32, len, crc, 0x4D53_5250 ^ len ^ crc] {
        long.extend(w.to_le_bytes());
    }
    long.extend_from_slice(&blob);
    for (preload, want) in [
        (Some(&flipped[..]), "MSR-BENCH-ERROR preloaded model refused: Crc"),
        (Some(&long[..]), "MSR-BENCH-ERROR preloaded model refused: TooLarge"),
        (None, "MSR-BENCH-ERROR no model: none is built in and none was preloaded"),
    ] {
        let opts = qemu::Options { preload, ..qemu::Options::default() };
        let exit = qemu::run_image(&img, &opts, Duration::from_secs(60), |_, _| Ok(())).unwrap();
        assert_eq!(exit.code, Some(1), "{want}: {}", exit.output);
        assert_eq!(exit.output.lines().filter(|l| l.starts_with("MSR-BENCH")).collect::<Vec<_>>(), [want], "{}", exit.output);
    }
}

/// The board image runs free without the lockstep pipe, but asked to start in lockstep without
/// it, where nothing could drive its clock, it says so and ends instead of waiting.
#[test]
fn board_image_refuses_lockstep_without_its_pipe() {
    let Some(img) = image(qemu::BOARD_IMAGE) else { return };
    let opts = qemu::Options { without_lockstep_pipe: true, ..qemu::Options::default() };
    let (mut ls, crc) = Lockstep::start_opts(&img, &opts).unwrap();
    assert_eq!(crc, 0, "a fresh board has no model");
    assert!(!ls.status_frame().unwrap().is_empty(), "running free, it answers");
    let e = format!("{:#}", ls.reset(Some(TICK_US)).unwrap_err());
    assert!(e.contains("ended before answering start-up"), "{e}");
    assert!(e.contains("lockstep asked for, but QEMU was started without the lockstep pipe (descriptor 3)"), "{e}");
}

/// A bad upload is refused with the reason, and the model in use stays: same CRC, same results.
#[test]
fn bad_upload_keeps_the_running_model() {
    let Some(img) = image(qemu::BOARD_IMAGE) else { return };
    let m = synthetic(ArchKind::Conv).unwrap();
    let model = Model::parse(&m.blob).unwrap();
    let (mut host, _) = Rig::start(&img);
    // Before any model: the status says so.
    assert_eq!(host.status().model_crc, 0);
    assert_eq!(host.upload(&m.blob), model.crc32);
    let pixels = make_frame(&model, [0.0, 0.0], Some((20, 30)), 5);
    let before = host.detection(&model, 1, &pixels);
    assert!(before.blob.is_some());

    // Short blobs keep this quick: QEMU's UART moves a few KB per second.
    // 1. Bytes damaged in transit: the announced CRC-32 does not match.
    let good = &m.blob[..2048];
    let mut damaged = good.to_vec();
    damaged[100] ^= 0x40;
    assert_eq!(host.begin(damaged.len(), CRC32.checksum(good)), 0);
    for (i, c) in damaged.chunks(CHUNK).enumerate() {
        host.send(&HostToBoard::ModelChunk { offset: (i * CHUNK) as u32, data: c });
    }
    host.send(&HostToBoard::ModelCommit);
    let (code, _) = host.until(5000, |m| match m {
        BoardToHost::Error { code: c @ (ErrorCode::BadUpload | ErrorCode::BadModel), .. } => Some(*c),
        BoardToHost::ModelAccepted { .. } => panic!("a damaged upload was accepted"),
        _ => None,
    });
    assert_eq!(code, ErrorCode::BadUpload);
    // 2. Intact transfer of a blob that fails validation (truncated: its header says longer).
    let (code, _) = {
        assert_eq!(host.begin(damaged.len(), CRC32.checksum(&damaged)), 0);
        for (i, c) in damaged.chunks(CHUNK).enumerate() {
            host.send(&HostToBoard::ModelChunk { offset: (i * CHUNK) as u32, data: c });
        }
        host.send(&HostToBoard::ModelCommit);
        host.until(5000, |m| match m {
            BoardToHost::Error { code: c @ (ErrorCode::BadUpload | ErrorCode::BadModel), .. } => Some(*c),
            BoardToHost::ModelAccepted { .. } => panic!("an invalid blob was accepted"),
            _ => None,
        })
    };
    assert_eq!(code, ErrorCode::BadModel);
    // 3. A chunk past a gap is not stored: the board asks for the upload from its start, and a
    // commit now is refused the same way; the running model stays.
    assert_eq!(host.begin(m.blob.len(), CRC32.checksum(&m.blob)), 0);
    host.send(&HostToBoard::ModelChunk { offset: CHUNK as u32, data: &m.blob[CHUNK..2 * CHUNK] });
    host.send(&HostToBoard::ModelCommit);
    // Three answers, all "from 0": the begin's (above), the gap's and the early commit's.
    let mut acks = 1;
    host.until(5000, |m| match m {
        BoardToHost::UploadAck { next: 0 } => {
            acks += 1;
            (acks == 3).then_some(())
        }
        BoardToHost::UploadAck { .. } | BoardToHost::ModelAccepted { .. } => panic!("{m:?}"),
        _ => None,
    });

    assert_eq!(host.status().model_crc, model.crc32, "the running model changed");
    let after = host.detection(&model, 2, &pixels);
    assert_eq!(after.blob, before.blob);
    assert_eq!(after.reach.map(|r| r.map(f32::to_bits)), before.reach.map(|r| r.map(f32::to_bits)));
    let (exit, _) = host.exit();
    exit.success().unwrap();
}

/// The other way in: a model built into the image at compile time (`MSR_MODEL_BLOB`). Builds that
/// variant of the board image into its own target folder (about a minute), then runs frames on
/// it without any upload.
#[test]
fn built_in_model_runs_without_upload() {
    if image(qemu::BOARD_IMAGE).is_none() {
        return;
    }
    let m = synthetic(ArchKind::Conv).unwrap();
    let model = Model::parse(&m.blob).unwrap();
    let crate_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/qemu");
    let target_dir = crate_dir.join("target/built-in-test");
    std::fs::create_dir_all(&target_dir).unwrap();
    let blob_path = target_dir.join("conv.msrm");
    std::fs::write(&blob_path, &m.blob).unwrap();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args(["build", "--release", "--bin", "msr-qemu"])
        .current_dir(&crate_dir)
        .env("MSR_MODEL_BLOB", &blob_path)
        .env("CARGO_TARGET_DIR", &target_dir)
        .output()
        .expect("running cargo");
    assert!(out.status.success(), "building the image with a built-in model failed:\n{}", String::from_utf8_lossy(&out.stderr));
    let img = target_dir.join(qemu::TARGET).join("release").join(qemu::BOARD_IMAGE);

    let (mut host, crc) = Rig::start(&img);
    assert_eq!(crc, model.crc32, "the built-in model is not the one the image reports at start-up");
    assert_eq!(host.status().model_crc, model.crc32, "the built-in model is not the one running");
    let pixels = make_frame(&model, [0.0, 0.0], Some((20, 30)), 9);
    let d = host.detection(&model, 1, &pixels);
    assert_eq!(d.blob.map(|b| b.area), Some(225), "{d:?}");
    let (exit, _) = host.exit();
    exit.success().unwrap();
    assert!(exit.output.contains(&format!("built-in model {} bytes", m.blob.len())), "{}", exit.output);
}
