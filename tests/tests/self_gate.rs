//! The self gate in-process, in the three scenes: the robot's own mirror image, another robot
//! of the same look with the mark on its face, and the mirror image through a video delay.
//! Few trials (CI has two cores); the 200-trial figures are in the README.
mod common;

use msr_host::episode::{self, Backend, EpisodeConfig, Scene, ServoBus, Summary, Trial};
use msr_host::train::self_gate::{attach, detach, GateCalibration};
use msr_sim::Robot;

fn gated(robot: Robot) -> (Vec<u8>, Vec<u8>) {
    let plain = common::trained_model(robot);
    let (gated, _) = attach(&plain, robot, &GateCalibration::default()).unwrap();
    (plain, gated)
}

fn run(blob: &[u8], scene: Scene, n: usize, seed: u64) -> (Summary, Vec<Trial>) {
    run_with(blob, scene, n, seed, |_| {})
}

/// [`run`] with the episodes' configuration changed by `set` (the servos, their bus).
fn run_with(blob: &[u8], scene: Scene, n: usize, seed: u64, set: impl FnOnce(&mut EpisodeConfig)) -> (Summary, Vec<Trial>) {
    let mut cfg = EpisodeConfig::new(Robot::Red);
    set(&mut cfg);
    cfg.no_mark_share = 0.0;
    cfg.scene = scene;
    cfg.parallel = 2;
    let trials = episode::run_inproc(blob, &cfg, n, seed, &|t| {
        eprintln!("{}", msr_host::cmd::mirror_test::describe(t))
    })
    .unwrap();
    let s = episode::summarise(Backend::Inproc, Robot::Red, cfg.servo_bus, &trials);
    eprintln!("{}", msr_host::cmd::mirror_test::readable(&s));
    (s, trials)
}

#[test]
fn switching_the_gate_off_gives_back_the_models_bytes() {
    let (plain, gated) = gated(Robot::Red);
    assert_ne!(plain, gated);
    assert_eq!(detach(&gated).unwrap(), plain);
    let g = msr_shared::blob::Model::parse(&gated).unwrap().self_gate.unwrap();
    // The own image's crop moves against the yaw by about the camera's focal length per radian.
    assert!((250.0..350.0).contains(&g.gain.abs()), "{g:?}");
}

#[test]
fn the_own_mirror_image_passes_and_is_touched_as_without_the_gate() {
    let (plain, gated) = gated(Robot::Red);
    let (off, _) = run(&plain, Scene::Mirror, 4, 11);
    let (on, trials) = run(&gated, Scene::Mirror, 4, 11);
    assert_eq!(on.scene, "mirror");
    assert_eq!(on.touched, off.touched, "{trials:#?}");
    assert!(on.touched >= 3);
    for t in trials.iter().filter(|t| t.reached) {
        assert_eq!(t.gate.last().map(|g| g.decision.as_str()), Some("pass"), "{t:#?}");
    }
    let (a, b) = (off.latency_ms_median.unwrap(), on.latency_ms_median.unwrap());
    // The probe: two poses and the rest, each held 250 ms after the servos report it reached
    // (`GateCalibration`'s settle wait; 100 ms left the own face moving) plus the turns.
    assert!(b > a && b <= a + 1750.0, "latency {a} ms without the gate, {b} ms with it");
}

/// Servos whose readings wander by a count or two while they hold still (encoder noise of
/// half a count RMS): the probe is centred where the head holds, not on a reading, so the
/// head does not move in pitch and its own image stays level.
#[test]
fn the_own_mirror_image_passes_with_noisy_encoders() {
    let (_, gated) = gated(Robot::Red);
    let (on, trials) = run_with(&gated, Scene::Mirror, 6, 11, |c| c.servo.encoder_noise = 0.5);
    assert_eq!(on.gate_rejects, 0, "{trials:#?}");
    assert!(on.touched >= 5, "{on:?}");
}

/// Pitch servos that hold six counts off their goals (gravity against a holding loop without
/// an integral term): the probe keeps the pitch where it was sent, and the gate, calibrated
/// over resting pitches too, passes the own image at the face's new sub-pixel height (with a
/// gate calibrated at pitch 0 alone, 4 of these 6 were refused on the level).
#[test]
fn the_own_mirror_image_passes_with_sagging_pitch_servos() {
    let (_, gated) = gated(Robot::Red);
    let (on, trials) = run_with(&gated, Scene::Mirror, 6, 11, |c| c.servo.sag = -6.0);
    assert_eq!(on.gate_rejects, 0, "{trials:#?}");
    assert!(on.touched >= 5, "{on:?}");
}

/// Servos that static friction stops two counts short of their goals, on the side they came
/// from (a holding loop without an integral term). The gate measures the span and the line the
/// board commanded; with poses approached from both sides it refused every own image (red 0 of
/// 173 in 200 trials at one count). Every pose is now approached from below, so each stops as
/// far short, and the rest is taken where the encoder says the head rested.
#[test]
fn the_own_mirror_image_passes_with_a_yaw_servo_held_short_by_friction() {
    let (_, gated) = gated(Robot::Red);
    let (on, trials) = run_with(&gated, Scene::Mirror, 6, 11, |c| c.servo.dead_band = 2.0);
    assert_eq!(on.gate_rejects, 0, "{trials:#?}");
    assert!(on.touched >= 5, "{on:?}");
}

