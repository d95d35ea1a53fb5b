//! A fixed, small training workload whose result fingerprints the core's arithmetic.
//!
//! It exercises every numerical routine of the core (RNG draws, batch forward and backward of
//! both networks, the Gaussian's sampling, log-density and KL gradients, gradient clipping,
//! Adam) and returns an FNV-1a hash of the final parameters; [`SelfCheck::learner`] does the
//! same for whole learner updates (E-step with its temperature solve, M-step, TD and Retrace
//! targets, action penalization, shared samples, Polyak targets, the layer-normalised critic). The same seed must give the
//! same hash in every build: std and `no_std`, debug and release, any target CPU. The
//! freestanding test binary prints it, and the test suite compares.

use bytemuck::Zeroable;

use crate::actor::{Actor, ActorTape, ActorTransposed};
use crate::adam::{AdamConfig, AdamState, adam_step};
use crate::config::MpoConfig;
use crate::critic::{Critic, CriticTape, CriticTransposed};
use crate::gaussian::{Gaussian, GaussianGrad, head_backward, kl_parts_grad};
use crate::learner::Learner;
use crate::params::{Params, clip_global_norm, fingerprint};
use crate::rng::Rng;

const OBS: usize = 5;
const ACT: usize = 2;
const TRI: usize = 3;
const H: usize = 16;
const B: usize = 8;
const FLOOR: f32 = 1e-3;

type A = Actor<OBS, ACT, TRI, H, H>;
type C = Critic<OBS, ACT, H, H>;
/// The learner of the check: 2 chunks of 4 rows, sequences of up to 3, 6 samples.
type SmallLearner = Learner<OBS, ACT, TRI, H, H, 12, H, 4, 2, 3, 6, 6>;

/// All the state of the workload (about 40 KiB: fits on any stack it is meant for).
#[derive(Zeroable)]
pub struct SelfCheck {
    actor: A,
    actor_old: A,
    actor_grad: A,
    actor_m: A,
    actor_v: A,
    actor_opt: AdamState,
    critic: C,
    critic_grad: C,
    critic_m: C,
    critic_v: C,
    critic_opt: AdamState,
    actor_tape: ActorTape<B, H, H>,
    critic_tape: CriticTape<B, H, H>,
    actor_t: ActorTransposed<ACT, TRI, H, H>,
    critic_t: CriticTransposed<H, H>,
    learner: SmallLearner,
}

impl SelfCheck {
    /// Runs `steps` training steps from `seed` and returns the parameter fingerprint.
    pub fn run(&mut self, seed: u64, steps: usize) -> u64 {
        let mut rng = Rng::seed_from_u64(seed);
        self.actor.init(&mut rng, 0.5, FLOOR);
        self.critic.init(&mut rng);
        self.actor_m.fill_zero();
        self.actor_v.fill_zero();
        self.critic_m.fill_zero();
        self.critic_v.fill_zero();
        self.actor_opt = AdamState::default();
        self.critic_opt = AdamState::default();
        let cfg = AdamConfig::with_lr(1e-2);
        for _ in 0..steps {
            self.step(&mut rng, &cfg);
        }
        fingerprint(&self.actor) ^ fingerprint(&self.critic).rotate_left(1)
    }

    fn step(&mut self, rng: &mut Rng, cfg: &AdamConfig) {
        let mut obs = [[0f32; OBS]; B];
        rng.fill_normal(obs.as_flattened_mut());
        let mut mean = [[0f32; ACT]; B];
        let mut chol = [[0f32; TRI]; B];
        let mut d_mean = [[0f32; ACT]; B];
        let mut d_chol = [[0f32; TRI]; B];
        let mut actions = [[0f32; ACT]; B];
        let mut reward = [0f32; B];
        self.actor_old.copy_from(&self.actor);
        self.actor
            .forward(&obs, &mut self.actor_tape, &mut mean, &mut chol);
        for n in 0..B {
            let pi = Gaussian::from_head(&mean[n], &chol[n], FLOOR);
            pi.sample(rng, &mut actions[n]);
            // Supervised target: the action (tanh(s0), -s1/2), pushed to be likely, with a
            // small KL penalty to a perturbed copy of the current policy.
            let target = [libm::tanhf(obs[n][0]), -0.5 * obs[n][1]];
            let mut g = GaussianGrad::ZERO;
            pi.log_prob_grad(&target, -1.0 / B as f32, &mut g);
            let mut old = pi;
            old.mu[0] += 0.1;
            kl_parts_grad(&old, &pi, 0.1, 0.1, &mut g);
            head_backward(&chol[n], &g, &mut d_mean[n], &mut d_chol[n]);
            reward[n] = -(actions[n][0] - target[0]).abs() - (actions[n][1] - target[1]).abs();
        }
        self.actor.backward(
            &obs,
            &mut self.actor_tape,
            &d_mean,
            &d_chol,
            &mut self.actor_t,
            &mut self.actor_grad,
        );
        clip_global_norm(&mut self.actor_grad, 1.0);
        adam_step(
            cfg,
            &mut self.actor_opt,
            &mut self.actor,
            &self.actor_grad,
            &mut self.actor_m,
            &mut self.actor_v,
        );

        let mut q = [[0f32; 1]; B];
        self.critic
            .forward(&obs, &actions, &mut self.critic_tape, &mut q, false);
        let mut dq = [[0f32; 1]; B];
        for n in 0..B {
            dq[n][0] = (q[n][0] - reward[n]) / B as f32;
        }
        self.critic.backward(
            &obs,
            &actions,
            &mut self.critic_tape,
            &dq,
            &mut self.critic_t,
            &mut self.critic_grad,
            false,
        );
        clip_global_norm(&mut self.critic_grad, 1.0);
        adam_step(
            cfg,
            &mut self.critic_opt,
            &mut self.critic,
            &self.critic_grad,
            &mut self.critic_m,
            &mut self.critic_v,
        );
    }
}

