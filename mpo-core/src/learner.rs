//! The MPO learner: policy evaluation, E-step and M-step over one sampled batch.
//!
//! One [`Learner::update`] on a batch of `B = BC * C` rows (`C` chunks of `BC`):
//! 1. **Policy evaluation**: the critic regresses `Q(s_0, a_0)` on a target built from the
//!    target networks with `N` target-policy actions per next state: with `sequence_len = 1`
//!    the TD(0) expected-SARSA target `r + bootstrap * mean_j Q'(s', a'_j)` (n-step
//!    transitions are folded by the caller into `r` and `bootstrap`), with `sequence_len > 1`
//!    Retrace over the row's consecutive transitions ([`crate::evaluation::retrace`]). One
//!    Adam step on `0.5 mean (Q - y)^2`.
//! 2. **E-step** ([`crate::estep`], paper eq. 7-8): `M` actions per state from the target
//!    policy, their target-critic values, the temperature from the dual and the weights
//!    `softmax_j(Q_ij / eta*)`; with action penalization a second temperature and set of
//!    weights for `-|a - clip(a)|^2` over the same samples. With `shared_samples` (Acme) the
//!    E-step reuses the TD target's `N` samples at the next states.
//! 3. **M-step** ([`crate::mstep`]), `mstep_iters` times: one Adam step of the actor on the
//!    weighted likelihood with the decoupled KL penalties, one of the multipliers.
//!    With `clip_critic_actions` (Acme's) every action the critic is given in 1-2 is first
//!    clipped to `[-1, 1]`, as the plant applies it; the samples stay unclipped elsewhere.
//! 4. The targets follow the online networks: a copy every `target_period` updates, or Polyak
//!    averaging with `target_tau` after every update.
//!
//! **Threads, same bits.** The work of each phase is split into independent items and handed
//! to a [`Parallel`]: the batch chunks for everything per row (network passes, sampling, the
//! Gaussian algebra), blocks of parameter rows for the weight gradients. Every row draws from
//! its own random stream keyed by the update and the row's index, every weight gradient sums
//! its rows in batch order, and every reduction over rows (losses, KLs, the E-step's dual)
//! adds them in batch order afterwards. So the result depends on `B` and the configuration,
//! never on `C`, on the number of threads or on their timing.
//!
//! "Old" is the target policy throughout. Everything lives in the struct: construct it zeroed
//! (`bytemuck::zeroed_box` on a host, a zeroed static on a device), then [`Learner::init`].
//! A non-finite value anywhere in an update makes it return an error with every parameter,
//! optimiser moment and multiplier as it was before the update.

use bytemuck::Zeroable;

use crate::actor::{Actor, ActorGradInputs, ActorTape, ActorTransposed};
use crate::adam::{AdamConfig, AdamState, adam_step_with};
use crate::config::{ConfigError, MpoConfig};
use crate::critic::{Critic, CriticGradInputs, CriticTape, CriticTransposed};
use crate::estep::{DualRow, DualSums, dual_row, solve_temperature_with};
use crate::gaussian::{Gaussian, SampleStats};
use crate::mstep::{LOG_ALPHA_MAX, StateTerms, state_gradient, update_multipliers};
use crate::parallel::{Parallel, Serial};
use crate::params::Params;
use crate::rng::Rng;

/// Random stream tags (see [`Rng::for_stream`]): E-step samples, and next-action samples of
/// sequence position `k` at `STREAM_NEXT + k`.
const STREAM_ESTEP: u32 = 0;
const STREAM_NEXT: u32 = 1;

/// One chunk of the batch: `BC` rows of up to `L` consecutive transitions, position-major
/// (`[k][n]` is transition `k` of row `n`). Single-transition batches use position 0 only.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct BatchChunk<const BC: usize, const L: usize, const OBS: usize, const ACT: usize> {
    /// States `s_k`.
    pub obs: [[[f32; OBS]; BC]; L],
    /// Actions `a_k` taken by the behaviour policy (as sampled, before the plant clips them).
    pub action: [[[f32; ACT]; BC]; L],
    /// Rewards `r_k` (n-step sums for n-step transitions).
    pub reward: [[f32; BC]; L],
    /// Next states `s_{k+1}` (`s_{k+n}` for n-step transitions).
    pub next_obs: [[[f32; OBS]; BC]; L],
    /// Multiplier of the next-state value: `gamma^n` times the environment's discounts (0
    /// after a true terminal; a time-limit truncation keeps it).
    pub bootstrap: [[f32; BC]; L],
    /// `ln b(a_k | s_k)` of the behaviour policy (Retrace's importance weights).
    pub behaviour_log_prob: [[f32; BC]; L],
}

