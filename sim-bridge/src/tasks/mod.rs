//! The ten Control Suite tasks: their fixed parameters (the table) and their logic (one module per
//! domain, each mirroring `dm_control/suite/<domain>.py`).

mod acrobot;
mod cartpole;
mod cheetah;
mod hopper;
mod pendulum;
pub(crate) mod randomizers;
mod walker;

use crate::TaskSpec;
use crate::error::SimError;
use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};

/// What a Control Suite task adds to the physics: `base.Task` minus the action plumbing.
pub(crate) trait Task: Send {
    /// `initialize_episode`: writes the initial state, drawing from the task's `RandomState`.
    /// Runs after `Physics::reset` and before the final forward pass, like dm_control's
    /// `reset_context`.
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut RandomState);
    /// `get_observation`, flattened in the OrderedDict's order into `obs` (`obs.len() == obs_dim`).
    fn observe(&self, physics: &Physics, obs: &mut [f64]);
    /// `get_reward`.
    fn reward(&self, physics: &Physics) -> f64;
    /// Before the physics steps with `action` (in the actuators' units): a task file
    /// evaluates its `prev(...)` values here.
    fn before_step(&mut self, _physics: &mut Physics, _action: &[f64]) {}
    /// After a step (and after a reset), before `observe`, `reward` and `terminated`: a
    /// task file evaluates its expressions here.
    fn after_step(&mut self, _physics: &mut Physics) {}
    /// True when the state is terminal (the episode ends with discount 0).
    fn terminated(&self) -> bool {
        false
    }
    /// What `observe` and `reward` need to be current after a control step (see [`Sync`]).
    fn sync(&self) -> Sync {
        Sync::Full
    }
}

/// The fixed facts of one task; `task_spec` derives the public [`TaskSpec`] from them without
/// loading MuJoCo, and `make` checks them against the loaded model.
pub(crate) struct Entry {
    pub name: &'static str,
    /// The model file stem (`cartpole` for `cartpole.xml`).
    pub domain: &'static str,
    pub obs_dim: usize,
    pub act_dim: usize,
    /// `opt.timestep` of the model file.
    pub timestep: f64,
    /// `n_sub_steps` dm_control derives from the task's control timestep (1 when it sets none).
    pub n_sub_steps: usize,
    /// The task's `time_limit` in seconds.
    pub time_limit: f64,
}

impl Entry {
    pub fn spec(&self) -> TaskSpec {
        // dm_control: control_timestep = timestep * n_sub_steps, and the episode ends at the
        // first step count >= time_limit / control_timestep.
        let control_timestep = self.timestep * self.n_sub_steps as f64;
        let limit = self.time_limit / control_timestep;
        TaskSpec {
            name: self.name.to_string(),
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            control_timestep,
            episode_steps: limit.ceil() as usize,
        }
    }

    /// Builds the task logic for a loaded model.
    pub fn build(&self, physics: &Physics) -> Result<Box<dyn Task>, SimError> {
        let name = self.name;
        Ok(match name {
            "cartpole-balance" => Box::new(cartpole::Balance::new(physics, name, false)?),
            "cartpole-swingup" => Box::new(cartpole::Balance::new(physics, name, true)?),
            "hopper-stand" => Box::new(hopper::Hopper::new(physics, name, false)?),
            "hopper-hop" => Box::new(hopper::Hopper::new(physics, name, true)?),
            "acrobot-swingup" => Box::new(acrobot::Balance::new(physics, name)?),
            "pendulum-swingup" => Box::new(pendulum::SwingUp::new(physics, name)?),
            "walker-stand" => Box::new(walker::PlanarWalker::new(physics, name, 0.0)?),
            "walker-walk" => Box::new(walker::PlanarWalker::new(
                physics,
                name,
                walker::WALK_SPEED,
            )?),
            "walker-run" => Box::new(walker::PlanarWalker::new(physics, name, walker::RUN_SPEED)?),
            "cheetah-run" => Box::new(cheetah::Cheetah::new(physics, name)?),
            _ => {
                return Err(SimError::UnknownTask {
                    task: name.to_string(),
                });
            }
        })
    }
}

/// The tasks, in `TASKS` order. Time limits, control timesteps and model timesteps are those of
/// dm_control 1.0.50 (`_DEFAULT_TIME_LIMIT`, `_CONTROL_TIMESTEP`, `<option timestep>`).
pub(crate) const ENTRIES: [Entry; 10] = [
    Entry {
        name: "cartpole-balance",
        domain: "cartpole",
        obs_dim: 5,
        act_dim: 1,
        timestep: 0.01,
        n_sub_steps: 1,
        time_limit: 10.0,
    },
    Entry {
        name: "cartpole-swingup",
        domain: "cartpole",
        obs_dim: 5,
        act_dim: 1,
        timestep: 0.01,
        n_sub_steps: 1,
        time_limit: 10.0,
    },
    Entry {
        name: "hopper-stand",
        domain: "hopper",
        obs_dim: 15,
        act_dim: 4,
        timestep: 0.005,
        n_sub_steps: 4,
        time_limit: 20.0,
    },
    Entry {
        name: "hopper-hop",
        domain: "hopper",
        obs_dim: 15,
        act_dim: 4,
        timestep: 0.005,
        n_sub_steps: 4,
        time_limit: 20.0,
    },
    Entry {
        name: "acrobot-swingup",
        domain: "acrobot",
        obs_dim: 6,
        act_dim: 1,
        timestep: 0.01,
        n_sub_steps: 1,
        time_limit: 10.0,
    },
    Entry {
        name: "pendulum-swingup",
        domain: "pendulum",
        obs_dim: 3,
        act_dim: 1,
        timestep: 0.02,
        n_sub_steps: 1,
        time_limit: 20.0,
    },
    Entry {
        name: "walker-stand",
        domain: "walker",
        obs_dim: 24,
        act_dim: 6,
        timestep: 0.0025,
        n_sub_steps: 10,
        time_limit: 25.0,
    },
    Entry {
        name: "walker-walk",
        domain: "walker",
        obs_dim: 24,
        act_dim: 6,
        timestep: 0.0025,
        n_sub_steps: 10,
        time_limit: 25.0,
    },
    Entry {
        name: "walker-run",
        domain: "walker",
        obs_dim: 24,
        act_dim: 6,
        timestep: 0.0025,
        n_sub_steps: 10,
        time_limit: 25.0,
    },
    Entry {
        name: "cheetah-run",
        domain: "cheetah",
        obs_dim: 17,
        act_dim: 6,
        timestep: 0.01,
        n_sub_steps: 1,
        time_limit: 10.0,
    },
];

/// The table entry of a task name.
pub(crate) fn entry(task: &str) -> Result<&'static Entry, SimError> {
    ENTRIES
        .iter()
        .find(|e| e.name == task)
        .ok_or_else(|| SimError::UnknownTask {
            task: task.to_string(),
        })
}

/// `physics.control()` through `tolerance(margin=1, value_at_margin=0, sigmoid='quadratic')`:
/// the small-control term of cartpole and hopper.
pub(crate) fn small_control(ctrl: f64) -> f64 {
    use crate::rewards::{Sigmoid, Tolerance};
    Tolerance {
        margin: 1.0,
        sigmoid: Sigmoid::Quadratic,
        value_at_margin: 0.0,
        ..Tolerance::default()
    }
    .eval(ctrl)
}
