//! One joint's emulated servo: first-order motion toward its goal within the joint's limits and
//! velocity, sag under load, static friction, and a 12-bit encoder with optional noise.
use msr_shared::joints::Joint;

/// Encoder counts per turn.
pub const ENCODER_COUNTS: u32 = 4096;

#[derive(Clone, Copy, Debug, PartialEq)]
/// Settings of the emulated servos and their bus.
pub struct ServoConfig {
    /// Time constant of the first-order response, seconds.
    pub time_constant_s: f64,
    /// Fraction of the URDF velocity limit the servo can reach.
    pub velocity_fraction: f64,
    /// How often the bus reports every joint's state, microseconds.
    pub report_period_us: u64,
    /// How long without a new target before a servo holds where it is, microseconds.
    pub hold_timeout_us: u64,
    /// Integration step.
    pub step_us: u64,
    /// Encoder noise, counts RMS: each integration step draws Gaussian noise of this spread
    /// onto the position before the encoder rounds it, so a servo holding still reads the
    /// counts around its position by turns (most often the two nearest), as a real one can
    /// (vibration, the holding loop's dither, electrical noise). 0: none.
    pub encoder_noise: f64,
    /// Seed of the encoder noise's draws.
    pub noise_seed: u64,
    /// Counts by which a pitch servo (the head's and the shoulders') holds off its goal, as a
    /// real one under the load of what it carries does when its holding loop has no integral
    /// term (a Dynamixel's default gains): gravity wins that many counts back. 0: none.
    pub sag: f64,
    /// Static friction, counts: the drive, proportional to the error, cannot move the joint
    /// once it is within this many counts of where it holds, so a servo stops that far short
    /// of a goal on the side it came from (a Dynamixel with no integral term stops a count or
    /// two short under friction alone). Every joint. 0: none.
    pub dead_band: f64,
}

impl Default for ServoConfig {
    fn default() -> Self {
        ServoConfig {
            time_constant_s: 0.03,
            velocity_fraction: 1.0,
            report_period_us: 10_000,
            hold_timeout_us: 100_000,
            step_us: 1_000,
            encoder_noise: 0.0,
            noise_seed: 0,
            sag: 0.0,
            dead_band: 0.0,
        }
    }
}

/// One joint's servo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Servo {
    /// The joint this servo drives.
    pub joint: Joint,
    pub(crate) min: f64,
    pub(crate) max: f64,
    max_velocity: f64,
    /// Where the servo holds against its goal, radians ([`ServoConfig::sag`]).
    sag: f64,
    /// [`ServoConfig::dead_band`], radians.
    dead_band: f64,
    /// True (unquantised) position.
    pub position: f64,
    /// The goal, radians, within the joint's limits.
    pub target: f64,
    /// Whether the servo drives its joint (false: limp).
    pub stiff: bool,
    /// Fault flags (`msr_shared::msg::fault`).
    pub faults: u8,
    /// Velocity over the last integration step (rad/s).
    pub velocity: f64,
    /// The encoder noise drawn for this integration step, counts
    /// ([`ServoConfig::encoder_noise`]).
    pub noise: f64,
    pub(crate) last_target_us: Option<u64>,
}

impl Servo {
    pub(crate) fn new(joint: Joint, position: f64, cfg: &ServoConfig) -> Option<Servo> {
        let l = joint.limits()?;
        let (min, max) = (l.min as f64, l.max as f64);
        // A start angle that is not finite starts at 0 (clamped), never as NaN.
        let position = if position.is_finite() { position } else { 0.0 }.clamp(min, max);
        Some(Servo {
            joint,
            min,
            max,
            max_velocity: l.max_velocity as f64 * cfg.velocity_fraction,
            sag: if matches!(joint, Joint::HeadPitch | Joint::LShoulderPitch | Joint::RShoulderPitch) {
                cfg.sag * COUNT_RAD
            } else {
                0.0
            },
            dead_band: cfg.dead_band * COUNT_RAD,
            position,
            target: position,
            stiff: true,
            faults: 0,
            velocity: 0.0,
            noise: 0.0,
            last_target_us: None,
        })
    }

    /// What the encoder reads.
    pub fn measured(&self) -> f64 {
        quantise(self.position + self.noise * COUNT_RAD)
    }

    /// A new goal, kept inside the joint's limits (the caller has checked it).
    pub(crate) fn set_target(&mut self, a: f64) {
        if a.is_finite() {
            self.target = a.clamp(self.min, self.max);
        }
    }

    /// Moves the servo by one integration step of `dt` seconds (time constant `tau`).
    pub(crate) fn step(&mut self, dt: f64, tau: f64) {
        if !self.stiff {
            self.velocity = 0.0;
            return;
        }
        let held = (self.target + self.sag).clamp(self.min, self.max);
        if (held - self.position).abs() <= self.dead_band {
            self.velocity = 0.0;
            return;
        }
        let v = ((held - self.position) / tau).clamp(-self.max_velocity, self.max_velocity);
        let next = self.position + v * dt;
        // First order never overshoots; the clamp keeps a limit-hugging target inside.
        let next = next.clamp(self.min, self.max);
        self.velocity = (next - self.position) / dt;
        self.position = next;
    }
}

/// One encoder count, radians.
pub const COUNT_RAD: f64 = std::f64::consts::TAU / ENCODER_COUNTS as f64;

/// Rounds an angle to the encoder's resolution.
pub fn quantise(angle: f64) -> f64 {
    (angle / COUNT_RAD).round() * COUNT_RAD
}
