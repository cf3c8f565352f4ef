//! The board through the emulated links, as the sim drives it: model uploads (bad ones are
//! refused and the previous model keeps running), truncated and oversized frames, both watchdogs.
mod common;

use msr_shared::frame::MAX_WIRE_FRAME;
use msr_shared::msg::{BoardToHost, ErrorCode, HostToBoard, Mode, CHUNK};
use msr_sim::link::FaultConfig;
use msr_sim::world::{Flow, WorldConfig};
use msr_sim::Robot;

fn errors(msgs: &[(u64, BoardToHost)]) -> Vec<ErrorCode> {
    msgs.iter()
        .filter_map(|(_, m)| {
            if let BoardToHost::Error { code, .. } = m {
                Some(*code)
            } else {
                None
            }
        })
        .collect()
}

fn detections(msgs: &[(u64, BoardToHost)]) -> Vec<msr_shared::msg::Detection> {
    msgs.iter()
        .filter_map(|(_, m)| {
            if let BoardToHost::Detection(d) = m {
                Some(*d)
            } else {
                None
            }
        })
        .collect()
}

fn crc(b: &[u8]) -> u32 {
    msr_shared::blob::CRC32.checksum(b)
}

#[test]
fn bad_uploads_are_refused_and_the_previous_model_keeps_running() {
    let good = common::trained_model(Robot::Red);
    let mark = common::a_mark(Robot::Red, 3);
    // 1. Garbage with a correct CRC: the upload completes and validation refuses it.
    let garbage: Vec<u8> = (0..3000u32).map(|i| (i * 7 + 3) as u8).collect();
    // 2. The first 4 KiB of a real blob announced with the whole blob's length and CRC, then a
    //    commit: the upload is incomplete (the board answers where to resume).
    let other = msr_host::bench::synthetic(msr_host::models::ArchKind::Conv)
        .unwrap()
        .blob;
    let seen = common::scripted(
        Some(&good),
        &WorldConfig::default(),
        Robot::Red,
        3_000_000,
        |w, pc, _| {
            let t = w.now_us;
            if t == 0 {
                let mut b = pc.port.encode(&HostToBoard::ModelBegin {
                    len: garbage.len() as u32,
                    crc32: crc(&garbage),
                });
                for (i, c) in garbage.chunks(CHUNK).enumerate() {
                    b.extend(pc.port.encode(&HostToBoard::ModelChunk {
                        offset: (i * CHUNK) as u32,
                        data: c,
                    }));
                }
                b.extend(pc.port.encode(&HostToBoard::ModelCommit));
                w.host.send(&b);
            }
            if t == 200_000 {
                let mut b = pc.port.encode(&HostToBoard::ModelBegin {
                    len: other.len() as u32,
                    crc32: crc(&other),
                });
                for (i, c) in other[..4096].chunks(CHUNK).enumerate() {
                    b.extend(pc.port.encode(&HostToBoard::ModelChunk {
                        offset: (i * CHUNK) as u32,
                        data: c,
                    }));
                }
                b.extend(pc.port.encode(&HostToBoard::ModelCommit));
                w.host.send(&b);
            }
            // Frames with a mark all along: the old model must keep finding it.
            if t >= 300_000 && t % 100_000 == 0 && w.host.tx_idle_at_us() <= t {
                pc.send_frame(w, Some(&mark));
            }
            if t == 1_500_000 {
                w.host.send(&pc.port.encode(&HostToBoard::GetStatus));
            }
            Flow::Continue
        },
    );
    let errs = errors(&seen.msgs);
    assert!(
        errs.contains(&ErrorCode::BadModel),
        "garbage refused by validation: {errs:?}"
    );
    // The incomplete upload is not committed: the board says where it stopped (and keeps it,
    // so the host can resume).
    assert!(
        seen.msgs.iter().any(|(_, m)| *m == BoardToHost::UploadAck { next: 4096 }),
        "incomplete upload not committed: {errs:?}"
    );
    assert!(!seen
        .msgs
        .iter()
        .any(|(_, m)| matches!(m, BoardToHost::ModelAccepted { .. })));
    assert_eq!(
        seen.status.model_crc,
        msr_shared::blob::Model::parse(&good).unwrap().crc32,
        "the built-in model still runs"
    );
    let dets = detections(&seen.msgs);
    // Detection pauses once the arm goes up, so the answers stop at the confirming frame.
    assert!(
        dets.iter().filter(|d| d.blob.is_some()).count() >= 3,
        "the old model still finds the mark"
    );
    assert!(dets.iter().any(|d| d.confirmed), "and reaches for it");
    assert_eq!(seen.world.servos.counters().limit_violations, 0);
}

