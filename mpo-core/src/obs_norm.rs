//! Observation normalisation: the policy's input layer `x -> clip((x - shift) * scale)`.
//!
//! The Control Suite's observations mix unit-scale quantities (orientations as cosines and
//! sines, heights) with joint velocities of tens of radians per second. Fed raw, the velocities
//! dominate the first layer, and an Adam step of a given size moves those units far more than
//! the others. tonic's MPO normalises every observation with running statistics; this module
//! does the same with a fixed-size, deterministic state.
//!
//! The normaliser is part of the policy's parameters ([`InputNorm`] is a [`Params`] with three
//! tensors, never changed by gradients), so everything that moves a policy — checkpoints,
//! `params_sha256`, the controller's parameter blocks, the firmware's exported source —
//! carries it, and a deployed policy normalises exactly as in training. The statistics are
//! refit from the replay's observations (mean and standard deviation in f64, summed in slot
//! order: the same bits on every build and device) by [`InputNorm::fit`]; the learner's
//! batches are normalised once, before an update ([`InputNorm::apply_rows`]), and
//! single-state inference normalises its input ([`InputNorm::apply`]).
//!
//! The initial state is the identity (shift 0, scale 1, limit `f32::MAX`), which maps every
//! finite observation to itself bit for bit: with normalisation off, the policy computes
//! exactly what it did before this module existed.

use bytemuck::Zeroable;

use crate::params::Params;

/// Normalised inputs are clipped to `[-CLIP, CLIP]` (tonic's bound): a state far outside what
/// the replay has seen cannot saturate the first layer.
pub const CLIP: f32 = 5.0;

/// Smallest standard deviation divided by: a (nearly) constant observation is centred, not
/// blown up.
pub const STD_FLOOR: f64 = 1e-3;

/// Per-input shift, scale and clip bound.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct InputNorm<const OBS: usize> {
    /// Subtracted first (the observations' mean).
    pub shift: [f32; OBS],
    /// Then multiplied by (`1 / max(std, STD_FLOOR)`).
    pub scale: [f32; OBS],
    /// Then clipped to `[-limit, limit]` ([`CLIP`] once fit; `f32::MAX` for the identity).
    pub limit: [f32; OBS],
}

impl<const OBS: usize> Params for InputNorm<OBS> {
    const TENSORS: usize = 3;
    fn tensor(&self, k: usize) -> &[f32] {
        match k {
            0 => &self.shift,
            1 => &self.scale,
            2 => &self.limit,
            _ => panic!("InputNorm has 3 tensors"),
        }
    }
    fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
        match k {
            0 => &mut self.shift,
            1 => &mut self.scale,
            2 => &mut self.limit,
            _ => panic!("InputNorm has 3 tensors"),
        }
    }
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
        f(&mut self.shift);
        f(&mut self.scale);
        f(&mut self.limit);
    }
}

impl<const OBS: usize> InputNorm<OBS> {
    /// The identity: every finite input passes unchanged, bit for bit.
    pub fn init(&mut self) {
        self.shift.fill(0.0);
        self.scale.fill(1.0);
        self.limit.fill(f32::MAX);
    }

    /// True for the identity (normalisation never fit).
    pub fn is_identity(&self) -> bool {
        self.shift.iter().all(|&s| s == 0.0)
            && self.scale.iter().all(|&s| s == 1.0)
            && self.limit.iter().all(|&l| l == f32::MAX)
    }

    /// Fits shift and scale to the mean and standard deviation of `rows` (two passes in f64,
    /// rows in order) and sets the clip bound to [`CLIP`]. No rows: unchanged.
    pub fn fit(&mut self, rows: &[[f32; OBS]]) {
        if rows.is_empty() {
            return;
        }
        let n = rows.len() as f64;
        let mut mean = [0f64; OBS];
        for r in rows {
            for (m, &x) in mean.iter_mut().zip(r) {
                *m += x as f64;
            }
        }
        for m in mean.iter_mut() {
            *m /= n;
        }
        let mut var = [0f64; OBS];
        for r in rows {
            for ((v, &m), &x) in var.iter_mut().zip(&mean).zip(r) {
                let d = x as f64 - m;
                *v += d * d;
            }
        }
        for j in 0..OBS {
            let std = libm::sqrt(var[j] / n).max(STD_FLOOR);
            self.shift[j] = mean[j] as f32;
            self.scale[j] = (1.0 / std) as f32;
            self.limit[j] = CLIP;
        }
    }

    /// One normalised input: `(x - shift) * scale`, clipped to `[-limit, limit]`. Written with
    /// comparisons rather than `clamp`, so a NaN input stays NaN (callers reject non-finite
    /// policy outputs) and parameters read from outside (a negative or NaN limit) cannot panic.
    #[inline]
    pub fn apply(&self, x: &[f32; OBS]) -> [f32; OBS] {
        core::array::from_fn(|j| {
            let (v, l) = ((x[j] - self.shift[j]) * self.scale[j], self.limit[j]);
            if v > l {
                l
            } else if v < -l {
                -l
            } else {
                v
            }
        })
    }

    /// Normalises rows in place (a batch, before the learner's update).
    pub fn apply_rows(&self, rows: &mut [[f32; OBS]]) {
        for r in rows.iter_mut() {
            *r = self.apply(r);
        }
    }
}
