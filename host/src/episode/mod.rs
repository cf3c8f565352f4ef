//! Mirror-test episodes: the sim world on one thread, the firmware on the other, the emulated host
//! link and servo bus between them, and a scenario that plays the PC and judges.
//!
//! One trial, in simulated time (each trial is a fresh world and a fresh board, so trials are
//! independent and run in parallel):
//! - 0 s: the robot sits at home (the observe posture); the PC streams camera frames every
//!   [`EpisodeConfig::frame_period_us`]: rendered at the posture the servos hold *now*, cropped
//!   with the model's face template (the host crop), sent over the host link.
//! - [`EpisodeConfig::mark_at_us`]: a mark appears on the face (random kind, colour and place,
//!   redrawn while it is too faint to see, as the datasets do), except in a share of trials.
//! - The board reads the head angles from the servos, detects, confirms and reaches; the PC sees
//!   the confirmed detection (the reach starts) on the host link.
//! - The judge samples the true joint angles every 10 ms. Once all five reach joints are within
//!   [`HELD_TOLERANCE_RAD`] of the reach target the reach is held; after
//!   [`EpisodeConfig::judge_hold_us`] of holding, the trial is judged by forward kinematics
//!   (`msr_sim::kin::judge_touch`: every held sample within 20 mm of the mark's 3-D point) and
//!   ends. The rest of the 5 s hold would only repeat the same posture.
//! - A reach while no mark is on the face is a false reach. A trial without a reach ends
//!   [`EpisodeConfig::watch_us`] after the mark time.
//!
//! While the arm is up the board pauses detection, so the PC sends frames only every
//! [`ARM_UP_FRAME_PERIOD_US`] then, enough to keep the face watchdog (500 ms) fed.
mod config;
pub mod qemu;
mod runners;
mod scenario;
pub mod scene;
pub mod sim_board;
mod summary;

pub use config::{arm_of, Backend, EpisodeConfig, FaultLinks, LightSpan, ServoBus};
pub use msr_firmware::model::HeapStore;
pub use runners::{
    inproc_board, run_inproc, run_one_board, run_trial_inproc, trial_seed, InprocBoard, Tee,
};
pub use scenario::{
    run_trial_with, Camera, ARM_UP_FRAME_PERIOD_US, FACE_ACK_TIMEOUT_US, FACE_MAX_AGE_PERIODS,
    HELD_TOLERANCE_RAD, SAMPLE_US,
};
pub use scene::Scene;
pub use summary::{
    add_board_counters, add_gate_joints, end_with_status, median, summarise, GateRecord, Summary,
    Trial,
};
