use super::*;
use embedded_io::ErrorType;
use msr_shared::dynamixel::{Instruction, Packet};
use std::collections::VecDeque;

/// A test bus: records what the master writes and answers as scripted servos would.
struct Bus {
    written: Vec<u8>,
    to_master: VecDeque<u8>,
    rx: Receiver<256>,
    servos: Vec<Fake>,
    /// Flip this bit of the next status (bit index in the packet).
    damage: Option<usize>,
}

#[derive(Clone)]
struct Fake {
    id: u8,
    raw: i32,
    limits: (i32, i32),
    torque: bool,
    alive: bool,
    hw: u8,
    locked: bool,
    goals: Vec<i32>,
}

impl Bus {
    fn new() -> Bus {
        let servos = default_map()
            .iter()
            .map(|e| Fake { id: e.id, raw: e.zero, limits: (0, 4095), torque: true, alive: true, hw: 0, locked: false, goals: vec![] })
            .collect();
        Bus { written: vec![], to_master: VecDeque::new(), rx: Receiver::new(), servos, damage: None }
    }

    fn servo(&mut self, id: u8) -> &mut Fake {
        self.servos.iter_mut().find(|s| s.id == id).unwrap()
    }

    fn status(&mut self, id: u8, err: u8, params: &[u8]) {
        let f = self.servos.iter().find(|s| s.id == id).unwrap();
        if !f.alive {
            return;
        }
        let err = if f.hw != 0 { err | error::ALERT } else { err };
        let mut b = [0u8; 64];
        let n = dxl::status(id, err, params, &mut b).unwrap();
        if let Some(bit) = self.damage.take() {
            b[bit / 8 % n] ^= 1 << (bit % 8);
        }
        self.to_master.extend(&b[..n]);
    }

    fn on_packet(&mut self, p: Packet) {
        let id = p.id;
        match Instruction::of(&p) {
            Instruction::Ping => self.status(id, 0, &[0xFC, 0x03, 46]),
            Instruction::Write { addr, data } => {
                let s = self.servo(id);
                let err = match addr {
                    64 => {
                        s.torque = data[0] == 1;
                        0
                    }
                    48 if s.locked => 0,
                    48 if !s.torque => {
                        let v = |k: usize| i32::from_le_bytes(data[k..k + 4].try_into().unwrap());
                        s.limits = (v(4), v(0));
                        0
                    }
                    _ => error::ACCESS,
                };
                self.status(id, err, &[]);
            }
            Instruction::Read { addr: 48, len: 8 } => {
                let (min, max) = self.servo(id).limits;
                let v = [max.to_le_bytes(), min.to_le_bytes()].concat();
                self.status(id, 0, &v);
            }
            Instruction::Read { addr: 70, len: 1 } => {
                let h = self.servo(id).hw;
                self.status(id, 0, &[h]);
            }
            Instruction::SyncRead { addr: 132, len: 4, ids } => {
                for &i in ids {
                    if !self.servo(i).alive {
                        break; // the ones after a silent servo wait for it forever
                    }
                    let r = self.servo(i).raw;
                    self.status(i, 0, &r.to_le_bytes());
                }
            }
            Instruction::SyncWrite { .. } => {
                let ins = Instruction::of(&p);
                for (i, d) in ins.sync_entries() {
                    let v = i32::from_le_bytes(d.try_into().unwrap());
                    let s = self.servo(i);
                    s.goals.push(v);
                    s.raw = v;
                }
            }
            other => panic!("unexpected {other:?}"),
        }
    }
}

