//! Environment steps per second for every task, side by side in one run with
//! - raw `mj_step` x n_sub_steps on the same model and data (the floor: MuJoCo alone),
//! - the environment's physics step sequence alone (dm_control's legacy sequence, see
//!   `Physics::step_synced`), so the wrapper's own cost (observation, reward, bookkeeping) shows,
//! - dm_control's Python `env.step` (what users would otherwise run), timed by the venv python.
//!
//! Run: `cargo bench -p sim-bridge --bench env_step` (needs scripts/setup-mujoco; the Python
//! column needs scripts/setup-dm-control and is shown as n/a without it). Each figure is the best
//! of 7 rounds of the mean time per control step (random actions in [-1, 1], resets untimed);
//! rounds of the three Rust loops are interleaved.

use std::hint::black_box;
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use sim_bridge::numpy_rng::RandomState;
use sim_bridge::physics::{Physics, Sync};
use sim_bridge::{Environment, SuiteEnv, TASKS};

const ROUNDS: usize = 7;
/// Wall-clock target per timed round.
const ROUND_SECONDS: f64 = 0.1;

/// The fastest round: on a shared, noisy machine interference only ever adds time, so the
/// minimum is the most repeatable estimate of the intrinsic cost (and of ratios between loops).
fn best(v: Vec<f64>) -> f64 {
    v.into_iter().fold(f64::INFINITY, f64::min)
}

/// Mean seconds per control step over `actions` with the full environment. Each episode-long
/// chunk starts from a (untimed) reset.
#[inline(never)]
fn time_env(env: &mut SuiteEnv, actions: &[Vec<f64>], obs: &mut [f64]) -> f64 {
    let episode = env.spec().episode_steps;
    let mut elapsed = 0.0;
    for chunk in actions.chunks(episode) {
        env.reset(obs);
        let t0 = Instant::now();
        for a in chunk {
            black_box(env.step(black_box(a), obs));
        }
        elapsed += t0.elapsed().as_secs_f64();
        black_box(&obs);
    }
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
        if legacy {
            legacy_loop(physics, chunk, n, sync);
        } else {
            raw_loop(physics, chunk, n);
        }
        elapsed += t0.elapsed().as_secs_f64();
        black_box(physics.qpos());
    }
    elapsed / actions.len() as f64
}

/// Separate, non-inlined loops so that `valgrind --tool=callgrind` can count each one's
/// instructions (see docs/sim-bridge.md).
#[inline(never)]
fn legacy_loop(physics: &mut Physics, actions: &[Vec<f64>], n: usize, sync: Sync) {
    for a in actions {
        physics.ctrl_mut().copy_from_slice(black_box(a));
        physics.step_synced(n, sync);
    }
}

#[inline(never)]
fn raw_loop(physics: &mut Physics, actions: &[Vec<f64>], n: usize) {
    for a in actions {
        physics.ctrl_mut().copy_from_slice(black_box(a));
        physics.raw_step(n);
    }
}

/// dm_control's `env.step`, timed in the venv's python; None when the venv is not set up.
fn time_python(task: &str, steps: usize) -> Option<f64> {
    if std::env::var_os("SIM_BRIDGE_BENCH_NO_PYTHON").is_some() {
        return None;
    }
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
        // One environment per loop, identically seeded: every loop resets to the same initial
        // states, so env.step and the legacy sequence run bit-identical trajectories.
        let new_env = || SuiteEnv::new(task, 0).expect("run scripts/setup-mujoco first");
        let (mut probe_env, mut env, mut legacy_env, mut raw_env) =
            (new_env(), new_env(), new_env(), new_env());
        let spec = env.spec().clone();
        let mut obs = vec![0.0; spec.obs_dim];
        let mut rng = RandomState::new(1);
        let mut draw = |n: usize| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| (0..spec.act_dim).map(|_| rng.uniform(-1.0, 1.0)).collect())
                .collect()
        };
        // Calibrate the round length on a short run.
        let per_step = time_physics(&mut probe_env, &draw(200), &mut obs, false);
        let steps = ((ROUND_SECONDS / per_step) as usize).clamp(500, 50_000);
        let actions = draw(steps);
        // For instruction counting (scripts/bench-instructions): each loop runs ROUNDS * steps.
        eprintln!("{task}: {steps} control steps per round");
        let (mut env_t, mut legacy_t, mut raw_t) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..ROUNDS {
            env_t.push(time_env(&mut env, &actions, &mut obs));
            legacy_t.push(time_physics(&mut legacy_env, &actions, &mut obs, true));
            raw_t.push(time_physics(&mut raw_env, &actions, &mut obs, false));
        }
        let (e, l, r) = (best(env_t), best(legacy_t), best(raw_t));
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
    load_times();
}

/// Model load time: MuJoCo's plain XML loader on the suite file (with the skybox texture) versus
/// sim-bridge's loader (skybox replaced by an empty include), best of 5 each.
fn load_times() {
    use mujoco_rs::prelude::MjModel;
    println!();
    println!(
        "{:<10} {:>16} {:>16}",
        "model", "with skybox ms", "sim-bridge ms"
    );
    for domain in [
        "cartpole", "hopper", "acrobot", "pendulum", "walker", "cheetah",
    ] {
        let path = sim_bridge::assets::suite_dir().join(format!("{domain}.xml"));
        let time = |f: &dyn Fn()| {
            best(
                (0..5)
                    .map(|_| {
                        let t0 = Instant::now();
                        f();
                        t0.elapsed().as_secs_f64()
                    })
                    .collect(),
            )
        };
        let plain = time(&|| drop(black_box(MjModel::from_xml(&path).expect("load"))));
        let ours = time(&|| {
            drop(black_box(
                sim_bridge::assets::load_model(domain).expect("load"),
            ))
        });
        println!("{:<10} {:>16.1} {:>16.1}", domain, plain * 1e3, ours * 1e3);
    }
}
