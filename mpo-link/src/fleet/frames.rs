//! The frames of the fleet protocol: a fixed header, then a fixed payload struct, then (for a
//! block of transitions) the records as `f32` words. Everything is `#[repr(C)]`, little-endian
//! plain data without padding, so iceoryx2 (a byte slice in shared memory) and zenoh (a byte
//! payload over the network) carry the same bytes, and a frame is built into and read from a
//! buffer sized once.

use bytemuck::{Pod, Zeroable};

use crate::messages::{CHUNK, ParamChunk};

/// First word of every frame ("MPOF").
pub const MAGIC: u32 = 0x464f_504d;
/// Protocol version; a frame of another version is ignored (and counted).
pub const VERSION: u32 = 1;
/// Most plants one learner takes (the width of [`Go::members`]).
pub const MAX_PLANTS: usize = 256;
/// Most transitions in one block.
pub const MAX_BLOCK: usize = 1000;

/// Plant to learner: asks to join (and to rejoin, after a learner restart or a drop).
pub const HELLO: u32 = 1;
/// Plant to learner: a block of transitions.
pub const BLOCK: u32 = 2;
/// Plant to learner: leaving (refused, stopped, or its environment failed).
pub const BYE: u32 = 3;
/// Learner to plant: accepted, with the plant's configuration.
pub const WELCOME: u32 = 16;
/// Learner to plant: refused, with why.
pub const REFUSE: u32 = 17;
/// Learner to plants: one block of a policy's parameters.
pub const PARAMS: u32 = 18;
/// Learner to plants: the next round may start (deterministic), or the learner's progress
/// (free-running).
pub const GO: u32 = 19;
/// Learner to plants: the run is over; exit.
pub const STOP: u32 = 20;
/// Learner to a plant: dropped (it missed its round, or hung): join again.
pub const DROPPED: u32 = 21;
/// Learner to plants: a learner is waiting for its plants to join (sent every half second
/// while it admits them). A plant that works for another incarnation of the run's learner
/// (one that died and was resumed) joins this one.
pub const ANNOUNCE: u32 = 22;

/// The header of every frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct Header {
    /// [`MAGIC`].
    pub magic: u32,
    /// [`VERSION`].
    pub version: u32,
    /// The frame's kind ([`HELLO`], ...).
    pub kind: u32,
    /// The plant it is from or for (`u32::MAX`: every plant).
    pub plant: u32,
    /// [`run_tag`] of the run's id: a frame of another run is ignored.
    pub run: u64,
    /// The sender's incarnation (a random number per process start): a plant or learner that
    /// restarted is told apart from its previous self.
    pub incarnation: u64,
    /// `CLOCK_MONOTONIC` at send, nanoseconds (same clock in every process of a host and in
    /// network namespaces of one host).
    pub t_send_ns: u64,
    /// Bytes after the header.
    pub len: u32,
    /// Zero.
    pub reserved: u32,
}

/// A learner's sizes and task, as a plant states them in its [`Hello`] and the learner checks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct Identity {
    /// The task's name, UTF-8, NUL-padded.
    pub task: [u8; 64],
    /// The task's hash (a task file's text and model; a built-in task's name), hex, NUL-padded.
    pub task_sha256: [u8; 64],
    /// The row's network variant, NUL-padded.
    pub net: [u8; 32],
    /// obs, act, actor widths (2), critic widths (2), batch, chunks, seq, M, N: the row's sizes.
    pub sizes: [u32; 11],
    /// The policy's scalar parameters.
    pub policy_len: u32,
    /// Replay capacity.
    pub replay: u64,
}

/// [`HELLO`]'s payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct Hello {
    /// What the plant runs.
    pub id: Identity,
    /// The learner incarnation it last worked for (0: none yet).
    pub learner: u64,
    /// Its process id (for the learner's log).
    pub pid: u32,
    /// Nonzero: the plant was started by the learner (its process is the learner's child).
    pub spawned: u32,
}

