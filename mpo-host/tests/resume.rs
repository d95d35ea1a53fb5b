//! Resuming continues bit-identically: N steps in one go versus N/2, then `--resume` to N,
//! and a run stopped by Ctrl-C then resumed.

mod common;
use common::*;

fn rows_without_wall(dir: &std::path::Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            let o = v.as_object_mut().unwrap();
            for k in ["wall_s", "env_steps_per_s", "updates_per_s"] {
                o.remove(k);
            }
            v
        })
        .collect()
}

#[test]
fn half_then_resume_equals_uninterrupted() {
    let d = scratch("resume");
    let (a, b) = (d.join("whole"), d.join("split"));
    let whole = ok_json(&tiny(&a, 4000, &[]));
    let half = ok_json(&tiny(&b, 2000, &[]));
    assert_eq!(half["env_steps"], 2000);
    assert_ne!(half["params_sha256"], whole["params_sha256"]);
    let resumed = ok_json(&mpo(&[
        "train",
        "--no-progress",
        "--resume",
        b.to_str().unwrap(),
        "--steps",
        "4000",
    ]));
    assert_eq!(resumed["env_steps"], 4000);
    assert_eq!(resumed["updates"], whole["updates"]);
    assert_eq!(resumed["params_sha256"], whole["params_sha256"]);
    assert_eq!(resumed["eval_return_mean"], whole["eval_return_mean"]);
    // Metrics rows agree too, learner statistics included (the accumulator is checkpointed).
    assert_eq!(rows_without_wall(&a), rows_without_wall(&b));
    // The checkpoint of both runs holds the same bytes of parameters, moments and replay.
    for f in [
        "params.safetensors",
        "optimizer.safetensors",
        "replay.safetensors",
    ] {
        let x = std::fs::read(a.join("checkpoint").join(f)).unwrap();
        let y = std::fs::read(b.join("checkpoint").join(f)).unwrap();
        assert!(x == y, "{f} differs");
    }
}

#[test]
fn ctrl_c_checkpoints_at_an_episode_boundary_and_resume_matches() {
    let d = scratch("ctrlc");
    let (a, b) = (d.join("whole"), d.join("interrupted"));
    let steps = 20_000u64;
    let whole = ok_json(&tiny(&a, steps, &[]));

    let child = std::process::Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["train", "--net", "tiny", "--no-progress", "--steps"])
        .arg(steps.to_string())
        .arg("--out")
        .arg(&b)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Interrupt once the first checkpoint exists (the run is then well under way).
    let t0 = std::time::Instant::now();
    while !b.join("checkpoint").join("SHA256SUMS").exists() {
        assert!(t0.elapsed().as_secs() < 120, "no checkpoint appeared");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let pid = child.id().to_string();
    assert!(
        std::process::Command::new("kill")
            .args(["-INT", &pid])
            .status()
            .unwrap()
            .success()
    );
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(130), "stderr:\n{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let summary: serde_json::Value =
        serde_json::from_str(String::from_utf8(out.stdout).unwrap().trim()).unwrap();
    assert_eq!(summary["interrupted"], true);
    let stopped = summary["env_steps"].as_u64().unwrap();
    assert!(stopped < steps, "interrupted at {stopped}");
    assert_eq!(stopped % 1000, 0, "stopped at an episode boundary");
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(b.join("checkpoint").join("meta.json")).unwrap())
            .unwrap();
    assert_eq!(meta["env_steps"].as_u64(), Some(stopped));

    let resumed = ok_json(&mpo(&[
        "train",
        "--no-progress",
        "--resume",
        b.to_str().unwrap(),
    ]));
    assert_eq!(resumed["env_steps"].as_u64(), Some(steps));
    assert_eq!(resumed["params_sha256"], whole["params_sha256"]);
}

/// The learner's thread count changes nothing: one, two and three threads give the same
/// parameters and metrics, for TD and for Retrace with action penalization, Polyak targets,
/// the layer-normalised critic, observation normalisation and the clip before the critic,
/// and for correlated (AR(1)) and
/// pink exploration noise; and a run resumed on a different number of threads still matches.
#[test]
fn thread_count_does_not_change_a_bit() {
    let d = scratch("threads");
    let mut first = vec![];
    for (name, extra) in [
        ("td", &[][..]),
        (
            "retrace",
            &[
                "--set",
                "mpo.policy_evaluation=\"retrace\"",
                "--set",
                "mpo.n_step=3",
                "--set",
                "mpo.target_tau=0.01",
                "--set",
                "mpo.critic_layer_norm=true",
                "--set",
                "mpo.obs_norm_interval=200",
                "--set",
                "mpo.tanh_mean=true",
                "--set",
                "mpo.clip_critic_actions=true",
            ][..],
        ),
        ("noise", &["--set", "schedule.noise_corr=0.9"][..]),
        ("pink", &["--set", "schedule.noise_pink=true"][..]),
    ] {
        let mut sums = vec![];
        for threads in ["1", "2", "3"] {
            let dir = d.join(format!("{name}-{threads}"));
            let mut args = extra.to_vec();
            args.extend_from_slice(&["--threads", threads]);
            let s = ok_json(&tiny(&dir, 3000, &args));
            sums.push((s["params_sha256"].clone(), rows_without_wall(&dir)));
        }
        assert_eq!(sums[0], sums[1], "{name}: 1 vs 2 threads");
        assert_eq!(sums[0], sums[2], "{name}: 1 vs 3 threads");
        first.push(sums.swap_remove(0).0);
    }
    assert_ne!(
        first[0], first[2],
        "correlated noise left the run unchanged"
    );
    assert_ne!(first[0], first[3], "pink noise left the run unchanged");
    assert_ne!(first[2], first[3], "pink noise is the AR(1) noise");
    // 1000 steps on 3 threads, then resumed on 1 (with correlated noise too: the noise
    // restarts at the episode boundary a checkpoint is taken at, so nothing of it is lost).
    for (name, extra) in [
        ("td", &[][..]),
        ("noise", &["--set", "schedule.noise_corr=0.9"][..]),
        ("pink", &["--set", "schedule.noise_pink=true"][..]),
    ] {
        let dir = d.join(format!("{name}-switch"));
        let mut args = extra.to_vec();
        args.extend_from_slice(&["--threads", "3"]);
        ok_json(&tiny(&dir, 1000, &args));
        let resumed = ok_json(&mpo(&[
            "train",
            "--no-progress",
            "--resume",
            dir.to_str().unwrap(),
            "--steps",
            "3000",
            "--threads",
            "1",
        ]));
        let whole: serde_json::Value = serde_json::from_str(
            std::fs::read_to_string(d.join(format!("{name}-1/checkpoint/meta.json")))
                .unwrap()
                .as_str(),
        )
        .unwrap();
        assert_eq!(resumed["params_sha256"], whole["params_sha256"], "{name}");
    }
}
