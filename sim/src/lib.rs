//! The mirror world: what stands in for Gazebo, the camera, the mirror and the Nao.
pub mod layout;
pub mod qemu;
