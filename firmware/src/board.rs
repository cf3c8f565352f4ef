//! The board: bytes in, commands out. One [`Board::poll`] call reads what has arrived on the
//! host link and the servo bus, answers it, runs the watchdogs, and every 10 ms sends the next
//! servo targets. Nothing else: no clock, no interrupts, no heap, so the host (the sim drives it
//! in-process), QEMU and the real board run the same code.

use crate::confirm::Confirm;
use crate::dynamixel::Master;
use crate::link::{
    read_ready, Assembly, Rx, Tx, Watchdog, FACE_TIMEOUT_US, READ_CHUNK, SERVO_TIMEOUT_US,
};
use crate::model::{self, ModelStore, Upload};
use crate::motion::{Motion, Phase, PERIOD_US};
use crate::pipeline::Workspace;
use crate::saliency::Settings;
use crate::self_gate::Gate;
use embedded_io::{Read, ReadReady, Write};
use msr_shared::frame::FrameError;
use msr_shared::msg::{
    BoardToHost, Detection, ErrorCode, HostToBoard, Mode, RoomReport, RoomState, ServoToBoard,
    Status,
};
use head::{Head, Steady};

mod frame;
mod head;
mod host;
mod servos;
pub use head::{HOLD_RAD, SETTLE_MARGIN_US, SETTLE_PERIODS, SETTLE_RAD, STILL_RAD};

/// The room's offsets ([`crate::room`]) are saved to the store this often while they change.
pub const ROOM_SAVE_MS: u64 = 5 * 60 * 1000;
/// Most bytes taken from one link per poll, so a flood cannot starve the control loop.
pub const MAX_BYTES_PER_POLL: usize = 4096;
/// Ask the servos for their state when none came for this long.
pub const STATE_REQUEST_US: u64 = 20_000;
/// The model in use, as far as the board needs to remember it between frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Loaded {
    crc: u32,
    face_w: u16,
    face_h: u16,
}

/// What the board counts, as `Status` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Counts {
    frames: u32,
    detections: u32,
    reaches: u32,
    clamped_targets: u32,
    /// Frames the photometric fit refused, by reason.
    no_face: u32,
    scene_changed: u32,
}

impl Counts {
    const ZERO: Counts = Counts { frames: 0, detections: 0, reaches: 0, clamped_targets: 0, no_face: 0, scene_changed: 0 };
}

/// Everything but the big buffers and the receivers (split so a received message, which borrows
/// its receiver, can be handled while the rest changes).
struct Core<S: ModelStore> {
    store: S,
    checked: bool,
    loaded: Option<Loaded>,
    upload: Upload,
    settings: Option<Settings>,
    confirm: Confirm,
    /// The model's self gate (`None`: a confirmed mark is reached at once).
    gate: Option<Gate>,
    motion: Motion,
    measured: [Option<f32>; 5],
    host_tx: Tx,
    servo_tx: Tx,
    face_wd: Watchdog,
    servo_wd: Watchdog,
    next_tick_us: Option<u64>,
    last_request_us: Option<u64>,
    stiffness_sent: bool,
    status_pending: bool,
    counts: Counts,
    /// The servo bus speaks Dynamixel Protocol 2.0 with this master (`None`: framed).
    dxl: Option<Master>,
    /// The servo bus's protocol is known (see [`Board::await_servo_bus`]): until then nothing
    /// is sent on it and what arrives there is dropped.
    bus_known: bool,
    /// Bytes were dropped mid-frame before the bus was known: the framed receiver joins the
    /// bus at the next delimiter (the rest of that frame is not an error of the link).
    servo_mid_frame: bool,
    dxl_stopped: bool,
    /// The detection that started the reach in progress, repeated while the arm is up so
    /// that a host that lost it still learns of the reach.
    last_reach: Option<Detection>,
    /// The time of the latest poll, for decisions made outside one.
    last_poll_us: u64,
    /// The head move the host waits on.
    head: Head,
    /// The head pose the pipeline was last given.
    steady: Steady,
    /// `ModelBegin` was taken while the store erased: the `UploadAck` goes out once it is done.
    upload_ack_due: bool,
    /// `ModelCommit` came while the store was busy: it is carried out once it is done.
    commit_due: bool,
    /// Board time the room's offsets were last saved (or loaded), ms; they are saved again
    /// [`ROOM_SAVE_MS`] later if they changed.
    room_saved_ms: u64,
    /// The room's offsets changed since they were last saved.
    room_unsaved: bool,
    /// What `Status` says of the room (kept here: `status` does not see the workspace).
    room: RoomReport,
}

