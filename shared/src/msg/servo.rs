//! The servo bus's messages: joint targets from the board, joint states from the servos.
use crate::joints::Joint;
use serde::{Deserialize, Serialize};

/// Most joints in one servo-bus message: head and both arms.
pub const MAX_BUS_JOINTS: usize = 14;

/// One joint's commanded position.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointTarget {
    /// Which joint.
    pub joint: Joint,
    /// Radians; the sender guarantees it is inside the joint's limits.
    pub position: f32,
}

/// Fault flags a servo reports, as bits of [`JointState::faults`].
pub mod fault {
    /// A target outside the joint limits arrived and was refused.
    pub const LIMIT: u8 = 1 << 0;
    /// The servo is not following its target.
    pub const STALL: u8 = 1 << 1;
    /// The servo is overheating.
    pub const OVERHEAT: u8 = 1 << 2;
    /// No target for the servo's hold timeout: holding position.
    pub const TIMEOUT: u8 = 1 << 3;
}

/// One joint's reported state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Which joint.
    pub joint: Joint,
    /// Measured position in radians (encoder-quantised).
    pub position: f32,
    /// Whether the servo's torque is on (it holds its position).
    pub stiffness: bool,
    /// Fault bits, see [`fault`].
    pub faults: u8,
}

/// Board to servos.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum BoardToServo {
    /// Position targets, sent every control period while moving or holding.
    Targets {
        /// Board time in ms when the targets were sent (wraps after about 49 days).
        time_ms: u32,
        /// One target per joint to move; at most [`MAX_BUS_JOINTS`].
        targets: heapless::Vec<JointTarget, MAX_BUS_JOINTS>,
    },
    /// Asks every servo on the bus for its state.
    StateRequest,
    /// Turns every servo's torque on (`on: true`: they hold where they are) or off.
    #[allow(missing_docs)]
    Stiffness { on: bool },
}

/// Servos to board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ServoToBoard {
    /// Every joint's state, sent periodically and in answer to [`BoardToServo::StateRequest`].
    States {
        /// Servo time in ms when the states were measured.
        time_ms: u32,
        /// One state per joint on the bus; at most [`MAX_BUS_JOINTS`].
        states: heapless::Vec<JointState, MAX_BUS_JOINTS>,
    },
}
