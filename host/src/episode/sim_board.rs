//! A simulated board on a pseudo-terminal: the in-process firmware with the sim's servos, its
//! host link bridged to a PTY, in real time, so that `msr run --port PATH` (or any `serialport`
//! code) talks to it exactly as it would to a board on a USB serial port.
use crate::episode::inproc_board;
use anyhow::{anyhow, Result};
use msr_shared::msg::Status;
use msr_sim::link::LinkEnd;
use msr_sim::pty::{Pty, PtyBridge};
use msr_sim::world::{self, Flow, World, WorldConfig};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// What the served board did, when it stopped.
#[derive(Debug)]
pub struct Served {
    pub status: Status,
    pub limit_violations: u32,
    pub to_board_bytes: u64,
    pub from_board_bytes: u64,
}

pub struct SimBoard {
    path: String,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<Served>>>,
}

impl SimBoard {
    /// Starts a board with `blob` built in (or none) behind a new PTY.
    pub fn start(blob: Option<Vec<u8>>) -> Result<SimBoard> {
        let pty = Pty::open()?;
        let path = pty.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new().name("sim-board".into()).spawn(
            move || -> Result<Served> {
                let mut board = match &blob {
                    Some(b) => inproc_board(b),
                    None => Box::new(msr_firmware::Board::new(crate::episode::HeapStore::new(
                        None,
                        2 * 1024 * 1024,
                    ))),
                };
                let mut bridge = PtyBridge::new(pty);
                let mut io_error = None;
                let cfg = WorldConfig {
                    pace: Some(1.0),
                    ..WorldConfig::default()
                };
                let (w, _) = {
                    let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| board.poll(now, h, s);
                    world::run(
                        &cfg,
                        &mut fw,
                        |w: &mut World| {
                            if let Err(e) = bridge.pump(&mut w.host) {
                                io_error = Some(e);
                                return Flow::Stop;
                            }
                            if stop2.load(Ordering::SeqCst) {
                                Flow::Stop
                            } else {
                                Flow::Continue
                            }
                        },
                        u64::MAX / 2,
                    )
                    .map_err(|e| anyhow!("{e}"))?
                };
                if let Some(e) = io_error {
                    return Err(anyhow!("PTY: {e}"));
                }
                Ok(Served {
                    status: board.status(),
                    limit_violations: w.servos.counters().limit_violations,
                    to_board_bytes: bridge.to_link,
                    from_board_bytes: bridge.to_pty,
                })
            },
        )?;
        Ok(SimBoard {
            path,
            stop,
            thread: Some(thread),
        })
    }

    /// The device path to open, e.g. `/dev/pts/5`.
    pub fn path(&self) -> &str {
        &self.path
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
