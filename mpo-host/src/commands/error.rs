//! What a command can fail with.

use std::path::PathBuf;

use crate::checkpoint::CheckpointError;
use crate::registry::MissingInstance;
use crate::render::RenderError;
use crate::rows::RowError;
use crate::run::RunError;
use crate::settings::SettingsError;
use crate::train::TrainError;

/// Everything a command can fail with.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Configuration.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The task or its row.
    #[error(transparent)]
    Row(#[from] RowError),
    /// The row's sizes have no instantiation in this build.
    #[error(transparent)]
    MissingInstance(#[from] MissingInstance),
    /// Checkpoint.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// Training.
    #[error(transparent)]
    Train(#[from] TrainError),
    /// Running a policy (`mpo run`).
    #[error(transparent)]
    Run(#[from] RunError),
    /// Rendering a policy (`mpo render`, `mpo train --render-every`).
    #[error(transparent)]
    Render(#[from] RenderError),
    /// The controller process (`mpo controller`).
    #[error("controller: {0}")]
    Controller(String),
    /// A fleet's plant process (`mpo plant-worker`).
    #[error("plant: {0}")]
    Plant(String),
    /// Simulator.
    #[error("simulator: {0}")]
    Sim(#[from] sim_bridge::SimError),
    /// A metrics file that cannot be read or plotted.
    #[error("{0}")]
    Plot(String),
    /// The run directory already holds a run.
    #[error(
        "{0} already holds a checkpoint: continue it with `mpo train --resume {0}`, or choose another --out"
    )]
    OutExists(String),
    /// A file that cannot be written.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}
