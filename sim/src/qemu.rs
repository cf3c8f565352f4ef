//! Running the bare-metal firmware image under `qemu-system-arm` (mps2-an386) with its UARTs
//! connected to byte streams on the host side.
//!
//! QEMU runs with `-icount shift=0`: every emulated instruction advances the virtual clock by
//! 1 ns, so the image's SysTick counts instructions and its timing (watchdogs, the 10 ms motion
//! period) is virtual time, independent of how fast this machine is.
//!
//! UART0 (the host link), UART1 (the servo bus) and UART2 (the board image's clock channel) are
//! unix-domain sockets: this side listens, QEMU connects as a client at start-up. QEMU also
//! inherits the read end of a pipe as its descriptor 3, which the board image reads through
//! semihosting in lockstep ([`Lockstep`]). What the image
//! prints through semihosting lands in [`QemuExit::output`]; its semihosting exit code is QEMU's
//! exit status.
//!
//! The board image's own clock is virtual time, which runs at no fixed rate against this
//! machine's clock (a spinning image under `-icount` saw 30 ms of it per real second; a sleeping
//! one about real time; a busy host stretches everything). [`Lockstep`] therefore drives the
//! image's clock from the simulation: one command per tick, with the exact bytes of that tick,
//! so the firmware sees the world as the in-process firmware does, at any host load.

use std::io::{self, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};

/// The Rust target the images are built for.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// The board image: the pipeline on frames from UART0, servo targets on UART1.
pub const BOARD_IMAGE: &str = "msr-qemu";
/// The benchmark image: pipeline stages on a model and frames it is sent, counts printed.
pub const BENCH_IMAGE: &str = "msr-qemu-bench";
/// Where the board image takes a preloaded model from (`firmware/qemu/src/model_area.rs`,
/// `PRELOAD_ADDR`): the board's PSRAM.
pub const PRELOAD_ADDR: u32 = 0x2100_0000;
/// The preload header's first word, `"MSRP"` (`PRELOAD_MAGIC` there).
const PRELOAD_MAGIC: u32 = 0x4D53_5250;

/// What QEMU's generic loader puts at [`PRELOAD_ADDR`] for `blob`: the 16-byte header the board
/// image reads (magic, length, the blob's CRC-32 as `ModelBegin` carries it, a check word), then
/// the blob.
pub fn preload_bytes(blob: &[u8]) -> Vec<u8> {
    let (len, crc) = (blob.len() as u32, msr_shared::blob::CRC32.checksum(blob));
    let mut out = Vec::with_capacity(16 + blob.len());
    for w in [PRELOAD_MAGIC, len, crc, PRELOAD_MAGIC ^ len ^ crc] {
        out.extend(w.to_le_bytes());
    }
    out.extend_from_slice(blob);
    out
}

/// How QEMU starts, beyond the image.
#[derive(Clone, Copy, Debug, Default)]
pub struct Options<'a> {
    /// Put into the board's PSRAM by QEMU's generic loader (see [`preload_bytes`]).
    pub preload: Option<&'a [u8]>,
    /// The board's flash, kept in this file (it must exist, with the emulated flash's size; see
    /// `firmware/qemu/src/flash_file.rs`): read at start-up, every program and erase written
    /// through.
    pub flash_file: Option<&'a Path>,
    /// Starts QEMU without the lockstep pipe (see [`Lockstep`]): the image then refuses to run
    /// in lockstep, which its tests check.
    pub without_lockstep_pipe: bool,
}

/// QEMU is killed when the thread that started it ends: a `msr serve` killed with SIGKILL takes
/// its board down with it instead of leaving a QEMU that holds the flash file.
fn die_with_parent(cmd: &mut Command) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: only prctl, which is async-signal-safe, runs between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = cmd;
}

/// The descriptor QEMU finds the lockstep pipe's read end at (`firmware/qemu/src/pipe.rs`
/// opens `/dev/fd/3`).
const PIPE_FD: i32 = 3;

