//! Host side of `mpo`: the training loop, evaluation, checkpoints, metrics and plots.
//!
//! The `mpo` binary only parses flags and maps errors to exit codes; everything it does is a
//! function of [`commands`], so tests and other programs can call it directly.
#![deny(missing_docs)]

pub mod caption;
pub mod checkpoint;
pub mod cli;
pub mod commands;
pub mod contact_sheet;
pub mod device;
pub mod eval;
pub mod link;
pub mod metrics;
pub mod outage_log;
pub mod plot;
pub mod pool;
pub mod render;
pub mod run;
pub mod settings;
pub mod tasks;
pub mod train;
pub mod video;
