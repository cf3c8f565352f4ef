//! What the end-to-end tests share: a trained model per robot, made once and kept under
//! `target/msr-tests/` so that every test binary reuses it.
//!
//! The model is small on purpose (CI has two cores): 400 rendered frames, the published fully
//! connected decoder trained for 20 epochs (the paper's optimiser and schedule), calibrated on the
//! training split with `msr train`'s default error pooling and pose cells, the reach network on
//! 70 sim IK pairs. Good enough to find the sim's marks and
//! reach them; the full protocol is what `msr demo` runs.
#![allow(dead_code)]

use msr_host::models::ArchKind;
use msr_host::train::{self, TrainConfig};
use msr_sim::Robot;
use std::path::{Path, PathBuf};

pub const TRAIN_FRAMES: usize = 400;
pub const TRAIN_EPOCHS: usize = 20;

fn cache_dir() -> PathBuf {
    // tests/ -> the workspace's target/.
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"));
    target.join("msr-tests")
}

/// An exclusive lock on `dir/NAME.lock`, held until the file is closed: test binaries and the
/// processes of one binary (cargo-nextest runs each test in its own) make a model once between
/// them.
fn lock(dir: &Path, name: &str) -> std::fs::File {
    std::fs::create_dir_all(dir).unwrap();
    let f = std::fs::File::create(dir.join(format!("{name}.lock"))).unwrap();
    f.lock().expect("lock the model cache");
    f
}

/// The blob of a small model trained on sim frames of `robot` (the published fully connected
/// decoder).
pub fn trained_model(robot: Robot) -> Vec<u8> {
    trained_model_of(robot, ArchKind::Mlp)
}

/// The same with the demo's convolutional decoder (about 180 KB against 1.2 MB: what QEMU's
/// emulated UART uploads in seconds rather than a minute).
pub fn conv_model(robot: Robot) -> Vec<u8> {
    trained_model_of(robot, ArchKind::Conv)
}

fn trained_model_of(robot: Robot, arch: ArchKind) -> Vec<u8> {
    let kind = match arch {
        ArchKind::Mlp => "",
        ArchKind::Conv => "conv-",
    };
    // The key names every setting the blob depends on that has changed since models were first
    // cached, so that a model made under other defaults is never taken for this one: the error
    // pooling and the pose cells (their older defaults were per pixel and one set).
    let (pool, pose_bins) = (train::calibrate::DEFAULT_POOL, train::calibrate::DEFAULT_POSE_BINS);
    let key = format!("{}-{kind}f{TRAIN_FRAMES}-e{TRAIN_EPOCHS}-subpixel-pool{pool}-bins{pose_bins}-v3", robot.name());
    let dir = cache_dir();
    let _lock = lock(&dir, &key);
    let path = dir.join(format!("{key}.msrm"));
    if let Ok(b) = std::fs::read(&path) {
        // A cached blob counts only when it holds what the key says.
        let holds = |m: &msr_shared::blob::Model| {
            m.novelty.pool == pool && m.pose.as_ref().map_or(0, |p| p.grid.bins[0]) == pose_bins
        };
        if msr_shared::blob::Model::parse(&b).is_ok_and(|m| holds(&m)) {
            return b;
        }
    }
    let work = dir.join(format!("{key}-work-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    let data = work.join("data");
    let mut cfg = msr_sim::dataset::DatasetConfig::paper(robot, 7);
    cfg.count = TRAIN_FRAMES;
    msr_sim::dataset::write_dataset(&cfg, &data).expect("render the training set");
    let models = work.join("models");
    train::run(
        TrainConfig::new(data, models.clone())
            .with_arch(arch)
            .with_epochs(TRAIN_EPOCHS)
            .with_pool(pool)
            .with_pose_bins(pose_bins)
            .with_quiet(true),
    )
    .expect("train the decoder");
    let reach = msr_host::quant::model_blob::train_sim_reach(70, 0).expect("train the reach network");
    let blob = msr_host::quant::model_blob::blob_from_training(&models, "decoder", &reach)
        .expect("make the blob");
    // Write then rename, so a concurrent test binary never reads half a file.
    std::fs::create_dir_all(&dir).unwrap();
    let tmp = dir.join(format!("{key}.{}.tmp", std::process::id()));
    std::fs::write(&tmp, &blob).unwrap();
    std::fs::rename(&tmp, &path).unwrap();
    let _ = std::fs::remove_dir_all(&work);
    blob
}

use msr_host::episode::{inproc_board, Camera};
use msr_shared::host_port::HostPort;
use msr_shared::msg::{BoardToHost, Status};
use msr_sim::link::LinkEnd;
use msr_sim::world::{self, Flow, World, WorldConfig};

/// What a scripted run saw.
pub struct Seen {
    pub world: World,
    /// Every message the board sent, with the time the PC received it.
    pub msgs: Vec<(u64, BoardToHost)>,
    /// The board's counters at the end.
    pub status: Status,
    /// The PC's own framing counters.
    pub pc: msr_shared::frame::LinkCounters,
}

/// The PC's tools for a script: the world, the port, a camera at the model's template.
pub struct Pc<'a> {
    pub port: HostPort,
    pub camera: Camera<'a>,
    pub rng: rand_chacha::ChaCha8Rng,
}

impl Pc<'_> {
    /// Renders a frame at the pose the servos hold (with `mark`), crops it, sends it.
    pub fn send_frame(&mut self, w: &mut World, mark: Option<&msr_sim::marks::Mark>) {
        let (_, face) = self
            .camera
            .shoot(&w.body_pose(), mark, &mut self.rng, msr_sim::light::Light::FIXED)
            .unwrap();
        let bytes = self.port.encode_face(face.crop.origin(), face.crop.size(), &face.grey).unwrap();
        w.host.send(&bytes);
    }
}

