//! The mirror world.
