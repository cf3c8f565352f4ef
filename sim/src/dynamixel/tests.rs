use super::*;
use crate::servo::{ServoBus, ServoConfig};
use msr_shared::dynamixel::map::default_map;
use msr_shared::dynamixel::table::*;

fn bus(faults: Vec<DxlFault>) -> ServoBus {
    ServoBus::at_home(ServoConfig::default())
        .with_dynamixel(DxlConfig { faults, ..DxlConfig::default() })
        .unwrap()
}

/// Sends `packet` so that its last byte arrives at `end_us` (1 Mbaud: 10 us a byte), and runs
/// the bus at `now_us`.
fn send(bus: &mut ServoBus, packet: &[u8], end_us: u64, now_us: u64) -> Vec<(u64, Vec<u8>)> {
    let n = packet.len() as u64;
    let timed: Vec<(u64, u8)> =
        packet.iter().enumerate().map(|(i, &b)| (end_us + 10 * (i as u64 + 1) - 10 * n, b)).collect();
    bus.exchange(&timed, now_us)
}

fn enc(f: impl FnOnce(&mut [u8]) -> Result<usize, dxl::EncodeError>) -> Vec<u8> {
    let mut b = [0u8; 256];
    let n = f(&mut b).unwrap();
    b[..n].to_vec()
}

fn statuses(answers: &[(u64, Vec<u8>)]) -> Vec<(u8, u8, Vec<u8>)> {
    answers.iter().flat_map(|(_, b)| parse_status(b)).collect()
}

fn id(j: Joint) -> u8 {
    default_map().iter().find(|e| e.joint == j).unwrap().id
}

#[test]
fn ping_answers_model_and_firmware_after_the_return_delay() {
    let mut b = bus(vec![]);
    let a = send(&mut b, &enc(|w| dxl::ping(1, w)), 1_000, 1_000);
    assert_eq!(a.len(), 1);
    // 250 * 2 us after the last byte.
    assert_eq!(a[0].0, 1_500);
    let s = statuses(&a);
    assert_eq!(s, vec![(1, 0, vec![0xFC, 0x03, FIRMWARE])]); // 1020 = 0x03FC
    // An ID nobody has: silence.
    assert!(send(&mut b, &enc(|w| dxl::ping(99, w)), 2_000, 2_000).is_empty());
}

#[test]
fn reads_and_writes_the_control_table() {
    let mut b = bus(vec![]);
    let yaw = id(Joint::HeadYaw);
    // Present Position at home (yaw 0): the centre.
    let a = send(&mut b, &enc(|w| dxl::read(yaw, 132, 4, w)), 1_000, 1_000);
    assert_eq!(statuses(&a), vec![(yaw, 0, 2048u32.to_le_bytes().to_vec())]);
    // Model number and ID in one read.
    let a = send(&mut b, &enc(|w| dxl::read(yaw, 0, 8, w)), 2_000, 2_000);
    assert_eq!(statuses(&a)[0].2, vec![0xFC, 0x03, 0, 0, 0, 0, FIRMWARE, yaw]);
    // EEPROM with torque on: Access Error; with torque off: written, and read back.
    let lim = [2300u32.to_le_bytes(), 1800u32.to_le_bytes()].concat();
    let a = send(&mut b, &enc(|w| dxl::write(yaw, 48, &lim, w)), 3_000, 3_000);
    assert_eq!(statuses(&a), vec![(yaw, error::ACCESS, vec![])]);
    let a = send(&mut b, &enc(|w| dxl::write(yaw, 64, &[0], w)), 4_000, 4_000);
    assert_eq!(statuses(&a), vec![(yaw, 0, vec![])]);
    let limits = [2300u32.to_le_bytes(), 1800u32.to_le_bytes()].concat(); // Max 2300, Min 1800
    let a = send(&mut b, &enc(|w| dxl::write(yaw, 48, &limits, w)), 5_000, 5_000);
    assert_eq!(statuses(&a), vec![(yaw, 0, vec![])]);
    let a = send(&mut b, &enc(|w| dxl::read(yaw, 48, 8, w)), 6_000, 6_000);
    assert_eq!(statuses(&a)[0].2, limits);
    assert_eq!(b.dynamixel().unwrap().position_limits(Joint::HeadYaw), Some((1800, 2300)));
    // Half an item: Data Length Error; an unknown address: Access Error.
    let a = send(&mut b, &enc(|w| dxl::write(yaw, 116, &[1, 2], w)), 7_000, 7_000);
    assert_eq!(statuses(&a)[0].1, error::DATA_LENGTH);
    let a = send(&mut b, &enc(|w| dxl::write(yaw, 117, &[1], w)), 8_000, 8_000);
    assert_eq!(statuses(&a)[0].1, error::ACCESS);
    assert_eq!(b.dynamixel().unwrap().counters().limit_violations, 0);
}

