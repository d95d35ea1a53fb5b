//! The policy network: a two-hidden-layer ReLU trunk with a mean head and a Cholesky head.
//!
//! Two heads instead of one output layer of width `A + A(A+1)/2` keep every size a plain const
//! generic (stable Rust has no size expressions in types).
//!
//! Training splits the backward pass in two, so a batch held in chunks can be spread over
//! threads: [`Actor::backprop`] carries the head gradients down to the hidden layers of one
//! chunk (rows are independent), then [`Actor::grad_parts`] and [`ActorGradPart::compute`]
//! form the weight gradients from every chunk's activations, one block of parameter rows at a
//! time (blocks are independent). [`Actor::backward`] does both for one contiguous batch.

use bytemuck::Zeroable;

use crate::gaussian::{Gaussian, softplus_inverse, tri_index};
use crate::linear::Linear;
#[cfg(feature = "train")]
use crate::linear::{accumulate, bias_grad_chunks, relu_backward, transpose, weight_grad_chunks};
use crate::network::PolicyNet;
#[cfg(feature = "train")]
use crate::network::{PolicyGradInputs, PolicyTrain, block_rows, chunk_slices};
use crate::obs_norm::InputNorm;
#[cfg(feature = "train")]
use crate::parallel::Parallel;
use crate::params::Params;
use crate::rng::Rng;
use crate::squash::MeanSquash;

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
    /// Observation normalisation (the identity unless fit; never trained by gradients).
    pub input: InputNorm<OBS>,
    /// Input layer.
    pub l1: Linear<OBS, H1>,
    /// Second hidden layer.
    pub l2: Linear<H1, H2>,
    /// Mean head.
    pub mean: Linear<H2, ACT>,
    /// Cholesky head (packed lower triangle; diagonal before softplus).
    pub chol: Linear<H2, TRI>,
    /// The mean's bound (unbounded unless set; never trained by gradients).
    pub squash: MeanSquash<ACT>,
}

crate::impl_params_for_fields!(Actor<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize> {
    input: InputNorm<OBS>,
    l1: Linear<OBS, H1>,
    l2: Linear<H1, H2>,
    mean: Linear<H2, ACT>,
    chol: Linear<H2, TRI>,
    squash: MeanSquash<ACT>,
});

impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize>
    Actor<OBS, ACT, TRI, H1, H2>
{
    const SHAPE_OK: () = assert!(TRI == ACT * (ACT + 1) / 2, "TRI must be ACT(ACT+1)/2");

    /// Initialises in place: uniform fan-in layers, heads scaled down so the initial policy is
    /// close to `N(0, init_std^2 I)` whatever the observation. The mean is unbounded (set
    /// [`Self::squash`] to bound it).
    pub fn init(&mut self, rng: &mut Rng, init_std: f32, std_floor: f32) {
        let () = Self::SHAPE_OK;
        self.input.init();
        self.squash.init(0.0);
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

    /// Trunk for a batch: `h1 = relu(l1 x)`, `h2 = relu(l2 h1)`. Batch paths take observations
    /// already normalised by [`Self::input`] (the learner normalises its batch once); the
    /// single-state paths below normalise their own input.
    pub fn trunk(&self, obs: &[[f32; OBS]], h1: &mut [[f32; H1]], h2: &mut [[f32; H2]]) {
        self.l1.forward_relu(obs, h1);
        self.l2.forward_relu(h1, h2);
    }

    #[cfg(feature = "train")]
    /// Head outputs for a batch (the mean squashed, the Cholesky head raw), keeping the
    /// activations in `tape` for the backward pass.
    pub fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut ActorTape<B, H1, H2>,
        mean: &mut [[f32; ACT]; B],
        chol: &mut [[f32; TRI]; B],
    ) {
        self.trunk(obs, &mut tape.h1, &mut tape.h2);
        self.mean.forward(&tape.h2, mean);
        self.squash.apply_rows(mean);
        self.chol.forward(&tape.h2, chol);
    }

    #[cfg(feature = "train")]
    /// Turns gradients at the squashed means [`Self::forward`] returned into gradients at the
    /// mean head's raw outputs, which [`Self::backprop`] and [`Self::backward`] take.
    pub fn squash_backward(&self, mean: &[[f32; ACT]], d_mean: &mut [[f32; ACT]]) {
        self.squash.backward_rows(mean, d_mean);
    }

    #[cfg(feature = "train")]
    /// Fills `t` with the transposed weights [`Self::backprop`] multiplies by.
    pub fn transpose_into(&self, t: &mut ActorTransposed<ACT, TRI, H1, H2>) {
        transpose(&self.mean.w, &mut t.mean);
        transpose(&self.chol.w, &mut t.chol);
        transpose(&self.l2.w, &mut t.l2);
    }

    #[cfg(feature = "train")]
    /// Carries the head gradients `d_mean` (at the raw mean head: see
    /// [`Self::squash_backward`]), `d_chol` of one chunk down to the hidden layers:
    /// fills `tape.d_h2` and `tape.d_h1` (gradients at the post-ReLU activations' inputs).
    /// `tape` holds the chunk's forward activations, `t` this network's transposed weights.
    pub fn backprop<const B: usize>(
        &self,
        tape: &mut ActorTape<B, H1, H2>,
        d_mean: &[[f32; ACT]; B],
        d_chol: &[[f32; TRI]; B],
        t: &ActorTransposed<ACT, TRI, H1, H2>,
    ) {
        for row in tape.d_h2.iter_mut() {
            row.fill(0.0);
        }
        accumulate(d_mean, &t.mean, &mut tape.d_h2);
        accumulate(d_chol, &t.chol, &mut tape.d_h2);
        relu_backward(&tape.h2, &mut tape.d_h2);
        for row in tape.d_h1.iter_mut() {
            row.fill(0.0);
        }
        accumulate(&tape.d_h2, &t.l2, &mut tape.d_h1);
        relu_backward(&tape.h1, &mut tape.d_h1);
    }

    #[cfg(feature = "train")]
    /// Gradients of `sum_n d_mean[n] . raw_mean[n] + d_chol[n] . chol[n]` with respect to
    /// every parameter, written into `grad`, for one contiguous batch (`raw_mean`: the mean
    /// head before the squash; [`Self::squash_backward`] converts). `tape` must hold the
    /// activations of the forward pass for the same `obs`; `t` is scratch.
    pub fn backward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut ActorTape<B, H1, H2>,
        d_mean: &[[f32; ACT]; B],
        d_chol: &[[f32; TRI]; B],
        t: &mut ActorTransposed<ACT, TRI, H1, H2>,
        grad: &mut Self,
    ) {
        self.transpose_into(t);
        self.backprop(tape, d_mean, d_chol, t);
        let inputs = ActorGradInputs {
            obs: &[&obs[..]],
            h1: &[&tape.h1[..]],
            h2: &[&tape.h2[..]],
            d_h1: &[&tape.d_h1[..]],
            d_h2: &[&tape.d_h2[..]],
            d_mean: &[&d_mean[..]],
            d_chol: &[&d_chol[..]],
        };
        for part in grad.grad_parts(usize::MAX).iter_mut() {
            part.compute(&inputs);
        }
    }

    #[cfg(feature = "train")]
    /// Splits `self` (a gradient) into independent blocks for [`ActorGradPart::compute`]:
    /// the first layer, the second layer's weights in blocks of `rows` input rows, its bias,
    /// and the heads. The blocks depend only on `rows`, never on who computes them.
    pub fn grad_parts(
        &mut self,
        rows: usize,
    ) -> heapless::Vec<ActorGradPart<'_, OBS, ACT, TRI, H1, H2>, MAX_PARTS> {
        let mut parts = heapless::Vec::new();
        let rows = rows.max(H1.div_ceil(MAX_PARTS - 3)).max(1);
        let mut push = |p| {
            if parts.push(p).is_err() {
                unreachable!("block count is bounded above");
            }
        };
        push(ActorGradPart::First(&mut self.l1));
        let mut i0 = 0;
        for block in self.l2.w.chunks_mut(rows) {
            let n = block.len();
            push(ActorGradPart::Second { w: block, i0 });
            i0 += n;
        }
        push(ActorGradPart::SecondBias(&mut self.l2.b));
        push(ActorGradPart::Heads {
            mean: &mut self.mean,
            chol: &mut self.chol,
        });
        parts
    }

    /// Head outputs for one state, as [`Self::forward`] (no tape: the inference path).
    pub fn forward_one(&self, obs: &[f32; OBS], mean: &mut [f32; ACT], chol: &mut [f32; TRI]) {
        let mut h1 = [[0f32; H1]; 1];
        let mut h2 = [[0f32; H2]; 1];
        let x = self.input.apply(obs);
        self.trunk(core::slice::from_ref(&x), &mut h1, &mut h2);
        self.mean.forward(&h2, core::slice::from_mut(mean));
        self.squash.apply(mean);
        self.chol.forward(&h2, core::slice::from_mut(chol));
    }

    /// The mean action for one state: what a deployed controller executes.
    pub fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        let mut h1 = [[0f32; H1]; 1];
        let mut h2 = [[0f32; H2]; 1];
        let x = self.input.apply(obs);
        self.trunk(core::slice::from_ref(&x), &mut h1, &mut h2);
        self.mean.forward(&h2, core::slice::from_mut(action));
        self.squash.apply(action);
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

impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize>
    PolicyNet<OBS, ACT, TRI> for Actor<OBS, ACT, TRI, H1, H2>
{
    const HIDDEN: [usize; 2] = [H1, H2];
    const BLOCKS: usize = 0;

    fn init(&mut self, rng: &mut Rng, init_std: f32, std_floor: f32) {
        Actor::init(self, rng, init_std, std_floor);
    }
    fn input(&self) -> &InputNorm<OBS> {
        &self.input
    }
    fn input_mut(&mut self) -> &mut InputNorm<OBS> {
        &mut self.input
    }
    fn squash(&self) -> &MeanSquash<ACT> {
        &self.squash
    }
    fn squash_mut(&mut self) -> &mut MeanSquash<ACT> {
        &mut self.squash
    }
    fn forward_one(&self, obs: &[f32; OBS], mean: &mut [f32; ACT], chol: &mut [f32; TRI]) {
        Actor::forward_one(self, obs, mean, chol);
    }
    fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]) {
        Actor::mean_action(self, obs, action);
    }
    fn forward_macs() -> usize {
        Actor::<OBS, ACT, TRI, H1, H2>::forward_macs()
    }
}

#[cfg(feature = "train")]
impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize>
    PolicyTrain<OBS, ACT, TRI> for Actor<OBS, ACT, TRI, H1, H2>
{
    type Tape<const B: usize> = ActorTape<B, H1, H2>;
    type Transposed = ActorTransposed<ACT, TRI, H1, H2>;

    fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut ActorTape<B, H1, H2>,
        mean: &mut [[f32; ACT]; B],
        chol: &mut [[f32; TRI]; B],
    ) {
        Actor::forward(self, obs, tape, mean, chol);
    }
    fn transpose_into(&self, t: &mut ActorTransposed<ACT, TRI, H1, H2>) {
        Actor::transpose_into(self, t);
    }
    fn backprop<const B: usize>(
        &self,
        tape: &mut ActorTape<B, H1, H2>,
        d_mean: &[[f32; ACT]; B],
        d_chol: &[[f32; TRI]; B],
        t: &ActorTransposed<ACT, TRI, H1, H2>,
    ) {
        Actor::backprop(self, tape, d_mean, d_chol, t);
    }
    fn weight_grads<Par: Parallel, const B: usize>(
        grad: &mut Self,
        par: &Par,
        x: &PolicyGradInputs<'_, OBS, ACT, TRI, ActorTape<B, H1, H2>>,
    ) -> f64 {
        let h1 = chunk_slices(x.tapes, |t| &t.h1[..]);
        let h2 = chunk_slices(x.tapes, |t| &t.h2[..]);
        let d_h1 = chunk_slices(x.tapes, |t| &t.d_h1[..]);
        let d_h2 = chunk_slices(x.tapes, |t| &t.d_h2[..]);
        let inputs = ActorGradInputs {
            obs: x.obs,
            h1: &h1,
            h2: &h2,
            d_h1: &d_h1,
            d_h2: &d_h2,
            d_mean: x.d_mean,
            d_chol: x.d_chol,
        };
        let mut parts: heapless::Vec<_, MAX_PARTS> = grad
            .grad_parts(block_rows(H1))
            .into_iter()
            .map(|p| (p, 0f64))
            .collect();
        par.for_each(&mut parts, &|_, (p, sq)| *sq = p.compute(&inputs));
        parts.iter().map(|(_, sq)| *sq).sum::<f64>()
    }
    fn backward_macs() -> usize {
        2 * Actor::<OBS, ACT, TRI, H1, H2>::forward_macs() - OBS * H1
    }
    fn relu_layers<const B: usize>(tape: &Self::Tape<B>, visit: &mut dyn FnMut(&[f32], usize)) {
        visit(tape.h1.as_flattened(), H1);
        visit(tape.h2.as_flattened(), H2);
    }
}

