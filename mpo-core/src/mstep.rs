//! The M-step (paper eq. 9-10, with the decoupled constraints derived in `docs/algorithm.md`,
//! "M-step"): fit the parametric policy to the E-step's weighted samples under KL trust
//! regions.
//!
//! Per state, with `pi_old` the target policy, `pi = N(mu, L L^T)` the online one and the
//! weighted samples summarised in [`SampleStats`], the loss is
//!
//! `-(1/B) [sum_j w_j ln N(a_j; mu, Sigma_old) + sum_j w_j ln N(a_j; mu_old, Sigma)]`
//! `+ (1/B) sum_k [alpha_mu,k KL_mu,k + alpha_Sigma,k KL_Sigma,k]`,
//!
//! with `KL_mu = KL(pi_old || N(mu, Sigma_old))` and `KL_Sigma = KL(pi_old || N(mu_old,
//! Sigma))` split by action dimension ([`crate::gaussian::KlPerDim`]). The multipliers are
//! held constant in the policy gradient (a stop-gradient) and trained by [`update_multipliers`]
//! on `alpha (eps - KL)` with the KLs held constant. [`state_gradient`] is one state's share:
//! loss terms, statistics and the gradient with respect to the head's raw outputs.

use bytemuck::Zeroable;

use crate::adam::{AdamConfig, AdamState};
use crate::config::{LOG_ALPHA_MAX, MpoConfig};
use crate::gaussian::{
    Gaussian, GaussianGrad, SampleStats, head_backward, kl_per_dim_grad, weighted_log_prob_cov,
    weighted_log_prob_mean,
};

/// The M-step multipliers (log parameterisation) with their Adam state, and the E-step's
/// temperatures: every dual variable an update carries to the next.
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

/// One state's share of the M-step loss.
#[derive(Clone, Copy, Debug, PartialEq, Zeroable)]
pub struct StateTerms<const A: usize> {
    /// `KL_mu` by dimension.
    pub kl_mean: [f32; A],
    /// `KL_Sigma` by dimension.
    pub kl_cov: [f32; A],
    /// Weighted negative log-likelihood (both halves, times `1/B`).
    pub nll: f32,
    /// The online policy's mean.
    pub mu: [f32; A],
    /// The online policy's standard deviations.
    pub std: [f32; A],
}

/// The loss terms of one state and their gradient with respect to the actor's raw head
/// outputs (`d_mean`, `d_chol`, overwritten). `c_nll` is `1/B`; `c_mean` and `c_cov` are the
/// multipliers times `1/B`.
#[allow(clippy::too_many_arguments)]
pub fn state_gradient<const A: usize, const T: usize>(
    old: &Gaussian<A>,
    mean_raw: &[f32; A],
    chol_raw: &[f32; T],
    stats: &SampleStats<A>,
    c_nll: f32,
    c_mean: &[f32; A],
    c_cov: &[f32; A],
    std_floor: f32,
    d_mean: &mut [f32; A],
    d_chol: &mut [f32; T],
) -> StateTerms<A> {
    let new = Gaussian::from_head(mean_raw, chol_raw, std_floor);
    let mut g = GaussianGrad::ZERO;
    // Stop-gradients: pi_mean's covariance and pi_cov's mean are the old ones.
    let lp_m = weighted_log_prob_mean(old, &new.mu, stats, -c_nll, &mut g);
    let lp_c = weighted_log_prob_cov(&new, stats, -c_nll, &mut g);
    let pi_mean = Gaussian {
        mu: new.mu,
        l: old.l,
    };
    let pi_cov = Gaussian {
        mu: old.mu,
        l: new.l,
    };
    let mut gk = GaussianGrad::ZERO;
    let km = kl_per_dim_grad(old, &pi_mean, c_mean, &[0.0; A], &mut gk);
    for k in 0..A {
        g.mu[k] += gk.mu[k];
    }
    let mut gk = GaussianGrad::ZERO;
    let kc = kl_per_dim_grad(old, &pi_cov, &[0.0; A], c_cov, &mut gk);
    for j in 0..A {
        for k in 0..=j {
            g.l[j][k] += gk.l[j][k];
        }
    }
    head_backward(chol_raw, &g, d_mean, d_chol);
    StateTerms {
        kl_mean: km.mean,
        kl_cov: kc.cov,
        nll: -(lp_m + lp_c) * c_nll,
        mu: new.mu,
        std: new.std_devs(),
    }
}

