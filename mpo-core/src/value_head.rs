//! The critic's output: one value regressed on its target, or a categorical distribution over
//! a fixed support trained by cross-entropy (DMPO's and SimbaV2's critics).
//!
//! A critic with `K` outputs is scalar when `K = 1`: `Q` is the output and the loss
//! `0.5 (Q - y)^2`. With `K > 1` the outputs are logits over the atoms
//! `z_k = value_min + k (value_max - value_min) / (K - 1)`, `p = softmax(logits)`, and
//! `Q = sum_k p_k z_k`: the E-step, the policy-evaluation targets and the statistics all read
//! this expectation, so MPO's algebra is unchanged. The target `y` (TD or Retrace, from the
//! target critic's expectations) is turned into a distribution `t` over the atoms
//! ([`project`]): two-hot (the two atoms around `y`, weighted so that `sum t_k z_k = y`) or
//! HL-Gauss (Farebrother et al., 2024: the mass of `N(y, sigma^2)` on each atom's bin,
//! renormalised over the support), and the loss is `-sum_k t_k ln p_k`, whose gradient at the
//! logits is `p - t`. `y` outside the support is clamped into it.
//!
//! The softmax uses [`crate::mathf::exp`] and eight-lane sums (`crate::lanes::sum8`), so it
//! vectorises and has the same bits on every build; the projection's `erf` and the loss's one
//! logarithm per row are `libm`'s (portable software; they run once per batch row, not per
//! sample).

use crate::config::MpoConfig;
use crate::lanes::{dot8, max8, sum8};
use crate::linear::mul_add;
use crate::mathf::exp;

/// The support and target form of a categorical head (read from [`MpoConfig`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Support {
    /// The smallest atom.
    pub min: f32,
    /// The largest atom.
    pub max: f32,
    /// HL-Gauss's standard deviation in units of the atoms' spacing; 0 = two-hot.
    pub sigma: f32,
    /// Atoms more than this below the largest logit get probability 0; 0 = off.
    pub floor: f32,
}

impl Support {
    /// The configuration's support.
    pub fn of(cfg: &MpoConfig) -> Self {
        Self {
            min: cfg.value_min,
            max: cfg.value_max,
            sigma: cfg.value_sigma,
            floor: cfg.logit_floor,
        }
    }

    /// The spacing of `K` atoms.
    pub fn spacing<const K: usize>(&self) -> f32 {
        (self.max - self.min) / (K - 1) as f32
    }

    /// The `K` atoms, `min + k spacing`.
    pub fn atoms<const K: usize>(&self) -> [f32; K] {
        let dz = self.spacing::<K>();
        core::array::from_fn(|k| mul_add(k as f32, dz, self.min))
    }
}

/// `p = softmax(logits)` (around the largest logit); returns `ln sum_k exp(logits_k)` over
/// the atoms kept.
///
/// Atoms whose logit lies more than `floor` below the largest get exactly 0 (`floor` 0: none
/// do). Their true probability is below `e^-floor` of the largest one's; left in, it and the
/// gradients made from it fall into f32's subnormal range once a critic's values sit near an
/// end of the support (Adam keeps pushing the far atoms' logits down), and x86 cores compute
/// on subnormal operands in microcode: `cargo bench --bench kernels -- value` measured the
/// output layer's backward 42x slower on such logits (docs/core.md). A fixed floor gives the
/// same bits on every target, unlike the processor's flush-to-zero mode. It does change the
/// bits of a long run (measured in docs/core.md), so it is a setting
/// (`MpoConfig::logit_floor`), off for runs made before it.
pub fn softmax<const K: usize>(logits: &[f32; K], p: &mut [f32; K], floor: f32) -> f32 {
    // The largest logit in eight lanes; a zero maximum's sign, the one thing the order could
    // change, changes no output (every `logits_k - m` and `m + ln s` is the same number).
    softmax_around(logits, max8(logits), p, floor)
}

/// [`softmax`] around the given largest logit `m`.
fn softmax_around<const K: usize>(logits: &[f32; K], m: f32, p: &mut [f32; K], floor: f32) -> f32 {
    // No finite difference lies below -inf: with the floor off every atom takes `exp`.
    let cut = if floor > 0.0 {
        -floor
    } else {
        f32::NEG_INFINITY
    };
    for k in 0..K {
        let d = logits[k] - m;
        p[k] = if d < cut { 0.0 } else { exp(d) };
    }
    let s = sum8(p);
    for x in p.iter_mut() {
        *x /= s;
    }
    m + libm::logf(s)
}

