//! The `dynamixel2` crate, an implementation of Protocol 2.0 that is not ours, against ours:
//! - as master of the emulated servos over a PTY (ping, read, write, sync read, sync write);
//! - writing, for the same instructions, the same bytes as the firmware's bus master.
use msr_firmware::dynamixel::{Master, Stage};
use msr_shared::dynamixel::map::default_map;
use msr_sim::servo::serve::{serve, servos};
use msr_sim::dynamixel::{DxlConfig, STALL_OVERLOAD_US};
use msr_sim::pty::Pty;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

#[test]
fn dynamixel2_drives_the_emulated_servos_over_a_pty() {
    let mut pty = Pty::open().unwrap();
    let path = pty.path().to_string();
    let stop = AtomicBool::new(false);
    let ids: Vec<u8> = default_map().iter().map(|e| e.id).collect();
    std::thread::scope(|s| {
        let server = s.spawn(|| {
            let mut bus = servos(DxlConfig::default()).unwrap();
            let served = serve(&mut bus, pty.master(), &stop, None);
            (served, bus)
        });
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| -> usize {
            let mut d = dynamixel2::Bus::open(&path, 1_000_000).unwrap();
            // Every instruction the servos must refuse or count as a limit violation, however
            // often it was sent.
            let mut refused_sends = 0;
            let p = patient(|| d.ping(1)).unwrap();
            assert_eq!((p.motor_id, p.alert, p.data.model), (1, false, 1020));
            assert!(d.ping(99).is_err(), "no servo 99");
            // Home: HeadYaw at 0 rad is the centre count.
            assert_eq!(patient(|| d.read_u32(1, 132)).unwrap().data, 2048);
            assert_eq!(patient(|| d.read_u16(1, 0)).unwrap().data, 1020);
            // A configured robot's servos: Min/Max Position Limit hold each joint's range from
            // power-on (what the board writes at start-up), not the factory 0 and 4095, and a
            // goal outside them is refused with Data Limit Error (error number 6).
            for e in default_map() {
                assert_eq!(patient(|| d.read_u32(e.id, 48)).unwrap().data, e.raw_max as u32, "{:?}", e.joint);
                assert_eq!(patient(|| d.read_u32(e.id, 52)).unwrap().data, e.raw_min as u32, "{:?}", e.joint);
            }
            let yaw = default_map()[0];
            assert_eq!(motor_error(counted(&mut refused_sends, || d.write_u32(1, 116, yaw.raw_max as u32 + 1))), Some(6));
            assert_eq!(motor_error(counted(&mut refused_sends, || d.write_u32(1, 116, yaw.raw_min as u32 - 1))), Some(6));
            // Torque off, limits, read back, torque on, goal.
            patient(|| d.write_u8(1, 64, 0)).unwrap();
            patient(|| d.write_u32(1, 48, 2300)).unwrap();
            patient(|| d.write_u32(1, 52, 1800)).unwrap();
            assert_eq!(patient(|| d.read_u32(1, 48)).unwrap().data, 2300);
            assert_eq!(patient(|| d.read_u32(1, 52)).unwrap().data, 1800);
            patient(|| d.write_u8(1, 64, 1)).unwrap();
            // A goal outside the limits: the servo refuses it (Data Limit Error, 0x06).
            assert_eq!(motor_error(counted(&mut refused_sends, || d.write_u32(1, 116, 2400))), Some(6));
            patient(|| d.write_u32(1, 116, 2200)).unwrap();
            std::thread::sleep(Duration::from_millis(300));
            let r = patient(|| d.sync_read_u32(&ids, 132)).unwrap();
            assert_eq!(r.iter().map(|r| r.motor_id).collect::<Vec<_>>(), ids);
            let yaw = r[0].data;
            assert!(yaw.abs_diff(2200) <= 2, "{yaw}");
            // Sync Write moves another joint.
            let goal = default_map()[2].to_raw(1.0).unwrap() as u32;
            d.sync_write_u32(116, [dynamixel2::instructions::SyncWriteData { motor_id: 3, data: goal }])
                .unwrap();
            std::thread::sleep(Duration::from_millis(600));
            let p = patient(|| d.read_u32(3, 132)).unwrap().data;
            assert!(p.abs_diff(goal) <= 2, "{p} vs {goal}");
            // Limits widened past the mechanical stop: a goal beyond it stalls the joint there,
            // and after STALL_OVERLOAD_US the servo raises Overload (Hardware Error Status bit
            // 5) with the Alert bit, and drops its torque.
            let roll = default_map()[3];
            patient(|| d.write_u8(roll.id, 64, 0)).unwrap();
            patient(|| d.write_u32(roll.id, 48, 4095)).unwrap();
            patient(|| d.write_u8(roll.id, 64, 1)).unwrap();
            counted(&mut refused_sends, || d.write_u32(roll.id, 116, roll.raw_max as u32 + 300)).unwrap();
            std::thread::sleep(Duration::from_millis(300));
            let r = patient(|| d.read_u8(roll.id, 70)).unwrap();
            assert_eq!((r.data, r.alert), (0, false), "not yet");
            let stop = patient(|| d.read_u32(roll.id, 132)).unwrap().data;
            assert!(stop.abs_diff(roll.raw_max as u32) <= 1, "at the stop: {stop} vs {}", roll.raw_max);
            std::thread::sleep(Duration::from_micros(STALL_OVERLOAD_US));
            let r = patient(|| d.read_u8(roll.id, 70)).unwrap();
            assert_eq!((r.data, r.alert), (0x20, true), "Overload and Alert");
            assert_eq!(patient(|| d.read_u8(roll.id, 64)).unwrap().data, 0, "torque off");
            refused_sends
        }));
        stop.store(true, Ordering::Relaxed);
        let (served, bus) = server.join().unwrap();
        assert!(served.unwrap().bytes_out > 0);
        let refused_sends = result.unwrap_or_else(|e| std::panic::resume_unwind(e));
        // The three refused goals and the one beyond the stop, each counted as often as it was
        // sent.
        assert!(refused_sends >= 4);
        assert_eq!(bus.dynamixel().unwrap().counters().limit_violations as usize, refused_sends);
    });
}

