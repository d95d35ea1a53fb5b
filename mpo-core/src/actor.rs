//! The policy network: a two-hidden-layer ReLU trunk with a mean head and a Cholesky head.
//!
//! Two heads instead of one output layer of width `A + A(A+1)/2` keep every size a plain const
//! generic (stable Rust has no size expressions in types).

use bytemuck::Zeroable;

use crate::gaussian::{Gaussian, softplus_inverse, tri_index};
use crate::linear::{Linear, relu};
use crate::params::Params;
use crate::rng::Rng;

/// Policy network for `OBS` observations and `ACT` actions (`TRI = ACT (ACT + 1) / 2`).
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Actor<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
> {
    /// Input layer.
    pub l1: Linear<OBS, H1>,
    /// Second hidden layer.
    pub l2: Linear<H1, H2>,
    /// Mean head.
    pub mean: Linear<H2, ACT>,
    /// Cholesky head (packed lower triangle; diagonal before softplus).
    pub chol: Linear<H2, TRI>,
}

crate::impl_params_for_fields!(Actor<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize> {
    l1: Linear<OBS, H1>,
    l2: Linear<H1, H2>,
    mean: Linear<H2, ACT>,
    chol: Linear<H2, TRI>,
});

impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize>
    Actor<OBS, ACT, TRI, H1, H2>
{
    const SHAPE_OK: () = assert!(TRI == ACT * (ACT + 1) / 2, "TRI must be ACT(ACT+1)/2");

    /// Initialises in place: uniform fan-in layers, heads scaled down so the initial policy is
    /// close to `N(0, init_std^2 I)` whatever the observation.
    pub fn init(&mut self, rng: &mut Rng, init_std: f32, std_floor: f32) {
        let () = Self::SHAPE_OK;
        self.l1.init_uniform(rng);
        self.l2.init_uniform(rng);
        self.mean.init_uniform(rng);
        self.chol.init_uniform(rng);
        self.mean.scale(0.01);
        self.chol.scale(0.01);
        let diag = softplus_inverse((init_std - std_floor).max(1e-3));
        for j in 0..ACT {
            self.chol.b[tri_index(j, j)] += diag;
        }
    }

    /// Trunk for a batch: `h1 = relu(l1 x)`, `h2 = relu(l2 h1)`.
    pub fn trunk(&self, obs: &[[f32; OBS]], h1: &mut [[f32; H1]], h2: &mut [[f32; H2]]) {
        self.l1.forward(obs, h1);
        relu(h1);
        self.l2.forward(h1, h2);
        relu(h2);
    }

    #[cfg(feature = "train")]
    /// Raw head outputs for a batch, keeping the activations in `tape` for [`Self::backward`].
    pub fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut ActorTape<B, H1, H2>,
        mean: &mut [[f32; ACT]; B],
        chol: &mut [[f32; TRI]; B],
    ) {
        self.trunk(obs, &mut tape.h1, &mut tape.h2);
        self.mean.forward(&tape.h2, mean);
        self.chol.forward(&tape.h2, chol);
    }

    #[cfg(feature = "train")]
    /// Gradients of `sum_n d_mean[n] . mean[n] + d_chol[n] . chol[n]` with respect to every
    /// parameter, written into `grad`. `tape` must hold the activations of the forward pass
    /// for the same `obs`.
    pub fn backward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut ActorTape<B, H1, H2>,
        d_mean: &[[f32; ACT]; B],
        d_chol: &[[f32; TRI]; B],
        grad: &mut Self,
    ) {
        self.mean
            .backward(&tape.h2, d_mean, &mut grad.mean, Some(&mut tape.d_h2));
        self.chol
            .backward(&tape.h2, d_chol, &mut grad.chol, Some(&mut tape.d_h2b));
        for (a, b) in tape
            .d_h2
            .as_flattened_mut()
            .iter_mut()
            .zip(tape.d_h2b.as_flattened())
        {
            *a += *b;
        }
        crate::linear::relu_backward(&tape.h2, &mut tape.d_h2);
        self.l2.backward_wide(
            &tape.h1,
            &tape.d_h2,
            &mut grad.l2,
            &mut tape.d_h1,
            &mut tape.w2t,
        );
        crate::linear::relu_backward(&tape.h1, &mut tape.d_h1);
        self.l1.backward(obs, &tape.d_h1, &mut grad.l1, None);
    }

    /// Raw head outputs for one state (no tape: the inference path).
    pub fn forward_one(&self, obs: &[f32; OBS], mean: &mut [f32; ACT], chol: &mut [f32; TRI]) {
        let mut h1 = [[0f32; H1]; 1];
        let mut h2 = [[0f32; H2]; 1];
        self.trunk(core::slice::from_ref(obs), &mut h1, &mut h2);
        self.mean.forward(&h2, core::slice::from_mut(mean));
        self.chol.forward(&h2, core::slice::from_mut(chol));
    }

    /// The mean action for one state: what a deployed controller executes.
    pub fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        let mut h1 = [[0f32; H1]; 1];
        let mut h2 = [[0f32; H2]; 1];
        self.trunk(core::slice::from_ref(obs), &mut h1, &mut h2);
        self.mean.forward(&h2, core::slice::from_mut(action));
    }

    /// The policy's distribution at one state.
    pub fn distribution(&self, obs: &[f32; OBS], std_floor: f32) -> Gaussian<ACT> {
        let mut m = [0f32; ACT];
        let mut c = [0f32; TRI];
        self.forward_one(obs, &mut m, &mut c);
        Gaussian::from_head(&m, &c, std_floor)
    }

    /// Multiply-adds of one forward pass for one state.
    pub const fn forward_macs() -> usize {
        OBS * H1 + H1 * H2 + H2 * (ACT + TRI)
    }
}

#[cfg(feature = "train")]
/// Activations and backward scratch for a batch of `B` states.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ActorTape<const B: usize, const H1: usize, const H2: usize> {
    /// First hidden activations (after ReLU).
    pub h1: [[f32; H1]; B],
    /// Second hidden activations (after ReLU).
    pub h2: [[f32; H2]; B],
    /// Gradient at the second hidden layer.
    pub d_h2: [[f32; H2]; B],
    /// Gradient at the second hidden layer from the Cholesky head (summed into `d_h2`).
    pub d_h2b: [[f32; H2]; B],
    /// Gradient at the first hidden layer.
    pub d_h1: [[f32; H1]; B],
    /// Transposed second-layer weights (scratch of the input gradient).
    pub w2t: [[f32; H1]; H2],
}
