//! The M-step (paper eq. 9-10, with the decoupled constraints of ALGORITHM-NOTES.md item 1):
//! fit the parametric policy to the E-step's weighted samples under KL trust regions.
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

use crate::adam::AdamConfig;
use crate::config::MpoConfig;
use crate::gaussian::{
    Gaussian, GaussianGrad, SampleStats, head_backward, kl_per_dim_grad, weighted_log_prob_cov,
    weighted_log_prob_mean,
};
use crate::learner::Duals;

/// Clamp of `ln alpha` (Acme clamps the duals below at `exp(-18)`).
pub const LOG_ALPHA_MAX: f32 = 18.0;

/// One state's share of the M-step loss.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Zeroable)]
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
/// `[-LOG_ALPHA_MAX, LOG_ALPHA_MAX]`.
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
        *r = r.clamp(-LOG_ALPHA_MAX, LOG_ALPHA_MAX);
    }
}
