//! Motion: observe -> reach -> hold -> return home -> observe, streamed every 10 ms.
//!
//! Each 10 ms step moves every commanded angle towards its goal by at most
//! `speed_fraction * max_velocity * 0.01` rad (default fraction 0.1, as the published robot's
//! `JointAnglesWithSpeed`), and every commanded angle is clamped to the joint limits: a target
//! outside them is never produced, whatever goal was asked for. Streaming starts from the
//! positions the servos report, so the first target is where the arm already is.

use msr_shared::joints::{DEFAULT_SPEED_FRACTION, HOME_POSTURE, REACH_JOINTS};

/// The control period: Nao's DCM cycle.
pub const PERIOD_US: u64 = 10_000;
/// How long a reach is held before going home (the published 5 s).
pub const DEFAULT_HOLD_MS: u32 = 5_000;
/// Longest hold the host may configure.
pub const MAX_HOLD_MS: u32 = 60_000;

const N: usize = REACH_JOINTS.len();

/// Where the behaviour is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// At (or settling to) the home posture, watching for a mark.
    Observe,
    /// Moving to the reach target.
    Reach,
    /// At the target, for the hold time.
    Hold,
    /// Going back home.
    Return,
    /// The self gate's head probe: the head moves, the arm stays home.
    Probe,
}

/// Why a head pose was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeadError {
    /// An angle outside its joint's limits, or not finite.
    OutOfLimits,
    /// No servo positions yet (or the servo link was lost).
    NotStreaming,
    /// A reach is in progress.
    Busy,
}

#[derive(Clone, Copy, Debug, PartialEq)]
/// The reach behaviour: the phase, the goal and the posture commanded each period.
pub struct Motion {
    /// Last commanded posture; `None` until the servos' positions are known.
    commanded: Option<[f32; N]>,
    goal: [f32; N],
    phase: Phase,
    hold_ticks_left: u32,
    speed_fraction: f32,
    hold_ms: u32,
}

impl Default for Motion {
    fn default() -> Self {
        Self::new()
    }
}

/// Clamps a posture into the limits; NaN goes to the joint's home angle.
fn safe(p: [f32; N]) -> [f32; N] {
    let mut out = HOME_POSTURE;
    for i in 0..N {
        if let Ok(v) = REACH_JOINTS[i].clamp(p[i]) {
            out[i] = v;
        }
    }
    out
}

impl Motion {
    /// Observing at home, nothing commanded yet, default speed and hold time.
    pub const fn new() -> Self {
        Motion {
            commanded: None,
            goal: HOME_POSTURE,
            phase: Phase::Observe,
            hold_ticks_left: 0,
            speed_fraction: DEFAULT_SPEED_FRACTION,
            hold_ms: DEFAULT_HOLD_MS,
        }
    }

    /// Where the behaviour is.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The arm is away from home or moving: detection pauses.
    pub fn arm_up(&self) -> bool {
        self.phase != Phase::Observe
    }

    /// The posture last commanded (radians, [`REACH_JOINTS`] order); `None` until the servos reported.
    pub fn commanded(&self) -> Option<[f32; N]> {
        self.commanded
    }

    /// Fraction of each joint's maximum velocity used, `0 < f <= 1`.
    pub fn speed_fraction(&self) -> f32 {
        self.speed_fraction
    }

    /// How long a reach is held, milliseconds.
    pub fn hold_ms(&self) -> u32 {
        self.hold_ms
    }

    /// Largest step of joint `i` per period.
    pub fn max_step(&self, i: usize) -> f32 {
        REACH_JOINTS[i].limits().map_or(0.0, |l| l.max_velocity) * self.speed_fraction * 0.01
    }

    /// Sets the speed fraction; refused unless `0 < f <= 1`.
    pub fn set_speed_fraction(&mut self, f: f32) -> bool {
        if f.is_finite() && f > 0.0 && f <= 1.0 {
            self.speed_fraction = f;
            true
        } else {
            false
        }
    }

    /// Sets the hold time; refused above [`MAX_HOLD_MS`].
    pub fn set_hold_ms(&mut self, ms: u32) -> bool {
        if ms <= MAX_HOLD_MS {
            self.hold_ms = ms;
            true
        } else {
            false
        }
    }

