//! What collecting experience shares between the in-process trainer ([`crate::trainer`]) and
//! a fleet's plant processes ([`crate::fleet`]): the agent's schedule from the settings, the
//! salt of the acting streams' seed, and one environment step with the transition it stores.
//! One copy of each, so a one-plant fleet and the in-process run draw and store the same bits.

use mpo_core::agent::AgentSchedule;
use mpo_core::replay::Transition;
use sim_bridge::{Environment, SimError};

use crate::settings::Settings;

/// Mixed into the run's seed for the collector and sampler root (the learner uses the seed
/// itself), so the streams differ.
pub const STREAM_SALT: u64 = 0x6d70_6f2d_686f_7374;

/// One environment step from `obs` with the behaviour policy's sample `act` (log-density
/// `log_prob`), and the transition it stores. The policy acts in [-1, 1] (the environment maps
/// it onto the actuators' ranges): the plant gets the clamped action, the replay keeps the
/// sample, and the reward pays `action_penalty` for what the clamp removed. Returns the
/// transition and whether the step ended the episode. The in-process trainer and a fleet's
/// plants step through this one function, so their transitions are the same bits.
pub fn env_step<const OBS: usize, const ACT: usize>(
    env: &mut dyn Environment,
    obs: &[f32; OBS],
    act: &[f32; ACT],
    log_prob: f32,
    action_penalty: f32,
    act64: &mut [f64; ACT],
    next64: &mut [f64; OBS],
) -> Result<(Transition<OBS, ACT>, bool), SimError> {
    for (o, a) in act64.iter_mut().zip(act) {
        *o = a.clamp(-1.0, 1.0) as f64;
    }
    let step = env.try_step(act64, next64)?;
    let mut excess = 0f32;
    for (a, c) in act.iter().zip(act64.iter()) {
        excess += (a - *c as f32) * (a - *c as f32);
    }
    let mut t = Transition {
        obs: *obs,
        action: *act,
        reward: step.reward as f32 - action_penalty * excess,
        next_obs: [0.0; OBS],
        discount: step.discount as f32,
        behaviour_log_prob: log_prob,
    };
    for (o, x) in t.next_obs.iter_mut().zip(next64.iter()) {
        *o = *x as f32;
    }
    Ok((t, step.last))
}

/// The agent's schedule from the run's settings.
pub fn agent_schedule(settings: &Settings) -> AgentSchedule {
    let s = &settings.schedule;
    AgentSchedule {
        warmup_steps: s.warmup_steps,
        update_interval: s.update_interval,
        updates_per_interval: s.updates_per_interval,
        n_step: match settings.mpo.policy_evaluation {
            crate::settings::PolicyEvaluation::NStep => settings.mpo.n_step,
            _ => 1,
        },
        noise_corr: s.noise_corr as f32,
        noise_pink: s.noise_pink,
    }
}
