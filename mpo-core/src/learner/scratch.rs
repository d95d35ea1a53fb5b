//! The learner's scratch memory: one [`Chunk`] per batch chunk, so chunks can run on
//! different threads with nothing mutable shared, and the [`Grads`] every chunk reads.

use bytemuck::Zeroable;

use crate::actor::{Actor, ActorTransposed};
use crate::critic::{Critic, CriticTransposed};
use crate::estep::EStepRows;
use crate::evaluation::TargetRows;
use crate::mstep::MStepRows;
use crate::nets::Passes;

/// Everything one batch chunk's rows need: the network passes' buffers and each phase's
/// rows.
#[derive(Zeroable)]
pub(super) struct Chunk<
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const L: usize,
    const M: usize,
    const N: usize,
> {
    /// Tapes, head outputs and critic values, used by one phase after another.
    pub passes: Passes<ACT, TRI, AH1, AH2, QH1, QH2, BC>,
    /// Policy evaluation: targets and residuals.
    pub eval: TargetRows<ACT, BC, L, N>,
    /// E-step: samples, values, weights.
    pub estep: EStepRows<ACT, BC, M>,
    /// M-step: loss terms and head gradients.
    pub mstep: MStepRows<ACT, TRI, BC>,
    /// With `clip_critic_actions`: the batch's actions clipped, as the critic's loss sees
    /// them, kept for the weight gradient (unused otherwise: the batch's own are read).
    pub critic_action: [[f32; ACT]; BC],
    /// The critic loss's gradient at the online critic's outputs.
    pub dq: [[f32; 1]; BC],
}

/// Gradients and transposed weights (shared, read by every chunk).
#[derive(Zeroable)]
pub(super) struct Grads<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
> {
    /// The actor's weight gradient.
    pub actor: Actor<OBS, ACT, TRI, AH1, AH2>,
    /// The critic's weight gradient.
    pub critic: Critic<OBS, ACT, QH1, QH2>,
    /// The online actor's weights, transposed for its input gradients.
    pub at: ActorTransposed<ACT, TRI, AH1, AH2>,
    /// The online critic's weights, transposed likewise.
    pub ct: CriticTransposed<QH1, QH2>,
}
