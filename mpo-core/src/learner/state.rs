//! What an update changes and a failed update restores: the online networks, their
//! optimisers and the duals.

use bytemuck::Zeroable;

use crate::actor::Actor;
use crate::adam::AdamState;
use crate::critic::Critic;
use crate::mstep::Duals;
use crate::params::Params;

/// Everything an update changes except the targets: what a failed update restores.
#[derive(Clone, Zeroable)]
pub struct Trainable<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
> {
    /// Online policy.
    pub actor: Actor<OBS, ACT, TRI, AH1, AH2>,
    /// Online critic.
    pub critic: Critic<OBS, ACT, QH1, QH2>,
    /// Actor Adam first moments.
    pub actor_m: Actor<OBS, ACT, TRI, AH1, AH2>,
    /// Actor Adam second moments.
    pub actor_v: Actor<OBS, ACT, TRI, AH1, AH2>,
    /// Critic Adam first moments.
    pub critic_m: Critic<OBS, ACT, QH1, QH2>,
    /// Critic Adam second moments.
    pub critic_v: Critic<OBS, ACT, QH1, QH2>,
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
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
> Trainable<OBS, ACT, TRI, AH1, AH2, QH1, QH2>
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
