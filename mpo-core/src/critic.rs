//! The action-value network `Q(s, a)`: a two-hidden-layer ReLU network on `(s, a)`, or, with
//! `layer_norm` (`MpoConfig::critic_layer_norm`), Acme's `LayerNormMLP` torso: the first layer's
//! pre-activations go through a [`LayerNorm`] and `tanh` instead of a ReLU.
//!
//! The first layer keeps separate weight blocks for the observation and the action, which is
//! the same function as one layer on the concatenation (bias, then observation inputs, then
//! action inputs, in that order) but lets the E-step compute the observation part once per
//! state and reuse it for every sampled action.

use bytemuck::Zeroable;

use crate::actor::{MAX_PARTS, sum_squares};
use crate::config::MpoConfig;
use crate::layer_norm::{LayerNorm, param_grad_chunks};
use crate::linear::{
    Linear, Start, accumulate, bias_grad_chunks, kernel, relu_backward, transpose,
    weight_grad_chunks,
};
use crate::network::{ValueGradInputs, ValueNet, block_rows, chunk_slices};
use crate::parallel::Parallel;
use crate::params::Params;
use crate::rng::Rng;
use crate::value_head::{self, Support};

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
    fn visit_mut<'a>(&'a mut self, f: &mut dyn FnMut(&'a mut [f32])) {
        f(self.w.as_flattened_mut());
    }
}

/// Critic for `OBS` observations and `ACT` actions.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Critic<
    const OBS: usize,
    const ACT: usize,
    const H1: usize,
    const H2: usize,
    const K: usize = 1,
> {
    /// First layer, observation block and bias.
    pub l1s: Linear<OBS, H1>,
    /// First layer, action block.
    pub l1a: Weights<ACT, H1>,
    /// The first layer's layer norm (used only with `layer_norm`; kept at its initial
    /// identity otherwise, since its gradient is then zero).
    pub ln1: LayerNorm<H1>,
    /// Second hidden layer.
    pub l2: Linear<H1, H2>,
    /// Output: the value (`K = 1`) or the logits of a categorical value
    /// ([`crate::value_head`]).
    pub out: Linear<H2, K>,
}

crate::impl_params_for_fields!(Critic<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize, const K: usize> {
    l1s: Linear<OBS, H1>,
    l1a: Weights<ACT, H1>,
    ln1: LayerNorm<H1>,
    l2: Linear<H1, H2>,
    out: Linear<H2, K>,
});

