//! Where a task's environments come from: MuJoCo in this process, or an external plant (a
//! task file with `plant = "external"`: another program steps it and answers over iceoryx2,
//! `mpo_link::external`, docs/external-plant.md).
//!
//! Training, evaluation and `mpo run` take every environment from [`make`]. For an external
//! plant the first call connects: it starts the task file's `[external] command` (or attaches
//! to the plant program run by hand with `--attach-plant RUN_ID`), checks the plant's sizes
//! against the file's, and keeps the connection for the rest of the command; every
//! environment (one per seed: the training environment, a fresh one per evaluation episode)
//! is an instance on that one connection. The connection ends (BYE, the program stopped, the
//! run's files removed) when the command's [`Session`] ends.
//!
//! The policy acts in `[-1, 1]`; the action is mapped linearly onto the task file's
//! `action_low`/`action_high` here, so the plant receives its own units.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use clap::Args;
use mpo_link::RunId;
use mpo_link::external::{Expected, ExternalOptions, ExternalPlant, PlantCommand};
use sim_bridge::{Environment, SimError, Step, TaskDef, TaskSpec};

/// `--attach-plant`, for the commands that step a plant.
#[derive(Debug, Clone, Default, Args)]
pub struct PlantArgs {
    /// With a task file of an external plant: attach to its program, started by hand with
    /// this run id (letters, digits, '-'), instead of starting the file's `[external] command`.
    #[arg(long, value_name = "RUN_ID")]
    pub attach_plant: Option<String>,
}

/// The command's connections to external plants.
struct Registry {
    /// `--attach-plant`.
    attach: Option<String>,
    /// By task file hash: the connection.
    plants: Vec<(String, Arc<Mutex<ExternalPlant>>)>,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry {
    attach: None,
    plants: Vec::new(),
});

fn registry() -> MutexGuard<'static, Registry> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// The external plants of one command: connections are made on demand by [`make`] and end
/// when this is dropped.
#[must_use = "the plants' connections end when the session is dropped"]
pub struct Session(());

impl Session {
    /// Starts the session of a command with these plant flags (its `--attach-plant`, if
    /// any; `None` for a command that has none).
    pub fn begin(args: Option<&PlantArgs>) -> Self {
        registry().attach = args.and_then(|a| a.attach_plant.clone());
        Self(())
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        shutdown();
    }
}

/// Ends every connection (BYE; a started program is given 5 s to exit, then killed).
pub fn shutdown() {
    let plants = std::mem::take(&mut registry().plants);
    drop(plants);
}

/// A fresh environment of `task` whose random stream is seeded with `seed`: the task's MuJoCo
/// simulation, or an instance of its external plant (connected on first use).
pub fn make(task: &TaskDef, seed: u32) -> Result<Box<dyn Environment>, SimError> {
    if !task.is_external() {
        if let Some(id) = &registry().attach {
            return Err(SimError::External(format!(
                "--attach-plant {id}: the task `{}` is simulated here, not an external plant",
                task.name()
            )));
        }
        return Ok(Box::new(task.make(seed)?));
    }
    let plant = connection(task)?;
    let id = lock(&plant).new_env();
    let spec = task.spec().clone();
    let scale = task
        .action_bounds()
        .iter()
        .map(|&(lo, hi)| ((lo + hi) / 2.0, (hi - lo) / 2.0))
        .collect();
    Ok(Box::new(ExternalEnv {
        plant,
        id,
        seed,
        fresh: true,
        ctrl: vec![0.0; spec.act_dim],
        spec,
        scale,
        step_count: None,
        failed: None,
    }))
}

fn lock(p: &Mutex<ExternalPlant>) -> MutexGuard<'_, ExternalPlant> {
    p.lock().unwrap_or_else(|e| e.into_inner())
}

