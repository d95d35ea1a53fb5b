//! The non-parametric E-step: the temperature `eta*` from the convex dual, then the sample
//! weights `q_ij = softmax_j(Q_ij / eta*)` (paper eq. 7-8; derived in `docs/algorithm.md`,
//! "E-step").
//!
//! With `M` actions sampled per state from the old policy, the sample-based dual is
//! `g(eta) = eta eps + eta mean_i log mean_j exp(Q_ij / eta)`, evaluated per state with a
//! log-sum-exp around the state's largest `Q`. Its derivative is `g'(eta) = eps - KL(eta)`,
//! where `KL(eta)` is the mean over states of `KL(q_i || uniform)` for the weights at that
//! temperature, and `g''(eta) = mean_i Var_q(Q_i / eta) / eta >= 0`. So `eta*` is where the
//! weights' KL to the sampling distribution equals `eps` (when the constraint binds), found
//! by a safeguarded Newton iteration on `ln eta` inside a bracket: deterministic, a fixed
//! worst-case cost, and warm-started from the previous temperature. All arithmetic in f64, so
//! `Q` of any scale or offset gives the same weights.
//!
//! Shapes: `q` is `[B][M]` (state-major), `weights` the same.

use bytemuck::Zeroable;

use crate::gaussian::{Gaussian, SampleStats};
use crate::nets::TargetNets;
use crate::rng::{Rng, stream};

/// Lower clamp of the temperature (as in Acme, about `exp(-18)`).
pub const ETA_MIN: f64 = 1e-8;
/// Upper clamp of the temperature.
pub const ETA_MAX: f64 = 1e12;

/// Result of the temperature solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EStepSolution {
    /// The temperature `eta*`.
    pub eta: f32,
    /// `g(eta*)`.
    pub dual: f64,
    /// Mean over states of `KL(q_i || uniform)` at `eta*` (equals `eps` when binding).
    pub kl: f64,
    /// Newton/bisection iterations used.
    pub iterations: u32,
    /// Whether `|KL - eps| <= tol * eps` was reached (false when the constraint cannot bind,
    /// e.g. every state's `Q` values are equal, and `eta` sits at a clamp).
    pub converged: bool,
}

/// One state's share of the dual at a temperature (see [`dual_row`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Zeroable)]
pub struct DualRow {
    /// `log mean_j exp(Q_j / eta)`.
    pub lse: f64,
    /// `KL(q || uniform)` of the state's weights at `eta`.
    pub kl: f64,
    /// Variance of `Q / eta` under the weights (the curvature term).
    pub var: f64,
}

/// Sums of [`DualRow`]s over the batch, added in state order.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DualSums {
    /// Sum of `lse`.
    pub lse: f64,
    /// Sum of `kl`.
    pub kl: f64,
    /// Sum of `var`.
    pub var: f64,
    /// Number of states.
    pub rows: usize,
}

impl DualSums {
    /// Adds one state's terms.
    pub fn add(&mut self, r: &DualRow) {
        self.lse += r.lse;
        self.kl += r.kl;
        self.var += r.var;
        self.rows += 1;
    }
}

/// One state's terms of the dual at `eta`, with a log-sum-exp around the state's largest `Q`.
pub fn dual_row<const M: usize>(row: &[f32; M], eta: f64) -> DualRow {
    let mut mx = f64::NEG_INFINITY;
    for &v in row {
        mx = mx.max(v as f64);
    }
    // z_j = (Q_j - max) / eta <= 0; s = sum exp(z); E[z], E[z^2] under softmax weights.
    let mut s = 0.0;
    let mut ez = 0.0;
    let mut ez2 = 0.0;
    for &v in row {
        let z = (v as f64 - mx) / eta;
        let e = libm::exp(z);
        s += e;
        ez += e * z;
        ez2 += e * z * z;
    }
    ez /= s;
    ez2 /= s;
    let log_mean = libm::log(s) - libm::log(M as f64);
    DualRow {
        // log mean_j exp(Q_j / eta) = max / eta + log_mean.
        lse: mx / eta + log_mean,
        // KL(w || uniform) = E_w[z] - log mean exp(z).
        kl: ez - log_mean,
        var: (ez2 - ez * ez).max(0.0),
    }
}

/// Dual value, derivative in `ln eta` and second derivative in `ln eta` from the summed rows:
/// `(g(eta), eps - KL(eta), mean Var)`.
fn dual_terms_from(sums: &DualSums, eps: f64, eta: f64) -> (f64, f64, f64) {
    let n = sums.rows as f64;
    (
        eta * eps + eta * sums.lse / n,
        eps - sums.kl / n,
        sums.var / n,
    )
}

fn sum_rows<const M: usize>(q: &[[f32; M]], eta: f64) -> DualSums {
    let mut s = DualSums::default();
    for row in q {
        s.add(&dual_row(row, eta));
    }
    s
}