/// Gives QEMU `read` as its descriptor [`PIPE_FD`].
fn pass_pipe(cmd: &mut Command, read: &std::io::PipeReader) {
    use std::os::fd::AsRawFd;
    use std::os::unix::process::CommandExt;
    let fd = read.as_raw_fd();
    // SAFETY: only dup2 and fcntl, which are async-signal-safe, run between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            // dup2 leaves the new descriptor open across exec; a pipe already at PIPE_FD keeps
            // its close-on-exec flag, which is cleared instead.
            let r = if fd == PIPE_FD { libc::fcntl(fd, libc::F_SETFD, 0) } else { libc::dup2(fd, PIPE_FD) };
            if r < 0 {
                return Err(io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// How long QEMU may run (its own processor time, [`Allowance`]) before it connects its UART
/// sockets.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);
/// UART sockets: host link, servo bus, clock channel.
const UARTS: usize = 3;

/// The QEMU binary: `$MSR_QEMU` or `qemu-system-arm` on the `PATH`.
pub fn qemu_binary() -> String {
    std::env::var("MSR_QEMU").unwrap_or_else(|_| "qemu-system-arm".into())
}

/// Whether the QEMU binary runs at all (tests skip with a message when it does not).
pub fn qemu_available() -> bool {
    Command::new(qemu_binary())
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// The folder with the release images: `firmware/qemu/target/thumbv7em-none-eabihf/release`,
/// or `$MSR_QEMU_IMAGES` when set.
pub fn image_dir() -> PathBuf {
    if let Ok(dir) = std::env::var("MSR_QEMU_IMAGES") {
        return PathBuf::from(dir);
    }
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../firmware/qemu/target")
        .join(TARGET)
        .join("release")
}

/// Why [`find_image`] found no image to run.
#[derive(Debug)]
pub enum ImageError {
    /// Not built (a fresh clone).
    Missing(PathBuf),
    /// Built before one of its sources last changed: the firmware it runs is not the firmware
    /// this `msr` was built with (after a `git pull`, say), and its trials would differ from
    /// in-process ones, or its protocol from this host's, for no reason a user could see.
    /// `image` is older than `source`.
    Stale {
        /// The image.
        image: PathBuf,
        /// The newer source file.
        source: PathBuf,
    },
}

impl std::fmt::Display for ImageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImageError::Missing(p) => write!(
                f,
                "firmware image {} is missing; build it with `cargo xtask images` \
                 (or `cd firmware/qemu && cargo build --release`)",
                p.display()
            ),
            ImageError::Stale { image, source } => write!(
                f,
                "firmware image {} is older than its source {}; rebuild it with `cargo xtask images` \
                 (or `cd firmware/qemu && cargo build --release`)",
                image.display(),
                source.display()
            ),
        }
    }
}

impl std::error::Error for ImageError {}

/// The path of a built image that is newer than its sources, or an [`ImageError`] that says how
/// to build it.
pub fn find_image(name: &str) -> Result<PathBuf> {
    let path = image_dir().join(name);
    if !path.is_file() {
        return Err(ImageError::Missing(path).into());
    }
    if let Some(source) = changed_source(&path) {
        return Err(ImageError::Stale { image: path, source }.into());
    }
    Ok(path)
}

/// A source of `image` modified after it: the first file that cargo's dep-info beside it
/// (`<image>.d`, the make rule cargo writes: `target: source source ...`, spaces in a path
/// escaped with `\`) names and that is newer than the image. `None` without a dep-info file (an
/// image copied elsewhere, `MSR_QEMU_IMAGES`), or when a listed file is missing (a checkout
/// elsewhere): only a source that is there and newer says the image is stale.
pub fn changed_source(image: &Path) -> Option<PathBuf> {
    let built = std::fs::metadata(image).and_then(|m| m.modified()).ok()?;
    let rule = std::fs::read_to_string(format!("{}.d", image.display())).ok()?;
    let sources = rule.lines().next()?.split_once(": ")?.1;
    dep_paths(sources).into_iter().find(|p| std::fs::metadata(p).and_then(|m| m.modified()).is_ok_and(|t| t > built))
}

/// The paths of a make rule's prerequisites: separated by spaces, `\ ` a space inside one.
fn dep_paths(list: &str) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut chars = list.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\\' if chars.peek() == Some(&' ') => cur.push(chars.next().unwrap_or(' ')),
            ' ' | '\t' => {
                if !cur.is_empty() {
                    out.push(PathBuf::from(std::mem::take(&mut cur)));
                }
            }
            c => cur.push(c),
        }
    }
    if !cur.is_empty() {
        out.push(PathBuf::from(cur));
    }
    out
}

