//! The mirror world: what stands in for Gazebo, the camera, the mirror and the Nao.
//!
//! - [`body`]: the one geometric model (ellipsoid body, mirror plane, camera) that rendering,
//!   mark placement and kinematics share.
//! - [`kin`]: forward and inverse kinematics, the touch judge.
//! - [`render`], [`looks`], [`marks`]: mirror-view frames of the `red` and `skin` robots, marks;
//!   [`light`]: the room's lamps, exposure, white balance and the camera's auto-exposure;
//!   [`imperfect`]: an ordinary camera's tone curve, white balance, noise, blur and JPEG.
//! - [`dataset`]: datasets in the layout of [`layout`], reach training pairs.
//! - [`actuator`]: one joint's emulated servo (motion, friction, sag, encoder); [`servo`]: the
//!   emulated servo bus, framed or (see [`dynamixel`]) as Dynamixel
//!   X-series servos on Protocol 2.0; [`link`]: baud-paced links and a fault layer;
//!   [`pty`]: a pseudo-terminal for `serialport` hosts.
//! - [`world`]: the world and the firmware on two threads in lock-step simulated time;
//!   [`camera`]: frames of the running world as host-link messages.
//!
//! Examples: `cargo run -p msr-sim --example sim_pictures` (frames under
//! `target/sim-pictures/`), `cargo run -p msr-sim --example sim_bench` (speeds).
#![warn(missing_docs)]

pub mod actuator;
pub mod body;
pub mod camera;
pub mod dataset;
pub mod dynamixel;
pub mod imperfect;
pub mod kin;
pub mod layout;
pub mod light;
pub mod link;
pub mod looks;
pub mod marks;
pub mod pty;
pub mod qemu;
pub mod render;
pub mod servo;
pub mod world;

pub use looks::Robot;

/// One standard normal deviate from two uniform ones (Box-Muller), for the sim's noises and the
/// host's: the same draws from the same generator everywhere.
pub fn standard_normal(rng: &mut impl rand::Rng) -> f64 {
    let (u1, u2): (f64, f64) = (rng.gen_range(f64::MIN_POSITIVE..1.0), rng.gen());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}
