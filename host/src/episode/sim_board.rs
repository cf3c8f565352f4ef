//! A simulated board on a pseudo-terminal: the in-process firmware, or the
//! firmware image in QEMU, with the sim's servos, its host link bridged to a PTY, in real time,
//! so that `msr run --port PATH` (or any `serialport` code) talks to it exactly as it would to a
//! board on a USB serial port.
//!
//! Under QEMU the board runs in lockstep with the sim's 1 ms ticks (see [`crate::episode::qemu`])
//! and the world is paced to real time: where QEMU cannot keep up, the board's time runs slower
//! than the wall clock, never faster.
use crate::episode::{inproc_board, Backend};
use anyhow::{anyhow, bail, Result};
use msr_shared::msg::Status;
use msr_sim::link::{FaultConfig, LinkEnd};
use msr_sim::pty::{Pty, PtyBridge};
use msr_sim::world::{self, Flow, World, WorldConfig};
use msr_sim::servo::ServoConfig;
use std::sync::atomic::{AtomicBool, Ordering};
use std::path::PathBuf;
use std::sync::Arc;
use msr_firmware::{Board, ModelStore};
use std::thread::JoinHandle;

/// What the served board did, when it stopped.
#[derive(Debug)]
pub struct Served {
    /// The board's own status when the world stopped (its counters, model and room).
    pub status: Status,
    /// Servo targets the emulated servos refused: outside a joint's limits, not finite, or for
    /// a joint with no limits.
    pub limit_violations: u32,
    /// Bytes carried from the PTY to the board's host link.
    pub to_board_bytes: u64,
    /// Bytes carried from the board's host link to the PTY.
    pub from_board_bytes: u64,
    /// Seconds of the board's clock (the world's): behind the wall clock when the board cannot
    /// keep up (QEMU's emulated UARTs move tens of KB/s; the link's 921600 baud is 92 KB/s).
    pub board_s: f64,
}

/// A board served behind a pseudo-terminal on a thread of its own, until stopped or dropped.
pub struct SimBoard {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<Served>>>,
    /// The flash file's lock and watch, when the board keeps its flash in one.
    flash: Option<crate::flash_file::FlashWatch>,
}

/// What `msr serve` serves.
#[derive(Clone, Debug, PartialEq)]
pub struct ServeConfig {
    /// What runs the firmware: in-process or the image in QEMU.
    pub backend: Backend,
    /// The model the board starts with (built in, or uploaded to QEMU before serving).
    pub model: Option<Vec<u8>>,
    /// Faults on the host link (both directions, between the PTY and the board; in-process
    /// board only), seeded by `seed`: a noisy USB-serial line to test a host against.
    pub host_faults: FaultConfig,
    /// Seed of the links' fault draws.
    pub seed: u64,
    /// The board's flash in this file (created when missing): uploads and statistics survive
    /// a restart. Without it an upload lives in RAM until the server stops.
    pub flash: Option<PathBuf>,
    /// How the emulated servos move and hold (sag, friction).
    pub servo: ServoConfig,
}

impl ServeConfig {
    /// A clean line to the board `backend` runs, with `model` (or none) in it.
    pub fn new(backend: Backend, model: Option<Vec<u8>>) -> ServeConfig {
        ServeConfig { backend, model, host_faults: FaultConfig::default(), seed: 0, flash: None, servo: ServoConfig::default() }
    }

    /// The world the served board lives in: real time, this config's seed and servos.
    fn world(&self) -> WorldConfig {
        let mut w = WorldConfig { pace: Some(1.0), ..WorldConfig::default() }.seeded(self.seed);
        w.servo = self.servo;
        w
    }
}

