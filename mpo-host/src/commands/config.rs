//! A run's configuration: the row's defaults, then a `--config` TOML file, then `--set`s, then
//! the explicit flags, each layer overriding single keys of the one below; or, resumed, the
//! checkpoint's, of which only `steps` may change.
//!
//! The task is resolved first (a layer's `task_file`, else its `task`; the last layer that
//! names one wins), because its row is the bottom layer.

use std::path::{Path, PathBuf};

use sim_bridge::TaskDef;

use super::error::Error;
use super::trained::open_checkpoint;
use crate::checkpoint::{self, Meta, Verified};
use crate::cli::TrainArgs;
use crate::rows::{self, Row, RowError};
use crate::settings::{self, Settings, SettingsError};
use crate::table::{DEFAULT_NET, DEFAULT_TASK};

/// A run's configuration with its task and row.
#[derive(Debug)]
pub struct Resolved {
    /// The settings.
    pub settings: Settings,
    /// The task they name.
    pub task: TaskDef,
    /// Its row (whose sizes are the learner's).
    pub row: Row,
}

/// The explicit flags of `mpo train` that set configuration keys.
#[derive(Clone, Debug, Default)]
pub struct Flags {
    /// `--task`.
    pub task: Option<String>,
    /// `--task-file`.
    pub task_file: Option<PathBuf>,
    /// `--net`.
    pub net: Option<String>,
    /// `--seed`.
    pub seed: Option<u32>,
    /// `--steps`.
    pub steps: Option<u64>,
}

fn str_value(t: &toml::Table, k: &str) -> Option<String> {
    t.get(k).and_then(|v| v.as_str()).map(str::to_string)
}

/// The layers above the defaults: the file, `--set`s, then explicit flags.
fn layers(args: &TrainArgs) -> Result<Vec<(String, toml::Table)>, Error> {
    let file = match &args.config {
        Some(p) => Some((p.display().to_string(), settings::read_table(p)?)),
        None => None,
    };
    let flags = Flags {
        task: args.task.clone(),
        task_file: args.task_file.clone(),
        net: args.net.clone(),
        seed: args.seed,
        steps: args.steps,
    };
    layers_from(file, &args.set, &flags)
}

/// The configuration layers above the row's defaults, lowest first: the parsed `--config`
/// file `(origin, table)`, each `--set KEY=VALUE`, then the explicit flags.
pub fn layers_from(
    file: Option<(String, toml::Table)>,
    sets: &[String],
    flags: &Flags,
) -> Result<Vec<(String, toml::Table)>, Error> {
    let mut out = Vec::new();
    out.extend(file);
    for s in sets {
        out.push((format!("--set {s}"), settings::parse_set(s)?));
    }
    let mut t = toml::Table::new();
    if let Some(v) = &flags.task {
        t.insert("task".into(), v.clone().into());
    }
    if let Some(p) = &flags.task_file {
        t.insert("task_file".into(), p.display().to_string().into());
    }
    if let Some(n) = &flags.net {
        t.insert("net".into(), n.clone().into());
    }
    if let Some(s) = flags.seed {
        t.insert("seed".into(), (s as i64).into());
    }
    if let Some(s) = flags.steps {
        t.insert("steps".into(), (s as i64).into());
    }
    out.push(("flags".into(), t));
    Ok(out)
}

fn apply(base: &toml::Table, layers: &[(String, toml::Table)]) -> Result<toml::Table, Error> {
    let mut t = base.clone();
    for (origin, l) in layers {
        settings::overlay(&mut t, l, origin, "")?;
        // Type errors are reported against the layer that introduced them.
        Settings::from_table(t.clone(), origin)?;
    }
    Ok(t)
}

/// The layers without the keys that name the task (resolved before the others).
fn without_task(layers: &[(String, toml::Table)]) -> Vec<(String, toml::Table)> {
    layers
        .iter()
        .map(|(o, t)| {
            let mut t = t.clone();
            t.remove("task");
            t.remove("task_file");
            (o.clone(), t)
        })
        .collect()
}

/// Which task the layers name: the last layer naming one decides; within a layer a
/// `task_file` wins and its `task`, if given, must be the file's name.
fn task_of_layers(layers: &[(String, toml::Table)]) -> Result<TaskDef, Error> {
    let mut chosen: Option<(String, Option<String>, Option<String>)> = None;
    for (origin, l) in layers {
        let (task, file) = (str_value(l, "task"), str_value(l, "task_file"));
        if task.is_some() || file.is_some() {
            chosen = Some((origin.clone(), task, file));
        }
    }
    let Some((origin, task, file)) = chosen else {
        return Ok(rows::builtin(DEFAULT_TASK)?);
    };
    let Some(file) = file else {
        return Ok(rows::builtin(&task.expect("one of the two"))?);
    };
    let def = TaskDef::from_file(Path::new(&file)).map_err(RowError::from)?;
    if let Some(t) = task.filter(|t| t != def.name()) {
        return Err(SettingsError::Invalid(format!(
            "{origin}: task = `{t}` but the task file {file} is task `{}`",
            def.name()
        ))
        .into());
    }
    Ok(def)
}

/// The row's defaults as settings.
pub fn defaults(row: &Row) -> Settings {
    Settings {
        task: row.task.clone(),
        task_file: None,
        net: row.net.clone(),
        seed: 0,
        steps: row.steps,
        schedule: row.schedule,
        mpo: row.mpo,
        network: Some(row.sizes),
    }
}

/// Range checks of `s` against its task and row.
fn validate(s: &Settings, task: &TaskDef, row: &Row) -> Result<(), Error> {
    let fixed = !task.can_terminate();
    Ok(s.validate(task.spec().episode_steps as u64, fixed, &row.sizes)?)
}

