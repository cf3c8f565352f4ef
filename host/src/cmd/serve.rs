//! `msr serve`: an emulated board on a new pseudo-terminal until interrupted (or `--seconds`),
//! the in-process firmware or the firmware image in QEMU, with the sim's servos behind it.
//! `msr run --port PATH` and `msr record --port PATH` talk to it as to a board on USB.
use crate::episode::sim_board::{ServeConfig, SimBoard};
use crate::episode::Backend;
use anyhow::Result;
use msr_sim::Robot;
use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `msr serve`'s flags: the backend, the robot, the model, the link's faults, the flash file and
/// the servos.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// What runs the firmware: this process, or the thumbv7em image in qemu-system-arm
    #[arg(long, value_enum, default_value_t = Backend::Inproc)]
    pub backend: Backend,
    /// The robot whose servos these are (both robots have the same joints)
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// A model blob (.msrm) the board starts with; without one the board waits for an upload
    /// (`msr run --upload`)
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Stop after this many seconds (default: until interrupted)
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Faults on the host link (in-process board)
    #[command(flatten)]
    pub noise: super::line_noise::LineNoise,
    /// Seed of the host link's faults
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Keep the board's flash in this file (created when missing): an uploaded model and the
    /// saved statistics are there again after a restart. Either backend reads the other's file;
    /// a model committed there runs instead of --model
    #[arg(long, value_name = "FILE")]
    pub flash: Option<PathBuf>,
    /// How the emulated servos hold their goals.
    #[command(flatten)]
    pub servos: super::ServoHold,
}

/// Starts the emulated board, prints its PTY's path on stdout, and serves until interrupted or
/// `--seconds` have passed.
pub fn run(a: Args) -> Result<()> {
    let model = match &a.model {
        Some(p) => Some(crate::fsio::read_blob(p)?),
        None => None,
    };
    let mut cfg = ServeConfig::new(a.backend, model);
    cfg.host_faults = a.noise.faults();
    cfg.seed = a.seed;
    cfg.flash = a.flash.clone();
    cfg.servo = a.servos.config();
    let board = SimBoard::serve(cfg)?;
    // The path on stdout alone, for scripts; the rest on stderr.
    println!("{}", board.path());
    std::io::stdout().flush()?;
    eprintln!(
        "{} robot: emulated board ({}) on {}, host link protocol {}; servos emulated",
        a.robot.name(),
        a.backend.name(),
        board.path(),
        msr_shared::frame::PROTOCOL_VERSION
    );
    if a.backend == Backend::Qemu {
        eprintln!(
            "the QEMU board runs slower than real time while bytes flow (its emulated UART carries tens of KB/s, \
             the line 92): give an upload time, `msr run --upload --timeout-ms 60000`"
        );
    }
    let t0 = Instant::now();
    let limit = a.seconds.map(Duration::from_secs_f64);
    while !board.finished() && limit.is_none_or(|l| t0.elapsed() < l) {
        // A flash file removed under the board: what it accepts from now on is kept nowhere,
        // so it stops rather than say "uploaded into flash".
        if let Err(e) = board.check_flash() {
            let _ = board.stop();
            return Err(e);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let served = board.stop()?;
    eprintln!(
        "served {:.1} s ({:.1} s of the board's clock): {} bytes in, {} bytes out, {} limit violations; board: {:?}",
        t0.elapsed().as_secs_f64(),
        served.board_s,
        served.to_board_bytes,
        served.from_board_bytes,
        served.limit_violations,
        served.status.mode
    );
    Ok(())
}