impl SimBoard {
    /// Starts the board `cfg` names behind a new PTY.
    pub fn serve(cfg: ServeConfig) -> Result<SimBoard> {
        let world = cfg.world();
        match cfg.backend {
            Backend::Inproc => match cfg.flash {
                Some(path) => {
                    let builtin = cfg.model.as_deref().map(crate::flash_file::leak_aligned);
                    let (store, watch) = crate::flash_file::open_store(&path, msr_firmware::store::EMULATED, builtin)?;
                    let mut b = SimBoard::start_board(Box::new(msr_firmware::Board::new(store)), cfg.host_faults, world)?;
                    b.flash = Some(watch);
                    Ok(b)
                }
                None => SimBoard::start_board(inproc_or_empty(cfg.model.as_deref()), cfg.host_faults, world),
            },
            Backend::Qemu => {
                // `msr serve`'s flags give a burst length even without bursts: ask what they do.
                if !cfg.host_faults.is_clean() {
                    bail!("host-link faults are emulated for the in-process board only");
                }
                // Checked (or created, erased) and locked here, so that a wrong file or one in use
                // is refused in one line before QEMU starts; the image then reads it and writes
                // through.
                let watch = match &cfg.flash {
                    Some(path) => {
                        let cells = crate::flash_file::FileCells::open(path, msr_firmware::store::EMULATED.len() as usize)?;
                        Some(cells.watch(path)?)
                    }
                    None => None,
                };
                let mut b = SimBoard::start_qemu_in(cfg.model.as_deref(), cfg.flash.as_deref(), world)?;
                b.flash = watch;
                Ok(b)
            }
        }
    }

    /// Starts the firmware image in QEMU (with `blob` preloaded, if given) behind a new PTY.
    pub fn start_qemu(blob: Option<&[u8]>) -> Result<SimBoard> {
        SimBoard::start_qemu_with(blob, None)
    }

    /// As [`SimBoard::start_qemu`], with the board's flash in `flash_file` (see
    /// [`crate::episode::qemu::start_lockstep`]).
    pub fn start_qemu_with(blob: Option<&[u8]>, flash_file: Option<&std::path::Path>) -> Result<SimBoard> {
        SimBoard::start_qemu_in(blob, flash_file, ServeConfig::new(Backend::Qemu, None).world())
    }

    /// As [`SimBoard::start_qemu_with`], in the world `cfg` (its pace and servos).
    fn start_qemu_in(blob: Option<&[u8]>, flash_file: Option<&std::path::Path>, cfg: WorldConfig) -> Result<SimBoard> {
        let (mut ls, _) = crate::episode::qemu::start_lockstep(blob, flash_file)?;
        let pty = Pty::open()?;
        let path = pty.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new().name("qemu-board".into()).spawn(
            move || -> Result<Served> {
                let mut bridge = PtyBridge::new(pty);
                let mut io_error = None;
                let (mut ho, mut so) = (Vec::new(), Vec::new());
                let (w, _) = {
                    let mut fw = |_now: u64, he: &mut LinkEnd, se: &mut LinkEnd| {
                        if io_error.is_some() {
                            return;
                        }
                        let (hi, si) = (he.receive(), se.receive());
                        ho.clear();
                        so.clear();
                        match ls.tick(&hi, &si, &mut ho, &mut so) {
                            Ok(()) => {
                                he.send(&ho);
                                se.send(&so);
                            }
                            Err(e) => io_error = Some(e),
                        }
                    };
                    run_served(&cfg, &mut fw, &mut bridge, &stop2)?
                };
                if let Some(e) = io_error {
                    return Err(e.context("the QEMU board"));
                }
                let status = crate::episode::qemu::lockstep_status(&mut ls)?;
                let _ = ls.exit(std::time::Duration::from_secs(10));
                Ok(Served {
                    status,
                    limit_violations: w.servos.counters().limit_violations,
                    to_board_bytes: bridge.to_link,
                    from_board_bytes: bridge.to_pty,
                    board_s: w.now_us as f64 / 1e6,
                })
            },
        )?;
        Ok(SimBoard { path, stop, thread: Some(thread), flash: None })
    }