/// `f` again while its answer timed out. The emulated servos answer from a thread in real time,
/// and on a loaded machine that thread can wake later than the 34 ms `dynamixel2` waits (as
/// the official SDK does); a master on a real bus retries a lost status the same way. Each try
/// is a new instruction: `dynamixel2` drops whatever came late before it writes.
fn patient<T>(mut f: impl FnMut() -> Result<T, dynamixel2::TransferError>) -> Result<T, dynamixel2::TransferError> {
    counted(&mut 0, &mut f)
}

/// [`patient`], adding every instruction sent to `sends`.
fn counted<T>(sends: &mut usize, mut f: impl FnMut() -> Result<T, dynamixel2::TransferError>) -> Result<T, dynamixel2::TransferError> {
    const TRIES: usize = 100;
    for _ in 1..TRIES {
        *sends += 1;
        match f() {
            Err(dynamixel2::TransferError::ReadError(dynamixel2::ReadError::Io(e)))
                if e.kind() == std::io::ErrorKind::TimedOut => {}
            r => return r,
        }
    }
    *sends += 1;
    f()
}

/// The error number of a status that refused the instruction (`None`: it was accepted).
fn motor_error<T>(r: Result<T, dynamixel2::TransferError>) -> Option<u8> {
    match r {
        Ok(_) => None,
        Err(dynamixel2::TransferError::ReadError(dynamixel2::ReadError::MotorError(e))) => Some(e.error_number()),
        Err(e) => panic!("not a status with an error number: {e:?}"),
    }
}

