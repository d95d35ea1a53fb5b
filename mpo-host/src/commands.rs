//! The subcommands, from parsed flags to results: configuration layering, resume checks,
//! dispatch through the task table.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use serde::Serialize;

use crate::checkpoint::{self, CheckpointError, Verified};
use crate::cli::{ControllerArgs, EvalArgs, ExportArgs, PlotArgs, RenderArgs, RunArgs, TrainArgs};
use crate::eval::{evaluate, mean_std};
use crate::link::LinkOptions;
use crate::render::{EvaluationStrips, RenderError, RenderOptions, RenderSummary};
use crate::run::{Limit, Pacing, RunError, RunRequest, RunSummary};
use crate::settings::{self, Settings, SettingsError};
use crate::tasks::{self, Row, RowVisitor, UnknownTask};
use crate::train::{Summary, TrainError, TrainRequest, TrainVisitor};

/// Everything a command can fail with.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// Configuration.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// Task not in the table.
    #[error(transparent)]
    UnknownTask(#[from] UnknownTask),
    /// Checkpoint.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// Training.
    #[error(transparent)]
    Train(#[from] TrainError),
    /// Running a policy (`mpo run`).
    #[error(transparent)]
    Run(#[from] RunError),
    /// Rendering a policy (`mpo render`, `mpo train --render-every`).
    #[error(transparent)]
    Render(#[from] RenderError),
    /// The controller process (`mpo controller`).
    #[error("controller: {0}")]
    Controller(String),
    /// Simulator.
    #[error("simulator: {0}")]
    Sim(#[from] sim_bridge::SimError),
    /// A metrics file that cannot be read or plotted.
    #[error("{0}")]
    Plot(String),
    /// The run directory already holds a run.
    #[error(
        "{0} already holds a checkpoint: continue it with `mpo train --resume {0}`, or choose another --out"
    )]
    OutExists(String),
    /// A file that cannot be written.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

fn str_value(t: &toml::Table, k: &str) -> Option<String> {
    t.get(k).and_then(|v| v.as_str()).map(str::to_string)
}

/// The layers above the defaults: the file, `--set`s, then explicit flags.
fn layers(args: &TrainArgs) -> Result<Vec<(String, toml::Table)>, Error> {
    let file = match &args.config {
        Some(p) => Some((p.display().to_string(), settings::read_table(p)?)),
        None => None,
    };
    let flags = Flags {
        task: args.task.clone(),
        net: args.net.clone(),
        seed: args.seed,
        steps: args.steps,
    };
    layers_from(file, &args.set, &flags)
}

/// The explicit flags of `mpo train` that set configuration keys.
#[derive(Clone, Debug, Default)]
pub struct Flags {
    /// `--task`.
    pub task: Option<String>,
    /// `--net`.
    pub net: Option<String>,
    /// `--seed`.
    pub seed: Option<u32>,
    /// `--steps`.
    pub steps: Option<u64>,
}

/// The configuration layers above the task table's defaults, lowest first: the parsed
/// `--config` file `(origin, table)`, each `--set KEY=VALUE`, then the explicit flags.
pub fn layers_from(
    file: Option<(String, toml::Table)>,
    sets: &[String],
    flags: &Flags,
) -> Result<Vec<(String, toml::Table)>, Error> {
    let mut out = Vec::new();
    out.extend(file);
    for s in sets {
        out.push((format!("--set {s}"), settings::parse_set(s)?));
    }
    let mut t = toml::Table::new();
    if let Some(v) = &flags.task {
        t.insert("task".into(), v.clone().into());
    }
    if let Some(n) = &flags.net {
        t.insert("net".into(), n.clone().into());
    }
    if let Some(s) = flags.seed {
        t.insert("seed".into(), (s as i64).into());
    }
    if let Some(s) = flags.steps {
        t.insert("steps".into(), (s as i64).into());
    }
    out.push(("flags".into(), t));
    Ok(out)
}

fn apply(base: &toml::Table, layers: &[(String, toml::Table)]) -> Result<toml::Table, Error> {
    let mut t = base.clone();
    for (origin, l) in layers {
        settings::overlay(&mut t, l, origin, "")?;
        // Type errors are reported against the layer that introduced them.
        Settings::from_table(t.clone(), origin)?;
    }
    Ok(t)
}

/// The table row's defaults as settings.
pub fn defaults(row: &Row) -> Settings {
    Settings {
        task: row.task.into(),
        net: row.net.into(),
        seed: 0,
        steps: row.steps,
        schedule: row.schedule,
        mpo: row.mpo,
        network: Some(row.sizes),
    }
}

/// [`checkpoint::open`], with a note on stderr when a crash (or a corrupt `checkpoint/`) made
/// it choose `checkpoint.tmp/` or `checkpoint.old/`.
fn open_checkpoint(dir: &Path) -> Result<Verified, Error> {
    let v = checkpoint::open(dir)?;
    if let Some(note) = &v.fallback {
        eprintln!("note: {note}");
    }
    Ok(v)
}

fn episode_steps(task: &str) -> Result<u64, Error> {
    Ok(sim_bridge::task_spec(task)?.episode_steps as u64)
}

/// The configuration of `mpo train` with these flags: a fresh run's, or with `--resume` the
/// resumed run's (with its verified checkpoint).
fn resolve_settings(args: &TrainArgs) -> Result<(Settings, Option<Verified>), Error> {
    let layers = layers(args)?;
    match &args.resume {
        Some(dir) => {
            let v = open_checkpoint(dir)?;
            Ok((resolve_resumed(&v.meta, &v.dir, &layers)?, Some(v)))
        }
        None => Ok((resolve_fresh(&layers)?, None)),
    }
}

/// Resolves the configuration of `mpo train` (fresh or resumed) and where it writes.
pub fn resolve_train(args: &TrainArgs) -> Result<(Settings, PathBuf, Option<Verified>), Error> {
    let (s, resumed) = resolve_settings(args)?;
    if let Some(v) = resumed {
        let out = args
            .out
            .clone()
            .unwrap_or_else(|| checkpoint::run_dir_of(&v.dir));
        return Ok((s, out, Some(v)));
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("runs/{}-seed{}", s.task, s.seed)));
    if checkpoint::locate(&out).is_ok() {
        return Err(Error::OutExists(out.display().to_string()));
    }
    Ok((s, out, None))
}

/// `mpo train --print-config`: the `config.toml` that `mpo train` with the same flags would
/// write (a fresh run's, or with `--resume` the resumed run's), without training or touching
/// any run directory, so a row's defaults and the effect of `--config`/`--set` can be read
/// before hours of training.
pub fn print_config(args: &TrainArgs) -> Result<String, Error> {
    let (s, _) = resolve_settings(args)?;
    Ok(s.config_toml(&tasks::row(&s.task, &s.net)?.sizes))
}

/// A fresh run's configuration: the task table row's defaults under `layers` (see
/// [`layers_from`]), validated. Reads no files.
pub fn resolve_fresh(layers: &[(String, toml::Table)]) -> Result<Settings, Error> {
    let mut task = tasks::DEFAULT_TASK.to_string();
    let mut net = tasks::DEFAULT_NET.to_string();
    for (_, l) in layers {
        task = str_value(l, "task").unwrap_or(task);
        net = str_value(l, "net").unwrap_or(net);
    }
    let row = tasks::row(&task, &net)?;
    let merged = apply(&defaults(row).to_table(), layers)?;
    let s = Settings::from_table(merged, "configuration")?;
    s.validate(episode_steps(&s.task)?, &row.sizes)?;
    Ok(s)
}

/// A resumed run's configuration: the checkpoint's (`meta`, from `dir`) under `layers`, which
/// may change `steps` only (raise it), validated against this build's task table. Reads no
/// files.
pub fn resolve_resumed(
    meta: &checkpoint::Meta,
    dir: &Path,
    layers: &[(String, toml::Table)],
) -> Result<Settings, Error> {
    let base = meta.settings.to_table();
    let merged = apply(&base, layers)?;
    let diffs = settings::differences(&base, &merged, "", &["steps"]);
    if !diffs.is_empty() {
        return Err(SettingsError::Mismatch {
            dir: dir.display().to_string(),
            differences: diffs,
        }
        .into());
    }
    let s = Settings::from_table(merged, "resumed configuration")?;
    let row = tasks::row(&s.task, &s.net)?;
    if meta.sizes != row.sizes {
        return Err(SettingsError::Mismatch {
            dir: dir.display().to_string(),
            differences: vec![format!(
                "network sizes are {:?} in the checkpoint, {:?} in this build's task table",
                meta.sizes, row.sizes
            )],
        }
        .into());
    }
    s.validate(episode_steps(&s.task)?, &row.sizes)?;
    if s.steps < meta.env_steps {
        return Err(SettingsError::Invalid(format!(
            "steps = {} is below the checkpoint's {} environment steps",
            s.steps, meta.env_steps
        ))
        .into());
    }
    Ok(s)
}

/// The deadline of a request in lockstep (training and `mpo run --lockstep` through a
/// controller): long enough that a descheduled controller on a loaded machine still answers,
/// so the run stays bit-identical to one in-process (100 ms was once missed under the whole
/// test suite on two vCPUs with a busy-polling controller); a dead controller costs a second
/// before the safe action and its restart.
const LOCKSTEP_DEADLINE: Duration = Duration::from_secs(1);

/// `mpo train`.
pub fn train(args: &TrainArgs, interrupt: &AtomicBool) -> Result<Summary, Error> {
    // Training through a controller is lockstep: a miss would make the run differ.
    let link = LinkOptions::from_args(&args.link, LOCKSTEP_DEADLINE, None)
        .map_err(SettingsError::Invalid)?;
    let (settings, out, mut resume) = resolve_train(args)?;
    if let Some(v) = &mut resume
        && checkpoint::run_dir_of(&v.dir) == out
        && v.dir.parent() == Some(out.as_path())
    {
        // Continuing in the run directory: finish what a crash may have left mid-swap first,
        // so the checkpoint resumed from is `checkpoint/` from now on.
        checkpoint::settle(&out)?;
        v.dir = out.join(checkpoint::SUBDIR);
    }
    if let Some(v) = &resume {
        eprintln!(
            "resuming from {} at environment step {}",
            v.dir.display(),
            v.meta.env_steps
        );
    }
    let (task, net) = (settings.task.clone(), settings.net.clone());
    let req_noise_corr = settings.schedule.noise_corr;
    let req_noise_pink = settings.schedule.noise_pink;
    // `--render-every N`: a machine that cannot render says so before training starts.
    let render = match args.render_every {
        Some(n) => {
            let strips = EvaluationStrips::new(n)?;
            strips.check(&task)?;
            Some(strips)
        }
        None => None,
    };
    let req = TrainRequest {
        settings,
        out,
        resume,
        progress: !args.no_progress,
        interrupt,
        link,
        threads: match args.threads {
            Some(0) => {
                return Err(SettingsError::Invalid("--threads must be at least 1".into()).into());
            }
            Some(n) => n,
            None => crate::pool::Pool::available(),
        },
        render,
        device: match &args.device {
            None => None,
            Some(_) if args.resume.is_some() => {
                return Err(SettingsError::Invalid(
                    "--device runs start fresh: a device's replay and optimiser state are not checkpointed, so they cannot be resumed".into(),
                )
                .into());
            }
            Some(_) if req_noise_corr != 0.0 => {
                return Err(SettingsError::Invalid(format!(
                    "schedule.noise_corr = {req_noise_corr} cannot run on a device: its START frame carries no noise correlation (set it to 0 with --device)"
                ))
                .into());
            }
            Some(_) if req_noise_pink => {
                return Err(SettingsError::Invalid(
                    "schedule.noise_pink cannot run on a device: its START frame carries no noise kind (leave it false with --device)".into(),
                )
                .into());
            }
            Some(_) if !(args.device_timeout.is_finite() && args.device_timeout > 0.0) => {
                return Err(
                    SettingsError::Invalid("--device-timeout must be positive".into()).into(),
                );
            }
            Some(cmd) => Some(crate::train::DeviceOptions {
                cmd: cmd.clone(),
                timeout: Duration::from_secs_f64(args.device_timeout),
            }),
        },
    };
    Ok(tasks::visit(&task, &net, TrainVisitor(req))??)
}

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

struct EvalVisitor {
    v: Verified,
    seed: u32,
    episodes: u32,
}

impl RowVisitor for EvalVisitor {
    type Out = Result<EvalSummary, Error>;
    fn visit<
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
        const CAP: usize,
    >(
        self,
        row: &'static Row,
    ) -> Self::Out {
        let m = &self.v.meta;
        let learner =
            load_learner::<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>(&self.v, row)?;
        let returns = evaluate(&learner, &m.settings.task, self.seed, self.episodes)?;
        let (return_mean, return_std) = mean_std(&returns);
        Ok(EvalSummary {
            task: m.settings.task.clone(),
            checkpoint_env_steps: m.env_steps,
            seed: self.seed,
            episodes: self.episodes,
            return_mean,
            return_std,
            returns,
        })
    }
}

struct RenderVisitor<'a> {
    v: Verified,
    opts: &'a RenderOptions,
}

impl RowVisitor for RenderVisitor<'_> {
    type Out = Result<RenderSummary, Error>;
    fn visit<
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
        const CAP: usize,
    >(
        self,
        row: &'static Row,
    ) -> Self::Out {
        let learner =
            load_learner::<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>(&self.v, row)?;
        Ok(crate::render::render(
            &self.v.meta.settings.task,
            self.v.meta.env_steps,
            |o, a| learner.mean_action(o, a),
            self.opts,
        )?)
    }
}