/// How a run ended.
#[derive(Clone, Debug)]
pub struct QemuExit {
    /// QEMU's exit status: the image's semihosting exit code. `None` if QEMU was killed.
    pub code: Option<i32>,
    /// What QEMU and the image printed (stdout then stderr).
    pub output: String,
    /// Whether the run hit its time limit.
    pub timed_out: bool,
}

impl QemuExit {
    /// Succeeds only on exit code 0, with the output in the error otherwise.
    pub fn success(&self) -> Result<()> {
        if self.code == Some(0) && !self.timed_out {
            Ok(())
        } else {
            bail!(
                "QEMU ended with {}{}; output:\n{}",
                self.code.map_or("no exit code".to_string(), |c| format!("exit code {c}")),
                if self.timed_out { " after a timeout" } else { "" },
                self.output
            )
        }
    }
}

/// A running image. Dropping it kills QEMU.
pub struct Qemu {
    child: Option<Child>,
    /// UART0: the host link.
    pub host: UnixStream,
    /// UART1: the servo bus.
    pub servo: UnixStream,
    /// UART2: the board image's clock channel (see [`Lockstep`]).
    pub clock: UnixStream,
    /// The write end of the pipe the board image reads its lockstep commands from.
    pipe: Option<std::io::PipeWriter>,
    stdout: Option<JoinHandle<Vec<u8>>>,
    stderr: Option<JoinHandle<Vec<u8>>>,
    /// Captured output so far, for error messages while running.
    live: Arc<Mutex<Vec<u8>>>,
    dir: PathBuf,
}

static RUN_ID: AtomicU32 = AtomicU32::new(0);

impl Qemu {
    /// Starts `image` and waits until QEMU has connected both UARTs.
    pub fn start(image: &Path) -> Result<Qemu> {
        Qemu::start_with(image, None)
    }

    /// Starts `image` with `preload` (see [`preload_bytes`]) loaded at [`PRELOAD_ADDR`] by
    /// QEMU's generic loader, if given: the board image finds it there at start-up.
    pub fn start_with(image: &Path, preload: Option<&[u8]>) -> Result<Qemu> {
        Qemu::start_opts(image, &Options { preload, ..Options::default() })
    }

