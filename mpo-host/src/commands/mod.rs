//! The subcommands, from parsed flags to results, one module each; [`config`] resolves a
//! run's configuration (the row's defaults under `--config`, `--set` and flags).

pub mod config;
mod controller;
mod error;
mod eval;
mod export;
mod plot;
mod render;
mod run;
mod tasks;
mod train;
mod trained;

pub use config::{
    Flags, Resolved, defaults, layers_from, print_config, resolve_fresh, resolve_resumed,
    resolve_train,
};
pub use controller::{controller, plant_worker};
pub use error::Error;
pub use eval::{EvalSummary, eval};
pub use export::{ExportSummary, export};
pub use plot::plot;
pub use render::render;
pub use run::run;
pub use tasks::tasks_listing;
pub use train::train;