/// [`WELCOME`]'s payload: how the plant is to run.
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Welcome {
    /// The plant incarnation this answers (a WELCOME for another is ignored).
    pub plant_incarnation: u64,
    /// Environment resets to replay after creating the environment from `env_seed`: its
    /// random stream then continues where the plant's previous process (before a drop, or a
    /// learner's checkpoint) left it.
    pub episodes: u64,
    /// The collector stream's state to start from.
    pub collector: [u8; 32],
    /// The learner's environment steps when the plant joins.
    pub env_steps: u64,
    /// Warm-up steps of the run (uniform actions while the learner's step count is below).
    pub warmup_steps: u64,
    /// 0 deterministic, 1 free-running.
    pub mode: u32,
    /// Steps per block (between two looks for new parameters).
    pub block: u32,
    /// The training environment's seed.
    pub env_seed: u32,
    /// `noise_corr`.
    pub noise_corr: f32,
    /// 1: pink noise.
    pub noise_pink: u32,
    /// The policy's standard deviation floor.
    pub std_floor: f32,
    /// `schedule.action_penalty`.
    pub action_penalty: f32,
    /// Zero.
    pub reserved: u32,
}

/// [`REFUSE`]'s payload and the text of a [`BYE`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct Text {
    /// The plant incarnation it answers (REFUSE), UTF-8 why, NUL-padded.
    pub plant_incarnation: u64,
    /// Why.
    pub message: [u8; 248],
}

/// [`GO`]'s payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct Go {
    /// Deterministic: the round that may start; free-running: 0.
    pub round: u64,
    /// The policy version to act with (its parameters were sent before this frame).
    pub version: u64,
    /// The learner's environment steps when the round starts (a plant's step `j` of the
    /// round is global step `env_steps + rank * block + j`, rank = its place among the
    /// members).
    pub env_steps: u64,
    /// The plants of the round, one bit each.
    pub members: [u64; MAX_PLANTS / 64],
}

/// The head of a [`BLOCK`]'s payload; `count` records of `record_words(obs, act)` words follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct BlockHead {
    /// Deterministic: the round; free-running: the plant's block counter.
    pub round: u64,
    /// The policy version every action of the block was taken with (0: the warm-up's
    /// uniform actions, or the learner's initial policy).
    pub version: u64,
    /// Resets of the plant's environment so far (with those it replayed at its start: see
    /// [`Welcome::episodes`]).
    pub episodes: u64,
    /// The collector stream's state after the block.
    pub collector: [u8; 32],
    /// The newest parameter update's latency at this plant: learner send to assembled (ns).
    pub param_latency_ns: u64,
    /// Records.
    pub count: u32,
    /// Observation size of each record.
    pub obs: u32,
    /// Action size.
    pub act: u32,
    /// Bit 0: the plant is between episodes after the block.
    pub flags: u32,
}

/// Record flag: the transition starts an episode.
pub const FIRST: u32 = 1;
/// Record flag: the transition ends an episode.
pub const LAST: u32 = 2;
/// [`BlockHead::flags`]: the plant is between episodes after the block.
pub const AT_BOUNDARY: u32 = 1;

/// `f32` words per record: flags (as bits), obs, action, reward, next obs, discount,
/// log-probability.
pub const fn record_words(obs: usize, act: usize) -> usize {
    1 + obs + act + 1 + obs + 1 + 1
}

/// Bytes of a block frame of `count` records.
pub const fn block_len(obs: usize, act: usize, count: usize) -> usize {
    size_of::<Header>() + size_of::<BlockHead>() + 4 * count * record_words(obs, act)
}

/// Bytes of the largest frame the learner sends (a parameter block).
pub const MAX_DOWN: usize = size_of::<Header>() + size_of::<ParamChunk>();

const _: () = {
    assert!(size_of::<Header>() == 48);
    assert!(size_of::<Identity>() == 64 + 64 + 32 + 44 + 4 + 8);
    assert!(size_of::<Hello>() == size_of::<Identity>() + 16);
    assert!(size_of::<Welcome>() == 8 + 8 + 32 + 8 + 8 + 8 * 4);
    assert!(size_of::<Text>() == 256);
    assert!(size_of::<Go>() == 24 + MAX_PLANTS / 8);
    assert!(size_of::<BlockHead>() == 24 + 32 + 8 + 16);
    assert!(CHUNK == 4096);
};

