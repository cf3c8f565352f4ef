//! The emulated servos on a real serial line (a PTY, or a port), in real time, so that any
//! Dynamixel software (DynamixelSDK, Dynamixel Wizard, the `dynamixel2` crate) can talk to them.
use crate::dynamixel::DxlConfig;
use crate::servo::{ServoBus, ServoConfig};
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// What a serving session did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Served {
    /// Bytes read from the line.
    pub bytes_in: u64,
    /// Bytes written to the line.
    pub bytes_out: u64,
}

/// The robot's servos at home, speaking Protocol 2.0 with `cfg`.
pub fn servos(cfg: DxlConfig) -> Result<ServoBus, String> {
    ServoBus::at_home(ServoConfig::default()).with_dynamixel(cfg)
}

/// Serves `bus` on `line` until `stop` is set: reads what arrived every `poll`, answers after
/// each servo's return delay (at the earliest: the OS's latency is larger), moves the servos in
/// real time. `line`'s reads must not block for long (a timeout of a few milliseconds).
/// Every byte received is copied to `log` when given.
pub fn serve<L: Read + Write>(
    bus: &mut ServoBus,
    line: &mut L,
    stop: &AtomicBool,
    mut log: Option<&mut dyn Write>,
) -> std::io::Result<Served> {
    let t0 = Instant::now();
    let now_us = || t0.elapsed().as_micros() as u64;
    let mut served = Served::default();
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let n = match line.read(&mut buf) {
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock | std::io::ErrorKind::Interrupted) => 0,
            Err(e) => return Err(e),
        };
        let t = now_us();
        if let Some(l) = log.as_deref_mut() {
            l.write_all(&buf[..n])?;
        }
        served.bytes_in += n as u64;
        let timed: Vec<(u64, u8)> = buf[..n].iter().map(|&b| (t, b)).collect();
        for (at, answer) in bus.exchange(&timed, t) {
            if let Some(wait) = at.checked_sub(now_us()) {
                std::thread::sleep(Duration::from_micros(wait));
            }
            line.write_all(&answer)?;
            line.flush()?;
            served.bytes_out += answer.len() as u64;
        }
        if n == 0 {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    Ok(served)
}
