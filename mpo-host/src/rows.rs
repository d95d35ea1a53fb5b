//! Rows: a task, a network variant, the learner's sizes and the run's default settings.
//!
//! A built-in task's rows are the table's ([`crate::table`]). A task file's rows are its
//! `[rows.<net>]` tables, each any subset of the keys below over the defaults chosen from the
//! task's sizes ([`default_row`]); a file without `[rows]` has the one row `default`:
//!
//! ```toml
//! [rows.default]
//! actor = [256, 256]      # the policy's hidden widths
//! critic = [256, 256]     # the critic's
//! batch = 256             # rows per update ...
//! chunks = 4              # ... split into equal chunks (one thread's work each; default 4,
//!                         #     else 2, else 1, whichever divides the batch)
//! seq = 8                 # longest replayed sequence (Retrace's n_step limit)
//! m = 20                  # E-step action samples per state
//! n = 20                  # next-action samples per next state
//! replay = 1_000_000      # replay capacity, transitions
//! steps = 1_000_000       # environment steps of a run
//! schedule = { warmup_steps = 5_000 }       # any keys of a run's [schedule]
//! mpo = { eps_mean = 0.005 }                # any keys of a run's [mpo]
//! ```
//!
//! Both kinds go through the same path: a row's sizes name an instantiation
//! ([`crate::registry::find`]), its settings are the layer under `--config` and the flags.

use std::path::{Path, PathBuf};

use serde::Deserialize;
use sim_bridge::{Origin, TaskDef};

use crate::checkpoint::{Meta, TaskFileRecord};
use crate::settings::{self, Schedule, Settings, SettingsError};
use crate::sizes::Sizes;
pub use crate::table::Row;
use crate::table::{self, SUITE_MPO, SUITE_SCHEDULE};

/// Why a task or row could not be found or read.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RowError {
    /// No built-in task of this name and no task file.
    #[error(
        "unknown task `{task}`; the built-in tasks are: {}; a task file is trained with --task-file FILE.toml (docs/task-files.md)",
        sim_bridge::TASKS.join(", ")
    )]
    UnknownTask {
        /// The name asked for.
        task: String,
    },
    /// The task has no row of this network variant.
    #[error("task `{task}` has no row `{net}`; its rows are: {}", .valid.join(", "))]
    UnknownNet {
        /// The task.
        task: String,
        /// The variant asked for.
        net: String,
        /// Its variants.
        valid: Vec<String>,
    },
    /// A task file's `[rows]` that cannot be used.
    #[error("{file}: {key}: {message}")]
    BadRow {
        /// The task file.
        file: String,
        /// The key, e.g. `rows.default.batch`.
        key: String,
        /// Why.
        message: String,
    },
    /// The task (file) itself.
    #[error(transparent)]
    Sim(#[from] sim_bridge::SimError),
    /// A checkpoint's task file is missing or changed.
    #[error("{0}")]
    TaskFileChanged(String),
}

/// A built-in task by name.
pub fn builtin(name: &str) -> Result<TaskDef, RowError> {
    if !sim_bridge::TASKS.contains(&name) {
        return Err(RowError::UnknownTask { task: name.into() });
    }
    Ok(TaskDef::builtin(name)?)
}

/// The task of `settings`: its task file, or the built-in task it names.
pub fn load_task(settings: &Settings) -> Result<TaskDef, RowError> {
    match &settings.task_file {
        Some(p) => {
            let t = TaskDef::from_file(p)?;
            if t.name() != settings.task {
                return Err(RowError::BadRow {
                    file: p.display().to_string(),
                    key: "name".into(),
                    message: format!(
                        "the file's task is `{}`, the configuration's `task` is `{}`",
                        t.name(),
                        settings.task
                    ),
                });
            }
            Ok(t)
        }
        None => builtin(&settings.task),
    }
}

/// What a checkpoint records of a task file (None for a built-in task).
pub fn task_record(task: &TaskDef) -> Option<TaskFileRecord> {
    match task.origin() {
        Origin::Builtin => None,
        Origin::File(p) => Some(TaskFileRecord {
            path: absolute(p),
            sha256: task.sha256().into(),
            text: task.text().into(),
        }),
    }
}

/// `p` made absolute against the working directory (a run can then be resumed from anywhere).
pub fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// The task a checkpoint was trained on: the built-in task, or its task file, which must
/// still hash as it did (text and model), so a checkpoint is never evaluated, resumed or
/// exported against a plant it was not trained on. `dir` names the checkpoint in errors.
pub fn task_of_checkpoint(meta: &Meta, dir: &Path) -> Result<TaskDef, RowError> {
    let Some(rec) = &meta.task_file else {
        return builtin(&meta.settings.task);
    };
    let hint = format!(
        "restore it (its text is in {}/meta.json, `task_file.text`), or train again",
        dir.display()
    );
    let t = TaskDef::from_file(&rec.path).map_err(|e| {
        RowError::TaskFileChanged(format!(
            "the checkpoint in {} was trained on the task file {}, which cannot be loaded now ({e}); {hint}",
            dir.display(),
            rec.path.display()
        ))
    })?;
    if t.sha256() != rec.sha256 {
        let what = if t.text() == rec.text {
            "its model (the MJCF files it names) changed"
        } else {
            "its text changed"
        };
        return Err(RowError::TaskFileChanged(format!(
            "the task file {} changed since the checkpoint in {} was written ({what}: sha256 {} then, {} now); {hint}",
            rec.path.display(),
            dir.display(),
            &rec.sha256[..12.min(rec.sha256.len())],
            &t.sha256()[..12.min(t.sha256().len())],
        )));
    }
    Ok(t)
}

