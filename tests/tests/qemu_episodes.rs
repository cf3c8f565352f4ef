//! Mirror-test episodes with the real thumbv7em firmware image in QEMU (mps2-an386): the sim's
//! host link and servo bus bridged to the board's UART0 and UART1, the board's clock driven by
//! the sim (lockstep: each tick's bytes through the image's pipe). The same trials run in-process must come out the same, field for
//! field: the same firmware, the same world, one clock.
//!
//! Skips with a message when `qemu-system-arm` or the board image is missing (the image is built
//! by `cargo xtask test` / `cargo xtask images`).
//!
//! The model is the demo's kind, a small convolutional decoder, preloaded into the board's
//! memory by QEMU's loader ([`QemuBoard::start`]); uploads over the host link have their tests
//! with `msr serve` (`flash_cli`, `upload_cli`) and in `qemu_firmware` and `qemu_flash`.

mod common;

use common::conv_model;
use msr_host::episode::{self, Camera, EpisodeConfig, Trial};
use msr_host::episode::qemu::QemuBoard;
use msr_sim::qemu;
use msr_sim::render::Renderer;
use msr_sim::Robot;


fn available() -> bool {
    if !qemu::qemu_available() {
        eprintln!("SKIPPED: {} not found; install qemu-system-arm to run the QEMU episodes", qemu::qemu_binary());
        return false;
    }
    if let Err(e) = qemu::find_image(qemu::BOARD_IMAGE) {
        eprintln!("SKIPPED: {e:#}");
        return false;
    }
    true
}

/// What a trial's camera is made of: the blob's face cropper and the robot's renderer.
fn camera_parts(blob: &[u8], robot: Robot) -> (msr_host::data::crop::Cropper, Renderer) {
    let model = msr_shared::blob::Model::parse(blob).unwrap();
    (msr_host::detect::cropper_of(&model).unwrap(), Renderer::new(robot))
}

/// A trial without its wall time: everything else must be the same on both backends.
fn outcome(t: &Trial) -> serde_json::Value {
    let mut v = serde_json::to_value(t).unwrap();
    v.as_object_mut().unwrap().remove("wall_s");
    v
}

#[test]
fn qemu_episodes_touch_marks_and_match_in_process() {
    if !available() {
        return;
    }
    let robot = Robot::Red;
    let blob = conv_model(robot);
    let (cropper, renderer) = camera_parts(&blob, robot);
    let mut marked = EpisodeConfig::new(robot);
    marked.no_mark_share = 0.0;
    let mut unmarked = EpisodeConfig::new(robot);
    unmarked.no_mark_share = 1.0;
    unmarked.watch_us = 2_000_000;
    // Both links cut for 200 ms while the robot watches: both watchdogs trip, the board recovers.
    let cut = marked.clone().with_disconnect(300_000, 200_000);
    // The same board on the Dynamixel bus (the PC switches it over the host link): UART1
    // carries Protocol 2.0 to the emulated servos.
    let mut dxl = marked.clone();
    dxl.servo_bus = episode::ServoBus::Dynamixel;
    // Under changing light: a lamp switched and the exposure drifting (the photometric fit and
    // the room's learning run on the board as in-process).
    let mut step = marked.clone();
    step.light = msr_sim::light::LightPlan::Step;
    let mut drift = unmarked.clone();
    drift.light = msr_sim::light::LightPlan::Drift;
    // Three clean marked trials, one without a mark and one with the cut, on one QEMU (a reset
    // between trials).
    let plan = [(&marked, 0usize), (&marked, 1), (&unmarked, 2), (&cut, 3), (&marked, 4), (&dxl, 5), (&step, 6), (&drift, 7)];

    let mut board = QemuBoard::start(&blob).unwrap();
    eprintln!("QEMU running the preloaded model ({} bytes) after {:.1} s", blob.len(), board.start_s);
    let mut qemu_trials = Vec::new();
    for (cfg, i) in plan {
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let t = board.trial(camera, cfg, i, episode::trial_seed(7, i)).unwrap();
        eprintln!("qemu:    {}", msr_host::cmd::mirror_test::describe(&t));
        qemu_trials.push(t);
    }
    let output = board.finish().unwrap();
    eprintln!("{output}");

    for ((cfg, i), q) in plan.iter().zip(&qemu_trials) {
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let t = episode::run_trial_inproc(&blob, camera, cfg, *i, episode::trial_seed(7, *i)).unwrap();
        eprintln!("inproc:  {}", msr_host::cmd::mirror_test::describe(&t));
        // Same firmware (bit-exact builds), same world, one clock: the same trial, to the bit.
        assert_eq!(outcome(q), outcome(&t), "trial {i}: QEMU and in-process differ");
    }

    // Reaches that end on the mark (the small model misses a mark now and then).
    let touched = qemu_trials.iter().filter(|t| t.touch_error_mm.is_some_and(|e| e < 21.0)).count();
    assert!(touched >= 3, "{touched} of 4 marked trials touched: {qemu_trials:#?}");
    let no_mark = &qemu_trials[2];
    assert!(no_mark.mark.is_none(), "{no_mark:#?}");
    assert!(!no_mark.reached && !no_mark.false_reach, "a reach without a mark: {no_mark:#?}");
    assert!(no_mark.frames_sent >= 20, "frames kept flowing: {no_mark:#?}");
    let cut = &qemu_trials[3];
    assert!(cut.watchdog_trips >= 1, "a 200 ms cut trips the watchdogs: {cut:#?}");
    for t in &qemu_trials {
        assert_eq!(t.limit_violations, 0, "{t:#?}");
    }
    for t in qemu_trials.iter().filter(|t| t.index != 3) {
        assert_eq!((t.crc_errors, t.resyncs, t.watchdog_trips), (0, 0, 0), "clean links, one clock: {t:#?}");
    }
    assert!(output.contains("servo_watchdog_trips: 0"), "{output}");
}

