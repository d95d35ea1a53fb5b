//! A trained policy behind sizes known only at run time: what the inference commands (`eval`,
//! `render`, `run`, `export`) use, so they are compiled once, not once per row, and load only
//! the actor of a checkpoint (never a learner).

use mpo_core::actor::Actor;
use mpo_core::network::PolicyNet;
use mpo_core::params::Params;
use mpo_core::residual::ResidualActor;

use crate::checkpoint::{CheckpointError, Verified};

/// A policy network of some sizes.
pub trait Policy {
    /// Observation size.
    fn obs_dim(&self) -> usize;
    /// Action size.
    fn act_dim(&self) -> usize;
    /// The mean action for one observation (`obs.len() == obs_dim()`, `action.len() ==
    /// act_dim()`): what a deployed controller executes.
    fn mean_action(&self, obs: &[f32], action: &mut [f32]);
    /// Hidden widths (an MLP's two layers, or a residual network's width and inner width).
    fn hidden(&self) -> [usize; 2];
    /// Residual blocks (0: an MLP).
    fn blocks(&self) -> usize;
    /// Scalar parameters (what the firmware keeps in flash, 4 bytes each).
    fn parameters(&self) -> usize;
    /// The policy as Rust source for the firmware (`mpo_core::export`), with `origin` in its
    /// header comment.
    fn firmware_source(&self, origin: &str) -> String;
    /// Pushes the policy's parameters to a controller process.
    fn push(&self, link: &mut crate::link::Link) -> Result<(), mpo_link::LinkError>;
}

/// [`Policy`] for a network of the core's, given how it writes its firmware source.
macro_rules! policy_for {
    ($ty:ty, [$($g:ident),*], $write:path) => {
        impl<const OBS: usize, const ACT: usize, const TRI: usize, $(const $g: usize),*> Policy
            for $ty
        {
            fn obs_dim(&self) -> usize {
                OBS
            }
            fn act_dim(&self) -> usize {
                ACT
            }
            fn mean_action(&self, obs: &[f32], action: &mut [f32]) {
                let obs: &[f32; OBS] = obs.try_into().expect("observation of the policy's size");
                let action: &mut [f32; ACT] =
                    action.try_into().expect("action of the policy's size");
                PolicyNet::mean_action(self, obs, action);
            }
            fn hidden(&self) -> [usize; 2] {
                <Self as PolicyNet<OBS, ACT, TRI>>::HIDDEN
            }
            fn blocks(&self) -> usize {
                <Self as PolicyNet<OBS, ACT, TRI>>::BLOCKS
            }
            fn parameters(&self) -> usize {
                self.len()
            }
            fn firmware_source(&self, origin: &str) -> String {
                let mut src = String::new();
                $write(self, origin, &mut src).expect("formatting into a String cannot fail");
                src
            }
            fn push(&self, link: &mut crate::link::Link) -> Result<(), mpo_link::LinkError> {
                link.push(self)
            }
        }
    };
}

policy_for!(
    Actor<OBS, ACT, TRI, H1, H2>,
    [H1, H2],
    mpo_core::export::write_actor_source
);
policy_for!(
    ResidualActor<OBS, ACT, TRI, W, F, D>,
    [W, F, D],
    mpo_core::export::write_residual_actor_source
);

/// The online policy of a verified checkpoint whose sizes are these (the instance's
/// `policy`; the caller has matched the checkpoint's sizes to the instance).
pub fn load<const OBS: usize, const ACT: usize, const TRI: usize, P>(
    v: &Verified,
) -> Result<Box<dyn Policy>, CheckpointError>
where
    P: PolicyNet<OBS, ACT, TRI> + Policy,
{
    let mut actor: Box<P> = bytemuck::zeroed_box();
    v.load_actor(actor.as_mut())?;
    Ok(actor)
}

/// Serves a policy of these sizes in the controller process (the instance's `serve`).
pub fn serve<const OBS: usize, const ACT: usize, const TRI: usize, P: PolicyNet<OBS, ACT, TRI>>(
    opts: &mpo_link::controller::ControllerOptions,
    ready: &mut dyn FnMut(),
) -> Result<mpo_link::controller::ControllerStats, mpo_link::LinkError> {
    mpo_link::controller::serve_policy::<OBS, ACT, TRI, P>(opts, ready)
}
