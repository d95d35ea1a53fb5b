//! `mpo eval`.

use serde::Serialize;

use super::error::Error;
use crate::cli::EvalArgs;
use crate::eval::{evaluate, mean_std};
use crate::settings::SettingsError;

/// What `mpo eval` prints.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct EvalSummary {
    /// Task.
    pub task: String,
    /// Environment steps of the checkpoint.
    pub checkpoint_env_steps: u64,
    /// Evaluation seed.
    pub seed: u32,
    /// Episodes.
    pub episodes: u32,
    /// Mean return.
    pub return_mean: f64,
    /// Population standard deviation of the returns.
    pub return_std: f64,
    /// Every episode's return.
    pub returns: Vec<f64>,
}

/// `mpo eval`: the checkpoint's mean-action policy on `--episodes` evaluation episodes.
pub fn eval(args: &EvalArgs) -> Result<EvalSummary, Error> {
    if args.episodes == 0 {
        return Err(SettingsError::Invalid("--episodes must be at least 1".into()).into());
    }
    let t = super::trained::trained(&args.checkpoint)?;
    let m = &t.v.meta;
    let seed = args.seed.unwrap_or(m.settings.seed);
    let returns = evaluate(t.policy.as_ref(), &t.task, seed, args.episodes)?;
    let (return_mean, return_std) = mean_std(&returns);
    Ok(EvalSummary {
        task: m.settings.task.clone(),
        checkpoint_env_steps: m.env_steps,
        seed,
        episodes: args.episodes,
        return_mean,
        return_std,
        returns,
    })
}
