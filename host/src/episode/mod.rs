//! Mirror-test episodes: the sim world on one thread, the firmware on the other, the emulated host
//! link and servo bus between them, and a scenario that plays the PC and judges.
//!
//! One trial, in simulated time (each trial is a fresh world and a fresh board, so trials are
//! independent and run in parallel):
//! - 0 s: the robot sits at home (the observe posture); the PC streams camera frames every
//!   [`EpisodeConfig::frame_period_us`]: rendered at the posture the servos hold *now*, cropped
//!   with the model's face template (the host crop), sent over the host link.
//! - [`EpisodeConfig::mark_at_us`]: a mark appears on the face (random kind, colour and place,
//!   redrawn while it is too faint to see, as the datasets do), except in a share of trials.
//! - The board reads the head angles from the servos, detects, confirms and reaches; the PC sees
//!   the confirmed detection (the reach starts) on the host link.
//! - The judge samples the true joint angles every 10 ms. Once all five reach joints are within
//!   [`HELD_TOLERANCE_RAD`] of the reach target the reach is held; after
//!   [`EpisodeConfig::judge_hold_us`] of holding, the trial is judged by forward kinematics
//!   (`msr_sim::kin::judge_touch`: every held sample within 20 mm of the mark's 3-D point) and
//!   ends. The rest of the 5 s hold would only repeat the same posture.
//! - A reach while no mark is on the face is a false reach. A trial without a reach ends
//!   [`EpisodeConfig::watch_us`] after the mark time.
//!
//! While the arm is up the board pauses detection, so the PC sends frames only every
//! [`ARM_UP_FRAME_PERIOD_US`] then, enough to keep the face watchdog (500 ms) fed.
pub mod qemu;
pub mod scene;
pub mod sim_board;
use crate::data::crop;
use anyhow::{anyhow, Result};
use image::{DynamicImage, GrayImage};

use msr_firmware::Board;
use msr_shared::blob::Model;
use msr_shared::deliver::{FaceLink, LinkStats};
use msr_shared::host_port::HostPort;
use msr_shared::msg::{BoardToHost, Config, Detection, GateDecision, GateReport, HostToBoard, ServoBusKind, Status};
pub use scene::Scene;
use scene::SceneState;
use msr_sim::body::BodyPose;
use msr_sim::imperfect::Imperfections;
use msr_sim::light::{Light, LightPlan, LightSchedule};
use msr_sim::link::{FaultConfig, LinkEnd};
use msr_sim::render::{Renderer, Variation};
use msr_sim::servo::ServoConfig;
use msr_sim::world::{self, Flow, World, WorldConfig};
use msr_sim::Robot;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// The reach is held when every reach joint is this close to its target.
pub const HELD_TOLERANCE_RAD: f64 = 0.01;
/// Frame period while the arm is up (detection paused; the face watchdog wants one per 500 ms).
pub const ARM_UP_FRAME_PERIOD_US: u64 = 250_000;
/// Joint samples for the judge: the DCM period.
pub const SAMPLE_US: u64 = 10_000;
/// How long after its line went idle the PC waits for the board's ack of a face-frame round
/// before polling again: two 1 ms ticks, the ack's bytes, a margin.
pub const FACE_ACK_TIMEOUT_US: u64 = 4_000;
/// A face frame still unfinished this many frame periods after it started is superseded by a
/// fresh camera frame (the face watchdog wants a whole frame every 500 ms).
pub const FACE_MAX_AGE_PERIODS: u64 = 2;

/// What runs the firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// `msr_firmware::Board` on a thread of this process.
    Inproc,
    /// The `thumbv7em-none-eabihf` image in `qemu-system-arm` (mps2-an386).
    Qemu,
}

impl Backend {
    pub fn name(self) -> &'static str {
        match self {
            Backend::Inproc => "inproc",
            Backend::Qemu => "qemu",
        }
    }
}

/// The servo bus's protocol, as the command line names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ServoBus {
    /// The project's frames (postcard + COBS), full duplex, 921600 baud.
    Framed,
    /// Dynamixel Protocol 2.0 at 1 Mbaud: the board is the master of emulated X-series servos.
    Dynamixel,
}

impl ServoBus {
    pub fn name(self) -> &'static str {
        match self {
            ServoBus::Framed => "framed",
            ServoBus::Dynamixel => "dynamixel",
        }
    }

    pub fn kind(self) -> ServoBusKind {
        match self {
            ServoBus::Framed => ServoBusKind::Framed,
            ServoBus::Dynamixel => ServoBusKind::Dynamixel,
        }
    }
}

/// Which links a fault setting hits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FaultLinks {
    /// The host link (PC to board) only.
    Host,
    /// The servo bus (board to servos) only.
    Servo,
    /// Both.
    Both,
}

/// How trials run.
#[derive(Clone, Debug)]
pub struct EpisodeConfig {
    pub robot: Robot,
    /// What stands in front of the robot.
    pub scene: Scene,
    /// The servo bus's protocol; the PC tells the board at the start of each trial.
    pub servo_bus: ServoBus,
    /// Keep the bytes the board sends on the servo bus (each trial's [`Trial::bus_bytes`]).
    pub log_bus: bool,
    /// Share of trials with no mark.
    pub no_mark_share: f64,
    pub frame_period_us: u64,
    /// When the mark appears.
    pub mark_at_us: u64,
    /// How long after the mark time a reach may start.
    pub watch_us: u64,
    /// How long the held reach is sampled before judging.
    pub judge_hold_us: u64,
    /// Faults on the host link (both directions).
    pub host_faults: FaultConfig,
    /// Faults on the servo bus (both directions).
    pub servo_faults: FaultConfig,
    /// Sent to the board at the start of each trial, if given.
    pub board_config: Option<Config>,
    /// Trials run at once (each uses two threads).
    pub parallel: usize,
    /// Simulated seconds per wall second; `None`: as fast as possible (in-process). A firmware
    /// with its own clock (QEMU) needs real time.
    pub pace: Option<f64>,
    /// Log each trial for `--mcap` (its model draws the saliency image).
    pub mcap: Option<crate::rosbag::session::LogModel>,
    /// Publish each trial's messages live as they happen (`--live`).
    pub live: Option<crate::rosbag::session::LiveTap>,
    /// How the light changes over each trial (`msr mirror-test --light`).
    pub light: LightPlan,
    /// The light's plan spans a run of trials rather than each trial ([`run_one_board`]).
    pub light_span: Option<LightSpan>,
    /// Let the board learn the room's light (its online self-calibration); off: the PC tells
    /// it to freeze at the start of each trial, so it keeps the model's own statistics.
    pub learn_room: bool,
    /// How the emulated servos move and hold (encoder noise, sag, friction); each trial draws
    /// its encoder noise from its own seed.
    pub servo: ServoConfig,
    /// The camera's imperfections (`msr mirror-test`'s camera flags); each trial draws its noise
    /// from its own seed, and the motion blur follows the head's speed between frames.
    pub camera: Imperfections,
}