#[test]
fn goals_move_the_joint_and_leaving_the_limits_is_refused_and_counted() {
    let mut b = bus(vec![]);
    let yaw = id(Joint::HeadYaw);
    let e = default_map()[0];
    // Torque off, limits [1800, 2300], torque on.
    send(&mut b, &enc(|w| dxl::write(yaw, 64, &[0], w)), 500, 1_000);
    let limits = [2300u32.to_le_bytes(), 1800u32.to_le_bytes()].concat();
    send(&mut b, &enc(|w| dxl::write(yaw, 48, &limits, w)), 1_500, 2_000);
    send(&mut b, &enc(|w| dxl::write(yaw, 64, &[1], w)), 2_500, 3_000);
    let goal = e.to_raw(0.3).unwrap() as u32;
    let sw = enc(|w| dxl::sync_write(116, 4, [(yaw, &goal.to_le_bytes()[..])], w));
    assert!(send(&mut b, &sw, 3_500, 4_000).is_empty(), "Sync Write is never answered");
    for t in (5_000..400_000).step_by(1_000) {
        b.exchange(&[], t);
    }
    assert!((b.position(Joint::HeadYaw) - 0.3).abs() < 2e-3, "{}", b.position(Joint::HeadYaw));
    let a = send(&mut b, &enc(|w| dxl::read(yaw, 132, 4, w)), 400_500, 401_000);
    let raw = u32::from_le_bytes(statuses(&a)[0].2[..].try_into().unwrap());
    assert!(raw.abs_diff(goal) <= 1, "{raw} vs {goal}");
    // Outside the servo's limits: refused with Data Limit Error, counted, not moved.
    let a = send(&mut b, &enc(|w| dxl::write(yaw, 116, &2400u32.to_le_bytes(), w)), 402_000, 402_000);
    assert_eq!(statuses(&a)[0].1, error::DATA_LIMIT);
    assert_eq!(b.dynamixel().unwrap().counters().limit_violations, 1);
    for t in (403_000..500_000).step_by(1_000) {
        b.exchange(&[], t);
    }
    assert!((b.position(Joint::HeadYaw) - 0.3).abs() < 2e-3);
}

#[test]
fn sync_read_answers_in_order_each_after_the_one_before() {
    let mut b = bus(vec![]);
    let ids: Vec<u8> = default_map().iter().map(|e| e.id).collect();
    let a = send(&mut b, &enc(|w| dxl::sync_read(132, 4, &ids, w)), 1_000, 1_000);
    assert_eq!(a.len(), ids.len());
    let s = statuses(&a);
    assert_eq!(s.iter().map(|s| s.0).collect::<Vec<_>>(), ids);
    // 15-byte statuses: each starts 500 us (return delay) after the one before it ends.
    let mut at = 1_000u64;
    for (t, bytes) in &a {
        assert_eq!(bytes.len(), 15);
        assert_eq!(*t, at + 500);
        at = t + 150;
    }
}

#[test]
fn a_silent_servo_silences_the_rest_of_a_sync_read_but_not_a_reordered_one() {
    let yaw = id(Joint::HeadYaw);
    let pitch = id(Joint::HeadPitch);
    let mut b = bus(vec![DxlFault::Silent { id: yaw, at_us: 5_000 }]);
    let sr = enc(|w| dxl::sync_read(132, 4, &[yaw, pitch], w));
    assert_eq!(send(&mut b, &sr, 1_000, 1_000).len(), 2);
    assert!(send(&mut b, &sr, 6_000, 6_000).is_empty());
    let sr = enc(|w| dxl::sync_read(132, 4, &[pitch, yaw], w));
    assert_eq!(statuses(&send(&mut b, &sr, 7_000, 7_000)).len(), 1);
    assert!(send(&mut b, &enc(|w| dxl::ping(yaw, w)), 8_000, 8_000).is_empty());
}