impl<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize, const K: usize>
    Critic<OBS, ACT, H1, H2, K>
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
        self.ln1.init();
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
        tape: &mut CriticTape<B, H1, H2, K>,
        q: &mut [[f32; K]; B],
        layer_norm: bool,
    ) {
        self.first_layer(act, Start::Rows(pre1_s), tape, layer_norm);
        self.finish_forward(tape, q);
    }

    /// Adds the action block to the observation part `start` and applies the first layer's
    /// activation (ReLU, or layer norm and `tanh`), into `tape.h1`.
    fn first_layer<const B: usize>(
        &self,
        act: &[[f32; ACT]; B],
        start: Start<'_, H1>,
        tape: &mut CriticTape<B, H1, H2, K>,
        layer_norm: bool,
    ) {
        if layer_norm {
            kernel::<ACT, H1, false>(act, &self.l1a.w, start, &mut tape.h1);
            self.ln1
                .forward_tanh(&mut tape.h1, &mut tape.xhat, &mut tape.rstd);
        } else {
            kernel::<ACT, H1, true>(act, &self.l1a.w, start, &mut tape.h1);
        }
    }

    /// The rest of the forward pass once `tape.h1` holds the first hidden layer.
    fn finish_forward<const B: usize>(
        &self,
        tape: &mut CriticTape<B, H1, H2, K>,
        q: &mut [[f32; K]; B],
    ) {
        self.l2.forward_relu(&tape.h1, &mut tape.h2);
        self.out.forward(&tape.h2, q);
    }

    /// `Q(s, a)` for a batch.
    pub fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2, K>,
        q: &mut [[f32; K]; B],
        layer_norm: bool,
    ) {
        self.state_part(obs, &mut tape.h1);
        self.first_layer(act, Start::Y, tape, layer_norm);
        self.finish_forward(tape, q);
    }

    /// Fills `t` with the transposed weights [`Self::backprop`] multiplies by.
    pub fn transpose_into(&self, t: &mut CriticTransposed<H1, H2, K>) {
        transpose(&self.out.w, &mut t.out);
        transpose(&self.l2.w, &mut t.l2);
    }

    /// Carries `dq` of one chunk down to the hidden layers: fills `tape.d_h2` and `tape.d_h1`.
    /// `tape` holds the chunk's forward activations, `t` this network's transposed weights.
    pub fn backprop<const B: usize>(
        &self,
        tape: &mut CriticTape<B, H1, H2, K>,
        dq: &[[f32; K]; B],
        t: &CriticTransposed<H1, H2, K>,
        layer_norm: bool,
    ) {
        for row in tape.d_h2.iter_mut() {
            row.fill(0.0);
        }
        accumulate(dq, &t.out, &mut tape.d_h2);
        relu_backward(&tape.h2, &mut tape.d_h2);
        for row in tape.d_h1.iter_mut() {
            row.fill(0.0);
        }
        accumulate(&tape.d_h2, &t.l2, &mut tape.d_h1);
        if layer_norm {
            let tape = &mut *tape;
            self.ln1.backward(
                &tape.h1,
                &tape.xhat,
                &tape.rstd,
                &mut tape.d_h1,
                &mut tape.d_y,
            );
        } else {
            relu_backward(&tape.h1, &mut tape.d_h1);
        }
    }

    /// Gradients of `sum_n dq[n] Q(s_n, a_n)` with respect to every parameter, written into
    /// `grad`, for one contiguous batch; `tape` must hold the activations of the forward pass
    /// on the same batch; `t` is scratch.
    // Every argument is a caller-owned buffer: nothing is allocated here.
    #[allow(clippy::too_many_arguments)]
    pub fn backward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2, K>,
        dq: &[[f32; K]; B],
        t: &mut CriticTransposed<H1, H2, K>,
        grad: &mut Self,
        layer_norm: bool,
    ) {
        self.transpose_into(t);
        self.backprop(tape, dq, t, layer_norm);
        let inputs = CriticGradInputs {
            obs: &[&obs[..]],
            act: &[&act[..]],
            h1: &[&tape.h1[..]],
            h2: &[&tape.h2[..]],
            d_h1: &[&tape.d_h1[..]],
            d_h2: &[&tape.d_h2[..]],
            dq: &[&dq[..]],
            xhat: &[&tape.xhat[..]],
            d_y: &[&tape.d_y[..]],
            layer_norm,
        };
        for part in grad.grad_parts(usize::MAX).iter_mut() {
            part.compute(&inputs);
        }
    }

    /// Splits `self` (a gradient) into independent blocks for [`CriticGradPart::compute`]
    /// (see [`crate::actor::Actor::grad_parts`]).
    pub fn grad_parts(
        &mut self,
        rows: usize,
    ) -> heapless::Vec<CriticGradPart<'_, OBS, ACT, H1, H2, K>, MAX_PARTS> {
        let mut parts = heapless::Vec::new();
        let rows = rows.max(H1.div_ceil(MAX_PARTS - 4)).max(1);
        let mut push = |p| {
            if parts.push(p).is_err() {
                unreachable!("block count is bounded above");
            }
        };
        push(CriticGradPart::First {
            s: &mut self.l1s,
            a: &mut self.l1a,
        });
        push(CriticGradPart::Norm(&mut self.ln1));
        let mut i0 = 0;
        for block in self.l2.w.chunks_mut(rows) {
            let n = block.len();
            push(CriticGradPart::Second { w: block, i0 });
            i0 += n;
        }
        push(CriticGradPart::SecondBias(&mut self.l2.b));
        push(CriticGradPart::Out(&mut self.out));
        parts
    }

    /// Multiply-adds of one forward pass for one pair.
    pub const fn forward_macs() -> usize {
        (OBS + ACT) * H1 + H1 * H2 + H2 * K
    }
}