/// A light plan drawn once for a run of trials, and where in it a trial starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSpan {
    /// Seed of the plan's draws.
    pub seed: u64,
    /// The plan's whole duration, simulated microseconds.
    pub span_us: u64,
    /// The trial's start in it.
    pub offset_us: u64,
}

impl EpisodeConfig {
    pub fn new(robot: Robot) -> EpisodeConfig {
        EpisodeConfig {
            robot,
            scene: Scene::Mirror,
            servo_bus: ServoBus::Framed,
            log_bus: false,
            no_mark_share: 0.2,
            frame_period_us: 100_000,
            mark_at_us: 400_000,
            watch_us: 4_000_000,
            judge_hold_us: 1_000_000,
            host_faults: FaultConfig::default(),
            servo_faults: FaultConfig::default(),
            board_config: None,
            parallel: std::thread::available_parallelism()
                .map_or(1, |n| n.get())
                .min(4),
            pace: None,
            mcap: None,
            live: None,
            light: LightPlan::Fixed,
            light_span: None,
            learn_room: true,
            servo: ServoConfig::default(),
            camera: Imperfections::NONE,
        }
    }

    /// Faults on both directions of the chosen links (added to what is there).
    pub fn with_faults(mut self, f: &FaultConfig, on: FaultLinks) -> Self {
        let add = |to: &mut FaultConfig| {
            to.bit_error_rate = f.bit_error_rate;
            to.drop_rate = f.drop_rate;
            to.burst_rate = f.burst_rate;
            to.burst_len = f.burst_len;
            to.disconnects.extend(f.disconnects.iter().copied());
        };
        if on != FaultLinks::Servo {
            add(&mut self.host_faults);
        }
        if on != FaultLinks::Host {
            add(&mut self.servo_faults);
        }
        self
    }

    /// The same bit-error rate on every direction of both links.
    pub fn with_ber(mut self, ber: f64) -> Self {
        self.host_faults.bit_error_rate = ber;
        self.servo_faults.bit_error_rate = ber;
        self
    }

    /// Both links dead for `duration_us` from `start_us`.
    pub fn with_disconnect(mut self, start_us: u64, duration_us: u64) -> Self {
        self.host_faults.disconnects.push((start_us, duration_us));
        self.servo_faults.disconnects.push((start_us, duration_us));
        self
    }

    fn world(&self, seed: u64) -> WorldConfig {
        let mut w = WorldConfig::default().seeded(seed);
        w.host_link.a_to_b = self.host_faults.clone();
        w.host_link.b_to_a = self.host_faults.clone();
        w.servo_link.a_to_b = self.servo_faults.clone();
        w.servo_link.b_to_a = self.servo_faults.clone();
        w.pace = self.pace;
        w.servo = ServoConfig { noise_seed: seed, ..self.servo };
        if self.servo_bus == ServoBus::Dynamixel {
            w.servo_link.baud = 1_000_000;
            w.dynamixel = Some(msr_sim::dynamixel::DxlConfig::default());
        }
        w
    }

    fn max_us(&self) -> u64 {
        // Mark, watch window, a reach at speed 0.1 (under 4 s for any IK posture), the judged
        // hold, and room for a watchdog recovery and a second reach.
        self.mark_at_us + self.watch_us + 2 * (4_000_000 + self.judge_hold_us)
    }
}

/// One decision of the board's self gate, as the PC saw it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GateRecord {
    /// Simulated time of the report, ms.
    pub at_ms: f64,
    /// `pass`, `reject` or `undecided: <why>`.
    pub decision: String,
    /// `null` when undecided before both probe poses (NaN on the wire).
    pub gain_ratio: Option<f32>,
    pub rest_px: Option<f32>,
    /// Largest range of the face's x while the head held (rest, each pose), pixels.
    #[serde(default)]
    pub hold_px: Option<f32>,
    /// Largest vertical move of the face at a pose from its rest, pixels.
    #[serde(default)]
    pub level_px: Option<f32>,
    /// With a return stage: the face back at the resting yaw, its distance from the probe's
    /// line, pixels.
    #[serde(default)]
    pub line_px: Option<f32>,
    /// Probe frames that did not show the face the model predicts there (return stage only).
    #[serde(default)]
    pub unlike: u8,
    /// Mean salient pixels at rest and at the two probe poses.
    pub salient: [Option<f32>; 3],
    pub frames: [u8; 2],
    pub elapsed_ms: u16,
    /// The statistics' squared shares of the model gate's tolerances, summed
    /// (`msr_firmware::self_gate::joint`; the gate passes at most its `joint_tol`): how near the
    /// tolerances the probe came all at once. `null` when undecided or not worked out
    /// ([`add_gate_joints`]).
    #[serde(default)]
    pub joint: Option<f32>,
}

impl GateRecord {
    pub fn of(at_us: u64, g: &GateReport) -> GateRecord {
        let finite = |v: f32| v.is_finite().then_some(v);
        GateRecord {
            at_ms: at_us as f64 / 1000.0,
            decision: match g.decision {
                GateDecision::Pass => "pass".into(),
                GateDecision::Reject => "reject".into(),
                GateDecision::Undecided(w) => format!("undecided: {w:?}"),
            },
            gain_ratio: finite(g.gain_ratio),
            rest_px: finite(g.rest_px),
            hold_px: finite(g.hold_px),
            level_px: finite(g.level_px),
            line_px: finite(g.line_px),
            unlike: g.unlike,
            salient: g.salient.map(finite),
            frames: g.frames,
            elapsed_ms: g.elapsed_ms,
            joint: None,
        }
    }