/// What `dynamixel2` writes for `f`, `packets` instruction packets, read off the PTY (answers,
/// if it waits for any, time out). The kernel hands a PTY's bytes over on a work queue of its
/// own, late on a loaded machine, so this reads until the packets are whole.
fn dynamixel2_bytes(packets: usize, f: impl FnOnce(&mut dynamixel2::Bus<Vec<u8>, Vec<u8>>)) -> Vec<u8> {
    let mut pty = Pty::open().unwrap();
    let mut d = dynamixel2::Bus::open(pty.path(), 1_000_000).unwrap();
    f(&mut d);
    let mut got = Vec::new();
    while whole_packets(&got) < packets {
        got.extend(pty.read_available().unwrap());
        std::thread::sleep(Duration::from_millis(1));
    }
    got
}

/// How many whole Protocol 2.0 packets `bytes` starts with (header FF FF FD 00, ID, a
/// little-endian length of what follows it).
fn whole_packets(bytes: &[u8]) -> usize {
    let (mut at, mut n) = (0, 0);
    while bytes.len() >= at + 7 {
        let len = u16::from_le_bytes([bytes[at + 5], bytes[at + 6]]) as usize;
        if bytes.len() < at + 7 + len {
            break;
        }
        at += 7 + len;
        n += 1;
    }
    n
}

/// A line between the firmware's master and the emulated servos: what the master writes is
/// recorded and reaches the servos 1 ms later, their answers come back on the next poll.
struct Line {
    to_servos: Vec<u8>,
    to_master: std::collections::VecDeque<u8>,
    written: Vec<u8>,
}

impl embedded_io::ErrorType for Line {
    type Error = embedded_io::ErrorKind;
}
impl embedded_io::Read for Line {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.to_master.len());
        for b in buf.iter_mut().take(n) {
            *b = self.to_master.pop_front().unwrap();
        }
        Ok(n)
    }
}
impl embedded_io::ReadReady for Line {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.to_master.is_empty())
    }
}
impl embedded_io::Write for Line {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.to_servos.extend_from_slice(buf);
        self.written.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[test]
fn the_firmware_writes_what_dynamixel2_writes() {
    // The firmware's master starts the emulated servos up, then runs one control period.
    let mut bus = servos(DxlConfig::default()).unwrap();
    let mut m = Master::new();
    let mut line = Line { to_servos: vec![], to_master: Default::default(), written: vec![] };
    let mut now = 0u64;
    while m.stage() != Stage::Running && now < 1_000_000 {
        m.poll(now, &mut line);
        now += 1000;
        let timed: Vec<(u64, u8)> = line.to_servos.drain(..).map(|b| (now, b)).collect();
        for (_, a) in bus.exchange(&timed, now) {
            line.to_master.extend(a);
        }
    }
    assert_eq!(m.stage(), Stage::Running);
    // Ping ID 1 came first.
    let ping = dynamixel2_bytes(1, |d| drop(d.ping(1)));
    assert_eq!(&line.written[..ping.len()], &ping[..]);
    line.written.clear();
    let map = default_map();
    let targets = [0.1f32, -0.2, 1.0, 0.2, -0.5];
    m.period(now, &mut line, Some(targets.map(Some)));
    let raw: Vec<u32> = map.iter().zip(targets).map(|(e, a)| e.to_raw(a).unwrap() as u32).collect();
    let ids: Vec<u8> = map.iter().map(|e| e.id).collect();
    let expected = dynamixel2_bytes(2, |d| {
        let data = ids.iter().zip(&raw).map(|(&motor_id, &data)| dynamixel2::instructions::SyncWriteData { motor_id, data });
        d.sync_write_u32(116, data.collect::<Vec<_>>()).unwrap();
        let _ = d.sync_read_u32(&ids, 132);
    });
    assert_eq!(line.written, expected);
    // A stuffed packet: the same bytes too.
    let mut ours = [0u8; 32];
    let n = msr_shared::dynamixel::write(1, 116, &[0xFF, 0xFF, 0xFD, 0x00], &mut ours).unwrap();
    let theirs = dynamixel2_bytes(1, |d| drop(d.write(1, 116, &[0xFF, 0xFF, 0xFD, 0x00])));
    assert_eq!(&ours[..n], &theirs[..]);
}