/// Minimises the dual over `eta` in `[ETA_MIN, ETA_MAX]`, starting from `eta_start`.
///
/// Solves `h(u) = eps - KL(e^u) = 0` (monotone increasing in `u = ln eta`) by Newton steps
/// that are kept inside a bracket and replaced by bisection when they leave it; stops when
/// `|h| <= tol * eps` or the bracket is narrower than 1e-12 in `ln eta`, after at most
/// `max_iter` evaluations (each costs `B M` exponentials).
pub fn solve_temperature<const M: usize>(
    q: &[[f32; M]],
    eps: f32,
    eta_start: f32,
    tol: f64,
    max_iter: u32,
) -> EStepSolution {
    solve_temperature_with(eps, eta_start, tol, max_iter, &mut |eta| sum_rows(q, eta))
}

/// [`solve_temperature`] with the batch's summed [`DualRow`]s at a temperature computed by
/// `eval` (which may spread the states over threads, as long as it adds them in order).
pub fn solve_temperature_with(
    eps: f32,
    eta_start: f32,
    tol: f64,
    max_iter: u32,
    eval: &mut dyn FnMut(f64) -> DualSums,
) -> EStepSolution {
    let eps = eps as f64;
    let mut terms = |eta: f64| dual_terms_from(&eval(eta), eps, eta);
    let (lo_lim, hi_lim) = (libm::log(ETA_MIN), libm::log(ETA_MAX));
    let mut u = libm::log((eta_start as f64).clamp(ETA_MIN, ETA_MAX));
    let (mut lo, mut hi) = (lo_lim, hi_lim);
    let mut it = 0;
    // The result is the last point evaluated (no extra pass over the batch).
    let (u, g, h) = loop {
        let (g, h, dh) = terms(libm::exp(u));
        it += 1;
        if h.abs() <= tol * eps {
            break (u, g, h);
        }
        if h > 0.0 {
            hi = u; // KL below eps: the root is at a smaller temperature
        } else {
            lo = u;
        }
        if it >= max_iter || hi - lo < 1e-12 {
            break (u, g, h);
        }
        let newton = if dh > 0.0 { u - h / dh } else { f64::NAN };
        // Until both ends are known, Newton steps are limited to 4 (a factor e^4 in eta) so a
        // flat dual cannot throw the iterate to a clamp.
        let step_ok = newton.is_finite() && newton > lo && newton < hi && (newton - u).abs() <= 4.0;
        // A walk that reaches a clamp needs no case of its own: if the sign holds there, the
        // next pass sets the clamp as the other end too and the collapsed bracket stops it.
        u = if step_ok {
            newton
        } else if lo == lo_lim && h > 0.0 {
            (u - 4.0).max(lo_lim)
        } else if hi == hi_lim && h < 0.0 {
            (u + 4.0).min(hi_lim)
        } else {
            0.5 * (lo + hi)
        };
    };
    EStepSolution {
        eta: libm::exp(u) as f32,
        dual: g,
        kl: eps - h,
        iterations: it,
        converged: h.abs() <= tol * eps,
    }
}

/// `weights[i][j] = softmax_j(Q_ij / eta)`; returns the mean over states of
/// `KL(weights_i || uniform)`.
pub fn weights<const M: usize>(q: &[[f32; M]], eta: f32, weights: &mut [[f32; M]]) -> f64 {
    assert_eq!(q.len(), weights.len(), "weights: shapes differ");
    let eta = eta as f64;
    let mut kl = 0.0;
    for (row, w) in q.iter().zip(weights.iter_mut()) {
        let mut mx = f64::NEG_INFINITY;
        for &v in row {
            mx = mx.max(v as f64);
        }
        let mut e = [0f64; M];
        let mut s = 0.0;
        for j in 0..M {
            e[j] = libm::exp((row[j] as f64 - mx) / eta);
            s += e[j];
        }
        for j in 0..M {
            let p = e[j] / s;
            w[j] = p as f32;
            if p > 0.0 {
                kl += p * libm::log(p * M as f64);
            }
        }
    }
    kl / q.len() as f64
}

/// `|a - clip(a, -1, 1)|^2`: how far an action lies outside the actuators' range (the
/// objective of action penalization is its negative).
pub fn action_excess<const A: usize>(a: &[f32; A]) -> f32 {
    let mut s = 0.0;
    for &x in a {
        let d = x - x.clamp(-1.0, 1.0);
        s += d * d;
    }
    s
}

/// The E-step on one batch chunk of `BC` states: `M` actions per state from the target
/// policy, their target-critic values, the dual's terms at a temperature, and the weighted
/// samples the M-step fits.
#[derive(Zeroable)]
pub(crate) struct EStepRows<const ACT: usize, const BC: usize, const M: usize> {
    /// The target policy `pi_old` at each state.
    pub old: [Gaussian<ACT>; BC],
    /// Sample `j` of state `n` at `[j][n]` (sample-major: one critic pass per `j`).
    pub samples: [[[f32; ACT]; BC]; M],
    /// `Q'(s_n, a_nj)`, state-major.
    pub q: [[f32; M]; BC],
    /// The penalty objective `-|a_nj - clip(a_nj)|^2` (with action penalization).
    pub q_penalty: [[f32; M]; BC],
    /// Each state's terms of the dual at the temperature last evaluated.
    pub dual: [DualRow; BC],
    /// `KL(q_n || pi_old)` of each state's weights at the solved temperature.
    pub kl: [f32; BC],
    /// Each state's weighted samples, summarised for the M-step.
    pub stats: [SampleStats<ACT>; BC],
}

