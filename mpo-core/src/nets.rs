//! The networks as the algorithm's phases use them on one batch chunk of `BC` rows.
//!
//! The E-step ([`crate::estep`]) and policy evaluation ([`crate::evaluation`]) ask the target
//! networks two things, whatever their form: the target policy at a chunk's states, and the
//! target critic's values of a set of actions at those states. [`TargetNets`] is that
//! question; [`TargetPass`] answers it with the real networks and the chunk's [`Passes`]
//! buffers (the learner owns both). The critic's observation part is computed once per set
//! of states and reused for every set of actions there.

use bytemuck::Zeroable;

use crate::config::MpoConfig;
use crate::gaussian::Gaussian;
use crate::network::{PolicyTrain, ValueNet};

/// The target networks on one chunk of `BC` rows of `OBS` observations and `ACT` actions.
pub(crate) trait TargetNets<const OBS: usize, const ACT: usize, const BC: usize> {
    /// The target policy at each row's state `obs[n]` into `pi[n]`. The values asked next
    /// are at these states.
    fn policy_at(&mut self, obs: &[[f32; OBS]; BC], pi: &mut [Gaussian<ACT>; BC]);
    /// `Q'(s_n, actions[n])` for every row, at the states of the last [`Self::policy_at`].
    fn values(&mut self, actions: &[[f32; ACT]; BC]) -> [f32; BC];
}

/// The buffers of one chunk's network passes: tapes, the policy head's outputs, the critic's
/// observation part and its values. Shared by the phases one after the other.
#[derive(Zeroable)]
#[zeroable(bound = "")]
pub(crate) struct Passes<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
> {
    /// The actor's activations (the M-step backpropagates through the online actor's).
    pub atape: P::Tape<BC>,
    /// The critic's activations (the critic step backpropagates through the online one's).
    pub ctape: Q::Tape<BC>,
    /// The policy head's means (squashed when the head is).
    pub mean: [[f32; ACT]; BC],
    /// The policy head's raw Cholesky outputs.
    pub chol: [[f32; TRI]; BC],
    /// The critic's observation part at the current states.
    pub pre1: Q::StatePart<BC>,
    /// The critic's values (expectations of a categorical critic).
    pub q: [f32; BC],
    /// A clipped copy of actions (with `clip_critic_actions`).
    pub clipped: [[f32; ACT]; BC],
}

/// [`TargetNets`] by the target actor and critic, in a chunk's [`Passes`].
pub(crate) struct TargetPass<
    'a,
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
> {
    /// The target policy.
    pub actor: &'a P,
    /// The target critic.
    pub critic: &'a Q,
    /// `std_floor`, `clip_critic_actions` and what the critic reads.
    pub cfg: &'a MpoConfig,
    /// The chunk's buffers.
    pub buf: &'a mut Passes<OBS, ACT, TRI, P, Q, BC>,
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
> TargetNets<OBS, ACT, BC> for TargetPass<'_, OBS, ACT, TRI, P, Q, BC>
{
    fn policy_at(&mut self, obs: &[[f32; OBS]; BC], pi: &mut [Gaussian<ACT>; BC]) {
        let b = &mut *self.buf;
        self.actor
            .forward(obs, &mut b.atape, &mut b.mean, &mut b.chol);
        self.critic.state_part(obs, &mut b.pre1);
        for n in 0..BC {
            pi[n] = Gaussian::from_head(&b.mean[n], &b.chol[n], self.cfg.std_floor);
        }
    }

    fn values(&mut self, actions: &[[f32; ACT]; BC]) -> [f32; BC] {
        let b = &mut *self.buf;
        self.critic.values_from_state_part(
            &b.pre1,
            critic_input(self.cfg, actions, &mut b.clipped),
            &mut b.ctape,
            &mut b.q,
            self.cfg,
        );
        b.q
    }
}

/// The actions a critic pass is given: `a` itself, or (with `clip_critic_actions`) a copy in
/// `buf` clipped to `[-1, 1]`, what the plant applies.
pub(crate) fn critic_input<'a, const ACT: usize, const BC: usize>(
    cfg: &MpoConfig,
    a: &'a [[f32; ACT]; BC],
    buf: &'a mut [[f32; ACT]; BC],
) -> &'a [[f32; ACT]; BC] {
    if cfg.clip_critic_actions {
        *buf = *a;
        for x in buf.iter_mut().flatten() {
            *x = x.clamp(-1.0, 1.0);
        }
        buf
    } else {
        a
    }
}