/// The firmware. `S` holds the model blobs (see [`ModelStore`]).
pub struct Board<S: ModelStore> {
    ws: Workspace,
    frame: Assembly,
    host_rx: Rx,
    servo_rx: Rx,
    core: Core<S>,
}

impl<S: ModelStore> Board<S> {
    /// A board with its model store. `const`, so a binary can place it in a `static`.
    pub const fn new(store: S) -> Self {
        Board {
            ws: Workspace::new(),
            frame: Assembly::new(),
            host_rx: Rx::new(),
            servo_rx: Rx::new(),
            core: Core {
                store,
                checked: false,
                loaded: None,
                upload: Upload::new(),
                settings: None,
                confirm: Confirm::defaults(),
                gate: None,
                motion: Motion::new(),
                measured: [None; 5],
                host_tx: Tx::new(),
                servo_tx: Tx::new(),
                face_wd: Watchdog::new(FACE_TIMEOUT_US),
                servo_wd: Watchdog::new(SERVO_TIMEOUT_US),
                next_tick_us: None,
                last_request_us: None,
                stiffness_sent: false,
                status_pending: false,
                counts: Counts::ZERO,
                dxl: None,
                bus_known: true,
                servo_mid_frame: false,
                dxl_stopped: false,
                last_reach: None,
                last_poll_us: 0,
                head: Head::new(),
                steady: Steady::new(),
                upload_ack_due: false,
                commit_due: false,
                room_saved_ms: 0,
                room_unsaved: false,
                room: RoomReport { state: RoomState::Off, frames: 0, updates: 0, largest_q88: 0, at_limit: 0 },
            },
        }
    }

    /// Chooses the servo bus: framed (`None`) or Dynamixel Protocol 2.0 with this master.
    /// A board built for one bus calls it at start-up; [`Board::new`] starts framed.
    pub fn set_servo_bus(&mut self, master: Option<Master>) {
        self.core.dxl = master;
        self.core.bus_known = true;
        self.core.dxl_stopped = false;
    }

    /// Leaves the servo bus's protocol to the host, for a board wired to either bus (QEMU, the
    /// sim's trials): nothing is sent on the servo bus until the host's `UseServoBus` (or
    /// `SetServoMap`: Dynamixel). A host that starts with anything but those or a query
    /// (`Ping`, `GetStatus`, `GetServoBus`, `GetStore`) gets the framed bus, the protocol's
    /// default. Call it at start-up, before the first poll.
    pub fn await_servo_bus(&mut self) {
        self.core.dxl = None;
        self.core.bus_known = false;
        self.core.dxl_stopped = false;
    }

    /// The Dynamixel master, when the servo bus speaks Protocol 2.0.
    pub fn dynamixel(&self) -> Option<&Master> {
        self.core.dxl.as_ref()
    }

