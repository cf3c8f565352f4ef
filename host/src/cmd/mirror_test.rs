//! `msr mirror-test`: run mirror-test episodes: sim world, emulated links, firmware in-process or
//! in QEMU. See [`crate::episode`] for what one trial is.
use crate::episode::{self, Backend, EpisodeConfig, FaultLinks, Scene, ServoBus, Summary, Trial};
use msr_sim::link::FaultConfig;
use anyhow::{bail, Result};
use msr_sim::Robot;
use std::path::PathBuf;

/// `msr mirror-test`'s flags: the model, the trials, the world, the links, the servos and the
/// outputs.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model blob (.msrm), with its face template and reach network
    #[arg(long)]
    pub model: PathBuf,
    /// Trials to run (1..=100000)
    #[arg(long, default_value_t = 20)]
    pub trials: usize,
    /// Seed of the trials (which are marked, the marks, the scene, the light, the link faults,
    /// the camera noise); the same seed gives the same trials
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// What runs the firmware: this process, or the thumbv7em image in qemu-system-arm
    #[arg(long, value_enum, default_value_t = Backend::Inproc)]
    pub backend: Backend,
    /// Which robot: red (the real red Nao's look) or skin (grey covers with skin taxels)
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// The servo bus's protocol
    #[arg(long, value_enum, default_value_t = ServoBus::Framed)]
    pub servo_bus: ServoBus,
    /// What stands in front of the robot: its mirror image, another robot of the same look
    /// (marks on its face), or the mirror image through a video delay of 0.3-2 s
    #[arg(long, value_enum, default_value_t = Scene::Mirror)]
    pub scene: Scene,
    /// How the light changes over each trial: fixed, drift (exposure ramps), step (a lamp
    /// switches), auto-exposure (the camera's own gain loop)
    #[arg(long, value_enum, default_value_t = super::light::RunLight::Fixed)]
    pub light: super::light::RunLight,
    /// The camera's imperfections, on every frame
    #[command(flatten)]
    pub imperfect: super::imperfect::CameraFlags,
    /// The sim's arm against its drawing
    #[command(flatten)]
    pub arm: super::ArmFlags,
    /// A touch: every held sample of the fingertip within this distance of the mark, mm
    /// (1..=100)
    #[arg(long, default_value_t = 20.0, value_parser = super::touch_radius)]
    pub touch_radius_mm: f64,
    /// Run the trials one after another as one long run of robot time: the light's plan spans
    /// the whole run (see --light turn) and each trial's board takes over the previous one's
    /// clock and what it learnt of the room; the world is fresh each trial (in-process only)
    #[arg(long)]
    pub one_board: bool,
    /// Let the board learn the room's light as it runs (its online self-calibration); off: it
    /// keeps the model's own statistics, for comparison
    #[arg(long, value_enum, default_value_t = OnOff::On)]
    pub learn_room: OnOff,
    /// The self gate: as the model blob has it, off (the paper's behaviour), or on (calibrated
    /// now for --robot), to compare the same model with and without it
    #[arg(long, value_enum, default_value_t = GateArg::Model)]
    pub self_gate: GateArg,
    /// Write the bytes the board sent on the servo bus to this file (in-process; all trials,
    /// in trial order)
    #[arg(long)]
    pub bus_log: Option<PathBuf>,
    /// Faults on the links `--faults-on` names
    #[command(flatten)]
    pub noise: super::line_noise::LineNoise,
    /// Which links the faults (--ber, bursts, --disconnect-ms) hit
    #[arg(long, value_enum, default_value_t = FaultLinks::Both)]
    pub faults_on: FaultLinks,
    /// Cut the links for this many milliseconds in every trial
    #[arg(long)]
    pub disconnect_ms: Option<u64>,
    /// When the cut starts, milliseconds into the trial
    #[arg(long, default_value_t = 1500)]
    pub disconnect_at_ms: u64,
    /// Noise on the servos' encoders, counts RMS (0..=4), drawn every millisecond before the
    /// encoder rounds: a servo holding still reads the counts around its position by turns,
    /// as a real one can
    #[arg(long, default_value_t = 0.0, value_parser = super::encoder_noise)]
    pub encoder_noise: f64,
    /// How the emulated servos hold their goals.
    #[command(flatten)]
    pub servos: super::ServoHold,
    /// Share of trials without a mark
    #[arg(long, default_value_t = 0.2)]
    pub no_mark_share: f64,
    /// Trials run at once in-process (each takes two threads); default: the machine's cores, at
    /// most 4. QEMU trials run one after another on one QEMU, reset between trials.
    #[arg(long)]
    pub parallel: Option<usize>,
    /// Also write every trial (mark, reach, error, why it failed) to this JSON file
    #[arg(long)]
    pub trials_out: Option<PathBuf>,
    /// Print the summary as JSON
    #[arg(long)]
    pub json: bool,
    /// Also write the trials as an MCAP file (ROS 2 messages: frames, face crops, saliency,
    /// annotations, joints, board status) for Foxglove or `ros2 bag play`
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Serving the trials live to Foxglove.
    // With --live the trials run one at a time unless --parallel says otherwise.
    #[command(flatten)]
    pub live: super::live::LiveFlags,
}

