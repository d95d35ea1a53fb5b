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

/// The repository's `tasks/gymnasium/<name>.toml`.
fn gymnasium_task(name: &str) -> sim_bridge::TaskDef {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../tasks/gymnasium/{name}.toml"));
    sim_bridge::TaskDef::from_file(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn gymnasium_task_files_load_from_files_and_are_not_built_in() {
    // (name, observation, action) of Gymnasium 1.4.0's v5 environments; dt = 5 x 0.01 s.
    for (name, obs, act) in [
        ("InvertedDoublePendulum-v5", 9, 1),
        ("HalfCheetah-v5", 17, 6),
    ] {
        assert!(!TASKS.contains(&name), "{name} must not be compiled in");
        let def = gymnasium_task(name);
        let s = def.spec();
        assert_eq!(
            (s.obs_dim, s.act_dim, s.episode_steps),
            (obs, act, 1000),
            "{name}"
        );
        assert_eq!(s.control_timestep, 0.01 * 5.0, "{name}");
        assert_eq!(
            def.convention(),
            sim_bridge::taskfile::Convention::Gymnasium
        );
        assert!(
            def.action_bounds().iter().all(|&b| b == (-1.0, 1.0)),
            "{name}"
        );
    }
    assert!(TASKS.iter().all(|t| !t.contains("v5")), "{TASKS:?}");
}

unsafe extern "C" {
    /// The C library's `pow`, which Python's `float ** float` and numpy's scalar `**` call.
    fn pow(x: f64, y: f64) -> f64;
}

#[test]
fn power_is_the_c_librarys_pow_and_square_is_a_product() {
    // A value where glibc 2.36's pow(x, 2) is one ulp above x * x (numpy's `np.float64(x) ** 2`
    // and Python's `x ** 2` give pow's result; `np.square(x)` gives x * x).
    let x = -1.439_494_399_547_860_4_f64;
    let dir = std::env::temp_dir().join(format!("sim-bridge-pow-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("pow.toml");
    std::fs::write(
        &path,
        format!(
            "model = \"suite:cartpole.xml\"\ntime_limit = 1.0\nreward = \"1\"\n\
             observation = [{{ name = \"p\", value = \"[q ** 2, square(q), q ** 3, q ** -1]\" }}]\n\
             [define]\nq = \"qpos('slider') + {x:?}\"\n"
        ),
    )
    .unwrap();
    let def = sim_bridge::TaskDef::from_file(&path).unwrap();
    let mut env = def.make(0).unwrap();
    let mut obs = vec![0.0; 4];
    env.reset(&mut obs);
    // At reset the slider is at 0: q is x.
    assert_eq!(env.qpos()[0], 0.0);
    // black_box: with a constant exponent LLVM would turn pow(x, 2.0) into x * x here.
    let c = |y| unsafe { pow(std::hint::black_box(x), std::hint::black_box(y)) };
    let want = [c(2.0), x * x, c(3.0), c(-1.0)];
    for (i, (a, b)) in obs.iter().zip(want).enumerate() {
        assert_eq!(a.to_bits(), b.to_bits(), "element {i}: {a:e} != {b:e}");
    }
}