    /// Starts a board with `blob` built in (or none) behind a new PTY.
    pub fn start(blob: Option<Vec<u8>>) -> Result<SimBoard> {
        SimBoard::start_with(blob, FaultConfig::default(), 0)
    }

    /// [`SimBoard::start`] with `faults` on both directions of the host link, seeded by `seed`.
    pub fn start_with(blob: Option<Vec<u8>>, faults: FaultConfig, seed: u64) -> Result<SimBoard> {
        let cfg = ServeConfig { seed, ..ServeConfig::new(Backend::Inproc, None) };
        SimBoard::start_board(inproc_or_empty(blob.as_deref()), faults, cfg.world())
    }

    /// Serves `board` (any model store) behind a new PTY, `faults` on its host link, in the
    /// world `cfg` (its pace, seed and servos).
    pub fn start_board<S: ModelStore + Send + 'static>(
        mut board: Box<Board<S>>,
        faults: FaultConfig,
        mut cfg: WorldConfig,
    ) -> Result<SimBoard> {
        faults.check().map_err(|e| anyhow!("host-link faults: {e}"))?;
        let pty = Pty::open()?;
        let path = pty.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new().name("sim-board".into()).spawn(
            move || -> Result<Served> {
                let mut bridge = PtyBridge::new(pty);
                cfg.host_link.a_to_b = faults.clone();
                cfg.host_link.b_to_a = faults;
                let (w, _) = {
                    let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| board.poll(now, h, s);
                    run_served(&cfg, &mut fw, &mut bridge, &stop2)?
                };
                Ok(Served {
                    status: board.status(),
                    limit_violations: w.servos.counters().limit_violations,
                    to_board_bytes: bridge.to_link,
                    from_board_bytes: bridge.to_pty,
                    board_s: w.now_us as f64 / 1e6,
                })
            },
        )?;
        Ok(SimBoard {
            path,
            stop,
            thread: Some(thread),
            flash: None,
        })
    }

    /// The device path to open, e.g. `/dev/pts/5`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The board stopped by itself (an error): [`SimBoard::stop`] says why.
    pub fn finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Errs when the board's flash file is no longer where it was named (see
    /// [`crate::flash_file::FlashWatch::check`]).
    pub fn check_flash(&self) -> Result<()> {
        self.flash.as_ref().map_or(Ok(()), |w| w.check())
    }

    /// Stops the world and returns what the board did.
    pub fn stop(mut self) -> Result<Served> {
        self.stop.store(true, Ordering::SeqCst);
        let t = self
            .thread
            .take()
            .ok_or_else(|| anyhow!("already stopped"))?;
        t.join()
            .map_err(|_| anyhow!("the simulated board's thread panicked"))?
    }
}

impl Drop for SimBoard {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// An in-process board with `blob` built in, or one that waits for an upload.
fn inproc_or_empty(blob: Option<&[u8]>) -> Box<Board<crate::episode::HeapStore>> {
    match blob {
        Some(b) => inproc_board(b),
        None => Box::new(msr_firmware::Board::new(crate::episode::HeapStore::new(None, 2 * 1024 * 1024))),
    }
}

/// Runs the world `cfg` with `fw` as its board until `stop` is set, the PC's end of the host
/// link pumped through the PTY at every step; a PTY error ends it as an error.
fn run_served<F: world::Firmware>(cfg: &WorldConfig, fw: &mut F, bridge: &mut PtyBridge, stop: &AtomicBool) -> Result<(World, world::RunReport)> {
    let mut pty_error = None;
    let r = world::run(
        cfg,
        fw,
        |w: &mut World| {
            if let Err(e) = bridge.pump(&mut w.host) {
                pty_error = Some(e);
                return Flow::Stop;
            }
            if stop.load(Ordering::SeqCst) {
                Flow::Stop
            } else {
                Flow::Continue
            }
        },
        u64::MAX / 2,
    )
    .map_err(|e| anyhow!("{e}"))?;
    if let Some(e) = pty_error {
        bail!("PTY: {e}");
    }
    Ok(r)
}