    /// One step: `now_us` is a monotonic clock in microseconds.
    pub fn poll<H, V>(&mut self, now_us: u64, host: &mut H, servo: &mut V)
    where
        H: Read + Write + ReadReady,
        V: Read + Write + ReadReady,
    {
        let core = &mut self.core;
        if !core.checked {
            core.checked = true;
            core.store.start();
            core.load_active(&mut self.ws, false);
        }
        // Flash work in steps (one sector's erase at most), so the control period holds.
        core.store.step();
        if core.upload_ack_due && !core.store.busy() {
            core.upload_ack_due = false;
            if let Some(next) = core.upload.next() {
                core.upload_ack(host, next);
            }
        }
        if core.commit_due && !core.store.busy() {
            core.commit_upload(&mut self.ws, &mut self.frame, host);
        }
        let mut buf = [0u8; READ_CHUNK];
        let mut taken = 0;
        if let Some(m) = core.dxl.as_mut() {
            let polled = m.poll(now_us, servo);
            core.on_positions(now_us, polled, host);
            taken = MAX_BYTES_PER_POLL; // The master has read the bus.
        } else if !core.bus_known {
            // Nobody was asked: whatever is there is not ours to parse (nor to count as errors).
            while taken < MAX_BYTES_PER_POLL {
                let n = read_ready(servo, &mut buf);
                if n == 0 {
                    break;
                }
                taken += n;
                core.servo_mid_frame = buf[n - 1] != 0;
            }
        }
        while taken < MAX_BYTES_PER_POLL {
            let n = read_ready(servo, &mut buf);
            if n == 0 {
                break;
            }
            taken += n;
            for &b in &buf[..n] {
                if core.servo_mid_frame {
                    core.servo_mid_frame = b != 0;
                    continue;
                }
                if let Some(Ok(f)) = self.servo_rx.push(b) {
                    match f.message::<ServoToBoard>() {
                        Ok(ServoToBoard::States { states, .. }) => {
                            core.on_states(now_us, &states, host)
                        }
                        Err(_) => self.servo_rx.count_malformed(),
                    }
                }
            }
        }
        let mut taken = 0;
        while taken < MAX_BYTES_PER_POLL {
            let n = read_ready(host, &mut buf);
            if n == 0 {
                break;
            }
            taken += n;
            for &b in &buf[..n] {
                match self.host_rx.push(b) {
                    Some(Ok(f)) => match f.message::<HostToBoard>() {
                        Ok(msg) => core.on_host(now_us, msg, &mut self.ws, &mut self.frame, host),
                        Err(_) => self.host_rx.count_malformed(),
                    },
                    // A host of another protocol: say so rather than go quiet.
                    Some(Err(FrameError::Version(v))) => {
                        core.error(host, ErrorCode::Version, v as u32)
                    }
                    _ => {}
                }
                if core.status_pending {
                    core.status_pending = false;
                    let s = core.status(&self.host_rx, &self.servo_rx, &self.frame);
                    core.host_tx.send(host, &BoardToHost::Status(s));
                }
            }
        }
        if core.face_wd.check(now_us) {
            core.error(host, ErrorCode::FaceTimeout, 0);
            let s = core.status(&self.host_rx, &self.servo_rx, &self.frame);
            core.host_tx.send(host, &BoardToHost::Status(s));
        }
        if core.servo_wd.check(now_us) {
            core.motion.stop();
            core.error(host, ErrorCode::ServoTimeout, 0);
            let s = core.status(&self.host_rx, &self.servo_rx, &self.frame);
            core.host_tx.send(host, &BoardToHost::Status(s));
        }
        core.gate_watch(now_us, host);
        let due = *core.next_tick_us.get_or_insert(now_us);
        if now_us >= due {
            core.tick(now_us, servo);
            core.check_head(now_us, host);
            let next = due + PERIOD_US;
            core.next_tick_us = Some(if next <= now_us {
                now_us + PERIOD_US
            } else {
                next
            });
        }
    }

    /// Counters and state, as `GetStatus` answers.
    pub fn status(&self) -> Status {
        self.core.status(&self.host_rx, &self.servo_rx, &self.frame)
    }

    /// The model store: the running blob and the upload staging area.
    pub fn store(&self) -> &S {
        &self.core.store
    }

    /// The model store, to change it outside the host link (a preloaded model at start-up).
    pub fn store_mut(&mut self) -> &mut S {
        &mut self.core.store
    }

    /// The behaviour's phase.
    pub fn phase(&self) -> Phase {
        self.core.motion.phase()
    }

    /// The posture last streamed (or to be streamed) to the servos.
    pub fn commanded(&self) -> Option<[f32; 5]> {
        self.core.motion.commanded()
    }

    /// What the board has learnt of the room's light ([`crate::room`]).
    pub fn room(&self) -> &crate::room::Room {
        &self.ws.room
    }