impl<const BC: usize, const L: usize, const OBS: usize, const ACT: usize>
    BatchChunk<BC, L, OBS, ACT>
{
    fn all_finite(&self, len: usize) -> bool {
        let f = |x: &[f32]| x.iter().all(|v| v.is_finite());
        (0..len).all(|k| {
            f(self.obs[k].as_flattened())
                && f(self.action[k].as_flattened())
                && f(self.next_obs[k].as_flattened())
                && f(&self.reward[k])
                && f(&self.bootstrap[k])
                && f(&self.behaviour_log_prob[k])
        })
    }
}

/// The M-step multipliers (log parameterisation) and the temperatures, with the
/// multipliers' Adam state.
#[derive(Clone, Copy, Debug, PartialEq, Zeroable)]
pub struct Duals<const ACT: usize> {
    /// E-step temperature `eta*` of the last update (the warm start of the next).
    pub eta: f32,
    /// Temperature of the action-penalty objective (with action penalization).
    pub eta_penalty: f32,
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

/// Per-chunk scratch: everything one batch chunk's rows need, so chunks can run on
/// different threads with nothing mutable shared.
#[derive(Zeroable)]
struct Chunk<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> {
    atape: ActorTape<BC, AH1, AH2>,
    ctape: CriticTape<BC, QH1, QH2>,
    mean: [[f32; ACT]; BC],
    chol: [[f32; TRI]; BC],
    d_mean: [[f32; ACT]; BC],
    d_chol: [[f32; TRI]; BC],
    /// The target policy at the improvement states.
    old: [Gaussian<ACT>; BC],
    /// The target policy at the current position's next states (Retrace reuses it at the
    /// next position, where they are the states).
    next_pi: [Gaussian<ACT>; BC],
    pre1: [[f32; QH1]; BC],
    next_samples: [[[f32; ACT]; BC]; N],
    samples: [[[f32; ACT]; BC]; M],
    q_samples: [[f32; M]; BC],
    q_penalty: [[f32; M]; BC],
    /// With `clip_critic_actions`: the batch's actions clipped, as the critic's loss sees
    /// them, kept for the weight gradient (unused otherwise: the batch's own are read).
    critic_action: [[f32; ACT]; BC],
    /// Scratch for a clipped copy of sampled or replayed actions before a critic pass.
    clipped: [[f32; ACT]; BC],
    stats: [SampleStats<ACT>; BC],
    q: [[f32; 1]; BC],
    dq: [[f32; 1]; BC],
    target: [f32; BC],
    err: [f32; BC],
    ret_q: [[f32; BC]; L],
    ret_v: [[f32; BC]; L],
    ret_log_ratio: [[f32; BC]; L],
    dual: [DualRow; BC],
    estep_kl: [f32; BC],
    terms: [StateTerms<ACT>; BC],
}

/// Gradients and transposed weights (shared, read by every chunk).
#[derive(Zeroable)]
struct Grads<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
> {
    actor: Actor<OBS, ACT, TRI, AH1, AH2>,
    critic: Critic<OBS, ACT, QH1, QH2>,
    at: ActorTransposed<ACT, TRI, AH1, AH2>,
    ct: CriticTransposed<QH1, QH2>,
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
    /// Smallest E-step `Q`.
    pub q_min: f32,
    /// Largest E-step `Q`.
    pub q_max: f32,
    /// Temperature `eta*`.
    pub eta: f32,
    /// Mean KL(q || pi_old) of the E-step weights (at the constraint: `eps_eta`).
    pub estep_kl: f32,
    /// Temperature solver iterations.
    pub estep_iterations: u32,
    /// Temperature of the action-penalty objective (0 without action penalization).
    pub eta_penalty: f32,
    /// Mean over the E-step samples of `|a - clip(a, -1, 1)|^2`.
    pub action_excess: f32,
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
    /// Mean standard deviation over states and dimensions.
    pub std_mean: f32,
    /// Smallest standard deviation.
    pub std_min: f32,
    /// Largest standard deviation.
    pub std_max: f32,
}

/// The complete MPO learner for `OBS` observations and `ACT` actions
/// (`TRI = ACT (ACT + 1) / 2`), actor widths `AH1`, `AH2`, critic widths `QH1`, `QH2`, a batch
/// of `C` chunks of `BC` rows of up to `L` transitions, `M` E-step samples per state and `N`
/// next-action samples per next state.
#[derive(Zeroable)]
pub struct Learner<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> {
    /// Hyperparameters (validated by [`Learner::init`]).
    pub cfg: MpoConfig,
    /// Online networks, optimiser states and duals.
    pub live: Trainable<OBS, ACT, TRI, AH1, AH2, QH1, QH2>,
    /// Target (old) policy.
    pub target_actor: Actor<OBS, ACT, TRI, AH1, AH2>,
    /// Target critic.
    pub target_critic: Critic<OBS, ACT, QH1, QH2>,
    /// Updates completed.
    pub updates: u64,
    /// State of the learner's random stream (restored exactly from checkpoints).
    pub rng_state: [u8; 32],
    /// The batch the next update learns from, in chunks (row `n` is `batch[n / BC]`, slot
    /// `n % BC`: see [`Learner::slot`]).
    pub batch: [BatchChunk<BC, L, OBS, ACT>; C],
    backup: Trainable<OBS, ACT, TRI, AH1, AH2, QH1, QH2>,
    grads: Grads<OBS, ACT, TRI, AH1, AH2, QH1, QH2>,
    chunks: [Chunk<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, L, M, N>; C],
}

/// Weight-gradient rows per parameter block: a multiple of the kernel's 6-row tile, about
/// eight blocks at a width of 256.
const fn block_rows(h: usize) -> usize {
    6 * h.div_ceil(48)
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>
{
    /// Rows in a batch.
    pub const B: usize = BC * C;

    /// Validates `cfg`, initialises the networks from `seed` and resets every optimiser,
    /// multiplier and counter.
    pub fn init(&mut self, cfg: MpoConfig, seed: u64) -> Result<(), ConfigError> {
        cfg.validate()?;
        const {
            assert!(
                BC > 0 && C > 0 && L > 0 && M > 0 && N > 0,
                "BC, C, L, M and N must be positive"
            )
        };
        if cfg.sequence_len as usize > L {
            return Err(ConfigError {
                field: "sequence_len",
                requirement: "at most the learner's sequence capacity L",
            });
        }
        if cfg.shared_samples && M != N {
            return Err(ConfigError {
                field: "shared_samples",
                requirement: "false unless the learner has M = N",
            });
        }
        self.cfg = cfg;
        let mut rng = Rng::seed_from_u64(seed);
        let l = &mut self.live;
        l.actor.init(&mut rng, cfg.init_std, cfg.std_floor);
        if cfg.tanh_mean {
            l.actor.squash.init(1.0);
        }
        l.critic.init(&mut rng);
        l.actor_m.fill_zero();
        l.actor_v.fill_zero();
        l.critic_m.fill_zero();
        l.critic_v.fill_zero();
        l.actor_opt = AdamState::default();
        l.critic_opt = AdamState::default();
        let raw = |x: f32| libm::logf(x).clamp(-LOG_ALPHA_MAX, LOG_ALPHA_MAX);
        l.duals = Duals {
            eta: cfg.eta_init,
            eta_penalty: cfg.eta_init,
            alpha_mean_raw: [raw(cfg.alpha_mean_init); ACT],
            alpha_cov_raw: [raw(cfg.alpha_cov_init); ACT],
            moments: [[0.0; ACT]; 4],
            opt: AdamState::default(),
        };
        self.target_actor.copy_from(&self.live.actor);
        self.target_critic.copy_from(&self.live.critic);
        self.updates = 0;
        self.rng_state = rng.state();
        Ok(())
    }

    /// The chunk and slot of batch row `n`.
    pub const fn slot(n: usize) -> (usize, usize) {
        (n / BC, n % BC)
    }

    /// A sampled action from the online policy and its log-probability (the behaviour policy
    /// while collecting experience).
    pub fn sample_action(&self, obs: &[f32; OBS], rng: &mut Rng, action: &mut [f32; ACT]) -> f32 {
        let mut z = [0f32; ACT];
        rng.fill_normal(&mut z);
        self.sample_action_from(obs, &z, action)
    }

    /// The online policy's action `mu + L z` for given standard-normal draws `z` and its
    /// log-density (what [`Learner::sample_action`] does with its own draws).
    pub fn sample_action_from(
        &self,
        obs: &[f32; OBS],
        z: &[f32; ACT],
        action: &mut [f32; ACT],
    ) -> f32 {
        let pi = self.live.actor.distribution(obs, self.cfg.std_floor);
        pi.transform(z, action);
        pi.log_prob(action)
    }

    /// The online policy's mean action (evaluation and deployment).
    pub fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        self.live.actor.mean_action(obs, action);
    }

    /// Refits the policy's observation normalisation to the observations `rows`
    /// ([`crate::obs_norm`]); the target policy gets the same normalisation, so every
    /// network of an update sees the batch in one scale.
    pub fn fit_obs_norm(&mut self, rows: &[[f32; OBS]]) {
        self.live.actor.input.fit(rows);
        self.target_actor.input = self.live.actor.input.clone();
    }

    /// Normalises the states and next states of `self.batch` (its first `sequence_len`
    /// positions) with the policy's observation normalisation: the batch paths of the
    /// networks take normalised observations.
    pub fn normalize_batch(&mut self) {
        let (norm, len) = (&self.live.actor.input, self.cfg.sequence_len as usize);
        for b in self.batch.iter_mut() {
            for k in 0..len {
                norm.apply_rows(&mut b.obs[k]);
                norm.apply_rows(&mut b.next_obs[k]);
            }
        }
    }

    /// The arithmetic of one update in FLOPs under the current configuration, counting the
    /// network passes (2 FLOPs per multiply-add; forward, weight and input gradients), not the
    /// per-sample Gaussian algebra.
    pub fn flops_per_update(&self) -> u64 {
        let a_fwd = Actor::<OBS, ACT, TRI, AH1, AH2>::forward_macs() as u64;
        let c_fwd = Critic::<OBS, ACT, QH1, QH2>::forward_macs() as u64;
        let c_tail = (QH1 * QH2 + QH2 + ACT * QH1) as u64; // after the shared state block
        let c_state = (OBS * QH1) as u64;
        let a_bwd = 2 * a_fwd - (OBS * AH1) as u64; // weight grads + input grads but layer 1
        let c_bwd = 2 * c_fwd - ((OBS + ACT) * QH1) as u64;
        let len = self.cfg.sequence_len as u64;
        let next = len * (a_fwd + c_state + N as u64 * c_tail) + (len - 1) * c_tail;
        let estep = if self.cfg.shared_samples {
            0
        } else {
            a_fwd + c_state + M as u64 * c_tail
        };
        let mstep = self.cfg.mstep_iters as u64 * (a_fwd + a_bwd);
        2 * Self::B as u64 * (next + c_fwd + c_bwd + estep + mstep)
    }

    /// One learner update on `self.batch`, on the calling thread. On error nothing but the
    /// random stream has changed.
    pub fn update(&mut self) -> Result<UpdateStats, UpdateError> {
        self.update_with(&Serial)
    }

    /// [`Learner::update`] with the work spread by `par`; the same bits for any `par`.
    pub fn update_with<P: Parallel>(&mut self, par: &P) -> Result<UpdateStats, UpdateError> {
        let len = self.cfg.sequence_len as usize;
        if !self.batch.iter().all(|b| b.all_finite(len)) {
            return Err(UpdateError::NonFinite(NonFinite::Batch));
        }
        self.backup.copy_from(&self.live);
        let mut rng = Rng::from_state(self.rng_state);
        let seed = rng.next_u64();
        self.rng_state = rng.state();
        let result = self.update_inner(par, seed);
        match result {
            Ok(stats) => {
                self.updates += 1;
                let tau = self.cfg.target_tau;
                if tau > 0.0 {
                    self.target_actor.polyak_from(&self.live.actor, tau);
                    self.target_critic.polyak_from(&self.live.critic, tau);
                } else if self.updates.is_multiple_of(self.cfg.target_period as u64) {
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

    fn update_inner<P: Parallel>(
        &mut self,
        par: &P,
        seed: u64,
    ) -> Result<UpdateStats, UpdateError> {
        let mut stats = UpdateStats::default();
        self.evaluate_and_sample(par, seed, &mut stats)?;
        self.critic_step(par, &mut stats)?;
        self.e_step(par, &mut stats)?;
        for _ in 0..self.cfg.mstep_iters {
            self.m_step(par, &mut stats)?;
        }
        if !self.live.actor.all_finite() || !self.live.critic.all_finite() {
            return Err(UpdateError::NonFinite(NonFinite::Parameters));
        }
        let (am, ac) = (self.live.duals.alpha_mean(), self.live.duals.alpha_cov());
        stats.alpha_mean = am.iter().sum::<f32>() / ACT as f32;
        stats.alpha_cov = ac.iter().sum::<f32>() / ACT as f32;
        Ok(stats)
    }

    /// Every row's work that needs only the target networks and the online critic: the
    /// E-step samples and their values, the policy-evaluation target, the online critic's
    /// forward pass and its gradient down to the hidden layers. Then the row statistics.
    fn evaluate_and_sample<P: Parallel>(
        &mut self,
        par: &P,
        seed: u64,
        stats: &mut UpdateStats,
    ) -> Result<(), UpdateError> {
        self.live.critic.transpose_into(&mut self.grads.ct);
        let (cfg, batch, ta, tc) = (
            &self.cfg,
            &self.batch,
            &self.target_actor,
            &self.target_critic,
        );
        let (critic, ct) = (&self.live.critic, &self.grads.ct);
        let ln = cfg.critic_layer_norm;
        par.for_each(&mut self.chunks, &|c, ch| {
            let b = &batch[c];
            if !cfg.shared_samples {
                estep_samples(cfg, ta, tc, &b.obs[0], seed, c, ch);
            }
            targets(cfg, ta, tc, b, seed, c, ch);
            let act = critic_input(cfg, &b.action[0], &mut ch.critic_action);
            critic.forward(&b.obs[0], act, &mut ch.ctape, &mut ch.q, ln);
            let inv_b = 1.0 / (BC * C) as f32;
            for n in 0..BC {
                ch.err[n] = ch.q[n][0] - ch.target[n];
                ch.dq[n][0] = ch.err[n] * inv_b;
            }
            critic.backprop(&mut ch.ctape, &ch.dq, ct, ln);
            if cfg.action_penalization {
                for n in 0..BC {
                    for j in 0..M {
                        ch.q_penalty[n][j] = -excess(&ch.samples[j][n]);
                    }
                }
            }
        });
        let (mut loss, mut tsum) = (0f32, 0f32);
        let (mut qsum, mut qmin, mut qmax, mut xsum) =
            (0f64, f32::INFINITY, f32::NEG_INFINITY, 0f64);
        for ch in &self.chunks {
            for n in 0..BC {
                loss += 0.5 * ch.err[n] * ch.err[n];
                tsum += ch.target[n];
                for j in 0..M {
                    let v = ch.q_samples[n][j];
                    qsum += v as f64;
                    qmin = qmin.min(v);
                    qmax = qmax.max(v);
                    xsum += excess(&ch.samples[j][n]) as f64;
                }
            }
        }
        let b = Self::B as f32;
        stats.critic_loss = loss / b;
        stats.target_mean = tsum / b;
        stats.q_mean = (qsum / (Self::B * M) as f64) as f32;
        stats.q_min = qmin;
        stats.q_max = qmax;
        stats.action_excess = (xsum / (Self::B * M) as f64) as f32;
        if !stats.critic_loss.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::CriticLoss));
        }
        if !qsum.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::EStep));
        }
        Ok(())
    }

    /// The critic's weight gradients (by parameter blocks), clipping and one Adam step.
    fn critic_step<P: Parallel>(
        &mut self,
        par: &P,
        stats: &mut UpdateStats,
    ) -> Result<(), UpdateError> {
        let chunks = &self.chunks;
        let batch = &self.batch;
        let obs: [&[[f32; OBS]]; C] = core::array::from_fn(|c| &batch[c].obs[0][..]);
        let clip = self.cfg.clip_critic_actions;
        let act: [&[[f32; ACT]]; C] = core::array::from_fn(|c| {
            if clip {
                &chunks[c].critic_action[..]
            } else {
                &batch[c].action[0][..]
            }
        });
        let h1: [&[[f32; QH1]]; C] = core::array::from_fn(|c| &chunks[c].ctape.h1[..]);
        let h2: [&[[f32; QH2]]; C] = core::array::from_fn(|c| &chunks[c].ctape.h2[..]);
        let d_h1: [&[[f32; QH1]]; C] = core::array::from_fn(|c| &chunks[c].ctape.d_h1[..]);
        let d_h2: [&[[f32; QH2]]; C] = core::array::from_fn(|c| &chunks[c].ctape.d_h2[..]);
        let dq: [&[[f32; 1]]; C] = core::array::from_fn(|c| &chunks[c].dq[..]);
        let xhat: [&[[f32; QH1]]; C] = core::array::from_fn(|c| &chunks[c].ctape.xhat[..]);
        let d_y: [&[[f32; QH1]]; C] = core::array::from_fn(|c| &chunks[c].ctape.d_y[..]);
        let inputs = CriticGradInputs {
            obs: &obs,
            act: &act,
            h1: &h1,
            h2: &h2,
            d_h1: &d_h1,
            d_h2: &d_h2,
            dq: &dq,
            xhat: &xhat,
            d_y: &d_y,
            layer_norm: self.cfg.critic_layer_norm,
        };
        let mut parts: heapless::Vec<_, { crate::actor::MAX_PARTS }> = self
            .grads
            .critic
            .grad_parts(block_rows(QH1))
            .into_iter()
            .map(|p| (p, 0f64))
            .collect();
        par.for_each(&mut parts, &|_, (p, sq)| *sq = p.compute(&inputs));
        let norm = libm::sqrt(parts.iter().map(|(_, sq)| *sq).sum::<f64>()) as f32;
        drop(parts);
        stats.critic_grad_norm = norm;
        if !norm.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::CriticGradients));
        }
        let scale = clip_scale(norm, self.cfg.critic_clip);
        let l = &mut self.live;
        adam_step_with(
            par,
            &AdamConfig::with_lr(self.cfg.critic_lr),
            &mut l.critic_opt,
            &mut l.critic,
            &self.grads.critic,
            scale,
            &mut l.critic_m,
            &mut l.critic_v,
        );
        Ok(())
    }

    /// Temperatures, weights and the per-state sample statistics of the M-step.
    fn e_step<P: Parallel>(&mut self, par: &P, stats: &mut UpdateStats) -> Result<(), UpdateError> {
        let cfg = self.cfg;
        let sol = solve_temperature_with(
            cfg.eps_eta,
            self.live.duals.eta,
            cfg.estep_tol,
            cfg.estep_max_iter,
            &mut |eta| dual_sums(par, &mut self.chunks, eta, false),
        );
        if !sol.eta.is_finite() || sol.eta <= 0.0 {
            return Err(UpdateError::NonFinite(NonFinite::EStep));
        }
        self.live.duals.eta = sol.eta;
        stats.eta = sol.eta;
        stats.estep_iterations = sol.iterations;
        let eta_pen = if cfg.action_penalization {
            let pen = solve_temperature_with(
                cfg.eps_penalty,
                self.live.duals.eta_penalty,
                cfg.estep_tol,
                cfg.estep_max_iter,
                &mut |eta| dual_sums(par, &mut self.chunks, eta, true),
            );
            if !pen.eta.is_finite() || pen.eta <= 0.0 {
                return Err(UpdateError::NonFinite(NonFinite::EStep));
            }
            self.live.duals.eta_penalty = pen.eta;
            stats.eta_penalty = pen.eta;
            Some(pen.eta)
        } else {
            None
        };
        par.for_each(&mut self.chunks, &|_, ch| {
            weigh_samples(ch, sol.eta, eta_pen)
        });
        let mut kl = 0f64;
        for ch in &self.chunks {
            for n in 0..BC {
                kl += ch.estep_kl[n] as f64;
            }
        }
        stats.estep_kl = (kl / Self::B as f64) as f32;
        Ok(())
    }

    /// One M-step iteration: the actor's gradient (rows, then parameter blocks), clipping,
    /// one Adam step, then one step of the multipliers.
    fn m_step<P: Parallel>(&mut self, par: &P, stats: &mut UpdateStats) -> Result<(), UpdateError> {
        let cfg = self.cfg;
        self.live.actor.transpose_into(&mut self.grads.at);
        let (d, actor, at, batch) = (
            &self.live.duals,
            &self.live.actor,
            &self.grads.at,
            &self.batch,
        );
        let inv_b = 1.0 / Self::B as f32;
        let c_mean = d.alpha_mean().map(|a| a * inv_b);
        let c_cov = d.alpha_cov().map(|a| a * inv_b);
        par.for_each(&mut self.chunks, &|c, ch| {
            let states = if cfg.shared_samples {
                &batch[c].next_obs[0]
            } else {
                &batch[c].obs[0]
            };
            actor.forward(states, &mut ch.atape, &mut ch.mean, &mut ch.chol);
            for n in 0..BC {
                ch.terms[n] = state_gradient(
                    &ch.old[n],
                    &ch.mean[n],
                    &ch.chol[n],
                    &ch.stats[n],
                    inv_b,
                    &c_mean,
                    &c_cov,
                    cfg.std_floor,
                    &mut ch.d_mean[n],
                    &mut ch.d_chol[n],
                );
            }
            actor.squash_backward(&ch.mean, &mut ch.d_mean);
            actor.backprop(&mut ch.atape, &ch.d_mean, &ch.d_chol, at);
        });
        let (mut kl_mean, mut kl_cov) = ([0f32; ACT], [0f32; ACT]);
        let mut nll = 0f32;
        let (mut mu_sum, mut mu_abs, mut sd_sum) = (0f32, 0f32, 0f32);
        let (mut sd_min, mut sd_max) = (f32::INFINITY, 0f32);
        for ch in &self.chunks {
            for t in &ch.terms {
                for k in 0..ACT {
                    kl_mean[k] += t.kl_mean[k] * inv_b;
                    kl_cov[k] += t.kl_cov[k] * inv_b;
                    mu_sum += t.mu[k];
                    mu_abs += t.mu[k].abs();
                    sd_sum += t.std[k];
                    sd_min = sd_min.min(t.std[k]);
                    sd_max = sd_max.max(t.std[k]);
                }
                nll += t.nll;
            }
        }
        let norm = self.actor_gradient(par);
        let (km_tot, kc_tot): (f32, f32) = (kl_mean.iter().sum(), kl_cov.iter().sum());
        if !(norm.is_finite() && nll.is_finite() && km_tot.is_finite() && kc_tot.is_finite()) {
            return Err(UpdateError::NonFinite(NonFinite::ActorGradients));
        }
        let scale = clip_scale(norm, cfg.actor_clip);
        let l = &mut self.live;
        adam_step_with(
            par,
            &AdamConfig::with_lr(cfg.actor_lr),
            &mut l.actor_opt,
            &mut l.actor,
            &self.grads.actor,
            scale,
            &mut l.actor_m,
            &mut l.actor_v,
        );
        update_multipliers(&mut l.duals, &cfg, &kl_mean, &kl_cov);

        let bd = (Self::B * ACT) as f32;
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

    /// The actor's weight gradients by parameter blocks from the chunks' tapes; returns the
    /// global norm (before clipping).
    fn actor_gradient<P: Parallel>(&mut self, par: &P) -> f32 {
        let (chunks, batch, shared) = (&self.chunks, &self.batch, self.cfg.shared_samples);
        let obs: [&[[f32; OBS]]; C] = core::array::from_fn(|c| {
            if shared {
                &batch[c].next_obs[0][..]
            } else {
                &batch[c].obs[0][..]
            }
        });
        let h1: [&[[f32; AH1]]; C] = core::array::from_fn(|c| &chunks[c].atape.h1[..]);
        let h2: [&[[f32; AH2]]; C] = core::array::from_fn(|c| &chunks[c].atape.h2[..]);
        let d_h1: [&[[f32; AH1]]; C] = core::array::from_fn(|c| &chunks[c].atape.d_h1[..]);
        let d_h2: [&[[f32; AH2]]; C] = core::array::from_fn(|c| &chunks[c].atape.d_h2[..]);
        let d_mean: [&[[f32; ACT]]; C] = core::array::from_fn(|c| &chunks[c].d_mean[..]);
        let d_chol: [&[[f32; TRI]]; C] = core::array::from_fn(|c| &chunks[c].d_chol[..]);
        let inputs = ActorGradInputs {
            obs: &obs,
            h1: &h1,
            h2: &h2,
            d_h1: &d_h1,
            d_h2: &d_h2,
            d_mean: &d_mean,
            d_chol: &d_chol,
        };
        let mut parts: heapless::Vec<_, { crate::actor::MAX_PARTS }> = self
            .grads
            .actor
            .grad_parts(block_rows(AH1))
            .into_iter()
            .map(|p| (p, 0f64))
            .collect();
        par.for_each(&mut parts, &|_, (p, sq)| *sq = p.compute(&inputs));
        libm::sqrt(parts.iter().map(|(_, sq)| *sq).sum::<f64>()) as f32
    }
}

