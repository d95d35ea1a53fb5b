//! What a task adds to the physics: the interface between the environment's episode
//! bookkeeping (`env.rs`) and a task's logic (`taskfile`).

use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};

/// What a Control Suite task adds to the physics: `base.Task` minus the action plumbing.
/// (dm_control's `base.Task` minus the action plumbing.)
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
