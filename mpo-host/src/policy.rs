//! A trained policy behind sizes known only at run time: what the inference commands (`eval`,
//! `render`, `run`, `export`) use, so they are compiled once, not once per row, and load only
//! the actor of a checkpoint (never a learner).

use mpo_core::actor::Actor;
use mpo_core::params::Params;

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
    /// Hidden widths.
    fn hidden(&self) -> [usize; 2];
    /// Scalar parameters (what the firmware keeps in flash, 4 bytes each).
    fn parameters(&self) -> usize;
    /// The policy as Rust source for the firmware (`mpo_core::export`), with `origin` in its
    /// header comment.
    fn firmware_source(&self, origin: &str) -> String;
    /// Pushes the policy's parameters to a controller process.
    fn push(&self, link: &mut crate::link::Link) -> Result<(), mpo_link::LinkError>;
}

impl<const OBS: usize, const ACT: usize, const TRI: usize, const H1: usize, const H2: usize> Policy
    for Actor<OBS, ACT, TRI, H1, H2>
{
    fn obs_dim(&self) -> usize {
        OBS
    }
    fn act_dim(&self) -> usize {
        ACT
    }
    fn mean_action(&self, obs: &[f32], action: &mut [f32]) {
        let obs: &[f32; OBS] = obs.try_into().expect("observation of the policy's size");
        let action: &mut [f32; ACT] = action.try_into().expect("action of the policy's size");
        Actor::mean_action(self, obs, action);
    }
    fn hidden(&self) -> [usize; 2] {
        [H1, H2]
    }
    fn parameters(&self) -> usize {
        self.len()
    }
    fn firmware_source(&self, origin: &str) -> String {
        let mut src = String::new();
        mpo_core::export::write_actor_source(self, origin, &mut src)
            .expect("formatting into a String cannot fail");
        src
    }
    fn push(&self, link: &mut crate::link::Link) -> Result<(), mpo_link::LinkError> {
        link.push(self)
    }
}

/// The online policy of a verified checkpoint whose sizes are these (the instance's
/// `policy`; the caller has matched the checkpoint's sizes to the instance).
pub fn load<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
>(
    v: &Verified,
) -> Result<Box<dyn Policy>, CheckpointError> {
    let mut actor: Box<Actor<OBS, ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    v.load_actor(actor.as_mut())?;
    Ok(actor)
}

/// Serves a policy of these sizes in the controller process (the instance's `serve`).
pub fn serve<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
>(
    opts: &mpo_link::controller::ControllerOptions,
    ready: &mut dyn FnMut(),
) -> Result<mpo_link::controller::ControllerStats, mpo_link::LinkError> {
    mpo_link::controller::serve::<OBS, ACT, TRI, H1, H2>(opts, ready)
}
