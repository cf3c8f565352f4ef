//! The board: bytes in, commands out. One [`Board::poll`] call reads what has arrived on the
//! host link and the servo bus, answers it, runs the watchdogs, and every 10 ms sends the next
//! servo targets. Nothing else: no clock, no interrupts, no heap, so the host (the sim drives it
//! in-process), QEMU and the real board run the same code.

use crate::confirm::Confirm;
use crate::dynamixel::{BusEvent, Master, Polled};
use crate::link::{
    read_ready, Assembly, Progress, Rx, Tx, Watchdog, FACE_TIMEOUT_US, READ_CHUNK,
    SERVO_TIMEOUT_US,
};
use crate::model::{self, ModelStore, Upload, UploadError};
use crate::motion::{HeadError, Motion, Phase, PERIOD_US};
use crate::pipeline::{self, Workspace};
use crate::saliency::Settings;
use crate::self_gate::{Gate, Step};
use embedded_io::{Read, ReadReady, Write};
use msr_shared::blob::{Merge, Model};
use msr_shared::frame::FrameError;
use msr_shared::joints::REACH_JOINTS;
use msr_shared::msg::{
    BlobReport, BoardToHost, BoardToServo, Config, Detection, ErrorCode, FrameAck, FrameHeader,
    FrameState, HostToBoard, JointTarget, Mode, ServoBusKind, ServoBusReport,
    GateUndecided, ModelSource, NoDetection, RoomCommand, RoomReport, RoomState, ServoToBoard,
    Status, StoreReport,
};
use crate::light::Verdict;
use head::{held, Head, Settle, Steady};

