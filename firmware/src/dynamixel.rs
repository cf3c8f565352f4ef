//! The board as master of a Dynamixel Protocol 2.0 bus (half duplex, one transaction at a time).
//!
//! - Start-up, one transaction each: Ping every mapped ID (a missing one is reported and the
//!   start-up begins again after [`RETRY_US`]; nothing is written, nothing moves), then per
//!   servo: torque off, write Max/Min Position Limit (the map's raw limits: the servo refuses a goal outside
//!   them too), read them back and compare, torque on.
//! - Then every control period: one Sync Write of Goal Position for the joints with a target,
//!   and one Sync Read of Present Position for every mapped joint. A status with the Alert bit
//!   is followed, in the same period if there is time, by a Read of Hardware Error Status.
//! - Nothing is sent while an answer is due: each transaction has a deadline from the bytes on
//!   the line, the servos' Return Delay Time and [`REPLY_SLACK_US`]; a period that finds the
//!   line busy sends nothing (counted).
//! - A position is used only from a status that passed its CRC, comes from the ID whose turn it
//!   is, has exactly the 4 bytes asked for, no error number, and a count inside the encoder's
//!   range. Per ID: timeouts, bad answers, errors and alerts are counted; a servo that misses a
//!   Sync Read goes to the end of the next one, so that it cannot silence the others (servos
//!   answer a Sync Read in order, each after the one before).
//!
//! Units: targets are checked in radians (joint limits) before conversion and in raw counts
//! (the map's raw limits) after, by [`JointMapEntry::to_raw`].

use embedded_io::{Read, ReadReady, Write};
use msr_shared::dynamixel::map::{check_map, default_map, JointMapEntry, MapError, MAP_JOINTS};
use msr_shared::dynamixel::{self as dxl, error, table, Receiver, Status};
use msr_shared::joints::REACH_JOINTS;

use crate::link::{read_ready, READ_CHUNK};

/// Added to every answer deadline: the poll granularity of the board's loop (1 ms in the sim)
/// and a margin.
pub const REPLY_SLACK_US: u64 = 2_000;
/// Pause before a failed start-up begins again.
pub const RETRY_US: u64 = 1_000_000;
/// Largest packet the master sends or takes.
const MAX_PACKET: usize = 128;

/// Line settings the master plans with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BusTiming {
    /// Bus speed, bits per second (8N1).
    pub baud: u32,
    /// The servos' Return Delay Time, in microseconds.
    pub return_delay_us: u32,
}

impl BusTiming {
    /// 1 Mbaud and the X series' factory Return Delay Time (500 us).
    pub const DEFAULT: BusTiming = BusTiming {
        baud: 1_000_000,
        return_delay_us: table::DEFAULT_RETURN_DELAY as u32 * table::RETURN_DELAY_UNIT_US,
    };

    /// Microseconds for `n` bytes on the line (8N1: 10 bits a byte), rounded up.
    pub const fn bytes_us(&self, n: usize) -> u64 {
        (n as u64 * 10 * 1_000_000).div_ceil(self.baud as u64)
    }

    /// One control period's traffic for `joints` servos: the Sync Write of Goal Position, the
    /// Sync Read of Present Position and every answer after its return delay.
    pub const fn period_us(&self, joints: usize) -> u64 {
        let write = dxl::packet_len(4 + 5 * joints);
        let read = dxl::packet_len(4 + joints);
        let status = dxl::packet_len(1 + 4);
        self.bytes_us(write + read)
            + joints as u64 * (self.return_delay_us as u64 + self.bytes_us(status))
    }
}

/// Per-ID fault counters: the host-link report's type, so the board sends them as they are.
pub use msr_shared::msg::ServoIdReport as IdStats;

/// Something the host should hear about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BusEvent {
    /// No answer to a start-up Ping.
    /// `id`: the mapped ID that did not answer.
    #[allow(missing_docs)]
    Missing { id: u8 },
    /// A start-up step failed for this servo: it refused (error number), or the limits read
    /// back differ (`error` 0).
    /// `id`: the servo; `error`: the status's error byte (0: the limits read back differ).
    #[allow(missing_docs)]
    StartFailed { id: u8, error: u8 },
    /// The servo raised its Alert; `hardware` is its Hardware Error Status.
    /// `id`: the servo.
    #[allow(missing_docs)]
    Alert { id: u8, hardware: u8 },
    /// The servo stopped answering (reported once until it answers again).
    /// `id`: the servo.
    #[allow(missing_docs)]
    Lost { id: u8 },
    /// Start-up done: streaming.
    Ready,
}

