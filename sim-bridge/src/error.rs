//! The errors of the sim-bridge crate, each worded so that the user knows what to do next.

use std::path::PathBuf;

/// The command that fetches MuJoCo and the Control Suite models.
pub const SETUP_COMMAND: &str = "scripts/setup-mujoco";

/// The environment variable that overrides the directory holding `cartpole.xml`, ...,
/// `common/materials.xml` (read by `assets::suite_dir`; named here, beside the setup command,
/// because the errors tell the user about both).
pub const SUITE_DIR_VAR: &str = "SIM_BRIDGE_SUITE_DIR";

/// Everything that can go wrong when making or stepping an environment.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("unknown task '{task}'; valid tasks: {}", valid.join(", "))]
    UnknownTask {
        task: String,
        valid: &'static [&'static str],
    },

    #[error(
        "the Control Suite model files are missing: {} not found; run `{SETUP_COMMAND}` from the \
         repository root (or point {} at a directory holding dm_control's suite/*.xml)",
        path.display(),
        SUITE_DIR_VAR
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

    /// A task file's expression gave NaN or an infinity: which file, which key, when.
    #[error("{file}: {key}: became {value} at step {step} of the episode ({detail})")]
    NonFinite {
        file: String,
        key: String,
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

/// `s` with its control characters written as escapes (`\n`, `\t`, `\u{1b}`): a message that
/// quotes a task file's text (which TOML lets hold newlines) stays one line.
pub(crate) fn one_line(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}
