//! The built-in task files against the Rust task logic they replace: the same seed and
//! action sequence must give the same bits of state, observation, reward and episode end.

use crate::{Environment, SuiteEnv, TaskDef};

/// A fixed pseudo-random action in [-1.2, 1.2] (beyond the actuators' range on purpose:
/// the controls are written unclipped and the control costs read them so).
fn action(step: u64, k: usize) -> f64 {
    let mut x = step
        .wrapping_mul(0x9e37_79b9_7f4a_7c15)
        .wrapping_add((k as u64).wrapping_mul(0xbf58_476d_1ce4_e5b9));
    x ^= x >> 31;
    x = x.wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 53) as f64 * 2.4 - 1.2
}

fn same(a: &[f64], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: length");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert_eq!(
            x.to_bits(),
            y.to_bits(),
            "{what}[{i}]: file {x:e}, Rust {y:e}"
        );
    }
}

#[test]
fn every_task_file_reproduces_the_rust_task_bit_for_bit() {
    for entry in crate::tasks::ENTRIES.iter() {
        let name = entry.name;
        for seed in [0, 7] {
            let mut file = TaskDef::builtin(name).unwrap().make(seed).unwrap();
            let mut rust = SuiteEnv::rust(name, seed).unwrap();
            assert_eq!(file.spec(), rust.spec(), "{name}");
            let spec = file.spec().clone();
            let (mut of, mut or) = (vec![0.0; spec.obs_dim], vec![0.0; spec.obs_dim]);
            let mut a = vec![0.0; spec.act_dim];
            let mut t = 0u64;
            // Three episodes: successive resets continue the RandomState stream.
            for episode in 0..3 {
                file.reset(&mut of);
                rust.reset(&mut or);
                let at = format!("{name} seed {seed} episode {episode}");
                same(&of, &or, &format!("{at} reset obs"));
                same(file.qpos(), rust.qpos(), &format!("{at} reset qpos"));
                same(file.qvel(), rust.qvel(), &format!("{at} reset qvel"));
                for s in 0..spec.episode_steps {
                    for (k, x) in a.iter_mut().enumerate() {
                        *x = action(t, k);
                    }
                    t += 1;
                    let sf = file.step(&a, &mut of);
                    let sr = rust.step(&a, &mut or);
                    let at = format!("{at} step {s}");
                    assert_eq!(
                        sf.reward.to_bits(),
                        sr.reward.to_bits(),
                        "{at} reward {} {}",
                        sf.reward,
                        sr.reward
                    );
                    assert_eq!((sf.discount, sf.last), (sr.discount, sr.last), "{at}");
                    same(&of, &or, &format!("{at} obs"));
                    same(file.qpos(), rust.qpos(), &format!("{at} qpos"));
                    same(file.qvel(), rust.qvel(), &format!("{at} qvel"));
                }
            }
        }
    }
}

#[test]
fn every_control_suite_task_reads_only_what_its_rust_twin_kept_current() {
    // cartpole and acrobot (RK4, poses only) skip the final mj_step1 as their Rust logic did.
    for name in ["cartpole-balance", "cartpole-swingup", "acrobot-swingup"] {
        let env = TaskDef::builtin(name).unwrap().make(0).unwrap();
        assert_eq!(env.sync(), crate::physics::Sync::Kinematics, "{name}");
    }
    let env = TaskDef::builtin("hopper-hop").unwrap().make(0).unwrap();
    assert_eq!(env.sync(), crate::physics::Sync::Full);
}
