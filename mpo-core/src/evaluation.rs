//! Policy evaluation targets: n-step returns and Retrace (paper eq. 11).
//!
//! The learner's default is the report's TD(0) with an expectation over next actions from
//! the target policy: `y = r + bootstrap * mean_j Q'(s', a'_j)`, where `bootstrap` is the
//! multiplier of the next-state value (`gamma` times the environment's discount, 0 at a true
//! terminal). An n-step transition has the same form with the summed discounted reward and
//! `bootstrap = gamma^n prod(discounts)`, which [`nstep`] computes; a time-limit truncation
//! keeps its discount of 1, so it still bootstraps.

use bytemuck::Zeroable;

use crate::batch::BatchChunk;
use crate::estep::EStepRows;
use crate::gaussian::Gaussian;
use crate::nets::TargetNets;
use crate::rng::{Rng, stream};

/// Folds `rewards[k]`, `discounts[k]` (environment discount after step `k`: 0 at a terminal,
/// 1 otherwise) of `n` consecutive steps into `(sum_k gamma^k prod_{i<k} d_i r_k,
/// gamma^n prod_k d_k)`: the reward and bootstrap multiplier of one n-step transition.
pub fn nstep(rewards: &[f32], discounts: &[f32], gamma: f32) -> (f32, f32) {
    assert_eq!(rewards.len(), discounts.len(), "nstep: lengths differ");
    let mut ret = 0.0;
    let mut mult = 1.0;
    for (r, d) in rewards.iter().zip(discounts) {
        ret += mult * r;
        mult *= gamma * d;
    }
    (ret, mult)
}

/// Retrace targets for every position of one sequence of `L` transitions (paper eq. 11,
/// with the discount on the next-state value written out):
///
/// `Q_ret(j) = r_j + gamma d_j (V(s_{j+1}) + c_{j+1} (Q_ret(j+1) - Q(s_{j+1}, a_{j+1})))`,
/// `c_k = min(1, pi(a_k | s_k) / b(a_k | s_k))`, and past the last transition only `V` is used.
///
/// - `q[j] = Q_target(s_j, a_j)` for the actions taken;
/// - `v_next[j] = E_{a ~ pi}[Q_target(s_{j+1}, a)]`;
/// - `log_ratio[j] = ln pi(a_j | s_j) - ln b(a_j | s_j)` (behaviour log-probabilities are
///   stored in the replay);
/// - `discount[j]`: environment discount after step `j` (0 at a terminal).
pub fn retrace(
    q: &[f32],
    v_next: &[f32],
    reward: &[f32],
    discount: &[f32],
    log_ratio: &[f32],
    gamma: f32,
    out: &mut [f32],
) {
    let l = q.len();
    assert!(
        v_next.len() == l && reward.len() == l && discount.len() == l && log_ratio.len() == l,
        "retrace: lengths differ"
    );
    assert_eq!(out.len(), l, "retrace: output length differs");
    let mut next: Option<(f32, f32, f32)> = None; // (Q_ret(j+1), Q(j+1), c_{j+1})
    for j in (0..l).rev() {
        let tail = match next {
            Some((ret1, q1, c1)) => v_next[j] + c1 * (ret1 - q1),
            None => v_next[j],
        };
        out[j] = reward[j] + gamma * discount[j] * tail;
        let c = libm::expf(log_ratio[j].min(0.0));
        next = Some((out[j], q[j], c));
    }
}

/// Policy evaluation on one batch chunk of `BC` rows: each row's target `y` from the target
/// networks, with what Retrace reads along the row's sequence.
#[derive(Zeroable)]
pub(crate) struct TargetRows<const ACT: usize, const BC: usize, const L: usize, const N: usize> {
    /// The target policy at the current position's next states (Retrace reuses it at the
    /// next position, where they are the states).
    next_pi: [Gaussian<ACT>; BC],
    /// Next-action sample `j` of row `n` at `[j][n]`.
    next_samples: [[[f32; ACT]; BC]; N],
    /// `Q'(s_k, a_k)` of the actions taken (positions `1..len`).
    q: [[f32; BC]; L],
    /// `mean_j Q'(s_{k+1}, a'_j)`.
    v_next: [[f32; BC]; L],
    /// `ln pi(a_k | s_k) - ln b(a_k | s_k)` (positions `1..len`).
    log_ratio: [[f32; BC]; L],
    /// The target `y` of each row (Retrace's at position 0).
    pub target: [f32; BC],
    /// The critic's loss on each row (from `ValueNet::loss`).
    pub loss: [f32; BC],
}

