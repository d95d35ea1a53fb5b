//! The fixed-size messages exchanged over shared memory, and their validation.
//!
//! Every message is `#[repr(C)]`, `Copy`, free of pointers and of fixed size, so iceoryx2 can
//! place it in shared memory and both processes read the same bytes. The explicit `type_name`
//! makes the two sides agree on the type even when they were built separately (iceoryx2
//! otherwise compares `core::any::type_name`, which contains the crate path). The maxima are
//! generous so one message layout serves every task in the table; the lengths say how much of
//! each array is used, and validation checks them against the policy's real sizes.

use iceoryx2::prelude::ZeroCopySend;

/// Largest observation any task sends (hopper: 15, walker: 24).
pub const MAX_OBS: usize = 64;
/// Largest action any task uses (hopper: 4, walker: 6).
pub const MAX_ACT: usize = 8;
/// Scalars per parameter block: 16 KiB of payload, so a 256-256 hopper policy (73,486
/// parameters) takes 18 blocks.
pub const CHUNK: usize = 4096;
/// Most blocks one parameter generation may have (the subscriber's buffer and history hold
/// this many, so a controller that starts late still receives the newest complete set).
pub const MAX_BLOCKS: usize = 32;

/// Request flag: answer with a sample `mu + L z` for the noise `z` carried in the request, and
/// its log-probability (training). Without it the controller answers with the mean action.
pub const OBS_SAMPLE: u32 = 1;

/// Reply flag: the action is a sample and `log_prob` is its log-density.
pub const ACT_SAMPLED: u32 = 1;

/// One observation from the plant, asking for one action.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("mpo_link::ObsMsg/v1")]
#[repr(C)]
pub struct ObsMsg {
    /// Strictly increasing per plant; the reply must echo it.
    pub seq: u64,
    /// `CLOCK_MONOTONIC` at send, nanoseconds.
    pub t_send_ns: u64,
    /// Episode index (for logs; the controller does not interpret it).
    pub episode: u64,
    /// Step within the episode.
    pub step: u32,
    /// Used entries of `obs`; must equal the controller's policy input size.
    pub len: u32,
    /// `OBS_*` flags.
    pub flags: u32,
    /// Lower bound on the policy's standard deviations, used when sampling.
    pub std_floor: f32,
    /// The observation; entries past `len` are ignored.
    pub obs: [f32; MAX_OBS],
    /// Standard-normal noise for `OBS_SAMPLE` (the plant draws it, so a run through the
    /// controller consumes random numbers exactly like the in-process path).
    pub noise: [f32; MAX_ACT],
}

/// One action from the controller, answering the observation with the same `seq`.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("mpo_link::ActMsg/v1")]
#[repr(C)]
pub struct ActMsg {
    /// The request's sequence number.
    pub seq: u64,
    /// `CLOCK_MONOTONIC` when the controller took the observation, nanoseconds.
    pub t_recv_ns: u64,
    /// `CLOCK_MONOTONIC` when the controller sent this reply, nanoseconds.
    pub t_send_ns: u64,
    /// Parameter generation the action was computed with (0: the controller's initial one).
    pub generation: u64,
    /// Used entries of `action`.
    pub len: u32,
    /// `ACT_*` flags.
    pub flags: u32,
    /// `ln pi(a | s)` when sampled, else 0.
    pub log_prob: f32,
    /// Requests and parameter blocks the controller has rejected so far (so the plant can
    /// report the controller's view too).
    pub rejected: u32,
    /// The action; entries past `len` are zero.
    pub action: [f32; MAX_ACT],
}

/// One block of a parameter generation (policy update), in `Params` tensor order.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("mpo_link::ParamChunk/v1")]
#[repr(C)]
pub struct ParamChunk {
    /// Generation number, increasing per push; blocks of older generations are dropped.
    pub generation: u64,
    /// Checksum of the whole parameter vector (all blocks), verified after assembly.
    pub total_checksum: u64,
    /// Checksum of `payload[..len]`.
    pub checksum: u64,
    /// Total scalar count of the parameter vector (must equal the controller's policy).
    pub total_len: u32,
    /// This block's index, `0..count`.
    pub index: u32,
    /// Number of blocks of this generation.
    pub count: u32,
    /// Used entries of `payload`.
    pub len: u32,
    /// The scalars.
    pub payload: [f32; CHUNK],
}