/// `mpo render`: the checkpoint's mean-action policy on its evaluation episodes, as pictures.
pub fn render(args: &RenderArgs) -> Result<RenderSummary, Error> {
    let v = checkpoint::open(&args.checkpoint)?;
    let (task, net) = (v.meta.settings.task.clone(), v.meta.settings.net.clone());
    let opts = RenderOptions {
        episodes: args.episodes,
        seed: args.seed.unwrap_or(v.meta.settings.seed),
        steps: args.steps,
        width: args.width,
        height: args.height,
        camera: args.camera.clone(),
        fps: args.fps,
        out: args.out.clone(),
        strip: args.strip.clone(),
        strip_frames: args.strip_frames,
    };
    tasks::visit(&task, &net, RenderVisitor { v, opts: &opts })?
}

struct RunVisitor<'a> {
    v: Verified,
    req: RunRequest<'a>,
}

impl RowVisitor for RunVisitor<'_> {
    type Out = Result<RunSummary, Error>;
    fn visit<
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
        const CAP: usize,
    >(
        self,
        row: &'static Row,
    ) -> Self::Out {
        let learner =
            load_learner::<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>(&self.v, row)?;
        Ok(crate::run::run(&learner.live.actor, self.req)?)
    }
}

/// `mpo run`.
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
        Pacing::Lockstep => LOCKSTEP_DEADLINE,
        Pacing::Paced(hz) => Duration::from_secs_f64(0.5 / hz),
    };
    let link =
        LinkOptions::from_args(&args.link, default_deadline, args.realtime).map_err(invalid)?;
    let v = open_checkpoint(&args.checkpoint)?;
    let (task, net) = (v.meta.settings.task.clone(), v.meta.settings.net.clone());
    let req = RunRequest {
        task: task.clone(),
        net: net.clone(),
        checkpoint_env_steps: v.meta.env_steps,
        seed: args.seed.unwrap_or(v.meta.settings.seed),
        pacing,
        limit,
        link,
        realtime: args.realtime,
        progress: !args.no_progress,
        interrupt,
    };
    tasks::visit(&task, &net, RunVisitor { v, req })?
}