mod head;
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

    fn on_states<H: Write>(
        &mut self,
        now_us: u64,
        states: &[msr_shared::msg::JointState],
        host: &mut H,
    ) {
        let mut any = false;
        let mut yaw = false;
        for s in states {
            if let Some(i) = REACH_JOINTS.iter().position(|j| *j == s.joint) {
                if s.position.is_finite() {
                    self.measured[i] = Some(s.position);
                    any = true;
                    yaw |= i == 0;
                }
            }
        }
        if any {
            self.feed_servos(now_us);
        }
        if yaw {
            self.gate_report(now_us, host);
        }
    }

    /// Fresh positions of the servos arrived: the watchdog is fed, streaming (re)starts.
    fn feed_servos(&mut self, now_us: u64) {
        let recovered = self.servo_wd.feed(now_us);
        if self.motion.commanded().is_none() {
            if let [Some(a), Some(b), Some(c), Some(d), Some(e)] = self.measured {
                self.motion.start_from([a, b, c, d, e]);
                // After an outage the arm may be anywhere: finish by going home.
                if recovered {
                    self.motion.go_home();
                }
            }
        }
    }

    fn on_host<H: Write>(
        &mut self,
        now_us: u64,
        msg: HostToBoard,
        ws: &mut Workspace,
        frame: &mut Assembly,
        host: &mut H,
    ) {
        let chooses_nothing = matches!(
            msg,
            HostToBoard::Ping { .. }
                | HostToBoard::GetStatus
                | HostToBoard::GetServoBus
                | HostToBoard::GetStore
                | HostToBoard::UseServoBus(_)
                | HostToBoard::SetServoMap(_)
        );
        if !self.bus_known && !chooses_nothing {
            // A host that does not choose: the framed bus, as before the choice existed.
            self.bus_known = true;
        }
        match msg {
            HostToBoard::Ping { nonce } => {
                self.host_tx.send(host, &BoardToHost::Pong { nonce });
            }
            // Answered by `poll` once the message no longer borrows the receiver's counters.
            HostToBoard::GetStatus => self.status_pending = true,
            HostToBoard::FrameStart(h) => match self.loaded {
                None => self.error(host, ErrorCode::NoModel, 0),
                Some(l) => {
                    if frame.start(h, l.face_w, l.face_h).is_err() {
                        self.error(host, ErrorCode::BadFrame, h.frame as u32);
                    }
                }
            },
            HostToBoard::FrameChunk {
                frame: id,
                offset,
                data,
            } => match frame.chunk(id, offset, data) {
                Ok(Progress::Quiet) => {}
                Ok(Progress::Ack(a)) => self.ack(host, a),
                Ok(Progress::Complete(h)) => {
                    self.ack(host, FrameAck { frame: h.frame, round: 0, state: FrameState::Complete });
                    self.on_frame(now_us, h, frame.pixels(&h), ws, host)
                }
                Err(_) => self.error(host, ErrorCode::BadFrame, id as u32),
            },
            HostToBoard::FramePoll { header, round } => match self.loaded {
                None => self.error(host, ErrorCode::NoModel, 0),
                Some(l) => match frame.poll(header, round, l.face_w, l.face_h) {
                    Ok(a) => self.ack(host, a),
                    Err(_) => self.error(host, ErrorCode::BadFrame, header.frame as u32),
                },
            },
            HostToBoard::ModelBegin { len, crc32 } => match self.upload.begin(&mut self.store, len, crc32) {
                // The slot is being erased: the ack (and so the chunks) wait for it.
                Ok(_) if self.store.busy() => self.upload_ack_due = true,
                Ok(next) => self.upload_ack(host, next),
                Err(e) => self.error(host, ErrorCode::BadUpload, e.detail()),
            },
            // Chunks before the ack, or while the flash is busy: dropped (the host sends them
            // again from where the board says it stands).
            HostToBoard::ModelChunk { .. } if self.upload_ack_due || self.store.busy() => {}
            HostToBoard::ModelChunk { offset, data } => {
                match self.upload.chunk(&mut self.store, offset, data) {
                    Ok(None) => {}
                    Ok(Some(next)) => self.upload_ack(host, next),
                    Err(e) => self.error(host, ErrorCode::BadUpload, e.detail()),
                }
            }
            // The commit record waits for flash work in progress (a log compaction).
            HostToBoard::ModelCommit if self.store.busy() => self.commit_due = true,
            HostToBoard::ModelCommit => self.commit_upload(ws, frame, host),
            HostToBoard::Configure(c) => {
                if !self.configure(&c) {
                    self.error(host, ErrorCode::BadConfig, 0);
                }
            }
            HostToBoard::UseServoBus(kind) => {
                self.dxl = match kind {
                    ServoBusKind::Framed => None,
                    ServoBusKind::Dynamixel => Some(Master::new()),
                };
                self.bus_known = true;
                self.dxl_stopped = false;
            }
            HostToBoard::SetServoMap(map) => {
                self.bus_known = true;
                let m = self.dxl.get_or_insert_with(Master::new);
                if let Err(e) = m.set_map(map) {
                    let at = map.iter().position(|j| Some(j.joint) == map_error_joint(e));
                    self.error(host, ErrorCode::BadServoMap, at.map_or(u32::MAX, |i| i as u32));
                }
            }
            HostToBoard::GetServoBus => {
                let r = self.servo_bus_report();
                self.host_tx.send(host, &BoardToHost::ServoBus(r));
            }
            HostToBoard::MoveHead { yaw, pitch } => self.move_head(now_us, [yaw, pitch], host),
            HostToBoard::GetStore => self.store_report(now_us, host),
            HostToBoard::ResetStats => {
                ws.room.reset();
                self.room = ws.room.report(self.room_applies());
                let crc = self.loaded.map_or(0, |l| l.crc);
                if !self.store.reset_stats(crc) {
                    self.error(host, ErrorCode::StoreBusy, 0);
                }
                self.store_report(now_us, host);
            }
            HostToBoard::Room(cmd) => {
                match cmd {
                    RoomCommand::Freeze => ws.room.freeze(true),
                    RoomCommand::Resume => ws.room.freeze(false),
                    RoomCommand::Reset => {
                        ws.room.reset();
                        let crc = self.loaded.map_or(0, |l| l.crc);
                        if self.store.saved_stats(crc).is_some() && !self.store.reset_stats(crc) {
                            self.error(host, ErrorCode::StoreBusy, 0);
                        }
                    }
                    RoomCommand::Save => {
                        if !self.save_room(ws, now_us / 1000) {
                            self.error(host, ErrorCode::StoreBusy, 0);
                        }
                        self.store_report(now_us, host);
                        return;
                    }
                }
                self.room = ws.room.report(self.room_applies());
                self.status_pending = true;
            }
        }
    }

    fn commit_upload<H: Write>(&mut self, ws: &mut Workspace, frame: &mut Assembly, host: &mut H) {
        self.commit_due = false;
        match self.upload.commit(&mut self.store) {
            Ok(crc) => {
                frame.clear();
                // Just validated whole: its CRC need not be read again (a pass over the blob
                // would stretch this poll, and so the control period).
                self.load_active(ws, true);
                self.host_tx.send(host, &BoardToHost::ModelAccepted { crc32: crc });
            }
            Err(UploadError::Incomplete { next }) => self.upload_ack(host, next),
            Err(e @ UploadError::Invalid(_)) => self.error(host, ErrorCode::BadModel, e.detail()),
            Err(e) => self.error(host, ErrorCode::BadUpload, e.detail()),
        }
    }

    fn store_report<H: Write>(&mut self, now_us: u64, host: &mut H) {
        let crc = self.loaded.map_or(0, |l| l.crc);
        let r = StoreReport {
            model_crc: crc,
            source: if self.loaded.is_some() { self.store.source() } else { ModelSource::None },
            stats: self.loaded.and_then(|l| self.store.stats_age(l.crc)),
            now_ms: now_us / 1000,
            busy: self.store.busy(),
            capacity: self.store.capacity().min(u32::MAX as usize) as u32,
        };
        self.host_tx.send(host, &BoardToHost::Store(r));
    }

    fn move_head<H: Write>(&mut self, now_us: u64, head: [f32; 2], host: &mut H) {
        // Head babbling sends no face frames: the request is the host's sign of life.
        self.face_wd.feed(now_us);
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        let result = if self.servo_wd.tripped() || faulted {
            Err(HeadError::NotStreaming)
        } else {
            self.motion.move_head(head)
        };
        match result {
            Ok(periods) => {
                let planned = periods as u64 * PERIOD_US;
                self.head.start(head, now_us, planned);
            }
            Err(e) => {
                let detail = match e {
                    HeadError::OutOfLimits => 0,
                    HeadError::NotStreaming => 1,
                    HeadError::Busy => 2,
                };
                self.error(host, ErrorCode::HeadRefused, detail);
            }
        }
    }

    /// After each control period: answers a head pose once the servos report it settled.
    fn check_head<H: Write>(&mut self, now_us: u64, host: &mut H) {
        match self.head.check(now_us, &self.measured, &self.motion) {
            Settle::Idle => {}
            Settle::Settled => {
                let head = [self.measured[0].unwrap_or(0.0), self.measured[1].unwrap_or(0.0)];
                self.host_tx.send(host, &BoardToHost::HeadAt { head });
            }
            Settle::NotSettled(waited_ms) => self.error(host, ErrorCode::HeadNotSettled, waited_ms),
            // A move the host asked for is finished, not cut short by the face watchdog.
            Settle::Moving => {
                self.face_wd.feed(now_us);
            }
        }
    }

    fn servo_bus_report(&self) -> ServoBusReport {
        let mut r = ServoBusReport {
            kind: ServoBusKind::Framed,
            running: false,
            servos: Default::default(),
            rx_errors: 0,
            busy_periods: 0,
        };
        // Before the host chose (see `Board::await_servo_bus`): framed, not running.
        if let Some(m) = &self.dxl {
            r.kind = ServoBusKind::Dynamixel;
            r.running = m.stage() == crate::dynamixel::Stage::Running;
            r.servos = *m.stats();
            r.rx_errors = m.rx_counters().errors();
            r.busy_periods = m.busy_periods;
        }
        r
    }

    /// What a Dynamixel poll brought: positions, and events for the host.
    fn on_positions<H: Write>(&mut self, now_us: u64, polled: Polled, host: &mut H) {
        let yaw = polled.positions[0].is_some();
        for (m, p) in self.measured.iter_mut().zip(polled.positions) {
            if let Some(p) = p {
                *m = Some(p);
            }
        }
        while let Some(e) = self.dxl.as_mut().and_then(|m| m.event()) {
            let (code, detail) = match e {
                BusEvent::Ready => continue,
                BusEvent::Missing { id } => (ErrorCode::ServoMissing, id as u32),
                BusEvent::StartFailed { id, error } => (ErrorCode::ServoFault, id as u32 | (error as u32) << 16),
                BusEvent::Alert { id, hardware } => (ErrorCode::ServoFault, id as u32 | (hardware as u32) << 8),
                BusEvent::Lost { id } => (ErrorCode::ServoLost, id as u32),
            };
            self.error(host, code, detail);
        }
        // Only a Sync Read with every position feeds the watchdog: one silent servo is enough
        // to stop the motion once the watchdog's period has passed.
        if polled.complete {
            self.feed_servos(now_us);
        }
        if yaw {
            self.gate_report(now_us, host);
        }
    }

    fn ack<H: Write>(&mut self, host: &mut H, a: FrameAck) {
        self.host_tx.send(host, &BoardToHost::FrameAck(a));
    }

    fn upload_ack<H: Write>(&mut self, host: &mut H, next: u32) {
        self.host_tx.send(host, &BoardToHost::UploadAck { next });
    }

    /// Applies a configuration, all or nothing.
    fn configure(&mut self, c: &Config) -> bool {
        let s = Settings {
            threshold: c.threshold,
            normalisation: c.normalisation,
            sided: c.sided,
            min_area: c.min_area,
            // The merge is the model's: the host link does not carry one.
            merge: self.settings.map_or(Merge::OFF, |s| s.merge),
        };
        let Some(confirm) = Confirm::new(c.confirm_k, c.confirm_n) else {
            return false;
        };
        let mut motion = self.motion;
        if !s.is_valid()
            || !motion.set_speed_fraction(c.speed_fraction)
            || !motion.set_hold_ms(c.hold_ms)
        {
            return false;
        }
        self.motion = motion;
        self.confirm = confirm;
        if self.loaded.is_some() {
            self.settings = Some(s);
        }
        true
    }

    fn on_frame<H: Write>(
        &mut self,
        now_us: u64,
        h: FrameHeader,
        pixels: &[u8],
        ws: &mut Workspace,
        host: &mut H,
    ) {
        self.counts.frames = self.counts.frames.saturating_add(1);
        if self.face_wd.feed(now_us) {
            self.motion.go_home();
        }
        if self.motion.phase() == Phase::Probe {
            // The probe's frames go to the gate only: no reach while the head moves.
            let step = match (self.measured[0], self.measured[1]) {
                (Some(yaw), Some(pitch)) => {
                    let head = self.steady.pose([yaw, pitch]);
                    let salient = match (self.settings, self.store.active()) {
                        (Some(s), Some(bytes)) => Model::parse_trusted(bytes).ok().and_then(|m| {
                            pipeline::detect(ws, &m, &s, pixels, [h.crop_x, h.crop_y], head).ok()
                        }),
                        _ => None,
                    };
                    let face = salient.as_ref().is_some_and(|d| d.light.verdict == Verdict::Face);
                    let salient = salient.map_or(u32::MAX, |d| d.salient_pixels);
                    match self.gate.as_mut() {
                        Some(g) => g.on_probe_frame(now_us, h.frame, h.position(), salient, face),
                        None => Step::Wait,
                    }
                }
                _ => Step::Wait,
            };
            self.gate_step(now_us, step, h.frame, host);
            return;
        }
        if self.motion.arm_up() {
            // Detection pauses while the arm is up; the reach is reported again.
            if let Some(d) = self.last_reach {
                self.host_tx.send(host, &BoardToHost::Detection(d));
            }
            return;
        }
        self.last_reach = None;
        let (Some(yaw), Some(pitch)) = (self.measured[0], self.measured[1]) else {
            self.error(host, ErrorCode::ServoTimeout, 1);
            return;
        };
        let head = [yaw, pitch];
        let steady = self.steady.pose(head);
        if self.store.busy() {
            // On a board the model's flash bank may be being erased: reading it would stall the
            // CPU (and the control period) until the erase ends. The next frame is read.
            self.error(host, ErrorCode::StoreBusy, 1);
            return;
        }
        let result = match (self.settings, self.store.active()) {
            (Some(settings), Some(bytes)) => match Model::parse_trusted(bytes) {
                Ok(model) => {
                    pipeline::detect(ws, &model, &settings, pixels, [h.crop_x, h.crop_y], steady)
                        .map_err(|_| (ErrorCode::BadFrame, h.frame as u32))
                }
                Err(_) => Err((ErrorCode::NoModel, 1)),
            },
            _ => Err((ErrorCode::NoModel, 0)),
        };
        let det = match result {
            Ok(d) => d,
            Err((code, detail)) => {
                self.error(host, code, detail);
                return;
            }
        };
        if det.blob.is_some() {
            self.counts.detections = self.counts.detections.saturating_add(1);
        }
        let reason = match det.light.verdict {
            Verdict::Face => None,
            Verdict::NoFace => {
                self.counts.no_face = self.counts.no_face.saturating_add(1);
                Some(NoDetection::NoFace)
            }
            Verdict::SceneChanged => {
                self.counts.scene_changed = self.counts.scene_changed.saturating_add(1);
                Some(NoDetection::SceneChanged)
            }
        };
        if let Some(g) = self.gate.as_mut() {
            g.observe(h.position(), yaw, det.salient_pixels);
        }
        let mut confirmed = false;
        let held = held(head, self.motion.head_goal());
        if self.confirm.push(det.blob.is_some())
            && !self.servo_wd.tripped()
            && !self.face_wd.tripped()
        {
            if let (Some(target), Some(g)) = (det.reach, self.gate.as_mut()) {
                // Not yet: first the probe that tells whether this face is ours.
                self.confirm.reset();
                let step = g.start(now_us, h.frame, held, target);
                self.gate_step(now_us, step, h.frame, host);
            } else if let Some(target) = det.reach {
                if self.motion.reach(target) {
                    confirmed = true;
                    self.counts.reaches = self.counts.reaches.saturating_add(1);
                    self.counts.clamped_targets = self.counts.clamped_targets.saturating_add(det.reach_clamped);
                    self.confirm.reset();
                }
            }
        }
        // Online self-calibration, never on a frame that paid for a new prediction (rule 1):
        // the frame's budget has no room for both. Rule 3 on the next frame after a batch's
        // last, whatever it shows: that frame is not learnt from, so the update's cost and the
        // samples' never share one. Else rule 1: only a face with nothing on it, no candidate
        // being confirmed, observing with the head still.
        let held = !ws.afresh();
        if held && ws.room.pending() {
            self.room_unsaved |= ws.room.settle();
            self.room = ws.room.report(self.room_applies());
        } else if held
            && reason.is_none()
            && det.blob.is_none()
            && self.confirm.quiet()
            && self.motion.phase() == Phase::Observe
            && !self.head.moving()
            && self.room.state == RoomState::Learning
        {
            if let Some(m) = self.store.active().and_then(|b| Model::parse_trusted(b).ok()) {
                self.room_unsaved |= ws.learn(&m, pixels, now_us);
                self.room = ws.room.report(true);
            }
        }
        let now_ms = now_us / 1000;
        if self.room_unsaved && now_ms.saturating_sub(self.room_saved_ms) >= ROOM_SAVE_MS {
            self.save_room(ws, now_ms);
        }
        let blob = det.blob.zip(det.centroid).map(|(b, c)| BlobReport {
            area: b.area,
            box_xyxy: [
                b.x0.saturating_add(h.crop_x),
                b.y0.saturating_add(h.crop_y),
                b.x1.saturating_add(h.crop_x),
                b.y1.saturating_add(h.crop_y),
            ],
            centroid: c,
        });
        let d = Detection {
            frame: h.frame,
            head,
            blob,
            confirmed,
            reach: det.reach,
            reason,
        };
        if confirmed {
            self.last_reach = Some(d);
        }
        self.host_tx.send(host, &BoardToHost::Detection(d));
    }

    /// Carries out what the self gate asks: a head pose, or its decision (reported on the host
    /// link; a pass starts the reach as a confirmed detection of `frame`, anything else goes home).
    fn gate_step<H: Write>(&mut self, now_us: u64, step: Step, frame: u16, host: &mut H) {
        match step {
            Step::Wait => {}
            Step::Head(head) => {
                if !self.motion.probe(head) {
                    // Not streaming (the servos went quiet just now): undecided.
                    if let Some(g) = self.gate.as_mut() {
                        let s = g.abort(now_us, GateUndecided::ServosSilent);
                        self.gate_step(now_us, s, frame, host);
                    }
                }
            }
            Step::Done(report, target) => {
                self.host_tx.send(host, &BoardToHost::SelfGate(report));
                match target {
                    Some(t) if self.motion.reach(t) => {
                        self.counts.reaches = self.counts.reaches.saturating_add(1);
                        let head = [self.measured[0].unwrap_or(f32::NAN), self.measured[1].unwrap_or(f32::NAN)];
                        let d = Detection { frame, head, blob: None, confirmed: true, reach: Some(t), reason: None };
                        self.last_reach = Some(d);
                        self.host_tx.send(host, &BoardToHost::Detection(d));
                    }
                    _ => self.motion.go_home(),
                }
            }
        }
    }

    /// A fresh report of the head's yaw (this poll's servo status, not the last one kept): to
    /// the gate, which averages the reports at rest and at each probe pose. Fresh only: a poll
    /// runs as often as its loop does (each sim tick, unpaced on a board), not once a report.
    fn gate_report<H: Write>(&mut self, now_us: u64, host: &mut H) {
        let (Some(yaw), Some(g)) = (self.measured[0], self.gate.as_mut()) else { return };
        let step = g.on_servo(now_us, yaw);
        let frame = self.last_reach.map_or(0, |d| d.frame);
        self.gate_step(now_us, step, frame, host);
    }

    /// While probing: the ways a probe ends without frames (a watchdog, a bus fault, the
    /// timeout).
    fn gate_watch<H: Write>(&mut self, now_us: u64, host: &mut H) {
        self.last_poll_us = now_us;
        let Some(g) = self.gate.as_mut() else { return };
        if !g.probing() {
            return;
        }
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        let step = if self.servo_wd.tripped() || faulted || self.motion.commanded().is_none() {
            g.abort(now_us, GateUndecided::ServosSilent)
        } else if self.face_wd.tripped() {
            g.abort(now_us, GateUndecided::FaceLost)
        } else {
            g.poll(now_us)
        };
        let frame = self.last_reach.map_or(0, |d| d.frame);
        self.gate_step(now_us, step, frame, host);
    }

    /// One control period.
    fn tick<V: Write>(&mut self, now_us: u64, servo: &mut V) {
        if !self.bus_known {
            // Not a byte on a bus whose protocol is not known. The servo watchdog is armed by
            // the first positions only, so this silence trips nothing.
            return;
        }
        if self.dxl.is_some() {
            return self.tick_dynamixel(now_us, servo);
        }
        let time_ms = (now_us / 1000) as u32;
        let stale = self
            .servo_wd
            .last_us()
            .is_none_or(|t| now_us.saturating_sub(t) >= STATE_REQUEST_US);
        let asked = self
            .last_request_us
            .is_some_and(|t| now_us.saturating_sub(t) < STATE_REQUEST_US);
        if stale && !asked {
            self.servo_tx.send(servo, &BoardToServo::StateRequest);
            self.last_request_us = Some(now_us);
        }
        if self.servo_wd.tripped() {
            return; // Not streaming until the servos answer again.
        }
        let posture = if self.face_wd.tripped() {
            self.motion.hold_still()
        } else {
            self.motion.tick()
        };
        let Some(p) = posture else { return };
        if !self.stiffness_sent {
            self.stiffness_sent = self
                .servo_tx
                .send(servo, &BoardToServo::Stiffness { on: true });
        }
        let mut targets = heapless::Vec::new();
        for (j, a) in REACH_JOINTS.iter().zip(p) {
            // The last line of defence: only angles the joint table accepts are ever sent.
            match j.validate(a) {
                Ok(a) => {
                    let _ = targets.push(JointTarget {
                        joint: *j,
                        position: a,
                    });
                }
                Err(_) => self.counts.clamped_targets = self.counts.clamped_targets.saturating_add(1),
            }
        }
        self.servo_tx
            .send(servo, &BoardToServo::Targets { time_ms, targets });
    }

    /// One control period on the Dynamixel bus: goals for the posture (none while a watchdog
    /// holds or a servo reports a hardware error), and the positions read back.
    fn tick_dynamixel<V: Write>(&mut self, now_us: u64, servo: &mut V) {
        let faulted = self.dxl.as_ref().is_some_and(|m| m.faulted());
        if faulted && !self.dxl_stopped {
            self.dxl_stopped = true;
            self.motion.stop();
        }
        let posture = if self.servo_wd.tripped() || faulted {
            None
        } else if self.face_wd.tripped() {
            self.motion.hold_still()
        } else {
            self.motion.tick()
        };
        let targets = posture.map(|p| {
            let mut t = [None; REACH_JOINTS.len()];
            for ((o, j), a) in t.iter_mut().zip(REACH_JOINTS).zip(p) {
                // Radians first; the master checks raw counts after conversion.
                match j.validate(a) {
                    Ok(a) => *o = Some(a),
                    Err(_) => self.counts.clamped_targets = self.counts.clamped_targets.saturating_add(1),
                }
            }
            t
        });
        if let Some(m) = self.dxl.as_mut() {
            m.period(now_us, servo, targets);
        }
    }
}

/// The joint a map error names.
fn map_error_joint(e: msr_shared::dynamixel::map::MapError) -> Option<msr_shared::joints::Joint> {
    use msr_shared::dynamixel::map::MapError::*;
    match e {
        BadId { joint } | BadJoint { joint } | BadScale { joint } | BadRawLimits { joint }
        | LeavesLimits { joint } | TargetOutOfRange { joint } | RawOutOfRange { joint, .. } => {
            Some(joint)
        }
    }
}

#[cfg(test)]
mod tests;
