use super::*;
use msr_shared::frame::encode_message_vec;
use msr_shared::msg::JointTarget;

fn targets(t: &[(Joint, f32)]) -> Vec<u8> {
    let mut v = heapless::Vec::new();
    for &(joint, position) in t {
        v.push(JointTarget { joint, position }).unwrap();
    }
    encode_message_vec(0, &BoardToServo::Targets { time_ms: 0, targets: v }).unwrap()
}

fn bus() -> ServoBus {
    ServoBus::new(ServoConfig::default(), &[])
}

/// Runs the bus in 1 ms steps from `from` to `to`, collecting parsed reports.
fn run(bus: &mut ServoBus, from: u64, to: u64) -> Vec<(u32, Vec<JointState>)> {
    let mut acc = FrameAccumulator::<MAX_WIRE_FRAME>::new();
    let mut out = Vec::new();
    let mut t = from;
    while t <= to {
        if let Some(bytes) = bus.step(t) {
            for b in bytes {
                if let Some(Ok(f)) = acc.push(b) {
                    let ServoToBoard::States { time_ms, states } = f.message().unwrap();
                    out.push((time_ms, states.to_vec()));
                }
            }
        }
        t += 1000;
    }
    out
}

#[test]
fn velocity_limit_and_first_order_response() {
    let mut b = bus();
    b.receive(&targets(&[(Joint::HeadYaw, 1.0)]), 0);
    run(&mut b, 0, 50_000);
    // A big step saturates at 8.26797 rad/s: 0.4134 rad after 50 ms.
    let p = b.position(Joint::HeadYaw);
    assert!((p - 8.26797 * 0.05).abs() < 1e-6, "{p}");
    // A small step is first order: 1 - e^-1 = 63 % after one time constant (30 ms).
    let mut b = bus();
    b.receive(&targets(&[(Joint::HeadPitch, 0.02)]), 0);
    run(&mut b, 0, 30_000);
    let frac = b.position(Joint::HeadPitch) / 0.02;
    assert!((frac - 0.632).abs() < 0.03, "{frac}");
    run(&mut b, 31_000, 90_000);
    assert!((b.position(Joint::HeadPitch) - 0.02).abs() < 1e-3);
}

#[test]
fn limits_hold_and_encoder_is_12_bit() {
    let mut b = bus();
    let max = Joint::HeadPitch.limits().unwrap().max;
    b.receive(&targets(&[(Joint::HeadPitch, max)]), 0);
    for t in (0..=300_000).step_by(1000) {
        b.step(t);
        if t % 50_000 == 0 {
            b.receive(&targets(&[(Joint::HeadPitch, max)]), t);
        }
        assert!(b.position(Joint::HeadPitch) <= max as f64);
    }
    assert!((b.position(Joint::HeadPitch) - max as f64).abs() < 1e-4);
    assert_eq!(b.counters().limit_violations, 0);
    let lsb = std::f64::consts::TAU / 4096.0;
    let s = b.servo(Joint::HeadPitch).unwrap();
    let counts = s.measured() / lsb;
    assert!((counts - counts.round()).abs() < 1e-9);
    assert!((s.measured() - s.position).abs() <= lsb / 2.0 + 1e-12);
    assert_eq!(quantise(0.7 * lsb), lsb);
    assert_eq!(quantise(0.4 * lsb), 0.0);
}

#[test]
fn reports_every_10_ms_with_every_joint() {
    let mut b = ServoBus::at_home(ServoConfig::default());
    let reports = run(&mut b, 0, 99_000);
    let times: Vec<u32> = reports.iter().map(|r| r.0).collect();
    assert_eq!(times, (0..10).map(|i| i * 10).collect::<Vec<_>>());
    let (_, states) = &reports[0];
    assert_eq!(states.len(), 12);
    let ids: Vec<Joint> = states.iter().map(|s| s.joint).collect();
    assert_eq!(ids, bus_joints());
    let ser = states.iter().find(|s| s.joint == Joint::LElbowRoll).unwrap();
    assert!((ser.position as f64 - crate::kin::home()[4]).abs() < 0.002);
    // A state request is answered at once.
    b.receive(&encode_message_vec(1, &BoardToServo::StateRequest).unwrap(), 100_500);
    assert!(b.step(100_500).is_some());
}

