//! The inference-only firmware: exported weights in read-only data, mpo-core without training
//! code, no std, no allocator; its mean actions equal the host's bit for bit.
//!
//! Builds `freestanding/firmware` (release, baseline x86-64 CPU) for two 64-64 profiles
//! (cartpole-sized and hopper-sized policies), streams observations through it and compares
//! every action with `Actor::mean_action` computed here. Negative controls show the build fails
//! when `alloc` or `std` enter, or when the firmware reaches for training code.

use std::io::Write;
use std::process::{Command, Stdio};

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_integration::firmware::{build, export, export_and_build};
use mpo_integration::workspace_root as root;

/// A policy with full-scale heads (an initialised policy's heads are scaled down, which would
/// make the comparison easy).
fn policy<const OBS: usize, const ACT: usize, const TRI: usize>(
    seed: u64,
) -> Box<Actor<OBS, ACT, TRI, 64, 64>> {
    let mut a: Box<Actor<OBS, ACT, TRI, 64, 64>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(seed);
    a.init(&mut rng, 0.5, 1e-4);
    a.mean.init_uniform(&mut rng);
    a
}

fn check_profile<const OBS: usize, const ACT: usize, const TRI: usize>(name: &str, seed: u64) {
    let actor = policy::<OBS, ACT, TRI>(seed);
    let bin = export_and_build(&*actor, name);

    // 2000 observations, wide-ranging, with one non-finite record.
    let mut rng = Rng::seed_from_u64(seed + 1);
    let mut obs = vec![[0f32; OBS]; 2000];
    for o in &mut obs {
        rng.fill_normal(o);
        let scale = 1.0 + 9.0 * rng.uniform();
        o.iter_mut().for_each(|x| *x *= scale);
    }
    obs[1234][0] = f32::NAN;
    // Finite but huge: the network overflows, so the safe action is expected (found by the
    // fuzz target `firmware_records`).
    obs[1500] = [f32::from_bits(0x7f7f_7f7f); OBS];
    let stdout = mpo_integration::firmware::run(&bin, &obs);
    assert_eq!(
        stdout.len(),
        obs.len() * ACT * 4,
        "one action per observation"
    );
    let mut overflowed = false;
    for (k, (o, bytes)) in obs.iter().zip(stdout.chunks_exact(ACT * 4)).enumerate() {
        let mut want = [0f32; ACT];
        if o.iter().all(|x| x.is_finite()) {
            actor.mean_action(o, &mut want);
            if !want.iter().all(|x| x.is_finite()) {
                assert_eq!(k, 1500, "{name}: only the huge record overflows");
                overflowed = true;
                want = [0.0; ACT];
            }
        }
        for j in 0..ACT {
            let got = f32::from_le_bytes(bytes[4 * j..4 * j + 4].try_into().unwrap());
            assert_eq!(
                got.to_bits(),
                want[j].to_bits(),
                "{name}: record {k} action {j}: {got} vs {}",
                want[j]
            );
        }
    }
    assert!(
        overflowed,
        "{name}: the huge record must overflow the policy"
    );
    // A truncated record is an error, not a silent action.
    let mut child = Command::new(&bin)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(&[0u8; 6]).unwrap();
    assert_eq!(child.wait().unwrap().code(), Some(2));
}

#[test]
fn firmware_actions_equal_host_actions_bit_for_bit() {
    check_profile::<5, 1, 1>("cartpole-64", 11);
    check_profile::<15, 4, 10>("hopper-64", 12);
}

#[test]
fn firmware_build_fails_when_alloc_std_or_training_code_enter() {
    let actor = policy::<5, 1, 1>(3);
    let dir = root().join("target/firmware/negative");
    let src = dir.join("policy.rs");
    export(&*actor, "tests/firmware.rs", &src);
    mpo_integration::assert_builds_fail(
        &[
            ("use-alloc", "no global memory allocator"),
            ("use-std", "duplicate lang item"),
            ("reach-training-code", "adam"),
        ],
        |feature| build(&src, feature, &dir.join("build")),
    );
}
