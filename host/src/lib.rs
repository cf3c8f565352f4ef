//! Host side of the mirror mark test: the `msr` command and the library behind it.
//!
//! `cmd` holds the command shells (arguments, `run`, printing); the other modules are the library
//! they call, arranged by role.
pub mod cmd;
pub mod fsio;
pub mod data;
pub mod models;
pub mod train;
pub mod quant;
pub mod detect;
pub mod eval;
pub mod episode;
pub mod camera;
pub mod record;
pub mod session;
pub mod flash_file;
pub mod bench;
pub mod report;
pub mod demo;
pub mod rosbag;
pub mod live;
