//! Serial links in simulated time, and a fault layer for any byte stream.
//!
//! - [`link`] makes a duplex pipe paced at a baud rate: a byte written at time t leaves after the
//!   bytes queued before it and arrives one byte-time later (10 bits a byte for 8N1). Each end
//!   ([`LinkEnd`]) has its own clock, set by whoever drives it, and implements
//!   `embedded_io::{Read, Write, ReadReady}`: a read returns what has arrived by that end's time
//!   and never blocks. Because a byte written at t arrives strictly after t, two threads that
//!   step in lock-step see the same bytes at the same times, whatever the thread scheduling.
//! - [`Faults`] corrupts a byte stream: bit errors at a rate, dropped bytes, bursts of garbage,
//!   and disconnects (nothing gets through) for given windows of time; seeded. It is used inside
//!   the paced link and by [`FaultyStream`], which wraps any `std::io` or `embedded_io` stream.
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

/// What goes wrong on one direction of a link.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FaultConfig {
    /// Probability that each bit (8 per byte) is flipped.
    pub bit_error_rate: f64,
    /// Probability that a byte is lost.
    pub drop_rate: f64,
    /// Probability, per byte, that a burst starts: `burst_len` bytes replaced by random ones.
    pub burst_rate: f64,
    /// Bytes a burst replaces.
    pub burst_len: u32,
    /// Windows `(start_us, duration_us)` in which the line is dead: every byte is lost.
    pub disconnects: Vec<(u64, u64)>,
}

impl FaultConfig {
    /// Only bit errors, at `rate` per bit.
    pub fn ber(rate: f64) -> FaultConfig {
        FaultConfig { bit_error_rate: rate, ..Default::default() }
    }

    /// Only one dead window of `duration_us` from `start_us`.
    pub fn disconnect(start_us: u64, duration_us: u64) -> FaultConfig {
        FaultConfig { disconnects: vec![(start_us, duration_us)], ..Default::default() }
    }

    /// Refuses rates outside 0..=1 and NaN.
    pub fn check(&self) -> Result<(), String> {
        for (name, v) in [
            ("bit error rate", self.bit_error_rate),
            ("drop rate", self.drop_rate),
            ("burst rate", self.burst_rate),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{name} must be in 0..=1, got {v}"));
            }
        }
        Ok(())
    }

    /// Whether nothing goes wrong (`burst_len` alone, with no bursts, is clean).
    pub fn is_clean(&self) -> bool {
        self.bit_error_rate == 0.0 && self.drop_rate == 0.0 && self.burst_rate == 0.0 && self.disconnects.is_empty()
    }
}

/// What the fault layer did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultCounters {
    /// Bytes that passed through.
    pub bytes: u64,
    /// Bits flipped.
    pub bits_flipped: u64,
    /// Bytes dropped.
    pub bytes_dropped: u64,
    /// Bursts started.
    pub bursts: u64,
    /// Bytes replaced by bursts.
    pub burst_bytes: u64,
    /// Bytes lost to dead windows.
    pub disconnect_bytes: u64,
}

/// A seeded fault injector for one direction.
pub struct Faults {
    cfg: FaultConfig,
    rng: ChaCha8Rng,
    burst_left: u32,
    counters: FaultCounters,
}

impl Faults {
    /// A fault layer drawing from `seed`.
    pub fn new(cfg: FaultConfig, seed: u64) -> Faults {
        Faults { cfg, rng: ChaCha8Rng::seed_from_u64(seed), burst_left: 0, counters: FaultCounters::default() }
    }

    /// What the layer has counted.
    pub fn counters(&self) -> FaultCounters {
        self.counters
    }

    /// Whether the line is dead at `t_us`.
    pub fn disconnected(&self, t_us: u64) -> bool {
        self.cfg.disconnects.iter().any(|&(s, d)| t_us >= s && t_us < s.saturating_add(d))
    }