/// The factor that clips a gradient of global norm `norm` to `max` (1 when it is inside).
fn clip_scale(norm: f32, max: f32) -> f32 {
    if norm > max { max / norm } else { 1.0 }
}

/// `|a - clip(a, -1, 1)|^2`: how far an action lies outside the actuators' range.
fn excess<const A: usize>(a: &[f32; A]) -> f32 {
    let mut s = 0.0;
    for &x in a {
        let d = x - x.clamp(-1.0, 1.0);
        s += d * d;
    }
    s
}

/// Clips every action of `rows` to the actuators' range `[-1, 1]`.
fn clip_rows<const ACT: usize>(rows: &mut [[f32; ACT]]) {
    for x in rows.iter_mut().flatten() {
        *x = x.clamp(-1.0, 1.0);
    }
}

/// The actions a critic pass is given: `a` itself, or (with `clip_critic_actions`) a copy in
/// `buf` clipped to `[-1, 1]`, what the plant applies.
fn critic_input<'a, const ACT: usize, const BC: usize>(
    cfg: &MpoConfig,
    a: &'a [[f32; ACT]; BC],
    buf: &'a mut [[f32; ACT]; BC],
) -> &'a [[f32; ACT]; BC] {
    if cfg.clip_critic_actions {
        *buf = *a;
        clip_rows(buf);
        buf
    } else {
        a
    }
}

