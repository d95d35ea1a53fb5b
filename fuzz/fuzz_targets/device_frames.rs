//! The device trainer's byte protocol (`mpo-frames`: COBS frames with a CRC-32, reassembled
//! by `Receiver` one byte at a time), as both ends receive it. Mode 0 (even first byte): the
//! rest is a raw byte stream; every frame the receiver accepts has its kind's payload length
//! and survives a re-encoding (the encoder's output has no zero byte inside and decodes to the
//! same kind, sequence number and payload). Mode 1: the rest is (kind, seq, length, payload)
//! records, each encoded by `encode` and fed to the receiver: it gives the frame back exactly,
//! or rejects it because the kind is unknown or its length is not the kind's.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mpo_frames::{COUNTERS_LEN, Event, Fault, Receiver, encode, encoded_max, payload_len};

/// Sizes of the plant and learner the receivers are built for (a cartpole-sized plant and a
/// small learner: the frame code depends on them only through the payload lengths).
const OBS: usize = 5;
const ACT: usize = 1;
const PARAMS: usize = 300;
const CAP: usize = encoded_max(COUNTERS_LEN + 4 * PARAMS);

fn receiver() -> Box<Receiver<CAP>> {
    Box::new(Receiver::new(OBS, ACT, PARAMS))
}

/// Encodes and receives one frame: the event of its last byte, the payload received and the
/// frame's encoded length without its delimiter.
fn round_trip(kind: u8, seq: u8, payload: &[u8]) -> (Event, Vec<u8>, usize) {
    let mut out = vec![0u8; encoded_max(payload.len())];
    let n = encode(kind, seq, payload, &mut out);
    assert!(n <= out.len());
    assert_eq!(out[n - 1], 0, "a frame ends with the delimiter");
    assert!(!out[..n - 1].contains(&0), "no zero byte inside a frame");
    let mut rx = receiver();
    for &b in &out[..n - 1] {
        assert_eq!(rx.push(b), Event::Pending);
    }
    let e = rx.push(0);
    (e, rx.payload().to_vec(), n - 1)
}

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    if mode % 2 == 0 {
        let mut rx = receiver();
        let mut rejected = 0u32;
        for &b in rest {
            match rx.push(b) {
                Event::Pending => {}
                Event::Rejected(_) => rejected += 1,
                Event::Frame(kind, seq) => {
                    let p = rx.payload().to_vec();
                    assert_eq!(Some(p.len()), payload_len(kind, OBS, ACT, PARAMS));
                    let (e, again, _) = round_trip(kind, seq, &p);
                    assert_eq!(e, Event::Frame(kind, seq));
                    assert_eq!(again, p);
                }
            }
        }
        assert_eq!(rx.rejected, rejected, "every rejection is counted");
    } else {
        let mut rest = rest;
        while rest.len() >= 4 {
            let (kind, seq) = (rest[0], rest[1]);
            let len = (u16::from_le_bytes([rest[2], rest[3]]) as usize).min(rest.len() - 4);
            let payload = &rest[4..4 + len];
            rest = &rest[4 + len..];
            let (e, got, encoded) = round_trip(kind, seq, payload);
            // Longer than the receiver's buffer: rejected for its length whatever its kind.
            // (The encoded length, not `encoded_max`: COBS adds fewer bytes when the frame
            // has zeros, so a frame whose bound exceeds the buffer may still fit; found by
            // this target, whose first version used the bound.)
            let oversize = encoded > CAP;
            match payload_len(kind, OBS, ACT, PARAMS) {
                None if !oversize => assert_eq!(e, Event::Rejected(Fault::UnknownKind)),
                Some(want) if want == len => {
                    assert_eq!(e, Event::Frame(kind, seq));
                    assert_eq!(got, payload);
                }
                _ => assert_eq!(e, Event::Rejected(Fault::Length)),
            }
        }
    }
});
