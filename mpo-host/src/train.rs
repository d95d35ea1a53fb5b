//! `mpo train`'s loop, compiled once for every row: it drives a [`Training`] (a trainer of
//! the row's sizes) through the run's stages: attach a controller or device, evaluate the
//! untrained policy, then collect and learn in chunks, evaluating and checkpointing at episode
//! ends, until the budget or Ctrl-C; the summary last. Files are written by
//! [`crate::outputs`].
//!
//! Evaluations (and the checkpoints after them) happen at the first episode end at or after
//! each multiple of `eval_interval`, and the run ends at the first episode end at or after
//! `steps`: with the Control Suite's fixed 1000-step episodes and settings that are multiples
//! of it, exactly at those multiples.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::Serialize;
use sim_bridge::{SimError, TaskDef};

use crate::checkpoint::Verified;
use crate::eval::mean_std;
use crate::link::{Link, LinkOptions, LinkReport};
use crate::metrics::MetricsRow;
use crate::outputs::Outputs;
use crate::progress::Progress;
use crate::settings::Settings;
use crate::spec::Instance;
use crate::time_split::{Laps, TimeSplit};
pub use crate::training::{StepError, TrainError};
use crate::training::{Training, TrainingInit};

/// The one-line JSON printed when a run ends.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Summary {
    /// Task.
    pub task: String,
    /// Seed.
    pub seed: u32,
    /// Environment steps taken.
    pub env_steps: u64,
    /// Learner updates.
    pub updates: u64,
    /// Last evaluation's mean return.
    pub eval_return_mean: f64,
    /// Last evaluation's standard deviation.
    pub eval_return_std: f64,
    /// Training wall clock (summed over resumed segments).
    pub wall_s: f64,
    /// sha256 of the final online actor and critic parameters (little-endian f32, tensor
    /// order).
    pub params_sha256: String,
    /// Run directory.
    pub out: String,
    /// True when Ctrl-C ended the run early (at an episode boundary, checkpoint written).
    pub interrupted: bool,
    /// The controller link's counters with `--controller ipc` (absent in-process).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller: Option<LinkReport>,
    /// The device link's counters with `--device` (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<crate::device::DeviceReport>,
    /// Where this process's wall clock went (learning, environment, acting, evaluation,
    /// checkpoints): the learning part's updates/s is the figure the learner bench measures.
    #[serde(default)]
    pub time: TimeSplit,
    /// The fleet's counters with `--plants` (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fleet: Option<crate::fleet::FleetReport>,
}

/// What `mpo train` was asked to do.
pub struct TrainRequest<'a> {
    /// Resolved settings.
    pub settings: Settings,
    /// The task (built-in or a task file).
    pub task: TaskDef,
    /// The instantiation of the row's sizes.
    pub instance: Instance,
    /// Run directory.
    pub out: PathBuf,
    /// Checkpoint to continue from.
    pub resume: Option<Verified>,
    /// Show the progress bar (it also hides itself when stderr is not a terminal).
    pub progress: bool,
    /// Set by the Ctrl-C handler: finish the current episode, checkpoint, stop.
    pub interrupt: &'a AtomicBool,
    /// Act through a controller process (`--controller ipc`) instead of in-process.
    pub link: Option<LinkOptions>,
    /// Threads of the learner (results do not depend on it).
    pub threads: usize,
    /// Learn on a device program instead of in-process (`--device CMD`).
    pub device: Option<DeviceOptions>,
    /// `--render-every N`: contact sheets of the evaluation policy (`crate::render`).
    pub render: Option<crate::render::EvaluationStrips>,
    /// Collect with plant processes (`--plants N`) instead of in-process.
    pub fleet: Option<crate::fleet::FleetOptions>,
}

/// How to run the device trainer (`--device`).
#[derive(Clone, Debug)]
pub struct DeviceOptions {
    /// The program and its arguments.
    pub cmd: String,
    /// How long to wait for each reply before asking again.
    pub timeout: std::time::Duration,
}

