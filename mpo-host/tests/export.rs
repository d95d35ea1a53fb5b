//! `mpo export` on a real checkpoint: the firmware built from the exported source answers
//! every observation with exactly the host's evaluation action (`mean_action` of the
//! checkpoint's policy), bit for bit.

mod common;
use common::*;

use mpo_core::rng::Rng;
use mpo_host::checkpoint;

/// The `cartpole-balance`/`tiny` row's learner.
type TinyLearner = mpo_core::learner::Learner<5, 1, 1, 32, 32, 32, 32, 32, 2, 4, 10, 10>;

#[test]
fn exported_checkpoint_runs_on_the_firmware_bit_for_bit() {
    let d = scratch("export");
    let run = d.join("run");
    ok_json(&tiny(&run, 2000, &[]));
    let out_dir = d.join("export");
    let summary = ok_json(&mpo(&[
        "export",
        "--checkpoint",
        run.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]));
    assert_eq!(summary["task"], "cartpole-balance");
    assert_eq!(summary["obs"], 5);
    let policy = out_dir.join("policy.rs");

    let build = mpo_integration::firmware::build(&policy, "", &d.join("firmware"));
    assert!(
        build.status.success(),
        "firmware build failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let bin = d.join("firmware/x86_64-unknown-linux-gnu/release/mpo-firmware");

    // The host side: the checkpoint's policy, loaded through the library.
    let v = checkpoint::open(&run).unwrap();
    let mut learner: Box<TinyLearner> = bytemuck::zeroed_box();
    learner.init(v.meta.settings.mpo.to_config(), 0).unwrap();
    v.load_networks(&mut learner).unwrap();

    let mut rng = Rng::seed_from_u64(5);
    let obs: Vec<[f32; 5]> = (0..500)
        .map(|_| {
            let mut o = [0f32; 5];
            rng.fill_normal(&mut o);
            o
        })
        .collect();
    let stdout = mpo_integration::firmware::run(&bin, &obs);
    assert_eq!(stdout.len(), obs.len() * 4);
    for (k, (o, b)) in obs.iter().zip(stdout.chunks_exact(4)).enumerate() {
        let mut want = [0f32; 1];
        learner.mean_action(o, &mut want);
        let got = f32::from_le_bytes(b.try_into().unwrap());
        assert_eq!(
            got.to_bits(),
            want[0].to_bits(),
            "record {k}: {got} vs {}",
            want[0]
        );
    }
}

#[test]
fn export_of_a_missing_checkpoint_is_a_clear_error() {
    let d = scratch("export-missing");
    let out = mpo(&[
        "export",
        "--checkpoint",
        d.join("nothing").to_str().unwrap(),
        "--out",
        d.join("o").to_str().unwrap(),
    ]);
    let err = err_text(&out);
    assert!(err.contains("nothing"), "{err}");
}
