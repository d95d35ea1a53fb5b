//! Checkpoint round trip: what is restored saves back to the same bytes; the files are plain
//! safetensors with real shapes; `mpo eval` on a checkpoint repeats the run's evaluation.
//! Also the listings that read no checkpoint: `mpo tasks`, `mpo train --print-config`.

mod common;
use common::*;

use mpo_host::checkpoint;
use mpo_host::trainer::MlpTrainer as Trainer;
use safetensors::SafeTensors;

/// The `cartpole-balance`/`tiny` row's types.
type Tiny = Trainer<5, 1, 1, 32, 32, 32, 32, 32, 2, 4, 10, 10, 50_000>;

#[test]
fn restore_then_save_gives_the_same_bytes() {
    let d = scratch("roundtrip");
    let run = d.join("run");
    let summary = ok_json(&tiny(&run, 2000, &[]));
    let v = checkpoint::open(&run).unwrap();
    assert_eq!(v.meta.env_steps, 2000);
    assert_eq!(v.meta.episodes, 2);
    assert_eq!(
        v.meta.params_sha256,
        summary["params_sha256"].as_str().unwrap()
    );
    let t = Tiny::new(&v.meta.settings, Some(&v), 1).unwrap();
    assert_eq!(t.env_steps(), 2000);
    assert_eq!(t.agent.learner.updates, v.meta.updates);
    assert_eq!(t.agent.replay.len(), 2000);
    let copy = d.join("copy");
    std::fs::create_dir_all(&copy).unwrap();
    checkpoint::save(&copy, &t.agent.learner, &t.agent.replay, &v.meta).unwrap();
    for f in checkpoint::FILES.iter().chain([&checkpoint::SUMS]) {
        let a = std::fs::read(run.join("checkpoint").join(f)).unwrap();
        let b = std::fs::read(copy.join("checkpoint").join(f)).unwrap();
        assert!(a == b, "{f} differs after a round trip");
    }
    // Readable as plain safetensors, weights input-major with their real 2-D shapes.
    let bytes = std::fs::read(run.join("checkpoint/params.safetensors")).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(st.tensor("actor.l1.w").unwrap().shape(), &[5, 32]);
    assert_eq!(st.tensor("actor.chol.b").unwrap().shape(), &[1]);
    assert_eq!(st.tensor("critic.l1a.w").unwrap().shape(), &[1, 32]);
    assert_eq!(st.tensor("target_critic.out.w").unwrap().shape(), &[32, 1]);
    let w = st.tensor("actor.l1.w").unwrap();
    let first = f32::from_le_bytes(w.data()[..4].try_into().unwrap());
    assert_eq!(
        first.to_bits(),
        t.agent.learner.live.actor.l1.w[0][0].to_bits()
    );
    let bytes = std::fs::read(run.join("checkpoint/replay.safetensors")).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(st.tensor("obs").unwrap().shape(), &[2000, 5]);
}

#[test]
fn eval_repeats_the_runs_last_evaluation() {
    let d = scratch("evalrepeat");
    let run = d.join("run");
    let summary = ok_json(&tiny(&run, 1000, &[]));
    // The tiny row evaluates 3 episodes; `mpo eval` with the run's seed uses the same ones.
    let e = ok_json(&mpo(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--episodes",
        "3",
    ]));
    assert_eq!(e["return_mean"], summary["eval_return_mean"]);
    assert_eq!(e["checkpoint_env_steps"], 1000);
    // Another seed gives other episodes.
    let e2 = ok_json(&mpo(&[
        "eval",
        "--checkpoint",
        run.to_str().unwrap(),
        "--episodes",
        "3",
        "--seed",
        "7",
    ]));
    assert_ne!(e2["return_mean"], summary["eval_return_mean"]);
    for f in ["config.toml", "metrics.csv", "metrics.jsonl", "curve.png"] {
        assert!(run.join(f).exists(), "{f} missing");
    }
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    assert!(csv.starts_with("env_steps,updates,episodes,wall_s,eval_return_mean,eval_return_std"));
    assert_eq!(csv.lines().count(), 3, "header, untrained row, step 1000");
    let png = d.join("both.png");
    let out = mpo(&[
        "plot",
        "--out",
        png.to_str().unwrap(),
        run.to_str().unwrap(),
        run.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(std::fs::read(&png).unwrap().starts_with(b"\x89PNG"));
}

#[test]
fn tasks_lists_sizes() {
    let out = mpo(&["tasks"]);
    assert!(out.status.success());
    let s = String::from_utf8(out.stdout).unwrap();
    let line = s.lines().find(|l| l.starts_with("hopper-stand")).unwrap();
    let cols: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(&cols[1..3], &["15", "4"]);
    assert!(
        s.contains("--print-config"),
        "the listing points to the rows' settings"
    );
}

#[test]
fn print_config_is_the_config_toml_the_run_writes() {
    let d = scratch("print-config");
    let run = d.join("run");
    let flags = ["--seed", "3", "--set", "mpo.actor_lr=2e-4"];
    let printed = tiny(&run, 1000, &[&flags[..], &["--print-config"]].concat());
    assert!(printed.status.success(), "{printed:?}");
    assert!(!run.exists(), "--print-config created the run directory");
    ok_json(&tiny(&run, 1000, &flags));
    let written = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert_eq!(String::from_utf8(printed.stdout).unwrap(), written);

    // Resumed: the checkpoint's configuration with the new step count; a changed setting is
    // refused as it would be by the run itself.
    let dir = run.to_str().unwrap();
    let out = mpo(&[
        "train",
        "--resume",
        dir,
        "--steps",
        "3000",
        "--print-config",
    ]);
    assert!(out.status.success(), "{out:?}");
    let resumed = String::from_utf8(out.stdout).unwrap();
    assert_eq!(
        resumed,
        written.replace("\nsteps = 1000\n", "\nsteps = 3000\n")
    );
    assert_ne!(resumed, written);
    let refused = mpo(&[
        "train",
        "--resume",
        dir,
        "--set",
        "mpo.actor_lr=1e-3",
        "--print-config",
    ]);
    assert!(err_text(&refused).contains("actor_lr"));
}

#[test]
fn print_config_shows_the_row_and_the_overrides() {
    let table = |args: &[&str]| -> toml::Table {
        let out = mpo(&[&["train", "--print-config"], args].concat());
        assert!(out.status.success(), "{out:?}");
        String::from_utf8(out.stdout).unwrap().parse().unwrap()
    };
    let penalty = |t: &toml::Table| t["mpo"]["eps_penalty"].as_float().unwrap();
    let stand = table(&["--task", "hopper-stand"]);
    assert_eq!(stand["task"].as_str(), Some("hopper-stand"));
    assert_eq!(stand["network"]["obs"].as_integer(), Some(15));
    assert_eq!(penalty(&stand), 0.01);
    assert_eq!(penalty(&table(&["--task", "walker-stand"])), 0.1);
    let set = table(&["--task", "hopper-stand", "--set", "mpo.eps_penalty=0.05"]);
    assert_eq!(penalty(&set), 0.05);
}