    /// Starts `image` as `opts` say.
    pub fn start_opts(image: &Path, opts: &Options) -> Result<Qemu> {
        let preload = opts.preload;
        let dir = std::env::temp_dir().join(format!(
            "msr-qemu-{}-{}",
            std::process::id(),
            RUN_ID.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let paths: Vec<PathBuf> = (0..UARTS).map(|i| dir.join(format!("uart{i}.sock"))).collect();
        let listeners = paths
            .iter()
            .map(|p| {
                let _ = std::fs::remove_file(p);
                let l = UnixListener::bind(p).with_context(|| format!("binding {}", p.display()))?;
                l.set_nonblocking(true)?;
                Ok(l)
            })
            .collect::<Result<Vec<_>>>()?;

        let mut cmd = Command::new(qemu_binary());
        // The image's command line: `msr-qemu [lockstep-pipe] [flash=PATH]`
        // (`firmware/qemu/src/cmdline.rs`; the path runs to the end of the line).
        let mut semihosting = String::from("enable=on,target=native,arg=msr-qemu");
        if !opts.without_lockstep_pipe {
            semihosting += ",arg=lockstep-pipe";
        }
        if let Some(f) = opts.flash_file {
            let f = std::path::absolute(f).with_context(|| format!("the flash file {}", f.display()))?;
            let f = f.to_str().ok_or_else(|| anyhow!("the flash file's path {} is not UTF-8", f.display()))?;
            // QEMU doubles a comma inside an option's value.
            semihosting += &format!(",arg=flash={}", f.replace(',', ",,"));
        }
        cmd.args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-nographic", "-monitor", "none"])
            .args(["-semihosting-config", &semihosting])
            .args(["-icount", "shift=0"]);
        die_with_parent(&mut cmd);
        let pipe = if opts.without_lockstep_pipe {
            None
        } else {
            let (read, write) = std::io::pipe().context("making the lockstep pipe")?;
            pass_pipe(&mut cmd, &read);
            Some((read, write))
        };
        for (i, p) in paths.iter().enumerate() {
            cmd.arg("-chardev")
                .arg(format!("socket,id=uart{i},path={}", p.display()))
                .arg("-serial")
                .arg(format!("chardev:uart{i}"));
        }
        cmd.arg("-kernel").arg(image);
        if let Some(bytes) = preload {
            let path = dir.join("preload.bin");
            std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
            cmd.arg("-device")
                .arg(format!("loader,file={},addr={PRELOAD_ADDR:#x},force-raw=on", path.display()));
        }
        cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
        let mut child = cmd
            .spawn()
            .with_context(|| format!("starting {} (is qemu-system-arm installed?)", qemu_binary()))?;
        // QEMU holds the read end: a write after it ended fails instead of waiting.
        let pipe = pipe.map(|(_, write)| write);

        let live = Arc::new(Mutex::new(Vec::new()));
        let stdout = child.stdout.take().map(|s| capture(s, live.clone()));
        let stderr = child.stderr.take().map(|s| capture(s, live.clone()));
        let mut qemu = Qemu {
            child: Some(child),
            // Placeholders until QEMU connects; replaced below.
            host: UnixStream::pair()?.0,
            servo: UnixStream::pair()?.0,
            clock: UnixStream::pair()?.0,
            pipe,
            stdout,
            stderr,
            live,
            dir,
        };
        // QEMU's own processor time: a machine busy with other work does not spend it.
        let allowance = Allowance::start(qemu.child.as_ref().map(|c| c.id()), CONNECT_TIMEOUT);
        let mut streams = Vec::new();
        for l in &listeners {
            streams.push(qemu.accept(l, &allowance)?);
        }
        qemu.clock = streams.pop().expect("three listeners");
        qemu.servo = streams.pop().expect("three listeners");
        qemu.host = streams.pop().expect("three listeners");
        // Connected sockets need no name: gone now, they cannot outlive a process that is
        // killed (`msr serve` ends on Ctrl-C, which runs no destructor).
        for p in &paths {
            let _ = std::fs::remove_file(p);
        }
        if preload.is_none() {
            qemu.tidy();
        }
        Ok(qemu)
    }

    /// Removes this run's temporary directory. Call it once the image runs: QEMU has then
    /// read the preload (its loader keeps a copy for a reset) and connected its UARTs, and
    /// nothing there is needed again. Dropping the `Qemu` does the same.
    pub fn tidy(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }

    fn accept(&mut self, l: &UnixListener, allowance: &Allowance) -> Result<UnixStream> {
        loop {
            match l.accept() {
                Ok((s, _)) => {
                    s.set_nonblocking(false)?;
                    return Ok(s);
                }
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) => return Err(e).context("accepting QEMU's UART connection"),
            }
            if let Some(status) = self.child.as_mut().and_then(|c| c.try_wait().ok().flatten()) {
                bail!("QEMU exited ({status}) before connecting its UARTs:\n{}", self.output_so_far());
            }
            if allowance.spent() {
                bail!("QEMU ran {CONNECT_TIMEOUT:?} without connecting its UARTs:\n{}", self.output_so_far());
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// What the image has printed so far.
    pub fn output_so_far(&self) -> String {
        String::from_utf8_lossy(&self.live.lock().unwrap_or_else(|e| e.into_inner())).into_owned()
    }

    /// QEMU's process id, while it runs.
    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }

    /// Whether QEMU is still running.
    pub fn is_running(&mut self) -> bool {
        self.child.as_mut().is_some_and(|c| matches!(c.try_wait(), Ok(None)))
    }

    /// Waits for the image to end (semihosting exit), killing QEMU once it has run `timeout`
    /// more without ending. Where the system tells (Linux), that is QEMU's own processor time,
    /// not the wall clock's: a machine busy with other work gives QEMU less of each second,
    /// and a slow QEMU is not a hung one; a hung QEMU (an image spinning forever) still spends
    /// its allowance.
    pub fn wait(mut self, timeout: Duration) -> Result<QemuExit> {
        let mut child = self.child.take().ok_or_else(|| anyhow!("QEMU already waited for"))?;
        let allowance = Allowance::start(Some(child.id()), timeout);
        let mut timed_out = false;
        let status = loop {
            if let Some(s) = child.try_wait()? {
                break Some(s);
            }
            if allowance.spent() {
                timed_out = true;
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            std::thread::sleep(Duration::from_millis(2));
        };
        let mut output = Vec::new();
        for h in [self.stdout.take(), self.stderr.take()].into_iter().flatten() {
            output.extend(h.join().unwrap_or_default());
        }
        Ok(QemuExit {
            code: status.and_then(|s| s.code()),
            output: String::from_utf8_lossy(&output).into_owned(),
            timed_out,
        })
    }

    /// Stops QEMU now.
    pub fn kill(mut self) -> QemuExit {
        if let Some(c) = self.child.as_mut() {
            let _ = c.kill();
        }
        self.wait(Duration::from_secs(5)).unwrap_or(QemuExit {
            code: None,
            output: String::new(),
            timed_out: true,
        })
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        self.tidy();
    }
}

/// A time QEMU may take for something: its own processor time where the system tells (see
/// [`Qemu::wait`]), else the wall clock's.
struct Allowance {
    pid: Option<u32>,
    cpu0: Option<Duration>,
    t0: Instant,
    limit: Duration,
}

impl Allowance {
    fn start(pid: Option<u32>, limit: Duration) -> Allowance {
        Allowance { pid, cpu0: pid.and_then(cpu_time), t0: Instant::now(), limit }
    }

    fn spent(&self) -> bool {
        let ran = match (self.cpu0, self.pid.and_then(cpu_time)) {
            (Some(a), Some(b)) => b.saturating_sub(a),
            _ => self.t0.elapsed(),
        };
        ran > self.limit
    }
}

/// Fills `buf` from `s`, for as long as QEMU (process `pid`) has not spent `limit` of its own
/// time since the call ([`Allowance`]). A stream that ends is `UnexpectedEof`; an allowance
/// spent is `TimedOut`.
fn read_full(mut s: &UnixStream, buf: &mut [u8], pid: Option<u32>, limit: Duration) -> io::Result<()> {
    let allowance = Allowance::start(pid, limit);
    s.set_read_timeout(Some(Duration::from_millis(200)))?;
    let mut got = 0;
    while got < buf.len() {
        match s.read(&mut buf[got..]) {
            Ok(0) => return Err(io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => got += n,
            Err(e) if matches!(e.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut) => {
                if allowance.spent() {
                    return Err(io::Error::new(io::ErrorKind::TimedOut, format!("QEMU ran {limit:?} without sending it")));
                }
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// The processor time (user and system) process `pid` has used, from `/proc/PID/stat`; `None`
/// where that cannot be read (not Linux, or the process is gone).
fn cpu_time(pid: u32) -> Option<Duration> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: fields are counted after
    // its closing one. utime and stime are fields 14 and 15, in clock ticks of 1/100 s (Linux's
    // USER_HZ, the same on every architecture).
    let rest: Vec<&str> = stat.get(stat.rfind(')')? + 1..)?.split_whitespace().collect();
    let ticks = rest.get(11)?.parse::<u64>().ok()? + rest.get(12)?.parse::<u64>().ok()?;
    Some(Duration::from_millis(ticks * 10))
}

fn capture(mut r: impl Read + Send + 'static, live: Arc<Mutex<Vec<u8>>>) -> JoinHandle<Vec<u8>> {
    std::thread::spawn(move || {
        let mut all = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = r.read(&mut buf) {
            if n == 0 {
                break;
            }
            all.extend_from_slice(&buf[..n]);
            live.lock().unwrap_or_else(|e| e.into_inner()).extend_from_slice(&buf[..n]);
        }
        all
    })
}

/// Runs `image`, started as `opts` say, to its end with nothing on the UARTs but what `drive`
/// does with them.
pub fn run_image(
    image: &Path,
    opts: &Options,
    timeout: Duration,
    drive: impl FnOnce(&mut UnixStream, &mut UnixStream) -> Result<()>,
) -> Result<QemuExit> {
    let q = Qemu::start_opts(image, opts)?;
    let (mut host, mut servo) = (q.host.try_clone()?, q.servo.try_clone()?);
    if let Err(e) = drive(&mut host, &mut servo) {
        let out = q.kill();
        return Err(e.context(format!("while driving the QEMU image; it printed:\n{}", out.output)));
    }
    q.wait(timeout)
}

/// The board image (`msr-qemu`) with its clock driven by the caller: each [`Lockstep::tick`]
/// hands it the bytes that reached its two links during one tick, it runs one `Board::poll` at
/// that tick's time, and what it wrote comes back. From its start until a
/// [`Lockstep::reset`] into lockstep the image runs on its own clock (free running), e.g. for a
/// model upload.
///
/// The commands go on UART2 while the image runs free and through the pipe in lockstep, one
/// write a tick with the tick's bytes; the answers and what the board writes come back on the
/// UARTs. The protocol is documented in `firmware/qemu/src/main.rs` (module `ctl`).
pub struct Lockstep {
    qemu: Qemu,
    host: UnixStream,
    servo: UnixStream,
    clock: UnixStream,
    pipe: Option<std::io::PipeWriter>,
    /// Whether the image runs in lockstep, so that its commands go through the pipe.
    lockstep: bool,
    /// The longest wait for the image to answer, in QEMU's own processor time (see
    /// [`Qemu::wait`]).
    pub timeout: Duration,
    /// Ticks since the last reset.
    pub ticks: u64,
}

/// Most bytes one tick may bring to one link (the image's buffer).
pub const LOCKSTEP_MAX_TICK_BYTES: usize = 1024;

impl Lockstep {
    /// Starts `image` and waits for its start-up message; returns the CRC of the model it runs
    /// (0: none).
    pub fn start(image: &Path) -> Result<(Lockstep, u32)> {
        Lockstep::start_with(image, None)
    }

    /// As [`Lockstep::start`], with `preload` (see [`preload_bytes`]) in the board's PSRAM.
    pub fn start_with(image: &Path, preload: Option<&[u8]>) -> Result<(Lockstep, u32)> {
        Lockstep::start_opts(image, &Options { preload, ..Options::default() })
    }

    /// As [`Lockstep::start`], as `opts` say.
    pub fn start_opts(image: &Path, opts: &Options) -> Result<(Lockstep, u32)> {
        let mut qemu = Qemu::start_opts(image, opts)?;
        let mut ls = Lockstep {
            host: qemu.host.try_clone()?,
            servo: qemu.servo.try_clone()?,
            clock: qemu.clock.try_clone()?,
            pipe: qemu.pipe.take(),
            lockstep: false,
            qemu,
            timeout: Duration::from_secs(60),
            ticks: 0,
        };
        let crc = ls.hello()?;
        // The image runs: the preload is read.
        ls.qemu.tidy();
        Ok((ls, crc))
    }

    /// The running image, for its output or the host link in free-running mode.
    pub fn qemu(&self) -> &Qemu {
        &self.qemu
    }

    /// UART0, for talking to the board while it runs free.
    pub fn host_link(&self) -> &UnixStream {
        &self.host
    }

    /// UART1. While the board runs free it keeps asking for servo states there: read it (or
    /// [`Lockstep::drain_servo`]) or the board stalls (see [`Lockstep::drain_servo`]).
    pub fn servo_link(&self) -> &UnixStream {
        &self.servo
    }

    /// Throws away what the board wrote on the servo bus so far, without waiting.
    ///
    /// QEMU writes a UART's bytes to its socket one at a time, and every one-byte write takes
    /// about a kilobyte of the socket's buffer: a link nobody reads is full after about a
    /// thousand bytes, then the UART stays "transmitter full" and the firmware, waiting to
    /// send, stops reading its other link. That is what stalled model uploads: the board's
    /// servo state requests piled up on an unread UART1.
    pub fn drain_servo(&mut self) -> Result<usize> {
        let s = &self.servo;
        s.set_nonblocking(true)?;
        let mut total = 0;
        let mut buf = [0u8; 4096];
        while let Ok(n) = (&*s).read(&mut buf) {
            if n == 0 {
                break;
            }
            total += n;
        }
        s.set_nonblocking(false)?;
        Ok(total)
    }

    fn read_ctl(&mut self, n: usize, what: &str) -> Result<Vec<u8>> {
        let mut b = vec![0u8; n.max(1)];
        let (pid, limit) = (self.qemu.pid(), self.timeout);
        let r = read_full(&self.clock, &mut b[..1], pid, limit).and_then(|_| {
            if b[0] == b'E' {
                // An error answer is two bytes, whatever was asked.
                b.truncate(2);
            }
            read_full(&self.clock, &mut b[1..], pid, limit)
        });
        if let Err(e) = r {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                // QEMU ended; what the image printed last may still be in the pipe.
                std::thread::sleep(Duration::from_millis(200));
                bail!("the board image ended before answering {what}; it printed:\n{}", self.qemu.output_so_far());
            }
            bail!("the board image did not answer {what} within {:?} ({e}); it printed:\n{}", self.timeout, self.qemu.output_so_far());
        }
        if b[0] == b'E' {
            bail!("the board image refused {what} (error {})", b[1]);
        }
        Ok(b)
    }

    fn hello(&mut self) -> Result<u32> {
        let b = self.read_ctl(5, "start-up")?;
        if b[0] != b'H' {
            bail!("the board image's start-up message is {b:?}, not H");
        }
        Ok(u32::from_le_bytes([b[1], b[2], b[3], b[4]]))
    }

    /// Resets the board (the model it holds in its flash slots stays) and returns the CRC of the
    /// model it runs after the restart. With `lockstep_tick_us` it comes back in lockstep at
    /// time 0 (from its power-on state: nothing runs before the first tick); without, it runs
    /// free.
    pub fn reset(&mut self, lockstep_tick_us: Option<u32>) -> Result<u32> {
        // Nothing of the old run may reach the new one.
        self.drain()?;
        let mut cmd = vec![b'R'];
        cmd.extend(lockstep_tick_us.unwrap_or(0).to_le_bytes());
        self.command(&cmd)?;
        let crc = self.hello()?;
        self.lockstep = lockstep_tick_us.is_some_and(|t| t > 0);
        // What the board wrote between the drain above and its reset (a running-free board
        // keeps asking its servos) is in the sockets by now: QEMU writes a UART's bytes as they
        // are sent, and the start-up message came after them. In lockstep the board writes only
        // within ticks, so whatever is there is old.
        self.drain()?;
        self.ticks = 0;
        Ok(crc)
    }

    /// Throws away what the board wrote on its links.
    fn drain(&mut self) -> Result<()> {
        for s in [&self.host, &self.servo] {
            s.set_nonblocking(true)?;
            let mut buf = [0u8; 4096];
            while let Ok(n) = (&*s).read(&mut buf) {
                if n == 0 {
                    break;
                }
            }
            s.set_nonblocking(false)?;
        }
        Ok(())
    }

    /// One tick: `host_in` and `servo_in` reach the board's UART0 and UART1, the board runs
    /// once, and what it wrote on them is appended to `host_out` and `servo_out`.
    pub fn tick(&mut self, host_in: &[u8], servo_in: &[u8], host_out: &mut Vec<u8>, servo_out: &mut Vec<u8>) -> Result<()> {
        if host_in.len() > LOCKSTEP_MAX_TICK_BYTES || servo_in.len() > LOCKSTEP_MAX_TICK_BYTES {
            bail!(
                "{} + {} bytes in one tick: at most {LOCKSTEP_MAX_TICK_BYTES} per link",
                host_in.len(),
                servo_in.len()
            );
        }
        if !self.lockstep {
            bail!("a tick while the board runs free: reset it into lockstep first");
        }
        let mut cmd = Vec::with_capacity(5 + host_in.len() + servo_in.len());
        cmd.push(b'T');
        cmd.extend((host_in.len() as u16).to_le_bytes());
        cmd.extend((servo_in.len() as u16).to_le_bytes());
        cmd.extend_from_slice(host_in);
        cmd.extend_from_slice(servo_in);
        self.command(&cmd)?;
        let a = self.read_ctl(5, "a tick")?;
        if a[0] != b'T' {
            bail!("the board image answered a tick with {a:?}");
        }
        let (nh, ns) = (u16::from_le_bytes([a[1], a[2]]) as usize, u16::from_le_bytes([a[3], a[4]]) as usize);
        for (s, n, out) in [(&self.host, nh, host_out), (&self.servo, ns, servo_out)] {
            let start = out.len();
            out.resize(start + n, 0);
            read_full(s, &mut out[start..], self.qemu.pid(), self.timeout).context("reading what the board wrote in a tick")?;
        }
        self.ticks += 1;
        Ok(())
    }

    /// The board's status message, read out of band on the clock channel: the framed
    /// `BoardToHost::Status` bytes (decode them like the host link's).
    pub fn status_frame(&mut self) -> Result<Vec<u8>> {
        self.command(b"S")?;
        let h = self.read_ctl(3, "a status request")?;
        if h[0] != b'S' {
            bail!("the board image answered a status request with {h:?}");
        }
        let n = u16::from_le_bytes([h[1], h[2]]) as usize;
        let mut b = vec![0u8; n];
        read_full(&self.clock, &mut b, self.qemu.pid(), self.timeout).context("reading the board's status")?;
        Ok(b)
    }

    /// Ends the run: the image prints its status and exits.
    pub fn exit(mut self, timeout: Duration) -> Result<QemuExit> {
        let _ = self.drain();
        self.command(b"X")?;
        self.qemu.wait(timeout)
    }

    /// Sends a clock-channel command where the image reads them now: the pipe in lockstep,
    /// UART2 otherwise.
    fn command(&mut self, bytes: &[u8]) -> Result<()> {
        let sent = match (self.lockstep, self.pipe.as_mut()) {
            (false, _) => self.clock.write_all(bytes),
            (true, Some(pipe)) => pipe.write_all(bytes),
            (true, None) => bail!("the board runs in lockstep, and QEMU was started without its pipe"),
        };
        sent.map_err(|e| anyhow!("the board image takes no more commands ({e}); it printed:\n{}", self.qemu.output_so_far()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::SystemTime;

    #[cfg(target_os = "linux")]
    #[test]
    fn cpu_time_counts_the_processor_time_of_a_process_not_its_sleep() {
        // A process that sleeps uses next to no processor time; this one, spinning, some.
        let mut sleeper = Command::new("sleep").arg("30").spawn().unwrap();
        let before = cpu_time(sleeper.id()).expect("a running process has a stat");
        let spin_until = Instant::now() + Duration::from_millis(300);
        let mut x = 0u64;
        while Instant::now() < spin_until {
            x = std::hint::black_box(x.wrapping_add(1));
        }
        let slept = cpu_time(sleeper.id()).unwrap().saturating_sub(before);
        assert!(slept < Duration::from_millis(100), "{slept:?}");
        let _ = sleeper.kill();
        let _ = sleeper.wait();
        assert!(cpu_time(std::process::id()).unwrap() > Duration::ZERO);
        assert_eq!(cpu_time(u32::MAX), None);
    }

    #[test]
    fn a_make_rule_splits_at_spaces_but_not_escaped_ones() {
        assert_eq!(
            dep_paths("/a/lib.rs /b/my\\ dir/x.rs  /c/memory.x"),
            [PathBuf::from("/a/lib.rs"), PathBuf::from("/b/my dir/x.rs"), PathBuf::from("/c/memory.x")]
        );
        assert!(dep_paths("").is_empty());
    }

    #[test]
    fn an_image_older_than_a_source_it_names_is_stale() {
        let dir = std::env::temp_dir().join(format!("msr-stale-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("my src")).unwrap();
        let (image, src, gone) = (dir.join("msr-qemu"), dir.join("my src/lib.rs"), dir.join("gone.rs"));
        let set = |p: &Path, s: u64| {
            let f = std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(p).unwrap();
            f.set_modified(SystemTime::UNIX_EPOCH + Duration::from_secs(s)).unwrap();
        };
        std::fs::write(format!("{}.d", image.display()), format!("{}: {} {}\n", image.display(), src.display().to_string().replace(' ', "\\ "), gone.display())).unwrap();
        set(&image, 2_000_000);
        // `gone.rs` is listed but not there (a checkout elsewhere): it says nothing.
        set(&src, 1_000_000);
        assert_eq!(changed_source(&image), None, "a source older than the image");
        set(&src, 2_000_000);
        assert_eq!(changed_source(&image), None, "a source as old as the image");
        set(&src, 3_000_000);
        assert_eq!(changed_source(&image), Some(src.clone()), "a source newer than the image");
        let e = ImageError::Stale { image: image.clone(), source: src.clone() }.to_string();
        assert!(e.contains("is older than its source") && e.contains("cargo xtask images"), "{e}");
        std::fs::remove_file(format!("{}.d", image.display())).unwrap();
        assert_eq!(changed_source(&image), None, "no dep-info beside the image");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
