//! Mirror-test episodes with the firmware image in QEMU (`mps2-an386`, `thumbv7em-none-eabihf`):
//! the same trials as in-process (`crate::episode`), with the board's UART0 (host link) and UART1
//! (servo bus) bridged to the sim's two links.
//!
//! One QEMU serves the whole run. The model is uploaded once over UART0, with the board on its
//! own clock; the board keeps it in its flash slots. Every trial then resets the board (it comes
//! back with the uploaded model, which it reports) and runs in lockstep with the sim
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
use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

/// The world's tick (`msr_sim::world::WorldConfig::default`), which the board's clock follows.
const TICK_US: u32 = 1000;

/// QEMU's emulated UART takes one byte per turn of QEMU's event loop: about 15 to 40 KB/s on an
/// idle machine, a tenth of that when other QEMUs share two cores. So the upload is called stuck
/// only when it makes no progress for this long: QEMU reads nothing more from the link (what the
/// socket took, less what it still holds: [`unread`]), or no verdict comes after the last byte.
const UPLOAD_STALL: Duration = Duration::from_secs(60);

/// What the socket `s` holds that its peer has not read yet (Linux `SIOCOUTQ`: for a Unix
/// stream socket the send buffers not yet consumed, in the kernel's accounting, which includes
/// each buffer's overhead; it falls as the peer reads). A socket's buffers hold a few hundred KB,
/// so what `write` took says nothing of what QEMU read: at 3 KB/s, a loaded machine's rate,
/// the last 200 KB take a minute after the last `write`. 0 where it cannot be asked.
#[cfg(target_os = "linux")]
fn unread(s: &std::os::unix::net::UnixStream) -> usize {
    use std::os::fd::AsRawFd;
    let mut n: libc::c_int = 0;
    // SAFETY: SIOCOUTQ (= TIOCOUTQ) writes one int through the pointer, which is valid for the
    // call; the descriptor is open while `s` lives.
    let r = unsafe { libc::ioctl(s.as_raw_fd(), libc::TIOCOUTQ, &mut n) };
    if r == 0 { n.max(0) as usize } else { 0 }
}

#[cfg(not(target_os = "linux"))]
fn unread(_: &std::os::unix::net::UnixStream) -> usize {
    0
}

fn debug() -> bool {
    std::env::var_os("MSR_QEMU_DEBUG").is_some()
}

/// Passes of an upload: the first from byte 0, each next one from where the board said it
/// stands.
const UPLOAD_PASSES: usize = 8;

/// This long after QEMU read a pass's last byte and after the board's latest `UploadAck`, with
/// no verdict, the board is missing bytes: the next pass goes back to where that ack said. (Too
/// early only costs chunks the board already holds, which it ignores.)
const UPLOAD_QUIET: Duration = Duration::from_secs(2);

/// What one pass of an upload ended with.
enum Pass {
    Verdict(BoardToHost),
    /// The board wants this byte next.
    GoBack(u32),
}

/// Uploads `blob` while the board runs free and waits for its verdict. The servo bus is read
/// (and thrown away) meanwhile: an unread UART stalls the board (see
/// [`Lockstep::drain_servo`]). As `Session::upload` does against a real board, it goes back to
/// where the board stands: chunks that arrive while the board erases its staging slot are
/// dropped and answered with `UploadAck` (`msr_shared::msg`, model uploads); how many depends on
/// how fast QEMU reads the link against how fast the board erases, so on the machine's load
/// (a blind upload of the whole blob once stalled in CI with every byte read and no verdict).
fn upload(ls: &mut Lockstep, blob: &[u8]) -> Result<u32> {
    let mut port = HostPort::default();
    let t0 = Instant::now();
    let mut bytes = port.encode_upload(blob);
    for pass in 0..UPLOAD_PASSES {
        match upload_pass(ls, &mut port, bytes, t0)? {
            Pass::Verdict(BoardToHost::ModelAccepted { crc32 }) => {
                if debug() {
                    eprintln!("upload of {} bytes accepted after {:.1} s, {} passes", blob.len(), t0.elapsed().as_secs_f64(), pass + 1);
                }
                return Ok(crc32);
            }
            Pass::Verdict(other) => bail!("the QEMU board refused the model: {other:?}"),
            Pass::GoBack(next) => {
                if debug() {
                    eprintln!("upload: the board wants byte {next} next (pass {})", pass + 1);
                }
                bytes = port.encode_upload_from(blob, next as usize);
            }
        }
    }
    bail!("the QEMU board did not take its model in {UPLOAD_PASSES} passes ({:.0} s)", t0.elapsed().as_secs_f64())
}

