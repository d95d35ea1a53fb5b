//! The built-in tasks are task files; these pins hold the bits they gave when each was checked
//! against the Rust task logic it replaced (and that logic against dm_control, which
//! `dm_control_replay.rs` still checks): sha256 of states, observations, rewards and episode
//! ends over seeded resets and a fixed action sequence. An intended change of a task updates
//! `fixtures/task_trajectories.toml` (`SIM_BRIDGE_UPDATE_PINS=1`) with the reason in the commit.

use std::collections::BTreeMap;
use std::path::Path;

use sha2::{Digest, Sha256};
use sim_bridge::{Environment, SuiteEnv, TASKS};

/// A fixed pseudo-random action in [-1.2, 1.2] (beyond the actuators' range on purpose).
fn action(step: u64, k: usize) -> f64 {
    let mut x = step
        .wrapping_mul(0x9e37_79b9_7f4a_7c15)
        .wrapping_add((k as u64).wrapping_mul(0xbf58_476d_1ce4_e5b9));
    x ^= x >> 31;
    x = x.wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 53) as f64 * 2.4 - 1.2
}

/// sha256 of two episodes of `task` with `seed`: after each reset and step, qpos, qvel and
/// the observation, then reward, discount and `last` of the step.
fn trajectory_sha256(task: &str, seed: u32) -> String {
    let mut env = SuiteEnv::new(task, seed).unwrap();
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    let mut a = vec![0.0; spec.act_dim];
    let mut h = Sha256::new();
    let put = |h: &mut Sha256, v: &[f64]| v.iter().for_each(|x| h.update(x.to_le_bytes()));
    let mut t = 0;
    for _ in 0..2 {
        env.reset(&mut obs);
        put(&mut h, env.qpos());
        put(&mut h, env.qvel());
        put(&mut h, &obs);
        loop {
            for (k, x) in a.iter_mut().enumerate() {
                *x = action(t, k);
            }
            t += 1;
            let s = env.step(&a, &mut obs);
            put(&mut h, env.qpos());
            put(&mut h, env.qvel());
            put(&mut h, &obs);
            put(&mut h, &[s.reward, s.discount, f64::from(u8::from(s.last))]);
            if s.last {
                break;
            }
        }
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

#[test]
fn built_in_task_files_keep_the_bits_of_the_tasks_they_replaced() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/task_trajectories.toml");
    let mut got = BTreeMap::new();
    for task in TASKS {
        for seed in [0u32, 7] {
            got.insert(format!("{task}/{seed}"), trajectory_sha256(task, seed));
        }
    }
    if std::env::var_os("SIM_BRIDGE_UPDATE_PINS").is_some() {
        let mut text = String::from(
            "# sha256 of two seeded episodes of each built-in task (tests/task_files.rs).\n",
        );
        for (k, v) in &got {
            text.push_str(&format!("\"{k}\" = \"{v}\"\n"));
        }
        std::fs::write(&path, text).unwrap();
        return;
    }
    let pinned: BTreeMap<String, String> =
        toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(
        pinned.len(),
        got.len(),
        "one pin per built-in task and seed"
    );
    for (k, v) in &got {
        assert_eq!(pinned.get(k), Some(v), "{k}: the task's trajectory changed");
    }
}
