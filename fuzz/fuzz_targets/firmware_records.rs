//! The firmware's record stream (`mpo-records`, the loop the freestanding firmware runs over
//! stdin and stdout): for any input, one action record per whole observation record, zeros for
//! a record with a NaN or infinity, `Actor::mean_action` bit for bit otherwise, never a
//! non-finite action, exit 0 exactly when the input ends at a record boundary. The policies
//! have the firmware profiles' input and output sizes with 8-8 hidden layers (the record code
//! does not depend on the widths, and 64-64 ran at about 150 inputs per second).
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_records::{EXIT_ERROR, EXIT_OK, SliceReader, serve};

/// Hidden width of the fuzzed policies.
const H: usize = 8;

fn policy<const OBS: usize, const ACT: usize, const TRI: usize>() -> Box<Actor<OBS, ACT, TRI, H, H>>
{
    let mut a: Box<Actor<OBS, ACT, TRI, H, H>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(3);
    a.init(&mut rng, 0.5, 1e-4);
    a.mean.init_uniform(&mut rng);
    a
}

fn check<const OBS: usize, const ACT: usize, const TRI: usize>(
    actor: &Actor<OBS, ACT, TRI, H, H>,
    input: &[u8],
) {
    let mut r = SliceReader(input);
    let mut out = Vec::new();
    let (mut ib, mut ob) = (vec![0u8; 4 * OBS], vec![0u8; 4 * ACT]);
    let code = serve::<OBS, ACT>(
        &mut ib,
        &mut ob,
        |b| r.read_exact(b),
        |b| {
            out.extend_from_slice(b);
            true
        },
        |o, a| actor.mean_action(o, a),
    );
    let whole = input.len() / (4 * OBS);
    assert_eq!(out.len(), whole * 4 * ACT, "one action per whole record");
    let ok = input.len().is_multiple_of(4 * OBS);
    assert_eq!(code, if ok { EXIT_OK } else { EXIT_ERROR });
    for (rec, act) in input.chunks_exact(4 * OBS).zip(out.chunks_exact(4 * ACT)) {
        let o: [f32; OBS] =
            std::array::from_fn(|i| f32::from_le_bytes(rec[4 * i..4 * i + 4].try_into().unwrap()));
        let got: Vec<f32> = act
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert!(
            got.iter().all(|x| x.is_finite()),
            "a non-finite action {got:?} for the observation {o:?}"
        );
        let mut want = [0f32; ACT];
        if o.iter().all(|x| x.is_finite()) {
            actor.mean_action(&o, &mut want);
        }
        if want.iter().all(|x| x.is_finite()) {
            let want: Vec<u8> = want.iter().flat_map(|x| x.to_le_bytes()).collect();
            assert_eq!(act, &want[..]);
        }
    }
}

fuzz_target!(|data: &[u8]| {
    static CARTPOLE: OnceLock<Box<Actor<5, 1, 1, H, H>>> = OnceLock::new();
    static HOPPER: OnceLock<Box<Actor<15, 4, 10, H, H>>> = OnceLock::new();
    let Some((&which, input)) = data.split_first() else {
        return;
    };
    if which % 2 == 0 {
        check(CARTPOLE.get_or_init(policy::<5, 1, 1>), input);
    } else {
        check(HOPPER.get_or_init(policy::<15, 4, 10>), input);
    }
});
