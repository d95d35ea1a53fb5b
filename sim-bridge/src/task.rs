//! What a task adds to the physics: the interface between the environment's episode
//! bookkeeping (`env.rs`) and a task's logic (`taskfile`).

use crate::numpy_generator::Generator;
use crate::numpy_rng::RandomState;
use crate::physics::{Physics, Sync};

/// The random stream a task draws its initial states from: numpy's legacy `RandomState`
/// (dm_control's tasks) or `Generator(PCG64)` (Gymnasium's), each seeded as its library seeds
/// it, so a seed gives that library's initial states.
// One per environment: the 2.5 KiB of MT19937 state inline is no cost worth a Box.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub(crate) enum Random {
    /// `np.random.RandomState(seed)` (`convention = "dm_control"`).
    Legacy(RandomState),
    /// `np.random.Generator(PCG64(SeedSequence(seed)))` (`convention = "gymnasium"`).
    Generator(Generator),
}

impl Random {
    /// `uniform(low, high)`: `low + (high - low) * u` in both.
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        match self {
            Random::Legacy(r) => r.uniform(low, high),
            Random::Generator(g) => g.uniform(low, high),
        }
    }

    /// `standard_normal()`: polar Box-Muller (legacy) or the ziggurat (Generator).
    pub fn standard_normal(&mut self) -> f64 {
        match self {
            Random::Legacy(r) => r.standard_normal(),
            Random::Generator(g) => g.standard_normal(),
        }
    }
}

/// What a Control Suite task adds to the physics: `base.Task` minus the action plumbing.
/// (dm_control's `base.Task` minus the action plumbing.)
pub(crate) trait Task: Send {
    /// `initialize_episode`: writes the initial state, drawing from the task's random stream.
    /// Runs after `Physics::reset` and before the final forward pass, like dm_control's
    /// `reset_context`.
    fn initialize_episode(&mut self, physics: &mut Physics, random: &mut Random);
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
    /// The task file's key of observation element `index` (for error messages).
    fn observation_key(&self, _index: usize) -> String {
        "observation".into()
    }
    /// True when the state is terminal (the episode ends with discount 0).
    fn terminated(&self) -> bool {
        false
    }
    /// What `observe` and `reward` need to be current after a control step (see [`Sync`]).
    fn sync(&self) -> Sync {
        Sync::Full
    }
}