/// The values of a batch of outputs `out`: the output itself (`K = 1`), or the expectation over
/// the atoms of the softmax, which is kept in `probs` for the loss.
pub fn values<const K: usize>(
    support: &Support,
    out: &[[f32; K]],
    probs: &mut [[f32; K]],
    q: &mut [f32],
) {
    if K == 1 {
        for (q, o) in q.iter_mut().zip(out) {
            *q = o[0];
        }
        return;
    }
    let z = support.atoms::<K>();
    for ((o, p), q) in out.iter().zip(probs.iter_mut()).zip(q.iter_mut()) {
        softmax(o, p, support.floor);
        *q = dot8(p, &z);
    }
}

/// The distribution over the atoms that stands for the target `y` (module doc): two-hot when
/// `support.sigma` is 0, else HL-Gauss with standard deviation `sigma` atom spacings.
pub fn project<const K: usize>(support: &Support, y: f32, t: &mut [f32; K]) {
    let y = y.clamp(support.min, support.max);
    let dz = support.spacing::<K>();
    t.fill(0.0);
    if support.sigma > 0.0 {
        // Bin k is [z_k - dz/2, z_k + dz/2]; its edges in units of sigma sqrt(2) from y.
        let scale = 1.0 / (support.sigma * dz * core::f32::consts::SQRT_2);
        let edge = |k: usize| libm::erff((support.min + (k as f32 - 0.5) * dz - y) * scale);
        let (lo, hi) = (edge(0), edge(K));
        let mut prev = lo;
        for k in 0..K {
            let next = edge(k + 1);
            t[k] = (next - prev) / (hi - lo);
            prev = next;
        }
        return;
    }
    let pos = (y - support.min) / dz;
    let i = (libm::floorf(pos) as usize).min(K - 2);
    let frac = pos - i as f32;
    t[i] = 1.0 - frac;
    t[i + 1] = frac;
}

/// Each row's loss against its target `y[n]` and the loss's gradient at the outputs, times
/// `inv_b` (the batch mean's factor), into `d_out`. `K = 1`: `0.5 (q - y)^2`, gradient
/// `q - y`. `K > 1`: cross-entropy to [`project`]`(y)`, gradient `p - t` (`probs` and `q` as
/// [`values`] left them).
// Every argument is a caller-owned buffer: nothing is allocated here.
#[allow(clippy::too_many_arguments)]
pub fn loss<const K: usize>(
    support: &Support,
    out: &[[f32; K]],
    probs: &[[f32; K]],
    q: &[f32],
    y: &[f32],
    inv_b: f32,
    d_out: &mut [[f32; K]],
    loss: &mut [f32],
) {
    for n in 0..y.len() {
        if K == 1 {
            let err = q[n] - y[n];
            d_out[n][0] = err * inv_b;
            loss[n] = 0.5 * err * err;
            continue;
        }
        let mut t = [0f32; K];
        project(support, y[n], &mut t);
        let mut scratch = [0f32; K];
        let lse = softmax(&out[n], &mut scratch, support.floor);
        let mut ce = 0f32;
        for k in 0..K {
            ce = mul_add(t[k], lse - out[n][k], ce);
            d_out[n][k] = (probs[n][k] - t[k]) * inv_b;
        }
        loss[n] = ce;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `softmax` with the running maximum in index order (the form before [`max8`]).
    fn softmax_in_order<const K: usize>(logits: &[f32; K], p: &mut [f32; K], floor: f32) -> f32 {
        let mut m = logits[0];
        for &l in &logits[1..] {
            if l > m {
                m = l;
            }
        }
        softmax_around(logits, m, p, floor)
    }

    #[test]
    fn softmax_matches_the_in_order_maximum_bit_for_bit_with_zero_maxima_of_either_sign() {
        const K: usize = 21;
        let mut checked = 0;
        for case in 0..200u32 {
            // Logits at or below zero, the largest a zero of one sign or both, anywhere.
            let mut logits: [f32; K] =
                core::array::from_fn(|k| -(((case * 3 + k as u32 * 13) % 7) as f32) * 0.75);
            for k in 0..K {
                if logits[k] == 0.0 && (case + k as u32) % 2 == 1 {
                    logits[k] = -0.0;
                }
            }
            let zeros = logits.iter().filter(|l| **l == 0.0).count();
            let negative_zero = logits.iter().any(|l| *l == 0.0 && l.is_sign_negative());
            for floor in [0.0, 10.0] {
                let (mut p, mut q) = ([0f32; K], [0f32; K]);
                let a = softmax(&logits, &mut p, floor);
                let b = softmax_in_order(&logits, &mut q, floor);
                assert_eq!(a.to_bits(), b.to_bits(), "log-sum-exp, case {case}");
                for k in 0..K {
                    assert_eq!(p[k].to_bits(), q[k].to_bits(), "p[{k}], case {case}");
                }
            }
            checked += usize::from(zeros > 1 && negative_zero);
        }
        assert!(
            checked > 20,
            "too few cases with tied zero maxima of both signs ({checked})"
        );
    }
}
