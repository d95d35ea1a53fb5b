//! One learner update: its phases over the batch chunks, each a parallel loop over the
//! chunks' rows (the per-row code is in the phase's module) followed by reductions in batch
//! order.

use crate::adam::{AdamConfig, adam_step_with};
use crate::estep::{DualSums, SampleSums, solve_temperature_with};
use crate::mstep::{LossScale, TermSums, update_multipliers};
use crate::nets::{TargetPass, critic_input};
use crate::network::{PolicyGradInputs, PolicyTrain, ValueGradInputs, ValueNet};
use crate::parallel::{Parallel, Serial};
use crate::rng::Rng;

use super::{LearnerOf, NonFinite, UpdateError, UpdateStats};

/// The factor that clips a gradient of global norm `norm` to `max` (1 when it is inside).
fn clip_scale(norm: f32, max: f32) -> f32 {
    if norm > max { max / norm } else { 1.0 }
}

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
    /// One learner update on `self.batch`, on the calling thread. On error nothing but the
    /// random stream has changed.
    pub fn update(&mut self) -> Result<UpdateStats, UpdateError> {
        self.update_with(&Serial)
    }

    /// [`LearnerOf::update`] with the work spread by `par`; the same bits for any `par`.
    pub fn update_with<Par: Parallel>(&mut self, par: &Par) -> Result<UpdateStats, UpdateError> {
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
                let every = self.cfg.reset_interval as u64;
                if every > 0 && self.updates.is_multiple_of(every) {
                    self.reset();
                }
                Ok(stats)
            }
            Err(e) => {
                self.live.copy_from(&self.backup);
                Err(e)
            }
        }
    }

    fn update_inner<Par: Parallel>(
        &mut self,
        par: &Par,
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
    // Never inlined: a phase is a function of its own in profiles (docs/core.md).
    #[inline(never)]
    fn evaluate_and_sample<Par: Parallel>(
        &mut self,
        par: &Par,
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
        let len = cfg.sequence_len as usize;
        let inv_b = 1.0 / Self::B as f32;
        par.for_each(&mut self.chunks, &|c, ch| {
            let (b, first_row) = (&batch[c], c * BC);
            let mut nets = TargetPass {
                actor: ta,
                critic: tc,
                cfg,
                buf: &mut ch.passes,
            };
            if !cfg.shared_samples {
                ch.estep.sample(&mut nets, &b.obs[0], seed, first_row);
            }
            let shared = cfg.shared_samples.then_some(&mut ch.estep);
            ch.eval.compute(&mut nets, b, len, seed, first_row, shared);
            let p = &mut ch.passes;
            let act = critic_input(cfg, &b.action[0], &mut ch.critic_action);
            critic.values(&b.obs[0], act, &mut p.ctape, &mut p.q, cfg);
            let e = &mut ch.eval;
            critic.loss(&mut p.ctape, &p.q, &e.target, inv_b, cfg, &mut e.loss);
            critic.backprop(&mut p.ctape, ct, cfg);
            if cfg.action_penalization {
                ch.estep.penalize();
            }
        });
        let (mut loss, mut tsum) = (0f32, 0f32);
        let mut samples = SampleSums::default();
        for ch in &self.chunks {
            ch.eval.add_loss(&mut loss, &mut tsum);
            ch.estep.add_samples(&mut samples);
        }
        let b = Self::B as f32;
        stats.critic_loss = loss / b;
        stats.target_mean = tsum / b;
        stats.q_mean = (samples.q / (Self::B * M) as f64) as f32;
        stats.q_min = samples.q_min;
        stats.q_max = samples.q_max;
        stats.action_excess = (samples.excess / (Self::B * M) as f64) as f32;
        if !stats.critic_loss.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::CriticLoss));
        }
        if !samples.q.is_finite() {
            return Err(UpdateError::NonFinite(NonFinite::EStep));
        }
        Ok(())
    }

    /// The critic's weight gradients (by parameter blocks), clipping and one Adam step.
    // Never inlined: a phase is a function of its own in profiles (docs/core.md).
    #[inline(never)]
    fn critic_step<Par: Parallel>(
        &mut self,
        par: &Par,
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
        let tapes: [&Q::Tape<BC>; C] = core::array::from_fn(|c| &chunks[c].passes.ctape);
        let inputs = ValueGradInputs {
            obs: &obs,
            act: &act,
            tapes: &tapes,
        };
        let sq = Q::weight_grads(&mut self.grads.critic, par, &inputs, &self.cfg);
        let norm = libm::sqrt(sq) as f32;
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
        if self.cfg.weight_norm {
            l.critic.project_weights();
        }
        Ok(())
    }

    /// Temperatures, weights and the per-state sample statistics of the M-step.
    // Never inlined: a phase is a function of its own in profiles (docs/core.md).
    #[inline(never)]
    fn e_step<Par: Parallel>(
        &mut self,
        par: &Par,
        stats: &mut UpdateStats,
    ) -> Result<(), UpdateError> {
        let cfg = self.cfg;
        let sol = solve_temperature_with(
            cfg.eps_eta,
            self.live.duals.eta,
            cfg.estep_tol,
            cfg.estep_max_iter,
            &mut |eta| self.dual_sums(par, eta, false),
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
                &mut |eta| self.dual_sums(par, eta, true),
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
        par.for_each(&mut self.chunks, &|_, ch| ch.estep.weigh(sol.eta, eta_pen));
        let mut kl = 0f64;
        for ch in &self.chunks {
            for n in 0..BC {
                kl += ch.estep.kl[n] as f64;
            }
        }
        stats.estep_kl = (kl / Self::B as f64) as f32;
        Ok(())
    }

    /// One M-step iteration: the actor's gradient (rows, then parameter blocks), clipping,
    /// one Adam step, then one step of the multipliers.
    // Never inlined: a phase is a function of its own in profiles (docs/core.md).
    #[inline(never)]
    fn m_step<Par: Parallel>(
        &mut self,
        par: &Par,
        stats: &mut UpdateStats,
    ) -> Result<(), UpdateError> {
        let cfg = self.cfg;
        self.live.actor.transpose_into(&mut self.grads.at);
        let (actor, at, batch) = (&self.live.actor, &self.grads.at, &self.batch);
        let scale = LossScale::new(&self.live.duals, Self::B);
        par.for_each(&mut self.chunks, &|c, ch| {
            let states = if cfg.shared_samples {
                &batch[c].next_obs[0]
            } else {
                &batch[c].obs[0]
            };
            let (p, e, m) = (&mut ch.passes, &ch.estep, &mut ch.mstep);
            actor.forward(states, &mut p.atape, &mut p.mean, &mut p.chol);
            m.gradients(&e.old, &e.stats, &p.mean, &p.chol, &scale, cfg.std_floor);
            actor.squash().backward_rows(&p.mean, &mut m.d_mean);
            actor.backprop(&mut p.atape, &m.d_mean, &m.d_chol, at);
        });
        let mut sums = TermSums::default();
        for ch in &self.chunks {
            ch.mstep.add_terms(scale.inv_b, &mut sums);
        }
        let norm = self.actor_gradient(par);
        let (km_tot, kc_tot): (f32, f32) = (sums.kl_mean.iter().sum(), sums.kl_cov.iter().sum());
        let nll = sums.nll;
        if !(norm.is_finite() && nll.is_finite() && km_tot.is_finite() && kc_tot.is_finite()) {
            return Err(UpdateError::NonFinite(NonFinite::ActorGradients));
        }
        let clip = clip_scale(norm, cfg.actor_clip);
        let l = &mut self.live;
        adam_step_with(
            par,
            &AdamConfig::with_lr(cfg.actor_lr),
            &mut l.actor_opt,
            &mut l.actor,
            &self.grads.actor,
            clip,
            &mut l.actor_m,
            &mut l.actor_v,
        );
        if cfg.weight_norm {
            l.actor.project_weights();
        }
        update_multipliers(&mut l.duals, &cfg, &sums.kl_mean, &sums.kl_cov);

        let bd = (Self::B * ACT) as f32;
        stats.kl_mean = km_tot;
        stats.kl_cov = kc_tot;
        stats.kl_mean_rel = km_tot / cfg.eps_mean;
        stats.kl_cov_rel = kc_tot / cfg.eps_cov;
        stats.policy_nll = nll;
        stats.actor_grad_norm = norm;
        stats.mu_mean = sums.mu / bd;
        stats.mu_abs_mean = sums.mu_abs / bd;
        stats.std_mean = sums.std / bd;
        stats.std_min = sums.std_min;
        stats.std_max = sums.std_max;
        Ok(())
    }

    /// The actor's weight gradients by parameter blocks from the chunks' tapes; returns the
    /// global norm (before clipping).
    // Never inlined: a phase is a function of its own in profiles (docs/core.md).
    #[inline(never)]
    fn actor_gradient<Par: Parallel>(&mut self, par: &Par) -> f32 {
        let (chunks, batch, shared) = (&self.chunks, &self.batch, self.cfg.shared_samples);
        let obs: [&[[f32; OBS]]; C] = core::array::from_fn(|c| {
            if shared {
                &batch[c].next_obs[0][..]
            } else {
                &batch[c].obs[0][..]
            }
        });
        let tapes: [&P::Tape<BC>; C] = core::array::from_fn(|c| &chunks[c].passes.atape);
        let d_mean: [&[[f32; ACT]]; C] = core::array::from_fn(|c| &chunks[c].mstep.d_mean[..]);
        let d_chol: [&[[f32; TRI]]; C] = core::array::from_fn(|c| &chunks[c].mstep.d_chol[..]);
        let inputs = PolicyGradInputs {
            obs: &obs,
            tapes: &tapes,
            d_mean: &d_mean,
            d_chol: &d_chol,
        };
        libm::sqrt(P::weight_grads(&mut self.grads.actor, par, &inputs)) as f32
    }

    /// The summed dual terms of every chunk at `eta` (of the penalty objective when
    /// `penalty`), computed by `par` and added in batch order.
    // Never inlined: a phase is a function of its own in profiles (docs/core.md).
    #[inline(never)]
    fn dual_sums<Par: Parallel>(&mut self, par: &Par, eta: f64, penalty: bool) -> DualSums {
        par.for_each(&mut self.chunks, &|_, ch| ch.estep.dual_rows(eta, penalty));
        let mut s = DualSums::default();
        for ch in &self.chunks {
            ch.estep.add_dual(&mut s);
        }
        s
    }
}