/// Environment steps per call of [`Training::collect`]: how often the progress bar, Ctrl-C and
/// the controller's events are looked at.
const CHUNK: u64 = 100;

/// Runs `mpo train`: the trainer of the request's instance through the stages of a run.
pub fn run(req: TrainRequest<'_>) -> Result<Summary, TrainError> {
    let mut t = (req.instance.trainer)(TrainingInit {
        settings: &req.settings,
        task: &req.task,
        resume: req.resume.as_ref(),
        threads: req.threads,
    })?;
    attach(t.as_mut(), &req)?;
    let mut s = Session::start(&req, t.as_ref())?;
    if s.rows.is_empty() {
        // The untrained policy: the curve's first point and the baseline of every later one.
        s.evaluate(t.as_mut())?;
        s.write_metrics()?;
        let (m, sd) = s.last_eval;
        s.progress.log(&format!(
            "step {:>8}  eval {m:7.1} +- {sd:5.1}  (untrained)",
            0
        ));
    }
    let interrupted = s.train(t.as_mut())?;
    Ok(s.finish(t.as_mut(), interrupted))
}

/// Connects the trainer to the controller process or the device the request asks for.
fn attach(t: &mut dyn Training, req: &TrainRequest<'_>) -> Result<(), TrainError> {
    let z = t.sizes();
    if let Some(opts) = &req.link {
        let target = crate::link::ControllerTarget::of(&req.settings);
        let link = Link::start(&target, z.obs, z.act, opts)?;
        eprintln!(
            "acting through controller process {} (run id {}, {} wait)",
            link.controller_pid()
                .map(|p| format!("pid {p}"))
                .unwrap_or_else(|| "attached".into()),
            link.run_id(),
            opts.wait.name()
        );
        t.attach_link(link);
    }
    if let Some(opts) = &req.device {
        let params = t.param_count();
        let dev = crate::device::Device::start(&opts.cmd, z.obs, z.act, params, opts.timeout)?;
        eprintln!("learning on the device `{}`", opts.cmd);
        t.attach_device(dev, &req.settings)?;
    }
    if let Some(opts) = &req.fleet {
        let fleet = start_fleet(opts, req, z, t.policy_len())?;
        t.attach_fleet(fleet);
    }
    Ok(())
}

/// Starts the plant processes of `--plants N` and waits until they joined.
fn start_fleet(
    opts: &crate::fleet::FleetOptions,
    req: &TrainRequest<'_>,
    z: crate::sizes::Sizes,
    policy_len: usize,
) -> Result<crate::fleet::learner::Fleet, TrainError> {
    let s = &req.settings;
    let identity = crate::fleet::identity(&req.task, &s.net, &z, policy_len);
    let welcome = crate::fleet::welcome_of(s);
    // A fleet's checkpoint has its plants' streams; an in-process run's streams go on in
    // plant 0.
    let resumed = req.resume.as_ref().map(|v| match &v.meta.fleet {
        Some(f) => f.clone(),
        None => crate::checkpoint::FleetRecord {
            run: String::new(),
            plants: vec![crate::checkpoint::PlantRecord {
                collector: v.meta.collector_rng.clone(),
                resets: v.meta.episodes,
            }],
        },
    });
    let resumed = resumed.as_ref();
    let mut opts = opts.clone();
    if opts.run.is_none() && opts.remote.is_some() {
        // Plants on other hosts that worked for the learner resumed from know its run id.
        opts.run = resumed.and_then(|r| mpo_link::RunId::parse(&r.run).ok());
    }
    let opts = &opts;
    if let Some(r) = resumed {
        eprintln!(
            "fleet: {} plant(s) continue their streams from the checkpoint{}",
            r.plants.len().min(opts.plants),
            match r.run.is_empty() {
                true => " (of a run that collected in-process: plant 0 continues its)".into(),
                false => format!(" (fleet run id {})", r.run),
            }
        );
    }
    let mut fleet =
        crate::fleet::learner::Fleet::open(opts.clone(), identity, welcome, s.seed, resumed)?;
    let task_args = crate::link::ControllerTarget::of(s).args();
    match &opts.remote {
        None => {
            for i in 0..opts.plants {
                fleet.spawn(i, &task_args)?;
            }
        }
        Some(r) => {
            // The plants are started by hand on their hosts: say how.
            let mut cmd = format!("mpo plant-worker --run {}", fleet.run_id());
            for e in &r.listen.endpoints {
                cmd.push_str(&format!(" --fleet-connect {e}"));
            }
            if r.listen.tls.is_some() {
                cmd.push_str(" --fleet-ca CA.pem --fleet-cert PLANT.pem --fleet-key PLANT.key");
            }
            cmd.push(' ');
            cmd.push_str(&task_args.join(" "));
            eprintln!(
                "fleet: listening on {} over zenoh{}, run id {}; waiting {:.0} s for {} plant(s): \
                 on each plant's host run `{cmd} --block-hint {} --index I` (I = 0 to {})",
                r.listen.endpoints.join(", "),
                if r.listen.tls.is_some() {
                    " (mutual TLS)"
                } else {
                    ""
                },
                fleet.run_id(),
                opts.timeout.as_secs_f64(),
                opts.plants,
                opts.sync_every,
                opts.plants - 1
            );
        }
    }
    let joined = fleet.admit(opts.timeout);
    for e in fleet.take_events() {
        eprintln!("{e}");
    }
    joined?;
    eprintln!(
        "collecting with {} plant{} over {} (run id {}, {} schedule, {} steps per block)",
        opts.plants,
        match opts.remote {
            None => " processes",
            Some(_) => "s of other hosts",
        },
        fleet.transport(),
        fleet.run_id(),
        fleet.report().schedule,
        opts.sync_every
    );
    Ok(fleet)
}

