//! Host side of the mirror mark test: the `msr` command and the library behind it.
//!
//! `cmd` holds the command shells (arguments, `run`, printing); the other modules are the library
//! they call, arranged by role.
//!
//! The rule of the layers: the library never names `cmd`. Flag names, usage errors and exit codes
//! live in `cmd/`; the library takes typed configurations and returns typed errors (e.g.
//! [`train::ConfigError`], which `cmd` words with the flags' names) and values that print
//! themselves (the episode [`episode::Summary`] is `Display`). The imports between the files run
//! one way, with no circle. `cargo test -p xtask` checks both from the source text.
#![warn(missing_docs)]
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
pub mod describe;
pub mod flash_file;
pub mod bench;
pub mod report;
pub mod demo;
pub mod rosbag;
pub mod live;
pub mod learn_reach;
