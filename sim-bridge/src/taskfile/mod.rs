//! Tasks as data: a TOML file beside an MJCF model says what a Control Suite task's Python
//! says (the model, the physics steps per control step, the observation, the reward, the
//! termination, the episode length, the initial state), and the built-in tasks are such
//! files (`tasks/*.toml` in the repository, compiled in).
//!
//! Loading a file validates all of it against its model at once (every name resolved,
//! every size known), so a mistake is one clear error naming the file and the key before
//! anything runs. `docs/task-files.md` documents every key and function.

mod expr;
mod format;
mod plant;
mod program;

use std::path::{Path, PathBuf};

use mujoco_rs::prelude::MjtObjBase;
use sha2::{Digest, Sha256};

use format::TaskToml;
pub use format::{Convention, PlantKind};
pub(crate) use plant::FileTask;

use crate::TaskSpec;
use crate::error::SimError;
use crate::physics::Physics;

include!(concat!(env!("OUT_DIR"), "/builtin_tasks.rs"));

/// Where a task definition came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Origin {
    /// Compiled in from the repository's `tasks/` folder.
    Builtin,
    /// A file the user gave.
    File(PathBuf),
}

/// Where the MJCF model is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum ModelRef {
    /// `suite:<file>`: the Control Suite's models (`.deps/dm_control/suite`).
    Suite(String),
    /// `gymnasium:<file>`: Gymnasium's MuJoCo models (`.deps/gymnasium/assets`).
    Gymnasium(String),
    /// A file, relative to the task file's folder.
    Path(PathBuf),
}

/// A validated task definition: its text, its hash, and what it makes.
#[derive(Clone, Debug)]
pub struct TaskDef {
    name: String,
    description: String,
    origin: Origin,
    text: String,
    sha256: String,
    toml: TaskToml,
    parsed: Option<plant::Parsed>,
    model: Option<ModelRef>,
    spec: TaskSpec,
    n_sub_steps: usize,
    /// Actuator ids the action drives, in action order.
    actuators: Vec<usize>,
    /// Per action dimension: `(mid, half)` of its range; `None` when every range is
    /// `[-1, 1]` (the action is written to `ctrl` unchanged, bit for bit).
    scale: Option<Vec<(f64, f64)>>,
    /// Per action dimension, `[low, high]` in the actuators' units.
    bounds: Vec<(f64, f64)>,
    /// How an external plant is reached (None for MuJoCo).
    external: Option<ExternalDef>,
}

/// How the learner reaches an external plant (a task file's `[external]` beyond the sizes;
/// `docs/external-plant.md`).
#[derive(Clone, Debug, PartialEq)]
pub struct ExternalDef {
    /// `command`: the plant's program and its arguments (None: it is started by hand and
    /// attached to).
    pub command: Option<Vec<String>>,
    /// The task file's folder, where the command runs.
    pub dir: PathBuf,
    /// `timeout`: seconds per reset or step.
    pub timeout: f64,
    /// `connect_timeout`: seconds for the handshake, the program's start-up included.
    pub connect_timeout: f64,
}

/// The most numbers an observation may have (Gymnasium's Humanoid-v5 has 348).
pub const MAX_OBS: usize = 1024;
/// The most action dimensions (dm_control's dog has 38).
pub const MAX_ACT: usize = 64;
/// The longest task file, in bytes.
pub const MAX_FILE_BYTES: usize = 1 << 20;

/// A task file's key and what is wrong with it.
fn bad(file: &str, key: &str, message: impl Into<String>) -> SimError {
    use crate::error::one_line;
    SimError::TaskFile {
        file: one_line(file),
        key: one_line(key),
        message: one_line(&message.into()),
    }
}

/// The names of the built-in tasks, in file-name order.
pub fn builtin_names() -> Vec<&'static str> {
    BUILTIN.iter().map(|(n, _)| *n).collect()
}

impl TaskDef {
    /// The built-in task `name` (`tasks/<name>.toml`).
    pub fn builtin(name: &str) -> Result<Self, SimError> {
        let (_, text) =
            BUILTIN
                .iter()
                .find(|(n, _)| *n == name)
                .ok_or_else(|| SimError::UnknownTask {
                    task: name.to_string(),
                    valid: BUILTIN_NAMES,
                })?;
        Self::from_text(text, name, Origin::Builtin, &builtin_dir())
    }

