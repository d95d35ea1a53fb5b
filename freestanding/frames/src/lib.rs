//! The byte-stream protocol between a plant on the host and a trainer on a device (a serial
//! line in the field; a pipe here): framed, checksummed messages, no platform.
//!
//! A frame is `kind, seq, len (u16 LE), payload (len bytes), CRC-32 (LE)`, the CRC (IEEE
//! 802.3, as zlib's `crc32`) taken over everything before it, sent COBS-encoded (consistent
//! overhead byte stuffing: no zero byte inside) and ended by a zero byte. Whatever a damaged
//! line does to a frame (flipped bits, lost or extra bytes), the receiver finds the start of
//! the next one at the next zero byte. Every kind has one payload length (given the
//! observation and action sizes), which the receiver checks with the checksum. [`Receiver`]
//! takes bytes one at a time and yields whole, verified frames, counting the rejected ones.
//!
//! The messages (docs/device.md has the table):
//!
//! | host -> device | payload | device replies |
//! |---|---|---|
//! | `HELLO` | none | `INFO`: protocol version, OBS, ACT, parameter count, replay capacity |
//! | `START` | the learner's configuration, the schedule, the seed | `ACK` |
//! | `BEGIN` | first observation of an episode | `ACTION` |
//! | `STEP` | reward, discount, last (u8), next observation | `ACTION` (the next state's), or `ACK` after the last step of an episode |
//! | `EVAL` | an observation | `ACTION` (the mean action; nothing changes) |
//! | `PARAMS` | none | `PARAMS`: counters, then the online actor's and critic's parameters |
//!
//! Every request carries a sequence number (`seq`, one byte, counting up) that its reply
//! echoes. A request with the sequence number of the one before is a repeat: the device sends
//! its last reply again and changes nothing. So the host sends a request again, same number,
//! until a verified reply with that number arrives, whatever was lost or damaged on the way,
//! and no request is ever applied twice. A frame the device cannot use (bad checksum, unknown
//! kind, wrong length, a command out of order, a value out of range) gets `ERROR` with a code
//! and the device's counters; nothing else changes. `ACTION` carries the action and the
//! behaviour log-probability; `ACK`, `ERROR` and `PARAMS` carry the counters (environment
//! steps, updates, frames rejected, repeats answered).
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

/// The byte that ends every frame (and appears nowhere inside one).
pub const DELIMITER: u8 = 0;
/// Protocol version reported in `INFO`.
pub const VERSION: u16 = 1;
/// Bytes around a payload before encoding: kind, sequence number, length, checksum.
pub const HEADER: usize = 8;

/// The encoded size of a frame with `len` payload bytes, at most (COBS adds one byte per 254,
/// plus one; then the delimiter).
pub const fn encoded_max(len: usize) -> usize {
    let raw = len + HEADER;
    raw + raw / 254 + 2
}

/// Message kinds. Host to device below `0x80`, device to host from `0x80`.
pub mod kind {
    /// Host: who are you?
    pub const HELLO: u8 = 0x01;
    /// Host: configuration, schedule and seed; start a fresh run.
    pub const START: u8 = 0x02;
    /// Host: the first observation of an episode.
    pub const BEGIN: u8 = 0x03;
    /// Host: the outcome of the last action.
    pub const STEP: u8 = 0x04;
    /// Host: the mean action for an observation (evaluation).
    pub const EVAL: u8 = 0x05;
    /// Host: send the parameters.
    pub const PARAMS: u8 = 0x06;
    /// Device: sizes and version.
    pub const INFO: u8 = 0x81;
    /// Device: done, with counters.
    pub const ACK: u8 = 0x82;
    /// Device: an action.
    pub const ACTION: u8 = 0x83;
    /// Device: counters and parameters.
    pub const PARAMS_REPLY: u8 = 0x86;
    /// Device: the last frame could not be used.
    pub const ERROR: u8 = 0x8F;
}