impl<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize>
    Critic<OBS, ACT, H1, H2, 1>
{
    /// `Q(s, a)` for one pair (a scalar critic).
    pub fn q_one(&self, obs: &[f32; OBS], act: &[f32; ACT], layer_norm: bool) -> f32 {
        let mut h1 = [[0f32; H1]; 1];
        let mut h2 = [[0f32; H2]; 1];
        let mut q = [[0f32; 1]; 1];
        self.l1s.forward(core::slice::from_ref(obs), &mut h1);
        if layer_norm {
            kernel::<ACT, H1, false>(core::slice::from_ref(act), &self.l1a.w, Start::Y, &mut h1);
            let (mut xhat, mut rstd) = ([[0f32; H1]; 1], [0f32; 1]);
            self.ln1.forward_tanh(&mut h1, &mut xhat, &mut rstd);
        } else {
            kernel::<ACT, H1, true>(core::slice::from_ref(act), &self.l1a.w, Start::Y, &mut h1);
        }
        self.l2.forward_relu(&h1, &mut h2);
        self.out.forward(&h2, &mut q);
        q[0][0]
    }
}

/// One independent block of a critic's weight gradient (see [`Critic::grad_parts`]).
pub enum CriticGradPart<
    'a,
    const OBS: usize,
    const ACT: usize,
    const H1: usize,
    const H2: usize,
    const K: usize = 1,
> {
    /// The first layer (observation block with the bias, action block).
    First {
        /// Observation block and bias.
        s: &'a mut Linear<OBS, H1>,
        /// Action block.
        a: &'a mut Weights<ACT, H1>,
    },
    /// The first layer's layer norm (zero without `layer_norm`).
    Norm(&'a mut LayerNorm<H1>),
    /// Second-layer weight rows `i0 ..`.
    Second {
        /// The rows.
        w: &'a mut [[f32; H2]],
        /// Index of the first row.
        i0: usize,
    },
    /// The second layer's bias.
    SecondBias(&'a mut [f32; H2]),
    /// The output layer.
    Out(&'a mut Linear<H2, K>),
}

/// The activations and gradients of a batch held in chunks (entry `c` of every list is chunk
/// `c`), as the critic's weight gradients read them.
pub struct CriticGradInputs<
    'a,
    const OBS: usize,
    const ACT: usize,
    const H1: usize,
    const H2: usize,
    const K: usize = 1,
> {
    /// States.
    pub obs: &'a [&'a [[f32; OBS]]],
    /// Actions.
    pub act: &'a [&'a [[f32; ACT]]],
    /// First hidden activations.
    pub h1: &'a [&'a [[f32; H1]]],
    /// Second hidden activations.
    pub h2: &'a [&'a [[f32; H2]]],
    /// Gradients at the first hidden layer's pre-activations.
    pub d_h1: &'a [&'a [[f32; H1]]],
    /// Gradients at the second hidden layer's pre-activations.
    pub d_h2: &'a [&'a [[f32; H2]]],
    /// Gradients at the outputs.
    pub dq: &'a [&'a [[f32; K]]],
    /// Normalised first-layer pre-activations (read only with `layer_norm`).
    pub xhat: &'a [&'a [[f32; H1]]],
    /// Gradients at the layer norm's outputs (read only with `layer_norm`).
    pub d_y: &'a [&'a [[f32; H1]]],
    /// Whether the first layer is layer-normalised.
    pub layer_norm: bool,
}