    /// [`GateRecord::joint`] under `gate`, the gate that decided (the report does not carry it).
    pub fn joint_under(&self, gate: &msr_shared::blob::SelfGate) -> Option<f32> {
        let line = match gate.line_tol {
            Some(_) => self.line_px?,
            None => 0.0,
        };
        let j = msr_firmware::self_gate::joint(gate, self.gain_ratio?, self.rest_px?, self.hold_px?, self.level_px?, line);
        j.is_finite().then_some(j)
    }
}

/// Fills every gate decision's [`GateRecord::joint`] under `gate`, the model's.
pub fn add_gate_joints(trials: &mut [Trial], gate: &msr_shared::blob::SelfGate) {
    for r in trials.iter_mut().flat_map(|t| t.gate.iter_mut()) {
        r.joint = r.joint_under(gate);
    }
}

/// One trial's outcome (`Default`: nothing happened yet).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Trial {
    pub index: usize,
    /// The scene (`mirror`, `other`, `delayed`).
    pub scene: String,
    /// Delayed scene: the video delay.
    pub delay_ms: Option<f64>,
    /// Other scene: whether the other robot babbled its head (else it held still).
    pub other_babbles: Option<bool>,
    /// The self gate's decisions, in order (empty without a gate in the model).
    pub gate: Vec<GateRecord>,
    /// The mark (kind, colour) when one was put on the face.
    pub mark: Option<String>,
    /// The trial was drawn to get a mark but ended (a false reach) before the mark appeared: it
    /// counts neither as a marked trial nor as one without a mark.
    pub ended_before_mark: bool,
    /// The mark's centre in the frame at head (0, 0), pixels.
    pub mark_pixel: Option<[f64; 2]>,
    /// A reach started (the board confirmed a detection).
    pub reached: bool,
    /// A reach while no mark was on the face.
    pub false_reach: bool,
    pub touched: bool,
    /// Worst fingertip-to-mark distance while held (marked trials with a held reach).
    pub touch_error_mm: Option<f64>,
    /// Simulated time from the mark appearing to the reach starting.
    pub latency_ms: Option<f64>,
    /// The reach target the board streamed, when it reached.
    pub reach_target: Option<[f32; 5]>,
    /// Why a marked trial failed, for finding the stage at fault.
    pub failure: Option<String>,
    pub frames_sent: u32,
    pub detections: u32,
    pub limit_violations: u32,
    pub crc_errors: u32,
    pub resyncs: u32,
    pub watchdog_trips: u32,
    /// The PC's face-frame delivery: frames delivered and superseded, bytes, chunks resent.
    pub link: LinkStats,
    pub sim_s: f64,
    pub wall_s: f64,
    /// What the board sent on the servo bus, when [`EpisodeConfig::log_bus`].
    #[serde(skip)]
    pub bus_bytes: Vec<u8>,
    /// The trial as ROS 2 messages, when [`EpisodeConfig::mcap`].
    #[serde(skip)]
    pub log: Option<crate::rosbag::session::SessionLog>,
    /// Frames the board answered with no detection because the photometric fit refused them
    /// (`NoFace`, `SceneChanged`).
    #[serde(default)]
    pub no_face_frames: u32,
    #[serde(default)]
    pub scene_changed_frames: u32,
}

/// The summary `msr mirror-test --json` prints, exactly these keys.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Summary {
    pub backend: String,
    pub robot: String,
    pub servo_bus: String,
    /// The scene of the trials.
    pub scene: String,
    pub trials: usize,
    /// Trials in which a reach started, marked or not.
    pub reaches: usize,
    /// The self gate's decisions over all trials.
    pub gate_passes: usize,
    pub gate_rejects: usize,
    pub gate_undecided: usize,
    pub marked_trials: usize,
    pub touched: usize,
    /// Touched / marked trials; `null` when no trial had a mark.
    pub touch_rate: Option<f64>,
    pub no_mark_trials: usize,
    /// Trials drawn to get a mark that ended (a false reach) before it appeared.
    pub ended_before_mark: usize,
    pub false_reaches: usize,
    pub median_touch_error_mm: Option<f64>,
    pub latency_ms_median: Option<f64>,
    pub limit_violations: u64,
    pub crc_errors: u64,
    pub resyncs: u64,
    pub watchdog_trips: u64,
    /// Face bytes the board took whole per simulated second, over all trials.
    pub goodput_bytes_per_s: f64,
    /// Face chunks sent again (selective repeat).
    pub retransmissions: u64,
    /// Face frames given up unfinished for a newer one.
    pub frames_superseded: u64,
    /// Frames refused by the photometric fit, over all trials: `NoFace`, `SceneChanged`.
    #[serde(default)]
    pub no_face_frames: u64,
    #[serde(default)]
    pub scene_changed_frames: u64,
    /// Robot time of all trials, seconds.
    #[serde(default)]
    pub sim_s: f64,
    /// What the board had learnt of the room at the end of a run on one board (`--one-board`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub room: Option<msr_shared::msg::RoomReport>,
    /// What the live server served (`--live`): clients, messages, and those dropped for
    /// clients that read too slowly.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub live: Option<crate::live::LiveStats>,
}