    /// One byte on the line at `t_us`: what arrives, if anything.
    pub fn apply(&mut self, t_us: u64, byte: u8) -> Option<u8> {
        self.counters.bytes += 1;
        if self.cfg.is_clean() {
            return Some(byte);
        }
        if self.disconnected(t_us) {
            self.counters.disconnect_bytes += 1;
            return None;
        }
        if self.burst_left == 0 && self.cfg.burst_rate > 0.0 && self.rng.gen_bool(self.cfg.burst_rate) {
            self.burst_left = self.cfg.burst_len;
            self.counters.bursts += 1;
        }
        if self.burst_left > 0 {
            self.burst_left -= 1;
            self.counters.burst_bytes += 1;
            return Some(self.rng.gen());
        }
        if self.cfg.drop_rate > 0.0 && self.rng.gen_bool(self.cfg.drop_rate) {
            self.counters.bytes_dropped += 1;
            return None;
        }
        let mut b = byte;
        if self.cfg.bit_error_rate > 0.0 {
            for bit in 0..8 {
                if self.rng.gen_bool(self.cfg.bit_error_rate) {
                    b ^= 1 << bit;
                    self.counters.bits_flipped += 1;
                }
            }
        }
        Some(b)
    }
}

/// A link's line settings.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkConfig {
    /// Line speed, bits per second.
    pub baud: u32,
    /// Bits on the line per byte: 10 for 8N1.
    pub bits_per_byte: u32,
    /// Faults from end A to end B and back.
    pub a_to_b: FaultConfig,
    /// Faults from end B to end A.
    pub b_to_a: FaultConfig,
    /// Seed of the fault draws.
    pub seed: u64,
    /// Bytes a sender may queue; more are dropped and counted as overflow.
    pub tx_capacity: usize,
}

impl Default for LinkConfig {
    fn default() -> Self {
        LinkConfig {
            baud: 921_600,
            bits_per_byte: 10,
            a_to_b: FaultConfig::default(),
            b_to_a: FaultConfig::default(),
            seed: 0,
            tx_capacity: 1 << 20,
        }
    }
}

impl LinkConfig {
    /// Nanoseconds one byte takes on the line.
    pub fn byte_ns(&self) -> f64 {
        self.bits_per_byte as f64 * 1e9 / self.baud as f64
    }
}

/// One direction of a link.
struct Lane {
    byte_ns: f64,
    /// When the line finishes sending what is queued.
    line_free_ns: f64,
    queue: VecDeque<(u64, u8)>,
    faults: Faults,
    capacity: usize,
    overflow: u64,
    sent: u64,
    delivered: u64,
}

impl Lane {
    fn write(&mut self, now_us: u64, bytes: &[u8]) {
        let now_ns = now_us as f64 * 1000.0;
        for &b in bytes {
            if self.queue.len() >= self.capacity {
                self.overflow += 1;
                continue;
            }
            let start = self.line_free_ns.max(now_ns);
            let end = start + self.byte_ns;
            self.line_free_ns = end;
            self.sent += 1;
            // The fault sees the byte at the time it is on the line.
            if let Some(out) = self.faults.apply((start / 1000.0) as u64, b) {
                self.queue.push_back((end.ceil() as u64, out));
            }
        }
    }

    fn ready(&self, now_us: u64) -> bool {
        self.queue.front().is_some_and(|(t, _)| *t <= now_us * 1000)
    }

    fn read(&mut self, now_us: u64, buf: &mut [u8]) -> usize {
        let mut n = 0;
        while n < buf.len() && self.ready(now_us) {
            buf[n] = self.queue.pop_front().expect("ready").1;
            n += 1;
        }
        self.delivered += n as u64;
        n
    }
}

/// Counters of one direction, as seen from the sending end.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LaneStats {
    /// Bytes the sender queued.
    pub sent: u64,
    /// Bytes the receiver got.
    pub delivered: u64,
    /// Bytes on the line now.
    pub in_flight: u64,
    /// Bytes dropped because the queue was full.
    pub overflow: u64,
    /// What the fault layer did.
    pub faults: FaultCounters,
}

