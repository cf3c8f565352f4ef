//! The mirror world: what stands in for Gazebo, the camera, the mirror and the Nao.
//!
//! - [`body`]: the one geometric model (ellipsoid body, mirror plane, camera) that rendering,
//!   mark placement and kinematics share.
//! - [`kin`]: forward and inverse kinematics, the touch judge.
//! - [`render`], [`looks`], [`marks`]: mirror-view frames of the `red` and `skin` robots, marks.
//! - [`dataset`]: datasets in the layout of [`layout`], reach training pairs.
pub mod body;
pub mod dataset;
pub mod kin;
pub mod layout;
pub mod link;
pub mod looks;
pub mod marks;
pub mod pty;
pub mod qemu;
pub mod render;
pub mod servo;
pub mod world;

pub use looks::Robot;
