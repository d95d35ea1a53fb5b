//! What an update changes and a failed update restores: the online networks, their
//! optimisers and the duals.

// `derive(Zeroable)` repeats the structs' bounds on the type parameters their fields are.
#![allow(clippy::multiple_bound_locations)]

use bytemuck::Zeroable;

use crate::adam::AdamState;
use crate::mstep::Duals;
use crate::network::{PolicyTrain, ValueNet};

/// Everything an update changes except the targets: what a failed update restores.
#[derive(Clone, Zeroable)]
#[zeroable(bound = "")]
pub struct Trainable<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
> {
    /// Online policy.
    pub actor: P,
    /// Online critic.
    pub critic: Q,
    /// Actor Adam first moments.
    pub actor_m: P,
    /// Actor Adam second moments.
    pub actor_v: P,
    /// Critic Adam first moments.
    pub critic_m: Q,
    /// Critic Adam second moments.
    pub critic_v: Q,
    /// Actor Adam state.
    pub actor_opt: AdamState,
    /// Critic Adam state.
    pub critic_opt: AdamState,
    /// Temperatures and multipliers.
    pub duals: Duals<ACT>,
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
> Trainable<OBS, ACT, TRI, P, Q>
{
    /// Copies every field in place (no temporary on the stack).
    pub fn copy_from(&mut self, o: &Self) {
        self.actor.copy_from(&o.actor);
        self.critic.copy_from(&o.critic);
        self.actor_m.copy_from(&o.actor_m);
        self.actor_v.copy_from(&o.actor_v);
        self.critic_m.copy_from(&o.critic_m);
        self.critic_v.copy_from(&o.critic_v);
        self.actor_opt = o.actor_opt;
        self.critic_opt = o.critic_opt;
        self.duals = o.duals;
    }
}
