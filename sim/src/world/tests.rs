use super::*;
use crate::link::FaultConfig;
use embedded_io::{Read as _, ReadReady as _, Write as _};
use msr_shared::frame::{encode_message_vec, FrameAccumulator, MAX_WIRE_FRAME};
use msr_shared::msg::{BoardToHost, BoardToServo, HostToBoard, JointTarget, ServoToBoard};

/// A scripted stand-in for the board: ramps HeadYaw to 0.3 rad in 10 ms steps, records the
/// servo reports it gets, answers pings on the host link.
#[derive(Default)]
struct FakeBoard {
    servo_rx: Option<Box<FrameAccumulator<MAX_WIRE_FRAME>>>,
    host_rx: Option<Box<FrameAccumulator<MAX_WIRE_FRAME>>>,
    reports: Vec<(u64, u32, f32)>,
    seq: u16,
    next_send_us: u64,
    /// Send one target outside the limits at this time.
    bad_at_us: Option<u64>,
}

impl FakeBoard {
    fn poll(&mut self, now: u64, host: &mut LinkEnd, servo: &mut LinkEnd) {
        let srx = self.servo_rx.get_or_insert_with(|| Box::new(FrameAccumulator::new()));
        let mut buf = [0u8; 64];
        while servo.read_ready().unwrap() {
            let n = servo.read(&mut buf).unwrap();
            for &b in &buf[..n] {
                if let Some(Ok(f)) = srx.push(b) {
                    if let Ok(ServoToBoard::States { time_ms, states }) = f.message() {
                        let yaw = states.iter().find(|s| s.joint == Joint::HeadYaw).unwrap().position;
                        self.reports.push((now, time_ms, yaw));
                    }
                }
            }
        }
        let hrx = self.host_rx.get_or_insert_with(|| Box::new(FrameAccumulator::new()));
        while host.read_ready().unwrap() {
            let n = host.read(&mut buf).unwrap();
            for &b in &buf[..n] {
                if let Some(Ok(f)) = hrx.push(b) {
                    if let Ok(HostToBoard::Ping { nonce }) = f.message() {
                        host.write_all(&encode_message_vec(0, &BoardToHost::Pong { nonce }).unwrap()).unwrap();
                    }
                }
            }
        }
        if now >= self.next_send_us {
            self.next_send_us = now + 10_000;
            let yaw = (now as f32 * 1e-6).min(0.3);
            let mut t = heapless::Vec::new();
            t.push(JointTarget { joint: Joint::HeadYaw, position: yaw }).unwrap();
            if self.bad_at_us.is_some_and(|b| now >= b) {
                self.bad_at_us = None;
                t.push(JointTarget { joint: Joint::HeadPitch, position: 1.0 }).unwrap();
            }
            let msg = BoardToServo::Targets { time_ms: (now / 1000) as u32, targets: t };
            self.seq = self.seq.wrapping_add(1);
            servo.write_all(&encode_message_vec(self.seq, &msg).unwrap()).unwrap();
        }
    }
}

/// Runs 600 ms with pings every 50 ms; returns the board, the world, and the pongs seen.
fn episode(cfg: &WorldConfig, bad_at_us: Option<u64>) -> (FakeBoard, World, Vec<(u64, u32)>, RunReport) {
    let mut board = FakeBoard { bad_at_us, ..Default::default() };
    let mut pongs = Vec::new();
    let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    let (world, report) = {
        let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| board.poll(now, h, s);
        run(
            cfg,
            &mut fw,
            |w: &mut World| {
                for b in w.host.receive() {
                    if let Some(Ok(f)) = acc.push(b) {
                        if let Ok(BoardToHost::Pong { nonce }) = f.message() {
                            pongs.push((w.now_us, nonce));
                        }
                    }
                }
                if w.now_us.is_multiple_of(50_000) {
                    let nonce = (w.now_us / 1000) as u32;
                    w.host.send(&encode_message_vec(0, &HostToBoard::Ping { nonce }).unwrap());
                }
                Flow::Continue
            },
            600_000,
        )
        .unwrap()
    };
    (board, world, pongs, report)
}