/// A 64-bit tag of a run id (FNV-1a of its text): every frame carries it.
pub fn run_tag(run: &str) -> u64 {
    let mut h = crate::messages::CHECKSUM_SEED;
    for b in run.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Writes `s` NUL-padded into `field` (cut at a character boundary when too long).
pub fn put_text(field: &mut [u8], s: &str) {
    field.fill(0);
    let mut n = s.len().min(field.len());
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    field[..n].copy_from_slice(&s.as_bytes()[..n]);
}

/// The text of a NUL-padded field.
pub fn text_of(field: &[u8]) -> String {
    let end = field.iter().position(|&b| b == 0).unwrap_or(field.len());
    String::from_utf8_lossy(&field[..end]).into_owned()
}

/// Why a received frame was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bad {
    /// Shorter than its header or its kind's payload, or its `len` disagrees.
    Short,
    /// Not this protocol (magic or version).
    Protocol,
    /// Another run's.
    OtherRun,
}

/// Counters of frames not used, per [`Bad`] reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ignored {
    /// Malformed.
    pub short: u64,
    /// Another protocol or version.
    pub protocol: u64,
    /// Another run's.
    pub other_run: u64,
}

impl Ignored {
    /// Counts one.
    pub fn count(&mut self, b: Bad) {
        match b {
            Bad::Short => self.short += 1,
            Bad::Protocol => self.protocol += 1,
            Bad::OtherRun => self.other_run += 1,
        }
    }
}

/// Splits a received frame into its header and payload bytes, checking magic, version, run
/// and length.
pub fn parse(frame: &[u8], run: u64) -> Result<(Header, &[u8]), Bad> {
    let hl = size_of::<Header>();
    if frame.len() < hl {
        return Err(Bad::Short);
    }
    let h: Header = bytemuck::pod_read_unaligned(&frame[..hl]);
    if h.magic != MAGIC || h.version != VERSION {
        return Err(Bad::Protocol);
    }
    if h.run != run {
        return Err(Bad::OtherRun);
    }
    let body = &frame[hl..];
    if h.len as usize != body.len() {
        return Err(Bad::Short);
    }
    Ok((h, body))
}

/// The payload struct at the start of `body` (copied out: the bytes need not be aligned).
pub fn read<T: Pod>(body: &[u8]) -> Result<T, Bad> {
    if body.len() < size_of::<T>() {
        return Err(Bad::Short);
    }
    Ok(bytemuck::pod_read_unaligned(&body[..size_of::<T>()]))
}

/// Writes a frame of `kind` with payload `payload` (and `tail` bytes after it) into `buf`
/// (cleared first; its capacity is reused, so a buffer sized once never allocates).
pub fn write<T: Pod>(buf: &mut Vec<u8>, head: Header, payload: &T, tail: &[u8]) {
    buf.clear();
    let mut h = head;
    h.magic = MAGIC;
    h.version = VERSION;
    h.len = (size_of::<T>() + tail.len()) as u32;
    h.t_send_ns = crate::service::monotonic_ns();
    buf.extend_from_slice(bytemuck::bytes_of(&h));
    buf.extend_from_slice(bytemuck::bytes_of(payload));
    buf.extend_from_slice(tail);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_round_trip_and_other_runs_are_told_apart() {
        let run = run_tag("123-abc");
        let mut buf = Vec::new();
        let mut go: Go = Zeroable::zeroed();
        go.round = 7;
        go.members[1] = 5;
        let head = Header {
            kind: GO,
            plant: u32::MAX,
            run,
            incarnation: 9,
            ..Default::default()
        };
        write(&mut buf, head, &go, &[]);
        let (h, body) = parse(&buf, run).unwrap();
        assert_eq!((h.kind, h.incarnation), (GO, 9));
        assert_eq!(read::<Go>(body).unwrap(), go);
        assert_eq!(parse(&buf, run_tag("123-abd")), Err(Bad::OtherRun));
        assert_eq!(parse(&buf[..40], run), Err(Bad::Short));
        assert_eq!(parse(&buf[..buf.len() - 1], run), Err(Bad::Short));
        let mut bad = buf.clone();
        bad[4] = 2;
        assert_eq!(parse(&bad, run), Err(Bad::Protocol));
        assert_eq!(read::<Welcome>(body), Err(Bad::Short));
    }

    #[test]
    fn text_fields_are_cut_at_character_boundaries() {
        let mut f = [0u8; 5];
        put_text(&mut f, "abcdé");
        assert_eq!(text_of(&f), "abcd");
        put_text(&mut f, "ab");
        assert_eq!(text_of(&f), "ab");
    }
}
