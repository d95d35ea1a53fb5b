//! A fleet: many plants, one learner. Each plant steps its own environment with the newest
//! policy it has and sends its transitions in blocks; the learner inserts them into its replay,
//! learns, and sends the policy's parameters back. This module is the link: the frames
//! ([`frames`]) and the two ends of a transport, over iceoryx2 between processes of a host
//! ([`ipc`]) or over zenoh between hosts (`zenoh`, with the `zenoh` feature). What a plant and
//! the learner do with the frames (the schedules, membership, faults) is `mpo-host`'s.
//!
//! A transport only moves whole frames: the learner broadcasts (every plant receives every
//! frame sent down, and keeps those for it or for all), the plants send up. Frames carry the
//! run's tag, so traffic of another run that reaches an endpoint is counted and dropped.

use core::time::Duration;

pub mod frames;
pub mod ipc;

use crate::service::LinkError;

/// The learner's end of a transport.
pub trait LearnerPort {
    /// Sends one frame to every plant.
    fn send_down(&mut self, frame: &[u8]) -> Result<(), LinkError>;
    /// Hands every frame received since the last call to `f`; returns how many.
    fn recv_up(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError>;
    /// Sleeps until a frame may have arrived or `timeout` passed.
    fn wait(&mut self, timeout: Duration);
    /// Clears what dead plants left registered (after a plant died).
    fn cleanup_dead(&mut self) {}
    /// A short name for logs (`iceoryx2`, `zenoh`).
    fn name(&self) -> &'static str;
}

/// A plant's end of a transport.
pub trait PlantPort {
    /// Sends one frame to the learner.
    fn send_up(&mut self, frame: &[u8]) -> Result<(), LinkError>;
    /// Hands every frame received since the last call to `f`; returns how many.
    fn recv_down(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError>;
    /// Sleeps until a frame may have arrived or `timeout` passed.
    fn wait(&mut self, timeout: Duration);
}
