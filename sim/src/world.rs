//! The simulated world and the firmware side, on two threads in lock-step simulated time.
//!
//! Every tick (default 1 ms) the world thread moves the servos, answers the servo bus and runs
//! the scenario (which plays the PC on the host link: sends frames, reads reports, judges), while
//! the firmware thread calls the firmware's `poll(now_us, host_link, servo_bus)`; then both meet
//! at a barrier and time advances. A byte written at time t arrives strictly after t (see
//! [`crate::link`]), so what each side sees does not depend on thread timing: a run is
//! reproducible for a seed.
use crate::body::BodyPose;
use crate::kin::LeftArm;
use crate::link::{link, LinkConfig, LinkEnd};
use crate::servo::{ServoBus, ServoConfig};
use msr_shared::joints::Joint;
use std::sync::{Condvar, Mutex};

/// The firmware side: called once a tick with the time and its two link ends.
pub trait Firmware: Send {
    /// Runs the firmware for one tick at `now_us`.
    fn poll(&mut self, now_us: u64, host: &mut LinkEnd, servo: &mut LinkEnd);
}

impl<F: FnMut(u64, &mut LinkEnd, &mut LinkEnd) + Send> Firmware for F {
    fn poll(&mut self, now_us: u64, host: &mut LinkEnd, servo: &mut LinkEnd) {
        self(now_us, host, servo)
    }
}

#[derive(Clone, Debug, PartialEq)]
/// Settings of the world: tick, links and servos.
pub struct WorldConfig {
    /// Simulated time per tick, microseconds.
    pub tick_us: u64,
    /// Host link: end A is the world (the PC's side), end B the firmware.
    pub host_link: LinkConfig,
    /// Servo bus: end A is the firmware, end B the servos.
    pub servo_link: LinkConfig,
    /// The servos' settings.
    pub servo: ServoConfig,
    /// The servos speak Dynamixel Protocol 2.0 (`None`: the framed protocol).
    pub dynamixel: Option<crate::dynamixel::DxlConfig>,
    /// Simulated seconds per wall-clock second, for talking to real-time peers (a PTY);
    /// `None` runs as fast as it can.
    pub pace: Option<f64>,
    /// How the left arm differs from its drawing (what the camera sees of it).
    pub arm_error: crate::kin::ArmError,
}

impl Default for WorldConfig {
    fn default() -> Self {
        WorldConfig {
            tick_us: 1000,
            host_link: LinkConfig::default(),
            servo_link: LinkConfig { seed: 1, ..LinkConfig::default() },
            servo: ServoConfig::default(),
            dynamixel: None,
            pace: None,
            arm_error: crate::kin::ArmError::EXACT,
        }
    }
}

impl WorldConfig {
    /// Seeds both links' fault layers from one seed.
    pub fn seeded(mut self, seed: u64) -> Self {
        self.host_link.seed = seed.wrapping_mul(2);
        self.servo_link.seed = seed.wrapping_mul(2).wrapping_add(1);
        self
    }
}

/// The world side: servos on the servo bus, and the PC's end of the host link.
pub struct World {
    /// Simulated time, microseconds.
    pub now_us: u64,
    /// The servos on the servo bus.
    pub servos: ServoBus,
    /// The world's end of the host link; the scenario sends and receives on it.
    pub host: LinkEnd,
    servo_end: LinkEnd,
    /// How the left arm differs from its drawing.
    pub arm_error: crate::kin::ArmError,
}

impl World {
    fn step(&mut self) {
        let now = self.now_us;
        self.servo_end.set_time(now);
        self.host.set_time(now);
        let bytes = self.servo_end.receive_timed();
        for (at, answer) in self.servos.exchange(&bytes, now) {
            self.servo_end.send_at(at, &answer);
        }
    }

    /// The body pose the servos hold now (true positions), for rendering: head and both arms.
    pub fn body_pose(&self) -> BodyPose {
        let s = &self.servos;
        let arm = |sp, sr, ey, er, wy| LeftArm {
            shoulder_pitch: s.position(sp),
            shoulder_roll: s.position(sr),
            elbow_yaw: s.position(ey),
            elbow_roll: s.position(er),
            wrist_yaw: s.position(wy),
        };
        use Joint::*;
        BodyPose {
            head_yaw: s.position(HeadYaw),
            head_pitch: s.position(HeadPitch),
            left_arm: arm(LShoulderPitch, LShoulderRoll, LElbowYaw, LElbowRoll, LWristYaw),
            right_arm: arm(RShoulderPitch, RShoulderRoll, RElbowYaw, RElbowRoll, RWristYaw),
            arm_error: self.arm_error,
        }
    }

    /// What the servo bus has seen of the firmware's traffic (as the firmware's sending end).
    pub fn servo_link_stats(&self) -> crate::link::LaneStats {
        self.servo_end.tx_stats()
    }
}

/// What the scenario tells the world after each tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Go on to the next tick.
    Continue,
    /// End the run.
    Stop,
}

