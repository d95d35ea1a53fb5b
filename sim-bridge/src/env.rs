//! `rl/control.py`'s `Environment` for one task: episode bookkeeping around physics and task.

use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};
use crate::tasks::{self, Task};
use crate::{Environment, Step, TaskSpec};

/// A Control Suite environment: model, task logic, the task's `RandomState` and the step count.
pub struct SuiteEnv {
    spec: TaskSpec,
    physics: Physics,
    task: Box<dyn Task>,
    random: RandomState,
    n_sub_steps: usize,
    /// How much state the task needs refreshed after each step.
    sync: Sync,
    /// Control steps taken in the current episode; `None` outside an episode.
    step_count: Option<usize>,
}

impl std::fmt::Debug for SuiteEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SuiteEnv")
            .field("spec", &self.spec)
            .field("step_count", &self.step_count)
            .finish()
    }
}

impl SuiteEnv {
    /// Loads the model, checks it against the task table and seeds the task's `RandomState`.
    pub fn new(task: &str, seed: u32) -> Result<Self, SimError> {
        let entry = tasks::entry(task)?;
        let physics = Physics::load(entry.domain)?;
        let name = entry.name;
        let model = physics.model().ffi();
        let mismatch = |detail: String| Err(SimError::ModelMismatch { task: name, detail });
        if physics.timestep() != entry.timestep {
            return mismatch(format!(
                "timestep {} (expected {})",
                physics.timestep(),
                entry.timestep
            ));
        }
        if model.nu as usize != entry.act_dim {
            return mismatch(format!(
                "{} actuators (expected {})",
                model.nu, entry.act_dim
            ));
        }
        let task_logic = entry.build(&physics)?;
        let sync = task_logic.sync();
        Ok(Self {
            sync,
            spec: entry.spec(),
            physics,
            task: task_logic,
            random: RandomState::new(seed),
            n_sub_steps: entry.n_sub_steps,
            step_count: None,
        })
    }

    /// The simulation, for benchmarks and diagnostics.
    pub fn physics(&self) -> &Physics {
        &self.physics
    }

    /// Mutable simulation access (the benchmark steps it raw).
    pub fn physics_mut(&mut self) -> &mut Physics {
        &mut self.physics
    }

    /// `n_sub_steps`: physics steps per control step.
    pub fn n_sub_steps(&self) -> usize {
        self.n_sub_steps
    }

    /// The [`Sync`] the task steps with.
    pub fn sync(&self) -> Sync {
        self.sync
    }

    /// The reward of the current state (dm_control's `task.get_reward(physics)`).
    pub fn reward(&self) -> f64 {
        self.task.reward(&self.physics)
    }

    fn check(&self, action: &[f64], obs: &[f64]) -> Result<(), SimError> {
        if action.len() != self.spec.act_dim {
            return Err(SimError::ActionWidth {
                task: self.spec.name,
                expected: self.spec.act_dim,
                got: action.len(),
            });
        }
        if let Some((index, &value)) = action.iter().enumerate().find(|(_, a)| !a.is_finite()) {
            return Err(SimError::NonFiniteAction { index, value });
        }
        assert_eq!(obs.len(), self.spec.obs_dim, "observation buffer length");
        match self.step_count {
            Some(n) if n < self.spec.episode_steps => Ok(()),
            _ => Err(SimError::EpisodeOver {
                steps: self.spec.episode_steps,
            }),
        }
    }
}

impl Environment for SuiteEnv {
    fn spec(&self) -> &TaskSpec {
        &self.spec
    }

    fn reset(&mut self, obs: &mut [f64]) {
        assert_eq!(obs.len(), self.spec.obs_dim, "observation buffer length");
        // `with physics.reset_context(): task.initialize_episode(physics)`.
        self.physics.reset();
        self.task
            .initialize_episode(&mut self.physics, &mut self.random);
        self.physics.forward_without_actuation();
        self.task.observe(&self.physics, obs);
        self.step_count = Some(0);
    }

    fn step(&mut self, action: &[f64], obs: &mut [f64]) -> Step {
        match self.try_step(action, obs) {
            Ok(step) => step,
            Err(e) => panic!("{e}"),
        }
    }

    fn try_step(&mut self, action: &[f64], obs: &mut [f64]) -> Result<Step, SimError> {
        self.check(action, obs)?;
        // `task.before_step` (set_control: copied as given, unclipped), `physics.step`.
        self.physics.ctrl_mut().copy_from_slice(action);
        let warnings = self.physics.warning_counts();
        self.physics.step_synced(self.n_sub_steps, self.sync);
        if let Some(warnings) = self.physics.new_warnings(&warnings) {
            // Like dm_control's PhysicsError: the episode cannot continue.
            self.step_count = None;
            return Err(SimError::PhysicsError { warnings });
        }
        let reward = self.task.reward(&self.physics);
        self.task.observe(&self.physics, obs);
        let count = self.step_count.map_or(1, |n| n + 1);
        let last = count >= self.spec.episode_steps;
        self.step_count = if last { None } else { Some(count) };
        Ok(Step {
            reward,
            discount: 1.0,
            last,
        })
    }

    fn qpos(&self) -> &[f64] {
        self.physics.qpos()
    }

    fn qvel(&self) -> &[f64] {
        self.physics.qvel()
    }
}