/// A run in progress: its outputs, metrics rows, clocks and the marks rates are measured
/// from.
struct Session<'r> {
    req: &'r TrainRequest<'r>,
    outputs: Outputs,
    progress: Progress,
    rows: Vec<MetricsRow>,
    /// Wall clock of the resumed segments before this one.
    wall0: f64,
    started: Instant,
    /// (wall clock, environment steps, updates) at the last evaluation.
    mark: (f64, u64, u64),
    /// The last evaluation's mean and standard deviation.
    last_eval: (f64, f64),
    last_checkpoint: Option<u64>,
    /// Updates at the start of this segment, and the loop's own parts of the time split.
    updates0: u64,
    times: TimeSplit,
}

impl<'r> Session<'r> {
    fn start(req: &'r TrainRequest<'r>, t: &dyn Training) -> Result<Self, TrainError> {
        let (rows, wall0, last_checkpoint) = match &req.resume {
            Some(v) => (
                v.meta.metrics.clone(),
                v.meta.wall_s,
                Some(v.meta.env_steps),
            ),
            None => (Vec::new(), 0.0, None),
        };
        let outputs = Outputs::create(&req.out, &req.settings, &req.task, t.sizes())?;
        let progress = Progress::new(
            req.progress,
            req.settings.steps,
            "{elapsed_precise} [{bar:30}] {pos}/{len} steps  {msg}  ETA {eta}",
        );
        progress.set_position(t.env_steps());
        let last_eval = rows
            .last()
            .map(|r: &MetricsRow| (r.eval_return_mean, r.eval_return_std))
            .unwrap_or((f64::NAN, f64::NAN));
        Ok(Self {
            req,
            outputs,
            progress,
            rows,
            wall0,
            started: Instant::now(),
            mark: (wall0, t.env_steps(), t.updates()),
            last_eval,
            last_checkpoint,
            updates0: t.updates(),
            times: TimeSplit::default(),
        })
    }

    /// Training wall clock, over resumed segments.
    fn wall(&self) -> f64 {
        self.wall0 + self.started.elapsed().as_secs_f64()
    }

    /// Evaluates the current policy and appends the metrics row (and, with
    /// `--render-every`, a contact sheet: it only reads the policy, a failure is a warning).
    fn evaluate(&mut self, t: &mut dyn Training) -> Result<(), TrainError> {
        let mut laps = Laps::start();
        let r = self.evaluate_untimed(t);
        laps.lap(&mut self.times.evaluate_s);
        r
    }