#[test]
fn a_good_upload_replaces_the_model() {
    let good = common::trained_model(Robot::Red);
    let other = msr_host::bench::synthetic(msr_host::models::ArchKind::Conv)
        .unwrap()
        .blob;
    // At 921600 baud (about 92 KB/s) the upload takes len / 92 ms.
    let max_us = 1_000_000 + other.len() as u64 * 11;
    let seen = common::scripted(
        Some(&good),
        &WorldConfig::default(),
        Robot::Red,
        max_us,
        |w, pc, _| {
            if w.now_us == 0 {
                let b = pc.port.encode_upload(&other);
                w.host.send(&b);
            }
            Flow::Continue
        },
    );
    let accepted: Vec<u32> = seen
        .msgs
        .iter()
        .filter_map(|(_, m)| {
            if let BoardToHost::ModelAccepted { crc32 } = m {
                Some(*crc32)
            } else {
                None
            }
        })
        .collect();
    let want = msr_shared::blob::Model::parse(&other).unwrap().crc32;
    assert_eq!(accepted.len(), 1, "{:?}", errors(&seen.msgs));
    assert_eq!(seen.status.model_crc, want);
}

#[test]
fn truncated_wrong_size_and_oversized_frames() {
    let blob = common::trained_model(Robot::Red);
    let seen = common::scripted(
        Some(&blob),
        &WorldConfig::default(),
        Robot::Red,
        1_500_000,
        |w, pc, _| {
            let t = w.now_us;
            match t {
                // A crop of the wrong size is refused at its start.
                100_000 => {
                    let h = msr_shared::deliver::face_header(900, [0, 0], [80, 58], 224, &[0; 80 * 58]);
                    w.host.send(&pc.port.encode(&HostToBoard::FrameStart(h)));
                }
                // A truncated frame: its last chunk never comes; then a whole one.
                200_000 => {
                    let (_, face) = pc.camera.shoot(&w.body_pose(), None, &mut pc.rng, msr_sim::light::Light::FIXED).unwrap();
                    let mut b = pc.port.encode_face(face.crop.origin(), face.crop.size(), &face.grey).unwrap();
                    // Cut the wire bytes of the last chunk off (everything after the second-to-last delimiter).
                    let delims: Vec<usize> = b
                        .iter()
                        .enumerate()
                        .filter(|(_, &x)| x == 0)
                        .map(|(i, _)| i)
                        .collect();
                    b.truncate(delims[delims.len() - 2] + 1);
                    w.host.send(&b);
                }
                400_000 => pc.send_frame(w, None),
                // A chunk past the end of the frame.
                600_000 => {
                    let (_, face) = pc.camera.shoot(&w.body_pose(), None, &mut pc.rng, msr_sim::light::Light::FIXED).unwrap();
                    let b = pc.port.encode_face(face.crop.origin(), face.crop.size(), &face.grey).unwrap();
                    w.host.send(&b);
                    let data = [1u8; 16];
                    let size = [face.crop.width as u16, face.crop.height as u16];
                    let h = msr_shared::deliver::face_header(77, [0, 0], size, 224, &face.grey);
                    w.host.send(&pc.port.encode(&HostToBoard::FrameStart(h)));
                    w.host.send(&pc.port.encode(&HostToBoard::FrameChunk {
                        frame: 77,
                        offset: 65000,
                        data: &data,
                    }));
                }
                // Garbage longer than any frame, no delimiter: skipped as one oversized frame.
                800_000 => w.host.send(&vec![0x55u8; MAX_WIRE_FRAME * 3]),
                801_000 => w.host.send(&[0]),
                1_000_000 => pc.send_frame(w, None),
                1_200_000 => w.host.send(&pc.port.encode(&HostToBoard::GetStatus)),
                _ => {}
            }
            Flow::Continue
        },
    );
    let errs = errors(&seen.msgs);
    assert!(
        errs.iter().filter(|e| **e == ErrorCode::BadFrame).count() >= 2,
        "{errs:?}"
    );
    let dets = detections(&seen.msgs);
    assert_eq!(
        dets.len(),
        3,
        "the truncated frame gives nothing; the three whole ones are answered: {dets:?}"
    );
    // The truncated frame and frame 77 were left unfinished and superseded by the next ones.
    assert_eq!(seen.status.frames_superseded, 2, "{:?}", seen.status);
    assert!(
        seen.status.host_link.oversized >= 1,
        "{:?}",
        seen.status.host_link
    );
    assert_eq!(seen.status.frames, 3);
    assert_eq!(seen.world.servos.counters().limit_violations, 0);
}