/// The row `net` of `task`.
pub fn row(task: &TaskDef, net: &str) -> Result<Row, RowError> {
    let rows = rows_of(task)?;
    let valid = rows.iter().map(|r| r.net.clone()).collect();
    rows.into_iter()
        .find(|r| r.net == net)
        .ok_or_else(|| RowError::UnknownNet {
            task: task.name().into(),
            net: net.into(),
            valid,
        })
}

/// Every row of `task`.
pub fn rows_of(task: &TaskDef) -> Result<Vec<Row>, RowError> {
    match task.origin() {
        Origin::Builtin => Ok(table::rows()
            .iter()
            .filter(|r| r.task == task.name())
            .cloned()
            .collect()),
        Origin::File(p) => file_rows(task, &p.display().to_string()),
    }
}

/// The row a task file gets by default, from its sizes: the suite's 256-256 networks, batch
/// and samples, its settings ([`SUITE_SCHEDULE`], [`SUITE_MPO`]), a million steps; the
/// evaluation interval and the budget rounded up to whole episodes when every episode has the
/// same length.
pub fn default_row(task: &TaskDef) -> Row {
    let spec = task.spec();
    let whole = |n: u64| match task.can_terminate() {
        true => n,
        false => n.div_ceil(spec.episode_steps as u64) * spec.episode_steps as u64,
    };
    Row {
        task: task.name().into(),
        net: table::DEFAULT_NET.into(),
        sizes: Sizes::mlp(
            spec.obs_dim,
            spec.act_dim,
            [256, 256],
            [256, 256],
            [256, 4, 8, 20, 20, 1_000_000],
        ),
        steps: whole(1_000_000),
        schedule: Schedule {
            eval_interval: whole(SUITE_SCHEDULE.eval_interval),
            ..SUITE_SCHEDULE
        },
        mpo: SUITE_MPO,
    }
}

/// A `[rows.<net>]` table as written.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileRow {
    actor: Option<[usize; 2]>,
    critic: Option<[usize; 2]>,
    actor_blocks: Option<usize>,
    critic_blocks: Option<usize>,
    bins: Option<usize>,
    batch: Option<usize>,
    chunks: Option<usize>,
    seq: Option<usize>,
    m: Option<usize>,
    n: Option<usize>,
    replay: Option<usize>,
    steps: Option<u64>,
    schedule: Option<toml::Table>,
    mpo: Option<toml::Table>,
}

fn file_rows(task: &TaskDef, file: &str) -> Result<Vec<Row>, RowError> {
    let Some(table) = task.rows() else {
        return Ok(vec![default_row(task)]);
    };
    let mut rows = Vec::new();
    for (net, value) in table {
        let key = format!("rows.{net}");
        let bad = |key: &str, message: String| RowError::BadRow {
            file: file.into(),
            key: key.into(),
            message,
        };
        let t = value
            .as_table()
            .ok_or_else(|| bad(&key, "must be a table of row keys".into()))?;
        let r: FileRow = toml::Value::Table(t.clone())
            .try_into()
            .map_err(|e: toml::de::Error| bad(&key, e.message().to_string()))?;
        rows.push(apply_file_row(default_row(task), net, r, &key, file)?);
    }
    Ok(rows)
}

fn apply_file_row(
    mut row: Row,
    net: &str,
    r: FileRow,
    key: &str,
    file: &str,
) -> Result<Row, RowError> {
    let bad = |k: &str, message: String| RowError::BadRow {
        file: file.into(),
        key: format!("{key}{k}"),
        message,
    };
    row.net = net.into();
    let z = &mut row.sizes;
    z.actor = r.actor.unwrap_or(z.actor);
    z.critic = r.critic.unwrap_or(z.critic);
    z.actor_blocks = r.actor_blocks.unwrap_or(z.actor_blocks);
    z.critic_blocks = r.critic_blocks.unwrap_or(z.critic_blocks);
    z.bins = r.bins.unwrap_or(z.bins);
    z.batch = r.batch.unwrap_or(z.batch);
    // Four chunks where the batch splits so (two threads' work, evenly), else two, else one.
    let batch = z.batch;
    z.chunks = r.chunks.unwrap_or_else(|| {
        [4, 2, 1]
            .into_iter()
            .find(|c| batch.is_multiple_of(*c))
            .unwrap_or(1)
    });
    z.seq = r.seq.unwrap_or(z.seq);
    z.m = r.m.unwrap_or(z.m);
    z.n = r.n.unwrap_or(z.n);
    z.replay_capacity = r.replay.unwrap_or(z.replay_capacity);
    z.check().map_err(|m| bad("", m))?;
    row.steps = r.steps.unwrap_or(row.steps);
    if let Some(t) = r.schedule {
        row.schedule = overlay(&row.schedule, &t, &format!("{file} {key}.schedule"))
            .map_err(|e| bad(".schedule", e.to_string()))?;
    }
    if let Some(t) = r.mpo {
        row.mpo = overlay(&row.mpo, &t, &format!("{file} {key}.mpo"))
            .map_err(|e| bad(".mpo", e.to_string()))?;
    }
    Ok(row)
}

/// `base` with the keys of `over` written over it (unknown keys are errors).
fn overlay<T: serde::Serialize + serde::de::DeserializeOwned>(
    base: &T,
    over: &toml::Table,
    origin: &str,
) -> Result<T, SettingsError> {
    let mut t = toml::Table::try_from(base).expect("settings serialise to TOML");
    settings::overlay(&mut t, over, origin, "")?;
    toml::Value::Table(t)
        .try_into()
        .map_err(|e: toml::de::Error| SettingsError::Parse {
            origin: origin.into(),
            message: e.message().to_string(),
        })
}
