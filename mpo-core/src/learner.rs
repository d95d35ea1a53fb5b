//! The MPO learner: policy evaluation, E-step and M-step over one sampled batch.
//!
//! One [`Learner::update`] on a batch of `B` transitions:
//! 1. **Policy evaluation** (TD(0), the report's method): for each next state, `N` actions
//!    from the target policy, `y = r + bootstrap * mean_j Q_target(s', a'_j)`; one Adam step
//!    on `0.5 mean (Q(s, a) - y)^2`.
//! 2. **E-step** (paper eq. 7-8): `M` actions per state from the target policy, their values
//!    under the target critic, the temperature from the dual ([`crate::estep`]) and the
//!    weights `q_ij = softmax_j(Q_ij / eta*)`.
//! 3. **M-step** (paper eq. 9-10 with the decoupled constraints of ALGORITHM-NOTES.md item 1),
//!    `mstep_iters` times: minimise
//!    the sum of `alpha_mu KL_mu + alpha_Sigma KL_Sigma` and the weighted negative
//!    log-likelihood `(1/B) sum_ij q_ij [ln N(a_ij; mu_theta, Sigma_old) + ln N(a_ij; mu_old, Sigma_theta)]`
//!    (with a minus sign) over the actor (multipliers held constant: a stop-gradient), and
//!    `alpha (eps - KL)` over the multipliers (KLs held constant), with
//!    `KL_mu = KL(pi_old || N(mu_theta, Sigma_old))` and
//!    `KL_Sigma = KL(pi_old || N(mu_old, Sigma_theta))`. The multipliers are `exp(raw)`
//!    (clamped to `[e^-18, e^18]`), so they stay `>= 0` and Adam changes them by a factor per
//!    step rather than by an amount: a multiplier that must grow (or shrink) by orders of
//!    magnitude gets there in tens of updates.
//! 4. Every `target_period` updates the target networks take the online parameters.
//!
//! "Old" is the target policy throughout. Shapes: `B` batch, `M` E-step samples per state,
//! `N` next-action samples per next state. Everything lives in the struct: construct it zeroed
//! (`bytemuck::zeroed_box` on a host, a zeroed static on a device), then [`Learner::init`].
//! A non-finite value anywhere in an update makes it return an error with every parameter,
//! optimiser moment and multiplier as it was before the update.

use bytemuck::Zeroable;

use crate::actor::{Actor, ActorTape};
use crate::adam::{AdamConfig, AdamState, adam_step};
use crate::config::{ConfigError, MpoConfig};
use crate::critic::{Critic, CriticTape};
use crate::estep::{solve_temperature, weights};
use crate::gaussian::{Gaussian, GaussianGrad, head_backward, kl_per_dim_grad};

/// Clamp of `ln alpha` (Acme clamps the duals below at `exp(-18)`).
const LOG_ALPHA_MAX: f32 = 18.0;
use crate::params::{Params, clip_global_norm};
use crate::rng::Rng;

/// A batch of transitions, filled by the caller before [`Learner::update`].
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Batch<const B: usize, const OBS: usize, const ACT: usize> {
    /// States.
    pub obs: [[f32; OBS]; B],
    /// Actions taken.
    pub action: [[f32; ACT]; B],
    /// Rewards (n-step sums for n-step transitions).
    pub reward: [f32; B],
    /// Next states (`s_{t+n}` for n-step transitions).
    pub next_obs: [[f32; OBS]; B],
    /// Multiplier of the next-state value: `gamma^n` times the environment's discounts (0
    /// after a true terminal; a time-limit truncation keeps it).
    pub bootstrap: [f32; B],
}

impl<const B: usize, const OBS: usize, const ACT: usize> Batch<B, OBS, ACT> {
    fn all_finite(&self) -> bool {
        self.obs.as_flattened().iter().all(|x| x.is_finite())
            && self.action.as_flattened().iter().all(|x| x.is_finite())
            && self.next_obs.as_flattened().iter().all(|x| x.is_finite())
            && self.reward.iter().all(|x| x.is_finite())
            && self.bootstrap.iter().all(|x| x.is_finite())
    }
}