struct ControllerVisitor {
    opts: mpo_link::controller::ControllerOptions,
}

impl RowVisitor for ControllerVisitor {
    type Out = Result<mpo_link::controller::ControllerStats, Error>;
    fn visit<
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
        const CAP: usize,
    >(
        self,
        _row: &'static Row,
    ) -> Self::Out {
        use std::io::Write;
        let ready = || {
            let mut out = std::io::stdout();
            let _ = writeln!(out, "ready");
            let _ = out.flush();
        };
        mpo_link::controller::serve::<OBS, ACT, TRI, AH1, AH2>(&self.opts, ready)
            .map_err(|e| Error::Controller(e.to_string()))
    }
}

/// `mpo controller`: serves the run until SIGINT/SIGTERM; returns its counters.
pub fn controller(args: &ControllerArgs) -> Result<mpo_link::controller::ControllerStats, Error> {
    let run = mpo_link::RunId::parse(&args.run).map_err(|e| Error::Controller(e.to_string()))?;
    let wait = mpo_link::WaitMode::parse(&args.wait)
        .ok_or_else(|| Error::Controller(format!("unknown wait mode {:?}", args.wait)))?;
    let row = tasks::row(&args.task, &args.net)?;
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
    tasks::visit(&args.task, &args.net, ControllerVisitor { opts })?
}

