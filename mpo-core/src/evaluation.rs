//! Policy evaluation targets: n-step returns and Retrace (paper eq. 11).
//!
//! The learner's default is the report's TD(0) with an expectation over next actions from
//! the target policy: `y = r + bootstrap * mean_j Q'(s', a'_j)`, where `bootstrap` is the
//! multiplier of the next-state value (`gamma` times the environment's discount, 0 at a true
//! terminal). An n-step transition has the same form with the summed discounted reward and
//! `bootstrap = gamma^n prod(discounts)`, which [`nstep`] computes; a time-limit truncation
//! keeps its discount of 1, so it still bootstraps.

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
