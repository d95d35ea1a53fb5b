//! `rl/control.py`'s `Environment` for one task: episode bookkeeping around physics and task.

use crate::error::SimError;
use crate::numpy_generator::Generator;
use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};
use crate::task::{Random, Task};
use crate::{Environment, Step, TaskSpec};

/// A MuJoCo environment: model, task logic (a task file's, or during the move to files a
/// Rust one), the task's random stream and the step count.
pub struct SuiteEnv {
    spec: TaskSpec,
    physics: Physics,
    task: Box<dyn Task>,
    random: Random,
    n_sub_steps: usize,
    /// How much state the task needs refreshed after each step.
    sync: Sync,
    /// Gymnasium's call sequence instead of dm_control's.
    gymnasium: bool,
    /// Actuator ids the action drives, in action order.
    actuators: Vec<usize>,
    /// Per action dimension `(mid, half)`: ctrl = mid + action * half; `None` writes the
    /// action to ctrl unchanged (every range `[-1, 1]`, the Control Suite's).
    scale: Option<Vec<(f64, f64)>>,
    /// The action in the actuators' units (scratch, sized once).
    ctrl: Vec<f64>,
    /// The task file, for error messages.
    file: String,
    /// Control steps taken in the current episode; `None` outside an episode.
    step_count: Option<usize>,
}

/// What [`SuiteEnv::from_parts`] assembles.
pub(crate) struct Parts {
    pub spec: TaskSpec,
    pub physics: Physics,
    pub task: Box<dyn Task>,
    pub seed: u32,
    pub n_sub_steps: usize,
    pub gymnasium: bool,
    pub actuators: Vec<usize>,
    pub scale: Option<Vec<(f64, f64)>>,
    pub file: String,
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
    /// The built-in task `task` (`tasks/<task>.toml`), its `RandomState` seeded with `seed`.
    pub fn new(task: &str, seed: u32) -> Result<Self, SimError> {
        crate::TaskDef::builtin(task)?.make(seed)
    }

    pub(crate) fn from_parts(p: Parts) -> Self {
        let sync = p.task.sync();
        let act = p.actuators.len();
        Self {
            spec: p.spec,
            physics: p.physics,
            task: p.task,
            // Each library's seeding: dm_control's `RandomState(seed)`, Gymnasium's
            // `reset(seed=seed)` (`Generator(PCG64(SeedSequence(seed)))`).
            random: if p.gymnasium {
                Random::Generator(Generator::new(u64::from(p.seed)))
            } else {
                Random::Legacy(RandomState::new(p.seed))
            },
            n_sub_steps: p.n_sub_steps,
            sync,
            gymnasium: p.gymnasium,
            actuators: p.actuators,
            scale: p.scale,
            ctrl: vec![0.0; act],
            file: p.file,
            step_count: None,
        }
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
                task: self.spec.name.clone(),
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

impl SuiteEnv {
    fn non_finite(&self, key: String, value: f64, step: usize) -> SimError {
        let (q, v) = (self.physics.qpos(), self.physics.qvel());
        let finite = q.iter().chain(v).all(|x| x.is_finite());
        SimError::NonFinite {
            file: crate::error::one_line(&self.file),
            key: crate::error::one_line(&key),
            value,
            step,
            detail: match (finite, step) {
                (true, 0) => "after the initial state, which is finite: an expression of the file divides by zero or leaves its domain".into(),
                (true, _) => "the state is finite: an expression of the file divides by zero or leaves its domain".into(),
                (false, 0) => "the initial state is not finite: see the file's init".into(),
                (false, _) => "the simulation diverged".into(),
            },
        }
    }

    /// The first non-finite reward or observation element of the current state, as an error.
    fn check_values(&self, reward: Option<f64>, obs: &[f64], step: usize) -> Result<(), SimError> {
        if let Some(r) = reward.filter(|r| !r.is_finite()) {
            return Err(self.non_finite("reward".into(), r, step));
        }
        match obs.iter().position(|v| !v.is_finite()) {
            Some(i) => Err(self.non_finite(self.task.observation_key(i), obs[i], step)),
            None => Ok(()),
        }
    }
}

impl Environment for SuiteEnv {
    fn spec(&self) -> &TaskSpec {
        &self.spec
    }

    fn reset(&mut self, obs: &mut [f64]) {
        if let Err(e) = self.try_reset(obs) {
            panic!("{e}");
        }
    }

    fn try_reset(&mut self, obs: &mut [f64]) -> Result<(), SimError> {
        assert_eq!(obs.len(), self.spec.obs_dim, "observation buffer length");
        self.physics.reset();
        self.task
            .initialize_episode(&mut self.physics, &mut self.random);
        if self.gymnasium {
            // `set_state`: mj_forward with the controls the reset left.
            self.physics.forward();
        } else {
            // `with physics.reset_context(): task.initialize_episode(physics)`.
            self.physics.forward_without_actuation();
        }
        self.ctrl.iter_mut().for_each(|c| *c = 0.0);
        self.task.before_step(&mut self.physics, &self.ctrl);
        self.task.after_step(&mut self.physics);
        self.task.observe(&self.physics, obs);
        // A non-finite initial state (an `init` expression out of its domain) starts no episode.
        self.step_count = None;
        self.check_values(None, obs, 0)?;
        self.step_count = Some(0);
        Ok(())
    }

    fn step(&mut self, action: &[f64], obs: &mut [f64]) -> Step {
        match self.try_step(action, obs) {
            Ok(step) => step,
            Err(e) => panic!("{e}"),
        }
    }

    fn try_step(&mut self, action: &[f64], obs: &mut [f64]) -> Result<Step, SimError> {
        self.check(action, obs)?;
        match &self.scale {
            None => self.ctrl.copy_from_slice(action),
            Some(s) => {
                for ((c, a), (mid, half)) in self.ctrl.iter_mut().zip(action).zip(s) {
                    *c = mid + a * half;
                }
            }
        }
        self.task.before_step(&mut self.physics, &self.ctrl);
        // `task.before_step` (set_control: copied as given, unclipped), `physics.step`.
        for (&id, &c) in self.actuators.iter().zip(&self.ctrl) {
            self.physics.ctrl_mut()[id] = c;
        }
        let warnings = self.physics.warning_counts();
        if self.gymnasium {
            self.physics.step_gymnasium(self.n_sub_steps);
        } else {
            self.physics.step_synced(self.n_sub_steps, self.sync);
        }
        if let Some(warnings) = self.physics.new_warnings(&warnings) {
            // Like dm_control's PhysicsError: the episode cannot continue.
            self.step_count = None;
            return Err(SimError::PhysicsError { warnings });
        }
        self.task.after_step(&mut self.physics);
        let reward = self.task.reward(&self.physics);
        self.task.observe(&self.physics, obs);
        let count = self.step_count.map_or(1, |n| n + 1);
        if let Err(e) = self.check_values(Some(reward), obs, count) {
            self.step_count = None;
            return Err(e);
        }
        let terminated = self.task.terminated();
        let last = terminated || count >= self.spec.episode_steps;
        self.step_count = if last { None } else { Some(count) };
        Ok(Step {
            reward,
            discount: if terminated { 0.0 } else { 1.0 },
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
