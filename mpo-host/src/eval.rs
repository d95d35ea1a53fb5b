//! Evaluation: the online policy's mean action, one episode per fresh environment.
//!
//! Every evaluation of a run uses the same environment seeds (see [`eval_env_seed`]), so
//! successive points of a learning curve differ only by the policy, and `mpo eval` on a
//! checkpoint reproduces the run's last evaluation exactly.

use sim_bridge::{SimError, TaskDef};

use crate::policy::Policy;

/// Environment seed of evaluation episode `i` of a run seeded `seed`:
/// `(2^31 + 1000 seed + i) mod 2^32`, far from the training environment's seed `seed`.
pub fn eval_env_seed(seed: u32, i: u32) -> u32 {
    (1u32 << 31)
        .wrapping_add(seed.wrapping_mul(1000))
        .wrapping_add(i)
}

/// Returns of `episodes` evaluation episodes of the policy `act` (observation to action; the
/// action, in the policy's `[-1, 1]`, is clipped there before the environment maps it onto the
/// actuators). Episode `i` runs on a fresh environment seeded [`eval_env_seed`]`(seed, i)`.
pub fn evaluate_with(
    task: &TaskDef,
    seed: u32,
    episodes: u32,
    act_fn: &mut dyn FnMut(&[f32], &mut [f32]),
) -> Result<Vec<f64>, SimError> {
    let spec = task.spec();
    let mut returns = Vec::with_capacity(episodes as usize);
    let (mut obs64, mut obs) = (vec![0f64; spec.obs_dim], vec![0f32; spec.obs_dim]);
    let (mut act, mut act64) = (vec![0f32; spec.act_dim], vec![0f64; spec.act_dim]);
    for i in 0..episodes {
        let mut env = crate::plant::make(task, eval_env_seed(seed, i))?;
        env.reset(&mut obs64);
        let mut ret = 0.0;
        loop {
            for (o, x) in obs.iter_mut().zip(&obs64) {
                *o = *x as f32;
            }
            act_fn(&obs, &mut act);
            for (o, a) in act64.iter_mut().zip(&act) {
                *o = a.clamp(-1.0, 1.0) as f64;
            }
            let step = env.try_step(&act64, &mut obs64)?;
            ret += step.reward;
            if step.last {
                break;
            }
        }
        returns.push(ret);
    }
    Ok(returns)
}

/// Returns of `episodes` evaluation episodes of `policy`'s mean action.
pub fn evaluate(
    policy: &dyn Policy,
    task: &TaskDef,
    seed: u32,
    episodes: u32,
) -> Result<Vec<f64>, SimError> {
    evaluate_with(task, seed, episodes, &mut |o, a| policy.mean_action(o, a))
}

/// Mean and population standard deviation.
pub fn mean_std(x: &[f64]) -> (f64, f64) {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}
