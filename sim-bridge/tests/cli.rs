//! The `sim-bridge` command end to end: a replay agrees with dm_control's recording, and every bad
//! input gets a clear message and exit status 1, never a panic.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};

const BIN: &str = env!("CARGO_BIN_EXE_sim-bridge");

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("sim-bridge-cli-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn file(&self, name: &str, contents: &str) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, contents).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn run(bin: &Path, args: &[&str]) -> Output {
    Command::new(bin)
        .args(args)
        .env_remove("LD_LIBRARY_PATH")
        .output()
        .unwrap()
}

fn replay(task: &str, actions: &Path) -> Output {
    run(
        Path::new(BIN),
        &[
            "replay",
            "--task",
            task,
            "--seed",
            "3",
            "--actions",
            actions.to_str().unwrap(),
        ],
    )
}

/// Asserts a clean failure: status 1, no stdout, a one-line `error:` message containing `needles`.
fn assert_fails_with(out: &Output, needles: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "status; stderr: {stderr}");
    assert!(
        out.stdout.is_empty(),
        "no partial output expected, got {}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(stderr.starts_with("error: "), "{stderr}");
    assert!(
        !stderr.contains("panicked") && !stderr.contains("RUST_BACKTRACE"),
        "{stderr}"
    );
    for needle in needles {
        assert!(stderr.contains(needle), "expected '{needle}' in: {stderr}");
    }
    stderr
}

fn rows(n: usize, width: usize) -> String {
    (0..n)
        .map(|i| {
            let row: Vec<String> = (0..width)
                .map(|j| format!("{}", ((i * 7 + j) % 11) as f64 / 5.0 - 1.0))
                .collect();
            row.join(",") + "\n"
        })
        .collect()
}

#[test]
fn replay_prints_reset_then_every_step() {
    let dir = TempDir::new();
    let actions = dir.file("a.csv", &rows(5, 6));
    let out = replay("walker-walk", &actions);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 6);
    assert!(lines[0]["reward"].is_null() && lines[0]["discount"].is_null());
    for (i, line) in lines.iter().enumerate() {
        assert_eq!(line["step"], i);
        assert_eq!(line["obs"].as_array().unwrap().len(), 24);
        assert_eq!(line["qpos"].as_array().unwrap().len(), 9);
        assert_eq!(line["qvel"].as_array().unwrap().len(), 9);
        if i > 0 {
            assert_eq!(line["discount"], 1.0);
            assert!(line["reward"].as_f64().unwrap() >= 0.0);
        }
    }
}

/// The command's output for a recorded dm_control episode equals the recording (bit for bit for
/// the physics state; the recordings come from `scripts/setup-dm-reference`).
#[test]
fn replay_matches_a_dm_control_recording() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../.deps/dm_reference/hopper-hop_random-wide.jsonl");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|_| {
        panic!(
            "{} missing: run `scripts/setup-dm-reference`",
            path.display()
        )
    });
    let mut lines = text.lines();
    let header: serde_json::Value = serde_json::from_str(lines.next().unwrap()).unwrap();
    let episode = header["episodes"][0].as_array().unwrap();
    let csv: String = episode
        .iter()
        .map(|row| {
            let v: Vec<String> = row
                .as_array()
                .unwrap()
                .iter()
                .map(|x| format!("{:?}", x.as_f64().unwrap()))
                .collect();
            v.join(",") + "\n"
        })
        .collect();
    let dir = TempDir::new();
    let actions = dir.file("a.csv", &csv);
    let seed = header["seed"].to_string();
    let out = run(
        Path::new(BIN),
        &[
            "replay",
            "--task",
            "hopper-hop",
            "--seed",
            &seed,
            "--actions",
            actions.to_str().unwrap(),
        ],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ours = String::from_utf8(out.stdout).unwrap();
    let ours: Vec<serde_json::Value> = ours
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(ours.len(), episode.len() + 1);
    for (a, b) in ours.iter().zip(lines) {
        let b: serde_json::Value = serde_json::from_str(b).unwrap();
        assert_eq!(a["step"], b["step"]);
        assert_eq!(a["qpos"], b["qpos"], "step {}", a["step"]);
        assert_eq!(a["qvel"], b["qvel"], "step {}", a["step"]);
        let (ra, rb) = (a["reward"].as_f64(), b["reward"].as_f64());
        assert!(
            ra.zip(rb).is_none_or(|(x, y)| (x - y).abs() <= 1e-12) && ra.is_some() == rb.is_some()
        );
    }
}

