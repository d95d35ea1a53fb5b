//! The policy's mean squashed into the actuators' range: `mean = b tanh(raw / b)` (tonic's).
//!
//! The Control Suite clips every action to `[-1, 1]`, so the critic is flat outside the box and
//! the E-step weights a sample out there by the critic's extrapolation alone: the mean can drift
//! outwards. Action penalization (`MpoConfig::action_penalization`) pulls it back through a second
//! E-step; squashing bounds the mean by construction instead (the samples around it still leave
//! the box by their spread, and the penalty, if on, still acts on them). The Gaussian is then
//! over the actions themselves with the squashed mean, so the E-step, the M-step's KLs and the
//! log-probabilities are unchanged; only the mean head's gradient gains the factor
//! `1 - (mean / b)^2`.
//!
//! The bound is part of the policy's parameters ([`MeanSquash`] is a [`Params`] with one tensor,
//! never changed by gradients: its gradient is always zero), so checkpoints, `params_sha256`,
//! the controller's parameter blocks and the firmware's exported source carry it, and a deployed
//! policy squashes exactly as in training. A bound of 0 in a dimension means no squashing there:
//! the initial (zeroed) state is the old, unbounded mean, bit for bit.

use bytemuck::Zeroable;

use crate::mathf::tanh;
use crate::params::Params;

/// Per-action bound of the mean; `0` = unbounded.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct MeanSquash<const ACT: usize> {
    /// `b_k`: the mean of action `k` lies in `(-b_k, b_k)` when `b_k > 0`.
    pub bound: [f32; ACT],
}

impl<const ACT: usize> Params for MeanSquash<ACT> {
    const TENSORS: usize = 1;
    fn tensor(&self, k: usize) -> &[f32] {
        assert!(k == 0, "MeanSquash has 1 tensor");
        &self.bound
    }
    fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
        assert!(k == 0, "MeanSquash has 1 tensor");
        &mut self.bound
    }
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
        f(&mut self.bound);
    }
}

impl<const ACT: usize> MeanSquash<ACT> {
    /// Every dimension bounded by `bound` (`0` = off, the identity).
    pub fn init(&mut self, bound: f32) {
        self.bound.fill(bound);
    }

    /// Squashes one raw mean in place. Bounds that are not `> 0` (0, or a NaN read from
    /// outside) leave their dimension unchanged.
    #[inline]
    pub fn apply(&self, mean: &mut [f32; ACT]) {
        for (m, &b) in mean.iter_mut().zip(&self.bound) {
            if b > 0.0 {
                *m = b * tanh(*m / b);
            }
        }
    }

    /// Squashes rows in place (a batch's raw head outputs).
    pub fn apply_rows(&self, rows: &mut [[f32; ACT]]) {
        for r in rows.iter_mut() {
            self.apply(r);
        }
    }

    /// Turns gradients at the squashed means `mean` into gradients at the raw head outputs:
    /// `d raw = d mean (1 - (mean / b)^2)`, since `d/dx b tanh(x / b) = 1 - tanh^2(x / b)`.
    pub fn backward_rows(&self, mean: &[[f32; ACT]], d_mean: &mut [[f32; ACT]]) {
        for (m, d) in mean.iter().zip(d_mean.iter_mut()) {
            for ((d, &m), &b) in d.iter_mut().zip(m).zip(&self.bound) {
                if b > 0.0 {
                    let t = m / b;
                    *d *= 1.0 - t * t;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_bounds_are_the_identity_and_positive_ones_bound() {
        let mut s = MeanSquash::<3>::zeroed();
        assert_eq!(s.bound, [0.0; 3]);
        let raw = [1e6f32, -0.0, f32::NAN];
        let mut m = raw;
        s.apply(&mut m);
        assert_eq!(m[..2], raw[..2]);
        assert!(m[2].is_nan());
        let mut d = [[2.0f32; 3]];
        s.backward_rows(&[raw], &mut d);
        assert_eq!(d, [[2.0; 3]]);

        // Bounded in 0 and 1, a NaN bound (read from outside) leaves its dimension alone.
        s.bound = [1.0, 0.5, f32::NAN];
        let mut m = [3.0f32, -0.25, 7.0];
        s.apply(&mut m);
        assert_eq!(m[0], tanh(3.0));
        assert_eq!(m[1], 0.5 * tanh(-0.5));
        assert_eq!(m[2], 7.0);
        let mut d = [[1.0f32; 3]];
        s.backward_rows(&[m], &mut d);
        let t = tanh(3.0);
        assert_eq!(d[0][0], 1.0 - t * t);
        assert_eq!(d[0][2], 1.0);
    }
}