/// `B` replayed sequences of `L` consecutive transitions (position-major: `[k][n]` is
/// transition `k` of sequence `n`), for [`Learner::update_retrace`].
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct SequenceBatch<const B: usize, const L: usize, const OBS: usize, const ACT: usize> {
    /// States `s_k`.
    pub obs: [[[f32; OBS]; B]; L],
    /// Actions `a_k` taken by the behaviour policy.
    pub action: [[[f32; ACT]; B]; L],
    /// Rewards `r_k`.
    pub reward: [[f32; B]; L],
    /// Next states `s_{k+1}`.
    pub next_obs: [[[f32; OBS]; B]; L],
    /// Environment discount after step `k` (0 at a terminal; 1 at a time-limit truncation).
    pub discount: [[f32; B]; L],
    /// `ln b(a_k | s_k)` of the behaviour policy, stored in the replay when acting.
    pub behaviour_log_prob: [[f32; B]; L],
}

impl<const B: usize, const L: usize, const OBS: usize, const ACT: usize>
    SequenceBatch<B, L, OBS, ACT>
{
    fn all_finite(&self) -> bool {
        let f = |x: &[f32]| x.iter().all(|v| v.is_finite());
        (0..L).all(|k| {
            f(self.obs[k].as_flattened())
                && f(self.action[k].as_flattened())
                && f(self.next_obs[k].as_flattened())
                && f(&self.reward[k])
                && f(&self.discount[k])
                && f(&self.behaviour_log_prob[k])
        })
    }
}

/// The M-step multipliers (log parameterisation) and the temperature, with the
/// multipliers' Adam state.
#[derive(Clone, Copy, Debug, PartialEq, Zeroable)]
pub struct Duals<const ACT: usize> {
    /// E-step temperature `eta*` of the last update (the warm start of the next).
    pub eta: f32,
    /// `alpha_mu = exp(raw)` per dimension (all equal without per-dimension KL).
    pub alpha_mean_raw: [f32; ACT],
    /// `alpha_Sigma = exp(raw)` per dimension.
    pub alpha_cov_raw: [f32; ACT],
    /// Adam moments of the raw multipliers.
    pub moments: [[f32; ACT]; 4],
    /// Adam state of the multipliers.
    pub opt: AdamState,
}

impl<const ACT: usize> Duals<ACT> {
    /// `alpha_mu` per dimension.
    pub fn alpha_mean(&self) -> [f32; ACT] {
        self.alpha_mean_raw.map(libm::expf)
    }
    /// `alpha_Sigma` per dimension.
    pub fn alpha_cov(&self) -> [f32; ACT] {
        self.alpha_cov_raw.map(libm::expf)
    }
}

/// Everything an update changes except the targets: what a failed update restores.
#[derive(Clone, Zeroable)]
pub struct Trainable<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
> {
    /// Online policy.
    pub actor: Actor<OBS, ACT, TRI, H1, H2>,
    /// Online critic.
    pub critic: Critic<OBS, ACT, H1, H2>,
    /// Actor Adam first moments.
    pub actor_m: Actor<OBS, ACT, TRI, H1, H2>,
    /// Actor Adam second moments.
    pub actor_v: Actor<OBS, ACT, TRI, H1, H2>,
    /// Critic Adam first moments.
    pub critic_m: Critic<OBS, ACT, H1, H2>,
    /// Critic Adam second moments.
    pub critic_v: Critic<OBS, ACT, H1, H2>,
    /// Actor Adam state.
    pub actor_opt: AdamState,
    /// Critic Adam state.
    pub critic_opt: AdamState,
    /// Temperature and multipliers.
    pub duals: Duals<ACT>,
}

impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize>
    Trainable<OBS, ACT, TRI, H1, H2>
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

/// Scratch memory of one update.
#[derive(Zeroable)]
struct Scratch<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
    const B: usize,
    const M: usize,
