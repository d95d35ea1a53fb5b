//! What the learner asks of its two networks, so it can run with either form of each: the
//! two-layer MLPs ([`crate::actor::Actor`], [`crate::critic::Critic`]) or the residual,
//! layer-normalised networks ([`crate::residual`]).
//!
//! Every size stays a const generic: a network type fixes its widths, and the batch size of a
//! pass is the const parameter of its tape (`Tape<B>`). Training splits each backward pass as
//! the MLPs always did, so a batch held in chunks can be spread over threads: `backprop`
//! carries the output gradients of one chunk down through the network (rows are independent),
//! then `weight_grads` forms the weight gradients from every chunk's tape in blocks of
//! parameter rows handed to a [`crate::parallel::Parallel`] (blocks are independent; each sums
//! its rows in batch order), and returns the gradient's squared norm summed over the blocks in
//! order. So the bits never depend on the chunking or the threads.

use bytemuck::Zeroable;

use crate::gaussian::Gaussian;
use crate::obs_norm::InputNorm;
use crate::params::Params;
use crate::rng::Rng;
use crate::squash::MeanSquash;

#[cfg(feature = "train")]
use crate::config::MpoConfig;
#[cfg(feature = "train")]
use crate::parallel::Parallel;

/// Most chunks a batch may be held in (the weight gradients list one slice per chunk).
pub const MAX_CHUNKS: usize = 64;

/// A policy network for `OBS` observations and `ACT` actions (`TRI = ACT (ACT + 1) / 2`): the
/// Gaussian head's mean and raw Cholesky entries for a state. What a deployed controller and the
/// firmware run.
pub trait PolicyNet<const OBS: usize, const ACT: usize, const TRI: usize>:
    Params + Zeroable + Clone + Send + Sync + 'static
{
    /// The hidden widths: the two layers of an MLP, or a residual network's width and its
    /// blocks' inner width.
    const HIDDEN: [usize; 2];
    /// Residual blocks (0: an MLP).
    const BLOCKS: usize;

    /// Initialises in place so the initial policy is close to `N(0, init_std^2 I)` whatever
    /// the observation; the observation normalisation is the identity and the mean unbounded.
    fn init(&mut self, rng: &mut Rng, init_std: f32, std_floor: f32);
    /// The observation normalisation (never trained by gradients).
    fn input(&self) -> &InputNorm<OBS>;
    /// The observation normalisation, to refit.
    fn input_mut(&mut self) -> &mut InputNorm<OBS>;
    /// The mean's bound (never trained by gradients).
    fn squash(&self) -> &MeanSquash<ACT>;
    /// The mean's bound, to set.
    fn squash_mut(&mut self) -> &mut MeanSquash<ACT>;
    /// Head outputs for one state (normalised here): the squashed mean and the raw Cholesky
    /// entries.
    fn forward_one(&self, obs: &[f32; OBS], mean: &mut [f32; ACT], chol: &mut [f32; TRI]);
    /// The mean action for one state: what a deployed controller executes.
    fn mean_action(&self, obs: &[f32; OBS], action: &mut [f32; ACT]);
    /// Multiply-adds of one forward pass for one state.
    fn forward_macs() -> usize;

    /// The policy's distribution at one state.
    fn distribution(&self, obs: &[f32; OBS], std_floor: f32) -> Gaussian<ACT> {
        let mut m = [0f32; ACT];
        let mut c = [0f32; TRI];
        self.forward_one(obs, &mut m, &mut c);
        Gaussian::from_head(&m, &c, std_floor)
    }
}

#[cfg(feature = "train")]
/// What a policy's weight gradients read for a batch held in chunks (entry `c` of every list
/// is chunk `c`): the states, the chunks' tapes after `backprop`, and the head gradients.
pub struct PolicyGradInputs<'a, const OBS: usize, const ACT: usize, const TRI: usize, T> {
    /// States (normalised).
    pub obs: &'a [&'a [[f32; OBS]]],
    /// Each chunk's tape.
    pub tapes: &'a [&'a T],
    /// Gradients at the mean head's raw outputs.
    pub d_mean: &'a [&'a [[f32; ACT]]],
    /// Gradients at the Cholesky head's outputs.
    pub d_chol: &'a [&'a [[f32; TRI]]],
}

