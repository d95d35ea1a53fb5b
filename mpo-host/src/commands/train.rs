//! `mpo train`.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use super::error::Error;
use crate::cli::TrainArgs;
use crate::link::LinkOptions;
use crate::render::EvaluationStrips;
use crate::settings::{Settings, SettingsError};
use crate::train::{DeviceOptions, Summary, TrainRequest};

/// The deadline of a request in lockstep (training and `mpo run --lockstep` through a
/// controller): long enough that a descheduled controller on a loaded machine still answers,
/// so the run stays bit-identical to one in-process (100 ms was once missed under the whole
/// test suite on two vCPUs with a busy-polling controller); a dead controller costs a second
/// before the safe action and its restart.
pub(super) const LOCKSTEP_DEADLINE: Duration = Duration::from_secs(1);

/// `mpo train`.
pub fn train(args: &TrainArgs, interrupt: &AtomicBool) -> Result<Summary, Error> {
    // Training through a controller is lockstep: a miss would make the run differ.
    let link = LinkOptions::from_args(&args.link, LOCKSTEP_DEADLINE, None)
        .map_err(SettingsError::Invalid)?;
    let (resolved, out, mut resume) = super::config::resolve_train(args)?;
    if let Some(v) = &mut resume
        && crate::checkpoint::run_dir_of(&v.dir) == out
        && v.dir.parent() == Some(out.as_path())
    {
        // Continuing in the run directory: finish what a crash may have left mid-swap first,
        // so the checkpoint resumed from is `checkpoint/` from now on.
        crate::checkpoint::settle(&out)?;
        v.dir = out.join(crate::checkpoint::SUBDIR);
    }
    if let Some(v) = &resume {
        eprintln!(
            "resuming from {} at environment step {}",
            v.dir.display(),
            v.meta.env_steps
        );
    }
    let instance = crate::registry::find(&resolved.row.sizes)?;
    // `--render-every N`: a machine that cannot render says so before training starts.
    let render = match args.render_every {
        Some(n) => {
            let strips = EvaluationStrips::new(n)?;
            strips.check(&resolved.task)?;
            Some(strips)
        }
        None => None,
    };
    let device = device_options(args, &resolved.settings)?;
    let threads = match args.threads {
        Some(0) => return Err(invalid("--threads must be at least 1")),
        Some(n) => n,
        None => crate::pool::Pool::available(),
    };
    Ok(crate::train::run(TrainRequest {
        settings: resolved.settings,
        task: resolved.task,
        instance,
        out,
        resume,
        progress: !args.no_progress,
        interrupt,
        link,
        threads,
        device,
        render,
        fleet: fleet_options(args)?,
    })?)
}

/// `--plants N` (or `--plants-remote N`) and its flags, checked.
fn fleet_options(args: &TrainArgs) -> Result<Option<crate::fleet::FleetOptions>, Error> {
    use mpo_link::fleet::{frames, ipc};
    let tls = args.fleet_tls.files();
    if tls.is_some() && args.plants_remote.is_none() {
        return Err(invalid(
            "--fleet-ca/--fleet-cert/--fleet-key secure --plants-remote's link",
        ));
    }
    let mut run = None;
    let (plants, remote) = match (args.plants, args.plants_remote) {
        (None, None) => return Ok(None),
        (Some(n), _) => {
            if n == 0 || n > ipc::MAX_LOCAL {
                return Err(invalid(&format!(
                    "--plants must be 1 to {} on one host",
                    ipc::MAX_LOCAL
                )));
            }
            (n, None)
        }
        (None, Some(n)) => {
            if n == 0 || n > frames::MAX_PLANTS {
                return Err(invalid(&format!(
                    "--plants-remote must be 1 to {}",
                    frames::MAX_PLANTS
                )));
            }
            let listen = mpo_link::fleet::Remote {
                endpoints: args.fleet_listen.clone(),
                tls,
                // (a learner listens; it connects to nothing)
                connect_timeout: Duration::ZERO,
            };
            crate::fleet::check_remote(&listen).map_err(|e| invalid(&e.0))?;
            if let Some(r) = &args.fleet_run {
                run = Some(mpo_link::RunId::parse(r).map_err(|e| invalid(&e.0))?);
            }
            (n, Some(crate::fleet::RemoteOptions { listen }))
        }
    };
    let k = args.sync_every.unwrap_or(crate::fleet::DEFAULT_SYNC_EVERY);
    if k == 0 || k as usize > frames::MAX_BLOCK {
        return Err(invalid(&format!(
            "--sync-every must be 1 to {}",
            frames::MAX_BLOCK
        )));
    }
    if args.link.controller != crate::link::ControllerKind::InProcess {
        return Err(invalid(
            "--plants and --controller: a fleet's plants act with their own copy of the policy",
        ));
    }
    if let Some(r) = args.plant_rate
        && !(r.is_finite() && r > 0.0)
    {
        return Err(invalid("--plant-rate must be positive"));
    }
    if !(args.plant_timeout.is_finite() && args.plant_timeout > 0.0) {
        return Err(invalid("--plant-timeout must be positive"));
    }
    Ok(Some(crate::fleet::FleetOptions {
        plants,
        sync_every: k,
        schedule: crate::fleet::FleetSchedule::parse(&args.schedule)
            .ok_or_else(|| invalid("--schedule: deterministic or free"))?,
        timeout: Duration::from_secs_f64(args.plant_timeout),
        max_lag: crate::fleet::DEFAULT_MAX_LAG,
        rate: args.plant_rate,
        restarts: args.plant_restarts,
        run,
        remote,
    }))
}

fn invalid(m: &str) -> Error {
    SettingsError::Invalid(m.into()).into()
}

/// `--device CMD`, checked against what a device run can do.
fn device_options(args: &TrainArgs, s: &Settings) -> Result<Option<DeviceOptions>, Error> {
    let Some(cmd) = &args.device else {
        return Ok(None);
    };
    if args.resume.is_some() {
        return Err(invalid(
            "--device runs start fresh: a device's replay and optimiser state are not checkpointed, so they cannot be resumed",
        ));
    }
    if s.schedule.noise_corr != 0.0 {
        return Err(invalid(&format!(
            "schedule.noise_corr = {} cannot run on a device: its START frame carries no noise correlation (set it to 0 with --device)",
            s.schedule.noise_corr
        )));
    }
    if s.schedule.noise_pink {
        return Err(invalid(
            "schedule.noise_pink cannot run on a device: its START frame carries no noise kind (leave it false with --device)",
        ));
    }
    if !(args.device_timeout.is_finite() && args.device_timeout > 0.0) {
        return Err(invalid("--device-timeout must be positive"));
    }
    Ok(Some(DeviceOptions {
        cmd: cmd.clone(),
        timeout: Duration::from_secs_f64(args.device_timeout),
    }))
}
