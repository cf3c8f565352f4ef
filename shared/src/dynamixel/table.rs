//! The control-table items this project uses, at the addresses and sizes of the X series
//! (XM430-W350, XM430-W210, XL430-W250 share them), from the ROBOTIS e-Manual.

/// One control-table item: address and size in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Item {
    pub addr: u16,
    pub len: u16,
}

const fn item(addr: u16, len: u16) -> Item {
    Item { addr, len }
}

// EEPROM area: writable only while torque is off.
pub const MODEL_NUMBER: Item = item(0, 2);
pub const FIRMWARE_VERSION: Item = item(6, 1);
pub const ID: Item = item(7, 1);
pub const BAUD_RATE: Item = item(8, 1);
/// Delay before a status packet, in units of 2 us (default 250: 500 us).
pub const RETURN_DELAY_TIME: Item = item(9, 1);
pub const OPERATING_MODE: Item = item(11, 1);
pub const MAX_POSITION_LIMIT: Item = item(48, 4);
pub const MIN_POSITION_LIMIT: Item = item(52, 4);
// RAM area.
pub const TORQUE_ENABLE: Item = item(64, 1);
pub const LED: Item = item(65, 1);
/// 0: answers Ping only, 1: Ping and Read, 2: all instructions (default).
pub const STATUS_RETURN_LEVEL: Item = item(68, 1);
pub const HARDWARE_ERROR_STATUS: Item = item(70, 1);
pub const GOAL_POSITION: Item = item(116, 4);
pub const MOVING: Item = item(122, 1);
pub const PRESENT_VELOCITY: Item = item(128, 4);
pub const PRESENT_POSITION: Item = item(132, 4);

/// Model numbers (Ping answers them).
pub const XM430_W350: u16 = 1020;
pub const XM430_W210: u16 = 1030;
pub const XL430_W250: u16 = 1060;

/// Return Delay Time's unit in microseconds.
pub const RETURN_DELAY_UNIT_US: u32 = 2;
/// Its factory value (250: 500 us).
pub const DEFAULT_RETURN_DELAY: u8 = 250;

/// Bits of Hardware Error Status.
pub mod hw {
    pub const INPUT_VOLTAGE: u8 = 1 << 0;
    pub const OVERHEATING: u8 = 1 << 2;
    pub const MOTOR_ENCODER: u8 = 1 << 3;
    pub const ELECTRICAL_SHOCK: u8 = 1 << 4;
    pub const OVERLOAD: u8 = 1 << 5;
}

/// Encoder counts per turn of the X series (Position: 0..=4095 over 360 degrees).
pub const COUNTS_PER_TURN: u32 = 4096;
