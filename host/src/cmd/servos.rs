//! `msr servos`: the robot's emulated servos on a serial line until interrupted, so that any
//! Dynamixel software (Dynamixel Wizard, DynamixelSDK, the `dynamixel2` crate) can ping, read
//! and write them. With no `--port`, on a new pseudo-terminal whose path it prints.
use anyhow::{Context, Result};
use msr_sim::servo::serve::{serve, servos};
use msr_sim::dynamixel::DxlConfig;
use msr_sim::Robot;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

/// The protocol the emulated servos speak.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Bus {
    /// Dynamixel Protocol 2.0: XM430-W350 servos, IDs of the default joint map
    Dynamixel,
}

/// `msr servos`'s flags: the bus, the robot, the port, how long, and the byte log.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The servos' protocol
    #[arg(long, value_enum, default_value_t = Bus::Dynamixel)]
    pub bus: Bus,
    /// The robot whose servos these are (both robots have the same joints and IDs)
    #[arg(long, default_value = "red")]
    pub robot: Robot,
    /// A serial port to serve on; default: a new PTY
    #[arg(long)]
    pub port: Option<String>,
    /// Line speed on `--port` (a PTY ignores it)
    #[arg(long, default_value_t = 1_000_000)]
    pub baud: u32,
    /// Stop after this many seconds (default: until interrupted)
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Also write every byte received to this file
    #[arg(long)]
    pub bus_log: Option<PathBuf>,
}

/// Serves the robot's servos on `--port` or a new PTY (whose path it prints) until interrupted
/// or `--seconds` have passed.
pub fn run(a: Args) -> Result<()> {
    let Bus::Dynamixel = a.bus;
    let cfg = DxlConfig { baud: a.baud, ..DxlConfig::default() };
    let mut bus = servos(cfg.clone()).map_err(anyhow::Error::msg)?;
    let stop = AtomicBool::new(false);
    let mut log = match &a.bus_log {
        // Made only when the first byte comes: a run that fails first leaves the old log.
        Some(p) => Some(crate::fsio::LazyLog::new(p)?),
        None => None,
    };
    let ids: Vec<String> = cfg.map.iter().map(|e| format!("{} {}", e.joint.name(), e.id)).collect();
    let describe = |path: &str| {
        format!(
            "{} robot: emulated XM430-W350 servos ({}) on {path}, Protocol 2.0",
            a.robot.name(),
            ids.join(", ")
        )
    };
    std::thread::scope(|s| -> Result<()> {
        if let Some(secs) = a.seconds {
            let stop = &stop;
            s.spawn(move || {
                std::thread::sleep(std::time::Duration::from_secs_f64(secs.max(0.0)));
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
            });
        }
        let log = log.as_mut().map(|f| f as &mut dyn Write);
        let served = match &a.port {
            Some(p) => {
                let mut port = serialport::new(p, a.baud)
                    .timeout(std::time::Duration::from_millis(1))
                    .open()
                    .with_context(|| format!("opening {p}"))?;
                eprintln!("{}", describe(p));
                serve(&mut bus, &mut port, &stop, log)?
            }
            None => {
                let mut pty = msr_sim::pty::Pty::open()?;
                // The path on stdout alone, for scripts; the rest on stderr.
                println!("{}", pty.path());
                std::io::stdout().flush()?;
                eprintln!("{}", describe(pty.path()));
                serve(&mut bus, pty.master(), &stop, log)?
            }
        };
        eprintln!("served: {} bytes in, {} bytes out", served.bytes_in, served.bytes_out);
        Ok(())
    })
}