/// A learner of the row's types holding the checkpoint's networks (sizes checked against the
/// row, checksums verified).
fn load_learner<
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
    v: &Verified,
    row: &'static Row,
) -> Result<Box<mpo_core::learner::Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>>, Error>
{
    let m = &v.meta;
    if m.sizes != row.sizes {
        return Err(SettingsError::Mismatch {
            dir: v.dir.display().to_string(),
            differences: vec![format!(
                "network sizes are {:?} in the checkpoint, {:?} in this build's task table",
                m.sizes, row.sizes
            )],
        }
        .into());
    }
    let mut learner: Box<
        mpo_core::learner::Learner<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>,
    > = bytemuck::zeroed_box();
    learner
        .init(m.settings.mpo.to_config(), m.settings.seed as u64)
        .map_err(|e| SettingsError::Invalid(format!("mpo: {e}")))?;
    v.load_networks(&mut learner)?;
    Ok(learner)
}

/// What `mpo export` wrote.
#[derive(Debug, Serialize)]
pub struct ExportSummary {
    /// Task of the checkpoint.
    pub task: String,
    /// Environment steps of the checkpoint.
    pub checkpoint_env_steps: u64,
    /// The written Rust source.
    pub policy: PathBuf,
    /// Observation, action and hidden sizes.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// Hidden widths.
    pub hidden: [usize; 2],
    /// Scalar parameters of the actor (what the firmware keeps in flash, 4 bytes each).
    pub parameters: usize,
}

