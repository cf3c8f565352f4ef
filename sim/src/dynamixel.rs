//! Emulated Dynamixel X-series servos (XM430-W350) on a Protocol 2.0 bus.
//!
//! Each joint on the bus is one servo with the control-table items of
//! [`msr_shared::dynamixel::table`] at their real addresses and sizes, moved by the same dynamics
//! as the framed bus (`servo`), so that the two buses differ only on the wire. A servo
//! answers only when asked (Ping, Read, Write to its ID, Sync Read naming it), after its Return
//! Delay Time, and a Sync Read's answers follow one another in the order asked, each after the
//! one before it; a servo that does not answer silences those after it in that Sync Read (the
//! conservative reading of the e-Manual, where each waits for its predecessor).
//!
//! Like a real X-series servo: EEPROM items (Return Delay Time, Min/Max Position Limit, Status
//! Return Level) are writable only with torque off (else Access Error); a Goal Position outside
//! Min/Max Position Limit is refused (Data Limit Error, error number 6); torque on takes the
//! present position as the goal; an overload sets Hardware Error Status, turns the torque off and
//! raises the Alert bit of every status. IDs, the baud rate and the operating mode are read-only
//! here.
//!
//! Like a configured robot's servos: Min/Max Position Limit hold each joint's range (the map's
//! raw limits, what the board writes at start-up) from power-on, so that any master sees the
//! range the joint really has. A goal beyond the joint's mechanical stop (possible only once a
//! master has widened the limits, or through a mounting the master's map gets wrong) stalls the
//! joint at the stop; held there for [`STALL_OVERLOAD_US`], the servo raises Overload.
//!
//! Safety accounting (as the framed bus): a Goal Position that the servo refuses, or whose angle
//! through the robot's true mounting is outside the joint's limits, is a **limit violation**.
//!
//! Faults to inject ([`DxlFault`]): a servo that stops answering from a given time, an overload
//! from a given time; corrupted bytes come from the link's fault layer ([`crate::link`]).
use crate::actuator::{Servo, COUNT_RAD};
use msr_shared::dynamixel::map::JointMapEntry;
use msr_shared::dynamixel::table::{self, Item};
use msr_shared::dynamixel::{self as dxl, error, Instruction, Receiver, RxCounters, Status};
use msr_shared::joints::Joint;

/// What can go wrong with one servo, from `at_us` on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DxlFault {
    /// Never answers again (its writes still take effect: a broken return line).
    /// Servo `id` stops answering from `at_us` on.
    Silent {
        /// The servo.
        id: u8,
        /// From when, microseconds.
        at_us: u64,
    },
    /// Overload shutdown: Hardware Error Status bit 5, torque off, Alert in every status.
    /// Servo `id` reports an overload from `at_us` on.
    Overload {
        /// The servo.
        id: u8,
        /// From when, microseconds.
        at_us: u64,
    },
}

/// The emulated bus's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct DxlConfig {
    /// How each joint sits on its servo (the robot's true mounting); joints not listed have no
    /// servo on this bus.
    pub map: Vec<JointMapEntry>,
    /// Line speed, for the timing of answers.
    pub baud: u32,
    /// Bits on the line per byte: 10 for 8N1.
    pub bits_per_byte: u32,
    /// Return Delay Time at power-up, units of 2 us (factory 250: 500 us).
    pub return_delay: u8,
    /// Faults to inject.
    pub faults: Vec<DxlFault>,
}

impl Default for DxlConfig {
    fn default() -> Self {
        DxlConfig {
            map: msr_shared::dynamixel::map::default_map().to_vec(),
            baud: 1_000_000,
            bits_per_byte: 10,
            return_delay: table::DEFAULT_RETURN_DELAY,
            faults: Vec::new(),
        }
    }
}

/// What the emulated bus has counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DxlCounters {
    /// Instruction packets addressed to at least one servo here (or broadcast).
    pub instructions: u32,
    /// Status packets sent.
    pub statuses: u32,
    /// Goal Positions accepted.
    pub goals: u32,
    /// Goal Positions refused or outside the joint's limits.
    pub limit_violations: u32,
    /// Packets the servos answered with an error number.
    pub refused: u32,
    /// Status packets seen on the bus (another device's answer, or an echo).
    pub foreign_statuses: u32,
}