#[test]
fn face_watchdog_halts_and_frames_bring_it_back() {
    let blob = common::trained_model(Robot::Red);
    let seen = common::scripted(
        Some(&blob),
        &WorldConfig::default(),
        Robot::Red,
        2_000_000,
        |w, pc, _| {
            let t = w.now_us;
            // Frames until 300 ms, none until 1.2 s (the face watchdog is 500 ms), then frames again.
            if t % 100_000 == 0 && (t <= 300_000 || t >= 1_200_000) {
                pc.send_frame(w, None);
            }
            if t == 1_000_000 || t == 1_900_000 {
                w.host.send(&pc.port.encode(&HostToBoard::GetStatus));
            }
            Flow::Continue
        },
    );
    assert!(errors(&seen.msgs).contains(&ErrorCode::FaceTimeout));
    let statuses: Vec<(u64, msr_shared::msg::Status)> = seen
        .msgs
        .iter()
        .filter_map(|(t, m)| {
            if let BoardToHost::Status(s) = m {
                Some((*t, *s))
            } else {
                None
            }
        })
        .collect();
    let during = statuses
        .iter()
        .find(|(t, _)| (1_000_000..1_100_000).contains(t))
        .expect("status at 1 s")
        .1;
    assert_eq!(during.mode, Mode::Halted);
    assert_eq!(during.face_watchdog_trips, 1);
    let after = statuses
        .iter()
        .find(|(t, _)| *t >= 1_900_000)
        .expect("status at 1.9 s")
        .1;
    assert_eq!(after.mode, Mode::Observe, "frames again: observing again");
    assert_eq!(seen.world.servos.counters().limit_violations, 0);
}

#[test]
fn servo_watchdog_stops_motion_until_the_servos_answer() {
    let blob = common::trained_model(Robot::Red);
    let mut cfg = WorldConfig::default();
    // The servo bus is dead from 0.5 s to 0.8 s (the servo watchdog is 100 ms).
    cfg.servo_link.a_to_b = FaultConfig::disconnect(500_000, 300_000);
    cfg.servo_link.b_to_a = FaultConfig::disconnect(500_000, 300_000);
    let mut targets_at = Vec::new();
    let seen = common::scripted(Some(&blob), &cfg, Robot::Red, 1_500_000, |w, pc, _| {
        let t = w.now_us;
        if t % 100_000 == 0 {
            pc.send_frame(w, None);
        }
        if t % 10_000 == 0 {
            targets_at.push((t, w.servos.counters().targets));
        }
        if t == 1_400_000 {
            w.host.send(&pc.port.encode(&HostToBoard::GetStatus));
        }
        Flow::Continue
    });
    assert!(errors(&seen.msgs).contains(&ErrorCode::ServoTimeout));
    assert_eq!(seen.status.servo_watchdog_trips, 1);
    let at = |t: u64| targets_at.iter().find(|(u, _)| *u == t).unwrap().1;
    assert!(at(500_000) > 0, "streaming before the outage");
    assert_eq!(
        at(800_000),
        at(500_000),
        "nothing arrives while the bus is dead"
    );
    assert!(at(1_400_000) > at(900_000), "streaming again after it");
    assert_eq!(seen.status.mode, Mode::Observe);
    assert_eq!(seen.world.servos.counters().limit_violations, 0);
}