#[cfg(feature = "train")]
/// A policy network the learner trains.
pub trait PolicyTrain<const OBS: usize, const ACT: usize, const TRI: usize>:
    PolicyNet<OBS, ACT, TRI>
{
    /// Activations and backward scratch of a batch of `B` states.
    type Tape<const B: usize>: Zeroable + Send + Sync;
    /// The weights transposed, as `backprop` multiplies by them.
    type Transposed: Zeroable + Send + Sync;
    /// Whether [`PolicyTrain::project_weights`] projects anything (the learner refuses
    /// `weight_norm` for a network that does not).
    const PROJECTS: bool = false;

    /// SimbaV2's projection ([`crate::hypersphere`]) of the hidden layers' incoming weight
    /// vectors onto the unit sphere; the heads stay free. Nothing for a network without it.
    fn project_weights(&mut self) {}
    /// Head outputs for a batch of normalised states (the mean squashed, the Cholesky head
    /// raw), keeping the activations in `tape`.
    fn forward<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        tape: &mut Self::Tape<B>,
        mean: &mut [[f32; ACT]; B],
        chol: &mut [[f32; TRI]; B],
    );
    /// Fills `t` for `backprop`.
    fn transpose_into(&self, t: &mut Self::Transposed);
    /// Carries one chunk's head gradients (at the raw mean: see [`MeanSquash::backward_rows`])
    /// down through the network, into `tape`.
    fn backprop<const B: usize>(
        &self,
        tape: &mut Self::Tape<B>,
        d_mean: &[[f32; ACT]; B],
        d_chol: &[[f32; TRI]; B],
        t: &Self::Transposed,
    );
    /// Writes the gradient of `sum_n d_mean[n] . raw_mean[n] + d_chol[n] . chol[n]` with
    /// respect to every parameter into `grad` (block by block, spread by `par`) and returns
    /// its squared norm (the blocks' sums added in order).
    fn weight_grads<Par: Parallel, const B: usize>(
        grad: &mut Self,
        par: &Par,
        x: &PolicyGradInputs<'_, OBS, ACT, TRI, Self::Tape<B>>,
    ) -> f64;
    /// Multiply-adds of one state's backward pass (weight gradients, and input gradients of
    /// every layer but the first).
    fn backward_macs() -> usize;
    /// Hands `visit` each ReLU layer's activations in `tape` after a `forward` (rows of
    /// `width` units, the layer's rows one after another), first layer first: what the host
    /// measures dormant units on (`mpo_host::dormant`).
    fn relu_layers<const B: usize>(tape: &Self::Tape<B>, visit: &mut dyn FnMut(&[f32], usize));
}

#[cfg(feature = "train")]
/// What a critic's weight gradients read for a batch held in chunks (entry `c` of every list
/// is chunk `c`): the states and actions and the chunks' tapes after `backprop`.
pub struct ValueGradInputs<'a, const OBS: usize, const ACT: usize, T> {
    /// States (normalised).
    pub obs: &'a [&'a [[f32; OBS]]],
    /// Actions, as the critic saw them.
    pub act: &'a [&'a [[f32; ACT]]],
    /// Each chunk's tape.
    pub tapes: &'a [&'a T],
}

