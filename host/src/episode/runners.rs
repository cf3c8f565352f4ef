//! Runs trials on the in-process board: one, many in parallel, or a run of them on one board.
use super::config::{EpisodeConfig, LightSpan};
use super::scenario::{run_trial_with, Camera};
use super::summary::{end_with_status, Trial};
use anyhow::{anyhow, Result};
use msr_firmware::model::HeapStore;
use msr_firmware::Board;
use msr_shared::blob::Model;
use msr_sim::link::LinkEnd;
use msr_sim::render::Renderer;

/// The in-process firmware: a board with the model built in.
pub type InprocBoard = Board<HeapStore>;

/// A fresh in-process board running `blob` as its built-in model, with room for uploads of up
/// to 512 KiB.
pub fn inproc_board(blob: &[u8]) -> Box<InprocBoard> {
    Box::new(Board::new(HeapStore::new(Some(blob), 512 * 1024)))
}

/// Runs one trial with the in-process board. `seed` makes the trial (mark, noise, link faults).
pub fn run_trial_inproc(
    blob: &[u8],
    camera: Camera,
    cfg: &EpisodeConfig,
    index: usize,
    seed: u64,
) -> Result<Trial> {
    let mut board = inproc_board(blob);
    // As the QEMU image: wired to either bus, the trial's host chooses.
    board.await_servo_bus();
    let mut log = Vec::new();
    let log_bus = cfg.log_bus;
    let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| {
        if log_bus {
            board.poll(now, h, &mut Tee { inner: s, log: &mut log })
        } else {
            board.poll(now, h, s)
        }
    };
    let (mut trial, _) = run_trial_with(&mut fw, camera, cfg, index, seed)?;
    trial.bus_bytes = log;
    // In-process the board's own counters are at hand (a GetStatus would report the same).
    let s = board.status();
    end_with_status(&mut trial, &s);
    Ok(trial)
}

/// A servo bus end that keeps a copy of what is written to it.
pub struct Tee<'a> {
    /// The bus end that reads and writes go to.
    pub inner: &'a mut LinkEnd,
    /// Every byte written to `inner`, in order.
    pub log: &'a mut Vec<u8>,
}

impl embedded_io::ErrorType for Tee<'_> {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Read for Tee<'_> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        embedded_io::Read::read(self.inner, buf)
    }
}

impl embedded_io::ReadReady for Tee<'_> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        embedded_io::ReadReady::read_ready(self.inner)
    }
}

impl embedded_io::Write for Tee<'_> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = embedded_io::Write::write(self.inner, buf)?;
        self.log.extend_from_slice(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        embedded_io::Write::flush(self.inner)
    }
}

/// Seed of trial `i` of a run seeded `seed`.
pub fn trial_seed(seed: u64, i: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((i as u64).wrapping_mul(0x2545_F491_4F6C_DD1D))
        .wrapping_add(1)
}

/// Runs `n` in-process trials, `cfg.parallel` at a time; `progress` is told after each.
pub fn run_inproc(
    blob: &[u8],
    cfg: &EpisodeConfig,
    n: usize,
    seed: u64,
    progress: &(dyn Fn(&Trial) + Sync),
) -> Result<Vec<Trial>> {
    let model = Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let renderer = Renderer::new(cfg.robot);
    let next = std::sync::atomic::AtomicUsize::new(0);
    // Reserve no more than a small start: `n` comes from the command line.
    let results = std::sync::Mutex::new(Vec::with_capacity(n.min(1024)));
    let first_error = std::sync::Mutex::new(None);
    std::thread::scope(|s| {
        for _ in 0..cfg.parallel.max(1).min(n.max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                if i >= n || first_error.lock().unwrap().is_some() {
                    return;
                }
                let camera = Camera {
                    renderer: &renderer,
                    cropper: &cropper,
                };
                match run_trial_inproc(blob, camera, cfg, i, trial_seed(seed, i)) {
                    Ok(t) => {
                        progress(&t);
                        results.lock().unwrap().push(t);
                    }
                    Err(e) => {
                        first_error.lock().unwrap().get_or_insert(e);
                    }
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().unwrap() {
        return Err(e);
    }
    let mut v = results.into_inner().unwrap();
    v.sort_by_key(|t| t.index);
    Ok(v)
}

/// Runs `n` in-process trials one after another as one long run of robot time: the light's
/// plan spans the run (`cfg.light` over `n` trials of `mark_at + watch`, each trial starting
/// where the last ended), and each trial's board takes over what the previous one learnt of
/// the room and its clock (the world and the links are fresh each trial). Returns the trials
/// and the room's state at the end.
pub fn run_one_board(
    blob: &[u8],
    cfg: &EpisodeConfig,
    n: usize,
    seed: u64,
    progress: &(dyn Fn(&Trial) + Sync),
) -> Result<(Vec<Trial>, msr_shared::msg::RoomReport)> {
    let model = Model::parse(blob).map_err(|e| anyhow!("model blob: {e}"))?;
    let cropper = crate::detect::cropper_of(&model)?;
    let renderer = Renderer::new(cfg.robot);
    let span_us = n as u64 * (cfg.mark_at_us + cfg.watch_us);
    let mut carried: Option<msr_firmware::room::Room> = None;
    let mut offset_us = 0u64;
    let mut trials = Vec::with_capacity(n.min(1024));
    let mut room = None;
    for i in 0..n {
        let mut c = cfg.clone();
        c.light_span = Some(LightSpan { seed, span_us, offset_us });
        let mut board = inproc_board(blob);
        board.await_servo_bus();
        let mut room_in = carried.take();
        // The board's clock runs on across trials, so what it learnt keeps its times.
        let mut fw = |now: u64, h: &mut LinkEnd, s: &mut LinkEnd| {
            board.poll(offset_us + now, h, s);
            // After the first poll: the board has loaded its model (which resets the room).
            if let Some(r) = room_in.take() {
                board.set_room(r);
            }
        };
        let camera = Camera { renderer: &renderer, cropper: &cropper };
        let (mut trial, _) = run_trial_with(&mut fw, camera, &c, i, trial_seed(seed, i))?;
        let s = board.status();
        end_with_status(&mut trial, &s);
        carried = Some(board.room().clone());
        room = Some(s.room);
        offset_us += (trial.sim_s * 1e6) as u64;
        progress(&trial);
        trials.push(trial);
    }
    Ok((trials, room.unwrap_or(msr_firmware::room::Room::new().report(false))))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trial_seeds_wrap_and_differ() {
        // Debug builds check overflow: large indices and seeds must wrap, not panic.
        let seeds: Vec<u64> = (0..300).map(|i| trial_seed(u64::MAX, i)).collect();
        let mut unique = seeds.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), seeds.len());
        assert_eq!(trial_seed(0, 0), 1);
        assert_ne!(trial_seed(0, 7), trial_seed(1, 7));
    }
}