    /// A task file. Its model path is relative to the file's folder.
    pub fn from_file(path: &Path) -> Result<Self, SimError> {
        let file = path.display().to_string();
        match std::fs::metadata(path) {
            Ok(m) if m.len() > MAX_FILE_BYTES as u64 => {
                return Err(bad(
                    &file,
                    "(file)",
                    format!(
                        "{} bytes; a task file has at most {MAX_FILE_BYTES}",
                        m.len()
                    ),
                ));
            }
            _ => {}
        }
        let text = std::fs::read_to_string(path)
            .map_err(|e| bad(&file, "(file)", format!("cannot be read: {e}")))?;
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "task".into());
        let dir = path.parent().unwrap_or(Path::new("."));
        Self::from_text_named(&text, &stem, Origin::File(path.to_path_buf()), dir, &file)
    }

    /// A task from text, its model found relative to `dir`.
    pub fn from_text(text: &str, stem: &str, origin: Origin, dir: &Path) -> Result<Self, SimError> {
        let file = match &origin {
            Origin::Builtin => format!("tasks/{stem}.toml"),
            Origin::File(p) => p.display().to_string(),
        };
        Self::from_text_named(text, stem, origin, dir, &file)
    }

    fn from_text_named(
        text: &str,
        stem: &str,
        origin: Origin,
        dir: &Path,
        file: &str,
    ) -> Result<Self, SimError> {
        if text.len() > MAX_FILE_BYTES {
            return Err(bad(
                file,
                "(file)",
                format!(
                    "{} bytes; a task file has at most {MAX_FILE_BYTES}",
                    text.len()
                ),
            ));
        }
        let toml = parse_toml(text, file)?;
        let name = toml.name.clone().unwrap_or_else(|| stem.to_string());
        if name.is_empty()
            || name.len() > 64
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        {
            return Err(bad(
                file,
                "name",
                format!("`{name}`: 1-64 letters, digits, `-`, `_` or `.`"),
            ));
        }
        let description = toml.description.clone().unwrap_or_default();
        if toml.plant == PlantKind::External {
            return Self::external(toml, name, description, origin, text, (file, dir));
        }
        let parsed = plant::parse(&toml).map_err(|e| bad(file, &e.key, e.message))?;
        let model_key = toml.model.as_deref().ok_or_else(|| {
            bad(
                file,
                "model",
                "missing: the MJCF model file (a path relative to this file, suite:<file> or gymnasium:<file>)",
            )
        })?;
        let model = model_ref(model_key, dir, file)?;
        let physics = load_physics(&model, file)?;
        let timestep = physics.timestep();
        let n_sub_steps = substeps(&toml, timestep, file)?;
        let control_timestep = timestep * n_sub_steps as f64;
        let episode_steps = episode_steps(&toml, control_timestep, file)?;
        let (actuators, bounds) = actuators(&toml, &physics, file)?;
        if actuators.len() > MAX_ACT {
            return Err(bad(
                file,
                "actuators",
                format!(
                    "{} action dimensions; at most {MAX_ACT} (list the ones the policy drives)",
                    actuators.len()
                ),
            ));
        }
        let unit = bounds.iter().all(|&b| b == (-1.0, 1.0));
        let scale = (!unit).then(|| {
            bounds
                .iter()
                .map(|&(lo, hi)| ((lo + hi) / 2.0, (hi - lo) / 2.0))
                .collect()
        });
        let task = FileTask::bind(
            &parsed,
            &physics,
            control_timestep,
            actuators.len(),
            toml.convention == Convention::Gymnasium,
        )
        .map_err(|e| bad(file, &e.key, e.message))?;
        let obs_dim = task.obs_dim();
        if obs_dim > MAX_OBS {
            return Err(bad(
                file,
                "observation",
                format!(
                    "{obs_dim} numbers ({}); at most {MAX_OBS}",
                    task.obs_parts()
                        .iter()
                        .map(|(n, l)| format!("{n} {l}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        if obs_dim == 0 {
            return Err(bad(
                file,
                "observation",
                "empty: give at least one part, e.g. { name = \"velocity\", value = \"qvel\" }",
            ));
        }
        let sha256 = hash(text, &model, file)?;
        Ok(Self {
            spec: TaskSpec {
                name: name.clone(),
                obs_dim,
                act_dim: actuators.len(),
                control_timestep,
                episode_steps,
            },
            name,
            description,
            origin,
            text: text.to_string(),
            sha256,
            toml,
            parsed: Some(parsed),
            model: Some(model),
            n_sub_steps,
            actuators,
            scale,
            bounds,
            external: None,
        })
    }

    fn external(
        toml: TaskToml,
        name: String,
        description: String,
        origin: Origin,
        text: &str,
        (file, dir): (&str, &Path),
    ) -> Result<Self, SimError> {
        let e = toml.external.clone().ok_or_else(|| {
            bad(
                file,
                "external",
                "missing: plant = \"external\" needs [external] obs, act, action_low, action_high",
            )
        })?;
        for (key, v) in [
            ("model", toml.model.is_some()),
            ("reward", toml.reward.is_some()),
            ("observation", !toml.observation.is_empty()),
            ("init", !toml.init.is_empty()),
        ] {
            if v {
                return Err(bad(
                    file,
                    key,
                    "an external plant computes this itself: remove the key",
                ));
            }
        }
        if !(1..=MAX_OBS).contains(&e.obs) {
            return Err(bad(
                file,
                "external.obs",
                format!("{}: from 1 to {MAX_OBS}", e.obs),
            ));
        }
        if !(1..=MAX_ACT).contains(&e.act) {
            return Err(bad(
                file,
                "external.act",
                format!("{}: from 1 to {MAX_ACT}", e.act),
            ));
        }
        let widen = |v: &[f64], key: &str| -> Result<Vec<f64>, SimError> {
            match v.len() {
                1 => Ok(vec![v[0]; e.act]),
                n if n == e.act => Ok(v.to_vec()),
                n => Err(bad(
                    file,
                    key,
                    format!(
                        "{n} values for {} action dimensions (give one, or one each)",
                        e.act
                    ),
                )),
            }
        };
        let (lo, hi) = (
            widen(&e.action_low, "external.action_low")?,
            widen(&e.action_high, "external.action_high")?,
        );
        let bounds: Vec<(f64, f64)> = lo.into_iter().zip(hi).collect();
        if let Some((l, h)) = bounds
            .iter()
            .find(|(l, h)| !(l.is_finite() && h.is_finite() && l < h))
        {
            return Err(bad(
                file,
                "external",
                format!("action bounds [{l}, {h}]: each low < high, finite"),
            ));
        }
        let episode_steps = toml.episode_steps.ok_or_else(|| {
            bad(
                file,
                "episode_steps",
                "missing: an external plant's episode length",
            )
        })?;
        if !(1..=10_000_000).contains(&episode_steps) {
            return Err(bad(
                file,
                "episode_steps",
                format!("{episode_steps}: from 1 to 10^7"),
            ));
        }
        let seconds = |v: Option<f64>, key: &str, default: f64| match v {
            None => Ok(default),
            Some(s) if s.is_finite() && s > 0.0 => Ok(s),
            Some(s) => Err(bad(file, key, format!("{s}: a positive number of seconds"))),
        };
        if e.command
            .as_ref()
            .is_some_and(|c| c.is_empty() || c[0].is_empty())
        {
            return Err(bad(
                file,
                "external.command",
                "empty: give the program and its arguments, e.g. [\"python3\", \"-m\", \"mpo_plant\", \"--gym\", \"Pendulum-v1\"]",
            ));
        }
        let external = ExternalDef {
            command: e.command.clone(),
            dir: dir.to_path_buf(),
            timeout: seconds(e.timeout, "external.timeout", 10.0)?,
            connect_timeout: seconds(e.connect_timeout, "external.connect_timeout", 60.0)?,
        };
        let control_timestep = toml.control_timestep.unwrap_or(0.0);
        if !(control_timestep.is_finite() && control_timestep >= 0.0) {
            return Err(bad(
                file,
                "control_timestep",
                format!("{control_timestep}: seconds, finite and not negative"),
            ));
        }
        let mut h = Sha256::new();
        h.update(text.as_bytes());
        Ok(Self {
            spec: TaskSpec {
                name: name.clone(),
                obs_dim: e.obs,
                act_dim: e.act,
                control_timestep,
                episode_steps,
            },
            name,
            description,
            origin,
            text: text.to_string(),
            sha256: hex(&h.finalize()),
            toml,
            parsed: None,
            model: None,
            n_sub_steps: 0,
            actuators: Vec::new(),
            scale: None,
            bounds,
            external: Some(external),
        })
    }

    /// The task's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its one-line description (empty when the file gives none).
    pub fn description(&self) -> &str {
        &self.description
    }

    /// Where it came from.
    pub fn origin(&self) -> &Origin {
        &self.origin
    }

    /// The file's text, as read.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// sha256 of the file's text followed by its model's files (the main XML and every file
    /// it includes or names): a changed task or model changes it.
    pub fn sha256(&self) -> &str {
        &self.sha256
    }

    /// The task's shape.
    pub fn spec(&self) -> &TaskSpec {
        &self.spec
    }

    /// True when an episode may end before its time limit: the file has a `terminate`
    /// condition, or another program steps the plant (it decides).
    pub fn can_terminate(&self) -> bool {
        self.toml.terminate.is_some() || self.is_external()
    }

    /// True for `plant = "external"` (another program steps it).
    pub fn is_external(&self) -> bool {
        self.toml.plant == PlantKind::External
    }

    /// How an external plant is reached (None for a task simulated here).
    pub fn external_plant(&self) -> Option<&ExternalDef> {
        self.external.as_ref()
    }

    /// The file's path for messages (`tasks/<name>.toml` for a built-in task).
    pub fn file_label(&self) -> String {
        self.display_file()
    }

    /// Per action dimension, its `[low, high]` in the plant's units (the policy acts in
    /// `[-1, 1]`, mapped linearly onto these).
    pub fn action_bounds(&self) -> &[(f64, f64)] {
        &self.bounds
    }

    /// The file's `[rows]` table (learner rows, for the `mpo` command), if any.
    pub fn rows(&self) -> Option<&toml::Table> {
        self.toml.rows.as_ref()
    }

    /// The physics convention.
    pub fn convention(&self) -> Convention {
        self.toml.convention
    }

    /// The model's path on disk (for renderers), or None for an external plant.
    pub fn model_path(&self) -> Option<PathBuf> {
        match self.model.as_ref()? {
            ModelRef::Suite(f) => Some(crate::assets::suite_dir().join(f)),
            ModelRef::Gymnasium(f) => Some(crate::assets::gymnasium_dir().join(f)),
            ModelRef::Path(p) => Some(p.clone()),
        }
    }

    /// The model with every visual asset (the skybox of the suite's models included), for a
    /// renderer; its dynamics are those of the simulated model.
    pub fn load_visual_model(&self) -> Result<mujoco_rs::prelude::MjModel, SimError> {
        match &self.model {
            Some(ModelRef::Suite(f)) => {
                crate::assets::load_visual_model(f.strip_suffix(".xml").unwrap_or(f))
            }
            Some(ModelRef::Gymnasium(f)) => {
                crate::assets::load_model_file(&crate::assets::gymnasium_dir().join(f))
            }
            Some(ModelRef::Path(p)) => crate::assets::load_model_file(p),
            None => Err(bad(
                &self.display_file(),
                "plant",
                "an external plant has no model to draw",
            )),
        }
    }

    /// A fresh environment of this task, its random stream seeded with `seed` (numpy's legacy
    /// `RandomState(seed)`, or `Generator(PCG64(SeedSequence(seed)))` with the gymnasium
    /// convention).
    pub fn make(&self, seed: u32) -> Result<crate::SuiteEnv, SimError> {
        let file = self.display_file();
        let (Some(model), Some(parsed)) = (&self.model, &self.parsed) else {
            return Err(bad(
                &file,
                "plant",
                "an external plant is stepped by its own program: run it and connect it through the link",
            ));
        };
        let physics = load_physics(model, &file)?;
        let task = FileTask::bind(
            parsed,
            &physics,
            self.spec.control_timestep,
            self.actuators.len(),
            self.toml.convention == Convention::Gymnasium,
        )
        .map_err(|e| bad(&file, &e.key, e.message))?;
        Ok(crate::SuiteEnv::from_parts(crate::env::Parts {
            spec: self.spec.clone(),
            physics,
            task: Box::new(task),
            seed,
            n_sub_steps: self.n_sub_steps,
            gymnasium: self.toml.convention == Convention::Gymnasium,
            actuators: self.actuators.clone(),
            scale: self.scale.clone(),
            file,
        }))
    }

    fn display_file(&self) -> String {
        match &self.origin {
            Origin::Builtin => format!("tasks/{}.toml", self.name),
            Origin::File(p) => p.display().to_string(),
        }
    }
}

/// The repository's `tasks/` folder (where built-in files' relative models would be).
fn builtin_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tasks")
}

fn parse_toml(text: &str, file: &str) -> Result<TaskToml, SimError> {
    toml::from_str(text).map_err(|e| {
        let key = e
            .span()
            .map(|s| {
                let line = text[..s.start.min(text.len())].lines().count().max(1);
                format!("line {line}")
            })
            .unwrap_or_else(|| "(file)".into());
        bad(file, &key, e.message().replace('\n', " "))
    })
}

/// The `model` key: `suite:<file>` and `gymnasium:<file>` name a file of that folder (checked
/// to be there, the folder's models listed when it is not), anything else is a path relative
/// to the task file.
fn model_ref(key: &str, dir: &Path, file: &str) -> Result<ModelRef, SimError> {
    let named = |prefix: &str, name: &str, folder: PathBuf, setup: &str| {
        let models = || {
            let mut v: Vec<String> = std::fs::read_dir(&folder)
                .map(|d| {
                    d.flatten()
                        .map(|e| e.file_name().to_string_lossy().to_string())
                        .filter(|n| n.ends_with(".xml"))
                        .collect()
                })
                .unwrap_or_default();
            v.sort();
            v.join(", ")
        };
        if !folder.is_dir() {
            return Err(bad(
                file,
                "model",
                format!(
                    "{prefix}{name}: the folder {} is missing; run `{setup}` from the repository root",
                    folder.display()
                ),
            ));
        }
        let plain =
            !name.is_empty() && !name.contains(['/', '\\', '\0']) && name != "." && name != "..";
        if !plain || !folder.join(name).is_file() {
            return Err(bad(
                file,
                "model",
                format!("{prefix}{name}: no such model (models: {})", models()),
            ));
        }
        Ok(name.to_string())
    };
    Ok(if let Some(f) = key.strip_prefix("suite:") {
        ModelRef::Suite(named(
            "suite:",
            f,
            crate::assets::suite_dir(),
            crate::SETUP_COMMAND,
        )?)
    } else if let Some(f) = key.strip_prefix("gymnasium:") {
        ModelRef::Gymnasium(named(
            "gymnasium:",
            f,
            crate::assets::gymnasium_dir(),
            "scripts/setup-gymnasium",
        )?)
    } else {
        let p = dir.join(key);
        if key.is_empty() || key.contains('\0') || !p.is_file() {
            return Err(bad(
                file,
                "model",
                format!(
                    "{} does not exist (a path relative to the task file, or suite:<file>, gymnasium:<file>)",
                    p.display()
                ),
            ));
        }
        ModelRef::Path(p)
    })
}

fn load_physics(model: &ModelRef, file: &str) -> Result<Physics, SimError> {
    let loaded = match model {
        ModelRef::Suite(f) => Physics::load_suite(f),
        ModelRef::Gymnasium(f) => Physics::load_file(&crate::assets::gymnasium_dir().join(f)),
        ModelRef::Path(p) => Physics::load_file(p),
    };
    // MuJoCo's own message (an XML error, a missing include) under the task file's key.
    loaded.map_err(|e| match e {
        SimError::ModelLoad { path, message } => bad(
            file,
            "model",
            format!(
                "MuJoCo cannot load {}: {}",
                path.display(),
                message.split_whitespace().collect::<Vec<_>>().join(" ")
            ),
        ),
        e => e,
    })
}

fn substeps(t: &TaskToml, timestep: f64, file: &str) -> Result<usize, SimError> {
    match (t.substeps, t.control_timestep) {
        (Some(_), Some(_)) => Err(bad(
            file,
            "substeps",
            "give substeps or control_timestep, not both",
        )),
        (Some(0), _) => Err(bad(file, "substeps", "must be at least 1")),
        (Some(n), None) if n <= 100_000 => Ok(n),
        (Some(n), None) => Err(bad(file, "substeps", format!("{n} is more than 100000"))),
        (None, Some(c)) => {
            // dm_control's compute_n_steps: the control timestep must be a whole number of
            // physics timesteps.
            let n = (c / timestep).round();
            if !(c.is_finite()
                && (1.0..=100_000.0).contains(&n)
                && ((c / timestep) - n).abs() < 1e-8)
            {
                return Err(bad(
                    file,
                    "control_timestep",
                    format!("{c} s is not a whole number of the model's {timestep} s timesteps"),
                ));
            }
            Ok(n as usize)
        }
        (None, None) => Ok(1),
    }
}

fn episode_steps(t: &TaskToml, control_timestep: f64, file: &str) -> Result<usize, SimError> {
    match (t.time_limit, t.episode_steps) {
        (Some(_), Some(_)) => Err(bad(
            file,
            "time_limit",
            "give time_limit or episode_steps, not both",
        )),
        (None, Some(n)) if (1..=10_000_000).contains(&n) => Ok(n),
        (None, Some(n)) => Err(bad(file, "episode_steps", format!("{n}: from 1 to 10^7"))),
        (Some(s), None) => {
            // dm_control: the episode ends at the first step count >= time_limit / dt.
            let limit = (s / control_timestep).ceil();
            if !(s.is_finite() && (1.0..=1e7).contains(&limit)) {
                return Err(bad(
                    file,
                    "time_limit",
                    format!("{s} s is not 1 to 10^7 control steps of {control_timestep} s"),
                ));
            }
            Ok(limit as usize)
        }
        (None, None) => Err(bad(
            file,
            "time_limit",
            "missing: the episode length (time_limit in seconds, or episode_steps)",
        )),
    }
}

/// The actuator ids of the action, and each one's control range.
type ActionMap = (Vec<usize>, Vec<(f64, f64)>);

fn actuators(t: &TaskToml, physics: &Physics, file: &str) -> Result<ActionMap, SimError> {
    let m = physics.model();
    let nu = m.ffi().nu as usize;
    let ids: Vec<usize> = match &t.actuators {
        None => (0..nu).collect(),
        Some(names) => {
            let mut ids = Vec::new();
            for n in names {
                let id = m
                    .name_to_id(MjtObjBase::mjOBJ_ACTUATOR, n)
                    .filter(|_| !n.contains('\0'))
                    .ok_or_else(|| {
                        bad(
                            file,
                            "actuators",
                            format!(
                                "no actuator named '{n}' ({})",
                                program::names(m, MjtObjBase::mjOBJ_ACTUATOR)
                            ),
                        )
                    })?;
                if ids.contains(&id) {
                    return Err(bad(file, "actuators", format!("'{n}' is listed twice")));
                }
                ids.push(id);
            }
            ids
        }
    };
    if ids.is_empty() {
        return Err(bad(
            file,
            "actuators",
            "the model has no actuators: an action needs at least one",
        ));
    }
    let mut bounds = Vec::new();
    for &id in &ids {
        let name = m.id_to_name(MjtObjBase::mjOBJ_ACTUATOR, id).unwrap_or("?");
        let [lo, hi] = m.actuator_ctrlrange()[id];
        if !m.actuator_ctrllimited()[id] || lo >= hi || lo.is_nan() || hi.is_nan() {
            return Err(bad(
                file,
                "actuators",
                format!(
                    "actuator '{name}' has no control range: the action's bounds come from it; give it ctrlrange=\"low high\" in the model"
                ),
            ));
        }
        bounds.push((lo, hi));
    }
    Ok((ids, bounds))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The task's hash: its text, then each model file (path relative to the model's folder,
/// then contents) in the order found.
fn hash(text: &str, model: &ModelRef, file: &str) -> Result<String, SimError> {
    let mut h = Sha256::new();
    h.update(text.as_bytes());
    let (dir, main) = match model {
        ModelRef::Suite(f) => (crate::assets::suite_dir(), f.clone()),
        ModelRef::Gymnasium(f) => (crate::assets::gymnasium_dir(), f.clone()),
        ModelRef::Path(p) => (
            p.parent().unwrap_or(Path::new(".")).to_path_buf(),
            p.file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default(),
        ),
    };
    for rel in crate::assets::model_files(&dir, &main).map_err(|e| bad(file, "model", e))? {
        let bytes = std::fs::read(dir.join(&rel))
            .map_err(|e| bad(file, "model", format!("{}: {e}", dir.join(&rel).display())))?;
        h.update(rel.as_bytes());
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(&bytes);
    }
    Ok(hex(&h.finalize()))
}
