//! Mirror-test episodes with the real thumbv7em firmware image in QEMU (mps2-an386): the sim's
//! host link and servo bus bridged to the board's UART0 and UART1, the board's clock driven by
//! the sim (lockstep on UART2). The same trials run in-process must come out the same, field for
//! field: the same firmware, the same world, one clock.
//!
//! Skips with a message when `qemu-system-arm` or the board image is missing (the image is built
//! by `cargo xtask test` / `cargo xtask images`).
//!
//! The model is the demo's kind, a small convolutional decoder (about 180 KB): QEMU's emulated
//! UART takes 20 to 40 KB/s, so the shared test model (the fully connected decoder, 1.2 MB) would
//! spend a minute uploading.

use msr_host::episode::{self, Camera, EpisodeConfig, Trial};
use msr_host::episode::qemu::QemuBoard;
use msr_sim::qemu;
use msr_sim::render::Renderer;
use msr_sim::Robot;
use std::path::{Path, PathBuf};

/// A small convolutional model of `robot`, trained once and kept under `target/msr-tests/`.
fn conv_model(robot: Robot) -> Vec<u8> {
    use msr_host::train::{self, DeviceArg, ModelKind, NormArg};
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _g = LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"))
        .join("msr-tests");
    let key = format!("{}-conv-f400-e20-subpixel-pool{}-v3", robot.name(), msr_host::train::calibrate::DEFAULT_POOL);
    let path = dir.join(format!("{key}.msrm"));
    if let Ok(b) = std::fs::read(&path) {
        if msr_shared::blob::Model::parse(&b).is_ok() {
            return b;
        }
    }
    let work = dir.join(format!("{key}-work-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    let data = work.join("data");
    let mut cfg = msr_sim::dataset::DatasetConfig::paper(robot, 7);
    cfg.count = 400;
    msr_sim::dataset::write_dataset(&cfg, &data).expect("render the training set");
    let models = work.join("models");
    train::run(train::Args {
        data,
        model: ModelKind::Decoder,
        arch: msr_host::models::ArchKind::Conv,
        conv_hidden: None,
        conv_channels: None,
        crop: msr_host::data::crop::CropMode::Subpixel,
        out: models.clone(),
        epochs: 20,
        batch: 128,
        lr: 0.005,
        lr_step: 10,
        lr_decay: 0.5,
        seed: 0,
        normalisation: NormArg::Std,
        two_sided: false,
        sigma_floor: msr_host::train::calibrate::DEFAULT_SIGMA_FLOOR,
        threshold: msr_host::train::calibrate::DEFAULT_THRESHOLD,
        threshold_percentile: None,
        min_area: msr_host::train::calibrate::DEFAULT_MIN_AREA,
        pool: msr_host::train::calibrate::DEFAULT_POOL,
        device: DeviceArg::Cpu,
        quiet: true,
    })
    .expect("train the decoder");
    let reach = msr_host::quant::model_blob::train_sim_reach(70, 0).expect("train the reach network");
    let blob = msr_host::quant::model_blob::blob_from_training(&models, "decoder", &reach).expect("make the blob");
    std::fs::create_dir_all(&dir).unwrap();
    let tmp = dir.join(format!("{key}.{}.tmp", std::process::id()));
    std::fs::write(&tmp, &blob).unwrap();
    std::fs::rename(&tmp, &path).unwrap();
    let _ = std::fs::remove_dir_all(&work);
    blob
}

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
    let model = msr_shared::blob::Model::parse(&blob).unwrap();
    let cropper = msr_host::detect::cropper_of(&model).unwrap();
    let renderer = Renderer::new(robot);
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
    // Three clean marked trials, one without a mark and one with the cut, on one QEMU (a reset
    // between trials).
    let plan = [(&marked, 0usize), (&marked, 1), (&unmarked, 2), (&cut, 3), (&marked, 4), (&dxl, 5)];

    let mut board = QemuBoard::start(&blob).unwrap();
    eprintln!("model upload ({} bytes): {:.1} s", blob.len(), board.upload_s);
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
