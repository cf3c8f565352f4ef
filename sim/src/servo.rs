//! Emulated position servos on the servo bus: every joint with limits (head and both arms).
//!
//! Each servo follows its target with a first-order response (time constant
//! [`ServoConfig::time_constant_s`]) capped at the joint's velocity limit, stays inside the joint
//! limits, reads its position through a 12-bit encoder (4096 counts per turn), and moves only
//! while stiff. The bus speaks `msr_shared::msg::{BoardToServo, ServoToBoard}` in
//! `msr_shared::frame` frames, reports every joint every [`ServoConfig::report_period_us`], and
//! holds position when no target has come for [`ServoConfig::hold_timeout_us`].
//!
//! Safety accounting: a target outside the limits, not finite, or for a joint without limits is a
//! **limit violation** (refused, counted, flagged in the joint's faults); a frame that fails its
//! checks or does not parse is a **frame error** (counted by kind), never a violation.
use msr_shared::frame::{encode_message, FrameAccumulator, LinkCounters, Sequencer, MAX_WIRE_FRAME};
use msr_shared::joints::Joint;
use msr_shared::msg::{fault, BoardToServo, JointState, ServoToBoard, MAX_BUS_JOINTS};

pub use crate::actuator::{quantise, Servo, ServoConfig, COUNT_RAD, ENCODER_COUNTS};

/// The joints on the bus: all joints with limits, in id order (12 of them).
pub fn bus_joints() -> Vec<Joint> {
    Joint::ALL.iter().copied().filter(|j| j.limits().is_some()).collect()
}

/// What the bus has counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Targets outside the limits, not finite or for an unlimited or unknown joint.
    pub limit_violations: u32,
    /// Accepted targets.
    pub targets: u32,
    /// Messages that parsed.
    pub messages: u32,
    /// State reports sent.
    pub reports: u32,
    /// Times the hold timeout fired.
    pub hold_timeouts: u32,
}

/// All servos on one bus, with the bus's framing.
pub struct ServoBus {
    cfg: ServoConfig,
    servos: Vec<Servo>,
    rx: FrameAccumulator<MAX_WIRE_FRAME>,
    seq: Sequencer,
    counters: BusCounters,
    now_us: u64,
    next_report_us: u64,
    report_now: bool,
    /// Speaking Dynamixel Protocol 2.0 instead of the framed protocol.
    dxl: Option<crate::dynamixel::DxlBus>,
    /// The encoder noise's draws.
    rng: rand_chacha::ChaCha8Rng,
}

impl ServoBus {
    /// Servos for every joint with limits, starting at `start` (angles for the joints named;
    /// others at 0 clamped into their limits).
    pub fn new(cfg: ServoConfig, start: &[(Joint, f64)]) -> ServoBus {
        let servos = bus_joints()
            .into_iter()
            .filter_map(|j| {
                let p = start.iter().find(|(k, _)| *k == j).map_or(0.0, |(_, a)| *a);
                Servo::new(j, p, &cfg)
            })
            .collect();
        ServoBus {
            cfg,
            servos,
            rx: FrameAccumulator::new(),
            seq: Sequencer::default(),
            counters: BusCounters::default(),
            now_us: 0,
            next_report_us: 0,
            report_now: false,
            dxl: None,
            rng: rand::SeedableRng::seed_from_u64(cfg.noise_seed),
        }
    }

    /// The same servos as emulated Dynamixel X-series servos on a Protocol 2.0 bus (see
    /// [`crate::dynamixel`]): only the joints of `cfg.map` are on that bus.
    pub fn with_dynamixel(mut self, cfg: crate::dynamixel::DxlConfig) -> Result<ServoBus, String> {
        self.dxl = Some(crate::dynamixel::DxlBus::new(cfg)?);
        Ok(self)
    }

    /// The Protocol 2.0 side, when the bus speaks it.
    pub fn dynamixel(&self) -> Option<&crate::dynamixel::DxlBus> {
        self.dxl.as_ref()
    }

    /// Feeds bytes with their arrival times (us) at `now_us`; returns the answers to send, each
    /// with the time it starts on the line (never before `now_us`: the caller sends it then).
    pub fn exchange(&mut self, bytes: &[(u64, u8)], now_us: u64) -> Vec<(u64, Vec<u8>)> {
        let Some(mut d) = self.dxl.take() else {
            let plain: Vec<u8> = bytes.iter().map(|&(_, b)| b).collect();
            self.receive(&plain, now_us);
            return self.step(now_us).map(|r| (now_us, r)).into_iter().collect();
        };
        // The dynamics step on the tick, as on the framed bus; a read answers the state now.
        self.advance(now_us);
        d.faults_at(now_us, &mut self.servos);
        d.receive(bytes, &mut self.servos);
        let answers = d.take_answers();
        self.dxl = Some(d);
        answers
    }