impl ErrorType for Bus {
    type Error = embedded_io::ErrorKind;
}
impl Read for Bus {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.to_master.len());
        for b in buf.iter_mut().take(n) {
            *b = self.to_master.pop_front().unwrap();
        }
        Ok(n)
    }
}
impl ReadReady for Bus {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.to_master.is_empty())
    }
}
impl Write for Bus {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.written.extend_from_slice(buf);
        for &b in buf {
            self.rx.push(b);
            while let Some((id, ins, params)) = self.rx.next_packet().map(|p| (p.id, p.instruction, p.params.to_vec())) {
                self.on_packet(Packet { id, instruction: ins, params: &params });
            }
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Polls every millisecond (as the board in the sim) from `from_us` for `ms`, with a control
/// period every 10 ms; returns the events and the last complete positions.
fn run(m: &mut Master, bus: &mut Bus, from_us: u64, ms: u64, targets: Option<[Option<f32>; 5]>) -> (Vec<BusEvent>, Vec<[Option<f32>; 5]>) {
    let mut events = vec![];
    let mut complete = vec![];
    for k in 0..ms {
        let now = from_us + k * 1000;
        if now.is_multiple_of(10_000) {
            m.period(now, bus, targets);
        }
        let p = m.poll(now, bus);
        if p.complete {
            complete.push(p.positions);
        }
        while let Some(e) = m.event() {
            events.push(e);
        }
    }
    (events, complete)
}

#[test]
fn start_up_pings_first_with_the_manual_bytes_then_sets_limits_and_torque() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    m.poll(0, &mut bus);
    // e-Manual, Ping example 1 (ID 1 is HeadYaw's servo).
    assert_eq!(bus.written, [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E]);
    let (events, _) = run(&mut m, &mut bus, 1_000, 200, None);
    assert_eq!(events, vec![BusEvent::Ready]);
    assert_eq!(m.stage(), Stage::Running);
    for (f, e) in bus.servos.iter().zip(default_map()) {
        assert_eq!(f.limits, (e.raw_min, e.raw_max));
        assert!(f.torque);
    }
    // One transaction at a time: 5 servos x (ping, torque off, limits, read back, torque on).
    let mut rx = Receiver::<256>::new();
    let mut kinds = vec![];
    for &b in &bus.written {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            if p.instruction != inst::SYNC_READ && p.instruction != inst::SYNC_WRITE {
                kinds.push(p.instruction);
            }
        }
    }
    assert_eq!(kinds.len(), 25);
    assert_eq!(&kinds[..5], &[inst::PING; 5]);
    assert_eq!(&kinds[5..9], &[inst::WRITE, inst::WRITE, inst::READ, inst::WRITE]);
}

use msr_shared::dynamixel::inst;

#[test]
fn a_missing_servo_is_reported_by_id_and_nothing_moves() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    bus.servo(4).alive = false;
    let (events, complete) = run(&mut m, &mut bus, 0, 2_500, Some([Some(0.1); 5]));
    assert_eq!(events.iter().filter(|e| **e == BusEvent::Missing { id: 4 }).count(), 3, "{events:?}");
    assert!(complete.is_empty());
    assert!(bus.servos.iter().all(|s| s.goals.is_empty()));
    assert!(bus.servos.iter().all(|s| s.limits == (0, 4095)), "nothing was written");
    assert!(matches!(m.stage(), Stage::Failed { .. }));
    assert!(m.stats()[3].timeouts >= 3);
}

#[test]
fn limits_that_do_not_read_back_stop_the_start_up() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    // Servo 2 acknowledges the limit write but keeps its old limits.
    bus.servo(2).locked = true;
    let (events, _) = run(&mut m, &mut bus, 0, 50, None);
    assert_eq!(events, vec![BusEvent::StartFailed { id: 2, error: 0 }]);
    assert!(matches!(m.stage(), Stage::Failed { .. }));
}

#[test]
fn every_period_writes_goals_and_reads_positions() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    run(&mut m, &mut bus, 0, 200, None);
    bus.written.clear();
    let targets = [Some(0.1), Some(-0.2), Some(1.0), Some(0.2), Some(-0.5)];
    let (_, complete) = run(&mut m, &mut bus, 200_000, 100, Some(targets));
    assert_eq!(complete.len(), 10);
    for (e, t) in default_map().iter().zip(targets) {
        let f = bus.servos.iter().find(|f| f.id == e.id).unwrap();
        assert_eq!(f.goals.len(), 10);
        assert_eq!(f.goals[0], e.to_raw(t.unwrap()).unwrap());
    }
    let last = complete.last().unwrap();
    for (e, (p, t)) in default_map().iter().zip(last.iter().zip(targets)) {
        assert!((p.unwrap() - t.unwrap()).abs() <= 1.0 / e.counts_per_rad, "{p:?} {t:?}");
    }
    // A target outside the joint's limits is refused before conversion, the others go.
    let bad = [Some(9.0), None, Some(1.0), Some(0.2), Some(-0.5)];
    run(&mut m, &mut bus, 300_000, 10, Some(bad));
    assert_eq!(m.refused_targets, 1);
}

