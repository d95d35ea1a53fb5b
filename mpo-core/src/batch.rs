//! The batch one learner update learns from: `C` chunks of `BC` rows, each row up to `L`
//! consecutive transitions. [`crate::replay`] fills it, [`crate::evaluation`] builds the
//! critic's targets from it, and the E- and M-steps read its states.

use bytemuck::Zeroable;

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
    /// Whether every value of the first `len` positions is finite.
    pub fn all_finite(&self, len: usize) -> bool {
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