    fn evaluate_untimed(&mut self, t: &mut dyn Training) -> Result<(), TrainError> {
        let s = &self.req.settings;
        let returns = t.evaluate(&self.req.task, s.seed, s.schedule.eval_episodes)?;
        let (mean, std) = mean_std(&returns);
        let now = self.wall();
        let dt = (now - self.mark.0).max(1e-9);
        let stats = t
            .take_stat_means()
            .into_iter()
            .map(|v| v.is_finite().then_some(v))
            .collect();
        self.rows.push(MetricsRow {
            env_steps: t.env_steps(),
            updates: t.updates(),
            episodes: t.episodes(),
            wall_s: now,
            eval_return_mean: mean,
            eval_return_std: std,
            env_steps_per_s: (t.env_steps() - self.mark.1) as f64 / dt,
            updates_per_s: (t.updates() - self.mark.2) as f64 / dt,
            stats,
            weight_growth: Some(t.weight_growth()),
            dormant: t.dormant(),
        });
        self.last_eval = (mean, std);
        if let Some(strips) = &self.req.render {
            let i = self.rows.len() - 1;
            let mut policy = |o: &[f32], a: &mut [f32]| t.mean_action(o, a);
            let (task, dir) = (&self.req.task, &self.req.out);
            if let Err(e) =
                strips.after_evaluation(i, t.env_steps(), task, s.seed, dir, &mut policy)
            {
                self.progress
                    .log(&format!("warning: evaluation sheet not written: {e}"));
            }
        }
        Ok(())
    }

    /// Writes the checkpoint of the trainer's present state.
    fn save(&mut self, t: &dyn Training) -> Result<(), TrainError> {
        let mut laps = Laps::start();
        self.outputs.checkpoint(t, &self.rows, self.wall())?;
        laps.lap(&mut self.times.checkpoint_s);
        self.last_checkpoint = Some(t.env_steps());
        Ok(())
    }

    /// Writes the metrics files (charged to checkpoints and metrics).
    fn write_metrics(&mut self) -> Result<(), TrainError> {
        let mut laps = Laps::start();
        self.outputs.metrics(&self.rows, &self.progress)?;
        laps.lap(&mut self.times.checkpoint_s);
        Ok(())
    }