/// A fresh run's configuration: the row's defaults under `layers` (see [`layers_from`]),
/// validated. Reads the task file, if one is named.
pub fn resolve_fresh(layers: &[(String, toml::Table)]) -> Result<Resolved, Error> {
    let task = task_of_layers(layers)?;
    let mut net = DEFAULT_NET.to_string();
    for (_, l) in layers {
        net = str_value(l, "net").unwrap_or(net);
    }
    let row = rows::row(&task, &net)?;
    let merged = apply(&defaults(&row).to_table(), &without_task(layers))?;
    let mut s = Settings::from_table(merged, "configuration")?;
    s.task = task.name().into();
    s.task_file = rows::task_record(&task).map(|r| r.path);
    validate(&s, &task, &row)?;
    Ok(Resolved {
        settings: s,
        task,
        row,
    })
}

/// A resumed run's configuration: the checkpoint's (`meta`, from `dir`) under `layers`, which
/// may change `steps` only (raise it), validated against this build's rows; a task file must
/// still hash as it did.
pub fn resolve_resumed(
    meta: &Meta,
    dir: &Path,
    layers: &[(String, toml::Table)],
) -> Result<Resolved, Error> {
    let mismatch = |differences: Vec<String>| -> Error {
        SettingsError::Mismatch {
            dir: dir.display().to_string(),
            differences,
        }
        .into()
    };
    let given = task_names(layers);
    let had = (
        meta.settings.task.clone(),
        meta.settings.task_file.as_ref().map(|p| rows::absolute(p)),
    );
    if let Some(d) = given.difference(&had) {
        return Err(mismatch(vec![d]));
    }
    let base = meta.settings.to_table();
    let merged = apply(&base, &without_task(layers))?;
    let diffs = settings::differences(&base, &merged, "", &["steps"]);
    if !diffs.is_empty() {
        return Err(mismatch(diffs));
    }
    let s = Settings::from_table(merged, "resumed configuration")?;
    let task = rows::task_of_checkpoint(meta, dir)?;
    let row = rows::row(&task, &s.net)?;
    if meta.sizes != row.sizes {
        return Err(mismatch(vec![format!(
            "network sizes are {} in the checkpoint, {} in this build's row",
            meta.sizes.describe(),
            row.sizes.describe()
        )]));
    }
    validate(&s, &task, &row)?;
    if s.steps < meta.env_steps {
        return Err(SettingsError::Invalid(format!(
            "steps = {} is below the checkpoint's {} environment steps",
            s.steps, meta.env_steps
        ))
        .into());
    }
    Ok(Resolved {
        settings: s,
        task,
        row,
    })
}

/// The task names given on a resumed run's layers (each must be the checkpoint's).
#[derive(Default)]
struct GivenTask {
    task: Option<String>,
    file: Option<PathBuf>,
}

fn task_names(layers: &[(String, toml::Table)]) -> GivenTask {
    let mut g = GivenTask::default();
    for (_, l) in layers {
        g.task = str_value(l, "task").or(g.task);
        g.file = str_value(l, "task_file")
            .map(|f| rows::absolute(Path::new(&f)))
            .or(g.file);
    }
    g
}

impl GivenTask {
    fn difference(&self, (task, file): &(String, Option<PathBuf>)) -> Option<String> {
        if let Some(t) = self.task.as_ref().filter(|t| *t != task) {
            return Some(format!("`task` is {task} in the checkpoint, {t} here"));
        }
        match (&self.file, file) {
            (Some(f), Some(g)) if f != g => Some(format!(
                "`task_file` is {} in the checkpoint, {} here",
                g.display(),
                f.display()
            )),
            (Some(f), None) => Some(format!(
                "the checkpoint's task is the built-in {task}, not the task file {}",
                f.display()
            )),
            _ => None,
        }
    }
}

/// The configuration of `mpo train` with these flags: a fresh run's, or with `--resume` the
/// resumed run's (with its verified checkpoint).
fn resolve_settings(args: &TrainArgs) -> Result<(Resolved, Option<Verified>), Error> {
    let layers = layers(args)?;
    match &args.resume {
        Some(dir) => {
            let v = open_checkpoint(dir)?;
            Ok((resolve_resumed(&v.meta, &v.dir, &layers)?, Some(v)))
        }
        None => Ok((resolve_fresh(&layers)?, None)),
    }
}

/// Resolves the configuration of `mpo train` (fresh or resumed) and where it writes.
pub fn resolve_train(args: &TrainArgs) -> Result<(Resolved, PathBuf, Option<Verified>), Error> {
    let (r, resumed) = resolve_settings(args)?;
    if let Some(v) = resumed {
        let out = args
            .out
            .clone()
            .unwrap_or_else(|| checkpoint::run_dir_of(&v.dir));
        return Ok((r, out, Some(v)));
    }
    let s = &r.settings;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("runs/{}-seed{}", s.task, s.seed)));
    if checkpoint::locate(&out).is_ok() {
        return Err(Error::OutExists(out.display().to_string()));
    }
    Ok((r, out, None))
}

/// `mpo train --print-config`: the `config.toml` that `mpo train` with the same flags would
/// write (a fresh run's, or with `--resume` the resumed run's), without training or touching
/// any run directory, so a row's defaults and the effect of `--config`/`--set` can be read
/// before hours of training.
pub fn print_config(args: &TrainArgs) -> Result<String, Error> {
    let (r, _) = resolve_settings(args)?;
    Ok(r.settings.config_toml(&r.row.sizes))
}