/// Runs the in-process board with `blob` built in under `cfg` for `max_us`; `script` plays the
/// PC every tick (it sees the messages so far).
pub fn scripted(
    blob: Option<&[u8]>,
    cfg: &WorldConfig,
    robot: Robot,
    max_us: u64,
    mut script: impl FnMut(&mut World, &mut Pc, &[(u64, BoardToHost)]) -> Flow,
) -> Seen {
    use rand::SeedableRng;
    let mut board = match blob {
        Some(b) => inproc_board(b),
        None => Box::new(msr_firmware::Board::new(msr_host::episode::HeapStore::new(
            None,
            2 << 20,
        ))),
    };
    let tpl_blob = blob
        .map(|b| b.to_vec())
        .unwrap_or_else(|| trained_model(robot));
    let model = msr_shared::blob::Model::parse(&tpl_blob).unwrap();
    let cropper = msr_host::detect::cropper_of(&model).unwrap();
    let renderer = msr_sim::render::Renderer::new(robot);
    let mut pc = Pc {
        port: HostPort::default(),
        camera: Camera {
            renderer: &renderer,
            cropper: &cropper,
        },
        rng: rand_chacha::ChaCha8Rng::seed_from_u64(1),
    };
    let mut msgs = Vec::new();
    let (w, _) = {
        let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| board.poll(now, h, s);
        world::run(
            cfg,
            &mut fw,
            |w: &mut World| {
                let bytes = w.host.receive();
                for m in pc.port.receive(&bytes) {
                    msgs.push((w.now_us, m));
                }
                script(w, &mut pc, &msgs)
            },
            max_us,
        )
        .unwrap()
    };
    let pc_counters = *pc.port.counters();
    Seen {
        world: w,
        msgs,
        status: board.status(),
        pc: pc_counters,
    }
}

/// A mark the camera sees at home.
pub fn a_mark(robot: Robot, seed: u64) -> msr_sim::marks::Mark {
    use rand::SeedableRng;
    let r = msr_sim::render::Renderer::new(robot);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let pose = msr_sim::body::BodyPose::head(0.0, 0.0);
    msr_sim::dataset::render_marked(&r, &pose, &msr_sim::render::Variation::CLEAN, &mut rng).0
}