/// Where the master is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Start-up step `step` of servo `index` (steps: ping, torque off, limits, read back, on).
    /// `index`: position in the joint map; `step`: 0 ping, 1 torque off, 2 limits, 3 read back, 4 torque on.
    #[allow(missing_docs)]
    Start { index: u8, step: u8 },
    /// Start-up failed; it begins again at `retry_us`.
    /// `retry_us`: board time, microseconds.
    #[allow(missing_docs)]
    Failed { retry_us: u64 },
    /// Start-up done: every control period writes goals and reads positions.
    Running,
}

/// What the transaction in flight waits for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Wait {
    Idle,
    /// A status from map entry `index` with `len` parameters.
    One { index: u8, len: u8 },
    /// Sync Read answers: entries `order[next..n]`, 4 parameters each.
    Positions { next: u8 },
}

/// The outcome of one [`Master::poll`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Polled {
    /// Positions (rad) taken this poll, in map order.
    pub positions: [Option<f32>; MAP_JOINTS],
    /// A Sync Read completed with every servo's position.
    pub complete: bool,
}

/// The bus master.
pub struct Master {
    map: [JointMapEntry; MAP_JOINTS],
    timing: BusTiming,
    stage: Stage,
    wait: Wait,
    deadline_us: u64,
    /// Sync Read order (map indices): servos that missed go last.
    order: [u8; MAP_JOINTS],
    missed: [bool; MAP_JOINTS],
    read_this_cycle: [bool; MAP_JOINTS],
    /// A Hardware Error Status read is due for this map index.
    alert_due: Option<u8>,
    rx: Receiver<MAX_PACKET>,
    stats: [IdStats; MAP_JOINTS],
    events: heapless::Deque<BusEvent, 8>,
    /// Periods that found the line still busy.
    pub busy_periods: u32,
    /// Targets refused by the map (outside the joint or raw limits).
    pub refused_targets: u32,
    /// Bytes that could not be written.
    pub write_failures: u32,
}

impl Master {
    /// A master for the emulated robot's map at 1 Mbaud.
    pub fn new() -> Master {
        Master::with(default_map(), BusTiming::DEFAULT).expect("the default map is valid")
    }

    /// A master for `map` (in [`REACH_JOINTS`] order); refused with the map's first error.
    pub fn with(map: [JointMapEntry; MAP_JOINTS], timing: BusTiming) -> Result<Master, MapError> {
        check_map(&map)?;
        for (e, j) in map.iter().zip(REACH_JOINTS) {
            if e.joint != j {
                return Err(MapError::BadJoint { joint: e.joint });
            }
        }
        let mut stats = [IdStats::default(); MAP_JOINTS];
        for (s, e) in stats.iter_mut().zip(&map) {
            s.id = e.id;
        }
        Ok(Master {
            map,
            timing,
            stage: Stage::Start { index: 0, step: 0 },
            wait: Wait::Idle,
            deadline_us: 0,
            order: core::array::from_fn(|i| i as u8),
            missed: [false; MAP_JOINTS],
            read_this_cycle: [false; MAP_JOINTS],
            alert_due: None,
            rx: Receiver::new(),
            stats,
            events: heapless::Deque::new(),
            busy_periods: 0,
            refused_targets: 0,
            write_failures: 0,
        })
    }

    /// Takes a new map: start-up runs again (the servos' limits change with it).
    pub fn set_map(&mut self, map: [JointMapEntry; MAP_JOINTS]) -> Result<(), MapError> {
        *self = Master::with(map, self.timing)?;
        Ok(())
    }

    /// The joint map in use.
    pub fn map(&self) -> &[JointMapEntry; MAP_JOINTS] {
        &self.map
    }

    /// Where start-up stands, or `Running`.
    pub fn stage(&self) -> Stage {
        self.stage
    }

    /// A servo has reported a hardware error (overload, overheating, ...): its torque may be
    /// off, so the board stops moving.
    pub fn faulted(&self) -> bool {
        self.stats.iter().any(|s| s.hardware_error != 0)
    }

