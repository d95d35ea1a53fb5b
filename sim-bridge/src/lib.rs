//! MuJoCo and the DeepMind Control Suite tasks, reproduced exactly.
//!
//! Ten Control Suite tasks run on the real MuJoCo 3.17.0 through `mujoco-rs`, stepped with
//! dm_control 1.0.50's call sequence, seeded with numpy's legacy `RandomState` stream, so that a
//! seed and an action sequence give the same physics states as `suite.load(domain, task,
//! task_kwargs={'random': seed})` bit for bit (proved by `tests/dm_control_replay.rs`).
//!
//! The trainer uses [`make`] and the [`Environment`] trait in-process; after construction no call
//! allocates. The `sim-bridge` binary replays action files for cross-checks.
//!
//! (`no_run`: rustdoc builds doctests in a temporary directory, where the rpath to
//! `.deps/mujoco` does not reach; the same code runs in `tests/no_alloc.rs`.)
//! ```no_run
//! let mut env = sim_bridge::make("pendulum-swingup", 0)?;
//! let spec = env.spec().clone();
//! let mut obs = vec![0.0; spec.obs_dim];
//! env.reset(&mut obs);
//! let mut total = 0.0;
//! for t in 0..spec.episode_steps {
//!     let step = env.step(&[(t as f64 * 0.1).sin()], &mut obs);
//!     total += step.reward;
//!     assert_eq!(step.last, t + 1 == spec.episode_steps);
//! }
//! assert!(total >= 0.0);
//! # Ok::<(), sim_bridge::SimError>(())
//! ```

pub mod assets;
pub mod cli;
mod env;
mod error;
pub mod launcher;
mod logging;
pub mod numpy_generator;
pub mod numpy_rng;
pub mod physics;
pub mod randomizers;
#[cfg(feature = "render")]
pub mod render;
pub mod rewards;
mod task;
pub mod taskfile;

pub use env::SuiteEnv;
pub use error::{SETUP_COMMAND, SUITE_DIR_VAR, SimError};
pub use taskfile::{ExternalDef, Origin, TaskDef};

/// The fixed shape of a task.
#[derive(Clone, Debug, PartialEq)]
pub struct TaskSpec {
    /// The task's name, e.g. `cartpole-swingup` (a task file's `name`, or its file's stem).
    pub name: String,
    /// Length of the flattened observation (all of dm_control's observation arrays, in order).
    pub obs_dim: usize,
    /// Number of actuators.
    pub act_dim: usize,
    /// Seconds of simulated time per control step.
    pub control_timestep: f64,
    /// Control steps per episode (the time limit; a task file's `terminate` may end one
    /// earlier).
    pub episode_steps: usize,
}

/// The outcome of one control step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    pub reward: f64,
    /// 0.0 when a task file's `terminate` ended the episode in a terminal state, else 1.0 (the
    /// time limit is not a terminal state; the Control Suite tasks never terminate).
    pub discount: f64,
    /// True on the episode's last step (the time limit or a termination); `reset` must come
    /// next.
    pub last: bool,
}

/// A Control Suite task as the trainer sees it.
pub trait Environment: Send {
    fn spec(&self) -> &TaskSpec;
    /// Starts an episode; draws the initial state from the environment's random stream
    /// (seeded at construction; successive resets continue the stream, as in dm_control and in
    /// Gymnasium after `reset(seed=...)`). Writes the flattened observation.
    ///
    /// # Panics
    /// When the initial observation is not finite ([`Environment::try_reset`] reports it).
    fn reset(&mut self, obs: &mut [f64]);
    /// Applies one action (not clipped, as dm_control), advances one control step, writes the
    /// observation.
    ///
    /// # Panics
    /// On a wrong action width, a non-finite action, a step outside an episode (before the first
    /// `reset` or after the `last` step), or an invalid physics state (a MuJoCo warning such as
    /// a diverging simulation, where dm_control raises `PhysicsError`): the conditions
    /// [`Environment::try_step`] reports as errors.
    fn step(&mut self, action: &[f64], obs: &mut [f64]) -> Step;
    fn qpos(&self) -> &[f64];
    fn qvel(&self) -> &[f64];
    /// [`Environment::step`] that reports bad input as an error instead of panicking. The default
    /// (for test doubles) just calls `step`; [`SuiteEnv`] checks everything `step` would panic on.
    fn try_step(&mut self, action: &[f64], obs: &mut [f64]) -> Result<Step, SimError> {
        Ok(self.step(action, obs))
    }
    /// [`Environment::reset`] that reports a non-finite initial observation (a task file's
    /// `init` or observation out of its domain) as an error instead of panicking; no episode
    /// starts then. The default just calls `reset`.
    fn try_reset(&mut self, obs: &mut [f64]) -> Result<(), SimError> {
        self.reset(obs);
        Ok(())
    }
}

/// The built-in tasks' names (the repository's `tasks/*.toml`, in file-name order).
pub const TASKS: &[&str] = taskfile::BUILTIN_NAMES;

/// Loads the built-in task's model and seeds its `RandomState` with `seed`.
pub fn make(task: &str, seed: u32) -> Result<Box<dyn Environment>, SimError> {
    Ok(Box::new(SuiteEnv::new(task, seed)?))
}

/// The built-in task's shape.
pub fn task_spec(task: &str) -> Result<TaskSpec, SimError> {
    Ok(TaskDef::builtin(task)?.spec().clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_control_suite_task_is_a_task_file_of_dm_controls_shape() {
        // (task, observation size, action size) of dm_control 1.0.50; every episode 1000 steps.
        for (name, obs, act) in [
            ("acrobot-swingup", 6, 1),
            ("cartpole-balance", 5, 1),
            ("cartpole-swingup", 5, 1),
            ("cheetah-run", 17, 6),
            ("hopper-hop", 15, 4),
            ("hopper-stand", 15, 4),
            ("pendulum-swingup", 3, 1),
            ("walker-run", 24, 6),
            ("walker-stand", 24, 6),
            ("walker-walk", 24, 6),
        ] {
            assert!(TASKS.contains(&name), "{name}");
            let spec = task_spec(name).unwrap();
            assert_eq!(
                (spec.obs_dim, spec.act_dim, spec.episode_steps),
                (obs, act, 1000),
                "{name}"
            );
        }
    }

    #[test]
    fn unknown_task_lists_the_valid_ones() {
        let message = task_spec("cartpole-juggle").unwrap_err().to_string();
        assert!(message.contains("cartpole-juggle"), "{message}");
        for name in TASKS {
            assert!(message.contains(name), "{message}");
        }
    }
}