    /// Collects and learns until the budget (or Ctrl-C), evaluating and checkpointing at
    /// the episode end at or after each multiple of the evaluation interval. Returns whether
    /// Ctrl-C ended it.
    fn train(&mut self, t: &mut dyn Training) -> Result<bool, TrainError> {
        let (steps, interval) = (
            self.req.settings.steps,
            self.req.settings.schedule.eval_interval,
        );
        let mut next_eval = (t.env_steps() / interval + 1) * interval;
        while !(t.env_steps() >= steps && t.at_episode_boundary()) {
            let target = next_eval.min(steps);
            let result = match target.checked_sub(t.env_steps()) {
                Some(left) if left > 0 => t.collect(CHUNK.min(left), false),
                // Past the mark in the middle of an episode: finish it.
                _ => t.collect(CHUNK, true),
            };
            if let Err(e) = result {
                self.progress.abandon();
                return Err(self.step_error(e, t));
            }
            self.after_chunk(t);
            let due = t.env_steps() >= next_eval || t.env_steps() >= steps;
            if due && t.at_episode_boundary() {
                self.evaluate(t)?;
                self.report_evaluation();
                self.mark = (self.wall(), t.env_steps(), t.updates());
                self.write_metrics()?;
                self.save(t)?;
                next_eval = (t.env_steps() / interval + 1) * interval;
            }
            if self.req.interrupt.load(Ordering::SeqCst) && t.at_episode_boundary() {
                if !(due && t.at_episode_boundary()) {
                    self.save(t)?;
                }
                self.progress.log(&format!(
                    "interrupted: checkpoint written at environment step {}",
                    t.env_steps()
                ));
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The progress bar and the controller's events after a chunk of steps.
    fn after_chunk(&mut self, t: &mut dyn Training) {
        if let Some(link) = t.link_mut() {
            for e in link.take_events() {
                self.progress.log(&e);
            }
        }
        if let Some(fleet) = t.fleet_mut() {
            for e in fleet.take_events() {
                self.progress.log(&e);
            }
        }
        self.progress.set_position(t.env_steps());
        let (now, (t0, s0, u0)) = (self.wall(), self.mark);
        if now - t0 > 0.0 && !self.progress.is_hidden() {
            self.progress.set_message(format!(
                "{:.0} steps/s  {:.0} upd/s  eval {:.1}",
                (t.env_steps() - s0) as f64 / (now - t0),
                (t.updates() - u0) as f64 / (now - t0),
                self.last_eval.0
            ));
        }
    }

    /// The log line of the evaluation just made.
    fn report_evaluation(&self) {
        let r = self.rows.last().expect("an evaluation row");
        self.progress.log(&format!(
            "step {:>8}  eval {:7.1} +- {:5.1}  updates {:>7}  {:.0} steps/s  {:.1} upd/s  wall {:.0} s",
            r.env_steps,
            r.eval_return_mean,
            r.eval_return_std,
            r.updates,
            r.env_steps_per_s,
            r.updates_per_s,
            r.wall_s
        ));
    }

    /// The error of a failed step, with where the last good checkpoint is.
    fn step_error(&self, e: StepError, t: &dyn Training) -> TrainError {
        match e {
            // An external plant that died or stopped answering: say where the run can resume.
            StepError::Sim(SimError::External(m)) => TrainError::Sim(SimError::External(format!(
                "{m}. Training stopped at environment step {}; {}",
                t.env_steps(),
                match self.last_checkpoint {
                    Some(s) => format!(
                        "the last checkpoint (environment step {s}) is kept in {}",
                        self.req.out.join(crate::checkpoint::SUBDIR).display()
                    ),
                    None => "no checkpoint had been written yet".into(),
                }
            ))),
            StepError::Sim(s) => TrainError::Sim(s),
            StepError::Link(l) => TrainError::Link(l),
            StepError::Device(d) => TrainError::Device(d),
            StepError::Fleet(f) => TrainError::Fleet(f),
            StepError::Update(what) => TrainError::NonFinite {
                update: t.updates(),
                env_steps: t.env_steps(),
                what,
                last_checkpoint: self.last_checkpoint,
                dir: self.req.out.join(crate::checkpoint::SUBDIR),
            },
        }
    }

    /// Closes the controller link and writes the summary.
    fn finish(self, t: &mut dyn Training, interrupted: bool) -> Summary {
        self.progress.finish();
        let controller = t.take_link().map(|mut l| {
            for e in l.drain_events() {
                self.progress.log(&e);
            }
            l.finish()
        });
        if let Some(c) = &controller
            && c.misses > 0
        {
            self.progress.log(&format!(
                "controller: {} of {} requests missed (safe action applied); the run differs from an in-process one",
                c.misses, c.requests
            ));
        }
        let fleet = t.take_fleet().map(|mut f| {
            for e in f.take_events() {
                self.progress.log(&e);
            }
            f.finish()
        });
        let inner = t.time_split();
        let time = TimeSplit {
            learn_s: inner.learn_s,
            env_s: inner.env_s,
            act_s: inner.act_s,
            total_s: self.started.elapsed().as_secs_f64(),
            updates: t.updates() - self.updates0,
            ..self.times
        };
        self.progress.log(&time.line());
        Summary {
            task: self.req.settings.task.clone(),
            seed: self.req.settings.seed,
            env_steps: t.env_steps(),
            updates: t.updates(),
            eval_return_mean: self.last_eval.0,
            eval_return_std: self.last_eval.1,
            wall_s: self.wall(),
            params_sha256: t.params_sha256(),
            out: self.req.out.display().to_string(),
            interrupted,
            controller,
            device: t.device_report(),
            time,
            fleet,
        }
    }
}