    /// Per-ID fault counters, in joint-map order.
    pub fn stats(&self) -> &[IdStats; MAP_JOINTS] {
        &self.stats
    }

    /// What the receiver threw away (CRC errors, noise, ...).
    pub fn rx_counters(&self) -> &dxl::RxCounters {
        self.rx.counters()
    }

    /// The next event for the host.
    pub fn event(&mut self) -> Option<BusEvent> {
        self.events.pop_front()
    }

    fn push_event(&mut self, e: BusEvent) {
        if self.events.is_full() {
            self.events.pop_front();
        }
        let _ = self.events.push_back(e);
    }

    /// Is an answer due?
    pub fn busy(&self) -> bool {
        self.wait != Wait::Idle
    }

    /// Reads what arrived, handles deadlines and advances the start-up.
    pub fn poll<V: Read + Write + ReadReady>(&mut self, now_us: u64, io: &mut V) -> Polled {
        let mut out = Polled::default();
        let mut buf = [0u8; READ_CHUNK];
        // Bounded: a flood cannot hold the loop.
        for _ in 0..64 {
            let n = read_ready(io, &mut buf);
            if n == 0 {
                break;
            }
            for &b in &buf[..n] {
                self.rx.push(b);
                while let Some(p) = self.rx.next_packet() {
                    // Statuses only: an instruction is our own echo on a half-duplex line.
                    let Some(s) = Status::of(&p) else { continue };
                    let (id, err, len) = (s.id, s.error, s.params.len());
                    let mut params = [0u8; 8];
                    let take = len.min(params.len());
                    params[..take].copy_from_slice(&s.params[..take]);
                    self.on_status(now_us, id, err, &params[..take], len, &mut out);
                }
            }
        }
        if self.wait != Wait::Idle && now_us >= self.deadline_us {
            self.on_timeout(now_us);
        }
        if self.wait == Wait::Idle {
            self.next_start_step(now_us, io);
        }
        out
    }

    /// One control period: Sync Write of `targets` (rad, map order; `None`: no goal for that
    /// joint) when given, then the Sync Read. Nothing when an answer is still due.
    pub fn period<V: Write>(&mut self, now_us: u64, io: &mut V, targets: Option<[Option<f32>; MAP_JOINTS]>) {
        if self.stage != Stage::Running {
            return;
        }
        if self.wait != Wait::Idle {
            self.busy_periods = self.busy_periods.saturating_add(1);
            return;
        }
        let mut pkt = [0u8; MAX_PACKET];
        let mut sent = 0;
        if let Some(t) = targets {
            let mut raw = [[0u8; 4]; MAP_JOINTS];
            let mut ids = [0u8; MAP_JOINTS];
            let mut n = 0;
            for (i, a) in t.iter().enumerate() {
                let Some(a) = a else { continue };
                match self.map[i].to_raw(*a) {
                    Ok(r) => {
                        raw[n] = (r as u32).to_le_bytes();
                        ids[n] = self.map[i].id;
                        n += 1;
                    }
                    Err(_) => self.refused_targets = self.refused_targets.saturating_add(1),
                }
            }
            if n > 0 {
                let entries = (0..n).map(|k| (ids[k], &raw[k][..]));
                if let Ok(len) = dxl::sync_write(table::GOAL_POSITION.addr, 4, entries, &mut pkt) {
                    sent += len;
                    self.send(io, &pkt[..len]);
                }
            }
        }
        let ids: [u8; MAP_JOINTS] = self.order.map(|i| self.map[i as usize].id);
        let p = table::PRESENT_POSITION;
        if let Ok(len) = dxl::sync_read(p.addr, p.len, &ids, &mut pkt) {
            sent += len;
            self.send(io, &pkt[..len]);
            self.read_this_cycle = [false; MAP_JOINTS];
            self.rx.clear();
            self.wait = Wait::Positions { next: 0 };
            let status = dxl::packet_len(1 + p.len as usize);
            self.deadline_us = now_us
                + self.timing.bytes_us(sent)
                + MAP_JOINTS as u64
                    * (self.timing.return_delay_us as u64 + self.timing.bytes_us(status))
                + REPLY_SLACK_US;
        }
    }

