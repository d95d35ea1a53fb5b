//! The task table: one row per (task, network variant), mapping the name to a concrete,
//! monomorphised learner type and to the run's default schedule and hyperparameters.
//!
//! Sizes are const generics of the learner (observation, action, hidden widths, batch `B`,
//! E-step samples `M`, next-action samples `N`, replay capacity), so they are fixed here at
//! compile time and cannot be changed by configuration; everything else in a row is a
//! default that `--config` and flags override. Each row costs one instantiation of the
//! learner, so the table holds the tasks we train rather than every Control Suite task.

use serde::{Deserialize, Serialize};

use crate::settings::{MpoSettings, Schedule};

/// A row's compile-time sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sizes {
    /// Observation size.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// First hidden width (actor and critic).
    pub h1: usize,
    /// Second hidden width.
    pub h2: usize,
    /// Batch size `B`.
    pub batch: usize,
    /// E-step action samples per state `M`.
    pub m: usize,
    /// Next-action samples per next state `N` (TD targets).
    pub n: usize,
    /// Replay capacity in transitions.
    pub replay_capacity: usize,
}

/// One row of the table.
#[derive(Debug)]
pub struct Row {
    /// Task name.
    pub task: &'static str,
    /// Network variant.
    pub net: &'static str,
    /// Sizes (the learner's type).
    pub sizes: Sizes,
    /// Default total environment steps.
    pub steps: u64,
    /// Default schedule.
    pub schedule: Schedule,
    /// Default hyperparameters.
    pub mpo: MpoSettings,
}

/// Called with the row's concrete sizes as const generics.
pub trait RowVisitor {
    /// Result.
    type Out;
    /// Runs with the row's types (`TRI = ACT (ACT + 1) / 2`, `CAP` replay capacity).
    fn visit<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const H1: usize,
        const H2: usize,
        const B: usize,
        const M: usize,
        const N: usize,
        const CAP: usize,
    >(
        self,
        row: &'static Row,
    ) -> Self::Out;
}

/// A task or network variant without a row.
#[derive(Debug, thiserror::Error)]
#[error("unknown task `{task}` (net `{net}`); the trainable tasks are: {valid}")]
pub struct UnknownTask {
    /// Requested task.
    pub task: String,
    /// Requested variant.
    pub net: String,
    /// `task (net)` for every row.
    pub valid: String,
}

macro_rules! table {
    ($( $task:literal / $net:literal : [$obs:literal, $act:literal, $tri:literal, $h1:literal, $h2:literal,
         $b:literal, $m:literal, $n:literal, $cap:literal], steps $steps:expr, $sched:expr, $mpo:expr; )*) => {
        /// Every row, in table order.
        pub static ROWS: &[Row] = &[$(
            Row {
                task: $task,
                net: $net,
                sizes: Sizes { obs: $obs, act: $act, h1: $h1, h2: $h2, batch: $b, m: $m, n: $n, replay_capacity: $cap },
                steps: $steps,
                schedule: $sched,
                mpo: $mpo,
            },
        )*];

        /// Calls `v` with the concrete types of the row `task`/`net`.
        pub fn visit<V: RowVisitor>(task: &str, net: &str, v: V) -> Result<V::Out, UnknownTask> {
            let mut i = 0usize;
            $(
                if task == $task && net == $net {
                    const { assert!($tri == $act * ($act + 1) / 2) };
                    return Ok(v.visit::<$obs, $act, $tri, $h1, $h2, $b, $m, $n, $cap>(&ROWS[i]));
                }
                i += 1;
            )*
            let _ = i;
            Err(UnknownTask {
                task: task.to_string(),
                net: net.to_string(),
                valid: ROWS.iter().map(|r| format!("{} (net {})", r.task, r.net)).collect::<Vec<_>>().join(", "),
            })
        }
    };
}

/// The report's hyperparameters with the changes that make cartpole learn within budget
/// (docs/training.md logs the tuning runs).
const CARTPOLE_MPO: MpoSettings = MpoSettings {
    eps_mean: 0.01,
    actor_clip: 40.0,
    ..MpoSettings::REPORT
};

const CARTPOLE_SCHEDULE: Schedule = Schedule {
    warmup_steps: 2_000,
    update_interval: 2,
    updates_per_interval: 1,
    eval_interval: 5_000,
    eval_episodes: 10,
    action_penalty: 1.0,
};

/// Acme-like settings for the larger tasks.
const HOPPER_MPO: MpoSettings = MpoSettings {
    eps_mean: 0.01,
    actor_clip: 40.0,
    ..MpoSettings::REPORT
};

const LONG_SCHEDULE: Schedule = Schedule {
    warmup_steps: 10_000,
    update_interval: 4,
    updates_per_interval: 1,
    eval_interval: 20_000,
    eval_episodes: 10,
    action_penalty: 1.0,
};

table! {
    "cartpole-balance" / "default": [5, 1, 1, 64, 64, 128, 20, 20, 100_000], steps 100_000, CARTPOLE_SCHEDULE, CARTPOLE_MPO;
    "cartpole-balance" / "tiny": [5, 1, 1, 32, 32, 64, 10, 10, 50_000], steps 4_000,
        Schedule { warmup_steps: 500, update_interval: 4, updates_per_interval: 1, eval_interval: 1_000, eval_episodes: 3, action_penalty: 1.0 },
        CARTPOLE_MPO;
    "acrobot-swingup" / "default": [6, 1, 1, 128, 128, 128, 20, 20, 1_000_000], steps 1_000_000, LONG_SCHEDULE, HOPPER_MPO;
    "hopper-stand" / "default": [15, 4, 10, 128, 128, 128, 20, 20, 1_000_000], steps 1_000_000, LONG_SCHEDULE, HOPPER_MPO;
    "hopper-hop" / "default": [15, 4, 10, 128, 128, 128, 20, 20, 1_000_000], steps 1_000_000, LONG_SCHEDULE, HOPPER_MPO;
}

/// The default network variant.
pub const DEFAULT_NET: &str = "default";
/// The default task.
pub const DEFAULT_TASK: &str = "cartpole-balance";

/// The row of `task`/`net`.
pub fn row(task: &str, net: &str) -> Result<&'static Row, UnknownTask> {
    ROWS.iter()
        .find(|r| r.task == task && r.net == net)
        .ok_or_else(|| UnknownTask {
            task: task.to_string(),
            net: net.to_string(),
            valid: ROWS
                .iter()
                .map(|r| format!("{} (net {})", r.task, r.net))
                .collect::<Vec<_>>()
                .join(", "),
        })
}