    /// (Re)starts streaming from the measured posture.
    pub fn start_from(&mut self, measured: [f32; N]) {
        self.commanded = Some(safe(measured));
    }

    /// Stops streaming until [`start_from`](Self::start_from) (the servo link was lost).
    pub fn stop(&mut self) {
        self.commanded = None;
    }

    /// Moves the head to `[yaw, pitch]` for the self gate, the rest staying where it is; only
    /// from `Observe` or `Probe` with streaming running. Clamped like every goal.
    pub fn probe(&mut self, head: [f32; 2]) -> bool {
        let Some(c) = self.commanded else { return false };
        if !matches!(self.phase, Phase::Observe | Phase::Probe) {
            return false;
        }
        let mut g = c;
        g[0] = head[0];
        g[1] = head[1];
        self.goal = safe(g);
        self.phase = Phase::Probe;
        true
    }

    /// Starts a reach; only from `Observe` (or the self gate's `Probe`) with streaming running.
    /// The target is clamped.
    pub fn reach(&mut self, target: [f32; N]) -> bool {
        if !matches!(self.phase, Phase::Observe | Phase::Probe) || self.commanded.is_none() {
            return false;
        }
        self.goal = safe(target);
        self.phase = Phase::Reach;
        true
    }

    /// Moves the head to `head` (HeadYaw, HeadPitch), the arm staying at its goal; only while
    /// observing with streaming running, and only to angles inside the limits (refused, not
    /// clamped: the host asked for a pose it means to record). Returns the longest move's
    /// duration in control periods.
    pub fn move_head(&mut self, head: [f32; 2]) -> Result<u32, HeadError> {
        if REACH_JOINTS[0].validate(head[0]).is_err() || REACH_JOINTS[1].validate(head[1]).is_err() {
            return Err(HeadError::OutOfLimits);
        }
        let Some(c) = self.commanded else { return Err(HeadError::NotStreaming) };
        if self.phase != Phase::Observe {
            return Err(HeadError::Busy);
        }
        self.goal[0] = head[0];
        self.goal[1] = head[1];
        let periods = (0..2)
            .map(|i| ((head[i] - c[i]).abs() / self.max_step(i)) as u32 + 1)
            .max()
            .unwrap_or(1);
        Ok(periods)
    }

    /// The head's part of the goal.
    pub fn head_goal(&self) -> [f32; 2] {
        [self.goal[0], self.goal[1]]
    }

    /// Abandons a reach or hold and goes home.
    pub fn go_home(&mut self) {
        if self.phase != Phase::Observe {
            self.phase = Phase::Return;
        }
        self.goal = HOME_POSTURE;
    }

    /// One control period: advances towards the goal and through the phases. Returns the posture
    /// to send, inside the limits, or `None` while not streaming.
    pub fn tick(&mut self) -> Option<[f32; N]> {
        let mut c = self.commanded?;
        let mut arrived = true;
        for i in 0..N {
            let step = self.max_step(i);
            // `f32::clamp`'s check (`min <= max`, panicking with both floats formatted) would
            // link float printing into the board image; `step` is never negative.
            let g = self.goal[i] - c[i];
            let d = if g < -step { -step } else if g > step { step } else { g };
            c[i] = if (self.goal[i] - c[i]).abs() <= step {
                self.goal[i]
            } else {
                c[i] + d
            };
            arrived &= c[i] == self.goal[i];
        }
        let c = safe(c);
        self.commanded = Some(c);
        match self.phase {
            Phase::Reach if arrived => {
                self.phase = Phase::Hold;
                self.hold_ticks_left = self.hold_ms.div_ceil((PERIOD_US / 1000) as u32);
            }
            Phase::Hold => {
                self.hold_ticks_left = self.hold_ticks_left.saturating_sub(1);
                if self.hold_ticks_left == 0 {
                    self.go_home();
                }
            }
            Phase::Return if arrived => self.phase = Phase::Observe,
            _ => {}
        }
        Some(c)
    }

