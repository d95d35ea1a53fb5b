//! Replays Gymnasium's own episodes (recorded by `scripts/gymnasium_replay.py record` into
//! `.deps/gym_reference/`) through the task files of `tasks/gymnasium/`: seeded initial states
//! (numpy's `Generator(PCG64)` stream, continued across resets), physics states, observations
//! and rewards must be bit-identical, termination must come with discount 0 on the same step,
//! and truncation (the 1000-step limit) must end the episode with discount 1.
//!
//! Missing recordings fail the test (they are never skipped): run `scripts/setup-dm-reference`.

use std::path::{Path, PathBuf};

use serde_json::Value;
use sim_bridge::{Environment, SuiteEnv, TaskDef};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn reference_dir() -> PathBuf {
    match std::env::var_os("SIM_BRIDGE_GYM_REFERENCE_DIR") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => repo().join(".deps/gym_reference"),
    }
}

fn floats(v: &Value, what: &str) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("{what} is not an array"))
        .iter()
        .map(|x| {
            x.as_f64()
                .unwrap_or_else(|| panic!("{what} holds a non-number"))
        })
        .collect()
}

fn same_bits(at: &str, name: &str, ours: &[f64], theirs: &[f64]) {
    assert_eq!(theirs.len(), ours.len(), "{at}: {name} length");
    for (i, (a, b)) in ours.iter().zip(theirs).enumerate() {
        assert_eq!(
            a.to_bits(),
            b.to_bits(),
            "{at}: {name}[{i}] = {a:e}, Gymnasium {b:e}"
        );
    }
}

/// Compares one recorded line with the environment after a reset (`outcome` None) or a step.
fn compare(at: &str, line: &Value, outcome: Option<sim_bridge::Step>, obs: &[f64], env: &SuiteEnv) {
    same_bits(at, "qpos", env.qpos(), &floats(&line["qpos"], "qpos"));
    same_bits(at, "qvel", env.qvel(), &floats(&line["qvel"], "qvel"));
    same_bits(at, "obs", obs, &floats(&line["obs"], "obs"));
    let Some(s) = outcome else {
        assert!(line["reward"].is_null(), "{at}: reset line");
        return;
    };
    let reward = line["reward"].as_f64().expect("reward");
    assert_eq!(
        s.reward.to_bits(),
        reward.to_bits(),
        "{at}: reward {:e}, Gymnasium {reward:e}",
        s.reward
    );
    let terminated = line["terminated"].as_bool().unwrap();
    let truncated = line["truncated"].as_bool().unwrap();
    assert_eq!(
        s.discount,
        if terminated { 0.0 } else { 1.0 },
        "{at}: discount (Gymnasium terminated = {terminated})"
    );
    assert_eq!(
        s.last,
        terminated || truncated,
        "{at}: last (Gymnasium terminated = {terminated}, truncated = {truncated})"
    );
}

/// Replays one recording; returns (task, steps compared).
fn replay_file(path: &Path) -> (String, usize) {
    let file = path.file_name().unwrap().to_string_lossy().into_owned();
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap());
    let header = lines.next().expect("header line");
    let task = header["task"].as_str().unwrap().to_string();
    let seed = u32::try_from(header["seed"].as_u64().unwrap()).unwrap();
    let def = TaskDef::from_file(&repo().join(format!("tasks/gymnasium/{task}.toml")))
        .unwrap_or_else(|e| panic!("{file}: {e}"));
    let mut env = def.make(seed).unwrap_or_else(|e| panic!("{file}: {e}"));
    let mut obs = vec![0.0; def.spec().obs_dim];
    let mut steps = 0;
    for (episode, rows) in header["episodes"].as_array().unwrap().iter().enumerate() {
        env.reset(&mut obs);
        let at = format!("{file}, episode {episode}, reset");
        compare(&at, &lines.next().expect("reset line"), None, &obs, &env);
        for (i, row) in rows.as_array().unwrap().iter().enumerate() {
            let outcome = env.step(&floats(row, "action"), &mut obs);
            let line = lines
                .next()
                .unwrap_or_else(|| panic!("{file}: episode {episode} ends early"));
            let at = format!("{file}, episode {episode}, step {}", i + 1);
            assert_eq!(line["step"].as_u64(), Some(i as u64 + 1), "{at}");
            compare(&at, &line, Some(outcome), &obs, &env);
            steps += 1;
        }
    }
    assert!(lines.next().is_none(), "{file}: extra lines");
    (task, steps)
}

#[test]
fn replays_gymnasium_recordings_exactly() {
    let dir = reference_dir();
    let complete = dir.join("COMPLETE");
    assert!(
        complete.is_file(),
        "Gymnasium reference recordings are missing ({} not found): run `scripts/setup-dm-reference` \
         from the repository root (it sets up MuJoCo, the venv with Gymnasium and records them)",
        complete.display()
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "jsonl"))
        .collect();
    files.sort();
    let done: Vec<(String, usize)> = files.iter().map(|p| replay_file(p)).collect();
    for task in ["InvertedDoublePendulum-v5", "HalfCheetah-v5"] {
        let n: usize = done.iter().filter(|(t, _)| t == task).map(|(_, n)| n).sum();
        assert!(
            n >= 2000,
            "{task}: only {n} steps recorded in {}; rerun scripts/setup-dm-reference",
            dir.display()
        );
    }
}