#[test]
fn tasks_lists_every_task() {
    let out = run(Path::new(BIN), &["tasks"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for task in sim_bridge::TASKS {
        assert!(text.contains(task), "{task} missing from {text}");
    }
    assert!(
        text.contains("walker-run") && text.contains(" 24 "),
        "{text}"
    );
}

#[test]
fn unknown_task_lists_valid_tasks() {
    let dir = TempDir::new();
    let actions = dir.file("a.csv", &rows(3, 1));
    let out = replay("cartpole-juggle", &actions);
    assert_fails_with(
        &out,
        &[
            "cartpole-juggle",
            "cartpole-swingup",
            "cheetah-run",
            "walker-walk",
        ],
    );
}

#[test]
fn wrong_action_width_names_the_row() {
    let dir = TempDir::new();
    let actions = dir.file("a.csv", "0.1\n0.2,0.3\n0.4\n");
    assert_fails_with(
        &replay("cartpole-swingup", &actions),
        &["row 2", "2 actions", "takes 1"],
    );
}

#[test]
fn unparsable_row_is_named() {
    let dir = TempDir::new();
    let actions = dir.file("a.csv", "0,0,0,0\n0,0,zero,0\n");
    assert_fails_with(
        &replay("hopper-hop", &actions),
        &["row 2", "column 3", "'zero' is not a number"],
    );
    let actions = dir.file("b.csv", "0.5\n\n0.5\n");
    assert_fails_with(&replay("pendulum-swingup", &actions), &["row 2 is empty"]);
}

#[test]
fn non_finite_actions_are_rejected() {
    let dir = TempDir::new();
    for (i, bad) in ["nan", "NaN", "inf", "-inf", "infinity"].iter().enumerate() {
        let actions = dir.file(&format!("a{i}.csv"), &format!("0.5\n0.25\n{bad}\n"));
        assert_fails_with(
            &replay("acrobot-swingup", &actions),
            &["row 3", "not finite"],
        );
    }
}

#[test]
fn more_rows_than_the_episode_are_rejected() {
    let dir = TempDir::new();
    let actions = dir.file("a.csv", &rows(1001, 1));
    assert_fails_with(
        &replay("cartpole-balance", &actions),
        &["1001 rows", "1000 steps", "row 1001"],
    );
    // Exactly one episode is fine and ends with the last step.
    let actions = dir.file("b.csv", &rows(1000, 1));
    let out = replay("cartpole-balance", &actions);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(String::from_utf8(out.stdout).unwrap().lines().count(), 1001);
}

#[test]
fn missing_action_file_is_reported() {
    let out = replay("cartpole-balance", Path::new("/nonexistent/actions.csv"));
    assert_fails_with(
        &out,
        &["cannot read action file", "/nonexistent/actions.csv"],
    );
}

#[test]
fn bad_seed_is_a_usage_error_not_a_panic() {
    let out = run(
        Path::new(BIN),
        &[
            "replay",
            "--task",
            "cartpole-balance",
            "--seed",
            "-1",
            "--actions",
            "x.csv",
        ],
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
}

#[test]
fn missing_model_files_name_the_setup_command() {
    let dir = TempDir::new();
    let actions = dir.file("a.csv", &rows(3, 1));
    let out = Command::new(BIN)
        .args([
            "replay",
            "--task",
            "cartpole-balance",
            "--seed",
            "0",
            "--actions",
            actions.to_str().unwrap(),
        ])
        .env("SIM_BRIDGE_SUITE_DIR", dir.0.join("no-suite-here"))
        .output()
        .unwrap();
    assert_fails_with(&out, &["cartpole.xml", "scripts/setup-mujoco"]);
}

/// Copied elsewhere, the binaries' rpath ($ORIGIN/../../.deps/mujoco) no longer finds libmujoco:
/// the launcher must say so and how to fix it (the engine alone would die in the dynamic loader).
#[test]
fn missing_mujoco_library_names_the_setup_command() {
    let dir = TempDir::new();
    let bin_dir = dir.0.join("a/b/c");
    std::fs::create_dir_all(&bin_dir).unwrap();
    let engine = Path::new(BIN).with_file_name("sim-bridge-engine");
    std::fs::copy(BIN, bin_dir.join("sim-bridge")).unwrap();
    std::fs::copy(&engine, bin_dir.join("sim-bridge-engine")).unwrap();
    let actions = dir.file("a.csv", &rows(3, 1));
    let out = run(
        &bin_dir.join("sim-bridge"),
        &[
            "replay",
            "--task",
            "cartpole-balance",
            "--seed",
            "0",
            "--actions",
            actions.to_str().unwrap(),
        ],
    );
    assert_fails_with(
        &out,
        &[
            "libmujoco.so.3.17.0",
            "scripts/setup-mujoco",
            "LD_LIBRARY_PATH",
        ],
    );

    // The engine on its own indeed cannot start (this is what the launcher guards against).
    let raw = run(&bin_dir.join("sim-bridge-engine"), &["tasks"]);
    assert_eq!(raw.status.code(), Some(127));

    // With the library on LD_LIBRARY_PATH the copied command works again.
    let lib_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/mujoco");
    let out = Command::new(bin_dir.join("sim-bridge"))
        .arg("tasks")
        .env("LD_LIBRARY_PATH", lib_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn launcher_without_engine_says_how_to_build_it() {
    let dir = TempDir::new();
    let bin_dir = dir.0.join("x/y");
    std::fs::create_dir_all(&bin_dir).unwrap();
    std::fs::copy(BIN, bin_dir.join("sim-bridge")).unwrap();
    let out = Command::new(bin_dir.join("sim-bridge"))
        .arg("tasks")
        .env(
            "LD_LIBRARY_PATH",
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/mujoco"),
        )
        .output()
        .unwrap();
    assert_fails_with(&out, &["sim-bridge-engine", "cargo build -p sim-bridge"]);
}

#[test]
fn engine_from_other_sources_is_refused() {
    let engine = Path::new(BIN).with_file_name("sim-bridge-engine");
    let out = Command::new(engine)
        .arg("tasks")
        .env("SIM_BRIDGE_LAUNCHER_BUILD_ID", "0000")
        .output()
        .unwrap();
    assert_fails_with(&out, &["different sources", "cargo build -p sim-bridge"]);
}

/// `sim-bridge replay` and `scripts/dm_control_replay.py replay` (dm_control itself) print the same
/// schema and the same trajectory for the same file: states bit for bit, obs and rewards to 1e-12.
#[test]
fn replay_agrees_with_the_dm_control_replay_script() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = root.join(".deps/venv/bin/python");
    assert!(
        python.is_file(),
        "{} missing: run `scripts/setup-dm-reference`",
        python.display()
    );
    let dir = TempDir::new();
    // Walker (6 actuators): sinusoids beyond the control range, then a stretch of zeros.
    let csv: String = (0..300)
        .map(|t| {
            let row: Vec<String> = (0..6)
                .map(|j| {
                    if t >= 250 {
                        "0".to_string()
                    } else {
                        format!("{:?}", 1.5 * ((t as f64) / 9.0 + j as f64).sin())
                    }
                })
                .collect();
            row.join(",") + "\n"
        })
        .collect();
    let actions = dir.file("a.csv", &csv);
    let args = [
        "replay",
        "--task",
        "walker-run",
        "--seed",
        "11",
        "--actions",
        actions.to_str().unwrap(),
    ];
    let ours = run(Path::new(BIN), &args);
    let theirs = Command::new(&python)
        .arg(root.join("scripts/dm_control_replay.py"))
        .args(args)
        .env("MUJOCO_GL", "disable")
        .output()
        .unwrap();
    assert!(
        ours.status.success() && theirs.status.success(),
        "{}",
        String::from_utf8_lossy(&theirs.stderr)
    );
    let parse = |out: &[u8]| -> Vec<serde_json::Value> {
        String::from_utf8_lossy(out)
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    };
    let (ours, theirs) = (parse(&ours.stdout), parse(&theirs.stdout));
    assert_eq!(ours.len(), 301);
    assert_eq!(ours.len(), theirs.len());
    for (a, b) in ours.iter().zip(&theirs) {
        let keys =
            |v: &serde_json::Value| v.as_object().unwrap().keys().cloned().collect::<Vec<_>>();
        assert_eq!(keys(a), keys(b), "same schema");
        assert_eq!(a["step"], b["step"]);
        assert_eq!(a["qpos"], b["qpos"], "step {}", a["step"]);
        assert_eq!(a["qvel"], b["qvel"], "step {}", a["step"]);
        assert_eq!(a["discount"], b["discount"]);
        for (x, y) in a["obs"]
            .as_array()
            .unwrap()
            .iter()
            .zip(b["obs"].as_array().unwrap())
        {
            assert!(
                (x.as_f64().unwrap() - y.as_f64().unwrap()).abs() <= 1e-12,
                "step {}",
                a["step"]
            );
        }
        match (a["reward"].as_f64(), b["reward"].as_f64()) {
            (Some(x), Some(y)) => assert!((x - y).abs() <= 1e-12, "step {}", a["step"]),
            (x, y) => assert_eq!(x, y),
        }
    }
}
