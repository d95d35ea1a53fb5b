//! The `sim-bridge` command: replay an action file through a task and print every state as JSON.
//!
//! `replay` has dm_control's semantics (`suite.load(domain, task, task_kwargs={'random': seed})`,
//! `reset()`, then `step(row)` per row) so its output can be compared line by line with
//! `scripts/dm_control_replay.py`. The whole action file is validated before the first step, so a
//! bad file produces an error and no partial trajectory.

use std::io::Write;
use std::path::{Path, PathBuf};

use clap::{Parser, Subcommand};
use serde::Serialize;

use crate::{TASKS, make, task_spec};

/// MuJoCo and the DeepMind Control Suite tasks, reproduced exactly.
#[derive(Debug, Parser)]
#[command(name = "sim-bridge", version)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Replays one action per CSV row from a seeded reset and prints one JSON object per line:
    /// the reset state, then every step (step, reward, discount, obs, qpos, qvel).
    Replay {
        /// Task name, e.g. cartpole-swingup (see `sim-bridge tasks`).
        #[arg(long)]
        task: String,
        /// dm_control's `task_kwargs={'random': SEED}`.
        #[arg(long)]
        seed: u32,
        /// CSV file, one row of comma-separated actions per control step.
        #[arg(long)]
        actions: PathBuf,
    },
    /// Lists the tasks with their observation and action sizes.
    Tasks,
}

/// One line of `replay` output.
#[derive(Debug, Serialize)]
pub struct Record<'a> {
    pub step: usize,
    pub reward: Option<f64>,
    pub discount: Option<f64>,
    pub obs: &'a [f64],
    pub qpos: &'a [f64],
    pub qvel: &'a [f64],
}

/// A failed command: the message printed after `error: `.
#[derive(Debug)]
pub struct CliError(pub String);

impl<E: std::error::Error> From<E> for CliError {
    fn from(e: E) -> Self {
        Self(e.to_string())
    }
}

/// Reads and parses the action file ([`parse_actions`]).
pub fn read_actions(path: &Path, width: usize, max_rows: usize) -> Result<Vec<Vec<f64>>, CliError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError(format!("cannot read action file {}: {e}", path.display())))?;
    parse_actions(&text, path, width, max_rows)
}

/// Parses an action file's text: one row per control step, `width` finite numbers per row, at
/// most `max_rows` rows; `path` only names the file in errors. (Pure, so the fuzz target
/// `actions_csv` reaches it without a file.)
pub fn parse_actions(
    text: &str,
    path: &Path,
    width: usize,
    max_rows: usize,
) -> Result<Vec<Vec<f64>>, CliError> {
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let row = i + 1;
        let line = line.trim();
        if line.is_empty() {
            return Err(CliError(format!("{}: row {row} is empty", path.display())));
        }
        let mut values = Vec::with_capacity(width);
        for (col, field) in line.split(',').enumerate() {
            let field = field.trim();
            let value: f64 = field.parse().map_err(|_| {
                CliError(format!(
                    "{}: row {row}, column {}: '{field}' is not a number",
                    path.display(),
                    col + 1
                ))
            })?;
            if !value.is_finite() {
                return Err(CliError(format!(
                    "{}: row {row}, column {}: action {value} is not finite",
                    path.display(),
                    col + 1
                )));
            }
            values.push(value);
        }
        if values.len() != width {
            return Err(CliError(format!(
                "{}: row {row} has {} actions, the task takes {width}",
                path.display(),
                values.len()
            )));
        }
        rows.push(values);
    }
    if rows.len() > max_rows {
        return Err(CliError(format!(
            "{}: {} rows, but an episode has only {max_rows} steps (row {} is past the end)",
            path.display(),
            rows.len(),
            max_rows + 1
        )));
    }
    Ok(rows)
}

fn emit(out: &mut impl Write, record: &Record<'_>) -> Result<(), CliError> {
    serde_json::to_writer(&mut *out, record)?;
    out.write_all(b"\n")?;
    Ok(())
}

/// `sim-bridge replay`. The output is buffered and written only when the whole replay succeeded,
/// so a failure (e.g. the physics diverging mid-episode) leaves no partial trajectory.
pub fn replay(
    task: &str,
    seed: u32,
    actions: &Path,
    sink: &mut impl Write,
) -> Result<(), CliError> {
    let mut buffer = Vec::new();
    let out = &mut buffer;
    let spec = task_spec(task)?;
    let rows = read_actions(actions, spec.act_dim, spec.episode_steps)?;
    let mut env = make(task, seed)?;
    let mut obs = vec![0.0; spec.obs_dim];
    env.reset(&mut obs);
    emit(
        out,
        &Record {
            step: 0,
            reward: None,
            discount: None,
            obs: &obs,
            qpos: env.qpos(),
            qvel: env.qvel(),
        },
    )?;
    for (i, row) in rows.iter().enumerate() {
        let step = env
            .try_step(row, &mut obs)
            .map_err(|e| CliError(format!("{}: row {}: {e}", actions.display(), i + 1)))?;
        emit(
            out,
            &Record {
                step: i + 1,
                reward: Some(step.reward),
                discount: Some(step.discount),
                obs: &obs,
                qpos: env.qpos(),
                qvel: env.qvel(),
            },
        )?;
        if step.last {
            break;
        }
    }
    sink.write_all(&buffer)?;
    sink.flush()?;
    Ok(())
}

/// `sim-bridge tasks`.
pub fn list_tasks(out: &mut impl Write) -> Result<(), CliError> {
    writeln!(
        out,
        "{:<18} {:>4} {:>4} {:>8} {:>6}",
        "task", "obs", "act", "dt", "steps"
    )?;
    for name in TASKS {
        let s = task_spec(name)?;
        writeln!(
            out,
            "{:<18} {:>4} {:>4} {:>8} {:>6}",
            s.name, s.obs_dim, s.act_dim, s.control_timestep, s.episode_steps
        )?;
    }
    Ok(())
}

/// Runs the parsed command; the binaries turn an error into `error: ...` and exit status 1.
pub fn run(cli: Cli) -> Result<(), CliError> {
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    match cli.command {
        Command::Replay {
            task,
            seed,
            actions,
        } => replay(&task, seed, &actions, &mut out),
        Command::Tasks => list_tasks(&mut out),
    }
}