/// A switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    /// Enabled
    On,
    /// Disabled
    Off,
}

/// Whose self gate the trials run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GateArg {
    /// The model blob's (none if it has none).
    Model,
    /// None.
    Off,
    /// One calibrated now for the robot (replacing the blob's).
    On,
}

/// The blob the trials run: `blob` with its self gate as `g` asks.
pub fn gated_blob(blob: Vec<u8>, g: GateArg, robot: Robot) -> Result<Vec<u8>> {
    use crate::train::self_gate::{attach, detach, GateCalibration};
    Ok(match g {
        GateArg::Model => blob,
        GateArg::Off => detach(&blob)?,
        GateArg::On => {
            let (gated, report) = attach(&blob, robot, &GateCalibration::default())?;
            eprintln!("self gate calibrated now: {}", serde_json::to_string(&report)?);
            gated
        }
    })
}

/// Refuses a model made for another robot's face, which the trials would run silently: the board
/// refuses every frame as no face (nothing is ever reached for), or finds a mark all over the
/// clean face (every trial a false reach). The test: one clean frame of each robot without a
/// mark, at the home posture, through the firmware's pipeline. No face on `robot`'s: refused. A
/// mark on `robot`'s clean face: refused when another robot's clean face fits the model, else a
/// warning (a weak model, or one of a real robot, may find one).
pub fn check_robot(blob: &[u8], robot: Robot) -> Result<()> {
    use crate::detect::pipeline::Verdict;
    let model = msr_shared::blob::Model::parse(blob).map_err(|e| anyhow::anyhow!("model blob: {e}"))?;
    // `None`: it fits; otherwise what the board makes of the robot's clean face, and whether
    // that is the face refused.
    let misfit = |r: Robot| -> Option<(&'static str, bool)> {
        let head = [msr_shared::joints::HOME_POSTURE[0], msr_shared::joints::HOME_POSTURE[1]];
        let pose = msr_sim::body::BodyPose::head(head[0] as f64, head[1] as f64);
        let frame = msr_sim::render::Renderer::new(r).render(&pose, None, &msr_sim::render::Variation::CLEAN);
        let grey = crate::data::crop::to_grey(&image::DynamicImage::ImageRgb8(frame.rgb));
        let det = crate::detect::cropper_of(&model)
            .and_then(|c| c.crop(&grey))
            .and_then(|face| crate::detect::fixed::detect(&model, &face, head));
        match det {
            Err(_) => Some(("its face is not found in the frame", true)),
            Ok(d) if d.light.verdict != Verdict::Face => Some(("the board would refuse every frame as no face", true)),
            Ok(d) if d.blob.is_some() => Some(("the board finds a mark on its clean face", false)),
            Ok(_) => None,
        }
    };
    let Some((why, no_face)) = misfit(robot) else { return Ok(()) };
    let fits: Vec<&str> = Robot::ALL.iter().filter(|&&r| r != robot && misfit(r).is_none()).map(|r| r.name()).collect();
    match fits.first() {
        Some(other) => bail!(
            "the model was made for robot {} (on robot {}'s face {why}): pass --robot {other}",
            fits.join(" or "),
            robot.name()
        ),
        None if no_face => bail!("the model does not fit robot {}'s face: {why}", robot.name()),
        None => {
            eprintln!("warning: {why} (robot {}, home posture): expect false reaches", robot.name());
            Ok(())
        }
    }
}

/// The episodes' configuration for these flags; an error for a flag the backend cannot honour.
pub fn config(a: &Args) -> Result<EpisodeConfig> {
    if !(0.0..=1.0).contains(&a.no_mark_share) {
        bail!("--no-mark-share must be in 0..=1, got {}", a.no_mark_share);
    }
    let faults = FaultConfig {
        disconnects: a
            .disconnect_ms
            .map(|ms| (a.disconnect_at_ms * 1000, ms * 1000))
            .into_iter()
            .collect(),
        ..a.noise.faults()
    };
    let mut c = EpisodeConfig::new(a.robot).with_faults(&faults, a.faults_on);
    c.no_mark_share = a.no_mark_share;
    c.servo_bus = a.servo_bus;
    c.scene = a.scene;
    c.light = a.light.into();
    c.camera = a.imperfect.imperfections(a.seed);
    c.arm_error = a.arm.arm(a.robot, a.seed);
    c.touch_radius_mm = a.touch_radius_mm;
    c.log_bus = a.bus_log.is_some();
    c.learn_room = a.learn_room == OnOff::On;
    c.servo = msr_sim::servo::ServoConfig { encoder_noise: a.encoder_noise, ..a.servos.config() };
    if a.one_board && a.backend != Backend::Inproc {
        return Err(super::usage("--one-board needs --backend inproc"));
    }
    if a.bus_log.is_some() && a.backend != Backend::Inproc {
        return Err(super::usage("--bus-log needs --backend inproc"));
    }
    if let Some(p) = a.parallel {
        c.parallel = p.max(1);
    }
    Ok(c)
}

