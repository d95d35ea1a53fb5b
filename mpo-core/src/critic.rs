//! The action-value network `Q(s, a)`: a two-hidden-layer ReLU network on `(s, a)`.
//!
//! The first layer keeps separate weight blocks for the observation and the action, which is
//! the same function as one layer on the concatenation (bias, then observation inputs, then
//! action inputs, in that order) but lets the E-step compute the observation part once per
//! state and reuse it for every sampled action.

use bytemuck::Zeroable;

use crate::linear::{Linear, accumulate, relu, relu_backward, weight_grad};
use crate::params::Params;
use crate::rng::Rng;

/// A bias-free weight block `y += x W` (the action part of the critic's first layer).
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Weights<const I: usize, const O: usize> {
    /// Input-major weights.
    pub w: [[f32; O]; I],
}

impl<const I: usize, const O: usize> Params for Weights<I, O> {
    const TENSORS: usize = 1;
    fn tensor(&self, k: usize) -> &[f32] {
        assert_eq!(k, 0, "Weights has 1 tensor");
        self.w.as_flattened()
    }
    fn tensor_mut(&mut self, k: usize) -> &mut [f32] {
        assert_eq!(k, 0, "Weights has 1 tensor");
        self.w.as_flattened_mut()
    }
}

/// Critic for `OBS` observations and `ACT` actions.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Critic<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize> {
    /// First layer, observation block and bias.
    pub l1s: Linear<OBS, H1>,
    /// First layer, action block.
    pub l1a: Weights<ACT, H1>,
    /// Second hidden layer.
    pub l2: Linear<H1, H2>,
    /// Scalar output.
    pub out: Linear<H2, 1>,
}

crate::impl_params_for_fields!(Critic<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize> {
    l1s: Linear<OBS, H1>,
    l1a: Weights<ACT, H1>,
    l2: Linear<H1, H2>,
    out: Linear<H2, 1>,
});

impl<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize>
    Critic<OBS, ACT, H1, H2>
{
    /// Initialises in place with uniform fan-in bounds (fan-in of the first layer is
    /// `OBS + ACT`, as for one layer on the concatenation).
    pub fn init(&mut self, rng: &mut Rng) {
        let bound = 1.0 / libm::sqrtf((OBS + ACT) as f32);
        for x in self.l1s.w.as_flattened_mut() {
            *x = rng.uniform_range(-bound, bound);
        }
        for x in &mut self.l1s.b {
            *x = rng.uniform_range(-bound, bound);
        }
        for x in self.l1a.w.as_flattened_mut() {
            *x = rng.uniform_range(-bound, bound);
        }
        self.l2.init_uniform(rng);
        self.out.init_uniform(rng);
    }

    /// The observation part of the first layer's pre-activation: `b + s W_s`.
    pub fn state_part(&self, obs: &[[f32; OBS]], pre1: &mut [[f32; H1]]) {
        self.l1s.forward(obs, pre1);
    }

    /// `Q` for a batch of actions given the observation part of each row (from
    /// [`Self::state_part`]); fills `tape` for [`Self::backward`].
    pub fn forward_from_state_part<const B: usize>(
        &self,
        pre1_s: &[[f32; H1]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2>,
        q: &mut [[f32; 1]; B],
    ) {
        tape.h1 = *pre1_s;
        self.finish_forward(act, tape, q);
    }

    /// The rest of the forward pass once `tape.h1` holds the observation part.
    fn finish_forward<const B: usize>(
        &self,
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2>,
        q: &mut [[f32; 1]; B],
    ) {
        accumulate(act, &self.l1a.w, &mut tape.h1);
        relu(&mut tape.h1);
        self.l2.forward(&tape.h1, &mut tape.h2);
        relu(&mut tape.h2);
        self.out.forward(&tape.h2, q);
    }

    /// `Q(s, a)` for a batch.
    pub fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2>,
        q: &mut [[f32; 1]; B],
    ) {
        self.state_part(obs, &mut tape.h1);
        self.finish_forward(act, tape, q);
    }

    /// Gradients of `sum_n dq[n] Q(s_n, a_n)` with respect to every parameter, written into
    /// `grad`; `tape` must hold the activations of the forward pass on the same batch.
    pub fn backward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2>,
        dq: &[[f32; 1]; B],
        grad: &mut Self,
    ) {
        self.out
            .backward(&tape.h2, dq, &mut grad.out, Some(&mut tape.d_h2));
        relu_backward(&tape.h2, &mut tape.d_h2);
        self.l2.backward_wide(
            &tape.h1,
            &tape.d_h2,
            &mut grad.l2,
            &mut tape.d_h1,
            &mut tape.w2t,
        );
        relu_backward(&tape.h1, &mut tape.d_h1);
        self.l1s.backward(obs, &tape.d_h1, &mut grad.l1s, None);
        weight_grad(act, &tape.d_h1, &mut grad.l1a.w);
    }

    /// `Q(s, a)` for one pair.
    pub fn q_one(&self, obs: &[f32; OBS], act: &[f32; ACT]) -> f32 {
        let mut h1 = [[0f32; H1]; 1];
        let mut h2 = [[0f32; H2]; 1];
        let mut q = [[0f32; 1]; 1];
        self.l1s.forward(core::slice::from_ref(obs), &mut h1);
        accumulate(core::slice::from_ref(act), &self.l1a.w, &mut h1);
        relu(&mut h1);
        self.l2.forward(&h1, &mut h2);
        relu(&mut h2);
        self.out.forward(&h2, &mut q);
        q[0][0]
    }

    /// Multiply-adds of one forward pass for one pair.
    pub const fn forward_macs() -> usize {
        (OBS + ACT) * H1 + H1 * H2 + H2
    }
}

/// Activations and backward scratch for a batch of `B` pairs.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct CriticTape<const B: usize, const H1: usize, const H2: usize> {
    /// First hidden activations (after ReLU).
    pub h1: [[f32; H1]; B],
    /// Second hidden activations (after ReLU).
    pub h2: [[f32; H2]; B],
    /// Gradient at the second hidden layer.
    pub d_h2: [[f32; H2]; B],
    /// Gradient at the first hidden layer.
    pub d_h1: [[f32; H1]; B],
    /// Transposed second-layer weights (scratch of the input gradient).
    pub w2t: [[f32; H1]; H2],
}