    /// The published home posture for the reach joints, everything else at 0 (LElbowYaw at the
    /// reach's fixed value).
    pub fn at_home(cfg: ServoConfig) -> ServoBus {
        let mut start: Vec<(Joint, f64)> = msr_shared::joints::REACH_JOINTS
            .iter()
            .zip(crate::kin::home())
            .map(|(j, a)| (*j, a))
            .collect();
        start.push((Joint::LElbowYaw, crate::kin::ARM_FIXED[0]));
        start.push((Joint::RShoulderPitch, crate::kin::home()[2]));
        start.push((Joint::RShoulderRoll, -crate::kin::home()[3]));
        start.push((Joint::RElbowRoll, -crate::kin::home()[4]));
        start.push((Joint::RElbowYaw, -crate::kin::ARM_FIXED[0]));
        ServoBus::new(cfg, &start)
    }

    /// Every servo, in bus order.
    pub fn servos(&self) -> &[Servo] {
        &self.servos
    }

    /// The servo of joint `j`, if it is on the bus.
    pub fn servo(&self, j: Joint) -> Option<&Servo> {
        self.servos.iter().find(|s| s.joint == j)
    }

    /// True position of a joint (0 for one not on the bus).
    pub fn position(&self, j: Joint) -> f64 {
        self.servo(j).map_or(0.0, |s| s.position)
    }

    /// True positions of the five reach joints.
    pub fn reach_angles(&self) -> crate::kin::Reach {
        msr_shared::joints::REACH_JOINTS.map(|j| self.position(j))
    }

    /// What the bus has counted.
    pub fn counters(&self) -> BusCounters {
        self.counters
    }

    /// Frame-level counters of what the bus received (CRC, COBS, oversized, malformed).
    pub fn frame_counters(&self) -> &LinkCounters {
        self.rx.counters()
    }

    /// Feeds bytes received from the board at `now_us`.
    pub fn receive(&mut self, bytes: &[u8], now_us: u64) {
        self.advance(now_us);
        for &b in bytes {
            let msg = match self.rx.push(b) {
                Some(Ok(f)) => f.message::<BoardToServo>(),
                _ => continue,
            };
            match msg {
                Ok(m) => {
                    self.counters.messages += 1;
                    self.apply(m, now_us);
                }
                Err(_) => self.rx.count_malformed(),
            }
        }
    }

    fn apply(&mut self, msg: BoardToServo, now_us: u64) {
        match msg {
            BoardToServo::Targets { targets, .. } => {
                for t in targets {
                    let Some(s) = self.servos.iter_mut().find(|s| s.joint == t.joint) else {
                        // A joint that has no limits is never commanded (see msr_shared::joints).
                        self.counters.limit_violations += 1;
                        continue;
                    };
                    let a = t.position as f64;
                    if t.joint.validate(t.position).is_err() {
                        self.counters.limit_violations += 1;
                        s.faults |= fault::LIMIT;
                        continue;
                    }
                    s.target = a.clamp(s.min, s.max);
                    s.last_target_us = Some(now_us);
                    s.faults &= !(fault::LIMIT | fault::TIMEOUT);
                    self.counters.targets += 1;
                }
            }
            BoardToServo::StateRequest => self.report_now = true,
            BoardToServo::Stiffness { on } => {
                for s in &mut self.servos {
                    s.stiff = on;
                    // Stiffening holds where the joint is, not where an old target was.
                    if on {
                        s.target = s.position;
                    }
                }
            }
        }
    }

    /// Moves the servos to `now_us`.
    fn advance(&mut self, now_us: u64) {
        let tau = self.cfg.time_constant_s;
        while self.now_us < now_us {
            let dt_us = self.cfg.step_us.min(now_us - self.now_us);
            let dt = dt_us as f64 * 1e-6;
            for s in &mut self.servos {
                s.step(dt, tau);
            }
            if self.cfg.encoder_noise > 0.0 {
                for s in &mut self.servos {
                    s.noise = self.cfg.encoder_noise * crate::standard_normal(&mut self.rng);
                }
            }
            self.now_us += dt_us;
        }
        for s in &mut self.servos {
            let stale = match s.last_target_us {
                Some(t) => now_us.saturating_sub(t) >= self.cfg.hold_timeout_us,
                None => false,
            };
            if stale && s.faults & fault::TIMEOUT == 0 {
                s.faults |= fault::TIMEOUT;
                s.target = s.position;
                s.last_target_us = None;
                self.counters.hold_timeouts += 1;
            }
        }
    }

    /// Advances to `now_us` and returns the bytes of a state report when one is due.
    pub fn step(&mut self, now_us: u64) -> Option<Vec<u8>> {
        self.advance(now_us);
        if now_us < self.next_report_us && !self.report_now {
            return None;
        }
        self.report_now = false;
        self.next_report_us = now_us - now_us % self.cfg.report_period_us + self.cfg.report_period_us;
        let mut states = heapless::Vec::<JointState, MAX_BUS_JOINTS>::new();
        for s in &self.servos {
            let st = JointState { joint: s.joint, position: s.measured() as f32, stiffness: s.stiff, faults: s.faults };
            if states.push(st).is_err() {
                break;
            }
        }
        let msg = ServoToBoard::States { time_ms: (now_us / 1000) as u32, states };
        let mut buf = [0u8; MAX_WIRE_FRAME];
        let n = encode_message(self.seq.next(), &msg, &mut buf).expect("a state report fits a frame");
        self.counters.reports += 1;
        Some(buf[..n].to_vec())
    }
}

pub mod serve;

#[cfg(test)]
mod tests;
