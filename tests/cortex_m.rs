//! The inference-only firmware on a Cortex-M4F: built for thumbv7em-none-eabihf (hardware FPU,
//! every multiply-add one `vfma.f32`), run on QEMU's `mps2-an386` board with the observations
//! and actions over its UART; its actions equal the host's (x86-64) bit for bit. And the
//! instruction counter the benchmarks use gives the same counts on every run.
//!
//! Needs `scripts/setup-cortex-m` (the tests fail with that command when its tools are missing).

use std::time::Duration;

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_integration::cortex_m;
use mpo_integration::firmware::export_and_build_cortex_m;

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

/// `n` wide-ranging observations (normal, scaled by 1 to 10).
fn observations<const OBS: usize>(seed: u64, n: usize) -> Vec<[f32; OBS]> {
    let mut rng = Rng::seed_from_u64(seed);
    let mut obs = vec![[0f32; OBS]; n];
    for o in &mut obs {
        rng.fill_normal(o);
        let scale = 1.0 + 9.0 * rng.uniform();
        o.iter_mut().for_each(|x| *x *= scale);
    }
    obs
}

fn bytes<const OBS: usize>(obs: &[[f32; OBS]]) -> Vec<u8> {
    obs.iter().flatten().flat_map(|x| x.to_le_bytes()).collect()
}

fn check_profile<const OBS: usize, const ACT: usize, const TRI: usize>(name: &str, seed: u64) {
    let actor = policy::<OBS, ACT, TRI>(seed);
    let elf = export_and_build_cortex_m(&*actor, name);
    let mut obs = observations::<OBS>(seed + 1, 2000);
    obs[1234][0] = f32::NAN;
    // Finite but huge: the network overflows (NaN on either CPU, with another sign bit on
    // each), so the safe action is expected.
    obs[1500] = [f32::from_bits(0x7f7f_7f7f); OBS];
    let out = cortex_m::exchange(
        &cortex_m::command(&elf, None),
        bytes(&obs),
        obs.len() * ACT * 4,
        Duration::from_secs(120),
    );
    let mut overflowed = false;
    for (k, (o, got)) in obs.iter().zip(out.chunks_exact(ACT * 4)).enumerate() {
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
            let g = f32::from_le_bytes(got[4 * j..4 * j + 4].try_into().unwrap());
            assert_eq!(
                g.to_bits(),
                want[j].to_bits(),
                "{name}: record {k} action {j}: Cortex-M4F {g} vs host {}",
                want[j]
            );
        }
    }
    assert!(overflowed, "{name}: the huge record must overflow");
}

#[test]
fn firmware_on_the_cortex_m4f_gives_the_host_actions_bit_for_bit() {
    check_profile::<5, 1, 1>("cartpole-64", 11);
    check_profile::<15, 4, 10>("hopper-64", 12);
}

/// The counter's per-inference counts for 300 records, on two runs of QEMU: equal, one per
/// record, and at least one instruction per multiply-add of the 64-64 network.
#[test]
fn instruction_counts_repeat_exactly() {
    let actor = policy::<5, 1, 1>(21);
    let elf = export_and_build_cortex_m(&*actor, "cartpole-64-count");
    let obs = observations::<5>(22, 300);
    let dir = mpo_integration::workspace_root().join("target/cortex-m/count-test");
    std::fs::create_dir_all(&dir).unwrap();
    let run = |i: u32| {
        let log = dir.join(format!("run{i}.log"));
        let _ = std::fs::remove_file(&log);
        cortex_m::exchange(
            &cortex_m::command(&elf, Some(&log)),
            bytes(&obs),
            obs.len() * 4,
            Duration::from_secs(120),
        );
        cortex_m::spans(&log)
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.len(), obs.len(), "one span per inference");
    assert_eq!(a, b, "instruction counts differ between two runs");
    let macs = (5 * 64 + 64 * 64 + 64) as u64;
    assert!(
        a.iter().all(|&n| n > macs),
        "fewer instructions than multiply-adds: {a:?}"
    );
}