impl std::fmt::Display for Summary {
    /// One line: the counts, rates and medians, the face link, the room and the live view.
    fn fmt(&self, out: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self;
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));
        let early = if s.ended_before_mark > 0 {
            format!(", {} ended before the mark appeared", s.ended_before_mark)
        } else {
            String::new()
        };
        let line = format!(
            "{} {} ({} servo bus, scene {}): {} trials, {} reaches, self gate {} pass / {} reject / {} undecided, \
             touched {}/{} marked ({} %), false reaches {} ({} trials without a mark{early}), \
             median touch error {} mm, median latency {} ms, limit violations {}, CRC errors {}, resyncs {}, \
             watchdog trips {}; face link: goodput {:.0} B/s, {} chunks sent again, {} frames superseded",
            s.backend,
            s.robot,
            s.servo_bus,
            s.scene,
            s.trials,
            s.reaches,
            s.gate_passes,
            s.gate_rejects,
            s.gate_undecided,
            s.touched,
            s.marked_trials,
            f(s.touch_rate.map(|r| 100.0 * r)),
            s.false_reaches,
            s.no_mark_trials,
            f(s.median_touch_error_mm),
            f(s.latency_ms_median),
            s.limit_violations,
            s.crc_errors,
            s.resyncs,
            s.watchdog_trips,
            s.goodput_bytes_per_s,
            s.retransmissions,
            s.frames_superseded
        ) + &s.room.map_or(String::new(), |r| {
            format!("; {:.1} min of robot time on one board, {}", s.sim_s / 60.0, crate::describe::describe_room(&r))
        }) + &s.live.map_or(String::new(), |l| format!("; {l}"));
        out.write_str(&line)
    }
}

pub fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    })
}

fn gate_count(trials: &[Trial], f: fn(&str) -> bool) -> usize {
    trials.iter().flat_map(|t| &t.gate).filter(|g| f(&g.decision)).count()
}

pub fn summarise(backend: Backend, robot: Robot, bus: ServoBus, trials: &[Trial]) -> Summary {
    let marked: Vec<&Trial> = trials.iter().filter(|t| t.mark.is_some()).collect();
    let touched = marked.iter().filter(|t| t.touched).count();
    let sum = |f: fn(&Trial) -> u32| trials.iter().map(|t| f(t) as u64).sum::<u64>();
    Summary {
        backend: backend.name().into(),
        robot: robot.name().into(),
        servo_bus: bus.name().into(),
        scene: trials.first().map_or("mirror".into(), |t| t.scene.clone()),
        trials: trials.len(),
        reaches: trials.iter().filter(|t| t.reached).count(),
        gate_passes: gate_count(trials, |d| d == "pass"),
        gate_rejects: gate_count(trials, |d| d == "reject"),
        gate_undecided: gate_count(trials, |d| d.starts_with("undecided")),
        marked_trials: marked.len(),
        touched,
        touch_rate: (!marked.is_empty()).then(|| touched as f64 / marked.len() as f64),
        no_mark_trials: trials
            .iter()
            .filter(|t| t.mark.is_none() && !t.ended_before_mark)
            .count(),
        ended_before_mark: trials.iter().filter(|t| t.ended_before_mark).count(),
        false_reaches: trials.iter().filter(|t| t.false_reach).count(),
        median_touch_error_mm: median(marked.iter().filter_map(|t| t.touch_error_mm).collect()),
        latency_ms_median: median(marked.iter().filter_map(|t| t.latency_ms).collect()),
        limit_violations: sum(|t| t.limit_violations),
        crc_errors: sum(|t| t.crc_errors),
        resyncs: sum(|t| t.resyncs),
        watchdog_trips: sum(|t| t.watchdog_trips),
        goodput_bytes_per_s: {
            let secs: f64 = trials.iter().map(|t| t.sim_s).sum();
            let bytes: u64 = trials.iter().map(|t| t.link.face_bytes).sum();
            if secs > 0.0 { bytes as f64 / secs } else { 0.0 }
        },
        retransmissions: trials.iter().map(|t| t.link.chunks_resent).sum(),
        frames_superseded: trials.iter().map(|t| t.link.superseded as u64).sum(),
        no_face_frames: sum(|t| t.no_face_frames),
        scene_changed_frames: sum(|t| t.scene_changed_frames),
        sim_s: trials.iter().map(|t| t.sim_s).sum(),
        room: None,
        live: None,
    }
}

pub use msr_firmware::model::HeapStore;

/// The in-process firmware: a board with the model built in.
pub type InprocBoard = Board<HeapStore>;

pub fn inproc_board(blob: &[u8]) -> Box<InprocBoard> {
    Box::new(Board::new(HeapStore::new(Some(blob), 512 * 1024)))
}


/// Renders and crops camera frames of one robot.
pub struct Camera<'a> {
    pub renderer: &'a Renderer,
    /// The model's template and crop mode.
    pub cropper: &'a crop::Cropper,
}

impl Camera<'_> {
    /// The grey frame at a pose with an optional mark, and its face crop.
    pub fn shoot(
        &self,
        pose: &BodyPose,
        mark: Option<&msr_sim::marks::Mark>,
        rng: &mut ChaCha8Rng,
        light: Light,
    ) -> Result<(GrayImage, crop::Face)> {
        self.take([pose.head_yaw, pose.head_pitch], pose, mark, rng, light, &Imperfections::NONE, 0)
    }

    /// As [`Camera::shoot`] with the camera at head angles `camera` and the body in view at
    /// `seen` (another robot, or a delayed picture).
    pub fn shoot_seen(
        &self,
        camera: [f64; 2],
        seen: &BodyPose,
        mark: Option<&msr_sim::marks::Mark>,
        rng: &mut ChaCha8Rng,
        light: Light,
    ) -> Result<(GrayImage, crop::Face)> {
        self.take(camera, seen, mark, rng, light, &Imperfections::NONE, 0)
    }

    /// As [`Camera::shoot_seen`], the frame taken through `through` (frame number `frame` for
    /// its noise).
    #[allow(clippy::too_many_arguments)]
    pub fn take(
        &self,
        camera: [f64; 2],
        seen: &BodyPose,
        mark: Option<&msr_sim::marks::Mark>,
        rng: &mut ChaCha8Rng,
        light: Light,
        through: &Imperfections,
        frame: u64,
    ) -> Result<(GrayImage, crop::Face)> {
        let var = Variation::random(rng).lit(light);
        let full = [0, 0, msr_sim::body::WIDTH, msr_sim::body::HEIGHT];
        let mut r = self.renderer.render_seen(camera, seen, mark, &var, full);
        if !through.is_none() {
            r.rgb = through.apply(&r.rgb, frame);
        }
        let grey = crop::to_grey(&DynamicImage::ImageRgb8(r.rgb));
        let face = self.cropper.crop(&grey)?;
        Ok((grey, face))
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    Watching,
    /// A reach started at this time, towards this target.
    Reaching {
        since_us: u64,
    },
    Held {
        since_us: u64,
    },
    Done,
}

