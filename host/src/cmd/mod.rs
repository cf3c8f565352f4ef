//! Argument parsing and dispatch for `msr`. Each command lives in its own module.
pub mod dataset;
pub mod blobs;
pub mod mirror_test;
pub mod demo;
pub mod run;
pub mod check;
pub mod servos;
pub mod train;
pub mod train_reach;
pub mod learn_reach;
pub mod quantize;
pub mod import;
pub mod detect;
pub mod eval;
pub mod bench;
pub mod serve;
pub mod record;
pub mod template;
pub mod line_noise;
pub mod status;
pub mod import_bag;
pub mod light;
pub mod imperfect;
pub mod camera_hold;
pub mod live;

use self::run as run_board;
use anyhow::Result;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// The whole `msr` command line: one subcommand and its flags.
#[derive(Parser, Debug)]
#[command(
    name = "msr",
    version,
    about = "Mirror self-recognition: a robot learns its face in a mirror, finds a mark, reaches for it"
)]
pub struct Cli {
    /// The subcommand to run, with its flags.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands of `msr`, each with the flags of its own module.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render a mirror dataset (frames, head angles, splits, marks) for one robot
    Dataset(dataset::Args),
    /// Train a decoder or autoencoder on a dataset and calibrate its error statistics
    Train(train::Args),
    /// Train the 2-10-5 reach network from mark positions to joint angles
    TrainReach(train_reach::Args),
    /// The sim's robot teaches itself its reach in the mirror, then trains the reach network
    LearnReach(learn_reach::Args),
    /// Turn a trained model into a fixed-point model blob and compare it with float
    Quantize(quantize::Args),
    /// Import the published model (safetensors, npy, template) into a model blob
    Import(import::Args),
    /// Find a mark in one camera frame with a model blob
    Detect(detect::Args),
    /// List the 8-connected blobs of a binary mask with the firmware's blob stage
    Blobs(blobs::Args),
    /// Evaluate detection on a dataset's test split (the paper's table)
    Eval(eval::Args),
    /// Instruction counts, memory and code size of the firmware pipeline
    Bench(bench::Args),
    /// Run mirror-test episodes: sim world, emulated links, firmware in-process or in QEMU
    MirrorTest(mirror_test::Args),
    /// Stream frames to a board over a serial port and print what it reports
    #[command(name = "run")]
    Run(run_board::Args),
    /// The robot's emulated servos on a serial port or a new PTY (Dynamixel Protocol 2.0)
    Servos(servos::Args),
    /// An emulated board (in-process or QEMU) with the sim's servos on a new PTY
    Serve(serve::Args),
    /// What a board runs: its model's CRC and origin, the saved statistics, its counters
    Status(status::Args),
    /// Record a training set on the robot: head babbling, frames with the reported head angles
    Record(record::Args),
    /// Cut a face template out of a camera frame
    Template(template::Args),
    /// From nothing to a report: dataset, training, reach, quantization, evaluation, episodes
    Demo(demo::Args),
    /// Import a ROS 2 bag (MCAP or SQLite3: camera images and joint states) as a dataset
    ImportBag(import_bag::Args),
}

/// `msr`'s argument parser: the derived one, with every flag that takes a value also taking a
/// negative number (`--ber -0.1` is a value that the range check refuses, not an unknown flag
/// `-0`).
pub fn command() -> clap::Command {
    Cli::command().mut_subcommands(|sc| {
        sc.mut_args(|a| {
            if a.get_action().takes_values() {
                a.allow_negative_numbers(true)
            } else {
                a
            }
        })
    })
}

/// Parses a command line (the first item is the program name).
pub fn parse_from<I, T>(args: I) -> Result<Cli, clap::Error>
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let mut c = command();
    let m = c.try_get_matches_from_mut(args)?;
    Cli::from_arg_matches(&m).map_err(|e| e.format(&mut c))
}

/// A clap error as one line: its first paragraph (and the list that follows a paragraph ending
/// in `:`, such as the missing arguments), without the usage and the `error: ` prefix.
pub fn clap_line(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let paras: Vec<&str> = text.split("\n\n").collect();
    let mut m = paras.first().copied().unwrap_or("bad arguments").trim().to_string();
    if m.ends_with(':') {
        if let Some(list) = paras.get(1) {
            m.push(' ');
            m.push_str(list);
        }
    }
    let m = m.split_whitespace().collect::<Vec<_>>().join(" ");
    m.strip_prefix("error: ").map(str::to_string).unwrap_or(m)
}

/// A flag value that does not parse or is out of range: `msr` exits with 2 (usage), as for the
/// values the parser itself refuses.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Encoder noise, counts RMS, 0..=4 (a clap value parser).
pub(crate) fn encoder_noise(s: &str) -> Result<f64, String> {
    number_within(s, 0.0..=4.0, "a noise between 0 and 4 counts")
}

/// The board's serial line: the flags of the commands that talk to a board.
#[derive(clap::Args, Debug, Clone)]
pub struct BoardLine {
    /// Serial port of the board (e.g. /dev/ttyACM0, or the PTY `msr serve` printed)
    #[arg(long)]
    pub port: String,
    /// Line rate, baud (1200..=20000000)
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
}

