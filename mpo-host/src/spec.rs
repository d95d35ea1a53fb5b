//! Learner instantiations: a row's compile-time sizes as one type.
//!
//! The learner's sizes are const generics (observation, action, the networks' widths, batch,
//! samples, replay capacity): the firmware, the zero-allocation core and the kernels' speed
//! depend on it. A [`Spec`] names one list of sizes; [`spec!`](crate::spec!) writes it from the
//! numbers (the Cholesky head's `TRI` and the chunk rows `BC` are computed), and its
//! [`Instance`] holds function pointers into the code monomorphised for those sizes: a trainer,
//! a policy loader for the inference commands (which never build a learner), a controller.
//! Everything above them (the training loop, evaluation, checkpoints' files, the commands) is
//! compiled once and works through [`crate::training::Training`] and
//! [`crate::policy::Policy`].
//!
//! Which sizes a build has: [`crate::registry`].

use crate::checkpoint::{CheckpointError, Verified};
use crate::policy::Policy;
pub use crate::sizes::Sizes;
use crate::training::{TrainError, Training, TrainingInit};

/// What the controller process needs to serve a policy of these sizes.
pub type ServeFn = fn(
    &mpo_link::controller::ControllerOptions,
    &mut dyn FnMut(),
) -> Result<mpo_link::controller::ControllerStats, mpo_link::LinkError>;

/// Function pointers into the code compiled for one list of sizes.
#[derive(Clone, Copy)]
pub struct Instance {
    /// The sizes.
    pub sizes: Sizes,
    /// A trainer for a run of these sizes (fresh or resumed).
    pub trainer: fn(TrainingInit<'_>) -> Result<Box<dyn Training>, TrainError>,
    /// The online policy of a checkpoint of these sizes (the actor only: no learner is built).
    pub policy: fn(&Verified) -> Result<Box<dyn Policy>, CheckpointError>,
    /// Serves a policy of these sizes in the controller process.
    pub serve: ServeFn,
    /// Runs a fleet's plant with a policy of these sizes (`mpo plant-worker`).
    pub plant: PlantFn,
}

/// What a fleet's plant process runs for a policy of some sizes; returns its steps.
pub type PlantFn = fn(&crate::fleet::worker::WorkerInit<'_>) -> Result<u64, String>;

impl std::fmt::Debug for Instance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Instance")
            .field("sizes", &self.sizes)
            .finish_non_exhaustive()
    }
}

impl Instance {
    /// The instance of `S`.
    pub fn of<S: Spec>() -> Self {
        S::instance()
    }
}

/// One list of sizes as a type. Written by [`spec!`](crate::spec!), not by hand.
pub trait Spec: 'static {
    /// The sizes.
    const SIZES: Sizes;
    /// The policy network: what the firmware and the controller run.
    type Policy;
    /// The critic.
    type Critic;
    /// The whole learning state on the host: learner, replay, random streams.
    type Agent;
    /// Function pointers into the code compiled for these sizes.
    fn instance() -> Instance;
}

/// True when a batch of `b` rows splits into `c` equal chunks (the check [`spec!`] makes at
/// compile time).
pub const fn splits(b: usize, c: usize) -> bool {
    c > 0 && b.is_multiple_of(c)
}

