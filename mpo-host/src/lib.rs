//! Host side of `mpo`: the training loop, evaluation, checkpoints, metrics and plots.
//!
//! The `mpo` binary is [`main_with`] with no instantiations of its own; everything it does is
//! a function of [`commands`], so tests and other programs can call it directly. A Rust
//! program that keeps its robot's learner sizes in its own crate declares them with
//! [`spec!`] and calls [`main_with`] (docs/your-own-robot.md).
#![deny(missing_docs)]

pub mod app;
pub mod caption;
pub mod checkpoint;
pub mod cli;
pub mod collection;
pub mod commands;
pub mod contact_sheet;
pub mod device;
pub mod dormant;
pub mod durable;
pub mod eval;
pub mod fleet;
pub mod link;
pub mod metrics;
pub mod outage_log;
pub mod outputs;
pub mod plant;
pub mod plot;
pub mod policy;
pub mod pool;
pub mod progress;
pub mod registry;
pub mod render;
pub mod rows;
pub mod run;
pub mod settings;
pub mod sizes;
pub mod spec;
pub mod table;
pub mod time_split;
pub mod train;
pub mod trainer;
pub mod training;
pub mod video;
pub mod weight_growth;

pub use app::main_with;

/// The core types [`spec!`] names (so a program using the macro needs no other dependency).
#[doc(hidden)]
pub mod reexport {
    pub use mpo_core::actor::Actor;
    pub use mpo_core::agent::{Agent, AgentOf};
    pub use mpo_core::critic::Critic;
    pub use mpo_core::residual::{ResidualActor, ResidualCritic};
}