/// One servo's registers (its motion lives in the bus's [`Servo`]).
#[derive(Clone, Debug)]
struct Regs {
    map: JointMapEntry,
    return_delay: u8,
    status_return_level: u8,
    min_limit: i32,
    max_limit: i32,
    torque: bool,
    led: u8,
    hw_error: u8,
    goal: i32,
    silent: bool,
    /// Since when the joint has been pushed against a mechanical stop with torque on.
    stalled_since: Option<u64>,
}

/// The Protocol 2.0 side of an emulated bus: registers, parsing, answers and their timing.
pub struct DxlBus {
    cfg: DxlConfig,
    regs: Vec<Regs>,
    rx: Receiver<1024>,
    counters: DxlCounters,
    byte_us: f64,
    /// Answers due: (start time in us, bytes).
    out: Vec<(u64, Vec<u8>)>,
}

/// A control-table image's size: everything up to Present Position.
const TABLE_LEN: usize = 136;

impl DxlBus {
    /// Servos for the map's joints, all with torque on (the robot already holds its posture).
    pub fn new(cfg: DxlConfig) -> Result<DxlBus, String> {
        msr_shared::dynamixel::map::check_map(&cfg.map).map_err(|e| format!("servo map: {e:?}"))?;
        if cfg.baud == 0 || cfg.bits_per_byte == 0 {
            return Err("baud and bits per byte must be positive".into());
        }
        let regs = cfg
            .map
            .iter()
            .map(|m| Regs {
                map: *m,
                return_delay: cfg.return_delay,
                status_return_level: 2,
                // As the board writes them at start-up: the joint's range.
                min_limit: m.raw_min,
                max_limit: m.raw_max,
                torque: true,
                led: 0,
                hw_error: 0,
                goal: m.zero,
                silent: false,
                stalled_since: None,
            })
            .collect();
        let byte_us = cfg.bits_per_byte as f64 * 1e6 / cfg.baud as f64;
        Ok(DxlBus { cfg, regs, rx: Receiver::new(), counters: DxlCounters::default(), byte_us, out: Vec::new() })
    }

    /// What the bus has counted so far.
    pub fn counters(&self) -> DxlCounters {
        self.counters
    }

    /// What the servos' receiver threw away (CRC errors, noise...).
    pub fn rx_counters(&self) -> RxCounters {
        *self.rx.counters()
    }

    /// The ID of a joint's servo.
    pub fn id_of(&self, j: Joint) -> Option<u8> {
        self.regs.iter().find(|r| r.map.joint == j).map(|r| r.map.id)
    }

    /// Hardware Error Status of a joint's servo.
    pub fn hardware_error(&self, j: Joint) -> Option<u8> {
        self.regs.iter().find(|r| r.map.joint == j).map(|r| r.hw_error)
    }

    /// Min/Max Position Limit as the servo holds them.
    pub fn position_limits(&self, j: Joint) -> Option<(i32, i32)> {
        self.regs.iter().find(|r| r.map.joint == j).map(|r| (r.min_limit, r.max_limit))
    }

    /// Whether a joint's servo has torque on.
    pub fn torque(&self, j: Joint) -> Option<bool> {
        self.regs.iter().find(|r| r.map.joint == j).map(|r| r.torque)
    }

    /// Applies the faults due by `now_us`, the overload of a joint stalled at a stop, and the
    /// torque state to the dynamics.
    pub fn faults_at(&mut self, now_us: u64, servos: &mut [Servo]) {
        for r in &mut self.regs {
            let s = servos.iter().find(|s| s.joint == r.map.joint);
            if r.torque && s.is_some_and(|s| pushed_against_stop(r, s)) {
                let since = *r.stalled_since.get_or_insert(now_us);
                if now_us - since >= STALL_OVERLOAD_US {
                    r.hw_error |= table::hw::OVERLOAD;
                    r.torque = false;
                }
            } else {
                r.stalled_since = None;
            }
        }
        for f in &self.cfg.faults {
            match *f {
                DxlFault::Silent { id, at_us } if now_us >= at_us => {
                    if let Some(r) = self.regs.iter_mut().find(|r| r.map.id == id) {
                        r.silent = true;
                    }
                }
                DxlFault::Overload { id, at_us } if now_us >= at_us => {
                    if let Some(r) = self.regs.iter_mut().find(|r| r.map.id == id) {
                        if r.hw_error & table::hw::OVERLOAD == 0 {
                            r.hw_error |= table::hw::OVERLOAD;
                            r.torque = false;
                        }
                    }
                }
                _ => {}
            }
        }
        for r in &self.regs {
            if let Some(s) = servos.iter_mut().find(|s| s.joint == r.map.joint) {
                s.stiff = r.torque;
            }
        }
    }