/// A Dynamixel goes to whole encoder steps. With a probe amplitude of 0.07 rad (45.6 steps)
/// both poses rounded outwards to 46, and the span the head moved was 0.8 % wider than the one
/// the gate divides by (the own image read a gain ratio 1.1 % higher on that bus than on the
/// framed one, and with a sag of 3 counts 12 of 170 were refused). The default amplitude is
/// now a whole number of steps: the same gain on both buses.
#[test]
fn the_own_image_turns_with_the_same_gain_on_the_dynamixel_bus() {
    let (_, gated) = gated(Robot::Red);
    let mean_ratio = |bus: ServoBus| {
        let (on, trials) = run_with(&gated, Scene::Mirror, 6, 11, |c| c.servo_bus = bus);
        let r: Vec<f64> = trials.iter().flat_map(|t| &t.gate).filter_map(|g| g.gain_ratio).map(f64::from).collect();
        assert!(r.len() >= 4, "{on:?}");
        r.iter().sum::<f64>() / r.len() as f64
    };
    let (framed, dxl) = (mean_ratio(ServoBus::Framed), mean_ratio(ServoBus::Dynamixel));
    assert!((dxl - framed).abs() < 0.004, "gain ratio {dxl} on the Dynamixel bus, {framed} on the framed one");
}

/// Probes of the own image under a lamp switched 25-45 % stronger or weaker (what `--light
/// step` switches to), drawn with a seed of their own: shading moves the template's match
/// differently as the face turns, and the gain's spread grows by half. The gate calibrated
/// over varied light refuses fewer of them than one calibrated in the fixed light alone (in
/// the mirror trials under a lamp step: 1 own image refused in 173 against 3). These probes
/// rest anywhere within 0.01 rad of home (the encoder's rounding up to half a pixel in the
/// rest distance), so more are refused than in the trials, whose head rests at home.
#[test]
fn the_own_mirror_image_passes_more_often_under_a_lamp_switched_on_or_off() {
    use msr_sim::light::LightMode;
    let plain = common::trained_model(Robot::Red);
    let gate_of = |c: &GateCalibration| {
        let (blob, report) = attach(&plain, Robot::Red, c).unwrap();
        let gate = msr_shared::blob::Model::parse(&blob).unwrap().self_gate.unwrap();
        (gate, report)
    };
    let (varied, _) = gate_of(&GateCalibration::default());
    let (fixed, _) = gate_of(&GateCalibration { light: LightMode::Fixed, ..GateCalibration::default() });
    let (_, lamp) = gate_of(&GateCalibration { light: LightMode::Lamp, seed: 26, ..GateCalibration::default() });
    // The board's decision on each probe's statistics (`msr_firmware::self_gate::passes`).
    let refused = |g: &msr_shared::blob::SelfGate| {
        (0..lamp.gains.len())
            .filter(|&i| {
                let ratio = (lamp.gains[i] / g.gain as f64) as f32;
                let s = [lamp.rest_px[i], lamp.hold_px[i], lamp.level_px[i], lamp.line_px[i]].map(|v| v as f32);
                !msr_firmware::self_gate::passes(g, ratio, s[0], s[1], s[2], s[3])
            })
            .count()
    };
    let (v, f) = (refused(&varied), refused(&fixed));
    eprintln!("of {} probes under a lamp refused: {v} (varied-light gate {varied:?}), {f} (fixed-light gate {fixed:?})", lamp.gains.len());
    assert!(varied.gain_tol > fixed.gain_tol);
    assert!(v < f && v <= lamp.gains.len() / 12, "{v} against {f}");
}

/// Another robot that holds still moves in the picture with the camera's turn alone: a gain
/// 3-4 % off the own image's, the gate's only tell. Servos stopping half a count short on the
/// side they came from, with poses approached from both sides, shrank the probe's span by a
/// count in 91 and let that robot through (85 of 186 probes in 200 trials of one seed, red); every
/// pose approached from below keeps the span.
#[test]
fn another_robot_that_holds_still_is_not_reached_for_with_servos_held_short_by_friction() {
    let (_, gated) = gated(Robot::Red);
    let (on, trials) = run_with(&gated, Scene::Other, 8, 0, |c| c.servo.dead_band = 0.5);
    let still: Vec<_> = trials.iter().filter(|t| t.other_babbles == Some(false) && !t.gate.is_empty()).collect();
    assert!(still.len() >= 2, "{on:?}");
    for t in still {
        assert!(!t.reached, "{t:#?}");
    }
}

#[test]
fn a_delayed_picture_is_never_reached_for() {
    let (plain, gated) = gated(Robot::Red);
    let (on, trials) = run(&gated, Scene::Delayed, 4, 5);
    assert_eq!(on.reaches, 0, "{trials:#?}");
    assert!(on.gate_rejects >= 1);
    for t in &trials {
        assert!((300.0..=2000.0).contains(&t.delay_ms.unwrap()));
        assert!(t.gate.iter().all(|g| g.decision != "pass"), "{t:#?}");
    }
    // Without the gate the same picture's marks are reached for.
    let (off, _) = run(&plain, Scene::Delayed, 4, 5);
    assert!(off.reaches >= 1, "{off:?}");
}

#[test]
fn another_robot_that_holds_still_is_not_reached_for() {
    let (plain, gated) = gated(Robot::Red);
    let (off, _) = run(&plain, Scene::Other, 6, 0);
    let (on, trials) = run(&gated, Scene::Other, 6, 0);
    assert_eq!(on.scene, "other");
    assert!(off.reaches >= 1, "without the gate it reaches for the other's mark: {off:?}");
    for t in trials.iter().filter(|t| t.other_babbles == Some(false)) {
        assert!(!t.reached, "{t:#?}");
        assert!(!t.touched);
    }
    assert!(trials.iter().any(|t| t.other_babbles == Some(false) && !t.gate.is_empty()));
}