/// One end of a paced link.
pub struct LinkEnd {
    tx: Arc<Mutex<Lane>>,
    rx: Arc<Mutex<Lane>>,
    now_us: u64,
}

/// Makes a duplex link; returns ends A and B.
pub fn link(cfg: &LinkConfig) -> Result<(LinkEnd, LinkEnd), String> {
    cfg.a_to_b.check()?;
    cfg.b_to_a.check()?;
    if cfg.baud == 0 || cfg.bits_per_byte == 0 {
        return Err("baud and bits per byte must be positive".into());
    }
    let lane = |f: &FaultConfig, salt: u64| {
        Arc::new(Mutex::new(Lane {
            byte_ns: cfg.byte_ns(),
            line_free_ns: 0.0,
            queue: VecDeque::new(),
            faults: Faults::new(f.clone(), cfg.seed ^ salt),
            capacity: cfg.tx_capacity,
            overflow: 0,
            sent: 0,
            delivered: 0,
        }))
    };
    let ab = lane(&cfg.a_to_b, 0xA2B);
    let ba = lane(&cfg.b_to_a, 0xB2A);
    Ok((
        LinkEnd { tx: ab.clone(), rx: ba.clone(), now_us: 0 },
        LinkEnd { tx: ba, rx: ab, now_us: 0 },
    ))
}

fn lock(l: &Mutex<Lane>) -> std::sync::MutexGuard<'_, Lane> {
    // A panic on the other thread must not hide what this one sees.
    l.lock().unwrap_or_else(|e| e.into_inner())
}

impl LinkEnd {
    /// Sets this end's clock (simulated microseconds); it never goes back.
    pub fn set_time(&mut self, now_us: u64) {
        self.now_us = self.now_us.max(now_us);
    }

    /// The link's clock, microseconds.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Queues bytes for sending at this end's time.
    pub fn send(&mut self, bytes: &[u8]) {
        lock(&self.tx).write(self.now_us, bytes);
    }

    /// Everything that has arrived by this end's time.
    pub fn receive(&mut self) -> Vec<u8> {
        let mut out = Vec::new();
        let mut buf = [0u8; 256];
        loop {
            let n = lock(&self.rx).read(self.now_us, &mut buf);
            if n == 0 {
                return out;
            }
            out.extend_from_slice(&buf[..n]);
        }
    }

    /// Queues bytes to start on the line at `at_us`, or at this end's time if that is later
    /// (a byte sent at t still arrives strictly after t).
    pub fn send_at(&mut self, at_us: u64, bytes: &[u8]) {
        lock(&self.tx).write(at_us.max(self.now_us), bytes);
    }

    /// Everything that has arrived by this end's time, each byte with its arrival time (us).
    pub fn receive_timed(&mut self) -> Vec<(u64, u8)> {
        let mut lane = lock(&self.rx);
        let mut out = Vec::new();
        while lane.ready(self.now_us) {
            let (t_ns, b) = lane.queue.pop_front().expect("ready");
            out.push((t_ns.div_ceil(1000), b));
        }
        lane.delivered += out.len() as u64;
        out
    }

    /// When the line will have sent everything this end queued (simulated microseconds).
    pub fn tx_idle_at_us(&self) -> u64 {
        (lock(&self.tx).line_free_ns / 1000.0).ceil() as u64
    }

    /// What this end sent.
    pub fn tx_stats(&self) -> LaneStats {
        let l = lock(&self.tx);
        LaneStats {
            sent: l.sent,
            delivered: l.delivered,
            in_flight: l.queue.len() as u64,
            overflow: l.overflow,
            faults: l.faults.counters(),
        }
    }
}

impl embedded_io::ErrorType for LinkEnd {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Read for LinkEnd {
    /// Returns what has arrived by this end's time; 0 when nothing has (check `read_ready`).
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        Ok(lock(&self.rx).read(self.now_us, buf))
    }
}

