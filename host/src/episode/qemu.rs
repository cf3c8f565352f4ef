//! Mirror-test episodes with the firmware image in QEMU (`mps2-an386`, `thumbv7em-none-eabihf`):
//! the same trials as in-process (`crate::episode`), with the board's UART0 (host link) and UART1
//! (servo bus) bridged to the sim's two links.
//!
//! One QEMU serves the whole run. The model is preloaded into the board's memory by QEMU's
//! loader and taken at start-up through the upload's own checks into the board's flash slots
//! (over the emulated UART, which moves a byte per turn of QEMU's event loop, the demo's model
//! took 24 s); uploads over the host link are tested with `msr serve` and the board image's own
//! tests. Every trial then resets the board (it comes back with the model, which it reports)
//! and runs in lockstep with the sim
//! ([`msr_sim::qemu::Lockstep`]): each 1 ms world tick hands the board exactly the bytes that
//! reached its UARTs in that tick, the board polls once at the tick's time, and what it wrote goes
//! back on the links. So the board's watchdogs and its 10 ms motion period share the world's
//! time whatever the machine's load, and a QEMU trial sees what an in-process trial of the same
//! seed sees. After the trial the board's counters come from a `GetStatus` over the link.
//!
//! Why not real time: the image's own clock under QEMU is virtual time, which runs at no fixed
//! rate against the host's (a spinning image under `-icount shift=0` saw about 30 ms of it per
//! real second), and the sim's servos and camera would run on the host's clock.
use crate::episode::{self, Camera, EpisodeConfig, Trial};
use msr_shared::host_port::HostPort;
use anyhow::{anyhow, bail, Context, Result};
use msr_shared::msg::{BoardToHost, Status};
use msr_sim::link::LinkEnd;
use msr_sim::qemu::{self, Lockstep};
use msr_sim::render::Renderer;
use std::time::{Duration, Instant};

/// The world's tick (`msr_sim::world::WorldConfig::default`), which the board's clock follows.
const TICK_US: u32 = 1000;

fn debug() -> bool {
    std::env::var_os("MSR_QEMU_DEBUG").is_some()
}

/// The board's counters, read beside the links (as the in-process trial reads its board's).
fn status(ls: &mut Lockstep) -> Result<Status> {
    let mut port = HostPort::default();
    for m in port.receive(&ls.status_frame()?) {
        if let BoardToHost::Status(st) = m {
            return Ok(st);
        }
    }
    bail!("the QEMU board's status did not decode")
}

/// Starts the board image in QEMU for `msr serve`, in lockstep with 1 ms ticks. `blob` (if
/// given) is preloaded and checked by the board as an upload is; with `flash_file` (which must
/// exist with the emulated flash's size: [`crate::flash_file::FileCells::open`] makes one) the
/// board's flash is that file, and a model committed there runs instead of `blob`, as a board
/// keeps what was uploaded to it. Returns the lockstep and the CRC of the model it runs (0: none).
pub fn start_lockstep(blob: Option<&[u8]>, flash_file: Option<&std::path::Path>) -> Result<(Lockstep, u32)> {
    if !qemu::qemu_available() {
        bail!("{} is not installed (Debian: apt-get install qemu-system-arm)", qemu::qemu_binary());
    }
    let image = qemu::find_image(qemu::BOARD_IMAGE)?;
    let preload = match blob {
        Some(b) => {
            msr_shared::blob::Model::parse(b).map_err(|e| anyhow!("model blob: {e}"))?;
            Some(qemu::preload_bytes(b))
        }
        None => None,
    };
    let opts = qemu::Options { preload: preload.as_deref(), flash_file, ..qemu::Options::default() };
    let (mut ls, _) = Lockstep::start_opts(&image, &opts)?;
    let got = ls.reset(Some(TICK_US))?;
    if let (Some(b), None) = (blob, flash_file) {
        let want = msr_shared::blob::Model::parse(b).map_err(|e| anyhow!("model blob: {e}"))?.crc32;
        if got != want {
            // What the image printed before its start-up message may still be on its way.
            std::thread::sleep(Duration::from_millis(200));
            bail!(
                "the QEMU board runs model {got:#010x}, not the preloaded {want:#010x}; it printed:\n{}",
                ls.qemu().output_so_far()
            );
        }
    }
    Ok((ls, got))
}

