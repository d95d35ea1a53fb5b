//! mpo-link messages as both ends validate them: observation requests answered by the
//! controller's `respond` (validation, mean action or sample), action replies checked by the
//! plant (`ActMsg::validate`), parameter blocks checked (`ParamChunk::validate`) and assembled
//! into a policy (`Assembler::add`, swapped in when a generation completes). Whatever the
//! bytes: no panic, a reply that is not rejected passes the plant's check with finite values,
//! and a swapped-in policy's parameters match the whole-vector checksum.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mpo_core::actor::Actor;
use mpo_core::params::Params;
use mpo_core::rng::Rng;
use mpo_fuzz::link::{ACT, CHUNK, FIX_CHECKSUMS, OBS};
use mpo_link::controller::{Assembler, ControllerStats, respond};
use mpo_link::messages::{ActMsg, CHECKSUM_SEED, ObsMsg, ParamChunk, checksum};
use mpo_link::plant::ACT_REJECTED;

/// The `cartpole-64` profile.
type Policy = Actor<5, 1, 1, 64, 64>;

/// Copies up to `size_of::<T>()` bytes from the front of `data` over a zeroed `T`.
fn take<T: bytemuck::Pod>(data: &mut &[u8], out: &mut T) {
    let bytes = bytemuck::bytes_of_mut(out);
    bytes.fill(0);
    let n = bytes.len().min(data.len());
    bytes[..n].copy_from_slice(&data[..n]);
    *data = &data[n..];
}

fuzz_target!(|input: &[u8]| {
    let Some((&flags, mut data)) = input.split_first() else {
        return;
    };
    let mut policy: Box<Policy> = bytemuck::zeroed_box();
    policy.init(&mut Rng::seed_from_u64(0), 0.5, 1e-4);
    let mut asm = Assembler::<Policy>::new(bytemuck::zeroed_box());
    let mut applied = 0u64;
    let mut stats = ControllerStats::default();
    let mut req: ObsMsg = bytemuck::Zeroable::zeroed();
    let mut reply: ActMsg = bytemuck::Zeroable::zeroed();
    let mut chunk: Box<ParamChunk> = bytemuck::zeroed_box();
    let mut last_seq = 0u64;
    while let Some((&tag, rest)) = data.split_first() {
        data = rest;
        match tag % 3 {
            OBS => {
                take(&mut data, &mut req);
                respond(&policy, &req, applied, &mut stats, &mut reply);
                last_seq = req.seq;
                if reply.flags != ACT_REJECTED {
                    let a = reply
                        .validate(req.seq, 1)
                        .expect("an answer passes the plant");
                    assert!(a.iter().all(|x| x.is_finite()));
                } else {
                    assert!(reply.action.iter().all(|&x| x == 0.0), "rejected: zeros");
                }
            }
            ACT => {
                take(&mut data, &mut reply);
                if let Ok(a) = reply.validate(last_seq, 1) {
                    assert_eq!(a.len(), 1);
                    assert!(a.iter().all(|x| x.is_finite()));
                }
            }
            CHUNK => {
                take(&mut data, &mut *chunk);
                if flags & FIX_CHECKSUMS != 0 && chunk.len as usize <= chunk.payload.len() {
                    chunk.checksum = checksum(CHECKSUM_SEED, &chunk.payload[..chunk.len as usize]);
                }
                if let Ok(true) = asm.add(&chunk, applied) {
                    asm.swap_into(&mut policy);
                    applied = asm.generation();
                    let mut h = CHECKSUM_SEED;
                    for k in 0..Policy::TENSORS {
                        h = checksum(h, policy.tensor(k));
                    }
                    assert_eq!(
                        h, chunk.total_checksum,
                        "swapped in a policy that fails its checksum"
                    );
                }
            }
            _ => unreachable!(),
        }
    }
});