impl<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize, const K: usize>
    CriticGradPart<'_, OBS, ACT, H1, H2, K>
{
    /// Computes this block of the gradient (overwriting it) and returns the sum of its
    /// squares.
    pub fn compute(&mut self, x: &CriticGradInputs<'_, OBS, ACT, H1, H2, K>) -> f64 {
        match self {
            Self::First { s, a } => {
                weight_grad_chunks(x.obs, x.d_h1, 0, &mut s.w);
                bias_grad_chunks(x.d_h1, &mut s.b);
                weight_grad_chunks(x.act, x.d_h1, 0, &mut a.w);
                sum_squares(s.w.as_flattened())
                    + sum_squares(&s.b)
                    + sum_squares(a.w.as_flattened())
            }
            Self::Norm(ln) => {
                if x.layer_norm {
                    param_grad_chunks(x.xhat, x.d_y, ln);
                } else {
                    ln.g.fill(0.0);
                    ln.b.fill(0.0);
                }
                sum_squares(&ln.g) + sum_squares(&ln.b)
            }
            Self::Second { w, i0 } => {
                weight_grad_chunks(x.h1, x.d_h2, *i0, w);
                sum_squares(w.as_flattened())
            }
            Self::SecondBias(b) => {
                bias_grad_chunks(x.d_h2, b);
                sum_squares(&b[..])
            }
            Self::Out(l) => {
                weight_grad_chunks(x.h2, x.dq, 0, &mut l.w);
                bias_grad_chunks(x.dq, &mut l.b);
                sum_squares(l.w.as_flattened()) + sum_squares(&l.b)
            }
        }
    }
}

/// The critic's weights transposed (output-major), as the backward pass multiplies by them.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct CriticTransposed<const H1: usize, const H2: usize, const K: usize = 1> {
    /// Output layer.
    pub out: [[f32; H2]; K],
    /// Second layer.
    pub l2: [[f32; H1]; H2],
}

/// Activations and backward scratch for a batch of `B` pairs.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct CriticTape<const B: usize, const H1: usize, const H2: usize, const K: usize = 1> {
    /// First hidden activations (after ReLU, or layer norm and `tanh`).
    pub h1: [[f32; H1]; B],
    /// The first layer's normalised pre-activations (layer norm only).
    pub xhat: [[f32; H1]; B],
    /// `1 / sqrt(var + eps)` of each row's first-layer pre-activations (layer norm only).
    pub rstd: [f32; B],
    /// Gradient at the layer norm's outputs (layer norm only).
    pub d_y: [[f32; H1]; B],
    /// Second hidden activations (after ReLU).
    pub h2: [[f32; H2]; B],
    /// Gradient at the second hidden layer.
    pub d_h2: [[f32; H2]; B],
    /// Gradient at the first hidden layer.
    pub d_h1: [[f32; H1]; B],
    /// The outputs (through [`ValueNet`]).
    pub out: [[f32; K]; B],
    /// A categorical head's probabilities (through [`ValueNet`]; unused when `K = 1`).
    pub probs: [[f32; K]; B],
    /// The loss's gradient at the outputs (through [`ValueNet`]).
    pub d_out: [[f32; K]; B],
}