    fn send<V: Write>(&mut self, io: &mut V, bytes: &[u8]) {
        if io.write_all(bytes).is_err() {
            self.write_failures = self.write_failures.saturating_add(1);
        }
    }

    /// Sends one instruction to map entry `index` and waits for its `len`-parameter status.
    fn transact<V: Write>(&mut self, now_us: u64, io: &mut V, index: u8, pkt: &[u8], len: u8) {
        self.send(io, pkt);
        self.rx.clear();
        self.wait = Wait::One { index, len };
        self.deadline_us = now_us
            + self.timing.bytes_us(pkt.len())
            + self.timing.return_delay_us as u64
            + self.timing.bytes_us(dxl::packet_len(1 + len as usize))
            + REPLY_SLACK_US;
    }

    fn next_start_step<V: Write>(&mut self, now_us: u64, io: &mut V) {
        let mut pkt = [0u8; MAX_PACKET];
        match self.stage {
            Stage::Running => {
                // A Hardware Error Status read, between periods.
                if let Some(i) = self.alert_due.take() {
                    let h = table::HARDWARE_ERROR_STATUS;
                    if let Ok(n) = dxl::read(self.map[i as usize].id, h.addr, h.len, &mut pkt) {
                        self.transact(now_us, io, i, &pkt[..n], h.len as u8);
                    }
                }
            }
            Stage::Failed { retry_us } => {
                if now_us >= retry_us {
                    self.stage = Stage::Start { index: 0, step: 0 };
                    self.next_start_step(now_us, io);
                }
            }
            Stage::Start { index, step } => {
                let e = self.map[index as usize];
                let (lim_max, lim_min) = (table::MAX_POSITION_LIMIT, table::MIN_POSITION_LIMIT);
                let (n, len) = match step {
                    0 => (dxl::ping(e.id, &mut pkt), 3),
                    1 => (dxl::write(e.id, table::TORQUE_ENABLE.addr, &[0], &mut pkt), 0),
                    2 => {
                        // Max (48) and Min (52) are adjacent: one Write of both.
                        let mut v = [0u8; 8];
                        v[..4].copy_from_slice(&(e.raw_max as u32).to_le_bytes());
                        v[4..].copy_from_slice(&(e.raw_min as u32).to_le_bytes());
                        (dxl::write(e.id, lim_max.addr, &v, &mut pkt), 0)
                    }
                    3 => (dxl::read(e.id, lim_max.addr, lim_max.len + lim_min.len, &mut pkt), 8),
                    _ => (dxl::write(e.id, table::TORQUE_ENABLE.addr, &[1], &mut pkt), 0),
                };
                if let Ok(n) = n {
                    self.transact(now_us, io, index, &pkt[..n], len);
                }
            }
        }
    }

    fn fail(&mut self, now_us: u64, e: BusEvent) {
        self.push_event(e);
        self.stage = Stage::Failed { retry_us: now_us + RETRY_US };
    }

    fn on_timeout(&mut self, now_us: u64) {
        match self.wait {
            Wait::One { index, .. } => {
                let i = index as usize;
                self.stats[i].timeouts = self.stats[i].timeouts.saturating_add(1);
                let id = self.map[i].id;
                if let Stage::Start { .. } = self.stage {
                    self.fail(now_us, BusEvent::Missing { id });
                }
            }
            Wait::Positions { next } => {
                // The servo whose turn it was did not answer, and those after it waited for
                // it. It goes to the end of the next Sync Read, the others keep their order.
                let culprit = self.order[next as usize];
                let i = culprit as usize;
                self.stats[i].timeouts = self.stats[i].timeouts.saturating_add(1);
                if !self.missed[i] {
                    self.missed[i] = true;
                    let id = self.map[i].id;
                    self.push_event(BusEvent::Lost { id });
                }
                let mut order = [culprit; MAP_JOINTS];
                for (k, &j) in self.order.iter().filter(|&&j| j != culprit).enumerate() {
                    order[k] = j;
                }
                self.order = order;
            }
            Wait::Idle => {}
        }
        self.wait = Wait::Idle;
    }