/// A QEMU trial logged for `--mcap` ends with the board's status on `/board/status`, as an
/// in-process trial's does.
#[test]
fn qemu_trial_log_has_the_board_status() {
    if !available() {
        return;
    }
    let robot = Robot::Red;
    let blob = conv_model(robot);
    let (cropper, renderer) = camera_parts(&blob, robot);
    let mut cfg = EpisodeConfig::new(robot);
    cfg.no_mark_share = 1.0;
    cfg.watch_us = 500_000;
    cfg.mcap = Some(msr_host::rosbag::session::LogModel(blob.clone().into()));
    let mut board = QemuBoard::start(&blob).unwrap();
    let t = board.trial(Camera { renderer: &renderer, cropper: &cropper }, &cfg, 0, episode::trial_seed(3, 0)).unwrap();
    board.finish().unwrap();
    let log = t.log.expect("a log with --mcap");
    let status: Vec<_> = log.msgs.iter().filter(|m| m.topic == "/board/status").collect();
    assert_eq!(status.len(), 1, "one status at the trial's end");
    let d: msr_host::rosbag::msgs::DiagnosticArray = msr_host::rosbag::msgs::decode(&status[0].cdr).unwrap();
    assert!(d.status[0].values.iter().any(|kv| kv.key == "frames"), "{d:?}");
}

/// The way in of every QEMU trial: the model preloaded into the board's PSRAM by QEMU's generic
/// loader, taken at start-up through the upload's checks. It runs (the same trials as
/// in-process), survives the resets between trials, and damaged bytes are refused by the board.
#[test]
fn qemu_preloaded_model_runs_and_a_damaged_one_is_refused() {
    if !available() {
        return;
    }
    let robot = Robot::Red;
    let blob = conv_model(robot);
    let (cropper, renderer) = camera_parts(&blob, robot);
    let mut cfg = EpisodeConfig::new(robot);
    cfg.no_mark_share = 0.0;

    let mut board = QemuBoard::start(&blob).unwrap();
    eprintln!("QEMU running the preloaded model ({} bytes) after {:.1} s", blob.len(), board.start_s);
    let mut qemu_trials = Vec::new();
    for i in 0..2 {
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        qemu_trials.push(board.trial(camera, &cfg, i, episode::trial_seed(7, i)).unwrap());
    }
    let output = board.finish().unwrap();
    eprintln!("{output}");
    assert!(output.contains(&format!("preloaded model accepted, crc {:#010x}", msr_shared::blob::Model::parse(&blob).unwrap().crc32)), "{output}");
    // Each trial's reset finds the model in the slots and leaves the preload alone.
    assert_eq!(output.matches("preloaded model left alone").count(), 2, "{output}");
    for (i, q) in qemu_trials.iter().enumerate() {
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let t = episode::run_trial_inproc(&blob, camera, &cfg, i, episode::trial_seed(7, i)).unwrap();
        assert_eq!(outcome(q), outcome(&t), "trial {i}: QEMU (preloaded) and in-process differ");
    }

    let image = qemu::find_image(qemu::BOARD_IMAGE).unwrap();
    // One byte of the blob changed after its header was made: the CRC-32 check refuses it.
    let mut flipped = qemu::preload_bytes(&blob);
    flipped[16 + blob.len() / 2] ^= 0x10;
    // A truncated blob under a header that matches it: the CRC passes, validation refuses it.
    let truncated = qemu::preload_bytes(&blob[..blob.len() - 100]);
    // A header whose check word does not match: not a preload at all.
    let mut bad_header = qemu::preload_bytes(&blob);
    bad_header[12] ^= 1;
    for (bytes, said) in [
        (&flipped, "preloaded model refused: Crc"),
        (&truncated, "preloaded model refused: Invalid("),
        (&bad_header, "msr-qemu: ready; built-in model 0 bytes; model in use crc 0x00000000"),
    ] {
        let (ls, crc) = qemu::Lockstep::start_with(&image, Some(bytes)).unwrap();
        assert_eq!(crc, 0, "the board runs no model");
        let exit = ls.exit(std::time::Duration::from_secs(10)).unwrap();
        assert!(exit.output.contains(said), "expected {said:?} in:\n{}", exit.output);
    }
    // The host refuses a blob that does not parse before starting QEMU.
    let e = QemuBoard::start(&blob[..blob.len() - 100]).err().expect("refused");
    assert!(format!("{e:#}").contains("model blob"), "{e:#}");
}

