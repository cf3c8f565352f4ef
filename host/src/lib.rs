//! Host side of the mirror mark test: the `msr` command and the library behind it.
//!
//! One module per command or stage; `cli` only parses arguments and dispatches.
pub mod cli;
pub mod predictor;
pub mod crop;
pub mod data;
pub mod metrics;
pub mod pipeline;
pub mod fixed;
pub mod dataset;
pub mod train;
pub mod train_reach;
pub mod quantize;
pub mod import;
pub mod detect;
pub mod blobs;
pub mod eval;
pub mod bench;
pub mod mirror_test;
pub mod run_board;
pub mod demo;
pub mod models;
pub mod calibrate;
pub mod episode;
pub mod episode_qemu;
pub mod model_blob;
pub mod report;
pub mod sim_board;
