//! The firmware's record stream: each input record is `OBS` little-endian f32 (an
//! observation), each output record `ACT` little-endian f32 (the action). A record with a NaN
//! or infinity gets the safe action (all zeros) instead of a policy output, and so does a
//! record whose policy output is not finite (huge finite observations overflow the network:
//! found by the fuzz target `firmware_records`); the stream ends cleanly only at a record
//! boundary.
//!
//! No platform here: [`serve`] takes the reader, the writer and the policy as functions, so
//! the firmware runs it over its raw system calls and tests and the fuzz target over byte
//! slices ([`SliceReader`]).
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

/// Exit status of a stream that ended at a record boundary.
pub const EXIT_OK: i32 = 0;
/// Exit status of a truncated record, a read error or a write error.
pub const EXIT_ERROR: i32 = 2;

/// Decodes one observation record (`4 * OBS` bytes, little-endian f32) into `obs`; true when
/// every value is finite.
///
/// # Panics
/// If `record` is not `4 * OBS` bytes long (the caller's buffer is sized for it).
pub fn decode_observation<const OBS: usize>(record: &[u8], obs: &mut [f32; OBS]) -> bool {
    assert!(
        record.len() == 4 * OBS,
        "an observation record is 4 * OBS bytes"
    );
    for (o, b) in obs.iter_mut().zip(record.chunks_exact(4)) {
        *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    }
    obs.iter().all(|x| x.is_finite())
}

/// Encodes an action as its record (`4 * ACT` bytes, little-endian f32).
///
/// # Panics
/// If `out` is not `4 * ACT` bytes long.
pub fn encode_action<const ACT: usize>(action: &[f32; ACT], out: &mut [u8]) {
    assert!(out.len() == 4 * ACT, "an action record is 4 * ACT bytes");
    for (b, a) in out.chunks_exact_mut(4).zip(action) {
        b.copy_from_slice(&a.to_le_bytes());
    }
}

/// Answers one observation record with its action record: `policy`'s action for a finite
/// observation if it is finite, zeros (the safe action) otherwise. A NaN action never drives
/// the plant (as in the controller process, `mpo_link::controller::respond`).
pub fn answer<const OBS: usize, const ACT: usize>(
    record: &[u8],
    out: &mut [u8],
    policy: impl FnOnce(&[f32; OBS], &mut [f32; ACT]),
) {
    let mut obs = [0f32; OBS];
    let mut action = [0f32; ACT];
    if decode_observation(record, &mut obs) {
        policy(&obs, &mut action);
        if !action.iter().all(|x| x.is_finite()) {
            action = [0.0; ACT];
        }
    }
    encode_action(&action, out);
}

/// The firmware's loop: reads records into `inbuf` (`4 * OBS` bytes) with `read_exact` until
/// the input ends, answers each ([`answer`]) through `outbuf` (`4 * ACT` bytes) and
/// `write_all`. Returns [`EXIT_OK`] at a clean end of input, [`EXIT_ERROR`] on a truncated
/// record or an I/O error.
///
/// `read_exact(buf)` fills `buf` and returns `Ok(true)`, or `Ok(false)` if the input ended
/// before its first byte, or `Err(())` (an error, or the end inside the buffer); `write_all`
/// writes all of its bytes or returns false.
pub fn serve<const OBS: usize, const ACT: usize>(
    inbuf: &mut [u8],
    outbuf: &mut [u8],
    mut read_exact: impl FnMut(&mut [u8]) -> Result<bool, ()>,
    mut write_all: impl FnMut(&[u8]) -> bool,
    mut policy: impl FnMut(&[f32; OBS], &mut [f32; ACT]),
) -> i32 {
    loop {
        match read_exact(inbuf) {
            Ok(true) => {}
            Ok(false) => return EXIT_OK,
            Err(()) => return EXIT_ERROR,
        }
        answer(inbuf, outbuf, &mut policy);
        if !write_all(outbuf) {
            return EXIT_ERROR;
        }
    }
}

/// `read_exact` over a byte slice, with the semantics [`serve`] expects (and the firmware's
/// `mpo_rt::read_exact` has): the end of input is clean only before a record's first byte.
pub struct SliceReader<'a>(pub &'a [u8]);

impl SliceReader<'_> {
    /// Fills `buf` from the front of the slice.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> Result<bool, ()> {
        if self.0.is_empty() && !buf.is_empty() {
            return Ok(false);
        }
        if self.0.len() < buf.len() {
            self.0 = &[];
            return Err(());
        }
        let (head, rest) = self.0.split_at(buf.len());
        buf.copy_from_slice(head);
        self.0 = rest;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn run(input: &[u8]) -> (i32, Vec<u8>) {
        let mut r = SliceReader(input);
        let mut out = Vec::new();
        let (mut ib, mut ob) = ([0u8; 8], [0u8; 4]);
        let code = serve::<2, 1>(
            &mut ib,
            &mut ob,
            |b| r.read_exact(b),
            |b| {
                out.extend_from_slice(b);
                true
            },
            |o, a| a[0] = o[0] + o[1],
        );
        (code, out)
    }

    #[test]
    fn records_in_actions_out_nan_gets_zeros_truncation_is_an_error() {
        let rec = |a: f32, b: f32| [a.to_le_bytes(), b.to_le_bytes()].concat();
        let input = [
            rec(1.0, 2.0),
            rec(f32::NAN, 1.0),
            rec(-1.5, 0.25),
            rec(f32::MAX, f32::MAX), // the policy's sum overflows: zeros, not infinity
        ]
        .concat();
        let (code, out) = run(&input);
        assert_eq!(code, EXIT_OK);
        let acts: Vec<f32> = out
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(acts, [3.0, 0.0, -1.25, 0.0]);
        assert_eq!(run(&[]), (EXIT_OK, Vec::new()));
        let (code, out) = run(&input[..10]);
        assert_eq!((code, out.len()), (EXIT_ERROR, 4));
    }
}
