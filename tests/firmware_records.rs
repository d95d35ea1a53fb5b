//! The firmware's record loop (`mpo-records`, the code the firmware binary runs) on the host:
//! actions equal `Actor::mean_action` bit for bit, non-finite records get zeros, and the
//! stream's end is clean only at a record boundary. Inputs the fuzz target `firmware_records`
//! found interesting are kept here as regression tests.

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_records::{EXIT_ERROR, EXIT_OK, SliceReader, serve};

const OBS: usize = 5;
const ACT: usize = 1;

fn policy() -> Box<Actor<OBS, ACT, 1, 64, 64>> {
    let mut a: Box<Actor<OBS, ACT, 1, 64, 64>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(7);
    a.init(&mut rng, 0.5, 1e-4);
    a.mean.init_uniform(&mut rng);
    a
}

/// Runs the loop over `input`: exit status and output bytes.
fn run(actor: &Actor<OBS, ACT, 1, 64, 64>, input: &[u8]) -> (i32, Vec<u8>) {
    let mut r = SliceReader(input);
    let mut out = Vec::new();
    let (mut ib, mut ob) = ([0u8; 4 * OBS], [0u8; 4 * ACT]);
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
    (code, out)
}

/// What the firmware must answer for `input`, computed record by record here.
fn expected(actor: &Actor<OBS, ACT, 1, 64, 64>, input: &[u8]) -> (i32, Vec<u8>) {
    let mut out = Vec::new();
    for rec in input.chunks_exact(4 * OBS) {
        let o: [f32; OBS] =
            std::array::from_fn(|i| f32::from_le_bytes(rec[4 * i..4 * i + 4].try_into().unwrap()));
        let mut a = [0f32; ACT];
        if o.iter().all(|x| x.is_finite()) {
            actor.mean_action(&o, &mut a);
            if !a.iter().all(|x| x.is_finite()) {
                a = [0.0; ACT];
            }
        }
        out.extend(a.iter().flat_map(|x| x.to_le_bytes()));
    }
    let code = if input.len().is_multiple_of(4 * OBS) {
        EXIT_OK
    } else {
        EXIT_ERROR
    };
    (code, out)
}

#[test]
fn loop_matches_mean_action_and_rejects_non_finite_and_truncated_records() {
    let actor = policy();
    let mut rng = Rng::seed_from_u64(1);
    let mut obs = vec![[0f32; OBS]; 300];
    for o in &mut obs {
        rng.fill_normal(o);
    }
    obs[10][2] = f32::NAN;
    obs[20][0] = f32::INFINITY;
    obs[30][4] = f32::NEG_INFINITY;
    obs[40][1] = f32::from_bits(0x7fc0_0001); // a NaN with a payload
    obs[50][3] = f32::MAX;
    obs[60][0] = f32::from_bits(1); // the smallest subnormal
    let input: Vec<u8> = obs.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
    let (code, out) = run(&actor, &input);
    assert_eq!(
        (code, &out),
        (expected(&actor, &input).0, &expected(&actor, &input).1)
    );
    assert_eq!(code, EXIT_OK);
    for k in [10, 20, 30, 40] {
        assert_eq!(&out[4 * k..4 * k + 4], &[0; 4], "record {k} gets zeros");
    }
    for cut in [1, 4 * OBS - 1, 4 * OBS + 3] {
        let (code, out) = run(&actor, &input[..input.len() - cut]);
        assert_eq!(code, EXIT_ERROR, "cut {cut}");
        assert_eq!(out.len(), (input.len() - cut) / (4 * OBS) * 4 * ACT);
    }
    assert_eq!(run(&actor, &[]), (EXIT_OK, vec![]));
}

/// Found by the fuzz target `firmware_records` (first run): five finite observations of
/// 3.3961514e38 (the bytes of the crash input) overflow the network and its mean action is
/// NaN; the firmware must answer with the safe action, not drive the plant with NaN.
#[test]
fn finite_observations_that_overflow_the_policy_get_the_safe_action() {
    let actor = policy();
    let o = [f32::from_bits(0x7f7f_7f7f); OBS];
    assert_eq!(o[0], 3.3961514e38);
    let mut raw = [0f32; ACT];
    actor.mean_action(&o, &mut raw);
    assert!(
        !raw[0].is_finite(),
        "the case needs a policy output that overflows (got {raw:?})"
    );
    let input: Vec<u8> = o.iter().flat_map(|x| x.to_le_bytes()).collect();
    assert_eq!(run(&actor, &input), (EXIT_OK, vec![0u8; 4 * ACT]));
}