    /// The posture to send while holding still: the last commanded one, unchanged.
    pub fn hold_still(&self) -> Option<[f32; N]> {
        self.commanded
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reach_hold_return_cycle() {
        let mut m = Motion::new();
        assert_eq!(m.tick(), None, "nothing is sent before the servos report");
        m.start_from(HOME_POSTURE);
        let target = [0.5, -0.3, -0.2, 0.1, -1.3];
        assert!(m.reach(target));
        assert!(
            !m.reach(HOME_POSTURE),
            "a second reach while one runs is refused"
        );
        let mut prev = HOME_POSTURE;
        let mut ticks = 0;
        while m.phase() == Phase::Reach {
            let c = m.tick().unwrap();
            for i in 0..N {
                assert!((c[i] - prev[i]).abs() <= m.max_step(i) * 1.0001);
            }
            prev = c;
            ticks += 1;
            assert!(ticks < 10_000);
        }
        assert_eq!(m.commanded(), Some(target));
        // LShoulderPitch moves 1.602 rad at 0.1 * 8.26797 rad/s: about 1.94 s.
        assert!((190..=200).contains(&ticks), "{ticks}");
        let mut hold = 0;
        while m.phase() == Phase::Hold {
            assert_eq!(m.tick(), Some(target));
            hold += 1;
        }
        assert_eq!(hold, 500);
        assert_eq!(m.phase(), Phase::Return);
        while m.phase() == Phase::Return {
            m.tick();
        }
        assert_eq!(m.commanded(), Some(HOME_POSTURE));
    }

    #[test]
    fn the_head_moves_alone_at_the_speed_fraction_and_bad_poses_are_refused() {
        let mut m = Motion::new();
        assert_eq!(m.move_head([0.05, 0.0]), Err(HeadError::NotStreaming));
        m.start_from(HOME_POSTURE);
        assert_eq!(m.move_head([f32::NAN, 0.0]), Err(HeadError::OutOfLimits));
        assert_eq!(m.move_head([0.0, 0.6]), Err(HeadError::OutOfLimits), "HeadPitch max 0.514872");
        assert_eq!(m.move_head([-2.1, 0.0]), Err(HeadError::OutOfLimits));
        // 0.0873 rad (5 deg) of HeadYaw at 0.1 * 8.26797 rad/s: 0.1056 s, 11 periods.
        let periods = m.move_head([0.0873, -0.05]).unwrap();
        assert_eq!(periods, 11);
        let mut n = 0;
        while m.commanded().unwrap()[..2] != [0.0873, -0.05] {
            let before = m.commanded().unwrap();
            let c = m.tick().unwrap();
            assert!((c[0] - before[0]).abs() <= m.max_step(0) * 1.0001);
            assert_eq!(c[2..], HOME_POSTURE[2..], "the arm stays");
            n += 1;
            assert!(n < 100);
        }
        assert_eq!(n, 11);
        assert_eq!(m.phase(), Phase::Observe);
        assert!(m.reach([0.1, 0.0, 0.5, 0.2, -1.0]));
        assert_eq!(m.move_head([0.0, 0.0]), Err(HeadError::Busy));
    }

    #[test]
    fn goals_outside_limits_are_clamped_and_nan_refused() {
        let mut m = Motion::new();
        m.start_from([9.0, f32::NAN, -9.0, f32::INFINITY, 0.0]);
        let c = m.commanded().unwrap();
        for (j, a) in REACH_JOINTS.iter().zip(c) {
            assert!(j.validate(a).is_ok(), "{j} {a}");
        }
        assert!(m.reach([100.0, -100.0, f32::NAN, 3.0, 1.0]));
        for _ in 0..2000 {
            let c = m.tick().unwrap();
            for (j, a) in REACH_JOINTS.iter().zip(c) {
                assert!(j.validate(a).is_ok(), "{j} {a}");
            }
        }
        assert!(!m.set_speed_fraction(0.0));
        assert!(!m.set_speed_fraction(f32::NAN));
        assert!(!m.set_speed_fraction(1.5));
        assert!(m.set_speed_fraction(1.0));
        assert!(!m.set_hold_ms(MAX_HOLD_MS + 1));
    }
}