/// The first trials (of seed 7) in `scene` whose scene draw satisfies `pick`, as (index, seed).
fn trials_where(scene: episode::Scene, n: usize, pick: impl Fn(&episode::scene::SceneState) -> bool) -> Vec<(usize, u64)> {
    use rand::SeedableRng;
    (0..200)
        .map(|i| (i, episode::trial_seed(7, i)))
        .filter(|&(_, seed)| {
            // The scene's own stream, as `episode` draws it.
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(2);
            pick(&episode::scene::SceneState::new(scene, rng))
        })
        .take(n)
        .collect()
}

#[test]
fn qemu_self_gate_refuses_another_robot_and_a_delayed_picture() {
    use episode::Scene;
    if !available() {
        return;
    }
    let robot = Robot::Red;
    let (blob, _) = msr_host::train::self_gate::attach(&conv_model(robot), robot, &Default::default()).unwrap();
    let (cropper, renderer) = camera_parts(&blob, robot);
    let scene = |s: Scene| {
        let mut c = EpisodeConfig::new(robot);
        c.no_mark_share = 0.0;
        c.scene = s;
        // The mark, its confirmation (after the delay), one probe (two poses and the return to
        // the rest, each held 250 ms after the servos report it: 1.6 s) and its refusal fit in
        // 3.5 s.
        c.watch_us = 3_500_000;
        c
    };
    let (other, delayed) = (scene(Scene::Other), scene(Scene::Delayed));
    // A babbling robot and a delay of 0.5 to 0.7 s (two trials: about 15 s of wall time each
    // on an idle CI machine; a robot holding still and longer delays are in tests/self_gate.rs).
    let mut plan: Vec<(&EpisodeConfig, usize, u64)> = Vec::new();
    plan.extend(trials_where(Scene::Other, 1, |s| s.babbles).into_iter().map(|(i, s)| (&other, i, s)));
    let short = |s: &episode::scene::SceneState| (500_000..=700_000).contains(&s.delay_us);
    plan.extend(trials_where(Scene::Delayed, 1, short).into_iter().map(|(i, s)| (&delayed, i, s)));
    assert_eq!(plan.len(), 2);

    let mut board = QemuBoard::start(&blob).unwrap();
    let mut qemu_trials = Vec::new();
    for &(cfg, i, seed) in &plan {
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let t = board.trial(camera, cfg, i, seed).unwrap();
        eprintln!("qemu:    {}", msr_host::cmd::mirror_test::describe(&t));
        qemu_trials.push(t);
    }
    board.finish().unwrap();
    for (&(cfg, i, seed), q) in plan.iter().zip(&qemu_trials) {
        // The gate decided on the real image as in-process, to the bit.
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let t = episode::run_trial_inproc(&blob, camera, cfg, i, seed).unwrap();
        assert_eq!(outcome(q), outcome(&t), "trial {i}: QEMU and in-process differ");
        assert!(!q.reached && !q.false_reach, "{q:#?}");
        // The mark was seen and the gate asked (and refused), not a mark missed.
        assert!(!q.gate.is_empty() && q.gate.iter().all(|g| g.decision == "reject"), "{q:#?}");
    }
}
