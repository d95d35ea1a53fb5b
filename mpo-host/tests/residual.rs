//! The residual networks and the categorical critic through the commands (the `tiny-simba`
//! row of cartpole-balance): a run repeats its bits on one and two threads and after a
//! resume, its checkpoint evaluates to the run's last evaluation, its exported policy
//! builds into the firmware, which answers with the host's actions bit for bit, and the
//! weights on the sphere (`weight_norm`) are a setting the checkpoint keeps.

mod common;
use common::*;

use std::path::Path;

use mpo_core::rng::Rng;

fn simba(dir: &Path, steps: u64, extra: &[&str]) -> serde_json::Value {
    let steps = steps.to_string();
    let mut args = vec![
        "train",
        "--task",
        "cartpole-balance",
        "--net",
        "tiny-simba",
        "--steps",
        &steps,
        "--no-progress",
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    ok_json(&mpo(&args))
}

/// `mpo train --resume dir --steps N`'s summary.
fn resume(dir: &Path, steps: u64) -> serde_json::Value {
    let steps = steps.to_string();
    ok_json(&mpo(&[
        "train",
        "--no-progress",
        "--resume",
        dir.to_str().unwrap(),
        "--steps",
        &steps,
    ]))
}

#[test]
fn a_residual_categorical_run_repeats_its_bits_on_any_thread_count_and_after_a_resume() {
    let d = scratch("residual-bits");
    let one = simba(&d.join("one"), 2000, &["--threads", "1"]);
    let two = simba(&d.join("two"), 2000, &["--threads", "2"]);
    assert_eq!(one["params_sha256"], two["params_sha256"]);
    assert_eq!(one["eval_return_mean"], two["eval_return_mean"]);
    let half = simba(&d.join("half"), 1000, &["--threads", "1"]);
    assert_ne!(half["params_sha256"], one["params_sha256"]);
    let resumed = resume(&d.join("half"), 2000);
    assert_eq!(resumed["params_sha256"], one["params_sha256"]);

    let eval = ok_json(&mpo(&[
        "eval",
        "--checkpoint",
        d.join("one").to_str().unwrap(),
        "--episodes",
        "3",
    ]));
    // The evaluation's episodes start from the run's evaluation seeds: the same returns.
    assert_eq!(eval["return_mean"], one["eval_return_mean"]);
}

/// A column of a run's `metrics.csv`, by name, one value per evaluation.
fn column(run: &Path, name: &str) -> Vec<f64> {
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let i = header.iter().position(|h| *h == name).expect(name);
    lines
        .map(|l| l.split(',').nth(i).unwrap().parse().unwrap())
        .collect()
}

/// A column of a run's `metrics.csv` with its empty cells as `None`.
fn cells(run: &Path, name: &str) -> Vec<Option<f64>> {
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let i = header.iter().position(|h| *h == name).expect(name);
    lines
        .map(|l| {
            let c = l.split(',').nth(i).unwrap();
            (!c.is_empty()).then(|| c.parse().unwrap())
        })
        .collect()
}

#[test]
fn weights_on_the_sphere_are_a_runs_setting_kept_by_its_checkpoint() {
    let d = scratch("residual-sphere");
    let wn = ["--threads", "2", "--set", "mpo.weight_norm=true"];
    let full = simba(&d.join("full"), 2000, &wn);
    let plain = simba(&d.join("plain"), 2000, &["--threads", "2"]);
    assert_ne!(full["params_sha256"], plain["params_sha256"]);
    simba(&d.join("half"), 1000, &wn);
    // Resumed without the --set: the checkpoint's settings hold it.
    let resumed = resume(&d.join("half"), 2000);
    assert_eq!(resumed["params_sha256"], full["params_sha256"]);
    // The logged weight growth: a fresh network's hidden columns have about their expected
    // norm at initialisation (1); on the sphere every hidden column has norm 1, which is
    // sqrt(3) times that, at every evaluation; a resumed run logs the same figures.
    for net in ["actor_weight_growth", "critic_weight_growth"] {
        let fresh = column(&d.join("plain"), net)[0];
        assert!(
            (fresh - 1.0).abs() < 0.1,
            "{net} of fresh networks: {fresh}"
        );
        let sphere = column(&d.join("full"), net);
        assert!(sphere.len() >= 2, "{sphere:?}");
        for g in &sphere {
            assert!(
                (g - 3f64.sqrt()).abs() < 1e-3,
                "{net} on the sphere: {sphere:?}"
            );
        }
        assert_eq!(column(&d.join("half"), net), sphere);
    }
    // The dormant units (`mpo_host::dormant`): nothing to measure on at the evaluation before
    // the first step, a share of the units at every later one, the same after a resume.
    assert_eq!(column(&d.join("full"), "env_steps")[0], 0.0);
    for net in ["actor_dormant", "critic_dormant"] {
        let full = cells(&d.join("full"), net);
        assert_eq!(full[0], None, "{net}: {full:?}");
        assert!(full.len() >= 2, "{full:?}");
        assert!(
            full[1..]
                .iter()
                .all(|v| v.is_some_and(|x| (0.0..=100.0).contains(&x))),
            "{net}: {full:?}"
        );
        assert_eq!(cells(&d.join("half"), net), full);
    }
    // An MLP row refuses it, naming the setting.
    let out = mpo(&[
        "train",
        "--no-progress",
        "--steps",
        "1000",
        "--set",
        "mpo.weight_norm=true",
        "--out",
        d.join("mlp").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("weight_norm") && err.contains("residual"),
        "{err}"
    );
}

#[test]
fn an_exported_residual_policy_runs_in_the_firmware_with_the_hosts_bits() {
    let d = scratch("residual-export");
    let run = d.join("run");
    simba(&run, 2000, &["--threads", "1"]);
    let out_dir = d.join("export");
    let summary = ok_json(&mpo(&[
        "export",
        "--checkpoint",
        run.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]));
    assert_eq!(summary["blocks"], 1);
    let policy = out_dir.join("policy.rs");
    let src = std::fs::read_to_string(&policy).unwrap();
    assert!(
        src.contains("ResidualActor"),
        "{}",
        &src[..src.len().min(400)]
    );

    let build = mpo_integration::firmware::build(&policy, "", &d.join("firmware"));
    assert!(
        build.status.success(),
        "firmware build failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let bin = d.join("firmware/x86_64-unknown-linux-gnu/release/mpo-firmware");

    // The host side: the checkpoint's policy as the inference commands load it.
    let v = mpo_host::checkpoint::open(&run).unwrap();
    let instance = mpo_host::registry::find(&v.meta.sizes).unwrap();
    let host = (instance.policy)(&v).unwrap();

    let mut rng = Rng::seed_from_u64(7);
    let obs: Vec<[f32; 5]> = (0..300)
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
        host.mean_action(o, &mut want);
        let got = f32::from_le_bytes(b.try_into().unwrap());
        assert_eq!(
            got.to_bits(),
            want[0].to_bits(),
            "record {k}: {got} vs {}",
            want[0]
        );
    }
}