#[test]
fn holds_when_targets_stop_and_stiffness_gates_motion() {
    let mut b = bus();
    b.receive(&targets(&[(Joint::LShoulderPitch, 2.0)]), 0);
    // Low velocity so that the move outlasts the 100 ms hold timeout.
    let reports = run(&mut b, 0, 100_000);
    let at_hold = b.position(Joint::LShoulderPitch);
    assert!(at_hold < 2.0 - 0.5 && at_hold > 0.5, "{at_hold}");
    run(&mut b, 101_000, 300_000);
    assert!((b.position(Joint::LShoulderPitch) - at_hold).abs() < 0.02, "kept moving after the hold");
    assert_eq!(b.counters().hold_timeouts, 1);
    let last = run(&mut b, 310_000, 310_000);
    let s = last[0].1.iter().find(|s| s.joint == Joint::LShoulderPitch).unwrap();
    assert!(s.faults & fault::TIMEOUT != 0);
    assert!(reports[0].1.iter().all(|s| s.faults == 0));
    // A new target clears the flag.
    b.receive(&targets(&[(Joint::LShoulderPitch, 0.0)]), 320_000);
    assert_eq!(b.servo(Joint::LShoulderPitch).unwrap().faults, 0);

    // Limp: targets are taken but nothing moves; stiff again: holds where it is.
    let mut b = bus();
    b.receive(&encode_message_vec(0, &BoardToServo::Stiffness { on: false }).unwrap(), 0);
    b.receive(&targets(&[(Joint::HeadYaw, 0.5)]), 0);
    run(&mut b, 0, 50_000);
    assert_eq!(b.position(Joint::HeadYaw), 0.0);
    assert!(!b.servo(Joint::HeadYaw).unwrap().stiff);
    b.receive(&encode_message_vec(1, &BoardToServo::Stiffness { on: true }).unwrap(), 50_000);
    run(&mut b, 50_000, 90_000);
    assert_eq!(b.position(Joint::HeadYaw), 0.0);
}

#[test]
fn unsafe_targets_are_counted_and_refused() {
    let mut b = bus();
    b.receive(&targets(&[(Joint::HeadPitch, 0.6), (Joint::HeadYaw, 0.1)]), 0);
    b.receive(&targets(&[(Joint::LElbowRoll, f32::NAN)]), 0);
    b.receive(&targets(&[(Joint::LHand, 0.5)]), 0);
    b.receive(&targets(&[(Joint::LKneePitch, 0.0)]), 0);
    assert_eq!(b.counters().limit_violations, 4);
    assert_eq!(b.counters().targets, 1);
    assert_eq!(b.servo(Joint::HeadPitch).unwrap().target, 0.0);
    assert!(b.servo(Joint::HeadPitch).unwrap().faults & fault::LIMIT != 0);
    assert!(b.servo(Joint::LElbowRoll).unwrap().target.is_finite());
    run(&mut b, 0, 50_000);
    assert!(b.position(Joint::HeadPitch).abs() < 1e-12);
    assert!(b.position(Joint::HeadYaw) > 0.07); // 81 % of the way after 50 ms
}

#[test]
fn frame_errors_are_not_violations() {
    let mut b = bus();
    let good = targets(&[(Joint::HeadYaw, 0.2)]);
    let mut flipped = good.clone();
    flipped[3] ^= 0x10;
    b.receive(&flipped, 0);
    b.receive(&[0x55, 0x13, 0xFF, 0x00], 0);
    // A valid frame whose payload is not a servo message.
    let mut raw = [0u8; MAX_WIRE_FRAME];
    let n = msr_shared::frame::encode_payload(5, &[0x7F, 1, 2], &mut raw).unwrap();
    b.receive(&raw[..n], 0);
    b.receive(&good, 0);
    let c = b.frame_counters();
    assert_eq!(c.frames, 2, "{c:?}");
    assert_eq!(c.resyncs(), 3, "{c:?}");
    assert_eq!(c.malformed, 1);
    assert_eq!(b.counters().limit_violations, 0);
    assert_eq!(b.counters().targets, 1);
}

#[test]
fn odd_start_angles_are_clamped() {
    let b = ServoBus::new(ServoConfig::default(), &[(Joint::HeadPitch, f64::NAN), (Joint::HeadYaw, 9.0), (Joint::LElbowRoll, 0.0)]);
    assert_eq!(b.position(Joint::HeadPitch), 0.0);
    assert_eq!(b.position(Joint::HeadYaw), Joint::HeadYaw.limits().unwrap().max as f64);
    assert_eq!(b.position(Joint::LElbowRoll), Joint::LElbowRoll.limits().unwrap().max as f64);
}