#[test]
fn an_overload_turns_the_torque_off_and_raises_the_alert() {
    let yaw = id(Joint::HeadYaw);
    let mut b = bus(vec![DxlFault::Overload { id: yaw, at_us: 2_000 }]);
    let a = send(&mut b, &enc(|w| dxl::read(yaw, 132, 4, w)), 1_000, 1_000);
    assert_eq!(statuses(&a)[0].1, 0);
    let a = send(&mut b, &enc(|w| dxl::read(yaw, 70, 1, w)), 3_000, 3_000);
    assert_eq!(statuses(&a), vec![(yaw, error::ALERT, vec![hw::OVERLOAD])]);
    assert_eq!(b.dynamixel().unwrap().torque(Joint::HeadYaw), Some(false));
    // Torque stays off until a reboot.
    send(&mut b, &enc(|w| dxl::write(yaw, 64, &[1], w)), 4_000, 4_000);
    assert_eq!(b.dynamixel().unwrap().torque(Joint::HeadYaw), Some(false));
}

#[test]
fn the_limits_are_the_joints_range_from_power_on() {
    let mut b = bus(vec![]);
    for e in default_map() {
        assert_eq!(b.dynamixel().unwrap().position_limits(e.joint), Some((e.raw_min, e.raw_max)));
        let a = send(&mut b, &enc(|w| dxl::read(e.id, 48, 8, w)), 1_000, 1_000);
        let want = [(e.raw_max as u32).to_le_bytes(), (e.raw_min as u32).to_le_bytes()].concat();
        assert_eq!(statuses(&a), vec![(e.id, 0, want)], "{:?}", e.joint);
    }
    // A goal one count past the range: Data Limit Error, counted, nothing moves.
    let e = default_map()[4];
    let a = send(&mut b, &enc(|w| dxl::write(e.id, 116, &(e.raw_max as u32 + 1).to_le_bytes(), w)), 2_000, 2_000);
    assert_eq!(statuses(&a), vec![(e.id, error::DATA_LIMIT, vec![])]);
    assert_eq!(b.dynamixel().unwrap().counters().goals, 0);
    assert_eq!(b.dynamixel().unwrap().counters().limit_violations, 1);
}

#[test]
fn a_joint_held_against_its_stop_overloads_after_the_stall_time() {
    let roll = default_map()[3];
    let mut b = bus(vec![]);
    // Limits widened past the stop, then a goal beyond it.
    send(&mut b, &enc(|w| dxl::write(roll.id, 64, &[0], w)), 500, 1_000);
    send(&mut b, &enc(|w| dxl::write(roll.id, 48, &4095u32.to_le_bytes(), w)), 1_500, 2_000);
    send(&mut b, &enc(|w| dxl::write(roll.id, 64, &[1], w)), 2_500, 3_000);
    let goal = (roll.raw_max + 200) as u32;
    let a = send(&mut b, &enc(|w| dxl::write(roll.id, 116, &goal.to_le_bytes(), w)), 3_500, 4_000);
    assert_eq!(statuses(&a), vec![(roll.id, 0, vec![])]);
    let limit = Joint::LShoulderRoll.limits().unwrap().max as f64;
    // At the stop in well under 0.5 s; no error while the stall is younger than the stall time.
    let mut t = 5_000;
    while t < 4_000 + STALL_OVERLOAD_US - 1_000 {
        b.exchange(&[], t);
        t += 1_000;
    }
    assert!((b.position(Joint::LShoulderRoll) - limit).abs() < 1e-9);
    assert_eq!(b.dynamixel().unwrap().hardware_error(Joint::LShoulderRoll), Some(0));
    assert_eq!(b.dynamixel().unwrap().torque(Joint::LShoulderRoll), Some(true));
    for t in (t..t + 600_000).step_by(1_000) {
        b.exchange(&[], t);
    }
    let d = b.dynamixel().unwrap();
    assert_eq!(d.hardware_error(Joint::LShoulderRoll), Some(hw::OVERLOAD));
    assert_eq!(d.torque(Joint::LShoulderRoll), Some(false));
    let a = send(&mut b, &enc(|w| dxl::read(roll.id, 70, 1, w)), 2_000_000, 2_000_000);
    assert_eq!(statuses(&a), vec![(roll.id, error::ALERT, vec![hw::OVERLOAD])]);
    // The other joints are fine; a goal inside the range never stalls.
    assert_eq!(b.dynamixel().unwrap().hardware_error(Joint::HeadYaw), Some(0));
}

