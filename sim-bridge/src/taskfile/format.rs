//! The keys of a task file, as read from TOML (documented for users in
//! `docs/task-files.md`; every key here is described there).

use std::collections::BTreeMap;

use serde::Deserialize;

/// A task file as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct TaskToml {
    /// The task's name (default: the file's stem).
    pub name: Option<String>,
    /// One line for `mpo tasks`.
    pub description: Option<String>,
    /// `mujoco` (the default: the model below, stepped here) or `external` (another program
    /// steps the plant and speaks the link; `[external]` gives its sizes).
    #[serde(default)]
    pub plant: PlantKind,
    /// The MJCF model: a path relative to this file, `suite:<file>` (the Control Suite's
    /// models) or `gymnasium:<file>` (Gymnasium's MuJoCo models).
    pub model: Option<String>,
    /// `dm_control` (the default) or `gymnasium`: which library's call sequence resets and
    /// steps the physics.
    #[serde(default)]
    pub convention: Convention,
    /// Physics steps per control step (dm_control's `n_sub_steps`, Gymnasium's
    /// `frame_skip`).
    pub substeps: Option<usize>,
    /// Seconds per control step, instead of `substeps` (a multiple of the model's timestep).
    pub control_timestep: Option<f64>,
    /// Seconds per episode (dm_control's `time_limit`).
    pub time_limit: Option<f64>,
    /// Control steps per episode, instead of `time_limit` (Gymnasium's `max_episode_steps`).
    pub episode_steps: Option<usize>,
    /// The actuators the action drives, in action order (default: all, in model order).
    pub actuators: Option<Vec<String>>,
    /// Named quantities, usable in every expression of the file.
    #[serde(default)]
    pub define: BTreeMap<String, String>,
    /// The observation: named parts, concatenated in this order.
    #[serde(default)]
    pub observation: Vec<ObservationPart>,
    /// The reward of a step, from the state after it.
    pub reward: Option<String>,
    /// When true (non-zero) after a step, the episode ends in a terminal state (discount 0).
    pub terminate: Option<String>,
    /// Statements that write the initial state, in order, after the physics is reset.
    #[serde(default)]
    pub init: Vec<String>,
    /// The sizes of an external plant.
    pub external: Option<External>,
    /// Learner rows (read by the `mpo` command, not by the simulator).
    pub rows: Option<toml::Table>,
}

/// Who steps the plant.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum PlantKind {
    /// MuJoCo, in this process.
    #[default]
    Mujoco,
    /// Another program, through the link.
    External,
}

/// Which library's call sequence resets and steps the physics.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Convention {
    /// dm_control's `Physics`: forward passes without actuation at reset, the legacy step
    /// (`mj_step2`, `mj_step` x (n - 1), `mj_step1`).
    #[default]
    DmControl,
    /// Gymnasium's `MujocoEnv`: `mj_forward` after the initial state, `mj_step` x n then
    /// `mj_rnePostConstraint`.
    Gymnasium,
}

/// One named part of the observation.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ObservationPart {
    /// Its name (dm_control's observation key).
    pub name: String,
    /// Its value: an expression.
    pub value: String,
}

/// The sizes of an external plant.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct External {
    /// Observation size.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// Per action dimension (or one for all): the plant's lower action bound.
    pub action_low: Vec<f64>,
    /// Per action dimension (or one for all): the upper bound.
    pub action_high: Vec<f64>,
    /// The program that serves the plant and its arguments, run from the task file's folder
    /// (a relative program path with a `/` is relative to it) with the run id in
    /// `MPO_PLANT_RUN`; without it the plant program is started by hand and attached to
    /// (`mpo train --attach-plant RUN_ID`). Documented in `docs/external-plant.md`.
    pub command: Option<Vec<String>>,
    /// Seconds the plant may take to answer one reset or step (default 10).
    pub timeout: Option<f64>,
    /// Seconds the plant may take to answer the handshake, its program's start-up included
    /// (default 60).
    pub connect_timeout: Option<f64>,
}