impl<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize, const K: usize>
    ValueNet<OBS, ACT> for Critic<OBS, ACT, H1, H2, K>
{
    const HIDDEN: [usize; 2] = [H1, H2];
    const BLOCKS: usize = 0;
    const BINS: usize = K;
    type StatePart<const B: usize> = [[f32; H1]; B];
    type Tape<const B: usize> = CriticTape<B, H1, H2, K>;
    type Transposed = CriticTransposed<H1, H2, K>;

    fn init(&mut self, rng: &mut Rng) {
        Critic::init(self, rng);
    }

    fn state_part<const B: usize>(&self, obs: &[[f32; OBS]; B], part: &mut [[f32; H1]; B]) {
        Critic::state_part(self, obs, part);
    }

    fn values_from_state_part<const B: usize>(
        &self,
        part: &[[f32; H1]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2, K>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    ) {
        self.first_layer(act, Start::Rows(part), tape, cfg.critic_layer_norm);
        self.l2.forward_relu(&tape.h1, &mut tape.h2);
        self.out.forward(&tape.h2, &mut tape.out);
        value_head::values(&Support::of(cfg), &tape.out, &mut tape.probs, q);
    }

    fn values<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut CriticTape<B, H1, H2, K>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    ) {
        self.state_part(obs, &mut tape.h1);
        self.first_layer(act, Start::Y, tape, cfg.critic_layer_norm);
        self.l2.forward_relu(&tape.h1, &mut tape.h2);
        self.out.forward(&tape.h2, &mut tape.out);
        value_head::values(&Support::of(cfg), &tape.out, &mut tape.probs, q);
    }

    fn loss<const B: usize>(
        &self,
        tape: &mut CriticTape<B, H1, H2, K>,
        q: &[f32; B],
        y: &[f32; B],
        inv_b: f32,
        cfg: &MpoConfig,
        loss: &mut [f32; B],
    ) {
        let s = Support::of(cfg);
        value_head::loss(
            &s,
            &tape.out,
            &tape.probs,
            q,
            y,
            inv_b,
            &mut tape.d_out,
            loss,
        );
    }

    fn transpose_into(&self, t: &mut CriticTransposed<H1, H2, K>) {
        Critic::transpose_into(self, t);
    }

    fn backprop<const B: usize>(
        &self,
        tape: &mut CriticTape<B, H1, H2, K>,
        t: &CriticTransposed<H1, H2, K>,
        cfg: &MpoConfig,
    ) {
        let dq = tape.d_out;
        Critic::backprop(self, tape, &dq, t, cfg.critic_layer_norm);
    }

    fn weight_grads<Par: Parallel, const B: usize>(
        grad: &mut Self,
        par: &Par,
        x: &ValueGradInputs<'_, OBS, ACT, CriticTape<B, H1, H2, K>>,
        cfg: &MpoConfig,
    ) -> f64 {
        let h1 = chunk_slices(x.tapes, |t| &t.h1[..]);
        let h2 = chunk_slices(x.tapes, |t| &t.h2[..]);
        let d_h1 = chunk_slices(x.tapes, |t| &t.d_h1[..]);
        let d_h2 = chunk_slices(x.tapes, |t| &t.d_h2[..]);
        let dq = chunk_slices(x.tapes, |t| &t.d_out[..]);
        let xhat = chunk_slices(x.tapes, |t| &t.xhat[..]);
        let d_y = chunk_slices(x.tapes, |t| &t.d_y[..]);
        let inputs = CriticGradInputs {
            obs: x.obs,
            act: x.act,
            h1: &h1,
            h2: &h2,
            d_h1: &d_h1,
            d_h2: &d_h2,
            dq: &dq,
            xhat: &xhat,
            d_y: &d_y,
            layer_norm: cfg.critic_layer_norm,
        };
        let mut parts: heapless::Vec<_, MAX_PARTS> = grad
            .grad_parts(block_rows(H1))
            .into_iter()
            .map(|p| (p, 0f64))
            .collect();
        par.for_each(&mut parts, &|_, (p, sq)| *sq = p.compute(&inputs));
        parts.iter().map(|(_, sq)| *sq).sum::<f64>()
    }

    fn forward_macs() -> usize {
        Critic::<OBS, ACT, H1, H2, K>::forward_macs()
    }

    fn state_macs() -> usize {
        OBS * H1
    }

    fn backward_macs() -> usize {
        2 * Critic::<OBS, ACT, H1, H2, K>::forward_macs() - (OBS + ACT) * H1
    }
    fn relu_layers<const B: usize>(
        tape: &Self::Tape<B>,
        cfg: &MpoConfig,
        visit: &mut dyn FnMut(&[f32], usize),
    ) {
        if !cfg.critic_layer_norm {
            visit(tape.h1.as_flattened(), H1);
        }
        visit(tape.h2.as_flattened(), H2);
    }
}