/// Runs the trials, printing one line per trial and then the summary (a line or JSON), and
/// writes the files the flags ask for.
pub fn run(a: Args) -> Result<()> {
    if a.trials == 0 {
        bail!("--trials must be at least 1");
    }
    let cfg = config(&a)?;
    let raw = crate::fsio::read_blob(&a.model)?;
    check_robot(&raw, a.robot)?;
    let blob = gated_blob(raw, a.self_gate, a.robot)?;
    let mut cfg = cfg;
    if a.mcap.is_some() {
        cfg.mcap = Some(crate::rosbag::session::LogModel(blob.clone().into()));
    }
    let quiet = a.json;
    if a.live.live.is_some() && a.parallel.is_none() {
        cfg.parallel = 1;
    }
    let live = a.live.start(quiet)?;
    if let Some(l) = &live {
        cfg.live = Some(crate::rosbag::session::LiveTap { live: l.clone(), model: crate::rosbag::session::LogModel(blob.clone().into()) });
    }
    // The gate the trials run with (the blob's, after --self-gate).
    let gate = msr_shared::blob::Model::parse(&blob).ok().and_then(|m| m.self_gate);
    if !quiet {
        eprintln!(
            "mirror-test: {} {} trials of robot {} (seed {}), scene {}, self gate {}",
            a.trials,
            a.backend.name(),
            a.robot,
            a.seed,
            a.scene.name(),
            gate.map_or("off".to_string(), |g| format!("on ({g:?})"))
        );
    }
    let progress = |t: &Trial| {
        if !quiet {
            eprintln!("{}", describe(t));
        }
    };
    let (mut trials, room) = match a.backend {
        Backend::Inproc if a.one_board => {
            let (t, r) = episode::run_one_board(&blob, &cfg, a.trials, a.seed, &progress)?;
            (t, Some(r))
        }
        Backend::Inproc => (episode::run_inproc(&blob, &cfg, a.trials, a.seed, &progress)?, None),
        Backend::Qemu => (crate::episode::qemu::run_qemu(&blob, &cfg, a.trials, a.seed, &progress)?, None),
    };
    if let Some(g) = &gate {
        episode::add_gate_joints(&mut trials, g);
    }
    let mut s = episode::summarise(a.backend, a.robot, a.servo_bus, &trials);
    s.room = room;
    s.live = a.live.finish(live);
    // The summary first: a failing --trials-out or --bus-log write (checked up front, but a disk
    // can fill) must not lose it.
    if a.json {
        println!("{}", serde_json::to_string(&s)?);
    } else {
        println!("{}", readable(&s));
    }
    if let Some(p) = &a.bus_log {
        let bytes: Vec<u8> = trials.iter().flat_map(|t| t.bus_bytes.iter().copied()).collect();
        crate::fsio::write(p, bytes)?;
    }
    if let Some(p) = &a.trials_out {
        crate::fsio::write(p, serde_json::to_vec_pretty(&trials)?)?;
    }
    if let Some(p) = &a.mcap {
        let counts = crate::rosbag::session::write_logs(p, trials.iter().filter_map(|t| t.log.as_ref()))?;
        if !quiet {
            eprintln!("wrote {}: {}", p.display(), serde_json::to_string(&counts)?);
        }
    }
    Ok(())
}

/// One line per trial, for progress.
pub fn describe(t: &Trial) -> String {
    let what = match (&t.mark, t.false_reach, t.touched) {
        (_, true, _) => "FALSE REACH".to_string(),
        (None, _, _) if t.ended_before_mark => "ended before the mark appeared".to_string(),
        (None, _, _) => "no mark, no reach".to_string(),
        (Some(m), _, true) => format!(
            "{m}: touched, {:.1} mm, {:.0} ms",
            t.touch_error_mm.unwrap_or(f64::NAN),
            t.latency_ms.unwrap_or(f64::NAN)
        ),
        (Some(m), _, false) => format!("{m}: MISSED ({})", t.failure.as_deref().unwrap_or("?")),
    };
    let gate: Vec<String> = t
        .gate
        .iter()
        .map(|g| format!("{} {:.3} {:?}", g.decision, g.gain_ratio.unwrap_or(f32::NAN), g.salient.map(|v| v.map(|v| v.round()))))
        .collect();
    let gate = if gate.is_empty() { String::new() } else { format!(" gate: {}", gate.join(", ")) };
    let delay = t.delay_ms.map_or(String::new(), |d| format!(" (delay {d:.0} ms)"));
    format!(
        "trial {:>3}: {what}{delay}{gate} [{:.1} s sim, {:.2} s wall]",
        t.index, t.sim_s, t.wall_s
    )
}

/// The summary's one line (its [`Display`](std::fmt::Display)).
pub fn readable(s: &Summary) -> String {
    s.to_string()
}