#[test]
fn corrupted_packets_are_not_obeyed_nor_answered() {
    let mut b = bus(vec![]);
    let yaw = id(Joint::HeadYaw);
    let mut w = enc(|w| dxl::write(yaw, 116, &2500u32.to_le_bytes(), w));
    w[10] ^= 0x10;
    assert!(send(&mut b, &w, 1_000, 1_000).is_empty());
    assert_eq!(b.dynamixel().unwrap().rx_counters().crc_errors, 1);
    assert_eq!(b.dynamixel().unwrap().counters().goals, 0);
}

/// The firmware's board as bus master against the emulated servos, in the lock-step world.
mod with_the_board {
    use super::*;
    use crate::link::{FaultConfig, LinkConfig, LinkEnd};
    use crate::world::{run, Flow, World, WorldConfig};
    use msr_firmware::dynamixel::{Master, Stage};
    use msr_firmware::{Board, RamStore};
    use msr_shared::frame::{FrameAccumulator, MAX_WIRE_FRAME};
    use msr_shared::msg::{BoardToHost, ErrorCode, Mode};

    struct Run {
        world: World,
        board: Box<Board<RamStore<64>>>,
        errors: Vec<(u64, ErrorCode, u32)>,
        /// Goal Positions accepted by the servos, sampled every 10 ms.
        goals: Vec<(u64, u32)>,
    }

    fn run_board(faults: Vec<DxlFault>, servo_faults: FaultConfig, ms: u64) -> Run {
        run_board_on(DxlConfig { faults, ..DxlConfig::default() }, servo_faults, ms)
    }

    fn run_board_on(dxl: DxlConfig, servo_faults: FaultConfig, ms: u64) -> Run {
        let mut board = Box::new(Board::new(RamStore::<64>::new(None)));
        board.set_servo_bus(Some(Master::new()));
        let cfg = WorldConfig {
            servo_link: LinkConfig { baud: 1_000_000, a_to_b: servo_faults.clone(), b_to_a: servo_faults, seed: 3, ..Default::default() },
            dynamixel: Some(dxl),
            ..WorldConfig::default()
        };
        let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
        let mut errors = vec![];
        let mut goals = vec![];
        let (world, _) = {
            let b = &mut board;
            let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| b.poll(now, h, s);
            run(
                &cfg,
                &mut fw,
                |w: &mut World| {
                    for b in w.host.receive() {
                        if let Some(Ok(f)) = acc.push(b) {
                            if let Ok(BoardToHost::Error { code, detail }) = f.message() {
                                errors.push((w.now_us, code, detail));
                            }
                        }
                    }
                    if w.now_us.is_multiple_of(10_000) {
                        goals.push((w.now_us, w.servos.dynamixel().unwrap().counters().goals));
                    }
                    Flow::Continue
                },
                ms * 1000,
            )
            .unwrap()
        };
        Run { world, board, errors, goals }
    }

    fn goals_after(r: &Run, t_us: u64) -> u32 {
        let at = |t: u64| r.goals.iter().rev().find(|g| g.0 <= t).map_or(0, |g| g.1);
        at(u64::MAX) - at(t_us)
    }

    #[test]
    fn starts_up_writes_the_limits_and_streams_every_period() {
        let r = run_board(vec![], FaultConfig::default(), 1_000);
        let m = r.board.dynamixel().unwrap();
        assert_eq!(m.stage(), Stage::Running);
        let d = r.world.servos.dynamixel().unwrap();
        for e in default_map() {
            assert_eq!(d.position_limits(e.joint), Some((e.raw_min, e.raw_max)), "{:?}", e.joint);
            assert_eq!(d.torque(e.joint), Some(true));
        }
        assert_eq!(d.counters().limit_violations, 0);
        assert!(r.errors.is_empty(), "{:?}", r.errors);
        // About one Sync Write (5 goals) per period once running; the arm stays home.
        let g = goals_after(&r, 500_000);
        assert!((240..=255).contains(&g), "{g} goals in 500 ms");
        for (j, a) in msr_shared::joints::REACH_JOINTS.iter().zip(msr_shared::joints::HOME_POSTURE) {
            assert!((r.world.servos.position(*j) - a as f64).abs() < 2e-3, "{j:?}");
        }
        assert!(m.stats().iter().all(|s| s.timeouts == 0 && s.bad_answers == 0), "{:?}", m.stats());
        assert_eq!(r.board.status().servo_watchdog_trips, 0);
    }