/// Writes `bytes` and reads the board until its verdict, or until it says (after the last byte)
/// where it stands.
fn upload_pass(ls: &mut Lockstep, port: &mut HostPort, bytes: Vec<u8>, t0: Instant) -> Result<Pass> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;
    let total = bytes.len();
    // The writer runs on its own thread so that the board's answers are read while it writes; it
    // counts what the link took, so that a slow upload is told from a stuck one.
    let written = Arc::new(AtomicUsize::new(0));
    let mut w = ls.host_link().try_clone()?;
    w.set_write_timeout(Some(UPLOAD_STALL))?;
    let counter = Arc::clone(&written);
    let writer = std::thread::spawn(move || -> std::io::Result<()> {
        for chunk in bytes.chunks(1024) {
            w.write_all(chunk)?;
            counter.fetch_add(chunk.len(), Ordering::Relaxed);
        }
        Ok(())
    });
    let mut r = ls.host_link().try_clone()?;
    r.set_read_timeout(Some(Duration::from_millis(50)))?;
    let mut buf = [0u8; 1024];
    let (mut seen, mut progress_at) = ((0usize, 0usize), Instant::now());
    // The board's latest UploadAck and when it came; since when QEMU has read the whole pass.
    let mut ack: Option<(u32, Instant)> = None;
    let mut all_read_since: Option<Instant> = None;
    let outcome = loop {
        ls.drain_servo()?;
        let now = (written.load(Ordering::Relaxed), unread(&r));
        if now != seen {
            (seen, progress_at) = (now, Instant::now());
        }
        all_read_since = if seen == (total, 0) { all_read_since.or_else(|| Some(Instant::now())) } else { None };
        if let (Some((next, at)), Some(since)) = (ack, all_read_since) {
            if at.elapsed() >= UPLOAD_QUIET && since.elapsed() >= UPLOAD_QUIET {
                break Pass::GoBack(next);
            }
        }
        if progress_at.elapsed() > UPLOAD_STALL {
            bail!(
                "the QEMU board stopped reading its model upload: {} of {total} bytes written to the \
                 link in {:.0} s, the link still holding about {} of them, then nothing moved for \
                 {UPLOAD_STALL:?} (no verdict); it printed:\n{}",
                seen.0,
                t0.elapsed().as_secs_f64(),
                seen.1,
                ls.qemu().output_so_far()
            );
        }
        let n = match r.read(&mut buf) {
            Ok(0) => bail!("QEMU closed UART0 during the upload"),
            Ok(n) => n,
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => continue,
            Err(e) => return Err(e).context("reading QEMU's UART0"),
        };
        let mut verdict = None;
        for m in port.receive(&buf[..n]) {
            match m {
                BoardToHost::ModelAccepted { .. } | BoardToHost::Error { .. } => verdict = Some(m),
                BoardToHost::UploadAck { next } => ack = Some((next, Instant::now())),
                _ => {}
            }
        }
        if let Some(m) = verdict {
            break Pass::Verdict(m);
        }
    };
    // A pass that went back was read to its last byte: the writer has finished.
    writer
        .join()
        .map_err(|_| anyhow!("the upload writer panicked"))?
        .context("writing the model to QEMU's UART0")?;
    Ok(outcome)
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
    let opts = qemu::Options { preload: preload.as_deref(), flash_file };
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

/// The board image running in QEMU with a model uploaded, ready for trials. Each
/// [`QemuBoard::trial`] resets the board first, so trials are independent.
pub struct QemuBoard {
    ls: Lockstep,
    crc: u32,
    /// Seconds the model upload took (with a preload: QEMU's start until the board ran it).
    pub upload_s: f64,
}

impl QemuBoard {
    /// Starts QEMU with the board image and uploads `blob` (checked by the board).
    pub fn start(blob: &[u8]) -> Result<QemuBoard> {
        if !qemu::qemu_available() {
            bail!("{} is not installed (Debian: apt-get install qemu-system-arm)", qemu::qemu_binary());
        }
        let image = qemu::find_image(qemu::BOARD_IMAGE)?;
        let model = msr_shared::blob::Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
        let (mut ls, _) = Lockstep::start(&image)?;
        let t0 = Instant::now();
        let crc = upload(&mut ls, blob)?;
        if crc != model.crc32 {
            bail!("the QEMU board accepted model {crc:#010x}, not {:#010x}", model.crc32);
        }
        Ok(QemuBoard { ls, crc, upload_s: t0.elapsed().as_secs_f64() })
    }

    /// Starts QEMU with `blob` preloaded into the board's memory by QEMU's generic loader
    /// instead of uploaded over the emulated UART (which moves 20-40 KB/s): the board takes it
    /// at start-up through the upload's own checks (CRC-32, blob validation) and refuses a bad
    /// one as an upload would, which fails here with the board's reason.
    pub fn start_preloaded(blob: &[u8]) -> Result<QemuBoard> {
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
        Ok(QemuBoard { ls, crc, upload_s: t0.elapsed().as_secs_f64() })
    }

    /// One trial, as [`episode::run_trial_inproc`] runs it, with this board.
    pub fn trial(&mut self, camera: Camera, cfg: &EpisodeConfig, index: usize, seed: u64) -> Result<Trial> {
        let ls = &mut self.ls;
        let got = ls.reset(Some(TICK_US))?;
        if got != self.crc {
            bail!("trial {index}: after its reset the QEMU board runs model {got:#010x}, not the uploaded {:#010x}", self.crc);
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
        eprintln!("model upload: {:.1} s", board.upload_s);
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

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::unread;
    use std::io::{Read, Write};

    /// The upload's progress is what the peer read: the socket reports what it still holds,
    /// less as the peer reads, and nothing once all is read.
    #[test]
    fn unread_falls_as_the_peer_reads() {
        let (mut a, mut b) = std::os::unix::net::UnixStream::pair().unwrap();
        assert_eq!(unread(&a), 0);
        for _ in 0..8 {
            a.write_all(&[7u8; 1024]).unwrap();
        }
        let full = unread(&a);
        assert!(full >= 8 * 1024, "{full}");
        let mut buf = [0u8; 4096];
        b.read_exact(&mut buf).unwrap();
        let half = unread(&a);
        assert!(half < full && half >= 4 * 1024, "{half} of {full}");
        b.read_exact(&mut buf).unwrap();
        assert_eq!(unread(&a), 0);
    }
}
