//! A learner's compile-time sizes as data: what a row names, a checkpoint records and a
//! build instantiates ([`crate::spec`]).

use serde::{Deserialize, Serialize};

/// A learner's compile-time sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sizes {
    /// Observation size.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// The policy's hidden widths.
    pub actor: [usize; 2],
    /// The critic's hidden widths.
    pub critic: [usize; 2],
    /// Batch size `B` (rows per update).
    pub batch: usize,
    /// Chunks the batch is split into for threads (`B / chunks` rows each; results do not
    /// depend on it).
    pub chunks: usize,
    /// Longest replayed sequence (the limit of `mpo.n_step` with Retrace).
    pub seq: usize,
    /// E-step action samples per state `M`.
    pub m: usize,
    /// Next-action samples per next state `N` (policy-evaluation targets).
    pub n: usize,
    /// Replay capacity in transitions.
    pub replay_capacity: usize,
}

/// Largest observation or action size, hidden width, batch, sample count and replay a task
/// file may ask for: beyond them one instantiation would need more memory than a host has
/// (the replay alone is `2 obs + act + 4` floats a transition) or a build would take hours.
pub const LIMITS: Sizes = Sizes {
    obs: 1024,
    act: 64,
    actor: [4096, 4096],
    critic: [4096, 4096],
    batch: 4096,
    chunks: 64,
    seq: 64,
    m: 256,
    n: 256,
    replay_capacity: 10_000_000,
};

impl Sizes {
    /// The packed lower triangle of the policy's Cholesky factor: `act (act + 1) / 2`.
    pub const fn tri(&self) -> usize {
        self.act * (self.act + 1) / 2
    }

    /// Every size within [`LIMITS`] and at least 1, the batch a multiple of its chunks.
    pub fn check(&self) -> Result<(), String> {
        let l = &LIMITS;
        let fields: [(&str, usize, usize); 12] = [
            ("obs", self.obs, l.obs),
            ("act", self.act, l.act),
            ("actor[0]", self.actor[0], l.actor[0]),
            ("actor[1]", self.actor[1], l.actor[1]),
            ("critic[0]", self.critic[0], l.critic[0]),
            ("critic[1]", self.critic[1], l.critic[1]),
            ("batch", self.batch, l.batch),
            ("chunks", self.chunks, l.chunks),
            ("seq", self.seq, l.seq),
            ("m", self.m, l.m),
            ("n", self.n, l.n),
            ("replay", self.replay_capacity, l.replay_capacity),
        ];
        for (name, v, max) in fields {
            if v == 0 || v > max {
                return Err(format!("{name} = {v} must be in 1..={max}"));
            }
        }
        if !self.batch.is_multiple_of(self.chunks) {
            return Err(format!(
                "batch = {} must be a multiple of chunks = {}",
                self.batch, self.chunks
            ));
        }
        Ok(())
    }

    /// One line for messages: `obs 5, act 1, actor 64-64, critic 64-64, batch 128 in 2, seq 8,
    /// M 20, N 20, replay 100000`.
    pub fn describe(&self) -> String {
        format!(
            "obs {}, act {}, actor {}-{}, critic {}-{}, batch {} in {}, seq {}, M {}, N {}, replay {}",
            self.obs,
            self.act,
            self.actor[0],
            self.actor[1],
            self.critic[0],
            self.critic[1],
            self.batch,
            self.chunks,
            self.seq,
            self.m,
            self.n,
            self.replay_capacity
        )
    }

    /// The line of `sizes/local.toml` that asks the build for these sizes.
    pub fn toml_line(&self) -> String {
        format!(
            "{{ obs = {}, act = {}, actor = [{}, {}], critic = [{}, {}], batch = {}, chunks = {}, seq = {}, m = {}, n = {}, replay_capacity = {} }}",
            self.obs,
            self.act,
            self.actor[0],
            self.actor[1],
            self.critic[0],
            self.critic[1],
            self.batch,
            self.chunks,
            self.seq,
            self.m,
            self.n,
            self.replay_capacity
        )
    }
}
