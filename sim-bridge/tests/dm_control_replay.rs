//! Replays dm_control's own trajectories (recorded by `scripts/dm_control_replay.py record` into
//! `.deps/dm_reference/`) through sim-bridge: physics states must be bit-identical, observations
//! and rewards within 1e-12, discounts equal, and the episode must end where dm_control's does.
//!
//! Missing recordings fail the test (they are never skipped): run `scripts/setup-dm-reference`.

use std::path::PathBuf;

use serde_json::Value;
use sim_bridge::{Environment, SuiteEnv, TASKS};

const TOLERANCE: f64 = 1e-12;

fn reference_dir() -> PathBuf {
    match std::env::var_os("SIM_BRIDGE_REFERENCE_DIR") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir),
        _ => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.deps/dm_reference"),
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

/// Compares one recorded line against sim-bridge's state after reset (`step == 0`) or a step.
fn compare(
    file: &str,
    line: &Value,
    step: usize,
    outcome: Option<sim_bridge::Step>,
    obs: &[f64],
    env: &SuiteEnv,
) {
    let at = format!("{file}, step {step}");
    assert_eq!(
        line["step"].as_u64(),
        Some(step as u64),
        "{at}: step number"
    );
    for (name, ours) in [("qpos", env.qpos()), ("qvel", env.qvel())] {
        let theirs = floats(&line[name], name);
        assert_eq!(theirs.len(), ours.len(), "{at}: {name} length");
        for (i, (a, b)) in ours.iter().zip(&theirs).enumerate() {
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "{at}: {name}[{i}] = {a:e}, dm_control {b:e}"
            );
        }
    }
    let theirs = floats(&line["obs"], "obs");
    assert_eq!(theirs.len(), obs.len(), "{at}: observation length");
    for (i, (a, b)) in obs.iter().zip(&theirs).enumerate() {
        assert!(
            (a - b).abs() <= TOLERANCE,
            "{at}: obs[{i}] = {a:e}, dm_control {b:e}"
        );
    }
    match outcome {
        None => {
            assert!(
                line["reward"].is_null() && line["discount"].is_null(),
                "{at}: reset line"
            );
        }
        Some(s) => {
            let reward = line["reward"].as_f64().expect("reward");
            assert!(
                (s.reward - reward).abs() <= TOLERANCE,
                "{at}: reward {} vs dm_control {reward}",
                s.reward
            );
            assert_eq!(
                Some(s.discount),
                line["discount"].as_f64(),
                "{at}: discount"
            );
        }
    }
}

/// Replays one recording file; returns its task.
fn replay_file(path: &std::path::Path) -> String {
    let file = path.file_name().unwrap().to_string_lossy().into_owned();
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap());
    let header = lines.next().expect("header line");
    let task = header["task"].as_str().unwrap().to_string();
    let seed = u32::try_from(header["seed"].as_u64().unwrap()).unwrap();
    let mut env = SuiteEnv::new(&task, seed).unwrap_or_else(|e| panic!("{file}: {e}"));
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    for (episode, rows) in header["episodes"].as_array().unwrap().iter().enumerate() {
        env.reset(&mut obs);
        compare(
            &file,
            &lines.next().expect("reset line"),
            0,
            None,
            &obs,
            &env,
        );
        let rows = rows.as_array().unwrap();
        for (i, row) in rows.iter().enumerate() {
            let action = floats(row, "action");
            let outcome = env.step(&action, &mut obs);
            let line = lines
                .next()
                .unwrap_or_else(|| panic!("{file}: episode {episode} ends early"));
            compare(&file, &line, i + 1, Some(outcome), &obs, &env);
            // dm_control's episode ends after episode_steps steps, and only there.
            assert_eq!(
                outcome.last,
                i + 1 == spec.episode_steps,
                "{file}: last flag at step {}",
                i + 1
            );
        }
    }
    assert!(lines.next().is_none(), "{file}: extra lines");
    task
}

#[test]
fn replays_dm_control_recordings_exactly() {
    let dir = reference_dir();
    let complete = dir.join("COMPLETE");
    assert!(
        complete.is_file(),
        "dm_control reference recordings are missing ({} not found): run `scripts/setup-dm-reference` \
         from the repository root (it sets up MuJoCo, the dm_control venv and records them)",
        complete.display()
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "jsonl"))
        .collect();
    files.sort();
    // Two threads: the machine has two cores and each file is independent.
    let (a, b) = files.split_at(files.len() / 2);
    let tasks: Vec<String> = std::thread::scope(|s| {
        let h = s.spawn(|| a.iter().map(|p| replay_file(p)).collect::<Vec<_>>());
        let mut tasks: Vec<String> = b.iter().map(|p| replay_file(p)).collect();
        tasks.extend(h.join().unwrap());
        tasks
    });
    for task in TASKS {
        let n = tasks.iter().filter(|t| t == task).count();
        assert!(
            n >= 4,
            "{task}: only {n} recordings in {}; rerun scripts/setup-dm-reference",
            dir.display()
        );
    }
}
