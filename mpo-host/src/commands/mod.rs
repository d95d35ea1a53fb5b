//! The subcommands, from parsed flags to results, one module each; [`config`] resolves a
//! run's configuration (the row's defaults under `--config`, `--set` and flags).

pub mod config;
mod controller;
mod eval;
mod export;
mod plot;
mod render;
mod run;
mod tasks;
mod train;

use std::path::{Path, PathBuf};

use sim_bridge::TaskDef;

use crate::checkpoint::{self, CheckpointError, Verified};
use crate::policy::Policy;
use crate::registry::MissingInstance;
use crate::render::RenderError;
use crate::rows::RowError;
use crate::run::RunError;
use crate::settings::SettingsError;
use crate::train::TrainError;

pub use config::{
    Flags, Resolved, defaults, layers_from, print_config, resolve_fresh, resolve_resumed,
    resolve_train,
};
pub use controller::controller;
pub use eval::{EvalSummary, eval};
pub use export::{ExportSummary, export};
pub use plot::plot;
pub use render::render;
pub use run::run;
pub use tasks::tasks_listing;
pub use train::train;

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

/// [`checkpoint::open`], with a note on stderr when a crash (or a corrupt `checkpoint/`) made
/// it choose `checkpoint.tmp/` or `checkpoint.old/`.
fn open_checkpoint(dir: &Path) -> Result<Verified, Error> {
    let v = checkpoint::open(dir)?;
    if let Some(note) = &v.fallback {
        eprintln!("note: {note}");
    }
    Ok(v)
}

/// A checkpoint's policy, with the task it was trained on (a task file must still hash as
/// it did).
struct Trained {
    v: Verified,
    task: TaskDef,
    policy: Box<dyn Policy>,
}

/// Opens the checkpoint in `dir` and loads its online policy (the actor only).
fn trained(dir: &Path) -> Result<Trained, Error> {
    let v = open_checkpoint(dir)?;
    let task = crate::rows::task_of_checkpoint(&v.meta, &v.dir)?;
    let instance = crate::registry::find(&v.meta.sizes)?;
    let policy = (instance.policy)(&v)?;
    Ok(Trained { v, task, policy })
}