    /// Feeds bytes with their arrival times (us); answers are queued for [`DxlBus::take_answers`].
    pub fn receive(&mut self, bytes: &[(u64, u8)], servos: &mut [Servo]) {
        for &(t, b) in bytes {
            self.rx.push(b);
            // Parse into an owned copy so that answering can change the registers.
            while let Some((id, instruction, params)) =
                self.rx.next_packet().map(|p| (p.id, p.instruction, p.params.to_vec()))
            {
                let p = dxl::Packet { id, instruction, params: &params };
                self.on_packet(t, &p, servos);
            }
        }
    }

    /// Answers whose time has come by `now_us` is not required: the caller sends each at its
    /// start time (or now, if later), and the line keeps them in order.
    pub fn take_answers(&mut self) -> Vec<(u64, Vec<u8>)> {
        std::mem::take(&mut self.out)
    }

    fn answer_at(&self, i: usize, after_us: f64) -> f64 {
        after_us + self.regs[i].return_delay as f64 * table::RETURN_DELAY_UNIT_US as f64
    }

    fn queue(&mut self, at_us: f64, bytes: Vec<u8>) -> f64 {
        let end = at_us + bytes.len() as f64 * self.byte_us;
        self.out.push((at_us.ceil() as u64, bytes));
        self.counters.statuses += 1;
        end
    }

    fn on_packet(&mut self, t_us: u64, p: &dxl::Packet, servos: &mut [Servo]) {
        let t = t_us as f64;
        let ins = Instruction::of(p);
        if ins == Instruction::Status {
            self.counters.foreign_statuses += 1;
            return;
        }
        let target = self.regs.iter().position(|r| r.map.id == p.id);
        if target.is_none() && p.id != dxl::BROADCAST {
            return; // Another device's.
        }
        self.counters.instructions += 1;
        match (ins, target) {
            (Instruction::Ping, Some(i)) => {
                let st = self.ping_status(i);
                let at = self.answer_at(i, t);
                self.reply(i, at, st.0, &st.1);
            }
            (Instruction::Ping, None) => {
                let mut at = t;
                for i in 0..self.regs.len() {
                    if self.regs[i].silent {
                        break;
                    }
                    let st = self.ping_status(i);
                    let start = self.answer_at(i, at);
                    at = self.reply(i, start, st.0, &st.1);
                }
            }
            (Instruction::Read { addr, len }, Some(i)) => {
                let (err, data) = self.read(i, addr, len, servos);
                if self.regs[i].status_return_level >= 1 {
                    let at = self.answer_at(i, t);
                    self.reply(i, at, err, &data);
                }
            }
            (Instruction::Write { addr, data }, Some(i)) => {
                let err = self.write(i, addr, data, servos);
                if self.regs[i].status_return_level >= 2 {
                    let at = self.answer_at(i, t);
                    self.reply(i, at, err, &[]);
                }
            }
            (Instruction::Write { addr, data }, None) => {
                for i in 0..self.regs.len() {
                    self.write(i, addr, data, servos);
                }
            }
            (Instruction::SyncRead { addr, len, ids }, None) => {
                let mut at = t;
                for &id in ids {
                    let Some(i) = self.regs.iter().position(|r| r.map.id == id) else { break };
                    if self.regs[i].silent {
                        break;
                    }
                    let (err, data) = self.read(i, addr, len, servos);
                    let start = self.answer_at(i, at);
                    at = self.reply(i, start, err, &data);
                }
            }
            (Instruction::SyncWrite { addr, .. }, None) => {
                let entries: Vec<(u8, Vec<u8>)> = ins.sync_entries().map(|(id, d)| (id, d.to_vec())).collect();
                for (id, data) in entries {
                    if let Some(i) = self.regs.iter().position(|r| r.map.id == id) {
                        self.write(i, addr, &data, servos);
                    }
                }
            }
            (_, Some(i)) => {
                let at = self.answer_at(i, t);
                self.reply(i, at, error::INSTRUCTION, &[]);
            }
            _ => {}
        }
    }

