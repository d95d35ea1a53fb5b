//! `mpo train --task-file`: a task file trains as a built-in task does (the same bits for the
//! same plant, sizes and settings), its checkpoint records the file and refuses a changed
//! one, and sizes the build lacks are asked for and reported with exit status 3.

mod common;
use common::*;

use std::path::{Path, PathBuf};

/// tasks/cartpole-balance.toml with a `[rows.tiny]` that is the built-in tiny row.
fn cartpole_with_tiny_row(dir: &Path, name: &str) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tasks/cartpole-balance.toml");
    let mut text = std::fs::read_to_string(src).unwrap();
    text.push_str(
        r#"
[rows.tiny]
actor = [32, 32]
critic = [32, 32]
batch = 64
chunks = 2
seq = 4
m = 10
n = 10
replay = 50_000
steps = 4_000
schedule = { warmup_steps = 500, update_interval = 4, eval_interval = 1_000, eval_episodes = 3, noise_corr = 0.0 }
mpo = { policy_evaluation = "td", n_step = 1, shared_samples = false }
"#,
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_task_file_trains_with_the_bits_of_the_built_in_task_and_records_itself() {
    let dir = scratch("task-file-bits");
    let file = cartpole_with_tiny_row(&dir, "my-cartpole");
    let (a, b) = (dir.join("builtin"), dir.join("file"));
    let builtin = ok_json(&tiny(&a, 2000, &["--threads", "1"]));
    let f = file.to_str().unwrap();
    let from_file = ok_json(&mpo(&[
        "train",
        "--task-file",
        f,
        "--net",
        "tiny",
        "--steps",
        "2000",
        "--threads",
        "1",
        "--no-progress",
        "--out",
        b.to_str().unwrap(),
    ]));
    assert_eq!(from_file["task"], "my-cartpole");
    assert_eq!(
        builtin["params_sha256"], from_file["params_sha256"],
        "the same plant, sizes and settings from a file must give the built-in run's bits"
    );
    assert_eq!(builtin["eval_return_mean"], from_file["eval_return_mean"]);

    let config = std::fs::read_to_string(b.join("config.toml")).unwrap();
    assert!(config.contains("task_file = "), "{config}");
    let meta = std::fs::read_to_string(b.join("checkpoint/meta.json")).unwrap();
    let meta: serde_json::Value = serde_json::from_str(&meta).unwrap();
    assert_eq!(
        meta["task_file"]["text"].as_str().unwrap(),
        std::fs::read_to_string(&file).unwrap()
    );

    // Evaluating the checkpoint repeats the run's last evaluation (the file's task).
    let eval = ok_json(&mpo(&[
        "eval",
        "--checkpoint",
        b.to_str().unwrap(),
        "--episodes",
        "3",
    ]));
    assert_eq!(eval["return_mean"], from_file["eval_return_mean"]);

    // A changed file is refused, naming the file and what changed, by every command.
    let original = std::fs::read_to_string(&file).unwrap();
    std::fs::write(&file, original.replace("margin=2)", "margin=3)")).unwrap();
    let cp = b.to_str().unwrap();
    for args in [
        vec!["eval", "--checkpoint", cp],
        vec![
            "export",
            "--checkpoint",
            cp,
            "--out",
            dir.join("exp").to_str().unwrap(),
        ],
        vec!["train", "--resume", cp, "--steps", "3000", "--no-progress"],
    ] {
        let e = err_text(&mpo(&args));
        assert!(e.contains("changed since the checkpoint"), "{args:?}: {e}");
        assert!(e.contains("its text changed") && e.contains(f), "{e}");
    }
    assert!(!dir.join("exp").exists(), "nothing half-written");
    // Restored, the run resumes.
    std::fs::write(&file, original).unwrap();
    let resumed = ok_json(&mpo(&[
        "train",
        "--resume",
        cp,
        "--steps",
        "3000",
        "--no-progress",
    ]));
    assert_eq!(resumed["env_steps"], 3000);
}

#[test]
fn sizes_the_build_lacks_are_requested_with_exit_status_3() {
    let dir = scratch("task-file-sizes");
    let file = cartpole_with_tiny_row(&dir, "odd-cartpole");
    let text = std::fs::read_to_string(&file)
        .unwrap()
        .replace("actor = [32, 32]", "actor = [24, 40]");
    std::fs::write(&file, text).unwrap();
    let local = dir.join("local.toml");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args([
            "train",
            "--task-file",
            file.to_str().unwrap(),
            "--net",
            "tiny",
        ])
        .args(["--no-progress", "--out", dir.join("run").to_str().unwrap()])
        .env("MPO_LOCAL_SIZES", &local)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("actor 24-40") && stderr.contains("rebuild"),
        "{stderr}"
    );
    let asked = std::fs::read_to_string(&local).unwrap();
    assert!(asked.contains("actor = [24, 40]"), "{asked}");
    assert!(
        !dir.join("run").exists(),
        "nothing written before the learner exists"
    );
    // `mpo tasks --task-file` says the row is not in this build.
    let list = mpo(&["tasks", "--task-file", file.to_str().unwrap()]);
    let list = String::from_utf8_lossy(&list.stdout);
    assert!(
        list.lines()
            .any(|l| l.starts_with("odd-cartpole") && l.contains("not in this build")),
        "{list}"
    );
}

#[test]
fn bad_rows_in_a_task_file_name_the_file_and_key() {
    let dir = scratch("task-file-bad-rows");
    let file = cartpole_with_tiny_row(&dir, "bad");
    let f = file.to_str().unwrap();
    let cases = [
        (
            "batch = 64",
            "batch = 63",
            "rows.tiny: batch = 63 must be a multiple of chunks = 2",
        ),
        ("m = 10", "m = 0", "rows.tiny: m = 0 must be in"),
        ("steps = 4_000", "stepz = 4_000", "unknown field `stepz`"),
        (
            "eval_episodes = 3",
            "eval_episodez = 3",
            "rows.tiny.schedule",
        ),
    ];
    let original = std::fs::read_to_string(&file).unwrap();
    for (from, to, want) in cases {
        std::fs::write(&file, original.replace(from, to)).unwrap();
        let e = err_text(&mpo(&[
            "train",
            "--task-file",
            f,
            "--net",
            "tiny",
            "--print-config",
        ]));
        assert!(e.contains(f) && e.contains(want), "{to}: {e}");
    }
    std::fs::write(&file, &original).unwrap();
    let e = err_text(&mpo(&[
        "train",
        "--task-file",
        f,
        "--net",
        "huge",
        "--print-config",
    ]));
    assert!(e.contains("has no row `huge`; its rows are: tiny"), "{e}");
    let out = mpo(&["train", "--task-file", f, "--task", "walker-walk"]);
    assert_eq!(out.status.code(), Some(2), "a usage error");
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot be used with"));
}
