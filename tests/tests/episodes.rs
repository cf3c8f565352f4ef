//! Mirror-test episodes in-process: the sim world, the emulated host link and servo bus, the
//! firmware's `Board` on its own thread; clean links and faulty ones.
mod common;

use msr_host::episode::{self, Backend, EpisodeConfig, Summary, Trial};
use msr_sim::link::FaultConfig;
use msr_sim::Robot;

fn run(robot: Robot, cfg: &EpisodeConfig, n: usize, seed: u64) -> (Summary, Vec<Trial>) {
    let blob = common::trained_model(robot);
    let trials = episode::run_inproc(&blob, cfg, n, seed, &|t| eprintln!("{}", msr_host::mirror_test::describe(t))).unwrap();
    let s = episode::summarise(Backend::Inproc, robot, &trials);
    eprintln!("{}", msr_host::mirror_test::readable(&s));
    (s, trials)
}

fn marked_only(robot: Robot) -> EpisodeConfig {
    let mut c = EpisodeConfig::new(robot);
    c.no_mark_share = 0.0;
    c
}

fn check_touches(robot: Robot) {
    let (s, trials) = run(robot, &marked_only(robot), 6, 11);
    assert_eq!(s.marked_trials, 6);
    assert!(s.touched >= 5, "{s:?}\n{trials:#?}");
    assert_eq!(s.limit_violations, 0);
    assert_eq!(s.false_reaches, 0);
    assert!(s.median_touch_error_mm.unwrap() < 20.0);
    // The reach starts after K = 3 confirming frames at 10 frames a second.
    let lat = s.latency_ms_median.unwrap();
    assert!((150.0..1500.0).contains(&lat), "{lat}");
    assert_eq!((s.crc_errors, s.resyncs, s.watchdog_trips), (0, 0, 0), "clean links");
}

#[test]
fn red_robot_touches_its_marks() {
    check_touches(Robot::Red);
}

#[test]
fn skin_robot_touches_its_marks() {
    check_touches(Robot::Skin);
}

#[test]
fn no_mark_no_reach() {
    let mut c = EpisodeConfig::new(Robot::Red);
    c.no_mark_share = 1.0;
    c.watch_us = 2_000_000;
    let (s, trials) = run(Robot::Red, &c, 4, 5);
    assert_eq!(s.no_mark_trials, 4);
    assert_eq!(s.false_reaches, 0, "{trials:#?}");
    assert!(trials.iter().all(|t| t.frames_sent >= 20), "frames kept flowing");
}

#[test]
fn bit_errors_are_counted_and_never_unsafe() {
    for ber in [1e-4, 1e-3] {
        let c = marked_only(Robot::Red).with_ber(ber);
        let (s, _) = run(Robot::Red, &c, 3, 21);
        assert_eq!(s.limit_violations, 0, "ber {ber}");
        assert!(s.crc_errors > 0 && s.resyncs >= s.crc_errors, "ber {ber}: {s:?}");
        assert!(s.touched >= 2, "ber {ber}: the robot still works: {s:?}");
    }
}

#[test]
fn bursts_are_resynchronised_past() {
    let mut c = marked_only(Robot::Red);
    let burst = FaultConfig { burst_rate: 2e-4, burst_len: 16, ..Default::default() };
    c.host_faults = burst.clone();
    c.servo_faults = burst;
    let (s, _) = run(Robot::Red, &c, 3, 31);
    assert_eq!(s.limit_violations, 0);
    assert!(s.resyncs > 0, "{s:?}");
    assert!(s.touched >= 2, "{s:?}");
}

#[test]
fn a_200_ms_disconnect_trips_the_servo_watchdog_and_recovers() {
    // Both links cut for 200 ms during the reach: the servo watchdog (100 ms) trips, the board
    // stops streaming, and when the servos answer again it goes home and observes again; the
    // mark is still there, so it reaches again and touches.
    let mut c = marked_only(Robot::Red).with_disconnect(1_200_000, 200_000);
    c.watch_us = 8_000_000;
    let (s, trials) = run(Robot::Red, &c, 3, 41);
    assert_eq!(s.limit_violations, 0);
    assert!(s.watchdog_trips >= 3, "{s:?}");
    assert!(s.touched >= 2, "{s:?}\n{trials:#?}");
}
