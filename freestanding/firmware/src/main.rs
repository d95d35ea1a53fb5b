//! Inference-only firmware: observations in, mean actions out, nothing else.
//!
//! Each record in (stdin on Linux, the UART on the Cortex-M4F board) is `OBS` little-endian
//! f32; for each, `ACT` little-endian f32 go out. A record with a non-finite value gets the
//! safe action (all zeros) instead of a network output. Exit 0 at the end of input (a UART has
//! none), 2 on a truncated record or an I/O error. The record format and the loop are
//! `mpo-records` (`freestanding/records`, also fuzzed); here only the byte stream (`mpo-rt`)
//! and the policy, bracketed by the measurement marks for the instruction counter.
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
    mpo_records::serve::<OBS, ACT>(
        &mut inbuf,
        &mut outbuf,
        |b| mpo_rt::read_exact(0, b),
        |b| mpo_rt::write_all(1, b),
        |o, a| {
            mpo_rt::mark_begin();
            ACTOR.mean_action(o, a);
            mpo_rt::mark_end();
        },
    )
}