> {
    atape: ActorTape<B, H1, H2>,
    ctape: CriticTape<B, H1, H2>,
    mean: [[f32; ACT]; B],
    chol: [[f32; TRI]; B],
    d_mean: [[f32; ACT]; B],
    d_chol: [[f32; TRI]; B],
    old: [Gaussian<ACT>; B],
    pre1: [[f32; H1]; B],
    next_action: [[f32; ACT]; B],
    samples: [[[f32; ACT]; B]; M],
    q_samples: [[f32; M]; B],
    weights: [[f32; M]; B],
    q: [[f32; 1]; B],
    target: [f32; B],
    dq: [[f32; 1]; B],
    actor_grad: Actor<OBS, ACT, TRI, H1, H2>,
    critic_grad: Critic<OBS, ACT, H1, H2>,
}

/// Where a non-finite value was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum NonFinite {
    /// The batch (observations, actions, rewards or bootstrap multipliers).
    Batch,
    /// The critic's TD targets or loss.
    CriticLoss,
    /// The critic's gradients.
    CriticGradients,
    /// The E-step values or temperature.
    EStep,
    /// The M-step loss, KLs or actor gradients.
    ActorGradients,
    /// Parameters after the step.
    Parameters,
}

/// Why an update was rejected (its changes are undone).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum UpdateError {
    /// A NaN or infinity appeared.
    NonFinite(NonFinite),
}

impl core::fmt::Display for UpdateError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NonFinite(w) => write!(f, "non-finite value in {w:?}; the update was undone"),
        }
    }
}

impl core::error::Error for UpdateError {}

/// What one update measured (for logging; returned, not stored).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UpdateStats {
    /// `0.5 mean (Q - y)^2` before the critic step.
    pub critic_loss: f32,
    /// Mean TD target.
    pub target_mean: f32,
    /// Mean `Q` over the E-step samples.
    pub q_mean: f32,
    /// Smallest and largest E-step `Q`.
    pub q_min: f32,
    /// Largest E-step `Q`.
    pub q_max: f32,
    /// Temperature `eta*`.
    pub eta: f32,
    /// Mean KL(q || pi_old) of the E-step weights (at the constraint: `eps_eta`).
    pub estep_kl: f32,
    /// Temperature solver iterations.
    pub estep_iterations: u32,
    /// Mean `alpha_mu` over dimensions, after the update.
    pub alpha_mean: f32,
    /// Mean `alpha_Sigma` over dimensions, after the update.
    pub alpha_cov: f32,
    /// Mean over states of KL_mu(target || online) before the last M-step iteration.
    pub kl_mean: f32,
    /// Mean over states of KL_Sigma(target || online) before the last M-step iteration.
    pub kl_cov: f32,
    /// `kl_mean / eps_mean` (1.0 = at the constraint).
    pub kl_mean_rel: f32,
    /// `kl_cov / eps_cov`.
    pub kl_cov_rel: f32,
    /// Weighted negative log-likelihood part of the M-step loss (last iteration).
    pub policy_nll: f32,
    /// Actor gradient norm before clipping (last iteration).
    pub actor_grad_norm: f32,
    /// Critic gradient norm before clipping.
    pub critic_grad_norm: f32,
    /// Mean of the online policy's means over states and dimensions.
    pub mu_mean: f32,
    /// Mean of `|mu|`.
    pub mu_abs_mean: f32,
    /// Mean, smallest and largest standard deviation over states and dimensions.
    pub std_mean: f32,
    /// Smallest standard deviation.
    pub std_min: f32,
    /// Largest standard deviation.
    pub std_max: f32,
}

/// The complete MPO learner for `OBS` observations and `ACT` actions
/// (`TRI = ACT (ACT + 1) / 2`), hidden widths `H1`, `H2`, batch `B`, `M` E-step samples per
/// state and `N` next-action samples per next state.
#[derive(Zeroable)]
pub struct Learner<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
    const B: usize,
    const M: usize,
    const N: usize,
