//! The learner's scratch memory: one [`Chunk`] per batch chunk, so chunks can run on
//! different threads with nothing mutable shared, and the [`Grads`] every chunk reads.

// `derive(Zeroable)` repeats the structs' bounds on the type parameters their fields are.
#![allow(clippy::multiple_bound_locations)]

use bytemuck::Zeroable;

use crate::estep::EStepRows;
use crate::evaluation::TargetRows;
use crate::mstep::MStepRows;
use crate::nets::Passes;
use crate::network::{PolicyTrain, ValueNet};

/// Everything one batch chunk's rows need: the network passes' buffers and each phase's
/// rows.
#[derive(Zeroable)]
#[zeroable(bound = "")]
pub(super) struct Chunk<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> {
    /// Tapes, head outputs and critic values, used by one phase after another.
    pub passes: Passes<OBS, ACT, TRI, P, Q, BC>,
    /// Policy evaluation: targets and losses.
    pub eval: TargetRows<ACT, BC, L, N>,
    /// E-step: samples, values, weights.
    pub estep: EStepRows<ACT, BC, M>,
    /// M-step: loss terms and head gradients.
    pub mstep: MStepRows<ACT, TRI, BC>,
    /// With `clip_critic_actions`: the batch's actions clipped, as the critic's loss sees
    /// them, kept for the weight gradient (unused otherwise: the batch's own are read).
    pub critic_action: [[f32; ACT]; BC],
}

/// Gradients and transposed weights (shared, read by every chunk).
#[derive(Zeroable)]
#[zeroable(bound = "")]
pub(super) struct Grads<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
> {
    /// The actor's weight gradient.
    pub actor: P,
    /// The critic's weight gradient.
    pub critic: Q,
    /// The online actor's weights, transposed for its input gradients.
    pub at: P::Transposed,
    /// The online critic's weights, transposed likewise.
    pub ct: Q::Transposed,
}