/// Why a frame was not used (the `ERROR` code).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Fault {
    /// The checksum did not match.
    Checksum = 1,
    /// A kind no side sends.
    UnknownKind = 2,
    /// The length does not match the kind.
    Length = 3,
    /// A command the device cannot take now (e.g. `STEP` before `START`).
    OutOfOrder = 4,
    /// A value out of range (e.g. a non-finite observation, an invalid configuration).
    Invalid = 5,
}

impl Fault {
    /// From an `ERROR` code.
    pub fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            1 => Self::Checksum,
            2 => Self::UnknownKind,
            3 => Self::Length,
            4 => Self::OutOfOrder,
            5 => Self::Invalid,
            _ => return None,
        })
    }
}

/// The frames' CRC-32: IEEE 802.3, reflected, as zlib's `crc32` (`CRC_32_ISO_HDLC` of the
/// `crc` crate, whose table is built at compile time: no_std, no allocation).
static CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// CRC-32 of the frames: a running value.
#[derive(Clone)]
pub struct Crc(crc::Digest<'static, u32>);

impl Crc {
    /// A fresh checksum.
    pub const fn new() -> Self {
        Self(CRC32.digest())
    }
    /// Adds bytes.
    pub fn update(&mut self, bytes: &[u8]) {
        self.0.update(bytes);
    }
    /// The checksum of what was added.
    pub fn finish(&self) -> u32 {
        self.0.clone().finalize()
    }
}

impl Default for Crc {
    fn default() -> Self {
        Self::new()
    }
}

/// The payload length of each kind for a plant of `obs` observations and `act` actions, and
/// `params` learner parameters (actor then critic); `None` for an unknown kind.
pub fn payload_len(kind: u8, obs: usize, act: usize, params: usize) -> Option<usize> {
    Some(match kind {
        kind::HELLO | kind::PARAMS => 0,
        kind::START => START_LEN,
        kind::BEGIN | kind::EVAL => 4 * obs,
        kind::STEP => 9 + 4 * obs,
        kind::INFO => 2 + 2 + 2 + 4 + 4,
        kind::ACK => COUNTERS_LEN,
        kind::ACTION => 4 * act + 4,
        kind::PARAMS_REPLY => COUNTERS_LEN + 4 * params,
        kind::ERROR => 1 + COUNTERS_LEN,
        _ => return None,
    })
}

/// The counters: environment steps (u64), updates (u64), frames rejected (u32), repeated
/// requests answered again (u32).
pub const COUNTERS_LEN: usize = 8 + 8 + 4 + 4;

/// The device's counters, as `ACK`, `ERROR` and `PARAMS` carry them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Environment steps observed.
    pub env_steps: u64,
    /// Learner updates done.
    pub updates: u64,
    /// Frames rejected (any [`Fault`]).
    pub rejected: u32,
    /// Repeated requests answered with the last reply again.
    pub resent: u32,
}

impl Counters {
    /// As bytes.
    pub fn encode(&self, out: &mut [u8; COUNTERS_LEN]) {
        out[0..8].copy_from_slice(&self.env_steps.to_le_bytes());
        out[8..16].copy_from_slice(&self.updates.to_le_bytes());
        out[16..20].copy_from_slice(&self.rejected.to_le_bytes());
        out[20..24].copy_from_slice(&self.resent.to_le_bytes());
    }
    /// From bytes.
    pub fn decode(b: &[u8]) -> Self {
        Self {
            env_steps: u64_at(b, 0),
            updates: u64_at(b, 8),
            rejected: u32_at(b, 16),
            resent: u32_at(b, 20),
        }
    }
}

/// `START`'s payload: the schedule (warm-up, update interval, updates per interval: u64 each;
/// n-step: u32), the seed (u32), then [`CONFIG_LEN`] bytes of configuration.
pub const START_LEN: usize = 8 + 8 + 8 + 4 + 4 + CONFIG_LEN;