/// How the emulated servos hold: the flags `msr serve` and `msr mirror-test` share.
#[derive(clap::Args, Debug, Clone)]
pub struct ServoHold {
    /// Counts by which the pitch servos (head, shoulders) hold off their goals, -6..=6, as
    /// servos without an integral term do under their load
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = sag)]
    pub sag: f64,
    /// Static friction, counts (0..=3): every servo stops this far short of its goal, on the
    /// side it came from
    #[arg(long, default_value_t = 0.0, value_parser = dead_band)]
    pub dead_band: f64,
}

impl ServoHold {
    /// The emulated servos these flags ask for.
    pub fn config(&self) -> msr_sim::servo::ServoConfig {
        msr_sim::servo::ServoConfig { sag: self.sag, dead_band: self.dead_band, ..Default::default() }
    }
}

/// The sim's arm against its drawing: the flag `msr mirror-test`, `msr serve` and `msr run --sim`
/// share.
#[derive(clap::Args, Debug, Clone)]
pub struct ArmFlags {
    /// How the sim's arm differs from its drawing, which the board and the trainer know: 0
    /// exact; 1 joint zeros within +-1.5 deg and link lengths within +-2.5 %; 2 within +-3 deg and
    /// +-5 % (drawn for the robot from --seed)
    #[arg(long, value_name = "LEVEL", default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=2))]
    pub arm_error: u8,
}

impl ArmFlags {
    /// The arm of `robot` these flags ask for, drawn from `seed`.
    pub fn arm(&self, robot: msr_sim::Robot, seed: u64) -> msr_sim::kin::ArmError {
        crate::episode::arm_of(robot, self.arm_error, seed).unwrap_or(msr_sim::kin::ArmError::EXACT)
    }
}

/// A touch radius, mm, 1..=100 (a clap value parser).
fn touch_radius(s: &str) -> Result<f64, String> {
    number_within(s, 1.0..=100.0, "a touch radius between 1 and 100 mm")
}

/// A servo's dead band, counts, 0..=3 (a clap value parser).
fn dead_band(s: &str) -> Result<f64, String> {
    number_within(s, 0.0..=3.0, "a dead band between 0 and 3 counts")
}

/// A pitch servo's sag, counts, -6..=6 (a clap value parser): within the 0.01 rad the
/// episodes' judge allows an arm that holds a reach (6.5 counts).
fn sag(s: &str) -> Result<f64, String> {
    number_within(s, -6.0..=6.0, "a sag between -6 and 6 counts")
}

/// `s` as a number within `range`, or an error saying it is not `what`.
fn number_within(s: &str, range: std::ops::RangeInclusive<f64>, what: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if range.contains(&v) => Ok(v),
        _ => Err(format!("`{s}` is not {what}")),
    }
}

/// A [`Usage`] error.
pub fn usage(msg: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(Usage(msg.into()))
}

/// The exit code for an error: 2 when a flag value was at fault, else 1.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    let train_usage = |c: &(dyn std::error::Error + 'static)| {
        c.downcast_ref::<crate::train::ConfigError>().is_some_and(train::is_usage)
    };
    if e.chain().any(|c| c.is::<Usage>() || train_usage(c)) {
        2
    } else {
        1
    }
}

/// An error as one line: its causes joined by `: `, a cause that repeats the text before it
/// left out (image errors carry their own message twice), line breaks folded.
pub fn one_line(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for c in e.chain() {
        // The library names a configuration's fields; the user typed flags.
        let m = if let Some(t) = c.downcast_ref::<crate::train::ConfigError>() {
            train::flag_text(t)
        } else if let Some(t) = c.downcast_ref::<crate::record::OutError>() {
            record::flag_text(t)
        } else if let Some(t) = c.downcast_ref::<crate::rosbag::import::UnnamedJoints>() {
            import_bag::flag_text(t)
        } else {
            c.to_string()
        };
        let m = m.trim();
        if m.is_empty() || out.ends_with(m) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(m);
    }
    out.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// One command's flags parsed alone (`argv[0]` is the program name), for the commands' tests.
#[cfg(test)]
pub(crate) fn parse_args<A: clap::Args>(argv: &[&str]) -> Result<A, clap::Error> {
    #[derive(Parser)]
    struct One<A: clap::Args> {
        #[command(flatten)]
        args: A,
    }
    One::<A>::try_parse_from(argv).map(|o| o.args)
}

/// Runs a parsed command: its arguments and paths are checked first ([`check::check`]).
pub fn run(cli: Cli) -> Result<()> {
    check::check(&cli.command)?;
    match cli.command {
        Command::Dataset(a) => dataset::run(a),
        Command::Train(a) => train::run(a),
        Command::TrainReach(a) => train_reach::run(a),
        Command::LearnReach(a) => learn_reach::run(a),
        Command::Quantize(a) => quantize::run(a),
        Command::Import(a) => import::run(a),
        Command::Detect(a) => detect::run(a),
        Command::Blobs(a) => blobs::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Bench(a) => bench::run(a),
        Command::MirrorTest(a) => mirror_test::run(a),
        Command::Run(a) => run_board::run(a),
        Command::Servos(a) => servos::run(a),
        Command::Serve(a) => serve::run(a),
        Command::Record(a) => record::run(a),
        Command::Template(a) => template::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Status(a) => status::run(a),
        Command::ImportBag(a) => import_bag::run(a),
    }
}