    /// Queues a status from servo `i`; returns when it ends on the line. A silent servo sends
    /// nothing (and the time does not move).
    fn reply(&mut self, i: usize, at_us: f64, err: u8, params: &[u8]) -> f64 {
        let r = &self.regs[i];
        if r.silent {
            return at_us;
        }
        if err & !error::ALERT != 0 {
            self.counters.refused += 1;
        }
        let err = if r.hw_error != 0 { err | error::ALERT } else { err };
        let mut buf = vec![0u8; 2 * params.len() + 16];
        let n = dxl::status(r.map.id, err, params, &mut buf).expect("a status fits twice its size");
        buf.truncate(n);
        self.queue(at_us, buf)
    }

    fn ping_status(&self, _i: usize) -> (u8, Vec<u8>) {
        let m = table::XM430_W350.to_le_bytes();
        (0, vec![m[0], m[1], FIRMWARE])
    }

    /// The control table now, as bytes.
    fn image(&self, i: usize, servos: &[Servo]) -> [u8; TABLE_LEN] {
        let r = &self.regs[i];
        let s = servos.iter().find(|s| s.joint == r.map.joint);
        let mut t = [0u8; TABLE_LEN];
        let mut put = |it: Item, v: u32| {
            let a = it.addr as usize;
            t[a..a + it.len as usize].copy_from_slice(&v.to_le_bytes()[..it.len as usize]);
        };
        put(table::MODEL_NUMBER, table::XM430_W350 as u32);
        put(table::FIRMWARE_VERSION, FIRMWARE as u32);
        put(table::ID, r.map.id as u32);
        put(table::BAUD_RATE, 3); // 1 Mbps
        put(table::RETURN_DELAY_TIME, r.return_delay as u32);
        put(table::OPERATING_MODE, 3); // position control
        put(table::MAX_POSITION_LIMIT, r.max_limit as u32);
        put(table::MIN_POSITION_LIMIT, r.min_limit as u32);
        put(table::TORQUE_ENABLE, r.torque as u32);
        put(table::LED, r.led as u32);
        put(table::STATUS_RETURN_LEVEL, r.status_return_level as u32);
        put(table::HARDWARE_ERROR_STATUS, r.hw_error as u32);
        put(table::GOAL_POSITION, r.goal as u32);
        if let Some(s) = s {
            let raw = |a: f64| (r.map.zero as f64 + sign(&r.map) * a * r.map.counts_per_rad as f64).round() as i32;
            put(table::MOVING, ((raw(s.target) - raw(s.position)).abs() > MOVING_THRESHOLD) as u32);
            // Present Velocity in units of 0.229 rev/min.
            let v = sign(&r.map) * s.velocity / (0.229 * std::f64::consts::TAU / 60.0);
            put(table::PRESENT_VELOCITY, v.round() as i32 as u32);
            put(table::PRESENT_POSITION, raw(s.position + s.noise * COUNT_RAD) as u32);
        }
        t
    }

    fn read(&self, i: usize, addr: u16, len: u16, servos: &[Servo]) -> (u8, Vec<u8>) {
        let (a, n) = (addr as usize, len as usize);
        if n == 0 || a + n > TABLE_LEN {
            return (error::ACCESS, Vec::new());
        }
        (0, self.image(i, servos)[a..a + n].to_vec())
    }