/// The scenario of one trial: the PC and the judge.
struct Scenario<'a> {
    cfg: &'a EpisodeConfig,
    camera: Camera<'a>,
    /// Camera noise: how many frames are shot depends on the link.
    rng: ChaCha8Rng,
    /// The mark alone, on a stream of its own, so that a noisy link (more or fewer frames shot
    /// before the mark) does not change which mark a seed draws.
    mark_rng: ChaCha8Rng,
    scene: SceneState,
    port: HostPort,
    /// Face frames out, with selective repeat.
    faces: FaceLink,
    /// The frame id of the reach last seen (the board repeats it while the arm is up).
    last_reach_frame: Option<u16>,
    marked: bool,
    mark: Option<msr_sim::marks::Mark>,
    next_frame_us: u64,
    next_sample_us: u64,
    stage: Stage,
    target: Option<[f32; 5]>,
    held: Vec<msr_sim::kin::Reach>,
    trial: Trial,
    error: Option<anyhow::Error>,
    status: Option<Status>,
    detections: Vec<(u64, Detection)>,
    /// Frames sent while the mark was on the face.
    frames_with_mark: usize,
    log: Option<crate::rosbag::session::SessionLog>,
    /// The trial's light (and the camera's gain loop).
    light: LightSchedule,
    /// Where the trial starts in `light` (a plan that spans a run of trials).
    light_offset_us: u64,
    /// The camera's imperfections, seeded for this trial.
    imperfect: Imperfections,
    /// When the last frame was taken and the camera's head angles then (for the motion blur).
    last_shot: Option<(u64, [f64; 2])>,
}