/// Declares learner instantiations: each line a [`Spec`] type of the given sizes.
///
/// ```
/// mpo_host::spec! {
///     /// My robot: 11 observations, 1 action.
///     pub MyRobot = obs 11, act 1, actor [256, 256], critic [256, 256], batch 256 / 4,
///         seq 8, samples 20 20, replay 1_000_000;
///     /// The same robot with residual networks and a categorical critic of 101 atoms.
///     pub MyRobotSimba = obs 11, act 1, actor [128, 256] x 1, critic [256, 512] x 2, bins 101,
///         batch 256 / 4, seq 8, samples 20 20, replay 1_000_000;
/// }
/// use mpo_host::spec::Spec;
/// assert_eq!(MyRobot::SIZES.tri(), 1);
/// assert_eq!(MyRobotSimba::SIZES.critic_blocks, 2);
/// assert_eq!(MyRobotSimba::SIZES.bins, 101);
/// ```
///
/// `actor [A1, A2]` is a two-layer MLP of those widths; `actor [W, F] x D` a residual network
/// (`mpo_core::residual`) of width `W` with `D` blocks of inner width `F`; the same for the
/// critic. `bins K` (optional) makes the critic categorical over `K` atoms
/// (`mpo_core::value_head`); without it the critic outputs one value. `batch B / C` splits the
/// batch into `C` equal chunks (one thread's work each); `samples M N` are the E-step's action
/// samples per state and the policy-evaluation targets' next-action samples.
#[macro_export]
macro_rules! spec {
    ($( $(#[$doc:meta])* $vis:vis $name:ident = obs $obs:literal, act $act:literal,
        actor [$a1:literal, $a2:literal] $(x $ad:literal)?,
        critic [$q1:literal, $q2:literal] $(x $qd:literal)?, $(bins $k:literal,)?
        batch $b:literal / $c:literal, seq $l:literal, samples $m:literal $n:literal,
        replay $cap:literal; )*) => {$(
        $(#[$doc])*
        $vis struct $name;
        impl $crate::spec::Spec for $name {
            const SIZES: $crate::spec::Sizes = $crate::spec::Sizes {
                obs: $obs, act: $act, actor: [$a1, $a2], critic: [$q1, $q2], batch: $b,
                chunks: $c, seq: $l, m: $m, n: $n, replay_capacity: $cap,
                actor_blocks: 0 $(+ $ad)?, critic_blocks: 0 $(+ $qd)?, bins: 1 $(- 1 + $k)?,
            };
            type Policy = $crate::__spec_policy!($obs, $act, $a1, $a2, [$($ad)?]);
            type Critic = $crate::__spec_critic!($obs, $act, $q1, $q2, [$($qd)?], [$($k)?]);
            type Agent = $crate::reexport::AgentOf<
                $obs, $act, { $act * ($act + 1) / 2 }, Self::Policy, Self::Critic, { $b / $c },
                $c, $l, $m, $n, $cap,
            >;
            fn instance() -> $crate::spec::Instance {
                const { assert!($crate::spec::splits($b, $c), "the batch must split into equal chunks") };
                $crate::spec::Instance {
                    sizes: <Self as $crate::spec::Spec>::SIZES,
                    trainer: $crate::trainer::Trainer::<
                        $obs, $act, { $act * ($act + 1) / 2 }, Self::Policy, Self::Critic,
                        { $b / $c }, $c, $l, $m, $n, $cap,
                    >::boxed,
                    policy: $crate::policy::load::<$obs, $act, { $act * ($act + 1) / 2 }, Self::Policy>,
                    serve: $crate::policy::serve::<$obs, $act, { $act * ($act + 1) / 2 }, Self::Policy>,
                    plant: $crate::fleet::worker::run::<$obs, $act, { $act * ($act + 1) / 2 }, Self::Policy>,
                }
            }
        }
    )*};
}

/// The policy type of a [`spec!`] line: the two-layer actor, or with a block count the
/// residual one.
#[doc(hidden)]
#[macro_export]
macro_rules! __spec_policy {
    ($obs:literal, $act:literal, $a1:literal, $a2:literal, []) => {
        $crate::reexport::Actor<$obs, $act, { $act * ($act + 1) / 2 }, $a1, $a2>
    };
    ($obs:literal, $act:literal, $a1:literal, $a2:literal, [$d:literal]) => {
        $crate::reexport::ResidualActor<$obs, $act, { $act * ($act + 1) / 2 }, $a1, $a2, $d>
    };
}

/// The critic type of a [`spec!`] line: two-layer or residual, scalar or categorical.
#[doc(hidden)]
#[macro_export]
macro_rules! __spec_critic {
    ($obs:literal, $act:literal, $q1:literal, $q2:literal, [], []) => {
        $crate::reexport::Critic<$obs, $act, $q1, $q2, 1>
    };
    ($obs:literal, $act:literal, $q1:literal, $q2:literal, [], [$k:literal]) => {
        $crate::reexport::Critic<$obs, $act, $q1, $q2, $k>
    };
    ($obs:literal, $act:literal, $q1:literal, $q2:literal, [$d:literal], []) => {
        $crate::reexport::ResidualCritic<$obs, $act, $q1, $q2, $d, 1>
    };
    ($obs:literal, $act:literal, $q1:literal, $q2:literal, [$d:literal], [$k:literal]) => {
        $crate::reexport::ResidualCritic<$obs, $act, $q1, $q2, $d, $k>
    };
}
