//! Inference-only firmware: observations in, mean actions out, nothing else.
//!
//! Each record on stdin is `OBS` little-endian f32; for each, `ACT` little-endian f32 go to
//! stdout. A record with a non-finite value gets the safe action (all zeros) instead of a
//! network output. Exit 0 at the end of input, 2 on a truncated record or an I/O error.
#![no_std]
#![no_main]

#[cfg(feature = "use-alloc")]
extern crate alloc;
#[cfg(feature = "use-std")]
extern crate std;

mod policy {
    include!(concat!(env!("OUT_DIR"), "/policy.rs"));
}
use policy::{ACT, ACTOR, OBS};

mpo_rt::entry!(main);

fn main() -> i32 {
    #[cfg(feature = "use-alloc")]
    core::hint::black_box(alloc::boxed::Box::new(1u8));
    #[cfg(feature = "reach-training-code")]
    core::hint::black_box(mpo_core::adam::AdamState::default());
    let mut inbuf = [0u8; OBS * 4];
    let mut outbuf = [0u8; ACT * 4];
    loop {
        match mpo_rt::read_exact(0, &mut inbuf) {
            Ok(true) => {}
            Ok(false) => return 0,
            Err(()) => return 2,
        }
        let mut obs = [0f32; OBS];
        for (o, b) in obs.iter_mut().zip(inbuf.chunks_exact(4)) {
            *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        let mut action = [0f32; ACT];
        if obs.iter().all(|x| x.is_finite()) {
            ACTOR.mean_action(&obs, &mut action);
        }
        for (b, a) in outbuf.chunks_exact_mut(4).zip(action) {
            b.copy_from_slice(&a.to_le_bytes());
        }
        if !mpo_rt::write_all(1, &outbuf) {
            return 2;
        }
    }
}