#[test]
fn a_fake_board_drives_the_servos_and_answers_the_host() {
    let (board, world, pongs, report) = episode(&WorldConfig::default(), None);
    assert_eq!(report.end_us, 600_000);
    // A report every 10 ms, each seen by the board shortly after it was sent.
    assert!(board.reports.len() >= 59, "{}", board.reports.len());
    for w in board.reports.windows(2) {
        assert_eq!(w[1].1 - w[0].1, 10);
    }
    for (seen, sent_ms, _) in &board.reports {
        assert!(*seen >= *sent_ms as u64 * 1000 && *seen <= *sent_ms as u64 * 1000 + 2000);
    }
    // The head followed the ramp and the encoder reading matches the world's position.
    let yaw = world.servos.position(Joint::HeadYaw);
    assert!((yaw - 0.3).abs() < 0.01, "{yaw}");
    let last = board.reports.last().unwrap().2 as f64;
    assert!((last - yaw).abs() < 0.01);
    assert_eq!(world.servos.counters().limit_violations, 0);
    // 12 pings (0..550 ms) and a pong within a couple of ticks of each.
    assert_eq!(pongs.len(), 12, "{pongs:?}");
    for (t, nonce) in &pongs {
        assert!(*t > *nonce as u64 * 1000 && *t <= *nonce as u64 * 1000 + 3000, "{t} {nonce}");
    }
    assert!(world.body_pose().head_yaw > 0.29);
}

#[test]
fn runs_are_reproducible_with_faults_and_seeds_matter() {
    let cfg = |seed| WorldConfig {
        host_link: LinkConfig { a_to_b: FaultConfig::ber(2e-3), b_to_a: FaultConfig::ber(2e-3), ..Default::default() },
        servo_link: LinkConfig { a_to_b: FaultConfig::ber(2e-3), b_to_a: FaultConfig::ber(2e-3), ..Default::default() },
        ..WorldConfig::default()
    }
    .seeded(seed);
    let (b1, w1, p1, _) = episode(&cfg(5), None);
    let (b2, w2, p2, _) = episode(&cfg(5), None);
    let (b3, _, _, _) = episode(&cfg(6), None);
    assert_eq!(b1.reports, b2.reports);
    assert_eq!(p1, p2);
    assert_eq!(w1.servos.position(Joint::HeadYaw), w2.servos.position(Joint::HeadYaw));
    assert_eq!(w1.servos.frame_counters(), w2.servos.frame_counters());
    assert_ne!(b1.reports, b3.reports);
    // Faults were there: some reports lost.
    assert!(b1.reports.len() < 60, "{}", b1.reports.len());
}

#[test]
fn an_unsafe_target_is_counted_and_a_disconnect_makes_the_servos_hold() {
    let (_, world, _, _) = episode(&WorldConfig::default(), Some(200_000));
    assert_eq!(world.servos.counters().limit_violations, 1);
    assert!(world.servos.position(Joint::HeadPitch).abs() < 1e-9);
    // Servo bus dead from 100 ms for 200 ms: no targets, so the servos hold after 100 ms.
    let cfg = WorldConfig {
        servo_link: LinkConfig { a_to_b: FaultConfig::disconnect(100_000, 200_000), ..Default::default() },
        ..WorldConfig::default()
    };
    let (board, world, _, _) = episode(&cfg, None);
    assert_eq!(world.servos.counters().hold_timeouts, 1);
    // While holding the head stood still; afterwards it followed the ramp again.
    let held: Vec<f32> = board.reports.iter().filter(|r| (210..300).contains(&r.1)).map(|r| r.2).collect();
    assert!(held.len() >= 8 && held.windows(2).all(|w| w[0] == w[1]), "{held:?}");
    assert!((world.servos.position(Joint::HeadYaw) - 0.3).abs() < 0.01);
}

#[test]
fn a_panicking_firmware_ends_the_run_with_an_error() {
    let mut fw = |now: u64, _: &mut LinkEnd, _: &mut LinkEnd| {
        if now == 5000 {
            panic!("boom");
        }
    };
    match run(&WorldConfig::default(), &mut fw, |_: &mut World| Flow::Continue, 1_000_000) {
        Err(RunError::FirmwarePanic { at_us, message }) => assert_eq!((at_us, message.as_str()), (5000, "boom")),
        other => panic!("{:?}", other.map(|r| r.1)),
    }
    let mut idle = |_: u64, _: &mut LinkEnd, _: &mut LinkEnd| {};
    let bad = WorldConfig { tick_us: 0, ..WorldConfig::default() };
    assert!(matches!(run(&bad, &mut idle, |_: &mut World| Flow::Continue, 10), Err(RunError::Config(_))));
}

#[test]
fn the_scenario_can_stop_the_run() {
    let mut idle = |_: u64, _: &mut LinkEnd, _: &mut LinkEnd| {};
    let (w, r) = run(&WorldConfig::default(), &mut idle, |w: &mut World| if w.now_us >= 42_000 { Flow::Stop } else { Flow::Continue }, 1_000_000).unwrap();
    assert_eq!((w.now_us, r.ticks), (42_000, 43));
}
