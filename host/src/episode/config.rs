//! How trials run: the firmware's backend, the servo bus, the faults, the light and the timings.
use super::scene::Scene;
use msr_shared::msg::{Config, ServoBusKind};
use msr_sim::kin::ArmError;
use msr_sim::imperfect::Imperfections;
use msr_sim::light::LightPlan;
use msr_sim::link::FaultConfig;
use msr_sim::servo::ServoConfig;
use msr_sim::world::WorldConfig;
use msr_sim::Robot;
use serde::{Deserialize, Serialize};

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
    /// The backend's name as the command line and the JSON summary spell it.
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
    /// The protocol's name as the command line and the JSON summary spell it.
    pub fn name(self) -> &'static str {
        match self {
            ServoBus::Framed => "framed",
            ServoBus::Dynamixel => "dynamixel",
        }
    }

    /// The protocol as the board's `UseServoBus` message names it.
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
    /// The robot the renderer draws (its looks); the model must be one trained on it.
    pub robot: Robot,
    /// What stands in front of the robot.
    pub scene: Scene,
    /// The servo bus's protocol; the PC tells the board at the start of each trial.
    pub servo_bus: ServoBus,
    /// Keep the bytes the board sends on the servo bus (each trial's
    /// [`Trial::bus_bytes`](super::Trial::bus_bytes)).
    pub log_bus: bool,
    /// Share of trials with no mark.
    pub no_mark_share: f64,
    /// Time between the camera frames the PC sends, simulated microseconds.
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
    /// The light's plan spans a run of trials rather than each trial
    /// ([`run_one_board`](super::run_one_board)).
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
    /// How the sim's left arm differs from its drawing, which the board and the trainer know:
    /// the camera sees this arm and the touch judge measures its fingertip.
    pub arm_error: ArmError,
    /// A touch: every held sample of the fingertip within this distance of the mark, mm.
    pub touch_radius_mm: f64,
}

/// `robot`'s arm at an arm-error `level` (0 exact, 1 or 2: [`ArmError::LEVELS`]), drawn for the
/// robot from a run's `seed`: each robot its own arm, the same for every trial of the run. `None`
/// for a level that does not exist.
pub fn arm_of(robot: Robot, level: u8, seed: u64) -> Option<ArmError> {
    ArmError::draw(level, seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(robot as u64))
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
    /// The defaults for `robot`: the mirror scene on the framed bus, no faults, a frame every
    /// 100 ms, the mark at 0.4 s on 80 % of trials, up to 4 trials at once.
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
            arm_error: ArmError::EXACT,
            touch_radius_mm: msr_sim::kin::TOUCH_RADIUS_M * 1000.0,
        }
    }

    /// Faults on both directions of the chosen links: `f`'s rates and bursts replace theirs, its
    /// disconnects are added to theirs.
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

    pub(super) fn world(&self, seed: u64) -> WorldConfig {
        let mut w = WorldConfig::default().seeded(seed);
        w.host_link.a_to_b = self.host_faults.clone();
        w.host_link.b_to_a = self.host_faults.clone();
        w.servo_link.a_to_b = self.servo_faults.clone();
        w.servo_link.b_to_a = self.servo_faults.clone();
        w.pace = self.pace;
        w.arm_error = self.arm_error;
        w.servo = ServoConfig { noise_seed: seed, ..self.servo };
        if self.servo_bus == ServoBus::Dynamixel {
            w.servo_link.baud = 1_000_000;
            w.dynamixel = Some(msr_sim::dynamixel::DxlConfig::default());
        }
        w
    }

    pub(super) fn max_us(&self) -> u64 {
        // Mark, watch window, a reach at speed 0.1 (under 4 s for any IK posture), the judged
        // hold, and room for a watchdog recovery and a second reach.
        self.mark_at_us + self.watch_us + 2 * (4_000_000 + self.judge_hold_us)
    }
}