/// One step of the multipliers on `alpha (eps - KL)` given the batch-mean KLs by dimension.
/// `d/d alpha` is `eps - KL`; through `alpha = exp(raw)` it is scaled by `alpha`. The step is
/// Adam's without momentum (`beta1 = 0`, so RMSProp with bias correction): a multiplier rises
/// exactly while its KL exceeds the bound and falls while it is below, instead of coasting
/// past the constraint on the momentum of earlier batches; the second moment keeps the step
/// a factor of about `e^dual_lr` whatever the scale of the KL.
/// Without per-dimension KL every entry sees the total against the whole bound; with it,
/// dimension `k` sees its own KL against `eps / ACT`. The raw values are clamped to
/// `[-LOG_ALPHA_MAX, cfg.log_alpha_max]`.
pub fn update_multipliers<const A: usize>(
    d: &mut Duals<A>,
    cfg: &MpoConfig,
    kl_mean: &[f32; A],
    kl_cov: &[f32; A],
) {
    let (alpha_mean, alpha_cov) = (d.alpha_mean(), d.alpha_cov());
    let (km_tot, kc_tot): (f32, f32) = (kl_mean.iter().sum(), kl_cov.iter().sum());
    let mut g_mean = [0f32; A];
    let mut g_cov = [0f32; A];
    for k in 0..A {
        let (dm, dc) = if cfg.per_dim_kl {
            (
                cfg.eps_mean / A as f32 - kl_mean[k],
                cfg.eps_cov / A as f32 - kl_cov[k],
            )
        } else {
            (cfg.eps_mean - km_tot, cfg.eps_cov - kc_tot)
        };
        g_mean[k] = dm * alpha_mean[k];
        g_cov[k] = dc * alpha_cov[k];
    }
    let dcfg = AdamConfig {
        beta1: 0.0,
        ..AdamConfig::with_lr(cfg.dual_lr)
    };
    d.opt.advance(&dcfg);
    let [m0, v0, m1, v1] = &mut d.moments;
    d.opt.apply(&dcfg, &mut d.alpha_mean_raw, &g_mean, m0, v0);
    d.opt.apply(&dcfg, &mut d.alpha_cov_raw, &g_cov, m1, v1);
    for r in d
        .alpha_mean_raw
        .iter_mut()
        .chain(d.alpha_cov_raw.iter_mut())
    {
        *r = r.clamp(-LOG_ALPHA_MAX, cfg.log_alpha_max);
    }
}

/// The M-step on one batch chunk of `BC` states: each state's loss terms and the gradient
/// with respect to the online actor's raw head outputs.
#[derive(Zeroable)]
pub(crate) struct MStepRows<const ACT: usize, const TRI: usize, const BC: usize> {
    /// Gradient at the mean head's outputs (squashed until the actor's `squash_backward`).
    pub d_mean: [[f32; ACT]; BC],
    /// Gradient at the Cholesky head's raw outputs.
    pub d_chol: [[f32; TRI]; BC],
    /// Each state's loss terms.
    pub terms: [StateTerms<ACT>; BC],
}

/// The per-state factors of the M-step loss in one update: `1/B` and the multipliers over
/// `B`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LossScale<const ACT: usize> {
    /// `1/B`.
    pub inv_b: f32,
    /// `alpha_mu / B` per dimension.
    pub mean: [f32; ACT],
    /// `alpha_Sigma / B` per dimension.
    pub cov: [f32; ACT],
}

impl<const ACT: usize> LossScale<ACT> {
    /// The factors for a batch of `b` states under the multipliers `d`.
    pub fn new(d: &Duals<ACT>, b: usize) -> Self {
        let inv_b = 1.0 / b as f32;
        Self {
            inv_b,
            mean: d.alpha_mean().map(|a| a * inv_b),
            cov: d.alpha_cov().map(|a| a * inv_b),
        }
    }
}

/// Sums of [`StateTerms`] over a batch, added in batch order.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TermSums<const ACT: usize> {
    /// Batch-mean `KL_mu` by dimension.
    pub kl_mean: [f32; ACT],
    /// Batch-mean `KL_Sigma` by dimension.
    pub kl_cov: [f32; ACT],
    /// The weighted negative log-likelihood.
    pub nll: f32,
    /// Sum of the means.
    pub mu: f32,
    /// Sum of `|mu|`.
    pub mu_abs: f32,
    /// Sum of the standard deviations.
    pub std: f32,
    /// Smallest standard deviation.
    pub std_min: f32,
    /// Largest standard deviation.
    pub std_max: f32,
}

impl<const ACT: usize> Default for TermSums<ACT> {
    fn default() -> Self {
        Self {
            kl_mean: [0.0; ACT],
            kl_cov: [0.0; ACT],
            nll: 0.0,
            mu: 0.0,
            mu_abs: 0.0,
            std: 0.0,
            std_min: f32::INFINITY,
            std_max: 0.0,
        }
    }
}

impl<const ACT: usize, const TRI: usize, const BC: usize> MStepRows<ACT, TRI, BC> {
    /// Each state's [`state_gradient`] given the online policy's head outputs `mean`, `chol`,
    /// the target policy `old` and the E-step's weighted samples `stats` there.
    pub fn gradients(
        &mut self,
        old: &[Gaussian<ACT>; BC],
        stats: &[SampleStats<ACT>; BC],
        mean: &[[f32; ACT]; BC],
        chol: &[[f32; TRI]; BC],
        scale: &LossScale<ACT>,
        std_floor: f32,
    ) {
        for n in 0..BC {
            self.terms[n] = state_gradient(
                &old[n],
                &mean[n],
                &chol[n],
                &stats[n],
                scale.inv_b,
                &scale.mean,
                &scale.cov,
                std_floor,
                &mut self.d_mean[n],
                &mut self.d_chol[n],
            );
        }
    }

    /// Adds the states' terms to `sums` in state order (KLs scaled by `inv_b`, so the sums are
    /// batch means).
    pub fn add_terms(&self, inv_b: f32, sums: &mut TermSums<ACT>) {
        for t in &self.terms {
            for k in 0..ACT {
                sums.kl_mean[k] += t.kl_mean[k] * inv_b;
                sums.kl_cov[k] += t.kl_cov[k] * inv_b;
                sums.mu += t.mu[k];
                sums.mu_abs += t.mu[k].abs();
                sums.std += t.std[k];
                sums.std_min = sums.std_min.min(t.std[k]);
                sums.std_max = sums.std_max.max(t.std[k]);
            }
            sums.nll += t.nll;
        }
    }
}
