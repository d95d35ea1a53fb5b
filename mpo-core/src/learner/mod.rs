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
//! to a [`Parallel`](crate::parallel::Parallel): the batch chunks for everything per row
//! (network passes, sampling, the Gaussian algebra), blocks of parameter rows for the weight
//! gradients. Every row draws from
//! its own random stream keyed by the update and the row's index, every weight gradient sums
//! its rows in batch order, and every reduction over rows (losses, KLs, the E-step's dual)
//! adds them in batch order afterwards. So the result depends on `B` and the configuration,
//! never on `C`, on the number of threads or on their timing.
//!
//! "Old" is the target policy throughout. Everything lives in the struct: construct it zeroed
//! (`bytemuck::zeroed_box` on a host, a zeroed static on a device), then [`Learner::init`].
//! A non-finite value anywhere in an update makes it return an error with every parameter,
//! optimiser moment and multiplier as it was before the update.
//!
//! **Networks.** [`LearnerOf`] takes its policy and critic as types (`P`, `Q`: any form with
//! the traits of [`crate::network`]); [`Learner`] is it with the two-layer MLPs, the form every
//! earlier row trains, with the same bits as before the traits existed.
//!
//! **Resets.** With `reset_interval > 0` (D'Oro et al., 2023), every `reset_interval` updates the
//! networks are drawn afresh from the learner's stream, their optimisers and the multipliers
//! restart and the targets copy them; the replay, the observation normalisation and the
//! counters stay ([`LearnerOf::reset`]). With `weight_norm` (SimbaV2's alternative), the hidden
//! layers' weights are held on the unit sphere instead: projected at initialisation and after
//! every Adam step of their network ([`crate::hypersphere`]).
//!
//! **Where things are.** This file holds the struct, its construction and acting; `update`
//! runs an update and its phases over the chunks (the parallel loops and the reductions in
//! batch order); `state` is what an update changes ([`Trainable`]), `scratch` the per-chunk
//! memory, `stats` what an update reports ([`UpdateStats`]), `error` why it failed. The
//! per-row work of each phase lives beside its maths, written once over a chunk's rows:
//! [`crate::evaluation`] (targets), [`crate::estep`] (samples, dual terms, weights) and
//! [`crate::mstep`] (loss terms and head gradients), through the private `nets` for the target
//! networks.

// `derive(Zeroable)` repeats `LearnerOf`'s bounds on the type parameters its fields are.
#![allow(clippy::multiple_bound_locations)]

mod error;
mod scratch;
mod state;
mod stats;
mod update;

pub use error::{NonFinite, UpdateError};
pub use state::Trainable;
pub use stats::UpdateStats;

use bytemuck::Zeroable;

use crate::actor::Actor;
use crate::adam::AdamState;
use crate::batch::BatchChunk;
use crate::config::{ConfigError, LOG_ALPHA_MAX, MpoConfig};
use crate::critic::Critic;
use crate::mstep::Duals;
use crate::network::{PolicyTrain, ValueNet};
use crate::rng::Rng;
use scratch::{Chunk, Grads};

/// The complete MPO learner for `OBS` observations and `ACT` actions
/// (`TRI = ACT (ACT + 1) / 2`) with the policy network `P` and the critic `Q`, a batch of `C`
/// chunks of `BC` rows of up to `L` transitions, `M` E-step samples per state and `N`
/// next-action samples per next state.
#[derive(Zeroable)]
#[zeroable(bound = "")]
pub struct LearnerOf<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> {
    /// Hyperparameters (validated by [`LearnerOf::init`]).
    pub cfg: MpoConfig,
    /// Online networks, optimiser states and duals.
    pub live: Trainable<OBS, ACT, TRI, P, Q>,
    /// Target (old) policy.
    pub target_actor: P,
    /// Target critic.
    pub target_critic: Q,
    /// Updates completed.
    pub updates: u64,
    /// State of the learner's random stream (restored exactly from checkpoints).
    pub rng_state: [u8; 32],
    /// The batch the next update learns from, in chunks (row `n` is `batch[n / BC]`, slot
    /// `n % BC`: see [`LearnerOf::slot`]).
    pub batch: [BatchChunk<BC, L, OBS, ACT>; C],
    backup: Trainable<OBS, ACT, TRI, P, Q>,
    grads: Grads<OBS, ACT, TRI, P, Q>,
    chunks: [Chunk<OBS, ACT, TRI, P, Q, BC, L, M, N>; C],
}

/// The learner with the two-layer MLPs (actor widths `AH1`, `AH2`, critic widths `QH1`,
/// `QH2`): [`LearnerOf`] as every row before the residual networks trained it.
pub type Learner<
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
> = LearnerOf<
    OBS,
    ACT,
    TRI,
    Actor<OBS, ACT, TRI, AH1, AH2>,
    Critic<OBS, ACT, QH1, QH2>,
    BC,
    C,
    L,
    M,
    N,
>;

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>
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
        if cfg.weight_norm && !(P::PROJECTS && Q::PROJECTS) {
            return Err(ConfigError {
                field: "weight_norm",
                requirement: "false unless both networks are residual (they project their weights)",
            });
        }
        self.cfg = cfg;
        let mut rng = Rng::seed_from_u64(seed);
        self.init_networks(&mut rng);
        self.updates = 0;
        self.rng_state = rng.state();
        Ok(())
    }

    /// Draws the online networks from `rng`, restarts their optimisers and the multipliers
    /// and copies the networks into the targets.
    fn init_networks(&mut self, rng: &mut Rng) {
        let cfg = self.cfg;
        let l = &mut self.live;
        l.actor.init(rng, cfg.init_std, cfg.std_floor);
        if cfg.tanh_mean {
            l.actor.squash_mut().init(1.0);
        }
        l.critic.init(rng);
        if cfg.weight_norm {
            l.actor.project_weights();
            l.critic.project_weights();
        }
        l.actor_m.fill_zero();
        l.actor_v.fill_zero();
        l.critic_m.fill_zero();
        l.critic_v.fill_zero();
        l.actor_opt = AdamState::default();
        l.critic_opt = AdamState::default();
        let raw = |x: f32| libm::logf(x).clamp(-LOG_ALPHA_MAX, cfg.log_alpha_max);
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
    }

    /// A periodic reset (`reset_interval`, D'Oro et al. 2023): fresh networks drawn from the
    /// learner's stream, fresh optimisers and multipliers, targets copied; the observation
    /// normalisation (a statistic of the replay, not learnt) and the counters are kept.
    pub fn reset(&mut self) {
        let input = self.live.actor.input().clone();
        let mut rng = Rng::from_state(self.rng_state);
        self.init_networks(&mut rng);
        self.rng_state = rng.state();
        *self.live.actor.input_mut() = input.clone();
        *self.target_actor.input_mut() = input;
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
    /// log-density (what [`LearnerOf::sample_action`] does with its own draws).
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
        self.live.actor.input_mut().fit(rows);
        *self.target_actor.input_mut() = self.live.actor.input().clone();
    }

    /// Normalises the states and next states of `self.batch` (its first `sequence_len`
    /// positions) with the policy's observation normalisation: the batch paths of the
    /// networks take normalised observations.
    pub fn normalize_batch(&mut self) {
        let (norm, len) = (self.live.actor.input(), self.cfg.sequence_len as usize);
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
        let a_fwd = P::forward_macs() as u64;
        let c_fwd = Q::forward_macs() as u64;
        let c_state = Q::state_macs() as u64;
        let c_tail = c_fwd - c_state; // after the shared state block
        let a_bwd = P::backward_macs() as u64;
        let c_bwd = Q::backward_macs() as u64;
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
}
