//! Every fault path ends with a clear message, exit status 1 and no panic.

mod common;
use common::*;

#[test]
fn corrupt_or_truncated_checkpoint_names_the_file() {
    let d = scratch("corrupt");
    let run = d.join("run");
    ok_json(&tiny(&run, 1000, &[]));
    let ck = run.join("checkpoint");

    // One flipped bit in the parameters.
    let p = ck.join("params.safetensors");
    let good = std::fs::read(&p).unwrap();
    let mut bad = good.clone();
    let k = bad.len() - 5;
    bad[k] ^= 1;
    std::fs::write(&p, &bad).unwrap();
    for args in [
        vec!["eval", "--checkpoint", run.to_str().unwrap()],
        vec!["train", "--no-progress", "--resume", run.to_str().unwrap()],
    ] {
        let e = err_text(&mpo(&args));
        assert!(e.contains("params.safetensors"), "{e}");
        assert!(e.contains("checksum mismatch"), "{e}");
    }
    std::fs::write(&p, &good).unwrap();

    // A truncated replay.
    let r = ck.join("replay.safetensors");
    let bytes = std::fs::read(&r).unwrap();
    std::fs::write(&r, &bytes[..bytes.len() / 2]).unwrap();
    let e = err_text(&mpo(&["eval", "--checkpoint", run.to_str().unwrap()]));
    assert!(
        e.contains("replay.safetensors") && e.contains("corrupt or truncated"),
        "{e}"
    );
    std::fs::write(&r, &bytes).unwrap();

    // A missing metadata file.
    let m = ck.join("meta.json");
    let meta = std::fs::read(&m).unwrap();
    std::fs::remove_file(&m).unwrap();
    let e = err_text(&mpo(&["eval", "--checkpoint", run.to_str().unwrap()]));
    assert!(e.contains("meta.json"), "{e}");
    std::fs::write(&m, &meta).unwrap();

    // An older format version, checksums intact: named, with what to do about it.
    let text = String::from_utf8(meta.clone()).unwrap();
    let current = format!("\"version\": {}", mpo_host::checkpoint::VERSION);
    let old = text.replacen(&current, "\"version\": 2", 1);
    assert_ne!(old, text, "meta.json holds {current}");
    let sums_path = ck.join("SHA256SUMS");
    let sums = std::fs::read_to_string(&sums_path).unwrap();
    let new_sums: String = sums
        .lines()
        .map(|l| match l.strip_suffix("  meta.json") {
            Some(_) => format!(
                "{}  meta.json\n",
                mpo_host::checkpoint::sha256_hex(old.as_bytes())
            ),
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&m, &old).unwrap();
    std::fs::write(&sums_path, &new_sums).unwrap();
    let e = err_text(&mpo(&["eval", "--checkpoint", run.to_str().unwrap()]));
    assert!(e.contains("version 2") && e.contains("train again"), "{e}");
    std::fs::write(&m, &meta).unwrap();
    std::fs::write(&sums_path, &sums).unwrap();

    // Intact again: evaluation works.
    let out = mpo(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--episodes",
        "2",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // No checkpoint at all.
    let e = err_text(&mpo(&["eval", "--checkpoint", d.to_str().unwrap()]));
    assert!(e.contains("no checkpoint in"), "{e}");
}

#[test]
fn configuration_mismatch_on_resume_is_refused() {
    let d = scratch("mismatch");
    let run = d.join("run");
    ok_json(&tiny(&run, 1000, &[]));
    let r = run.to_str().unwrap();
    let e = err_text(&mpo(&["train", "--resume", r, "--seed", "3"]));
    assert!(
        e.contains("does not match the checkpoint") && e.contains("`seed`"),
        "{e}"
    );
    let e = err_text(&mpo(&[
        "train",
        "--resume",
        r,
        "--set",
        "mpo.actor_lr=1e-3",
    ]));
    assert!(e.contains("`mpo.actor_lr`"), "{e}");
    let cfg = d.join("other.toml");
    std::fs::write(&cfg, "[schedule]\nupdate_interval = 1\n").unwrap();
    let e = err_text(&mpo(&[
        "train",
        "--resume",
        r,
        "--config",
        cfg.to_str().unwrap(),
    ]));
    assert!(e.contains("`schedule.update_interval`"), "{e}");
    // Starting a fresh run over an existing one is refused too.
    let e = err_text(&tiny(&run, 1000, &[]));
    assert!(e.contains("already holds a checkpoint"), "{e}");
}

#[test]
fn bad_configuration_is_reported() {
    let d = scratch("badcfg");
    let e = err_text(&tiny(&d.join("a"), 1500, &[]));
    assert!(e.contains("multiple of the episode length"), "{e}");
    let e = err_text(&tiny(&d.join("b"), 1000, &["--set", "mpo.actr_lr=1"]));
    assert!(e.contains("unknown setting `mpo.actr_lr`"), "{e}");
    let e = err_text(&tiny(&d.join("c"), 1000, &["--set", "mpo.gamma=2"]));
    assert!(e.contains("gamma"), "{e}");
    let e = err_text(&tiny(
        &d.join("n"),
        1000,
        &["--set", "schedule.noise_corr=1.0"],
    ));
    assert!(
        e.contains("schedule.noise_corr = 1 must be in [0, 1)"),
        "{e}"
    );
    let retrace_noise = [
        "--set",
        "schedule.noise_corr=0.5",
        "--set",
        "mpo.policy_evaluation=\"retrace\"",
        "--set",
        "mpo.n_step=3",
    ];
    let e = err_text(&tiny(&d.join("r"), 1000, &retrace_noise));
    assert!(
        e.contains("noise_corr must be 0 with mpo.policy_evaluation"),
        "{e}"
    );
    let two_noises = [
        "--set",
        "schedule.noise_pink=true",
        "--set",
        "schedule.noise_corr=0.5",
    ];
    let e = err_text(&tiny(&d.join("p"), 1000, &two_noises));
    assert!(e.contains("two kinds of exploration noise"), "{e}");
    let retrace_pink = [
        "--set",
        "schedule.noise_pink=true",
        "--set",
        "mpo.policy_evaluation=\"retrace\"",
        "--set",
        "mpo.n_step=3",
    ];
    let e = err_text(&tiny(&d.join("q"), 1000, &retrace_pink));
    assert!(
        e.contains("noise_pink must be false with mpo.policy_evaluation"),
        "{e}"
    );
    let cfg = d.join("bad.toml");
    std::fs::write(&cfg, "seed = \"zero\"\n").unwrap();
    let e = err_text(&tiny(
        &d.join("d"),
        1000,
        &["--config", cfg.to_str().unwrap()],
    ));
    assert!(e.contains("bad.toml"), "{e}");
}

#[test]
fn unknown_task_lists_the_valid_ones() {
    let d = scratch("unknown");
    let out = mpo(&[
        "train",
        "--task",
        "cartpole-balanse",
        "--out",
        d.to_str().unwrap(),
    ]);
    let e = err_text(&out);
    assert!(e.contains("unknown task `cartpole-balanse`"), "{e}");
    for t in [
        "cartpole-balance",
        "hopper-stand",
        "hopper-hop",
        "acrobot-swingup",
    ] {
        assert!(e.contains(t), "{e}");
    }
}

#[test]
fn non_finite_learner_stops_and_keeps_the_last_good_checkpoint() {
    let d = scratch("nonfinite");
    let run = d.join("run");
    // Learning starts after the first checkpoint (step 1000); an absurd critic step size then
    // overflows the critic within a few updates.
    let out = tiny(
        &run,
        3000,
        &[
            "--set",
            "schedule.warmup_steps=1004",
            "--set",
            "mpo.critic_lr=1e30",
        ],
    );
    let e = err_text(&out);
    assert!(
        e.contains("non-finite") || e.contains("learner statistic"),
        "{e}"
    );
    assert!(
        e.contains("last good checkpoint (environment step 1000)"),
        "{e}"
    );
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("checkpoint").join("meta.json")).unwrap())
            .unwrap();
    assert_eq!(meta["env_steps"], 1000);
    // The kept checkpoint is intact and usable.
    let out = mpo(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--episodes",
        "1",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