/// The connection to `task`'s plant: the existing one, or a new one.
fn connection(task: &TaskDef) -> Result<Arc<Mutex<ExternalPlant>>, SimError> {
    let mut reg = registry();
    if let Some((_, p)) = reg.plants.iter().find(|(k, _)| k == task.sha256()) {
        return Ok(p.clone());
    }
    let file = task.file_label();
    let def = task
        .external_plant()
        .ok_or_else(|| SimError::External(format!("{file}: not an external plant")))?;
    let spec = task.spec();
    let expected = Expected {
        task: task.name().into(),
        obs: spec.obs_dim,
        act: spec.act_dim,
        episode_steps: spec.episode_steps,
        bounds: task.action_bounds().to_vec(),
    };
    let opts = ExternalOptions {
        connect_timeout: Duration::from_secs_f64(def.connect_timeout),
        timeout: Duration::from_secs_f64(def.timeout),
    };
    let plant = match (&reg.attach, &def.command) {
        (Some(id), _) => {
            let run = RunId::parse(id).map_err(|e| SimError::External(format!("--attach-plant: {e}")))?;
            eprintln!("{file}: waiting for the plant program of run id {id}");
            ExternalPlant::attach(run, expected, opts, &file)
        }
        (None, Some(argv)) => {
            let cmd = PlantCommand {
                argv: argv.clone(),
                dir: def.dir.clone(),
            };
            ExternalPlant::start(&cmd, expected, opts, &file)
        }
        (None, None) => {
            return Err(SimError::External(format!(
                "{file}: external.command: missing: give the plant's program ([external] command = [\"python3\", \"-m\", \"mpo_plant\", \"--gym\", \"Pendulum-v1\"]), or start it by hand and pass --attach-plant RUN_ID"
            )));
        }
    }
    .map_err(|e| SimError::External(e.0))?;
    eprintln!(
        "{file}: external plant `{}` connected (run id {}{})",
        plant.info().name,
        plant.run_id().as_str(),
        plant
            .pid()
            .map(|p| format!(", pid {p}"))
            .unwrap_or_default()
    );
    let plant = Arc::new(Mutex::new(plant));
    reg.plants.push((task.sha256().into(), plant.clone()));
    Ok(plant)
}

/// One environment instance of an external plant.
struct ExternalEnv {
    plant: Arc<Mutex<ExternalPlant>>,
    id: u64,
    seed: u32,
    /// Until the first reset: the plant makes the instance and seeds it then.
    fresh: bool,
    spec: TaskSpec,
    /// Per action dimension `(mid, half)`: the plant's action = mid + action * half.
    scale: Vec<(f64, f64)>,
    /// The action in the plant's units (scratch, sized once).
    ctrl: Vec<f64>,
    step_count: Option<usize>,
    /// A failed reset, reported by the next step (`reset` cannot return an error).
    failed: Option<String>,
}

impl Environment for ExternalEnv {
    fn spec(&self) -> &TaskSpec {
        &self.spec
    }

    fn reset(&mut self, obs: &mut [f64]) {
        assert_eq!(obs.len(), self.spec.obs_dim, "observation buffer length");
        let r = lock(&self.plant).reset(self.id, self.seed as u64, self.fresh, obs);
        match r {
            Ok(()) => {
                self.fresh = false;
                self.step_count = Some(0);
            }
            Err(e) => {
                obs.fill(0.0);
                self.failed = Some(e.0);
                self.step_count = None;
            }
        }
    }

    fn step(&mut self, action: &[f64], obs: &mut [f64]) -> Step {
        match self.try_step(action, obs) {
            Ok(s) => s,
            Err(e) => panic!("{e}"),
        }
    }

    fn try_step(&mut self, action: &[f64], obs: &mut [f64]) -> Result<Step, SimError> {
        if let Some(m) = self.failed.take() {
            return Err(SimError::External(m));
        }
        if action.len() != self.spec.act_dim {
            return Err(SimError::ActionWidth {
                task: self.spec.name.clone(),
                expected: self.spec.act_dim,
                got: action.len(),
            });
        }
        if let Some((index, &value)) = action.iter().enumerate().find(|(_, a)| !a.is_finite()) {
            return Err(SimError::NonFiniteAction { index, value });
        }
        assert_eq!(obs.len(), self.spec.obs_dim, "observation buffer length");
        let count = match self.step_count {
            Some(n) if n < self.spec.episode_steps => n + 1,
            _ => {
                return Err(SimError::EpisodeOver {
                    steps: self.spec.episode_steps,
                });
            }
        };
        for ((c, a), (mid, half)) in self.ctrl.iter_mut().zip(action).zip(&self.scale) {
            *c = mid + a * half;
        }
        let r = lock(&self.plant).step(self.id, &self.ctrl, obs);
        let s = r.map_err(|e| {
            self.step_count = None;
            SimError::External(e.0)
        })?;
        // The task file's episode length ends the episode if the plant does not.
        let last = s.last || count >= self.spec.episode_steps;
        self.step_count = if last { None } else { Some(count) };
        Ok(Step {
            reward: s.reward,
            discount: s.discount,
            last,
        })
    }

    fn qpos(&self) -> &[f64] {
        &[]
    }

    fn qvel(&self) -> &[f64] {
        &[]
    }
}

impl Drop for ExternalEnv {
    fn drop(&mut self) {
        lock(&self.plant).close(self.id);
    }
}