/// The learner's configuration on the wire: [`CONFIG_FIELDS`] 32-bit little-endian words in
/// the order of `mpo_core::config::MpoConfig::to_words` (floats as their bits, flags as 0/1,
/// the f64 E-step tolerance as two words). This crate does not depend on the core; the host and
/// the trainer assert at compile time that the two counts agree.
pub const CONFIG_LEN: usize = 4 * CONFIG_FIELDS;
/// Words of the configuration.
pub const CONFIG_FIELDS: usize = 36;

/// Reads a little-endian u32 at `at`.
pub fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Reads a little-endian u64 at `at`.
pub fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut x = [0u8; 8];
    x.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(x)
}

/// Reads a little-endian f32 at `at`.
pub fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

/// The one NaN a frame carries: quiet, sign clear, no payload (`0x7fc0_0000`).
pub const CANONICAL_NAN: u32 = 0x7fc0_0000;

/// `x` as the 4 little-endian bytes a frame carries, every NaN as [`CANONICAL_NAN`]. The NaN an
/// invalid operation makes differs between instruction sets (x86's has its sign bit set, Arm's
/// does not; propagated NaNs keep payloads that depend on operand order), so without this a
/// device on another CPU would send other bytes for the same computation. Every float either
/// side sends goes through here.
pub fn f32_bytes(x: f32) -> [u8; 4] {
    if x.is_nan() {
        CANONICAL_NAN.to_le_bytes()
    } else {
        x.to_le_bytes()
    }
}

/// Writes `values` as little-endian f32 into `out` (4 bytes each; NaNs canonical:
/// [`f32_bytes`]).
pub fn put_f32s(values: &[f32], out: &mut [u8]) {
    for (o, v) in out.chunks_exact_mut(4).zip(values) {
        o.copy_from_slice(&f32_bytes(*v));
    }
}

/// Reads little-endian f32 from `b` into `values`.
pub fn get_f32s(b: &[u8], values: &mut [f32]) {
    for (v, c) in values.iter_mut().zip(b.chunks_exact(4)) {
        *v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    }
}

/// COBS-encodes bytes into `write` in blocks of at most 254 (the only buffering it needs).
///
/// Hand-written rather than a crate's (`cobs`, `corncobs`), on purpose: those encode a whole
/// input slice into an output buffer, and the device trainer's parameter reply (tens of KB)
/// would then need a second, encoded copy in a RAM budget of 256 KiB; this encoder streams the
/// frame to the UART through one 254-byte block. The decoder below works in place for the same
/// reason. Both are tested against the format's rules here and fuzzed (fuzz/, `frames`).
struct Cobs<'a, E> {
    block: [u8; 254],
    n: usize,
    write: &'a mut dyn FnMut(&[u8]) -> Result<(), E>,
}

impl<E> Cobs<'_, E> {
    fn put(&mut self, bytes: &[u8]) -> Result<(), E> {
        for &b in bytes {
            if b == 0 {
                self.flush()?;
            } else {
                self.block[self.n] = b;
                self.n += 1;
                if self.n == 254 {
                    // A full block: code 0xFF, and no zero is implied after it.
                    (self.write)(&[0xFF])?;
                    (self.write)(&self.block)?;
                    self.n = 0;
                }
            }
        }
        Ok(())
    }

    /// Ends a block at a zero byte (the code says where it was).
    fn flush(&mut self) -> Result<(), E> {
        (self.write)(&[self.n as u8 + 1])?;
        (self.write)(&self.block[..self.n])?;
        self.n = 0;
        Ok(())
    }
}

/// A sink of bytes that may fail with `E`.
pub type Sink<'a, E> = dyn FnMut(&[u8]) -> Result<(), E> + 'a;