#[test]
fn a_servo_that_stops_answering_is_reported_and_goes_last() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    run(&mut m, &mut bus, 0, 200, None);
    bus.servo(2).alive = false;
    let (events, complete) = run(&mut m, &mut bus, 200_000, 100, Some([Some(0.0); 5]));
    assert_eq!(events, vec![BusEvent::Lost { id: 2 }]);
    assert!(complete.is_empty(), "no period has every position");
    // After the first miss, ID 2 is asked last, so the others keep answering.
    bus.written.clear();
    let mut got = [0u32; 5];
    for k in 0..10u64 {
        let now = 300_000 + k * 1000;
        if k == 0 {
            m.period(now, &mut bus, None);
        }
        let p = m.poll(now, &mut bus);
        for (g, q) in got.iter_mut().zip(p.positions) {
            *g += q.is_some() as u32;
        }
    }
    assert_eq!(got, [1, 0, 1, 1, 1]);
    let mut rx = Receiver::<256>::new();
    for &b in &bus.written {
        rx.push(b);
        while let Some(p) = rx.next_packet() {
            if let Instruction::SyncRead { ids, .. } = Instruction::of(&p) {
                assert_eq!(ids, &[1, 3, 4, 6, 2]);
            }
        }
    }
}

#[test]
fn an_alert_is_read_out_and_reported_once() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    run(&mut m, &mut bus, 0, 200, None);
    assert!(!m.faulted());
    bus.servo(6).hw = table::hw::OVERLOAD;
    let (events, _) = run(&mut m, &mut bus, 200_000, 100, None);
    assert_eq!(events, vec![BusEvent::Alert { id: 6, hardware: table::hw::OVERLOAD }]);
    assert!(m.faulted());
    assert!(m.stats()[4].alerts >= 9);
}

#[test]
fn a_damaged_status_never_gives_a_position() {
    let mut m = Master::new();
    let mut bus = Bus::new();
    run(&mut m, &mut bus, 0, 200, None);
    let mut t = 200_000;
    // One bit of the first status of a period, each bit in turn; a new position each time.
    for bit in 0..15 * 8 {
        let raw = 1900 + bit as i32;
        bus.servo(1).raw = raw;
        bus.damage = Some(bit);
        m.period(t, &mut bus, None);
        let mut seen = None;
        for k in 0..10 {
            let p = m.poll(t + k * 1000, &mut bus);
            if let Some(a) = p.positions[0] {
                seen = Some(a);
            }
        }
        if let Some(a) = seen {
            assert_eq!(a, default_map()[0].to_rad(raw), "bit {bit}");
        }
        t += 10_000;
    }
}

#[test]
fn a_period_fits_10_ms_at_1_mbaud_and_needs_30_ms_at_57600() {
    let fast = BusTiming::DEFAULT;
    // 39 + 19 bytes out, 5 x (500 us delay + 15 bytes) back.
    assert_eq!(fast.period_us(5), 580 + 5 * (500 + 150));
    assert!(fast.period_us(5) + REPLY_SLACK_US < 10_000);
    let slow = BusTiming { baud: 57_600, ..fast };
    let need = slow.period_us(5);
    assert!(need > 20_000 && need < 30_000, "{need}");
}

#[test]
fn maps_that_let_targets_out_are_refused() {
    let mut map = default_map();
    map[2].raw_max += 50;
    assert!(matches!(Master::with(map, BusTiming::DEFAULT), Err(MapError::LeavesLimits { .. })));
    let mut map = default_map();
    map.swap(0, 1);
    assert!(matches!(Master::with(map, BusTiming::DEFAULT), Err(MapError::BadJoint { .. })));
}