struct ExportVisitor {
    v: Verified,
    out: PathBuf,
}

impl RowVisitor for ExportVisitor {
    type Out = Result<ExportSummary, Error>;
    fn visit<
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
        const CAP: usize,
    >(
        self,
        row: &'static Row,
    ) -> Self::Out {
        use mpo_core::params::Params;
        let learner =
            load_learner::<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N>(&self.v, row)?;
        let origin = format!(
            "checkpoint {} ({} at {} environment steps, params_sha256 {})",
            self.v.dir.display(),
            self.v.meta.settings.task,
            self.v.meta.env_steps,
            self.v.meta.params_sha256
        );
        let mut src = String::new();
        mpo_core::export::write_actor_source(&learner.live.actor, &origin, &mut src)
            .expect("formatting into a String cannot fail");
        let io = |e: std::io::Error| Error::Io {
            path: self.out.clone(),
            source: e,
        };
        let io = &io;
        std::fs::create_dir_all(&self.out).map_err(io)?;
        let policy = self.out.join("policy.rs");
        std::fs::write(&policy, src).map_err(io)?;
        Ok(ExportSummary {
            task: self.v.meta.settings.task.clone(),
            checkpoint_env_steps: self.v.meta.env_steps,
            policy,
            obs: OBS,
            act: ACT,
            hidden: [AH1, AH2],
            parameters: learner.live.actor.len(),
        })
    }
}