/// Writes one frame through `write` (which may be called many times): `payload` is called
/// with a sink it writes the payload's pieces to, in order, exactly `len` bytes. The checksum
/// and the encoding are computed on the way, so a large payload (the parameters) need not be
/// held in one buffer.
pub fn write_frame<E>(
    kind: u8,
    seq: u8,
    len: usize,
    write: &mut Sink<'_, E>,
    payload: &mut dyn FnMut(&mut Sink<'_, E>) -> Result<(), E>,
) -> Result<(), E> {
    let header = [kind, seq, len as u8, (len >> 8) as u8];
    let mut crc = Crc::new();
    crc.update(&header);
    let mut cobs = Cobs {
        block: [0; 254],
        n: 0,
        write,
    };
    cobs.put(&header)?;
    let mut written = 0usize;
    let mut result = Ok(());
    payload(&mut |piece: &[u8]| {
        crc.update(piece);
        written += piece.len();
        if result.is_ok() {
            result = cobs.put(piece);
        }
        Ok(())
    })?;
    result?;
    debug_assert_eq!(written, len, "payload length");
    cobs.put(&crc.finish().to_le_bytes())?;
    cobs.flush()?;
    (cobs.write)(&[DELIMITER])
}

/// Encodes a whole frame into `out` (at least [`encoded_max`] of the payload); returns its
/// length.
pub fn encode(kind: u8, seq: u8, payload: &[u8], out: &mut [u8]) -> usize {
    let mut n = 0;
    let r: Result<(), ()> = write_frame(
        kind,
        seq,
        payload.len(),
        &mut |b: &[u8]| {
            out[n..n + b.len()].copy_from_slice(b);
            n += b.len();
            Ok(())
        },
        &mut |w| w(payload),
    );
    r.expect("writing to a slice cannot fail");
    n
}

/// What [`Receiver::push`] made of a byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// Not a whole frame yet.
    Pending,
    /// A whole, verified frame: its kind and sequence number; the payload is
    /// [`Receiver::payload`].
    Frame(u8, u8),
    /// A frame was rejected.
    Rejected(Fault),
}

/// Reassembles frames from a byte stream in a fixed buffer of `CAP` bytes (at least
/// [`encoded_max`] of the largest payload it accepts; longer frames are rejected as
/// [`Fault::Length`]).
pub struct Receiver<const CAP: usize> {
    buf: [u8; CAP],
    n: usize,
    overflow: bool,
    payload: (usize, usize),
    /// Observation size (it fixes the lengths of the kinds that carry observations).
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// Parameter count (for `PARAMS` replies).
    pub params: usize,
    /// Frames rejected so far.
    pub rejected: u32,
}

impl<const CAP: usize> Receiver<CAP> {
    /// A receiver for a plant of `obs` observations and `act` actions and a learner of
    /// `params` parameters.
    pub const fn new(obs: usize, act: usize, params: usize) -> Self {
        Self {
            buf: [0; CAP],
            n: 0,
            overflow: false,
            payload: (0, 0),
            obs,
            act,
            params,
            rejected: 0,
        }
    }

    /// The payload of the last frame [`Receiver::push`] returned.
    pub fn payload(&self) -> &[u8] {
        &self.buf[self.payload.0..self.payload.1]
    }

    fn reject(&mut self, f: Fault) -> Event {
        self.rejected = self.rejected.wrapping_add(1);
        Event::Rejected(f)
    }

    /// Takes the next byte of the stream.
    pub fn push(&mut self, b: u8) -> Event {
        if b != DELIMITER {
            if self.n == CAP {
                self.overflow = true;
            } else {
                self.buf[self.n] = b;
                self.n += 1;
            }
            return Event::Pending;
        }
        let (n, overflow) = (self.n, self.overflow);
        self.n = 0;
        self.overflow = false;
        if n == 0 {
            return Event::Pending; // an empty frame: line noise between frames
        }
        if overflow {
            return self.reject(Fault::Length);
        }
        let Some(m) = cobs_decode(&mut self.buf[..n]) else {
            return self.reject(Fault::Checksum);
        };
        if m < HEADER {
            return self.reject(Fault::Length);
        }
        let (kind, seq) = (self.buf[0], self.buf[1]);
        let len = self.buf[2] as usize | (self.buf[3] as usize) << 8;
        match payload_len(kind, self.obs, self.act, self.params) {
            None => return self.reject(Fault::UnknownKind),
            Some(want) if want != len || len + HEADER != m => return self.reject(Fault::Length),
            Some(_) => {}
        }
        let mut crc = Crc::new();
        crc.update(&self.buf[..4 + len]);
        if crc.finish() != u32_at(&self.buf, 4 + len) {
            return self.reject(Fault::Checksum);
        }
        self.payload = (4, 4 + len);
        Event::Frame(kind, seq)
    }
}