/// How a run went.
#[derive(Clone, Debug, PartialEq)]
pub struct RunReport {
    /// Simulated time at the end, microseconds.
    pub end_us: u64,
    /// Ticks run.
    pub ticks: u64,
    /// Wall-clock seconds the run took.
    pub wall_s: f64,
    /// Simulated time over wall time.
    pub speedup: f64,
}

#[derive(Debug, thiserror::Error)]
/// Why a run failed.
pub enum RunError {
    #[error("bad world settings: {0}")]
    /// The world's settings are invalid.
    Config(String),
    #[error("the firmware panicked at {at_us} us: {message}")]
    /// The firmware panicked at `at_us`.
    FirmwarePanic {
        /// Simulated time of the panic, microseconds.
        at_us: u64,
        /// The panic's message.
        message: String,
    },
}

/// Builds the world (servos at home) and runs it with `firmware` on its own thread until the
/// scenario says stop or `max_us` of simulated time pass. Returns the world for inspection.
pub fn run<F, S>(cfg: &WorldConfig, firmware: &mut F, mut scenario: S, max_us: u64) -> Result<(World, RunReport), RunError>
where
    F: Firmware,
    S: FnMut(&mut World) -> Flow,
{
    if cfg.tick_us == 0 {
        return Err(RunError::Config("tick must be positive".into()));
    }
    if cfg.pace.is_some_and(|p| !(p.is_finite() && p > 0.0)) {
        return Err(RunError::Config("pace must be positive".into()));
    }
    let (host_world, mut host_fw) = link(&cfg.host_link).map_err(RunError::Config)?;
    let (mut servo_fw, servo_world) = link(&cfg.servo_link).map_err(RunError::Config)?;
    let mut servos = ServoBus::at_home(cfg.servo);
    if let Some(d) = &cfg.dynamixel {
        servos = servos.with_dynamixel(d.clone()).map_err(RunError::Config)?;
    }
    let mut world = World {
        now_us: 0,
        servos,
        host: host_world,
        servo_end: servo_world,
        arm_error: cfg.arm_error,
    };
    let barrier = TickBarrier::default();
    let failed: Mutex<Option<(u64, String)>> = Mutex::new(None);
    let tick = cfg.tick_us;
    let t0 = std::time::Instant::now();
    let mut ticks = 0u64;

    std::thread::scope(|scope| {
        let (barrier, failed) = (&barrier, &failed);
        scope.spawn(move || {
            let mut now = 0u64;
            loop {
                host_fw.set_time(now);
                servo_fw.set_time(now);
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    firmware.poll(now, &mut host_fw, &mut servo_fw)
                }));
                let mut stop = false;
                if let Err(e) = r {
                    let msg = e
                        .downcast_ref::<&str>()
                        .map(|s| s.to_string())
                        .or_else(|| e.downcast_ref::<String>().cloned())
                        .unwrap_or_else(|| "unknown panic".into());
                    *failed.lock().unwrap_or_else(|p| p.into_inner()) = Some((now, msg));
                    stop = true;
                }
                if barrier.wait(stop) {
                    return;
                }
                now += tick;
            }
        });
        loop {
            world.step();
            let flow = scenario(&mut world);
            let stop = flow == Flow::Stop || world.now_us + tick > max_us;
            ticks += 1;
            if barrier.wait(stop) {
                break;
            }
            world.now_us += tick;
            if let Some(p) = cfg.pace {
                let due = std::time::Duration::from_secs_f64(world.now_us as f64 * 1e-6 / p);
                if let Some(wait) = due.checked_sub(t0.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
        }
    });
    if let Some((at_us, message)) = failed.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(RunError::FirmwarePanic { at_us, message });
    }
    let wall_s = t0.elapsed().as_secs_f64();
    let end_us = world.now_us;
    Ok((world, RunReport { end_us, ticks, wall_s, speedup: end_us as f64 * 1e-6 / wall_s.max(1e-9) }))
}

/// A two-party barrier that also agrees on whether to stop: both sides get `true` when either
/// asked to stop at this tick (one meeting a tick instead of two with `std::sync::Barrier`).
#[derive(Default)]
struct TickBarrier {
    state: Mutex<BarrierState>,
    cv: Condvar,
}

#[derive(Default)]
struct BarrierState {
    arrived: u32,
    stop: bool,
    generation: u64,
    result: bool,
}

impl TickBarrier {
    fn wait(&self, stop: bool) -> bool {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let gen = s.generation;
        s.stop |= stop;
        s.arrived += 1;
        if s.arrived == 2 {
            s.result = s.stop;
            s.arrived = 0;
            s.stop = false;
            s.generation += 1;
            self.cv.notify_one();
            return s.result;
        }
        while s.generation == gen {
            s = self.cv.wait(s).unwrap_or_else(|p| p.into_inner());
        }
        // The other side cannot start the next generation before this one has left: it needs
        // this side to arrive again. So `result` is still this generation's.
        s.result
    }
}

#[cfg(test)]
mod tests;