impl Scenario<'_> {
    fn mark_on(&self, now: u64) -> bool {
        self.marked && now >= self.cfg.mark_at_us
    }

    fn step(&mut self, w: &mut World) -> Result<Flow> {
        let now = w.now_us;
        self.scene.step(now, &w.body_pose());
        if now == 0 {
            // The bus first: the board (in-process or QEMU) says nothing on it until told.
            let bytes = self.port.encode(&HostToBoard::UseServoBus(self.cfg.servo_bus.kind()));
            w.host.send(&bytes);
            if let Some(c) = self.cfg.board_config {
                let bytes = self.port.encode(&HostToBoard::Configure(c));
                w.host.send(&bytes);
            }
            if !self.cfg.learn_room {
                let bytes = self.port.encode(&HostToBoard::Room(msr_shared::msg::RoomCommand::Freeze));
                w.host.send(&bytes);
            }
        }
        let msgs = self.port.receive(&w.host.receive());
        self.port.check_version()?;
        for m in msgs {
            if let Some(l) = &mut self.log {
                l.board(now, &m);
            }
            self.faces.on_message(&m);
            match m {
                BoardToHost::Detection(d) => {
                    if d.confirmed && self.last_reach_frame == Some(d.frame) {
                        continue; // The reach again, while the arm is up.
                    }
                    if d.blob.is_some() {
                        self.trial.detections += 1;
                    }
                    match d.reason {
                        Some(msr_shared::msg::NoDetection::NoFace) => self.trial.no_face_frames += 1,
                        Some(msr_shared::msg::NoDetection::SceneChanged) => self.trial.scene_changed_frames += 1,
                        None => {}
                    }
                    if d.confirmed {
                        self.last_reach_frame = Some(d.frame);
                        self.on_reach(now, d);
                    }
                    self.detections.push((now, d));
                }
                BoardToHost::Status(s) => self.status = Some(s),
                BoardToHost::SelfGate(g) => self.trial.gate.push(GateRecord::of(now, &g)),
                _ => {}
            }
        }
        if self.trial.false_reach {
            return Ok(Flow::Stop);
        }
        // The mark appears: choose one that shows, at the pose the head has now.
        if self.mark_on(now) && self.mark.is_none() {
            // On the other robot's face in the other scene.
            let on = match self.scene.scene {
                Scene::Other => self.scene.view(now, &w.body_pose()).seen,
                _ => w.body_pose(),
            };
            let (m, _) = msr_sim::dataset::render_marked(
                self.camera.renderer,
                &on,
                &Variation::CLEAN,
                &mut self.mark_rng,
            );
            let p = msr_sim::body::project_head(&m.point_head(), 0.0, 0.0);
            self.trial.mark = Some(format!("{} {}", m.colour, m.kind));
            self.trial.mark_pixel = p;
            self.mark = Some(m);
        }
        let arm_up = !matches!(self.stage, Stage::Watching);
        let period = if arm_up {
            ARM_UP_FRAME_PERIOD_US.max(self.cfg.frame_period_us)
        } else {
            self.cfg.frame_period_us
        };
        // A new camera frame once the last one is through (or has taken too long: superseded).
        let ready = match self.faces.in_flight_since() {
            None => w.host.tx_idle_at_us() <= now,
            Some(t) => now.saturating_sub(t) >= FACE_MAX_AGE_PERIODS * period,
        };
        if now >= self.next_frame_us && ready {
            let light = self.light.at(now + self.light_offset_us);
            let pose = w.body_pose();
            let (head, seen, mark) = if self.scene.scene == Scene::Mirror {
                ([pose.head_yaw, pose.head_pitch], pose, self.mark.as_ref())
            } else {
                let v = self.scene.view(now, &pose);
                // A delayed picture shows the mark once it had appeared by then.
                (v.camera, v.seen, self.mark.as_ref().filter(|_| v.as_of_us >= self.cfg.mark_at_us))
            };
            // The head's speed since the last frame smears this one.
            let speed = match self.last_shot {
                Some((t, h)) if now > t => {
                    let dt = (now - t) as f64 * 1e-6;
                    [(head[0] - h[0]) / dt, (head[1] - h[1]) / dt]
                }
                _ => [0.0; 2],
            };
            self.last_shot = Some((now, head));
            let through = self.imperfect.moving(speed);
            let frame = self.trial.frames_sent as u64;
            let (grey, face) = self.camera.take(head, &seen, mark, &mut self.rng, light, &through, frame)?;
            self.light.observed_grey(&grey);
            let with_mark = mark.is_some();
            let logged = self.log.is_some().then(|| face.clone());
            let c = face.crop;
            let size = [c.width as u16, c.height as u16];
            // The sub-pixel part too: the self gate follows the face to a fraction of a pixel.
            let at = msr_shared::msg::CropAt::subpixel([c.x as u16, c.y as u16], face.at);
            let id = self.faces.start(at, size, face.grey, now);
            if let Some(f) = logged {
                self.log_frame(now, id, w, &grey, &f, with_mark);
            }
            self.trial.frames_sent += 1;
            if with_mark {
                self.frames_with_mark += 1;
            }
            self.next_frame_us = now + period;
        }
        self.faces.check(now);
        let mut bytes = Vec::new();
        let port = &mut self.port;
        self.faces.pump(|m| bytes.extend(port.encode(m)));
        if !bytes.is_empty() {
            w.host.send(&bytes);
        }
        self.faces.sent(w.host.tx_idle_at_us());
        if now >= self.next_sample_us {
            self.next_sample_us = now + SAMPLE_US;
            self.sample(now, w);
            if let Some(l) = &mut self.log {
                l.servos(now, w.servos.servos());
            }
        }
        let limit = match self.stage {
            Stage::Watching => self.cfg.mark_at_us + self.cfg.watch_us,
            _ => self.cfg.max_us(),
        };
        Ok(if self.stage == Stage::Done || now >= limit {
            Flow::Stop
        } else {
            Flow::Continue
        })
    }

    /// Logs a frame sent (`--mcap`), with the mark's box from a clean render of the same view.
    fn log_frame(&mut self, now: u64, id: u16, w: &World, grey: &GrayImage, face: &crop::Face, with_mark: bool) {
        let r = self.camera.renderer;
        let truth = match (with_mark, self.scene.scene) {
            (false, _) => None,
            (true, Scene::Mirror) => r.render(&w.body_pose(), self.mark.as_ref(), &Variation::CLEAN).mark,
            (true, _) => {
                let v = self.scene.view(now, &w.body_pose());
                let full = [0, 0, msr_sim::body::WIDTH, msr_sim::body::HEIGHT];
                r.render_seen(v.camera, &v.seen, self.mark.as_ref(), &Variation::CLEAN, full).mark
            }
        };
        let truth = truth.filter(|m| m.pixels > 0).map(|m| m.box_xyxy);
        let q = w.servos.reach_angles();
        if let Some(l) = &mut self.log {
            l.frame(now, id, grey, face, truth, [q[0] as f32, q[1] as f32]);
        }
    }

    fn on_reach(&mut self, now: u64, d: Detection) {
        self.trial.reached = true;
        if !self.mark_on(now) {
            self.trial.false_reach = true;
            self.trial.reach_target = d.reach;
            return;
        }
        if self.trial.latency_ms.is_none() {
            self.trial.latency_ms = Some((now - self.cfg.mark_at_us) as f64 / 1000.0);
        }
        self.target = d.reach;
        self.trial.reach_target = d.reach;
        self.held.clear();
        self.stage = Stage::Reaching { since_us: now };
    }

    fn sample(&mut self, now: u64, w: &World) {
        let q = w.servos.reach_angles();
        let Some(t) = self.target else { return };
        let near = q
            .iter()
            .zip(t)
            .all(|(a, b)| (a - b as f64).abs() <= HELD_TOLERANCE_RAD);
        match self.stage {
            Stage::Reaching { .. } if near => {
                self.stage = Stage::Held { since_us: now };
                self.held.push(q);
            }
            Stage::Held { since_us } => {
                if !near {
                    // The board left the target early (a watchdog): not a held reach.
                    self.stage = Stage::Watching;
                    self.trial.failure =
                        Some("the arm left the reach target before the hold was judged".into());
                    self.held.clear();
                } else {
                    self.held.push(q);
                    if now - since_us >= self.cfg.judge_hold_us {
                        self.judge();
                        self.stage = Stage::Done;
                    }
                }
            }
            _ => {}
        }
    }

    fn judge(&mut self) {
        let Some(m) = &self.mark else { return };
        if self.scene.scene == Scene::Other {
            // The mark is on the other robot: whatever the hand touched, it was the wrong face.
            self.trial.failure = Some("other: reached for its own face; the mark is on the other robot".into());
            return;
        }
        let (touched, worst) = msr_sim::kin::judge_touch(&self.held, &m.point_head());
        self.trial.touched = touched;
        self.trial.touch_error_mm = Some(worst * 1000.0);
        if !touched {
            self.trial.failure = Some(format!("reach held {:.1} mm from the mark", worst * 1000.0));
        }
    }

    /// Why a marked trial did not touch, from what the board reported.
    fn diagnose(&self) -> Option<String> {
        if !self.marked || self.trial.touched {
            return None;
        }
        if self.mark.is_none() {
            return Some(if self.trial.false_reach {
                "ended before the mark appeared: a false reach".into()
            } else {
                "ended before the mark appeared".into()
            });
        }
        if let Some(f) = &self.trial.failure {
            return Some(f.clone());
        }
        let after: Vec<&Detection> = self
            .detections
            .iter()
            .filter(|(t, _)| *t >= self.cfg.mark_at_us)
            .map(|(_, d)| d)
            .collect();
        let seen = after.iter().filter(|d| d.blob.is_some()).count();
        let sent = self.frames_with_mark;
        // Frames the board never answered were lost on the link, not missed by detection.
        let lost = sent.saturating_sub(after.len());
        Some(match (self.stage, seen) {
            _ if after.is_empty() => {
                format!("link: no answer from the board to any of the {sent} frames with the mark")
            }
            (_, 0) if lost > 0 => format!(
                "detection: no blob in the {} answered frames with the mark \
                 (link: {lost} of {sent} got no answer)",
                after.len()
            ),
            (_, 0) => format!("detection: no blob in {} frames with the mark", after.len()),
            (Stage::Watching, n) => format!("confirm: blob in only {n} of {} frames", after.len()),
            (Stage::Reaching { .. }, _) => {
                "motion: the arm never settled at the reach target".into()
            }
            _ => "unknown".into(),
        })
    }
}

