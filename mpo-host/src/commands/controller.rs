//! `mpo controller`: the policy in its own process.

use super::error::Error;
use crate::cli::ControllerArgs;
use crate::rows;

/// `mpo plant-worker`: a fleet's plant, until the learner stops it; returns its steps.
pub fn plant_worker(args: &crate::cli::PlantWorkerArgs) -> Result<u64, Error> {
    let run = mpo_link::RunId::parse(&args.run).map_err(|e| Error::Plant(e.to_string()))?;
    let task = match &args.task_file {
        Some(f) => sim_bridge::TaskDef::from_file(f).map_err(rows::RowError::from)?,
        None => rows::builtin(&args.task)?,
    };
    let row = rows::row(&task, &args.net)?;
    let instance = crate::registry::find(&row.sizes)?;
    // Ctrl-C in a terminal reaches the whole process group: the learner decides when its
    // plants stop (it finishes the episode, checkpoints, then sends STOP).
    let _ = ctrlc::set_handler(|| {});
    let remote = match (args.fleet_connect.is_empty(), args.fleet_tls.files()) {
        (true, None) => None,
        (true, Some(_)) => {
            return Err(Error::Plant(
                "--fleet-ca/--fleet-cert/--fleet-key secure --fleet-connect's link".into(),
            ));
        }
        (false, tls) => {
            let t = args.fleet_connect_timeout;
            if !(t.is_finite() && t > 0.0) {
                return Err(Error::Plant(
                    "--fleet-connect-timeout must be positive".into(),
                ));
            }
            let r = mpo_link::fleet::Remote {
                endpoints: args.fleet_connect.clone(),
                tls,
                connect_timeout: std::time::Duration::from_secs_f64(t),
            };
            crate::fleet::check_remote(&r).map_err(|e| Error::Plant(e.0))?;
            Some(r)
        }
    };
    let init = crate::fleet::worker::WorkerInit {
        run: &run,
        index: args.index,
        task: &task,
        net: &args.net,
        sizes: row.sizes,
        block_hint: args.block_hint,
        rate: args.rate,
        // A plant the learner started exits with it; one started by hand (a robot's program,
        // or any plant over zenoh) follows the run's learner through drops and restarts.
        spawned: args.spawned && remote.is_none(),
        remote: remote.as_ref(),
    };
    (instance.plant)(&init).map_err(Error::Plant)
}

/// `mpo controller`: serves the run until SIGINT/SIGTERM; returns its counters.
pub fn controller(args: &ControllerArgs) -> Result<mpo_link::controller::ControllerStats, Error> {
    let run = mpo_link::RunId::parse(&args.run).map_err(|e| Error::Controller(e.to_string()))?;
    let wait = mpo_link::WaitMode::parse(&args.wait)
        .ok_or_else(|| Error::Controller(format!("unknown wait mode {:?}", args.wait)))?;
    let task = match &args.task_file {
        Some(f) => sim_bridge::TaskDef::from_file(f).map_err(rows::RowError::from)?,
        None => rows::builtin(&args.task)?,
    };
    let row = rows::row(&task, &args.net)?;
    let instance = crate::registry::find(&row.sizes)?;
    if let Some(p) = args.realtime {
        if wait == mpo_link::WaitMode::BusyPoll {
            return Err(Error::Controller(
                "--realtime with --wait busy-poll would starve the core".into(),
            ));
        }
        mpo_link::realtime::enter(p).map_err(Error::Controller)?;
    }
    mpo_link::controller::install_stop_handler();
    let opts = mpo_link::controller::ControllerOptions {
        run,
        wait,
        seed: 0,
        init_std: row.mpo.init_std as f32,
    };
    let mut ready = || {
        use std::io::Write;
        let mut out = std::io::stdout();
        let _ = writeln!(out, "ready");
        let _ = out.flush();
    };
    (instance.serve)(&opts, &mut ready).map_err(|e| Error::Controller(e.to_string()))
}