impl SelfCheck {
    /// Runs `updates` learner updates on random batches in each of three configurations (TD
    /// with action penalization and per-dimension KL; Retrace over 3 transitions with Polyak
    /// targets; shared samples) and returns the combined fingerprint of the online networks,
    /// the temperatures and the multipliers.
    pub fn learner(&mut self, seed: u64, updates: usize) -> u64 {
        let base = MpoConfig {
            mstep_iters: 2,
            actor_clip: 40.0,
            ..MpoConfig::REPORT
        };
        let configs = [
            MpoConfig {
                action_penalization: true,
                per_dim_kl: true,
                eps_mean: 0.05,
                ..base
            },
            MpoConfig {
                sequence_len: 3,
                target_tau: 0.05,
                tanh_mean: true,
                clip_critic_actions: true,
                ..base
            },
            MpoConfig {
                shared_samples: true,
                critic_layer_norm: true,
                obs_norm_interval: 1,
                ..base
            },
        ];
        let mut h = 0u64;
        for (i, cfg) in configs.iter().enumerate() {
            let l = &mut self.learner;
            l.init(*cfg, seed + i as u64).expect("valid configuration");
            let mut rng = Rng::seed_from_u64(seed ^ 0x5eed);
            for _ in 0..updates {
                for b in l.batch.iter_mut() {
                    rng.fill_normal(b.obs.as_flattened_mut().as_flattened_mut());
                    // Actions partly outside [-1, 1], so the penalty objective has work.
                    rng.fill_normal(b.action.as_flattened_mut().as_flattened_mut());
                    for a in b.action.as_flattened_mut().as_flattened_mut() {
                        *a *= 1.5;
                    }
                    rng.fill_normal(b.next_obs.as_flattened_mut().as_flattened_mut());
                    rng.fill_normal(b.reward.as_flattened_mut());
                    for x in b.bootstrap.as_flattened_mut() {
                        *x = 0.99;
                    }
                    for x in b.behaviour_log_prob.as_flattened_mut() {
                        *x = -1.0 - rng.uniform();
                    }
                }
                if cfg.obs_norm_interval > 0 {
                    // The observation normaliser fit to the batch's first chunk of states,
                    // then applied to the whole batch, as the agent does with its replay.
                    let rows = l.batch[0].obs[0];
                    l.fit_obs_norm(&rows);
                    l.normalize_batch();
                }
                l.update().expect("finite update");
            }
            let d = &l.live.duals;
            let mut dh = 0xcbf2_9ce4_8422_2325u64;
            for x in [d.eta, d.eta_penalty]
                .iter()
                .chain(&d.alpha_mean_raw)
                .chain(&d.alpha_cov_raw)
            {
                dh = (dh ^ x.to_bits() as u64).wrapping_mul(0x0000_0100_0000_01b3);
            }
            h ^= (fingerprint(&l.live.actor) ^ fingerprint(&l.live.critic).rotate_left(1) ^ dh)
                .rotate_left(7 * i as u32);
        }
        h
    }
}

/// The fingerprint of the policy's forward pass on a fixed input after `init` from `seed`:
/// the firmware-sized check (inference only).
pub fn forward_checksum(seed: u64) -> u64 {
    let mut actor = A::zeroed();
    let mut rng = Rng::seed_from_u64(seed);
    actor.init(&mut rng, 0.5, FLOOR);
    // A non-trivial observation normaliser (shifts and scales away from the identity, one
    // input clipped), so the firmware's normalisation is in the fingerprint too.
    for j in 0..OBS {
        actor.input.shift[j] = 0.25 * rng.normal();
        actor.input.scale[j] = 0.5 + rng.uniform();
        actor.input.limit[j] = if j == 0 { 0.1 } else { crate::obs_norm::CLIP };
    }
    // Every other mean squashed, with a bound near the initial means' scale so `tanh` works
    // in its curved part: the firmware's squash is in the fingerprint too.
    for k in 0..ACT {
        actor.squash.bound[k] = if k % 2 == 0 { 0.02 } else { 0.0 };
    }
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for _ in 0..16 {
        let mut obs = [0f32; OBS];
        rng.fill_normal(&mut obs);
        let mut m = [0f32; ACT];
        let mut c = [0f32; TRI];
        actor.forward_one(&obs, &mut m, &mut c);
        for x in m.iter().chain(c.iter()) {
            h = (h ^ x.to_bits() as u64).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}