impl embedded_io::ReadReady for LinkEnd {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(lock(&self.rx).ready(self.now_us))
    }
}

impl embedded_io::Write for LinkEnd {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.send(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

impl embedded_io::WriteReady for LinkEnd {
    fn write_ready(&mut self) -> Result<bool, Self::Error> {
        let l = lock(&self.tx);
        Ok(l.queue.len() < l.capacity)
    }
}

/// Wraps any byte stream and puts [`Faults`] on both directions. Time for disconnect windows
/// comes from `clock` (microseconds); [`FaultyStream::real_time`] uses the wall clock.
pub struct FaultyStream<S> {
    inner: S,
    tx: Faults,
    rx: Faults,
    clock: Box<dyn FnMut() -> u64 + Send>,
}

impl<S> FaultyStream<S> {
    /// Wraps `inner`, with faults `tx` on what is written, `rx` on what is read, timed by `clock`.
    pub fn new(inner: S, tx: Faults, rx: Faults, clock: Box<dyn FnMut() -> u64 + Send>) -> Self {
        FaultyStream { inner, tx, rx, clock }
    }

    /// Disconnect windows count from now, in wall-clock microseconds.
    pub fn real_time(inner: S, tx: Faults, rx: Faults) -> Self {
        let t0 = std::time::Instant::now();
        Self::new(inner, tx, rx, Box::new(move || t0.elapsed().as_micros() as u64))
    }

    /// The wrapped stream.
    pub fn inner(&mut self) -> &mut S {
        &mut self.inner
    }

    /// What the fault layer did to written bytes.
    pub fn tx_counters(&self) -> FaultCounters {
        self.tx.counters()
    }

    /// What the fault layer did to read bytes.
    pub fn rx_counters(&self) -> FaultCounters {
        self.rx.counters()
    }

    /// Applies the receive faults in place; returns the bytes kept.
    fn corrupt_rx(&mut self, buf: &mut [u8], n: usize) -> usize {
        let t = (self.clock)();
        let mut kept = 0;
        for i in 0..n {
            if let Some(b) = self.rx.apply(t, buf[i]) {
                buf[kept] = b;
                kept += 1;
            }
        }
        kept
    }

    fn corrupt_tx(&mut self, buf: &[u8]) -> Vec<u8> {
        let t = (self.clock)();
        buf.iter().filter_map(|&b| self.tx.apply(t, b)).collect()
    }
}

impl<S: std::io::Read> std::io::Read for FaultyStream<S> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let n = self.inner.read(buf)?;
            if n == 0 {
                return Ok(0);
            }
            let kept = self.corrupt_rx(buf, n);
            // Everything read was lost: read again rather than report end of stream.
            if kept > 0 {
                return Ok(kept);
            }
        }
    }
}

impl<S: std::io::Write> std::io::Write for FaultyStream<S> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let out = self.corrupt_tx(buf);
        self.inner.write_all(&out)?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// The same wrapper over `embedded_io` streams (e.g. a [`LinkEnd`]); non-blocking reads may
/// return 0 when all that arrived was lost.
pub struct FaultyIo<S>(pub FaultyStream<S>);

impl<S: embedded_io::ErrorType> embedded_io::ErrorType for FaultyIo<S> {
    type Error = S::Error;
}

impl<S: embedded_io::Read> embedded_io::Read for FaultyIo<S> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = self.0.inner.read(buf)?;
        Ok(self.0.corrupt_rx(buf, n))
    }
}

impl<S: embedded_io::ReadReady> embedded_io::ReadReady for FaultyIo<S> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        self.0.inner.read_ready()
    }
}

impl<S: embedded_io::Write> embedded_io::Write for FaultyIo<S> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let out = self.0.corrupt_tx(buf);
        self.0.inner.write_all(&out)?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        self.0.inner.flush()
    }
}

#[cfg(test)]
mod tests;