/// Encoder noise: a servo holding still reads the counts around its position by turns, the
/// reports' mean within a tenth of a count of the true position (the noise dithers the
/// rounding), the same draws for the same seed; none by default.
#[test]
fn encoder_noise_makes_a_still_servo_read_the_counts_around_it() {
    let readings = |noise: f64, seed: u64| {
        let cfg = ServoConfig { encoder_noise: noise, noise_seed: seed, ..ServoConfig::default() };
        // 0.3 of a count past a count: its nearest count when read without noise.
        let yaw = (100.0 + 0.3) * COUNT_RAD;
        let mut b = ServoBus::new(cfg, &[(Joint::HeadYaw, yaw)]);
        let reports = run(&mut b, 0, 9_990_000);
        assert_eq!(b.position(Joint::HeadYaw), yaw, "noise moved the servo");
        reports
            .iter()
            .map(|(_, s)| {
                let p = s.iter().find(|s| s.joint == Joint::HeadYaw).unwrap().position as f64;
                (p / COUNT_RAD).round() as i32
            })
            .collect::<Vec<i32>>()
    };
    assert!(readings(0.0, 1).iter().all(|&c| c == 100));
    let r = readings(0.5, 1);
    let mean = r.iter().sum::<i32>() as f64 / r.len() as f64;
    assert!((mean - 100.3).abs() < 0.1, "mean reading {mean} counts");
    for c in [99, 100, 101] {
        assert!(r.contains(&c), "never read {c}");
    }
    assert!(r.iter().all(|c| (98..=102).contains(c)));
    assert_eq!(r, readings(0.5, 1));
    assert_ne!(r, readings(0.5, 2));
}

/// Sag: a pitch servo holds that many counts off its goal, wherever it is sent (the head's and
/// the shoulders'), the other joints where they are sent; none by default.
#[test]
fn a_sagging_pitch_servo_holds_off_its_goal_by_the_counts_given() {
    let hold = |sag: f64| {
        let cfg = ServoConfig { sag, ..ServoConfig::default() };
        let mut b = ServoBus::new(cfg, &[]);
        let goal = 40.0 * COUNT_RAD;
        let mut reports = Vec::new();
        // Sent again every 50 ms (the hold timeout is 100 ms), for ten time constants.
        for t in (0..300_000).step_by(50_000) {
            b.receive(&targets(&[(Joint::HeadPitch, goal as f32), (Joint::HeadYaw, goal as f32), (Joint::LShoulderPitch, goal as f32)]), t);
            reports = run(&mut b, t, t + 49_000);
        }
        let read = |j: Joint| {
            let s = reports.last().unwrap().1.iter().find(|s| s.joint == j).unwrap().position as f64;
            (s / COUNT_RAD).round() as i32
        };
        let off = |j: Joint| (b.position(j) - goal as f32 as f64) / COUNT_RAD;
        (read(Joint::HeadPitch), read(Joint::HeadYaw), read(Joint::LShoulderPitch), off(Joint::HeadPitch), off(Joint::HeadYaw))
    };
    let (pitch, yaw, shoulder, p_off, y_off) = hold(0.0);
    assert_eq!((pitch, yaw, shoulder), (40, 40, 40));
    assert!(p_off.abs() < 0.01 && y_off.abs() < 0.01);
    let (pitch, yaw, shoulder, p_off, y_off) = hold(3.0);
    assert_eq!((pitch, yaw, shoulder), (43, 40, 43));
    assert!((p_off - 3.0).abs() < 0.05 && y_off.abs() < 0.01, "{p_off} {y_off}");
    let (pitch, _, shoulder, _, _) = hold(-5.0);
    assert_eq!((pitch, shoulder), (35, 35));
}

/// Static friction: a servo stops where its drive falls under the friction, the dead band's
/// counts short of its goal on the side it came from, and stays there; none by default.
#[test]
fn a_servo_with_a_dead_band_stops_short_of_its_goal_on_the_side_it_came_from() {
    let stop = |dead_band: f64, from: f64| {
        let cfg = ServoConfig { dead_band, ..ServoConfig::default() };
        let mut b = ServoBus::new(cfg, &[]);
        let mut t = 0;
        for goal in [from, 0.0] {
            for _ in 0..6 {
                b.receive(&targets(&[(Joint::HeadYaw, (goal * COUNT_RAD) as f32)]), t);
                run(&mut b, t, t + 49_000);
                t += 50_000;
            }
        }
        b.position(Joint::HeadYaw) / COUNT_RAD
    };
    assert!(stop(0.0, 40.0).abs() < 0.01);
    let (above, below) = (stop(2.0, 40.0), stop(2.0, -40.0));
    assert!((1.9..=2.0).contains(&above), "{above}");
    assert!((-2.0..=-1.9).contains(&below), "{below}");
    // A goal within the dead band does not move it.
    assert!((stop(2.0, 1.5)).abs() < 1e-9);
}