/// The E-step's samples at the chunk's states `obs` and their target-critic values: the
/// target policy there (kept in `ch.old`), `M` draws per row from the row's own stream.
#[allow(clippy::too_many_arguments)]
fn estep_samples<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    cfg: &MpoConfig,
    ta: &Actor<OBS, ACT, TRI, AH1, AH2>,
    tc: &Critic<OBS, ACT, QH1, QH2>,
    obs: &[[f32; OBS]; BC],
    seed: u64,
    c: usize,
    ch: &mut Chunk<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, L, M, N>,
) {
    ta.forward(obs, &mut ch.atape, &mut ch.mean, &mut ch.chol);
    tc.state_part(obs, &mut ch.pre1);
    for n in 0..BC {
        ch.old[n] = Gaussian::from_head(&ch.mean[n], &ch.chol[n], cfg.std_floor);
        let mut z = [[0f32; ACT]; M];
        Rng::for_stream(seed, STREAM_ESTEP, (c * BC + n) as u32).fill_normal(z.as_flattened_mut());
        for j in 0..M {
            ch.old[n].transform(&z[j], &mut ch.samples[j][n]);
        }
    }
    for j in 0..M {
        tc.forward_from_state_part(
            &ch.pre1,
            critic_input(cfg, &ch.samples[j], &mut ch.clipped),
            &mut ch.ctape,
            &mut ch.q,
            cfg.critic_layer_norm,
        );
        for n in 0..BC {
            ch.q_samples[n][j] = ch.q[n][0];
        }
    }
}