// The zero value of every message is valid (all fields are integers and floats); building them
// zeroed avoids writing 16 KiB literals on the stack. They are also plain bytes (no padding:
// checked below), so a byte-stream transport (the Unix-socket baseline) can send them as is.
unsafe impl bytemuck::Zeroable for ObsMsg {}
unsafe impl bytemuck::Zeroable for ActMsg {}
unsafe impl bytemuck::Zeroable for ParamChunk {}
unsafe impl bytemuck::Pod for ObsMsg {}
unsafe impl bytemuck::Pod for ActMsg {}
unsafe impl bytemuck::Pod for ParamChunk {}
const _: () = {
    // Sum of the field sizes equals the struct size: no padding bytes.
    assert!(size_of::<ObsMsg>() == 3 * 8 + 4 * 4 + 4 * (MAX_OBS + MAX_ACT));
    assert!(size_of::<ActMsg>() == 4 * 8 + 4 * 4 + 4 * MAX_ACT);
    assert!(size_of::<ParamChunk>() == 3 * 8 + 4 * 4 + 4 * CHUNK);
};

/// FNV-1a over the bit patterns of `xs`, continuing from `h` (start with [`CHECKSUM_SEED`]).
///
/// Bits, not values: `-0.0` and `0.0` or two NaN payloads differ, and a corrupted block must
/// not pass because its floats compare equal.
pub fn checksum(mut h: u64, xs: &[f32]) -> u64 {
    for x in xs {
        for b in x.to_bits().to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}

/// FNV-1a offset basis.
pub const CHECKSUM_SEED: u64 = 0xcbf2_9ce4_8422_2325;

/// Why a message was rejected (each reason has its own counter).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reject {
    /// A length field does not match the policy's size (or exceeds the array).
    Length,
    /// A NaN or infinity among the used values.
    NonFinite,
    /// A sequence number that is not the expected one (stale reply or replay).
    Sequence,
    /// A parameter block whose checksum, index or shape is wrong.
    Corrupt,
}

/// Rejection counters, one per [`Reject`] reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rejections {
    /// Wrong lengths.
    pub length: u64,
    /// Non-finite values.
    pub non_finite: u64,
    /// Unexpected sequence numbers.
    pub sequence: u64,
    /// Corrupt parameter blocks or assemblies.
    pub corrupt: u64,
}

impl Rejections {
    /// Counts one rejection.
    pub fn count(&mut self, r: Reject) {
        match r {
            Reject::Length => self.length += 1,
            Reject::NonFinite => self.non_finite += 1,
            Reject::Sequence => self.sequence += 1,
            Reject::Corrupt => self.corrupt += 1,
        }
    }
    /// All rejections.
    pub fn total(&self) -> u64 {
        self.length + self.non_finite + self.sequence + self.corrupt
    }
}

fn all_finite(xs: &[f32]) -> bool {
    xs.iter().all(|x| x.is_finite())
}

impl ObsMsg {
    /// Checks the request against a policy with `obs_len` inputs and `act_len` outputs and
    /// returns the observation slice to feed it.
    pub fn validate(&self, obs_len: usize) -> Result<&[f32], Reject> {
        if self.len as usize != obs_len || obs_len > MAX_OBS {
            return Err(Reject::Length);
        }
        let obs = &self.obs[..obs_len];
        if !all_finite(obs) || !self.std_floor.is_finite() || self.std_floor < 0.0 {
            return Err(Reject::NonFinite);
        }
        if self.flags & OBS_SAMPLE != 0 && !all_finite(&self.noise) {
            return Err(Reject::NonFinite);
        }
        Ok(obs)
    }
}

impl ObsMsg {
    /// Writes an observation request (the plant's encoder): `obs` into the first `obs.len()`
    /// entries (the rest zero), and with `noise` the `OBS_SAMPLE` flag and the noise. The
    /// caller has checked the lengths against the policy and the values for finiteness.
    pub fn set_observation(&mut self, obs: &[f32], noise: Option<&[f32]>, std_floor: f32) {
        let n = obs.len();
        self.len = n as u32;
        self.obs[..n].copy_from_slice(obs);
        self.obs[n..].fill(0.0);
        self.noise = [0.0; MAX_ACT];
        self.flags = 0;
        self.std_floor = std_floor;
        if let Some(z) = noise {
            self.noise[..z.len()].copy_from_slice(z);
            self.flags = OBS_SAMPLE;
        }
    }
}

impl ActMsg {
    /// Checks a reply to request `seq` from a policy with `act_len` outputs.
    pub fn validate(&self, seq: u64, act_len: usize) -> Result<&[f32], Reject> {
        if self.seq != seq {
            return Err(Reject::Sequence);
        }
        if self.len as usize != act_len || act_len > MAX_ACT {
            return Err(Reject::Length);
        }
        let a = &self.action[..act_len];
        if !all_finite(a) || (self.flags & ACT_SAMPLED != 0 && !self.log_prob.is_finite()) {
            return Err(Reject::NonFinite);
        }
        Ok(a)
    }
}