/// `mpo export`: the checkpoint's online policy as Rust source for the firmware.
pub fn export(args: &ExportArgs) -> Result<ExportSummary, Error> {
    let v = open_checkpoint(&args.checkpoint)?;
    let (task, net) = (v.meta.settings.task.clone(), v.meta.settings.net.clone());
    tasks::visit(
        &task,
        &net,
        ExportVisitor {
            v,
            out: args.out.clone(),
        },
    )?
}

/// `mpo eval`.
pub fn eval(args: &EvalArgs) -> Result<EvalSummary, Error> {
    let v = open_checkpoint(&args.checkpoint)?;
    let (task, net) = (v.meta.settings.task.clone(), v.meta.settings.net.clone());
    let seed = args.seed.unwrap_or(v.meta.settings.seed);
    if args.episodes == 0 {
        return Err(SettingsError::Invalid("--episodes must be at least 1".into()).into());
    }
    tasks::visit(
        &task,
        &net,
        EvalVisitor {
            v,
            seed,
            episodes: args.episodes,
        },
    )?
}

/// `mpo tasks`: one line per task-table row (every Control Suite task has at least one).
pub fn tasks_listing() -> String {
    let mut s = format!(
        "{:<18} {:>3} {:>3}  {:<8} {:>9} {:>9} {:>4} {:>3} {:>3}  {:<12} {:>5} {:>9}\n",
        "task",
        "obs",
        "act",
        "net",
        "actor",
        "critic",
        "B",
        "M",
        "N",
        "evaluation",
        "noise",
        "steps"
    );
    for &name in sim_bridge::TASKS {
        let (obs, act) = sim_bridge::task_spec(name)
            .map(|t| (t.obs_dim.to_string(), t.act_dim.to_string()))
            .unwrap_or(("?".into(), "?".into()));
        let rows: Vec<&Row> = tasks::ROWS.iter().filter(|r| r.task == name).collect();
        if rows.is_empty() {
            s.push_str(&format!(
                "{name:<18} {obs:>3} {act:>3}  (no row: not trainable)\n"
            ));
        }
        for r in rows {
            let z = &r.sizes;
            let eval = match r.mpo.policy_evaluation {
                settings::PolicyEvaluation::Td => "td".to_string(),
                settings::PolicyEvaluation::NStep => format!("{}-step", r.mpo.n_step),
                settings::PolicyEvaluation::Retrace => format!("retrace {}", r.mpo.n_step),
            };
            s.push_str(&format!(
                "{name:<18} {obs:>3} {act:>3}  {:<8} {:>9} {:>9} {:>4} {:>3} {:>3}  {eval:<12} {:>5} {:>9}\n",
                r.net,
                format!("{}-{}", z.actor[0], z.actor[1]),
                format!("{}-{}", z.critic[0], z.critic[1]),
                z.batch,
                z.m,
                z.n,
                if r.schedule.noise_pink {
                    "pink".to_string()
                } else {
                    r.schedule.noise_corr.to_string()
                },
                r.steps
            ));
        }
    }
    s.push_str("\nA row's whole configuration: mpo train --task T [--net N] --print-config\n");
    s
}