/// The chunk's policy-evaluation targets into `ch.target`: Retrace over the rows'
/// `sequence_len` transitions (TD(0) expected SARSA when that is 1). Position `k` needs the
/// target policy and the target critic's state part at `s_{k+1}`; position `k + 1` reuses both
/// (its state is `s_{k+1}`) for its action's value and importance weight. In shared-samples
/// mode position 0's samples and values become the E-step's.
fn targets<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    cfg: &MpoConfig,
    ta: &Actor<OBS, ACT, TRI, AH1, AH2>,
    tc: &Critic<OBS, ACT, QH1, QH2>,
    b: &BatchChunk<BC, L, OBS, ACT>,
    seed: u64,
    c: usize,
    ch: &mut Chunk<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, L, M, N>,
) {
    let len = cfg.sequence_len as usize;
    for k in 0..len {
        if k > 0 {
            // s_k is the previous position's next state: its target policy and state part
            // are still in `next_pi` and `pre1`.
            tc.forward_from_state_part(
                &ch.pre1,
                critic_input(cfg, &b.action[k], &mut ch.clipped),
                &mut ch.ctape,
                &mut ch.q,
                cfg.critic_layer_norm,
            );
            for n in 0..BC {
                ch.ret_q[k][n] = ch.q[n][0];
                ch.ret_log_ratio[k][n] =
                    ch.next_pi[n].log_prob(&b.action[k][n]) - b.behaviour_log_prob[k][n];
            }
        }
        ta.forward(&b.next_obs[k], &mut ch.atape, &mut ch.mean, &mut ch.chol);
        tc.state_part(&b.next_obs[k], &mut ch.pre1);
        for n in 0..BC {
            ch.next_pi[n] = Gaussian::from_head(&ch.mean[n], &ch.chol[n], cfg.std_floor);
            let mut z = [[0f32; ACT]; N];
            Rng::for_stream(seed, STREAM_NEXT + k as u32, (c * BC + n) as u32)
                .fill_normal(z.as_flattened_mut());
            for j in 0..N {
                ch.next_pi[n].transform(&z[j], &mut ch.next_samples[j][n]);
            }
        }
        let mut v = [0f32; BC];
        for j in 0..N {
            tc.forward_from_state_part(
                &ch.pre1,
                critic_input(cfg, &ch.next_samples[j], &mut ch.clipped),
                &mut ch.ctape,
                &mut ch.q,
                cfg.critic_layer_norm,
            );
            for n in 0..BC {
                v[n] += ch.q[n][0];
            }
            if cfg.shared_samples && j < M {
                for n in 0..BC {
                    ch.q_samples[n][j] = ch.q[n][0];
                    ch.samples[j][n] = ch.next_samples[j][n];
                }
            }
        }
        for n in 0..BC {
            ch.ret_v[k][n] = v[n] / N as f32;
        }
    }
    if cfg.shared_samples {
        ch.old = ch.next_pi;
    }
    let (mut q, mut v, mut r, mut d, mut lr, mut out) = (
        [0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L],
    );
    for n in 0..BC {
        for k in 0..len {
            q[k] = ch.ret_q[k][n];
            v[k] = ch.ret_v[k][n];
            r[k] = b.reward[k][n];
            d[k] = b.bootstrap[k][n];
            lr[k] = ch.ret_log_ratio[k][n];
        }
        // The bootstrap multipliers already hold gamma times the discounts.
        crate::evaluation::retrace(
            &q[..len],
            &v[..len],
            &r[..len],
            &d[..len],
            &lr[..len],
            1.0,
            &mut out[..len],
        );
        ch.target[n] = out[0];
    }
}