/// Upper bound of the blocks [`Actor::grad_parts`] and the critic's equivalent return.
pub const MAX_PARTS: usize = 24;

#[cfg(feature = "train")]
/// One independent block of an actor's weight gradient (see [`Actor::grad_parts`]).
pub enum ActorGradPart<
    'a,
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
> {
    /// The first layer (weights and bias).
    First(&'a mut Linear<OBS, H1>),
    /// Second-layer weight rows `i0 ..`.
    Second {
        /// The rows.
        w: &'a mut [[f32; H2]],
        /// Index of the first row.
        i0: usize,
    },
    /// The second layer's bias.
    SecondBias(&'a mut [f32; H2]),
    /// Both heads.
    Heads {
        /// Mean head.
        mean: &'a mut Linear<H2, ACT>,
        /// Cholesky head.
        chol: &'a mut Linear<H2, TRI>,
    },
}

#[cfg(feature = "train")]
/// The activations and gradients of a batch held in chunks, as the weight gradients read
/// them: entry `c` of every list is chunk `c`.
pub struct ActorGradInputs<
    'a,
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
> {
    /// States.
    pub obs: &'a [&'a [[f32; OBS]]],
    /// First hidden activations.
    pub h1: &'a [&'a [[f32; H1]]],
    /// Second hidden activations.
    pub h2: &'a [&'a [[f32; H2]]],
    /// Gradients at the first hidden layer's pre-activations.
    pub d_h1: &'a [&'a [[f32; H1]]],
    /// Gradients at the second hidden layer's pre-activations.
    pub d_h2: &'a [&'a [[f32; H2]]],
    /// Gradients at the mean head's outputs.
    pub d_mean: &'a [&'a [[f32; ACT]]],
    /// Gradients at the Cholesky head's outputs.
    pub d_chol: &'a [&'a [[f32; TRI]]],
}

#[cfg(feature = "train")]
impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize>
    ActorGradPart<'_, OBS, ACT, TRI, H1, H2>
{
    /// Computes this block of the gradient (overwriting it) and returns the sum of its
    /// squares (the block's share of the global norm).
    pub fn compute(&mut self, x: &ActorGradInputs<'_, OBS, ACT, TRI, H1, H2>) -> f64 {
        match self {
            Self::First(l) => {
                weight_grad_chunks(x.obs, x.d_h1, 0, &mut l.w);
                bias_grad_chunks(x.d_h1, &mut l.b);
                sum_squares(l.w.as_flattened()) + sum_squares(&l.b)
            }
            Self::Second { w, i0 } => {
                weight_grad_chunks(x.h1, x.d_h2, *i0, w);
                sum_squares(w.as_flattened())
            }
            Self::SecondBias(b) => {
                bias_grad_chunks(x.d_h2, b);
                sum_squares(&b[..])
            }
            Self::Heads { mean, chol } => {
                weight_grad_chunks(x.h2, x.d_mean, 0, &mut mean.w);
                bias_grad_chunks(x.d_mean, &mut mean.b);
                weight_grad_chunks(x.h2, x.d_chol, 0, &mut chol.w);
                bias_grad_chunks(x.d_chol, &mut chol.b);
                sum_squares(mean.w.as_flattened())
                    + sum_squares(&mean.b)
                    + sum_squares(chol.w.as_flattened())
                    + sum_squares(&chol.b)
            }
        }
    }
}

#[cfg(feature = "train")]
/// `sum x^2` in f64, in order.
pub(crate) fn sum_squares(x: &[f32]) -> f64 {
    x.iter().map(|&v| v as f64 * v as f64).sum()
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
    /// Gradient at the first hidden layer.
    pub d_h1: [[f32; H1]; B],
}

#[cfg(feature = "train")]
/// The actor's weights transposed (output-major), as the backward pass multiplies by them.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct ActorTransposed<const ACT: usize, const TRI: usize, const H1: usize, const H2: usize> {
    /// Mean head.
    pub mean: [[f32; H2]; ACT],
    /// Cholesky head.
    pub chol: [[f32; H2]; TRI],
    /// Second layer.
    pub l2: [[f32; H1]; H2],
}