/// Decodes COBS in place; the decoded length, or `None` for an invalid encoding.
fn cobs_decode(buf: &mut [u8]) -> Option<usize> {
    let (mut r, mut w) = (0, 0);
    while r < buf.len() {
        let code = buf[r] as usize;
        if code == 0 || r + code > buf.len() {
            return None;
        }
        r += 1;
        for _ in 1..code {
            buf[w] = buf[r];
            w += 1;
            r += 1;
        }
        if code != 0xFF && r < buf.len() {
            buf[w] = 0;
            w += 1;
        }
    }
    Some(w)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec;
    use std::vec::Vec;

    #[test]
    fn every_nan_is_sent_as_the_canonical_one() {
        let made = core::hint::black_box(f32::INFINITY) * core::hint::black_box(0.0f32);
        #[cfg(target_arch = "x86_64")]
        assert_eq!(
            made.to_bits(),
            0xffc0_0000,
            "x86's invalid-operation NaN is negative"
        );
        for x in [
            made,
            -made,
            f32::NAN,
            f32::from_bits(0x7f80_0001),
            f32::from_bits(0xffff_ffff),
        ] {
            assert!(x.is_nan());
            assert_eq!(f32_bytes(x), CANONICAL_NAN.to_le_bytes());
        }
        let mut out = [0u8; 12];
        put_f32s(&[1.5, made, -0.0], &mut out);
        assert_eq!(f32_at(&out, 0), 1.5);
        assert_eq!(u32_at(&out, 4), CANONICAL_NAN);
        assert_eq!(u32_at(&out, 8), 0x8000_0000, "only NaNs change: -0 stays");
    }

    #[test]
    fn crc_matches_the_standard_check_value() {
        let mut c = Crc::new();
        c.update(b"123456789");
        assert_eq!(c.finish(), 0xCBF4_3926);
    }

    fn frame(kind: u8, payload: &[u8]) -> Vec<u8> {
        let mut out = [0u8; 1024];
        let n = encode(kind, 9, payload, &mut out);
        assert!(n <= encoded_max(payload.len()));
        assert!(!out[..n - 1].contains(&0), "no zero inside a frame");
        out[..n].to_vec()
    }

    fn feed(rx: &mut Receiver<64>, bytes: &[u8]) -> Vec<Event> {
        bytes
            .iter()
            .map(|&b| rx.push(b))
            .filter(|e| *e != Event::Pending)
            .collect()
    }

    #[test]
    fn frames_round_trip_and_streamed_writing_matches() {
        let mut rx = Receiver::<64>::new(5, 1, 0);
        let obs: Vec<u8> = (0..20u8).collect();
        let f = frame(kind::EVAL, &obs);
        assert_eq!(feed(&mut rx, &f), [Event::Frame(kind::EVAL, 9)]);
        assert_eq!(rx.payload(), &obs[..]);
        // The streamed writer gives the same bytes.
        let mut streamed = Vec::new();
        write_frame::<()>(
            kind::EVAL,
            9,
            20,
            &mut |b| {
                streamed.extend_from_slice(b);
                Ok(())
            },
            &mut |w| {
                w(&obs[..7])?;
                w(&obs[7..])
            },
        )
        .unwrap();
        assert_eq!(streamed, f);
    }

    #[test]
    fn long_payloads_with_zeros_round_trip() {
        // Parameters: over 254 bytes, with zero bytes and runs without any.
        let params: Vec<u8> = (0..700u32)
            .map(|i| if i % 97 == 0 { 0 } else { (i % 251) as u8 + 1 })
            .collect();
        let payload_len = params.len();
        let p = (payload_len - COUNTERS_LEN) / 4;
        let mut rx = Receiver::<2048>::new(5, 1, p);
        let f = frame(kind::PARAMS_REPLY, &params);
        let ev: Vec<Event> = f
            .iter()
            .map(|&b| rx.push(b))
            .filter(|e| *e != Event::Pending)
            .collect();
        assert_eq!(ev, [Event::Frame(kind::PARAMS_REPLY, 9)]);
        assert_eq!(rx.payload(), &params[..]);
    }

    #[test]
    fn every_single_bit_flip_is_rejected_and_the_next_frame_still_arrives() {
        let obs: Vec<u8> = (0..20u8).map(|x| x.wrapping_mul(37)).collect();
        let good = frame(kind::EVAL, &obs);
        let next = frame(kind::HELLO, &[]);
        for bit in 0..good.len() * 8 {
            let mut bad = good.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            let mut rx = Receiver::<64>::new(5, 1, 0);
            let mut stream = bad.clone();
            // A damaged delimiter merges the frame with the next one: the one after arrives.
            stream.extend_from_slice(&next);
            stream.extend_from_slice(&next);
            let ev = feed(&mut rx, &stream);
            assert!(
                !ev.contains(&Event::Frame(kind::EVAL, 9)),
                "bit {bit}: a damaged frame was accepted"
            );
            // A flip that makes a zero splits the frame in two, both rejected; the frame after
            // it arrives intact in every case.
            assert_eq!(
                ev.last(),
                Some(&Event::Frame(kind::HELLO, 9)),
                "bit {bit}: {ev:?}"
            );
            assert!(rx.rejected > 0, "bit {bit}: {ev:?}");
        }
    }

    #[test]
    fn truncated_frames_are_rejected_when_the_next_frame_arrives() {
        let good = frame(kind::EVAL, &[7u8; 20]);
        let next = frame(kind::PARAMS, &[]);
        for cut in 1..good.len() - 1 {
            let mut rx = Receiver::<64>::new(5, 1, 0);
            // The truncated frame runs into the next one, which is lost with it; the one
            // after arrives.
            let mut stream = good[..cut].to_vec();
            stream.extend_from_slice(&next);
            stream.extend_from_slice(&next);
            let ev = feed(&mut rx, &stream);
            assert!(!ev.contains(&Event::Frame(kind::EVAL, 9)), "cut {cut}");
            assert_eq!(
                ev,
                [
                    Event::Rejected(ev_fault(&ev)),
                    Event::Frame(kind::PARAMS, 9)
                ],
                "cut {cut}"
            );
        }
    }

    fn ev_fault(ev: &[Event]) -> Fault {
        match ev[0] {
            Event::Rejected(f) => f,
            e => panic!("first event {e:?}"),
        }
    }

    #[test]
    fn wrong_lengths_kinds_and_overlong_frames_are_rejected() {
        let mut rx = Receiver::<64>::new(5, 1, 0);
        assert_eq!(
            feed(&mut rx, &frame(0x42, &[])),
            [Event::Rejected(Fault::UnknownKind)]
        );
        assert_eq!(
            feed(&mut rx, &frame(kind::EVAL, &[1; 19])),
            [Event::Rejected(Fault::Length)]
        );
        let mut long = vec![1u8; 100];
        long.push(0);
        assert_eq!(feed(&mut rx, &long), [Event::Rejected(Fault::Length)]);
        assert_eq!(
            feed(&mut rx, &frame(kind::HELLO, &[])),
            [Event::Frame(kind::HELLO, 9)]
        );
        assert_eq!(rx.rejected, 3);
    }
}