impl ParamChunk {
    /// Checks one block's own consistency (not yet the assembled vector) against a policy with
    /// `total_len` parameters.
    pub fn validate(&self, total_len: usize) -> Result<&[f32], Reject> {
        let blocks = total_len.div_ceil(CHUNK);
        let expect_len = if (self.index as usize) + 1 == blocks {
            total_len - (blocks - 1) * CHUNK
        } else {
            CHUNK
        };
        if self.total_len as usize != total_len
            || self.count as usize != blocks
            || self.index >= self.count
            || self.len as usize != expect_len
        {
            return Err(Reject::Length);
        }
        let p = &self.payload[..self.len as usize];
        if checksum(CHECKSUM_SEED, p) != self.checksum {
            return Err(Reject::Corrupt);
        }
        if !all_finite(p) {
            return Err(Reject::NonFinite);
        }
        Ok(p)
    }
}

impl ParamChunk {
    /// Writes block `index` of generation `generation` of `policy`'s parameters (the plant's
    /// encoder): the scalars `index * CHUNK ..` in `Params` tensor order, the rest of the
    /// payload zero, the block's checksum, and `total_checksum` (the whole vector's, see
    /// [`checksum`]).
    pub fn set_block<P: mpo_core::params::Params>(
        &mut self,
        policy: &P,
        generation: u64,
        index: usize,
        total_checksum: u64,
    ) {
        let total = policy.len();
        let count = total.div_ceil(CHUNK);
        let len = CHUNK.min(total - index * CHUNK);
        // Skip to the block's start, then fill it from consecutive tensors.
        let (mut tensor, mut offset) = (0usize, index * CHUNK);
        while offset >= policy.tensor(tensor).len() {
            offset -= policy.tensor(tensor).len();
            tensor += 1;
        }
        let mut filled = 0;
        while filled < len {
            let t = policy.tensor(tensor);
            let take = (t.len() - offset).min(len - filled);
            self.payload[filled..filled + take].copy_from_slice(&t[offset..offset + take]);
            filled += take;
            offset += take;
            if offset == t.len() {
                tensor += 1;
                offset = 0;
            }
        }
        self.payload[len..].fill(0.0);
        self.generation = generation;
        self.total_checksum = total_checksum;
        self.checksum = checksum(CHECKSUM_SEED, &self.payload[..len]);
        self.total_len = total as u32;
        self.index = index as u32;
        self.count = count as u32;
        self.len = len as u32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(len: u32) -> ObsMsg {
        let mut m: ObsMsg = bytemuck::Zeroable::zeroed();
        m.len = len;
        m
    }

    #[test]
    fn obs_validation_rejects_bad_lengths_and_values() {
        assert!(obs(5).validate(5).is_ok());
        assert_eq!(obs(4).validate(5), Err(Reject::Length));
        assert_eq!(obs(99).validate(99), Err(Reject::Length));
        let mut m = obs(5);
        m.obs[4] = f32::NAN;
        assert_eq!(m.validate(5), Err(Reject::NonFinite));
        // Past `len` is ignored.
        let mut m = obs(5);
        m.obs[5] = f32::INFINITY;
        assert!(m.validate(5).is_ok());
        let mut m = obs(5);
        m.flags = OBS_SAMPLE;
        m.noise[7] = f32::NAN;
        assert_eq!(m.validate(5), Err(Reject::NonFinite));
    }

    #[test]
    fn act_validation_checks_sequence_first() {
        let mut a: ActMsg = bytemuck::Zeroable::zeroed();
        a.seq = 7;
        a.len = 4;
        assert!(a.validate(7, 4).is_ok());
        assert_eq!(a.validate(8, 4), Err(Reject::Sequence));
        assert_eq!(a.validate(7, 3), Err(Reject::Length));
        a.action[0] = f32::NEG_INFINITY;
        assert_eq!(a.validate(7, 4), Err(Reject::NonFinite));
    }

    #[test]
    fn chunk_checksum_catches_one_flipped_bit() {
        let mut c: Box<ParamChunk> = bytemuck::zeroed_box();
        let total = CHUNK + 10;
        c.total_len = total as u32;
        c.count = 2;
        c.index = 1;
        c.len = 10;
        c.payload[3] = 1.5;
        c.checksum = checksum(CHECKSUM_SEED, &c.payload[..10]);
        assert!(c.validate(total).is_ok());
        c.payload[3] = f32::from_bits(1.5f32.to_bits() ^ 1);
        assert_eq!(c.validate(total), Err(Reject::Corrupt));
        c.payload[3] = 1.5;
        c.len = 11;
        assert_eq!(c.validate(total), Err(Reject::Length));
    }
}