    #[test]
    fn a_servo_missing_at_start_up_is_reported_and_nothing_is_written() {
        let r = run_board(vec![DxlFault::Silent { id: 4, at_us: 0 }], FaultConfig::default(), 2_500);
        let missing: Vec<_> = r.errors.iter().filter(|e| e.1 == ErrorCode::ServoMissing).collect();
        assert!(missing.len() >= 2 && missing.iter().all(|e| e.2 == 4), "{:?}", r.errors);
        let d = r.world.servos.dynamixel().unwrap();
        assert_eq!(d.counters().goals, 0);
        let yaw = default_map()[0];
        assert_eq!(d.position_limits(Joint::HeadYaw), Some((yaw.raw_min, yaw.raw_max)), "as at power-on");
        assert!(matches!(r.board.dynamixel().unwrap().stage(), Stage::Failed { .. }));
        assert!(r.board.commanded().is_none());
    }

    #[test]
    fn a_servo_that_stops_answering_stops_the_motion_and_is_reported() {
        let r = run_board(vec![DxlFault::Silent { id: 3, at_us: 500_000 }], FaultConfig::default(), 1_200);
        assert!(r.errors.iter().any(|e| e.1 == ErrorCode::ServoLost && e.2 == 3), "{:?}", r.errors);
        assert!(r.errors.iter().any(|e| e.1 == ErrorCode::ServoTimeout), "{:?}", r.errors);
        assert_eq!(r.board.status().servo_watchdog_trips, 1);
        assert_eq!(r.board.status().mode, Mode::Halted);
        // Streaming stopped within the watchdog's period (100 ms) and a period.
        assert_eq!(goals_after(&r, 620_000), 0);
        assert_eq!(r.world.servos.dynamixel().unwrap().counters().limit_violations, 0);
    }

    #[test]
    fn an_overload_is_reported_and_the_board_stops_sending_goals() {
        let r = run_board(vec![DxlFault::Overload { id: 6, at_us: 500_000 }], FaultConfig::default(), 1_000);
        let want = 6 | (hw::OVERLOAD as u32) << 8;
        assert!(r.errors.iter().any(|e| e.1 == ErrorCode::ServoFault && e.2 == want), "{:?}", r.errors);
        assert_eq!(r.board.status().mode, Mode::Halted);
        assert_eq!(goals_after(&r, 530_000), 0);
    }

    #[test]
    fn a_joint_driven_into_its_stop_overloads_and_the_board_reports_it() {
        // LShoulderRoll's horn sits 300 counts (0.46 rad) off where the board's map has it: the
        // board's home goal lands past the true stop, the joint stalls there, and after the
        // stall time the servo raises Overload; the board reports it and stops.
        let mut map = default_map().to_vec();
        let roll = &mut map[3];
        roll.zero += 300;
        roll.raw_min += 300;
        roll.raw_max = (roll.raw_max + 300).min(4095);
        let r = run_board_on(DxlConfig { map, ..DxlConfig::default() }, FaultConfig::default(), 1_500 + STALL_OVERLOAD_US / 1000);
        let id = default_map()[3].id as u32;
        let want = id | (hw::OVERLOAD as u32) << 8;
        let at: Vec<u64> = r.errors.iter().filter(|e| e.1 == ErrorCode::ServoFault && e.2 == want).map(|e| e.0).collect();
        assert!(!at.is_empty(), "{:?}", r.errors);
        assert!(at[0] >= STALL_OVERLOAD_US, "reported at {} us, before the stall time", at[0]);
        let d = r.world.servos.dynamixel().unwrap();
        assert_eq!(d.torque(Joint::LShoulderRoll), Some(false));
        assert_eq!(r.board.status().mode, Mode::Halted);
        // The goals past the true stop were counted as what they are.
        assert!(d.counters().limit_violations > 0);
    }

    #[test]
    fn bit_errors_on_the_bus_cost_answers_not_safety() {
        let r = run_board(vec![], FaultConfig::ber(1e-4), 5_000);
        let d = r.world.servos.dynamixel().unwrap();
        assert_eq!(d.counters().limit_violations, 0);
        assert_eq!(r.board.status().servo_watchdog_trips, 0);
        assert!(goals_after(&r, 1_000_000) > 1_900);
        // The faults were there: damaged packets on both sides.
        let board_rx = r.board.dynamixel().unwrap().rx_counters().errors();
        assert!(board_rx > 0 && d.rx_counters().errors() > 0, "{board_rx} {:?}", d.rx_counters());
        for (j, a) in msr_shared::joints::REACH_JOINTS.iter().zip(msr_shared::joints::HOME_POSTURE) {
            assert!((r.world.servos.position(*j) - a as f64).abs() < 2e-3, "{j:?}");
        }
    }
}