/// `mpo plot`: one curve per run directory, labelled with the directory's name; with
/// `--by-task`, one panel per task.
pub fn plot(args: &PlotArgs) -> Result<(), Error> {
    let mut runs = Vec::new();
    for dir in &args.runs {
        runs.push(read_run_curve(dir)?);
    }
    if args.by_task {
        return plot_by_task(args, runs);
    }
    let title = args.title.clone().unwrap_or_else(|| {
        format!(
            "MPO {}",
            runs.iter().find_map(|r| r.2.clone()).unwrap_or_default()
        )
    });
    let task = runs.iter().find_map(|r| r.2.clone());
    let series: Vec<_> = runs
        .into_iter()
        .map(|(label, pts, _)| (label, pts))
        .collect();
    let what = task.as_deref().unwrap_or("runs");
    let (mean, line) = args
        .mean
        .then(|| mean_of_runs(what, &series))
        .transpose()?
        .unzip();
    crate::plot::write_curves(&args.out, &title, &series, mean).map_err(Error::Plot)?;
    // Only after the image is written, so a refused or failed command prints no figure.
    line.iter().for_each(|l| println!("{l}"));
    Ok(())
}

/// `--mean`: the mean curve over `series` ([`crate::plot::mean_over_runs`]) with its legend
/// label, and the line to print once the image is written: its last point and each run's
/// return there (`what` names the runs).
fn mean_of_runs(
    what: &str,
    series: &[crate::plot::Series],
) -> Result<(crate::plot::Series, String), Error> {
    let pts = crate::plot::mean_over_runs(series).ok_or_else(|| {
        Error::Plot(format!(
            "--mean: the {what} runs share no evaluation step (it averages at the steps every run has)"
        ))
    })?;
    let &(x, m, sd) = pts.last().expect("mean_over_runs returns points or None");
    let each: Vec<String> = series
        .iter()
        .filter_map(|(label, p)| {
            p.iter()
                .find(|q| q.0 == x)
                .map(|q| format!("{label} {:.1}", q.1))
        })
        .collect();
    let runs = match series.len() {
        1 => "1 run".to_string(),
        n => format!("{n} runs"),
    };
    let line = format!(
        "{what}: mean of {runs} at {x} steps: {m:.1} +- {sd:.1} ({})",
        each.join(", ")
    );
    let label = format!("mean of {} (+-1 std over runs)", series.len());
    Ok(((label, pts), line))
}

/// `mpo plot --by-task`: the runs grouped by their task into panels, with the `--target` lines.
fn plot_by_task(args: &PlotArgs, runs: Vec<RunCurve>) -> Result<(), Error> {
    let mut panels: Vec<crate::plot::Panel> = Vec::new();
    for ((label, pts, task), dir) in runs.into_iter().zip(&args.runs) {
        let task = task.ok_or_else(|| {
            Error::Plot(format!(
                "{}: no `task` in config.toml (--by-task groups runs by it)",
                dir.display()
            ))
        })?;
        match panels.iter_mut().find(|p| p.title == task) {
            Some(p) => p.series.push((label, pts)),
            None => panels.push(crate::plot::Panel {
                title: task,
                series: vec![(label, pts)],
                target: None,
                budget: None,
                mean: None,
            }),
        }
    }
    for t in &args.target {
        let (panel, value) =
            panel_setting(&mut panels, "--target", "RETURN", "walker-walk=900", t)?;
        panel.target = Some(value);
    }
    for t in &args.budget {
        let (panel, value) =
            panel_setting(&mut panels, "--budget", "STEPS", "walker-run=1000000", t)?;
        if !(1.0..=1e12).contains(&value) {
            return Err(Error::Plot(format!(
                "--budget {t}: STEPS must be from 1 to 10^12"
            )));
        }
        panel.budget = Some(value as u64);
    }
    let mut lines = Vec::new();
    if args.mean {
        for p in &mut panels {
            let (mean, line) = mean_of_runs(&p.title, &p.series)?;
            p.mean = Some(mean);
            lines.push(line);
        }
    }
    let title = args.title.clone().unwrap_or_else(|| "MPO".to_string());
    crate::plot::write_panels(&args.out, &title, &panels).map_err(Error::Plot)?;
    // Only after the image is written, so a refused or failed command prints no figure.
    lines.iter().for_each(|l| println!("{l}"));
    Ok(())
}