    /// Takes what another board learnt of the room with the running model, batch in progress
    /// and all (a long simulated run carries it from trial to trial; call after the first
    /// `poll`, which loads the model and so resets the room).
    pub fn set_room(&mut self, room: crate::room::Room) {
        self.ws.room = room;
        self.core.room = self.ws.room.report(self.core.room_applies());
    }

    /// The novelty settings in force (`None` without a model).
    pub fn settings(&self) -> Option<Settings> {
        self.core.settings
    }
}

impl<S: ModelStore> Core<S> {
    /// Takes the store's active blob if it validates (the built-in one at start-up); `trusted`:
    /// it validated just now, all but the CRC is checked again.
    fn load_active(&mut self, ws: &mut Workspace, trusted: bool) {
        ws.invalidate();
        self.loaded = None;
        self.settings = None;
        self.gate = None;
        if self.motion.phase() == Phase::Probe {
            self.motion.go_home();
        }
        let check = if trusted { model::validate_trusted } else { model::validate };
        if let Some(m) = self.store.active().and_then(|b| check(b).ok()) {
            self.gate = m.self_gate.map(Gate::new);
            self.loaded = Some(Loaded {
                crc: m.crc32,
                face_w: m.face_w,
                face_h: m.face_h,
            });
            self.settings = Some(Settings::of(&m));
        }
        // What was learnt of the room belongs to the model it was learnt with.
        ws.room.reset();
        if let Some(l) = self.loaded {
            if let Some(saved) = self.store.saved_stats(l.crc) {
                ws.room.restore(saved);
            }
        }
        self.room_saved_ms = self.last_poll_us / 1000;
        self.room_unsaved = false;
        self.room = ws.room.report(self.room_applies());
        self.confirm.reset();
    }

    /// Whether the room's offsets are in use: a model is loaded.
    fn room_applies(&self) -> bool {
        self.loaded.is_some()
    }

    /// Saves the room's offsets for the running model; false if the store could not.
    fn save_room(&mut self, ws: &Workspace, now_ms: u64) -> bool {
        let Some(l) = self.loaded else { return false };
        let mut bytes = [0u8; crate::room::SAVED_LEN];
        ws.room.save(&mut bytes);
        let ok = self.store.save_stats(l.crc, now_ms, &bytes);
        // A store that keeps nothing (RAM) is not asked again at every frame.
        self.room_saved_ms = now_ms;
        self.room_unsaved &= !ok;
        ok
    }

    fn mode(&self) -> Mode {
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        if self.face_wd.tripped() || self.servo_wd.tripped() || faulted {
            return Mode::Halted;
        }
        if self.loaded.is_none() {
            return Mode::NoModel;
        }
        match self.motion.phase() {
            Phase::Observe => Mode::Observe,
            Phase::Reach => Mode::Reach,
            Phase::Hold => Mode::Hold,
            Phase::Return => Mode::Return,
            Phase::Probe => Mode::SelfTest,
        }
    }

    fn status(&self, host_rx: &Rx, servo_rx: &Rx, frame: &Assembly) -> Status {
        Status {
            mode: self.mode(),
            model_crc: self.loaded.map_or(0, |l| l.crc),
            frames: self.counts.frames,
            detections: self.counts.detections,
            reaches: self.counts.reaches,
            host_link: *host_rx.counters(),
            servo_link: *servo_rx.counters(),
            face_watchdog_trips: self.face_wd.trips,
            servo_watchdog_trips: self.servo_wd.trips,
            clamped_targets: self
                .counts
                .clamped_targets
                .saturating_add(self.dxl.as_ref().map_or(0, |m| m.refused_targets)),
            frames_superseded: frame.superseded,
            chunks_ignored: frame.ignored,
            frame_crc_errors: frame.crc_errors,
            no_face: self.counts.no_face,
            scene_changed: self.counts.scene_changed,
            room: self.room,
        }
    }

    fn error<H: Write>(&mut self, host: &mut H, code: ErrorCode, detail: u32) {
        self.host_tx
            .send(host, &BoardToHost::Error { code, detail });
    }
}

#[cfg(test)]
mod tests;