impl<const ACT: usize, const BC: usize, const L: usize, const N: usize> TargetRows<ACT, BC, L, N> {
    /// The rows' targets: Retrace over their first `len` transitions (TD(0) expected SARSA
    /// when `len` is 1), `N` target-policy actions per next state, row `n` drawing position
    /// `k`'s from its own stream keyed by `seed` and its batch row `first_row + n`. Position
    /// `k` needs the target policy and the critic's observation part at `s_{k+1}`; position
    /// `k + 1` reuses both (its state is `s_{k+1}`) for its action's value and importance
    /// weight. With `shared` (Acme's shared samples, where `len` is 1) the samples, their
    /// values and the target policy at the next states become the E-step's.
    pub fn compute<const OBS: usize, const M: usize>(
        &mut self,
        nets: &mut impl TargetNets<OBS, ACT, BC>,
        b: &BatchChunk<BC, L, OBS, ACT>,
        len: usize,
        seed: u64,
        first_row: usize,
        mut shared: Option<&mut EStepRows<ACT, BC, M>>,
    ) {
        for k in 0..len {
            if k > 0 {
                // s_k is the previous position's next state: the target policy there is
                // still in `next_pi`, the critic's observation part in `nets`.
                let q = nets.values(&b.action[k]);
                for n in 0..BC {
                    self.q[k][n] = q[n];
                    self.log_ratio[k][n] =
                        self.next_pi[n].log_prob(&b.action[k][n]) - b.behaviour_log_prob[k][n];
                }
            }
            nets.policy_at(&b.next_obs[k], &mut self.next_pi);
            for n in 0..BC {
                let mut z = [[0f32; ACT]; N];
                Rng::for_stream(
                    seed,
                    stream::NEXT_ACTIONS + k as u32,
                    (first_row + n) as u32,
                )
                .fill_normal(z.as_flattened_mut());
                for j in 0..N {
                    self.next_pi[n].transform(&z[j], &mut self.next_samples[j][n]);
                }
            }
            let mut v = [0f32; BC];
            for j in 0..N {
                let q = nets.values(&self.next_samples[j]);
                for n in 0..BC {
                    v[n] += q[n];
                }
                if let Some(e) = shared.as_deref_mut().filter(|_| j < M) {
                    for n in 0..BC {
                        e.q[n][j] = q[n];
                        e.samples[j][n] = self.next_samples[j][n];
                    }
                }
            }
            for n in 0..BC {
                self.v_next[k][n] = v[n] / N as f32;
            }
        }
        if let Some(e) = shared {
            e.old = self.next_pi;
        }
        self.retrace_rows(b, len);
    }

    /// Each row's Retrace target at position 0 from the values gathered along its sequence.
    fn retrace_rows<const OBS: usize>(&mut self, b: &BatchChunk<BC, L, OBS, ACT>, len: usize) {
        let (mut q, mut v, mut r, mut d, mut lr, mut out) = (
            [0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L], [0f32; L],
        );
        for n in 0..BC {
            for k in 0..len {
                q[k] = self.q[k][n];
                v[k] = self.v_next[k][n];
                r[k] = b.reward[k][n];
                d[k] = b.bootstrap[k][n];
                lr[k] = self.log_ratio[k][n];
            }
            // The bootstrap multipliers already hold gamma times the discounts.
            retrace(
                &q[..len],
                &v[..len],
                &r[..len],
                &d[..len],
                &lr[..len],
                1.0,
                &mut out[..len],
            );
            self.target[n] = out[0];
        }
    }

    /// Adds the rows' losses to `loss` and their targets to `targets`, in row order.
    pub fn add_loss(&self, loss: &mut f32, targets: &mut f32) {
        for n in 0..BC {
            *loss += self.loss[n];
            *targets += self.target[n];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nstep_folds_rewards_and_stops_at_terminals() {
        let (r, m) = nstep(&[1.0, 2.0, 3.0], &[1.0, 1.0, 1.0], 0.5);
        assert_eq!((r, m), (1.0 + 0.5 * 2.0 + 0.25 * 3.0, 0.125));
        let (r, m) = nstep(&[1.0, 2.0, 3.0], &[1.0, 0.0, 1.0], 0.5);
        // After the terminal at step 1, nothing more counts and nothing bootstraps.
        assert_eq!((r, m), (2.0, 0.0));
    }
}
