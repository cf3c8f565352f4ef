//! The sim's robot as a [`Body`]: its renderer (the arm as it is, not as drawn), its servos at
//! the speeds below, and its sense of touch ([`msr_sim::kin::contact_of`]).
use super::{Approach, Body};
use anyhow::{bail, Result};
use image::RgbImage;
use msr_sim::body::BodyPose;
use msr_sim::kin::{self, ArmError, LeftArm, Reach};
use msr_sim::looks::Robot;
use msr_sim::render::{Renderer, Variation};

/// Joint speed of a move, radians a second (the largest joint's change sets the time).
pub const MOVE_SPEED: f64 = 1.0;
/// Joint speed while feeling for the face, radians a second.
pub const APPROACH_SPEED: f64 = 0.25;
/// Largest joint step between two checks of touch, radians.
pub const APPROACH_STEP: f64 = 0.002;
/// Time the servos settle after a move before a frame, seconds.
pub const SETTLE_S: f64 = 0.3;
/// One camera frame, seconds.
pub const FRAME_S: f64 = 1.0 / 30.0;

/// The sim's robot.
pub struct SimBody {
    renderer: Renderer,
    arm: ArmError,
    posture: Reach,
    noise_seed: Option<u64>,
    frames: u64,
    seconds: f64,
    contacts: Vec<kin::Contact>,
}

impl SimBody {
    /// `robot` with its left arm `arm`, standing at home; camera noise drawn from `noise_seed`
    /// (`None`: none).
    pub fn new(robot: Robot, arm: ArmError, noise_seed: Option<u64>) -> SimBody {
        SimBody { renderer: Renderer::new(robot), arm, posture: kin::home(), noise_seed, frames: 0, seconds: 0.0, contacts: Vec::new() }
    }
}

impl SimBody {
    /// What met the head at each touch so far (the sim knows; the robot only felt a touch).
    pub fn contacts(&self) -> &[kin::Contact] {
        &self.contacts
    }
}

fn inside_limits(q: &Reach) -> bool {
    q.iter().zip(kin::reach_limits()).all(|(v, l)| v.is_finite() && *v >= l[0] && *v <= l[1])
}

impl SimBody {
    /// Moves towards `to` at `speed`, checking for a touch every [`APPROACH_STEP`], and stops
    /// at the last posture before one.
    fn go(&mut self, to: Reach, speed: f64) -> Result<Approach> {
        if !inside_limits(&to) {
            bail!("posture {to:?} is outside the joint limits");
        }
        let from = self.posture;
        let span = from.iter().zip(&to).map(|(a, b)| (b - a).abs()).fold(0.0, f64::max);
        let steps = (span / APPROACH_STEP).ceil().max(1.0) as usize;
        let at = |k: usize| -> Reach { std::array::from_fn(|i| from[i] + k as f64 / steps as f64 * (to[i] - from[i])) };
        for k in 1..=steps {
            if let Some(c) = kin::contact_of(&at(k), &self.arm) {
                self.seconds += span * (k - 1) as f64 / steps as f64 / speed + SETTLE_S;
                self.posture = at(k - 1);
                self.contacts.push(c);
                return Ok(Approach { posture: self.posture, touched: true });
            }
        }
        self.seconds += span / speed + SETTLE_S;
        self.posture = to;
        Ok(Approach { posture: to, touched: false })
    }
}

impl Body for SimBody {
    fn approach(&mut self, to: Reach) -> Result<Approach> {
        self.go(to, APPROACH_SPEED)
    }

    fn move_to(&mut self, to: Reach) -> Result<Approach> {
        self.go(to, MOVE_SPEED)
    }

    fn frame(&mut self) -> Result<RgbImage> {
        let q = self.posture;
        let mut pose = BodyPose::head(q[0], q[1]);
        pose.left_arm = LeftArm::from_reach(&q);
        pose.arm_error = self.arm;
        let var = Variation { noise_seed: self.noise_seed.map(|s| s.wrapping_add(self.frames)), ..Variation::CLEAN };
        self.frames += 1;
        self.seconds += FRAME_S;
        Ok(self.renderer.render(&pose, None, &var).rgb)
    }

    fn posture(&self) -> Reach {
        self.posture
    }

    fn robot_seconds(&self) -> f64 {
        self.seconds
    }
}
