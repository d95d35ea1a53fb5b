//! Environment steps per second for every task, side by side in one run with
//! - raw `mj_step` x n_sub_steps on the same model and data (the floor: MuJoCo alone),
//! - the environment's physics step sequence alone (dm_control's legacy sequence, see
//!   `Physics::step_synced`), so the wrapper's own cost (observation, reward, bookkeeping) shows,
//! - dm_control's Python `env.step` (what users would otherwise run), timed by the venv python.
//!
//! Run: `cargo bench -p sim-bridge --bench env_step` (needs scripts/setup-mujoco; the Python
//! column needs scripts/setup-dm-control and is shown as n/a without it). Each figure is the median
//! of 5 rounds of the mean time per control step; rounds of the three Rust loops are interleaved.

use std::hint::black_box;
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use sim_bridge::numpy_rng::RandomState;
use sim_bridge::{Environment, SuiteEnv, TASKS};

const ROUNDS: usize = 5;
/// Wall-clock target per timed round.
const ROUND_SECONDS: f64 = 0.15;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Mean seconds per control step over `actions` with the full environment (resets not timed).
fn time_env(env: &mut SuiteEnv, actions: &[Vec<f64>], obs: &mut [f64]) -> f64 {
    let mut elapsed = 0.0;
    let mut t0 = Instant::now();
    for a in actions {
        let step = env.step(black_box(a), obs);
        if step.last {
            elapsed += t0.elapsed().as_secs_f64();
            env.reset(obs);
            t0 = Instant::now();
        }
    }
    elapsed += t0.elapsed().as_secs_f64();
    black_box(&obs);
    elapsed / actions.len() as f64
}

/// Mean seconds per control step of physics alone: `legacy` picks the environment's step sequence
/// (dm_control's, see `Physics::step_synced`) or plain `mj_step` x n. Like `time_env`, it starts
/// from a reset and resets (untimed) every episode, so all loops see the same kind of states.
fn time_physics(env: &mut SuiteEnv, actions: &[Vec<f64>], obs: &mut [f64], legacy: bool) -> f64 {
    let n = env.n_sub_steps();
    let sync = env.sync();
    let episode = env.spec().episode_steps;
    let mut elapsed = 0.0;
    for chunk in actions.chunks(episode) {
        env.reset(obs);
        let physics = env.physics_mut();
        let t0 = Instant::now();
        for a in chunk {
            physics.ctrl_mut().copy_from_slice(black_box(a));
            if legacy {
                physics.step_synced(n, sync);
            } else {
                physics.raw_step(n);
            }
        }
        elapsed += t0.elapsed().as_secs_f64();
        black_box(physics.qpos());
    }
    elapsed / actions.len() as f64
}

/// dm_control's `env.step`, timed in the venv's python; None when the venv is not set up.
fn time_python(task: &str, steps: usize) -> Option<f64> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = root.join(".deps/venv/bin/python");
    if !python.is_file() {
        return None;
    }
    let out = Command::new(python)
        .arg(root.join("scripts/dm_control_replay.py"))
        .args([
            "time",
            "--task",
            task,
            "--steps",
            &steps.to_string(),
            "--rounds",
            &ROUNDS.to_string(),
        ])
        .env("MUJOCO_GL", "disable")
        .output()
        .ok()?;
    if !out.status.success() {
        eprintln!(
            "python timing failed for {task}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    v["seconds_per_step"].as_f64()
}

fn main() {
    // `cargo bench` passes `--bench`; a filter argument selects tasks.
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    println!(
        "{:<17} {:>3} {:>10} {:>10} {:>10} {:>9} {:>9} {:>11} {:>8}",
        "task",
        "n",
        "raw mj_step",
        "legacy",
        "env.step",
        "wrapper",
        "vs raw",
        "dm_control",
        "speedup"
    );
    println!(
        "{:<17} {:>3} {:>10} {:>10} {:>10} {:>9} {:>9} {:>11} {:>8}",
        "", "", "us/step", "us/step", "us/step", "overhead", "overhead", "us/step", "x"
    );
    for task in TASKS
        .iter()
        .filter(|t| filter.is_empty() || filter.iter().any(|f| t.contains(f.as_str())))
    {
        let mut env = SuiteEnv::new(task, 0).expect("run scripts/setup-mujoco first");
        let spec = env.spec().clone();
        let mut obs = vec![0.0; spec.obs_dim];
        env.reset(&mut obs);
        let mut rng = RandomState::new(1);
        let mut draw = |n: usize| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| (0..spec.act_dim).map(|_| rng.uniform(-1.0, 1.0)).collect())
                .collect()
        };
        // Calibrate the round length on a short run.
        let probe = draw(200);
        let per_step = time_env(&mut env, &probe, &mut obs);
        let steps = ((ROUND_SECONDS / per_step) as usize).clamp(500, 50_000);
        let actions = draw(steps);
        let (mut env_t, mut legacy_t, mut raw_t) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..ROUNDS {
            env.reset(&mut obs);
            env_t.push(time_env(&mut env, &actions, &mut obs));
            legacy_t.push(time_physics(&mut env, &actions, &mut obs, true));
            raw_t.push(time_physics(&mut env, &actions, &mut obs, false));
        }
        let (e, l, r) = (median(env_t), median(legacy_t), median(raw_t));
        let py = time_python(task, steps.min(3000));
        let us = 1e6;
        println!(
            "{:<17} {:>3} {:>10.2} {:>10.2} {:>10.2} {:>8.1}% {:>8.1}% {:>11} {:>8}",
            task,
            env.n_sub_steps(),
            r * us,
            l * us,
            e * us,
            (e / l - 1.0) * 100.0,
            (e / r - 1.0) * 100.0,
            py.map_or("n/a".into(), |p| format!("{:.2}", p * us)),
            py.map_or("n/a".into(), |p| format!("{:.1}", p / e)),
        );
    }
}