/// Sums over the E-step's samples of a batch, added in batch order.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SampleSums {
    /// Sum of `Q`.
    pub q: f64,
    /// Smallest `Q`.
    pub q_min: f32,
    /// Largest `Q`.
    pub q_max: f32,
    /// Sum of [`action_excess`].
    pub excess: f64,
}

impl Default for SampleSums {
    fn default() -> Self {
        Self {
            q: 0.0,
            q_min: f32::INFINITY,
            q_max: f32::NEG_INFINITY,
            excess: 0.0,
        }
    }
}

impl<const ACT: usize, const BC: usize, const M: usize> EStepRows<ACT, BC, M> {
    /// The target policy at the states `obs` (kept in `old`), `M` draws per state and their
    /// values. State `n` draws from its own stream, keyed by the update's `seed` and its row
    /// in the batch, `first_row + n`.
    pub fn sample<const OBS: usize>(
        &mut self,
        nets: &mut impl TargetNets<OBS, ACT, BC>,
        obs: &[[f32; OBS]; BC],
        seed: u64,
        first_row: usize,
    ) {
        nets.policy_at(obs, &mut self.old);
        for n in 0..BC {
            let mut z = [[0f32; ACT]; M];
            Rng::for_stream(seed, stream::ESTEP, (first_row + n) as u32)
                .fill_normal(z.as_flattened_mut());
            for j in 0..M {
                self.old[n].transform(&z[j], &mut self.samples[j][n]);
            }
        }
        for j in 0..M {
            let q = nets.values(&self.samples[j]);
            for n in 0..BC {
                self.q[n][j] = q[n];
            }
        }
    }

    /// The penalty objective's values of the samples (action penalization).
    pub fn penalize(&mut self) {
        for n in 0..BC {
            for j in 0..M {
                self.q_penalty[n][j] = -action_excess(&self.samples[j][n]);
            }
        }
    }

    /// Each state's terms of the dual at `eta`, of the penalty objective when `penalty`.
    pub fn dual_rows(&mut self, eta: f64, penalty: bool) {
        for n in 0..BC {
            let row = if penalty {
                &self.q_penalty[n]
            } else {
                &self.q[n]
            };
            self.dual[n] = dual_row(row, eta);
        }
    }

    /// Adds the states' dual terms to `sums`, in state order.
    pub fn add_dual(&self, sums: &mut DualSums) {
        for r in &self.dual {
            sums.add(r);
        }
    }

    /// The weights at the solved temperatures, folded straight into each state's
    /// [`SampleStats`] (the penalty objective's weights join the task's, so both pull on one
    /// weighted likelihood), and each state's `KL(q || pi_old)`.
    pub fn weigh(&mut self, eta: f32, eta_penalty: Option<f32>) {
        for n in 0..BC {
            let mut w = [0f32; M];
            self.kl[n] = weights(
                core::slice::from_ref(&self.q[n]),
                eta,
                core::slice::from_mut(&mut w),
            ) as f32;
            if let Some(eta_p) = eta_penalty {
                let mut wp = [0f32; M];
                weights(
                    core::slice::from_ref(&self.q_penalty[n]),
                    eta_p,
                    core::slice::from_mut(&mut wp),
                );
                for j in 0..M {
                    w[j] += wp[j];
                }
            }
            let mut st = SampleStats::ZERO;
            for j in 0..M {
                st.add(w[j], &self.samples[j][n], &self.old[n].mu);
            }
            self.stats[n] = st;
        }
    }

    /// Adds the chunk's samples to `sums`, states in order, samples in order within each.
    pub fn add_samples(&self, sums: &mut SampleSums) {
        for n in 0..BC {
            for j in 0..M {
                let v = self.q[n][j];
                sums.q += v as f64;
                sums.q_min = sums.q_min.min(v);
                sums.q_max = sums.q_max.max(v);
                sums.excess += action_excess(&self.samples[j][n]) as f64;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_q_values_cannot_bind_and_give_uniform_weights() {
        let q = [[3.0f32; 8]; 4];
        let s = solve_temperature(&q, 0.1, 1.0, 1e-6, 100);
        assert!(!s.converged);
        assert!(s.kl.abs() < 1e-12);
        let mut w = [[0f32; 8]; 4];
        weights(&q, s.eta, &mut w);
        for row in w {
            for x in row {
                assert!((x - 0.125).abs() < 1e-7);
            }
        }
    }
}