/// Runs one trial with the in-process board. `seed` makes the trial (mark, noise, link faults).
pub fn run_trial_inproc(
    blob: &[u8],
    camera: Camera,
    cfg: &EpisodeConfig,
    index: usize,
    seed: u64,
) -> Result<Trial> {
    let mut board = inproc_board(blob);
    // As the QEMU image: wired to either bus, the trial's host chooses.
    board.await_servo_bus();
    let mut log = Vec::new();
    let log_bus = cfg.log_bus;
    let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| {
        if log_bus {
            board.poll(now, h, &mut Tee { inner: s, log: &mut log })
        } else {
            board.poll(now, h, s)
        }
    };
    let (mut trial, _) = run_trial_with(&mut fw, camera, cfg, index, seed)?;
    trial.bus_bytes = log;
    // In-process the board's own counters are at hand (a GetStatus would report the same).
    let s = board.status();
    end_with_status(&mut trial, &s);
    Ok(trial)
}

/// A servo bus end that keeps a copy of what is written to it.
pub struct Tee<'a> {
    pub inner: &'a mut LinkEnd,
    pub log: &'a mut Vec<u8>,
}

impl embedded_io::ErrorType for Tee<'_> {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Read for Tee<'_> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        embedded_io::Read::read(self.inner, buf)
    }
}

impl embedded_io::ReadReady for Tee<'_> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        embedded_io::ReadReady::read_ready(self.inner)
    }
}

impl embedded_io::Write for Tee<'_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = embedded_io::Write::write(self.inner, buf)?;
        self.log.extend_from_slice(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        embedded_io::Write::flush(self.inner)
    }
}

/// A trial's end: the board's last status into its counters and, at the trial's end, its log.
pub fn end_with_status(trial: &mut Trial, s: &Status) {
    add_board_counters(trial, s);
    if let Some(l) = &mut trial.log {
        l.status((trial.sim_s * 1e6) as u64, s);
    }
}

/// Adds the board's link counters and watchdog trips to a trial's.
pub fn add_board_counters(trial: &mut Trial, s: &Status) {
    trial.crc_errors += s.host_link.crc_errors + s.servo_link.crc_errors;
    trial.resyncs += s.host_link.resyncs() + s.servo_link.resyncs();
    trial.watchdog_trips += s.face_watchdog_trips + s.servo_watchdog_trips;
}

/// Runs one trial with any firmware; returns the trial (with the sim side's counters) and the
/// last status the board sent, if any.
pub fn run_trial_with<F: world::Firmware>(
    fw: &mut F,
    camera: Camera,
    cfg: &EpisodeConfig,
    index: usize,
    seed: u64,
) -> Result<(Trial, Option<Status>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let marked = !rng.gen_bool(cfg.no_mark_share.clamp(0.0, 1.0));
    let mut mark_rng = ChaCha8Rng::seed_from_u64(seed);
    mark_rng.set_stream(1);
    let mut scene_rng = ChaCha8Rng::seed_from_u64(seed);
    scene_rng.set_stream(2);
    let scene = SceneState::new(cfg.scene, scene_rng);
    let (delay_us, babbles) = (scene.delay_us, scene.babbles);
    // On a stream of its own: the fixed light's trials keep their draws.
    let mut light_rng = ChaCha8Rng::seed_from_u64(seed);
    light_rng.set_stream(3);
    let (light, light_offset_us) = match cfg.light_span {
        Some(r) => (LightSchedule::new(cfg.light, r.span_us, &mut ChaCha8Rng::seed_from_u64(r.seed)), r.offset_us),
        None => (LightSchedule::new(cfg.light, cfg.mark_at_us + cfg.watch_us, &mut light_rng), 0),
    };
    let mut sc = Scenario {
        cfg,
        camera,
        rng,
        mark_rng,
        scene,
        port: HostPort::default(),
        faces: FaceLink::new(FACE_ACK_TIMEOUT_US),
        last_reach_frame: None,
        marked,
        mark: None,
        next_frame_us: 0,
        next_sample_us: 0,
        stage: Stage::Watching,
        target: None,
        held: Vec::new(),
        trial: Trial {
            index,
            scene: cfg.scene.name().into(),
            delay_ms: (cfg.scene == Scene::Delayed).then(|| delay_us as f64 / 1000.0),
            other_babbles: (cfg.scene == Scene::Other).then_some(babbles),
            ..Default::default()
        },
        error: None,
        status: None,
        detections: Vec::new(),
        frames_with_mark: 0,
        log: crate::rosbag::session::SessionLog::for_episode(cfg.mcap.as_ref(), cfg.live.as_ref()),
        light,
        light_offset_us,
        imperfect: cfg.camera.with_seed(seed ^ 0xCA3E_7A01),
        last_shot: None,
    };
    let wcfg = cfg.world(seed);
    let (w, report) = world::run(
        &wcfg,
        fw,
        |w: &mut World| match sc.step(w) {
            Ok(f) => f,
            Err(e) => {
                sc.error = Some(e);
                Flow::Stop
            }
        },
        cfg.max_us(),
    )
    .map_err(|e| anyhow!("trial {index}: {e}"))?;
    if let Some(e) = sc.error.take() {
        return Err(e.context(format!("trial {index}")));
    }
    sc.trial.failure = sc.diagnose();
    sc.trial.ended_before_mark = sc.marked && sc.mark.is_none();
    let mut t = sc.trial.clone();
    t.limit_violations = w.servos.counters().limit_violations;
    t.link = sc.faces.stats;
    let bus = w.servos.frame_counters();
    let pc = sc.port.counters();
    t.crc_errors = bus.crc_errors + pc.crc_errors;
    t.resyncs = bus.resyncs() + pc.resyncs();
    if let Some(d) = w.servos.dynamixel() {
        // The servos refuse a Goal Position outside their limits; either way it is counted.
        t.limit_violations += d.counters().limit_violations;
        t.crc_errors += d.rx_counters().crc_errors;
        t.resyncs += d.rx_counters().errors() - d.rx_counters().crc_errors;
    }
    t.sim_s = report.end_us as f64 * 1e-6;
    t.wall_s = report.wall_s;
    if let Some(mut l) = sc.log.take() {
        l.outcome(0, &format!("trial {index}"), &t, (t.mark.is_some() && !t.touched) || t.false_reach);
        l.close()?;
        t.log = Some(l);
    }
    Ok((t, sc.status))
}