#[cfg(feature = "train")]
/// An action-value network `Q(s, a)` for `OBS` observations and `ACT` actions, scalar or
/// categorical ([`crate::value_head`]). Its first layer's observation part is computed once
/// per set of states (`state_part`) and reused for every set of actions there.
pub trait ValueNet<const OBS: usize, const ACT: usize>:
    Params + Zeroable + Clone + Send + Sync + 'static
{
    /// The hidden widths (as [`PolicyNet::HIDDEN`]).
    const HIDDEN: [usize; 2];
    /// Residual blocks (0: an MLP).
    const BLOCKS: usize;
    /// Outputs: 1 for a scalar critic, the atoms of a categorical one.
    const BINS: usize;
    /// The first layer's observation part for a batch of `B` states.
    type StatePart<const B: usize>: Zeroable + Send + Sync;
    /// Activations, outputs and backward scratch of a batch of `B` pairs.
    type Tape<const B: usize>: Zeroable + Send + Sync;
    /// The weights transposed, as `backprop` multiplies by them.
    type Transposed: Zeroable + Send + Sync;
    /// Whether [`ValueNet::project_weights`] projects anything.
    const PROJECTS: bool = false;

    /// Initialises in place.
    fn init(&mut self, rng: &mut Rng);
    /// As [`PolicyTrain::project_weights`]: the hidden layers onto the unit sphere, the output
    /// layer free.
    fn project_weights(&mut self) {}
    /// The first layer's observation part of a batch of states.
    fn state_part<const B: usize>(&self, obs: &[[f32; OBS]; B], part: &mut Self::StatePart<B>);
    /// `Q` of each row's action at the states of `part` (the expectation of a categorical
    /// head), filling `tape` for `loss` and `backprop`.
    fn values_from_state_part<const B: usize>(
        &self,
        part: &Self::StatePart<B>,
        act: &[[f32; ACT]; B],
        tape: &mut Self::Tape<B>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    );
    /// `Q(s_n, a_n)` for a batch, filling `tape`.
    fn values<const B: usize>(
        &self,
        obs: &[[f32; OBS]; B],
        act: &[[f32; ACT]; B],
        tape: &mut Self::Tape<B>,
        q: &mut [f32; B],
        cfg: &MpoConfig,
    );
    /// Each row's loss against its target `y[n]` (after `values` on the same tape, whose
    /// `q` it takes), and the loss's gradient at the outputs times `inv_b`, kept in `tape`.
    fn loss<const B: usize>(
        &self,
        tape: &mut Self::Tape<B>,
        q: &[f32; B],
        y: &[f32; B],
        inv_b: f32,
        cfg: &MpoConfig,
        loss: &mut [f32; B],
    );
    /// Fills `t` for `backprop`.
    fn transpose_into(&self, t: &mut Self::Transposed);
    /// Carries one chunk's output gradient (from `loss`) down through the network.
    fn backprop<const B: usize>(
        &self,
        tape: &mut Self::Tape<B>,
        t: &Self::Transposed,
        cfg: &MpoConfig,
    );
    /// Writes the gradient of the loss with respect to every parameter into `grad` (block by
    /// block, spread by `par`) and returns its squared norm (the blocks' sums in order).
    fn weight_grads<Par: Parallel, const B: usize>(
        grad: &mut Self,
        par: &Par,
        x: &ValueGradInputs<'_, OBS, ACT, Self::Tape<B>>,
        cfg: &MpoConfig,
    ) -> f64;
    /// Multiply-adds of one pair's forward pass.
    fn forward_macs() -> usize;
    /// Multiply-adds of the observation part alone.
    fn state_macs() -> usize;
    /// Multiply-adds of one pair's backward pass (weight gradients, and input gradients of
    /// every layer but the first).
    fn backward_macs() -> usize;
    /// As [`PolicyTrain::relu_layers`], after `values` with `cfg` (a layer norm and `tanh`
    /// first layer, `cfg.critic_layer_norm`, is not a ReLU layer and is not visited).
    fn relu_layers<const B: usize>(
        tape: &Self::Tape<B>,
        cfg: &MpoConfig,
        visit: &mut dyn FnMut(&[f32], usize),
    );
}

#[cfg(feature = "train")]
/// Weight-gradient rows per parameter block for a layer of `h` inputs: a multiple of the
/// kernel's 6-row tile, about eight blocks at a width of 256.
pub(crate) const fn block_rows(h: usize) -> usize {
    6 * h.div_ceil(48)
}

#[cfg(feature = "train")]
/// The slices `f(tape)` of every chunk, as the weight-gradient kernels take them.
pub fn chunk_slices<'a, T, R: 'a>(
    tapes: &[&'a T],
    f: impl Fn(&'a T) -> &'a [R],
) -> heapless::Vec<&'a [R], MAX_CHUNKS> {
    let mut v = heapless::Vec::new();
    for t in tapes {
        assert!(v.push(f(t)).is_ok(), "more than {MAX_CHUNKS} chunks");
    }
    v
}