    /// Writes whole items starting at `addr`; all or nothing. Returns the error number.
    fn write(&mut self, i: usize, addr: u16, data: &[u8], servos: &mut [Servo]) -> u8 {
        // Check every item first.
        let mut items = Vec::new();
        let mut a = addr;
        let mut rest = data;
        while !rest.is_empty() {
            let Some(it) = WRITABLE.iter().find(|it| it.addr == a) else {
                return error::ACCESS;
            };
            if rest.len() < it.len as usize {
                return error::DATA_LENGTH;
            }
            let mut v = [0u8; 4];
            v[..it.len as usize].copy_from_slice(&rest[..it.len as usize]);
            items.push((*it, i32::from_le_bytes(v)));
            rest = &rest[it.len as usize..];
            a += it.len;
        }
        let r = &self.regs[i];
        for &(it, v) in &items {
            let eeprom = it.addr < table::TORQUE_ENABLE.addr;
            if eeprom && r.torque {
                return error::ACCESS;
            }
            let max_raw = table::COUNTS_PER_TURN as i32 - 1;
            let ok = match it {
                table::MIN_POSITION_LIMIT | table::MAX_POSITION_LIMIT => (0..=max_raw).contains(&v),
                table::TORQUE_ENABLE => v <= 1,
                table::STATUS_RETURN_LEVEL => v <= 2,
                table::GOAL_POSITION => {
                    let ok = v >= r.min_limit && v <= r.max_limit;
                    let rad = r.map.to_rad(v);
                    let inside = r.map.joint.validate(rad).is_ok();
                    if !ok || !inside {
                        self.counters.limit_violations += 1;
                    }
                    if !ok {
                        return error::DATA_LIMIT;
                    }
                    true
                }
                _ => true,
            };
            if !ok {
                return error::DATA_RANGE;
            }
        }
        let r = &mut self.regs[i];
        let s = servos.iter_mut().find(|s| s.joint == r.map.joint);
        let mut s = s;
        for (it, v) in items {
            match it {
                table::RETURN_DELAY_TIME => r.return_delay = v as u8,
                table::MIN_POSITION_LIMIT => r.min_limit = v,
                table::MAX_POSITION_LIMIT => r.max_limit = v,
                table::STATUS_RETURN_LEVEL => r.status_return_level = v as u8,
                table::LED => r.led = v as u8,
                table::TORQUE_ENABLE => {
                    // An overload keeps the torque off until a reboot.
                    let on = v == 1 && r.hw_error == 0;
                    if on && !r.torque {
                        if let Some(s) = s.as_deref_mut() {
                            s.target = s.position;
                            r.goal = (r.map.zero as f64
                                + sign(&r.map) * s.position * r.map.counts_per_rad as f64)
                                .round() as i32;
                        }
                    }
                    r.torque = on;
                    if let Some(s) = s.as_deref_mut() {
                        s.stiff = on;
                    }
                }
                table::GOAL_POSITION => {
                    r.goal = v;
                    self.counters.goals += 1;
                    if let Some(s) = s.as_deref_mut() {
                        s.set_target(r.map.to_rad(v) as f64);
                    }
                }
                _ => {}
            }
        }
        0
    }
}

/// How long a joint may be held against a mechanical stop before the servo raises Overload.
/// The e-Manual says only "persistent load that exceeds maximum output" (Hardware Error Status
/// bit 5); 1 s at stall torque is our assumption for an X-series servo, not a ROBOTIS figure.
pub const STALL_OVERLOAD_US: u64 = 1_000_000;

/// The goal lies beyond a joint limit (the mechanical stop) and the joint sits at that stop.
fn pushed_against_stop(r: &Regs, s: &Servo) -> bool {
    let Some(l) = r.map.joint.limits() else { return false };
    let (goal, at) = (r.map.to_rad(r.goal) as f64, s.position);
    let count = 1.0 / r.map.counts_per_rad as f64;
    (goal > l.max as f64 + count && at >= l.max as f64 - count) || (goal < l.min as f64 - count && at <= l.min as f64 + count)
}

const FIRMWARE: u8 = 46;
/// Moving is 1 while the goal is more than this many counts away.
const MOVING_THRESHOLD: i32 = 10;
/// The items a master may write here.
const WRITABLE: [Item; 7] = [
    table::RETURN_DELAY_TIME,
    table::MAX_POSITION_LIMIT,
    table::MIN_POSITION_LIMIT,
    table::TORQUE_ENABLE,
    table::LED,
    table::STATUS_RETURN_LEVEL,
    table::GOAL_POSITION,
];

fn sign(m: &JointMapEntry) -> f64 {
    if m.forward {
        1.0
    } else {
        -1.0
    }
}

/// A status's value, for tests and tools: `(id, error, params)`.
pub fn parse_status(bytes: &[u8]) -> Vec<(u8, u8, Vec<u8>)> {
    let mut rx = Receiver::<1024>::new();
    let mut out = Vec::new();
    for &b in bytes {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            if let Some(s) = Status::of(&p) {
                out.push((s.id, s.error, s.params.to_vec()));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests;
