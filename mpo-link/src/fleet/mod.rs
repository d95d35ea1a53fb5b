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
#[cfg(feature = "zenoh")]
pub mod zenoh;

use crate::service::LinkError;

/// Where a fleet's zenoh link goes (`--fleet-listen` of the learner, `--fleet-connect` of a
/// plant) and its certificates. Plain data, in every build; only a build with the `zenoh`
/// feature can open it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Remote {
    /// zenoh endpoints: `tcp/ADDR:PORT`, or `tls/ADDR:PORT` with [`Remote::tls`].
    pub endpoints: Vec<String>,
    /// Mutual TLS: both sides present a certificate signed by the same CA.
    pub tls: Option<TlsFiles>,
    /// A plant: how long it tries to reach the learner before giving up (a refused TLS
    /// handshake is retried until then too).
    pub connect_timeout: Duration,
}

/// The PEM files of one side of a mutual-TLS link.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TlsFiles {
    /// The CA certificate that signs both sides' certificates (the only one trusted).
    pub ca: std::path::PathBuf,
    /// This side's certificate (the learner's names the address plants connect to).
    pub cert: std::path::PathBuf,
    /// This side's private key.
    pub key: std::path::PathBuf,
}

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