    fn on_status(&mut self, now_us: u64, id: u8, err: u8, params: &[u8], len: usize, out: &mut Polled) {
        match self.wait {
            Wait::Idle => {} // Late or stray: nobody asked.
            Wait::One { index, len: want } => {
                let i = index as usize;
                if id != self.map[i].id || len != want as usize {
                    self.stats[i].bad_answers = self.stats[i].bad_answers.saturating_add(1);
                    return; // Keep waiting: the right answer may still come.
                }
                self.wait = Wait::Idle;
                self.note_error(i, err);
                match self.stage {
                    Stage::Start { index, step } => {
                        let e = self.map[i];
                        let ok = err & !error::ALERT == 0
                            && (step != 3 || {
                                let max = i32::from_le_bytes([params[0], params[1], params[2], params[3]]);
                                let min = i32::from_le_bytes([params[4], params[5], params[6], params[7]]);
                                max == e.raw_max && min == e.raw_min
                            });
                        if !ok || err & error::ALERT != 0 {
                            self.fail(now_us, BusEvent::StartFailed { id, error: err });
                        } else if step == 0 && (index as usize) + 1 < MAP_JOINTS {
                            self.stage = Stage::Start { index: index + 1, step: 0 };
                        } else if step == 0 {
                            // Everyone answered the Ping: now configure them one by one.
                            self.stage = Stage::Start { index: 0, step: 1 };
                        } else if step < 4 {
                            self.stage = Stage::Start { index, step: step + 1 };
                        } else if (index as usize) + 1 < MAP_JOINTS {
                            self.stage = Stage::Start { index: index + 1, step: 1 };
                        } else {
                            self.stage = Stage::Running;
                            self.push_event(BusEvent::Ready);
                        }
                    }
                    _ => {
                        // The Hardware Error Status read.
                        if let Some(&h) = params.first() {
                            if h != self.stats[i].hardware_error {
                                self.push_event(BusEvent::Alert { id, hardware: h });
                            }
                            self.stats[i].hardware_error = h;
                        }
                    }
                }
            }
            Wait::Positions { next } => {
                let mut pos = next as usize;
                // Servos answer in order: an ID later in the list means the ones before it
                // were lost (e.g. to a damaged byte); an ID not still due is never taken.
                let Some(at) = (pos..MAP_JOINTS).find(|&k| self.map[self.order[k] as usize].id == id) else {
                    let i = self.order[pos] as usize;
                    self.stats[i].bad_answers = self.stats[i].bad_answers.saturating_add(1);
                    return;
                };
                for k in pos..at {
                    let j = self.order[k] as usize;
                    self.stats[j].timeouts = self.stats[j].timeouts.saturating_add(1);
                }
                pos = at;
                let next = at as u8;
                let i = self.order[pos] as usize;
                let raw = (len == 4).then(|| i32::from_le_bytes([params[0], params[1], params[2], params[3]]));
                let max_raw = table::COUNTS_PER_TURN as i32 - 1;
                match raw {
                    Some(r) if (0..=max_raw).contains(&r) && err & !error::ALERT == 0 => {
                        out.positions[i] = Some(self.map[i].to_rad(r));
                        self.read_this_cycle[i] = true;
                        if self.missed[i] {
                            self.missed[i] = false;
                        }
                    }
                    _ => self.stats[i].bad_answers = self.stats[i].bad_answers.saturating_add(1),
                }
                self.note_error(i, err);
                // Read Hardware Error Status when the Alert first shows (then it is known).
                if err & error::ALERT != 0 && self.stats[i].hardware_error == 0 && self.alert_due.is_none() {
                    self.alert_due = Some(i as u8);
                }
                if pos + 1 < MAP_JOINTS {
                    self.wait = Wait::Positions { next: next + 1 };
                } else {
                    self.wait = Wait::Idle;
                    out.complete = self.read_this_cycle.iter().all(|&r| r);
                }
            }
        }
    }

    fn note_error(&mut self, i: usize, err: u8) {
        let s = &mut self.stats[i];
        if err & !error::ALERT != 0 {
            s.errors = s.errors.saturating_add(1);
        }
        if err & error::ALERT != 0 {
            s.alerts = s.alerts.saturating_add(1);
        }
    }
}

impl Default for Master {
    fn default() -> Self {
        Master::new()
    }
}

#[cfg(test)]
mod tests;
