//! The control-table items this project uses, at the addresses and sizes of the X series
//! (XM430-W350, XM430-W210, XL430-W250 share them), from the ROBOTIS e-Manual.

/// One control-table item: address and size in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Item {
    /// Control-table address of the item's first byte.
    pub addr: u16,
    /// Size in bytes (1, 2 or 4), little-endian on the wire.
    pub len: u16,
}

const fn item(addr: u16, len: u16) -> Item {
    Item { addr, len }
}

// EEPROM area: writable only while torque is off.
/// Model number, read-only (e.g. [`XM430_W350`]); a Ping's status carries it too.
pub const MODEL_NUMBER: Item = item(0, 2);
/// Firmware version of the servo, read-only.
pub const FIRMWARE_VERSION: Item = item(6, 1);
/// The servo's bus ID, 0..=252 (factory 1).
pub const ID: Item = item(7, 1);
/// Baud rate code: 0 9600, 1 57600 (factory), 2 115200, 3 1M, 4 2M, 5 3M, 6 4M, 7 4.5M bps.
pub const BAUD_RATE: Item = item(8, 1);
/// Delay before a status packet, in units of 2 us (default 250: 500 us).
pub const RETURN_DELAY_TIME: Item = item(9, 1);
/// Control mode: 3 position control (factory), 4 extended position, 0 current, 1 velocity, 16 PWM.
pub const OPERATING_MODE: Item = item(11, 1);
/// Largest Goal Position accepted in position control mode, counts (0..=4095).
pub const MAX_POSITION_LIMIT: Item = item(48, 4);
/// Smallest Goal Position accepted in position control mode, counts (0..=4095).
pub const MIN_POSITION_LIMIT: Item = item(52, 4);
// RAM area.
/// 1 turns the motor's torque on (and locks the EEPROM area), 0 off.
pub const TORQUE_ENABLE: Item = item(64, 1);
/// 1 lights the servo's LED, 0 turns it off.
pub const LED: Item = item(65, 1);
/// 0: answers Ping only, 1: Ping and Read, 2: all instructions (default).
pub const STATUS_RETURN_LEVEL: Item = item(68, 1);
/// Why the servo shut down, as bits (see [`hw`]); the Alert bit of a status's error byte says one is set.
pub const HARDWARE_ERROR_STATUS: Item = item(70, 1);
/// Target position, counts (signed 32-bit; within the position limits in position control mode).
pub const GOAL_POSITION: Item = item(116, 4);
/// 1 while the servo is moving, 0 when it has stopped.
pub const MOVING: Item = item(122, 1);
/// Measured speed, signed, in units of 0.229 rpm.
pub const PRESENT_VELOCITY: Item = item(128, 4);
/// Measured position, counts (signed 32-bit).
pub const PRESENT_POSITION: Item = item(132, 4);

/// Model numbers (Ping answers them).
pub const XM430_W350: u16 = 1020;
/// XM430-W210's model number.
pub const XM430_W210: u16 = 1030;
/// XL430-W250's model number.
pub const XL430_W250: u16 = 1060;

/// Return Delay Time's unit in microseconds.
pub const RETURN_DELAY_UNIT_US: u32 = 2;
/// Its factory value (250: 500 us).
pub const DEFAULT_RETURN_DELAY: u8 = 250;

/// Bits of Hardware Error Status.
pub mod hw {
    /// Input voltage outside the operating range.
    pub const INPUT_VOLTAGE: u8 = 1 << 0;
    /// Internal temperature above the Temperature Limit.
    pub const OVERHEATING: u8 = 1 << 2;
    /// The motor encoder is not working.
    pub const MOTOR_ENCODER: u8 = 1 << 3;
    /// An electrical shock on the circuit, or not enough power.
    pub const ELECTRICAL_SHOCK: u8 = 1 << 4;
    /// A persistent load beyond the maximum output.
    pub const OVERLOAD: u8 = 1 << 5;
}

/// Encoder counts per turn of the X series (Position: 0..=4095 over 360 degrees).
pub const COUNTS_PER_TURN: u32 = 4096;