> {
    /// Hyperparameters (validated by [`Learner::init`]).
    pub cfg: MpoConfig,
    /// Online networks, optimiser states and duals.
    pub live: Trainable<OBS, ACT, TRI, H1, H2>,
    /// Target (old) policy.
    pub target_actor: Actor<OBS, ACT, TRI, H1, H2>,
    /// Target critic.
    pub target_critic: Critic<OBS, ACT, H1, H2>,
    /// Updates completed.
    pub updates: u64,
    /// State of the learner's random stream (restored exactly from checkpoints).
    pub rng_state: [u8; 32],
    /// The batch the next update learns from.
    pub batch: Batch<B, OBS, ACT>,
    backup: Trainable<OBS, ACT, TRI, H1, H2>,
    s: Scratch<OBS, ACT, TRI, H1, H2, B, M>,
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
    const B: usize,
    const M: usize,
    const N: usize,
> Learner<OBS, ACT, TRI, H1, H2, B, M, N>
{
    /// Validates `cfg`, initialises the networks from `seed` and resets every optimiser,
    /// multiplier and counter.
    pub fn init(&mut self, cfg: MpoConfig, seed: u64) -> Result<(), ConfigError> {
        cfg.validate()?;
        const { assert!(B > 0 && M > 0 && N > 0, "B, M and N must be positive") };
        self.cfg = cfg;
        let mut rng = Rng::seed_from_u64(seed);
        let l = &mut self.live;
        l.actor.init(&mut rng, cfg.init_std, cfg.std_floor);
        l.critic.init(&mut rng);
        l.actor_m.fill_zero();
        l.actor_v.fill_zero();
        l.critic_m.fill_zero();
        l.critic_v.fill_zero();
        l.actor_opt = AdamState::default();
        l.critic_opt = AdamState::default();
        l.duals = Duals {
            eta: cfg.eta_init,
            alpha_mean_raw: [libm::logf(cfg.alpha_mean_init).clamp(-LOG_ALPHA_MAX, LOG_ALPHA_MAX);
                ACT],
            alpha_cov_raw: [libm::logf(cfg.alpha_cov_init).clamp(-LOG_ALPHA_MAX, LOG_ALPHA_MAX);
                ACT],
            moments: [[0.0; ACT]; 4],
            opt: AdamState::default(),
        };
        self.target_actor.copy_from(&self.live.actor);
        self.target_critic.copy_from(&self.live.critic);
        self.updates = 0;
        self.rng_state = rng.state();
        Ok(())
    }

    /// A sampled action from the online policy and its log-probability (the behaviour policy
    /// while collecting experience).
    pub fn sample_action(&self, obs: &[f32; OBS], rng: &mut Rng, action: &mut [f32; ACT]) -> f32 {
        let pi = self.live.actor.distribution(obs, self.cfg.std_floor);
        pi.sample(rng, action);
        pi.log_prob(action)
    }

    /// The online policy's mean action (evaluation and deployment).
    pub fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        self.live.actor.mean_action(obs, action);
    }

    /// Multiply-adds... in FLOPs: the arithmetic of one update, counting the network passes
    /// (2 FLOPs per multiply-add; forward, weight and input gradients), not the small
    /// per-sample Gaussian algebra.
    pub const fn flops_per_update(mstep_iters: usize) -> u64 {
        let a_fwd = Actor::<OBS, ACT, TRI, H1, H2>::forward_macs() as u64;
        let c_fwd = Critic::<OBS, ACT, H1, H2>::forward_macs() as u64;
        let c_tail = (H1 * H2 + H2) as u64; // the part after the shared observation block
        let c_state = (OBS * H1) as u64;
        let a_bwd = 2 * a_fwd - (OBS * H1) as u64; // weight grads + input grads but layer 1
        let c_bwd = 2 * c_fwd - ((OBS + ACT) * H1) as u64;
        let b = B as u64;
        let next = a_fwd + c_state + N as u64 * (c_tail + (ACT * H1) as u64);
        let critic_step = c_fwd + c_bwd;
        let estep = a_fwd + c_state + M as u64 * (c_tail + (ACT * H1) as u64);
        let mstep = mstep_iters as u64 * (a_fwd + a_bwd);
        2 * b * (next + critic_step + estep + mstep)
    }

    /// One learner update on `self.batch`. On error nothing but the random stream has changed.
    pub fn update(&mut self) -> Result<UpdateStats, UpdateError> {
        if !self.batch.all_finite() {
            return Err(UpdateError::NonFinite(NonFinite::Batch));
        }
        self.backup.copy_from(&self.live);
        let mut rng = Rng::from_state(self.rng_state);
        let result = self.update_inner(&mut rng);
        self.rng_state = rng.state();
        self.finish(result)
    }

    /// Commits a successful update (counter, target copies) or undoes a failed one.
    fn finish(
        &mut self,
        result: Result<UpdateStats, UpdateError>,
    ) -> Result<UpdateStats, UpdateError> {
        match result {
            Ok(stats) => {
                self.updates += 1;
                if self.updates.is_multiple_of(self.cfg.target_period as u64) {
                    self.target_actor.copy_from(&self.live.actor);
                    self.target_critic.copy_from(&self.live.critic);
                }
                Ok(stats)
            }
            Err(e) => {
                self.live.copy_from(&self.backup);
                Err(e)
            }
        }
    }

    fn update_inner(&mut self, rng: &mut Rng) -> Result<UpdateStats, UpdateError> {
        let mut stats = UpdateStats::default();
        self.policy_evaluation(rng, &mut stats)?;
        self.improve(rng, stats)
    }

    /// Policy improvement on the batch's states: the E-step, then the M-step iterations.
    fn improve(
        &mut self,
        rng: &mut Rng,
        mut stats: UpdateStats,
    ) -> Result<UpdateStats, UpdateError> {
        self.e_step(rng, &mut stats)?;
        for _ in 0..self.cfg.mstep_iters {
            self.m_step(&mut stats)?;
        }
        if !self.live.actor.all_finite() || !self.live.critic.all_finite() {
            return Err(UpdateError::NonFinite(NonFinite::Parameters));
        }
        let (am, ac) = (self.live.duals.alpha_mean(), self.live.duals.alpha_cov());
        stats.alpha_mean = am.iter().sum::<f32>() / ACT as f32;
        stats.alpha_cov = ac.iter().sum::<f32>() / ACT as f32;
        Ok(stats)
    }

    /// TD(0) with the expectation over `N` next actions from the target policy.
    fn policy_evaluation(
        &mut self,
        rng: &mut Rng,
        stats: &mut UpdateStats,
    ) -> Result<(), UpdateError> {
        self.expected_next_value(rng);
        let s = &mut self.s;
        for n in 0..B {
            s.target[n] = self.batch.reward[n] + self.batch.bootstrap[n] * s.target[n];
        }
        self.critic_step(stats)
    }

    /// `s.target[n] = mean_j Q_target(s'_n, a_j)` with `a_j ~ pi_target(s'_n)` for the batch's
    /// next states.
    fn expected_next_value(&mut self, rng: &mut Rng) {
        let (s, batch, cfg) = (&mut self.s, &self.batch, &self.cfg);
        let x = &batch.next_obs;
        self.target_actor
            .forward(x, &mut s.atape, &mut s.mean, &mut s.chol);
        for n in 0..B {
            s.old[n] = Gaussian::from_head(&s.mean[n], &s.chol[n], cfg.std_floor);
        }
        self.target_critic.state_part(x, &mut s.pre1);
        s.target = [0.0; B];
        for _ in 0..N {
            for n in 0..B {
                s.old[n].sample(rng, &mut s.next_action[n]);
            }
            self.target_critic.forward_from_state_part(
                &s.pre1,
                &s.next_action,
                &mut s.ctape,
                &mut s.q,
            );
            for n in 0..B {
                s.target[n] += s.q[n][0];
            }
        }
        for n in 0..B {
            s.target[n] /= N as f32;
        }
    }

    /// One Adam step of the critic towards `s.target` on the batch's `(obs, action)`.
    fn critic_step(&mut self, stats: &mut UpdateStats) -> Result<(), UpdateError> {
        let (s, batch, cfg) = (&mut self.s, &self.batch, &self.cfg);
        let mut loss = 0.0;
        let mut tmean = 0.0;
        for n in 0..B {
            tmean += s.target[n];
        }
        let live = &mut self.live;
        live.critic
            .forward(&batch.obs, &batch.action, &mut s.ctape, &mut s.q);
        for n in 0..B {
            let e = s.q[n][0] - s.target[n];
            loss += 0.5 * e * e;
            s.dq[n][0] = e / B as f32;
        }
        stats.critic_loss = loss / B as f32;
        stats.target_mean = tmean / B as f32;
        if !stats.critic_loss.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::CriticLoss));
        }
        live.critic.backward(
            &batch.obs,
            &batch.action,
            &mut s.ctape,
            &s.dq,
            &mut s.critic_grad,
        );
        stats.critic_grad_norm = clip_global_norm(&mut s.critic_grad, cfg.critic_clip);
        if !stats.critic_grad_norm.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::CriticGradients));
        }
        let acfg = AdamConfig::with_lr(cfg.critic_lr);
        adam_step(
            &acfg,
            &mut live.critic_opt,
            &mut live.critic,
            &s.critic_grad,
            &mut live.critic_m,
            &mut live.critic_v,
        );
        Ok(())
    }

    /// Retrace policy evaluation (paper eq. 11) on `B` replayed sequences of `L` transitions:
    /// the critic regresses `Q(s_0, a_0)` on the Retrace target built from the target networks,
    /// with traces `c_k = min(1, pi_target(a_k | s_k) / b(a_k | s_k))` from the stored
    /// behaviour log-probabilities; then the E- and M-steps run on the first states `s_0`.
    /// With `L = 1` this is exactly [`Learner::update`] on the first transitions.
    pub fn update_retrace<const L: usize>(
        &mut self,
        seq: &SequenceBatch<B, L, OBS, ACT>,
    ) -> Result<UpdateStats, UpdateError> {
        const { assert!(L > 0, "sequences need at least one transition") };
        if !seq.all_finite() {
            return Err(UpdateError::NonFinite(NonFinite::Batch));
        }
        self.backup.copy_from(&self.live);
        let mut rng = Rng::from_state(self.rng_state);
        let result = self.retrace_inner(seq, &mut rng);
        self.rng_state = rng.state();
        self.finish(result)
    }

    fn retrace_inner<const L: usize>(
        &mut self,
        seq: &SequenceBatch<B, L, OBS, ACT>,
        rng: &mut Rng,
    ) -> Result<UpdateStats, UpdateError> {
        // Per position k: V(s_{k+1}), Q_target(s_k, a_k) and ln pi_target(a_k|s_k) - ln b.
        let mut v = [[0f32; B]; L];
        let mut q = [[0f32; B]; L];
        let mut log_ratio = [[0f32; B]; L];
        for k in 0..L {
            self.batch.obs = seq.obs[k];
            self.batch.action = seq.action[k];
            self.batch.next_obs = seq.next_obs[k];
            self.expected_next_value(rng);
            v[k] = self.s.target;
            if k > 0 {
                let (s, batch) = (&mut self.s, &self.batch);
                self.target_actor
                    .forward(&batch.obs, &mut s.atape, &mut s.mean, &mut s.chol);
                self.target_critic
                    .forward(&batch.obs, &batch.action, &mut s.ctape, &mut s.q);
                for n in 0..B {
                    let pi = Gaussian::from_head(&s.mean[n], &s.chol[n], self.cfg.std_floor);
                    log_ratio[k][n] = pi.log_prob(&batch.action[n]) - seq.behaviour_log_prob[k][n];
                    q[k][n] = s.q[n][0];
                }
            }
        }
        let (mut qn, mut vn, mut rn, mut dn, mut ln, mut out) = (
            [0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L],
        );
        for n in 0..B {
            for k in 0..L {
                qn[k] = q[k][n];
                vn[k] = v[k][n];
                rn[k] = seq.reward[k][n];
                dn[k] = seq.discount[k][n];
                ln[k] = log_ratio[k][n];
            }
            crate::evaluation::retrace(&qn, &vn, &rn, &dn, &ln, self.cfg.gamma, &mut out);
            self.s.target[n] = out[0];
        }
        self.batch.obs = seq.obs[0];
        self.batch.action = seq.action[0];
        self.batch.next_obs = seq.next_obs[0];
        for n in 0..B {
            self.batch.reward[n] = seq.reward[0][n];
            self.batch.bootstrap[n] = self.cfg.gamma * seq.discount[0][n];
        }
        let mut stats = UpdateStats::default();
        self.critic_step(&mut stats)?;
        self.improve(rng, stats)
    }

    /// Samples, values, temperature and weights.
    fn e_step(&mut self, rng: &mut Rng, stats: &mut UpdateStats) -> Result<(), UpdateError> {
        let (s, batch, cfg) = (&mut self.s, &self.batch, &self.cfg);
        self.target_actor
            .forward(&batch.obs, &mut s.atape, &mut s.mean, &mut s.chol);
        for n in 0..B {
            s.old[n] = Gaussian::from_head(&s.mean[n], &s.chol[n], cfg.std_floor);
        }
        self.target_critic.state_part(&batch.obs, &mut s.pre1);
        for j in 0..M {
            for n in 0..B {
                s.old[n].sample(rng, &mut s.samples[j][n]);
            }
            self.target_critic.forward_from_state_part(
                &s.pre1,
                &s.samples[j],
                &mut s.ctape,
                &mut s.q,
            );
            for n in 0..B {
                s.q_samples[n][j] = s.q[n][0];
            }
        }
        let (mut qsum, mut qmin, mut qmax) = (0f64, f32::INFINITY, f32::NEG_INFINITY);
        for row in &s.q_samples {
            for &v in row {
                qsum += v as f64;
                qmin = qmin.min(v);
                qmax = qmax.max(v);
            }
        }
        if !qsum.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::EStep));
        }
        let d = &mut self.live.duals;
        let sol = solve_temperature(
            &s.q_samples,
            cfg.eps_eta,
            d.eta,
            cfg.estep_tol,
            cfg.estep_max_iter,
        );
        if !sol.eta.is_finite() || sol.eta <= 0.0 {
            return Err(UpdateError::NonFinite(NonFinite::EStep));
        }
        d.eta = sol.eta;
        let kl = weights(&s.q_samples, sol.eta, &mut s.weights);
        stats.q_mean = (qsum / (B * M) as f64) as f32;
        stats.q_min = qmin;
        stats.q_max = qmax;
        stats.eta = sol.eta;
        stats.estep_kl = kl as f32;
        stats.estep_iterations = sol.iterations;
        Ok(())
    }

    /// One M-step iteration: actor gradient step and multiplier step.
    fn m_step(&mut self, stats: &mut UpdateStats) -> Result<(), UpdateError> {
        let (s, batch, cfg) = (&mut self.s, &self.batch, &self.cfg);
        let live = &mut self.live;
        live.actor
            .forward(&batch.obs, &mut s.atape, &mut s.mean, &mut s.chol);
        let alpha_mean = live.duals.alpha_mean();
        let alpha_cov = live.duals.alpha_cov();
        let inv_b = 1.0 / B as f32;
        let c_mean = alpha_mean.map(|a| a * inv_b);
        let c_cov = alpha_cov.map(|a| a * inv_b);
        let (mut kl_mean, mut kl_cov) = ([0f32; ACT], [0f32; ACT]);
        let mut nll = 0f32;
        let (mut mu_sum, mut mu_abs, mut sd_sum) = (0f32, 0f32, 0f32);
        let (mut sd_min, mut sd_max) = (f32::INFINITY, 0f32);
        for n in 0..B {
            let old = &s.old[n];
            let new = Gaussian::from_head(&s.mean[n], &s.chol[n], cfg.std_floor);
            let pi_mean = Gaussian {
                mu: new.mu,
                l: old.l,
            };
            let pi_cov = Gaussian {
                mu: old.mu,
                l: new.l,
            };
            let mut g = GaussianGrad::ZERO;
            for j in 0..M {
                let w = s.weights[n][j];
                let a = &s.samples[j][n];
                let mut gm = GaussianGrad::ZERO;
                let lp_m = pi_mean.log_prob_grad(a, -w * inv_b, &mut gm);
                let mut gc = GaussianGrad::ZERO;
                let lp_c = pi_cov.log_prob_grad(a, -w * inv_b, &mut gc);
                nll -= w * (lp_m + lp_c) * inv_b;
                // Stop-gradients: pi_mean's covariance and pi_cov's mean are the old ones.
                for k in 0..ACT {
                    g.mu[k] += gm.mu[k];
                }
                add_l(&mut g, &gc);
            }
            let mut gk = GaussianGrad::ZERO;
            let km = kl_per_dim_grad(old, &pi_mean, &c_mean, &[0.0; ACT], &mut gk);
            for k in 0..ACT {
                g.mu[k] += gk.mu[k];
            }
            let mut gk = GaussianGrad::ZERO;
            let kc = kl_per_dim_grad(old, &pi_cov, &[0.0; ACT], &c_cov, &mut gk);
            add_l(&mut g, &gk);
            for k in 0..ACT {
                kl_mean[k] += km.mean[k] * inv_b;
                kl_cov[k] += kc.cov[k] * inv_b;
            }
            head_backward(&s.chol[n], &g, &mut s.d_mean[n], &mut s.d_chol[n]);
            let sd = new.std_devs();
            for k in 0..ACT {
                mu_sum += new.mu[k];
                mu_abs += new.mu[k].abs();
                sd_sum += sd[k];
                sd_min = sd_min.min(sd[k]);
                sd_max = sd_max.max(sd[k]);
            }
        }
        live.actor.backward(
            &batch.obs,
            &mut s.atape,
            &s.d_mean,
            &s.d_chol,
            &mut s.actor_grad,
        );
        let norm = clip_global_norm(&mut s.actor_grad, cfg.actor_clip);
        let (km_tot, kc_tot): (f32, f32) = (kl_mean.iter().sum(), kl_cov.iter().sum());
        if !(norm.is_finite() && nll.is_finite() && km_tot.is_finite() && kc_tot.is_finite()) {
            return Err(UpdateError::NonFinite(NonFinite::ActorGradients));
        }
        let acfg = AdamConfig::with_lr(cfg.actor_lr);
        adam_step(
            &acfg,
            &mut live.actor_opt,
            &mut live.actor,
            &s.actor_grad,
            &mut live.actor_m,
            &mut live.actor_v,
        );

        // Multipliers: d/d alpha of alpha (eps - KL) is eps - KL; through alpha = exp(raw) it is
        // scaled by alpha. Without per-dimension KL every entry sees the total.
        let d = &mut live.duals;
        let mut g_mean = [0f32; ACT];
        let mut g_cov = [0f32; ACT];
        for k in 0..ACT {
            let (dm, dc) = if cfg.per_dim_kl {
                (
                    cfg.eps_mean / ACT as f32 - kl_mean[k],
                    cfg.eps_cov / ACT as f32 - kl_cov[k],
                )
            } else {
                (cfg.eps_mean - km_tot, cfg.eps_cov - kc_tot)
            };
            g_mean[k] = dm * alpha_mean[k];
            g_cov[k] = dc * alpha_cov[k];
        }
        let dcfg = AdamConfig::with_lr(cfg.dual_lr);
        d.opt.advance(&dcfg);
        let [m0, v0, m1, v1] = &mut d.moments;
        d.opt.apply(&dcfg, &mut d.alpha_mean_raw, &g_mean, m0, v0);
        d.opt.apply(&dcfg, &mut d.alpha_cov_raw, &g_cov, m1, v1);
        for r in d
            .alpha_mean_raw
            .iter_mut()
            .chain(d.alpha_cov_raw.iter_mut())
        {
            *r = r.clamp(-LOG_ALPHA_MAX, LOG_ALPHA_MAX);
        }

        let bd = (B * ACT) as f32;
        stats.kl_mean = km_tot;
        stats.kl_cov = kc_tot;
        stats.kl_mean_rel = km_tot / cfg.eps_mean;
        stats.kl_cov_rel = kc_tot / cfg.eps_cov;
        stats.policy_nll = nll;
        stats.actor_grad_norm = norm;
        stats.mu_mean = mu_sum / bd;
        stats.mu_abs_mean = mu_abs / bd;
        stats.std_mean = sd_sum / bd;
        stats.std_min = sd_min;
        stats.std_max = sd_max;
        Ok(())
    }
}

/// `g.l += h.l` (lower triangle).
fn add_l<const A: usize>(g: &mut GaussianGrad<A>, h: &GaussianGrad<A>) {
    for j in 0..A {
        for k in 0..=j {
            g.l[j][k] += h.l[j][k];
        }
    }
}
