//! Residual, layer-normalised networks in SimBa's form (Lee et al., 2025, "SimBa: Simplicity
//! Bias for Scaling Up Parameters in Deep Reinforcement Learning"): a linear embedding of the
//! input, `D` pre-LayerNorm residual blocks `x <- x + W_down relu(W_up LN(x))` of width `W` and
//! inner width `F`, and a final LayerNorm before the heads. The normalisation keeps every
//! block's input at one scale whatever the observations or the depth, and the skip path keeps
//! the gradient of every block the identity's plus its own, which is what lets these networks
//! grow without the MLP's loss of trainability.
//!
//! [`Trunk`] is the part the policy ([`ResidualActor`]) and the critic ([`ResidualCritic`])
//! share: the blocks and the final norm, after each network's own embedding. Every operation is
//! a kernel of [`crate::linear`] (fixed fma order), a layer norm with eight-lane sums
//! ([`crate::layer_norm`]), a ReLU or an add, so a batch gives the bits of one state at a time,
//! on every build and thread count. Training splits the backward pass as the MLPs do
//! ([`crate::network`]): [`Trunk::backprop`] per chunk, then [`TrunkPart`]s by parameter
//! blocks.
//!
//! Per row, block `d` computes `xhat_d, rstd_d = norm(x_d)`, `y_d = g_d xhat_d + b_d`,
//! `h_d = relu(up_d(y_d))`, and `x_(d+1) = (x_d + b_down) + h_d W_down` (the bias added first,
//! then one fma per inner unit in ascending order). Backward, with `g` the gradient at
//! `x_(d+1)`: `d_h = (g W_down^T) [h > 0]`, `d_y = d_h W_up^T`, and the gradient at `x_d` is
//! `g + norm_backward(d_y)`.
//!
//! What these networks take from SimbaV2 (Lee et al., 2025, "Hyperspherical Normalization for
//! Scalable Deep Reinforcement Learning"), and what not. Taken, as an option: its weights on
//! the unit sphere ([`crate::hypersphere`], `MpoConfig::weight_norm`), which holds a step at
//! one fraction of a weight for the whole run. Not taken: its features projected onto the
//! sphere after every layer, its residual as a learnt interpolation `x + alpha (f(x) - x)`
//! re-projected, and its learnt scalers. Here every weight layer already reads a layer norm's
//! output (each block's pre-norm, the final norm before the heads), which, like the
//! projection, removes the scale of what it normalises; what differs is the mean subtraction,
//! the gain and bias in place of the scalers, and the additive residual. Taking the rest would
//! be a second network family (other parameters, checkpoints, export and firmware code) whose
//! worth only long runs could show.

mod actor;
#[cfg(feature = "train")]
mod critic;
mod trunk;

pub use actor::ResidualActor;
#[cfg(feature = "train")]
pub use actor::ResidualActorTransposed;
#[cfg(feature = "train")]
pub use critic::{ResidualCritic, ResidualCriticTape, ResidualCriticTransposed};
pub use trunk::{Block, MAX_PARTS, Trunk, TrunkTape};
#[cfg(feature = "train")]
pub use trunk::{TrunkPart, TrunkTransposed};
