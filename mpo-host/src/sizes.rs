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
    /// The policy's hidden widths: the two layers of an MLP, or with `actor_blocks > 0` a
    /// residual network's width and its blocks' inner width.
    pub actor: [usize; 2],
    /// The critic's hidden widths (as `actor`, with `critic_blocks`).
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
    /// Residual blocks of the policy (`mpo_core::residual`); 0 (the default, not written) =
    /// the two-layer MLP.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub actor_blocks: usize,
    /// Residual blocks of the critic; 0 (the default, not written) = the two-layer MLP.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub critic_blocks: usize,
    /// The critic's outputs: 1 (the default, not written) = a value; more = the atoms of a
    /// categorical value (`mpo_core::value_head`).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub bins: usize,
}

fn is_zero(x: &usize) -> bool {
    *x == 0
}

fn is_one(x: &usize) -> bool {
    *x == 1
}

fn one() -> usize {
    1
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
    actor_blocks: 8,
    critic_blocks: 8,
    bins: 1024,
};

impl Sizes {
    /// The packed lower triangle of the policy's Cholesky factor: `act (act + 1) / 2`.
    pub const fn tri(&self) -> usize {
        self.act * (self.act + 1) / 2
    }

    /// The MLP sizes of the fields before the residual networks (no blocks, a scalar critic).
    pub const fn mlp(
        obs: usize,
        act: usize,
        actor: [usize; 2],
        critic: [usize; 2],
        [batch, chunks, seq, m, n, replay_capacity]: [usize; 6],
    ) -> Self {
        Self {
            obs,
            act,
            actor,
            critic,
            batch,
            chunks,
            seq,
            m,
            n,
            replay_capacity,
            actor_blocks: 0,
            critic_blocks: 0,
            bins: 1,
        }
    }

    /// Every size within [`LIMITS`] and at least 1 (blocks at least 0), the batch a multiple
    /// of its chunks.
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
        for (name, v, max) in [
            ("actor_blocks", self.actor_blocks, l.actor_blocks),
            ("critic_blocks", self.critic_blocks, l.critic_blocks),
        ] {
            if v > max {
                return Err(format!("{name} = {v} must be in 0..={max}"));
            }
        }
        if self.bins == 0 || self.bins > l.bins {
            return Err(format!(
                "bins = {} must be 1 (a value) or in 2..={} (the atoms of a categorical value)",
                self.bins, l.bins
            ));
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
    /// M 20, N 20, replay 100000` (a residual network as `actor 128/512 x 1`, a categorical
    /// critic with `, bins 101` after it).
    pub fn describe(&self) -> String {
        let net = |w: [usize; 2], blocks: usize| match blocks {
            0 => format!("{}-{}", w[0], w[1]),
            d => format!("{}/{} x {d}", w[0], w[1]),
        };
        let bins = match self.bins {
            1 => String::new(),
            k => format!(", bins {k}"),
        };
        format!(
            "obs {}, act {}, actor {}, critic {}{bins}, batch {} in {}, seq {}, M {}, N {}, replay {}",
            self.obs,
            self.act,
            net(self.actor, self.actor_blocks),
            net(self.critic, self.critic_blocks),
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
        let mut extra = String::new();
        if self.actor_blocks > 0 {
            extra += &format!(", actor_blocks = {}", self.actor_blocks);
        }
        if self.critic_blocks > 0 {
            extra += &format!(", critic_blocks = {}", self.critic_blocks);
        }
        if self.bins != 1 {
            extra += &format!(", bins = {}", self.bins);
        }
        format!(
            "{{ obs = {}, act = {}, actor = [{}, {}], critic = [{}, {}], batch = {}, chunks = {}, seq = {}, m = {}, n = {}, replay_capacity = {}{extra} }}",
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
