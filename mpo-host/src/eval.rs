//! Evaluation: the online policy's mean action, one episode per fresh environment.
//!
//! Every evaluation of a run uses the same environment seeds (see [`eval_env_seed`]), so
//! successive points of a learning curve differ only by the policy, and `mpo eval` on a
//! checkpoint reproduces the run's last evaluation exactly.

use mpo_core::learner::Learner;
use sim_bridge::SimError;

/// Environment seed of evaluation episode `i` of a run seeded `seed`:
/// `(2^31 + 1000 seed + i) mod 2^32`, far from the training environment's seed `seed`.
pub fn eval_env_seed(seed: u32, i: u32) -> u32 {
    (1u32 << 31)
        .wrapping_add(seed.wrapping_mul(1000))
        .wrapping_add(i)
}

/// Returns of `episodes` evaluation episodes of `learner`'s mean action.
pub fn evaluate<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const AH1: usize,
    const AH2: usize,
    const QH1: usize,
    const QH2: usize,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
>(
    learner: &Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>,
    task: &str,
    seed: u32,
    episodes: u32,
) -> Result<Vec<f64>, SimError> {
    evaluate_with(task, seed, episodes, |o, a| learner.mean_action(o, a))
}

/// Returns of `episodes` evaluation episodes of the policy `act` (observation to action; the
/// action is clipped to the actuator range [-1, 1] before it is applied).
pub fn evaluate_with<const OBS: usize, const ACT: usize>(
    task: &str,
    seed: u32,
    episodes: u32,
    mut act_fn: impl FnMut(&[f32; OBS], &mut [f32; ACT]),
) -> Result<Vec<f64>, SimError> {
    let mut returns = Vec::with_capacity(episodes as usize);
    let mut obs64 = [0f64; OBS];
    let mut obs = [0f32; OBS];
    let mut act = [0f32; ACT];
    let mut act64 = [0f64; ACT];
    for i in 0..episodes {
        let mut env = sim_bridge::make(task, eval_env_seed(seed, i))?;
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

/// Mean and population standard deviation.
pub fn mean_std(x: &[f64]) -> (f64, f64) {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}