/// The board's counters, read out of band.
pub fn lockstep_status(ls: &mut Lockstep) -> Result<Status> {
    status(ls)
}

/// The board image running in QEMU with a model, ready for trials. Each [`QemuBoard::trial`]
/// resets the board first, so trials are independent.
pub struct QemuBoard {
    ls: Lockstep,
    crc: u32,
    /// Seconds from QEMU's start until the board ran the preloaded model.
    pub start_s: f64,
}

impl QemuBoard {
    /// Starts QEMU with `blob` preloaded into the board's memory by QEMU's generic loader: the
    /// board takes it at start-up through the upload's own checks (CRC-32, blob validation)
    /// and refuses a bad one as an upload would, which fails here with the board's reason.
    pub fn start(blob: &[u8]) -> Result<QemuBoard> {
        if !qemu::qemu_available() {
            bail!("{} is not installed (Debian: apt-get install qemu-system-arm)", qemu::qemu_binary());
        }
        let image = qemu::find_image(qemu::BOARD_IMAGE)?;
        let model = msr_shared::blob::Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
        let t0 = Instant::now();
        let (ls, crc) = Lockstep::start_with(&image, Some(&qemu::preload_bytes(blob)))?;
        if crc != model.crc32 {
            // What the image printed before its start-up message may still be on its way.
            std::thread::sleep(Duration::from_millis(200));
            bail!(
                "the QEMU board runs model {crc:#010x}, not the preloaded {:#010x}; it printed:\n{}",
                model.crc32,
                ls.qemu().output_so_far()
            );
        }
        Ok(QemuBoard { ls, crc, start_s: t0.elapsed().as_secs_f64() })
    }

    /// One trial, as [`episode::run_trial_inproc`] runs it, with this board.
    pub fn trial(&mut self, camera: Camera, cfg: &EpisodeConfig, index: usize, seed: u64) -> Result<Trial> {
        let ls = &mut self.ls;
        let got = ls.reset(Some(TICK_US))?;
        if got != self.crc {
            bail!("trial {index}: after its reset the QEMU board runs model {got:#010x}, not the preloaded {:#010x}", self.crc);
        }
        let mut io_error: Option<anyhow::Error> = None;
        let (mut ho, mut so) = (Vec::new(), Vec::new());
        let mut fw = |now: u64, he: &mut LinkEnd, se: &mut LinkEnd| {
            if io_error.is_some() {
                return;
            }
            debug_assert_eq!(now, ls.ticks * TICK_US as u64);
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
        // The world's own pacing is not wanted: the board follows the world's clock.
        let mut c = cfg.clone();
        c.pace = None;
        let (mut trial, _) = episode::run_trial_with(&mut fw, camera, &c, index, seed)?;
        if let Some(e) = io_error {
            return Err(e.context(format!("trial {index}: QEMU board")));
        }
        let st = status(ls).with_context(|| format!("trial {index}"))?;
        episode::end_with_status(&mut trial, &st);
        Ok(trial)
    }

    /// Ends QEMU; fails unless the image exits cleanly. Returns what it printed (its counters
    /// and stack peak).
    pub fn finish(self) -> Result<String> {
        let exit = self.ls.exit(Duration::from_secs(10))?;
        if exit.timed_out || exit.code != Some(0) {
            bail!("the QEMU board did not exit cleanly ({:?}):\n{}", exit.code, exit.output);
        }
        Ok(exit.output)
    }
}

/// Runs `n` trials with the board image in QEMU, one at a time, on one QEMU.
pub fn run_qemu(blob: &[u8], cfg: &EpisodeConfig, n: usize, seed: u64, progress: &(dyn Fn(&Trial) + Sync)) -> Result<Vec<Trial>> {
    let model = msr_shared::blob::Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let renderer = Renderer::new(cfg.robot);
    let mut board = QemuBoard::start(blob)?;
    if debug() {
        eprintln!("QEMU running the preloaded model after {:.1} s", board.start_s);
    }
    let mut out = Vec::with_capacity(n.min(1024));
    for i in 0..n {
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let t = board.trial(camera, cfg, i, episode::trial_seed(seed, i))?;
        progress(&t);
        out.push(t);
    }
    let output = board.finish()?;
    if debug() {
        eprintln!("{output}");
    }
    Ok(out)
}
