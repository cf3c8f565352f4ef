//! Running the bare-metal firmware image under `qemu-system-arm` (mps2-an386) with its UARTs
//! connected to byte streams on the host side.
//!
//! QEMU runs with `-icount shift=0`: every emulated instruction advances the virtual clock by
//! 1 ns, so the image's SysTick counts instructions and its timing (watchdogs, the 10 ms motion
//! period) is virtual time, independent of how fast this machine is.
//!
//! UART0 (the host link) and UART1 (the servo bus) are unix-domain sockets: this side listens,
//! QEMU connects as a client at start-up. What the image prints through semihosting lands in
//! [`QemuExit::output`]; its semihosting exit code is QEMU's exit status.

use std::io::{self, Read};
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
/// How long QEMU gets to connect its UART sockets.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

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

/// The path of a built image, or an error that says how to build it.
pub fn find_image(name: &str) -> Result<PathBuf> {
    let path = image_dir().join(name);
    if path.is_file() {
        Ok(path)
    } else {
        bail!(
            "firmware image {} is missing; build it with `cargo xtask images` \
             (or `cd firmware/qemu && cargo build --release`)",
            path.display()
        )
    }
}

/// How a run ended.
#[derive(Clone, Debug)]
pub struct QemuExit {
    /// QEMU's exit status: the image's semihosting exit code. `None` if QEMU was killed.
    pub code: Option<i32>,
    /// What QEMU and the image printed (stdout then stderr).
    pub output: String,
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
        let dir = std::env::temp_dir().join(format!(
            "msr-qemu-{}-{}",
            std::process::id(),
            RUN_ID.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let paths = [dir.join("uart0.sock"), dir.join("uart1.sock")];
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
        cmd.args(["-machine", "mps2-an386", "-cpu", "cortex-m4", "-nographic", "-monitor", "none"])
            .args(["-semihosting-config", "enable=on,target=native"])
            .args(["-icount", "shift=0"]);
        for (i, p) in paths.iter().enumerate() {
            cmd.arg("-chardev")
                .arg(format!("socket,id=uart{i},path={}", p.display()))
                .arg("-serial")
                .arg(format!("chardev:uart{i}"));
        }
        cmd.arg("-kernel").arg(image);
        cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
        let mut child = cmd
            .spawn()
            .with_context(|| format!("starting {} (is qemu-system-arm installed?)", qemu_binary()))?;

        let live = Arc::new(Mutex::new(Vec::new()));
        let stdout = child.stdout.take().map(|s| capture(s, live.clone()));
        let stderr = child.stderr.take().map(|s| capture(s, live.clone()));
        let mut qemu = Qemu {
            child: Some(child),
            // Placeholders until QEMU connects; replaced below.
            host: UnixStream::pair()?.0,
            servo: UnixStream::pair()?.0,
            stdout,
            stderr,
            live,
            dir,
        };
        let deadline = Instant::now() + CONNECT_TIMEOUT;
        let mut streams = Vec::new();
        for l in &listeners {
            streams.push(qemu.accept(l, deadline)?);
        }
        qemu.servo = streams.pop().expect("two listeners");
        qemu.host = streams.pop().expect("two listeners");
        Ok(qemu)
    }

    fn accept(&mut self, l: &UnixListener, deadline: Instant) -> Result<UnixStream> {
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
            if Instant::now() > deadline {
                bail!("QEMU did not connect its UARTs within {CONNECT_TIMEOUT:?}:\n{}", self.output_so_far());
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// What the image has printed so far.
    pub fn output_so_far(&self) -> String {
        String::from_utf8_lossy(&self.live.lock().unwrap_or_else(|e| e.into_inner())).into_owned()
    }

    /// Whether QEMU is still running.
    pub fn is_running(&mut self) -> bool {
        self.child.as_mut().is_some_and(|c| matches!(c.try_wait(), Ok(None)))
    }

    /// Waits for the image to end (semihosting exit), killing QEMU after `timeout`.
    pub fn wait(mut self, timeout: Duration) -> Result<QemuExit> {
        let mut child = self.child.take().ok_or_else(|| anyhow!("QEMU already waited for"))?;
        let deadline = Instant::now() + timeout;
        let mut timed_out = false;
        let status = loop {
            if let Some(s) = child.try_wait()? {
                break Some(s);
            }
            if Instant::now() > deadline {
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
        let _ = std::fs::remove_dir_all(&self.dir);
    }
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

/// Runs `image` to its end with nothing on the UARTs but what `drive` does with them.
pub fn run_image(
    image: &Path,
    timeout: Duration,
    drive: impl FnOnce(&mut UnixStream, &mut UnixStream) -> Result<()>,
) -> Result<QemuExit> {
    let q = Qemu::start(image)?;
    let (mut host, mut servo) = (q.host.try_clone()?, q.servo.try_clone()?);
    if let Err(e) = drive(&mut host, &mut servo) {
        let out = q.kill();
        return Err(e.context(format!("while driving the QEMU image; it printed:\n{}", out.output)));
    }
    q.wait(timeout)
}