/// The summed dual rows of every chunk at `eta` (of the penalty objective when `penalty`),
/// computed by `par` and added in batch order.
fn dual_sums<
    P: Parallel,
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    par: &P,
    chunks: &mut [Chunk<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, L, M, N>],
    eta: f64,
    penalty: bool,
) -> DualSums {
    par.for_each(chunks, &|_, ch| {
        for n in 0..BC {
            let row = if penalty {
                &ch.q_penalty[n]
            } else {
                &ch.q_samples[n]
            };
            ch.dual[n] = dual_row(row, eta);
        }
    });
    let mut s = DualSums::default();
    for ch in chunks.iter() {
        for r in &ch.dual {
            s.add(r);
        }
    }
    s
}

/// The chunk's E-step weights at the solved temperatures, folded straight into each state's
/// [`SampleStats`] (the penalty objective's weights join the task's), and each state's
/// KL(q || pi_old).
fn weigh_samples<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    ch: &mut Chunk<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, L, M, N>,
    eta: f32,
    eta_penalty: Option<f32>,
) {
    for n in 0..BC {
        let mut w = [0f32; M];
        ch.estep_kl[n] = crate::estep::weights(
            core::slice::from_ref(&ch.q_samples[n]),
            eta,
            core::slice::from_mut(&mut w),
        ) as f32;
        if let Some(eta_p) = eta_penalty {
            let mut wp = [0f32; M];
            crate::estep::weights(
                core::slice::from_ref(&ch.q_penalty[n]),
                eta_p,
                core::slice::from_mut(&mut wp),
            );
            for j in 0..M {
                w[j] += wp[j];
            }
        }
        let mut st = SampleStats::ZERO;
        for j in 0..M {
            st.add(w[j], &ch.samples[j][n], &ch.old[n].mu);
        }
        ch.stats[n] = st;
    }
}