/// Seed of trial `i` of a run seeded `seed`.
pub fn trial_seed(seed: u64, i: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((i as u64).wrapping_mul(0x2545_F491_4F6C_DD1D))
        .wrapping_add(1)
}

/// Runs `n` in-process trials, `cfg.parallel` at a time; `progress` is told after each.
pub fn run_inproc(
    blob: &[u8],
    cfg: &EpisodeConfig,
    n: usize,
    seed: u64,
    progress: &(dyn Fn(&Trial) + Sync),
) -> Result<Vec<Trial>> {
    let model = Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let renderer = Renderer::new(cfg.robot);
    let next = std::sync::atomic::AtomicUsize::new(0);
    // Reserve no more than a small start: `n` comes from the command line.
    let results = std::sync::Mutex::new(Vec::with_capacity(n.min(1024)));
    let first_error = std::sync::Mutex::new(None);
    std::thread::scope(|s| {
        for _ in 0..cfg.parallel.max(1).min(n.max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                if i >= n || first_error.lock().unwrap().is_some() {
                    return;
                }
                let camera = Camera {
                    renderer: &renderer,
                    cropper: &cropper,
                };
                match run_trial_inproc(blob, camera, cfg, i, trial_seed(seed, i)) {
                    Ok(t) => {
                        progress(&t);
                        results.lock().unwrap().push(t);
                    }
                    Err(e) => {
                        first_error.lock().unwrap().get_or_insert(e);
                    }
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().unwrap() {
        return Err(e);
    }
    let mut v = results.into_inner().unwrap();
    v.sort_by_key(|t| t.index);
    Ok(v)
}

/// Runs `n` in-process trials one after another as one long run of robot time: the light's
/// plan spans the run (`cfg.light` over `n` trials of `mark_at + watch`, each trial starting
/// where the last ended), and each trial's board takes over what the previous one learnt of
/// the room and its clock (the world and the links are fresh each trial). Returns the trials
/// and the room's state at the end.
pub fn run_one_board(
    blob: &[u8],
    cfg: &EpisodeConfig,
    n: usize,
    seed: u64,
    progress: &(dyn Fn(&Trial) + Sync),
) -> Result<(Vec<Trial>, msr_shared::msg::RoomReport)> {
    let model = Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let renderer = Renderer::new(cfg.robot);
    let span_us = n as u64 * (cfg.mark_at_us + cfg.watch_us);
    let mut carried: Option<msr_firmware::room::Room> = None;
    let mut offset_us = 0u64;
    let mut trials = Vec::with_capacity(n.min(1024));
    let mut room = None;
    for i in 0..n {
        let mut c = cfg.clone();
        c.light_span = Some(LightSpan { seed, span_us, offset_us });
        let mut board = inproc_board(blob);
        board.await_servo_bus();
        let mut room_in = carried.take();
        // The board's clock runs on across trials, so what it learnt keeps its times.
        let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| {
            board.poll(offset_us + now, h, s);
            // After the first poll: the board has loaded its model (which resets the room).
            if let Some(r) = room_in.take() {
                board.set_room(r);
            }
        };
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let (mut trial, _) = run_trial_with(&mut fw, camera, &c, i, trial_seed(seed, i))?;
        let s = board.status();
        end_with_status(&mut trial, &s);
        carried = Some(board.room().clone());
        room = Some(s.room);
        offset_us += (trial.sim_s * 1e6) as u64;
        progress(&trial);
        trials.push(trial);
    }
    Ok((trials, room.unwrap_or(msr_firmware::room::Room::new().report(false))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trial_seeds_wrap_and_differ() {
        // Debug builds check overflow: large indices and seeds must wrap, not panic.
        let seeds: Vec<u64> = (0..300).map(|i| trial_seed(u64::MAX, i)).collect();
        let mut unique = seeds.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), seeds.len());
        assert_eq!(trial_seed(0, 0), 1);
        assert_ne!(trial_seed(0, 7), trial_seed(1, 7));
    }

    #[test]
    fn a_gate_records_joint_is_its_statistics_over_the_tolerances() {
        let gate = msr_shared::blob::SelfGate {
            amplitude: 0.07,
            gain: 296.0,
            gain_tol: 0.02,
            rest_tol: 0.5,
            hold_tol: 0.4,
            level_tol: 0.2,
            line_tol: Some(0.25),
            joint_tol: Some(0.875),
            latency_ms: 250,
            timeout_ms: 2500,
            min_frames: 2,
        };
        let report = GateReport {
            frame: 9,
            decision: GateDecision::Reject,
            gain_ratio: 1.01,
            rest_px: 0.25,
            hold_px: 0.2,
            level_px: 0.1,
            line_px: 0.125,
            unlike: 0,
            salient: [50.0, 60.0, 70.0],
            frames: [2, 2],
            elapsed_ms: 1600,
        };
        let mut trial = Trial::default();
        trial.gate.push(GateRecord::of(2_000_000, &report));
        // Undecided: no statistics, no joint.
        trial.gate.push(GateRecord::of(5_000_000, &GateReport { decision: GateDecision::Undecided(msr_shared::msg::GateUndecided::Timeout), gain_ratio: f32::NAN, ..report }));
        assert_eq!(trial.gate[0].joint, None);
        add_gate_joints(std::slice::from_mut(&mut trial), &gate);
        // Each statistic half its tolerance: 5 x 0.25.
        let j = trial.gate[0].joint.unwrap();
        assert!((j - 1.25).abs() < 1e-3, "{j}");
        assert_eq!(trial.gate[1].joint, None);
        // A two-stage gate leaves the line out.
        let two = msr_shared::blob::SelfGate { line_tol: None, joint_tol: None, ..gate };
        assert!((trial.gate[0].joint_under(&two).unwrap() - 1.0).abs() < 1e-3);
        let json = serde_json::to_value(&trial.gate[0]).unwrap();
        assert!((json["joint"].as_f64().unwrap() - 1.25).abs() < 1e-3);
    }
}
