//! `mpo run`.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use super::error::Error;
use crate::cli::RunArgs;
use crate::link::{ControllerTarget, LinkOptions};
use crate::run::{Limit, Pacing, RunRequest, RunSummary};
use crate::settings::SettingsError;

/// `mpo run`: the checkpoint's policy on its task, paced or in lockstep.
pub fn run(args: &RunArgs, interrupt: &AtomicBool) -> Result<RunSummary, Error> {
    let invalid = |m: String| Error::from(SettingsError::Invalid(m));
    let pacing = if args.lockstep {
        Pacing::Lockstep
    } else if args.rate.is_finite() && args.rate > 0.0 && args.rate <= 100_000.0 {
        Pacing::Paced(args.rate)
    } else {
        return Err(invalid(format!(
            "--rate {} must be in (0, 100000] Hz",
            args.rate
        )));
    };
    let limit = match args.steps {
        Some(0) => return Err(invalid("--steps must be at least 1".into())),
        Some(n) => Limit::Steps(n),
        None if args.seconds.is_finite() && args.seconds > 0.0 => Limit::Seconds(args.seconds),
        None => return Err(invalid("--seconds must be positive".into())),
    };
    if let Some(p) = args.realtime {
        if !(1..=99).contains(&p) {
            return Err(invalid(format!("--realtime {p}: priorities are 1-99")));
        }
        if args.link.wait == "busy-poll" {
            return Err(invalid(
                "--realtime with --wait busy-poll would starve the core".into(),
            ));
        }
    }
    // Paced: an answer later than half a period leaves too little of the period to step the
    // plant, so it counts as a miss.
    let default_deadline = match pacing {
        Pacing::Lockstep => super::train::LOCKSTEP_DEADLINE,
        Pacing::Paced(hz) => Duration::from_secs_f64(0.5 / hz),
    };
    let link =
        LinkOptions::from_args(&args.link, default_deadline, args.realtime).map_err(invalid)?;
    let t = super::trained::trained(&args.checkpoint)?;
    let m = &t.v.meta;
    let req = RunRequest {
        target: ControllerTarget::of(&m.settings),
        checkpoint_env_steps: m.env_steps,
        seed: args.seed.unwrap_or(m.settings.seed),
        task: t.task,
        pacing,
        limit,
        link,
        realtime: args.realtime,
        progress: !args.no_progress,
        interrupt,
    };
    Ok(crate::run::run(t.policy.as_ref(), req)?)
}
