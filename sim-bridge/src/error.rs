//! The errors of the sim-bridge crate, each worded so that the user knows what to do next.

use std::path::PathBuf;

/// The command that fetches MuJoCo and the Control Suite models.
pub const SETUP_COMMAND: &str = "scripts/setup-mujoco";

/// Everything that can go wrong when making or stepping an environment.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("unknown task '{task}'; valid tasks: {}", crate::TASKS.join(", "))]
    UnknownTask { task: String },

    #[error(
        "the Control Suite model files are missing: {} not found; run `{SETUP_COMMAND}` from the \
         repository root (or point {} at a directory holding dm_control's suite/*.xml)",
        path.display(),
        crate::assets::SUITE_DIR_VAR
    )]
    MissingAssets { path: PathBuf },

    #[error(
        "the MuJoCo library (libmujoco.so.3.17.0) cannot be loaded: {detail}; run \
         `{SETUP_COMMAND}` from the repository root, or set LD_LIBRARY_PATH to the directory that \
         holds libmujoco.so.3.17.0 (for example <repository>/.deps/mujoco)"
    )]
    MissingLibrary { detail: String },

    #[error("MuJoCo could not load {}: {message}", path.display())]
    ModelLoad { path: PathBuf, message: String },

    /// A task file that cannot be used: which file, which key, why (one line).
    #[error("{file}: {key}: {message}")]
    TaskFile {
        file: String,
        key: String,
        message: String,
    },

    #[error("{file}: the {what} became {value} at step {step} of the episode ({detail})")]
    NonFinite {
        file: String,
        what: &'static str,
        value: f64,
        step: usize,
        detail: String,
    },

    #[error("action has {got} values, but {task} takes {expected}")]
    ActionWidth {
        task: String,
        expected: usize,
        got: usize,
    },

    #[error("action element {index} is {value}, which is not finite")]
    NonFiniteAction { index: usize, value: f64 },

    #[error(
        "the physics state became invalid: MuJoCo raised {warnings} (dm_control raises \
         PhysicsError here too); reset() before stepping again"
    )]
    PhysicsError { warnings: String },

    /// An external plant that cannot be reached, dies, stops answering or answers wrongly
    /// (one line naming the task file and the cause).
    #[error("{0}")]
    External(String),

    #[error("the episode is over (it lasts {steps} steps); call reset() before stepping again")]
    EpisodeOver { steps: usize },
}