/// `TASK=VALUE` of `flag`: the panel of TASK and the value, or an error naming the flag.
fn panel_setting<'a>(
    panels: &'a mut [crate::plot::Panel],
    flag: &str,
    what: &str,
    example: &str,
    arg: &str,
) -> Result<(&'a mut crate::plot::Panel, f64), Error> {
    let bad = || {
        Error::Plot(format!(
            "{flag} {arg}: expected TASK={what}, e.g. {example}"
        ))
    };
    let (task, value) = arg.split_once('=').ok_or_else(bad)?;
    let value: f64 = value.trim().parse().map_err(|_| bad())?;
    let panel = panels
        .iter_mut()
        .find(|p| p.title == task.trim())
        .ok_or_else(|| {
            Error::Plot(format!(
                "{flag} {arg}: none of the runs given is of task {}",
                task.trim()
            ))
        })?;
    Ok((panel, value))
}

/// One run's curve: its label (the directory's name), `(env_steps, mean, std)` per evaluation
/// from `metrics.jsonl` (or `metrics.csv` without it), and its task from `config.toml` when there is one.
type RunCurve = (String, Vec<(u64, f64, f64)>, Option<String>);

fn read_run_curve(dir: &std::path::Path) -> Result<RunCurve, Error> {
    let jsonl = dir.join("metrics.jsonl");
    let csv = dir.join("metrics.csv");
    let pts = if jsonl.exists() || !csv.exists() {
        jsonl_points(&jsonl)?
    } else {
        csv_points(&csv)?
    };
    let task = settings::read_table(&dir.join("config.toml"))
        .ok()
        .and_then(|t| str_value(&t, "task"));
    let label = dir
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| dir.display().to_string());
    Ok((label, pts, task))
}

/// `(env_steps, mean, std)` per line of a `metrics.jsonl`.
fn jsonl_points(path: &std::path::Path) -> Result<Vec<(u64, f64, f64)>, Error> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::Plot(format!("{}: {e}", path.display())))?;
    let mut pts = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let v: serde_json::Value = serde_json::from_str(line)
            .map_err(|e| Error::Plot(format!("{} line {}: {e}", path.display(), i + 1)))?;
        let get = |k: &str| {
            v.get(k).and_then(|x| x.as_f64()).ok_or_else(|| {
                Error::Plot(format!(
                    "{} line {}: no number `{k}`",
                    path.display(),
                    i + 1
                ))
            })
        };
        pts.push((
            get("env_steps")? as u64,
            get("eval_return_mean")?,
            get("eval_return_std")?,
        ));
    }
    Ok(pts)
}

/// The same from a `metrics.csv` (for run directories kept without their JSON lines): the
/// columns found by name in the header, as `metrics::write_all` writes them (no quoting).
fn csv_points(path: &std::path::Path) -> Result<Vec<(u64, f64, f64)>, Error> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Error::Plot(format!("{}: {e}", path.display())))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let col = |k: &str| {
        header.iter().position(|h| *h == k).ok_or_else(|| {
            Error::Plot(format!("{}: no column `{k}` in the header", path.display()))
        })
    };
    let cols = [
        col("env_steps")?,
        col("eval_return_mean")?,
        col("eval_return_std")?,
    ];
    let mut pts = Vec::new();
    for (i, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        let mut v = [0.0; 3];
        for (x, &c) in v.iter_mut().zip(&cols) {
            *x = cells
                .get(c)
                .and_then(|s| s.trim().parse().ok())
                .ok_or_else(|| {
                    Error::Plot(format!(
                        "{} line {}: column {c} is not a number",
                        path.display(),
                        i + 2
                    ))
                })?;
        }
        pts.push((v[0] as u64, v[1], v[2]));
    }
    Ok(pts)
}
