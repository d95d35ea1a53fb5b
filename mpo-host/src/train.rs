//! The training loop: act with the sampled policy, store transitions, learn at the configured
//! ratio, evaluate and checkpoint at episode boundaries.
//!
//! Random streams (all xoshiro256++, all in the checkpoint): the learner's own (network
//! initialisation, then every update's samples), the collector's (warm-up actions and
//! exploration noise) and the replay sampler's (batch indices). The last two are split from
//! one root seeded from the run's seed, so acting and learning never share draws and the
//! ratio of updates to steps can change without changing what the collector does.
//!
//! Nothing in [`Trainer::collect`] (the act-and-learn loop) allocates: buffers are sized once.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mpo_core::agent::{Agent, AgentError, AgentSchedule};
use mpo_core::learner::UpdateError;
use mpo_core::replay::Transition;

use serde::Serialize;
use sim_bridge::{Environment, SimError};

use crate::checkpoint::{self, CheckpointError, Counters, Meta, Verified};
use crate::eval::{evaluate, evaluate_with, mean_std};
use crate::link::{Link, LinkOptions, LinkReport, LinkSetupError};
use crate::metrics::{self, MetricsRow, StatsAccumulator};
use crate::pool::PoolParallel;
use crate::settings::Settings;
use crate::tasks::{Row, RowVisitor};
use mpo_core::params::Params;

/// Mixed into the run's seed for the collector and sampler root (the learner uses the seed
/// itself), so the streams differ.
const STREAM_SALT: u64 = 0x6d70_6f2d_686f_7374;

/// Why training stopped early.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TrainError {
    /// Configuration.
    #[error(transparent)]
    Settings(#[from] crate::settings::SettingsError),
    /// Reading or writing a checkpoint.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The simulator (missing MuJoCo, a physics error).
    #[error("simulator: {0}")]
    Sim(#[from] SimError),
    /// A learner update failed; its changes were undone and no checkpoint was written for it.
    #[error(
        "learner update {update} (at environment step {env_steps}) failed: {what}. Training stopped; {}",
        match .last_checkpoint { Some(s) => format!("the last good checkpoint (environment step {s}) is kept in {}", .dir.display()), None => "no checkpoint had been written yet".to_string() }
    )]
    NonFinite {
        /// Updates completed before the failing one.
        update: u64,
        /// Environment steps taken.
        env_steps: u64,
        /// What was non-finite.
        what: String,
        /// Environment step of the last checkpoint written by this process or resumed from.
        last_checkpoint: Option<u64>,
        /// Checkpoint directory.
        dir: PathBuf,
    },
    /// Output files.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The controller process could not be started or reached.
    #[error(transparent)]
    LinkSetup(#[from] LinkSetupError),
    /// Pushing parameters to the controller failed.
    #[error("controller link: {0}")]
    Link(#[from] mpo_link::LinkError),
    /// The device trainer (`--device`) failed.
    #[error(transparent)]
    Device(#[from] crate::device::DeviceError),
    /// Sizes of the task table and the simulator disagree (a bug in the table).
    #[error("internal: {0}")]
    Internal(String),
}

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
}

/// What `mpo train` was asked to do.
pub struct TrainRequest<'a> {
    /// Resolved settings.
    pub settings: Settings,
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
}

/// How to run the device trainer (`--device`).
#[derive(Clone, Debug)]
pub struct DeviceOptions {
    /// The program and its arguments.
    pub cmd: String,
    /// How long to wait for each reply before asking again.
    pub timeout: std::time::Duration,
}

/// Why one step of [`Trainer::collect`] failed.
#[derive(Debug)]
pub enum StepError {
    /// The simulator refused the step.
    Sim(SimError),
    /// A learner update was rejected (or reported a non-finite statistic).
    Update(String),
    /// Parameters could not be pushed to the controller process.
    Link(mpo_link::LinkError),
    /// The device trainer failed.
    Device(crate::device::DeviceError),
}

/// The act-and-learn state of a run with the row's types.
pub struct Trainer<
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
> {
    /// The learner, its replay, the acting and sampling streams and the schedule: the part a
    /// device trainer runs too (`mpo_core::agent`).
    pub agent: Box<Agent<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>>,
    env: Box<dyn Environment>,
    /// Episodes completed.
    pub episodes: u64,
    in_episode: bool,
    /// Steps taken in the current episode (labels controller requests).
    episode_step: u32,
    obs64: [f64; OBS],
    next64: [f64; OBS],
    act64: [f64; ACT],
    /// Learner statistics since the last metrics row.
    pub stats: StatsAccumulator,
    action_penalty: f32,
    /// Runs the learner's work items on `--threads` threads.
    pool: PoolParallel,
    /// The controller process, when acting through one (`--controller ipc`).
    pub link: Option<Link>,
    /// The controller's policy is older than the learner's (pushed before the next request).
    params_dirty: bool,
    /// The device trainer, when learning on one (`--device`): it holds the learning agent;
    /// `agent` then only mirrors its parameters and counters.
    pub device: Option<crate::device::Device>,
    /// With a device: the action it chose for the current state, and its log-density.
    device_action: [f32; ACT],
}

impl<
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
> Trainer<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>
{
    /// A fresh run (networks initialised from the seed, empty replay), or the state of
    /// `resume`.
    /// `threads` runs the learner's work (any count gives the same bits).
    pub fn new(
        settings: &Settings,
        resume: Option<&Verified>,
        threads: usize,
    ) -> Result<Self, TrainError> {
        let spec = sim_bridge::task_spec(&settings.task)?;
        if spec.obs_dim != OBS || spec.act_dim != ACT {
            return Err(TrainError::Internal(format!(
                "task table row {} has OBS {OBS} ACT {ACT}, simulator says {} {}",
                settings.task, spec.obs_dim, spec.act_dim
            )));
        }
        let mut agent: Box<Agent<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>> =
            bytemuck::zeroed_box();
        agent
            .init(
                settings.mpo.to_config(),
                settings.seed as u64,
                settings.seed as u64 ^ STREAM_SALT,
                agent_schedule(settings),
            )
            .map_err(|e| crate::settings::SettingsError::Invalid(format!("mpo: {e}")))?;
        let mut env = sim_bridge::make(&settings.task, settings.seed)?;
        let (mut episodes, mut stats) = (0, StatsAccumulator::default());
        let mut obs64 = [0f64; OBS];
        if let Some(v) = resume {
            v.restore(&mut agent.learner, &mut agent.replay)?;
            let m = &v.meta;
            let bad = |what: &str| CheckpointError::Corrupt {
                path: v.dir.join("meta.json"),
                message: format!("bad {what}"),
            };
            agent.collector =
                checkpoint::unhex32(&m.collector_rng).ok_or_else(|| bad("collector_rng"))?;
            agent.sampler =
                checkpoint::unhex32(&m.sampler_rng).ok_or_else(|| bad("sampler_rng"))?;
            agent.env_steps = m.env_steps;
            episodes = m.episodes;
            stats = m.stats.clone();
            // The environment's RandomState advances once per reset: replay the resets.
            for _ in 0..episodes {
                env.reset(&mut obs64);
            }
        }
        if stats.sums.len() != metrics::STAT_NAMES.len() {
            // Sized once here, so `collect` never allocates.
            stats.sums = vec![0.0; metrics::STAT_NAMES.len()];
        }
        Ok(Self {
            agent,
            env,
            episodes,
            in_episode: false,
            episode_step: 0,
            obs64,
            next64: [0.0; OBS],
            act64: [0.0; ACT],
            stats,
            pool: PoolParallel::new(threads).map_err(|source| TrainError::Io {
                path: "learner threads".into(),
                source,
            })?,
            action_penalty: settings.schedule.action_penalty as f32,
            link: None,
            params_dirty: true,
            device: None,
            device_action: [0.0; ACT],
        })
    }

    /// Environment steps taken.
    pub fn env_steps(&self) -> u64 {
        self.agent.env_steps
    }

    /// The checkpoint metadata of the trainer's present state: counters, random streams,
    /// replay counters, statistics and parameter hash (what [`checkpoint::save`] writes
    /// beside the tensors).
    pub fn meta(
        &self,
        settings: &Settings,
        row: &Row,
        metrics: &[MetricsRow],
        wall_s: f64,
    ) -> Meta {
        let c = self.agent.replay.counters();
        let l = &self.agent.learner;
        Meta {
            format: checkpoint::FORMAT.into(),
            version: checkpoint::VERSION,
            settings: settings.clone(),
            sizes: row.sizes,
            env_steps: self.env_steps(),
            episodes: self.episodes,
            updates: l.updates,
            wall_s,
            learner_rng: checkpoint::hex(&l.rng_state),
            collector_rng: checkpoint::hex(&self.agent.collector),
            sampler_rng: checkpoint::hex(&self.agent.sampler),
            replay: Counters {
                head: c.head,
                len: c.len,
                inserted: c.inserted,
                current_episode: c.current_episode,
            },
            stats: self.stats.clone(),
            metrics: metrics.to_vec(),
            params_sha256: checkpoint::params_sha256(&l.live.actor, &l.live.critic),
        }
    }

    /// True between episodes (where checkpoints may be taken).
    pub fn at_episode_boundary(&self) -> bool {
        !self.in_episode
    }

    /// Acts through `link` from now on (the learner's current policy is pushed before the next
    /// request).
    pub fn attach(&mut self, link: Link) {
        self.link = Some(link);
        self.params_dirty = true;
    }

    /// Pushes the learner's policy to the controller if it changed since the last push.
    fn sync_controller(&mut self) -> Result<(), mpo_link::LinkError> {
        if let Some(link) = self.link.as_mut()
            && self.params_dirty
        {
            link.push(&self.agent.learner.live.actor)?;
            self.params_dirty = false;
        }
        Ok(())
    }

    /// Returns of the evaluation episodes of the current policy's mean action: in-process, or
    /// through the controller process (a missed request applies the safe action).
    pub fn evaluate(
        &mut self,
        task: &str,
        seed: u32,
        episodes: u32,
    ) -> Result<Vec<f64>, TrainError> {
        self.sync_controller()?;
        if let Some(dev) = self.device.as_mut() {
            let mut err = None;
            let returns = evaluate_with(
                task,
                seed,
                episodes,
                |o: &[f32; OBS], a: &mut [f32; ACT]| {
                    if err.is_none()
                        && let Err(e) = dev.eval(o, a)
                    {
                        err = Some(e);
                    }
                },
            )?;
            if let Some(e) = err {
                return Err(e.into());
            }
            self.fetch_device_params()?;
            return Ok(returns);
        }
        Ok(match self.link.as_mut() {
            Some(link) => evaluate_with(
                task,
                seed,
                episodes,
                |o: &[f32; OBS], a: &mut [f32; ACT]| {
                    link.act(o, a);
                },
            )?,
            None => evaluate(&self.agent.learner, task, seed, episodes)?,
        })
    }

    /// Takes `steps` environment steps, storing each transition and running the learner
    /// updates the schedule calls for. Allocates nothing (through a controller process:
    /// nothing while it answers).
    pub fn collect(&mut self, steps: u64) -> Result<(), StepError> {
        if self.device.is_some() {
            return self.collect_on_device(steps);
        }
        let mut obs = [0f32; OBS];
        let mut act = [0f32; ACT];
        for _ in 0..steps {
            if !self.in_episode {
                self.env.reset(&mut self.obs64);
                self.agent.begin_episode();
                self.in_episode = true;
                self.episode_step = 0;
            }
            for (o, x) in obs.iter_mut().zip(&self.obs64) {
                *o = *x as f32;
            }
            let log_prob = if self.link.is_some() && !self.agent.in_warmup() {
                self.act_through_link(&obs, &mut act)?
            } else {
                self.agent.act(&obs, &mut act)
            };
            // Every Control Suite actuator's range is [-1, 1]; the replay keeps the sample.
            for (o, a) in self.act64.iter_mut().zip(&act) {
                *o = a.clamp(-1.0, 1.0) as f64;
            }
            let step = self
                .env
                .try_step(&self.act64, &mut self.next64)
                .map_err(StepError::Sim)?;
            let mut excess = 0f32;
            for (a, c) in act.iter().zip(&self.act64) {
                excess += (a - *c as f32) * (a - *c as f32);
            }
            let mut t = Transition {
                obs,
                action: act,
                reward: step.reward as f32 - self.action_penalty * excess,
                next_obs: [0.0; OBS],
                discount: step.discount as f32,
                behaviour_log_prob: log_prob,
            };
            for (o, x) in t.next_obs.iter_mut().zip(&self.next64) {
                *o = *x as f32;
            }
            core::mem::swap(&mut self.obs64, &mut self.next64);
            self.episode_step += 1;
            if step.last {
                self.in_episode = false;
                self.episodes += 1;
            }
            self.observe(&t).map_err(StepError::Update)?;
        }
        Ok(())
    }

    /// [`Trainer::collect`] with the agent on the device: the host steps the plant, sends each
    /// outcome and gets the next action.
    fn collect_on_device(&mut self, steps: u64) -> Result<(), StepError> {
        let mut obs = [0f32; OBS];
        let mut next = [0f32; OBS];
        for _ in 0..steps {
            let dev = self.device.as_mut().expect("checked");
            if !self.in_episode {
                self.env.reset(&mut self.obs64);
                for (o, x) in obs.iter_mut().zip(&self.obs64) {
                    *o = *x as f32;
                }
                dev.begin(&obs, &mut self.device_action)
                    .map_err(StepError::Device)?;
                self.in_episode = true;
                self.episode_step = 0;
            }
            let act = self.device_action;
            for (o, a) in self.act64.iter_mut().zip(&act) {
                *o = a.clamp(-1.0, 1.0) as f64;
            }
            let step = self
                .env
                .try_step(&self.act64, &mut self.next64)
                .map_err(StepError::Sim)?;
            let mut excess = 0f32;
            for (a, c) in act.iter().zip(&self.act64) {
                excess += (a - *c as f32) * (a - *c as f32);
            }
            for (o, x) in next.iter_mut().zip(&self.next64) {
                *o = *x as f32;
            }
            let reward = step.reward as f32 - self.action_penalty * excess;
            dev.step(
                reward,
                step.discount as f32,
                step.last,
                &next,
                &mut self.device_action,
            )
            .map_err(StepError::Device)?;
            core::mem::swap(&mut self.obs64, &mut self.next64);
            self.episode_step += 1;
            self.agent.env_steps += 1;
            if step.last {
                self.in_episode = false;
                self.episodes += 1;
            }
        }
        Ok(())
    }

    /// Copies the device's parameters and counters into the mirror `agent` (for the
    /// checkpoint, the metrics and `params_sha256`).
    fn fetch_device_params(&mut self) -> Result<(), TrainError> {
        let Some(dev) = self.device.as_mut() else {
            return Ok(());
        };
        let mut flat = vec![0f32; dev.param_count()];
        let c = dev.params(&mut flat)?;
        let live = &mut self.agent.learner.live;
        let mut it = flat.into_iter();
        live.actor
            .visit_mut(&mut |t| t.iter_mut().for_each(|x| *x = it.next().unwrap_or(0.0)));
        live.critic
            .visit_mut(&mut |t| t.iter_mut().for_each(|x| *x = it.next().unwrap_or(0.0)));
        self.agent.learner.updates = c.updates;
        if c.env_steps != self.agent.env_steps {
            return Err(TrainError::Internal(format!(
                "the device counted {} environment steps, the host {}",
                c.env_steps, self.agent.env_steps
            )));
        }
        Ok(())
    }

    /// Learns on a device program from now on (a fresh run: the device starts from the
    /// run's seed).
    pub fn attach_device(
        &mut self,
        mut dev: crate::device::Device,
        settings: &Settings,
    ) -> Result<(), TrainError> {
        dev.configure(
            &settings.mpo.to_config(),
            &agent_schedule(settings),
            settings.seed,
        )?;
        self.device = Some(dev);
        Ok(())
    }

    /// The sampled action from the controller process: the same draws `Agent::act` makes
    /// in-process (`mu + L z` and its log-density, computed with the same code and
    /// parameters), so the action and the stored log-probability are bit-identical.
    fn act_through_link(
        &mut self,
        obs: &[f32; OBS],
        act: &mut [f32; ACT],
    ) -> Result<f32, StepError> {
        self.sync_controller().map_err(StepError::Link)?;
        let mut z = [0f32; ACT];
        self.agent.draw_noise(&mut z);
        let floor = self.agent.learner.cfg.std_floor;
        let link = self.link.as_mut().expect("checked");
        link.set_episode_step(self.episodes, self.episode_step);
        Ok(match link.act_sampled(obs, &z, floor, act) {
            Some((_, log_prob)) => log_prob,
            // Missed: `act` is the safe action (zero). Stored with its density under the
            // current policy (only Retrace would use it).
            None => self
                .agent
                .learner
                .live
                .actor
                .distribution(obs, floor)
                .log_prob(act),
        })
    }

    /// Stores a transition and runs the learner updates the schedule calls for.
    fn observe(&mut self, t: &Transition<OBS, ACT>) -> Result<(), String> {
        let mut bad = None;
        let (stats, dirty) = (&mut self.stats, &mut self.params_dirty);
        self.agent
            .observe(t, &self.pool, &mut |s| {
                *dirty = true;
                if bad.is_none() {
                    bad = metrics::first_non_finite(s);
                }
                stats.add(s);
            })
            .map_err(|e| match e {
                AgentError::Update(UpdateError::NonFinite(w)) => {
                    format!("non-finite value in {w:?} (the update was undone)")
                }
                e => e.to_string(),
            })?;
        match bad {
            Some((name, v)) => Err(format!("learner statistic {name} = {v}")),
            None => Ok(()),
        }
    }

    /// Draws the learner's next batch from the replay, as the configuration's policy
    /// evaluation needs (n-step transitions or sequences).
    pub fn fill_batch(&mut self) -> Result<(), String> {
        self.agent.fill_batch().map_err(|e| e.to_string())
    }
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

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Runs `mpo train` for the row's types (see [`crate::tasks::visit`]).
pub struct TrainVisitor<'a>(pub TrainRequest<'a>);

impl RowVisitor for TrainVisitor<'_> {
    type Out = Result<Summary, TrainError>;
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
        run::<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>(row, self.0)
    }
}

fn log(pb: &ProgressBar, msg: &str) {
    if pb.is_hidden() {
        eprintln!("{msg}");
    } else {
        pb.println(msg);
    }
}

fn run<
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
    row: &'static Row,
    req: TrainRequest<'_>,
) -> Result<Summary, TrainError> {
    let settings = req.settings;
    let out = req.out;
    let mut t = Trainer::<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>::new(
        &settings,
        req.resume.as_ref(),
        req.threads,
    )?;
    if let Some(opts) = &req.link {
        let link = Link::start(&settings.task, &settings.net, OBS, ACT, opts)?;
        eprintln!(
            "acting through controller process {} (run id {}, {} wait)",
            link.controller_pid()
                .map(|p| format!("pid {p}"))
                .unwrap_or_else(|| "attached".into()),
            link.run_id(),
            opts.wait.name()
        );
        t.attach(link);
    }
    if let Some(opts) = &req.device {
        let params = t.agent.learner.live.actor.len() + t.agent.learner.live.critic.len();
        let dev = crate::device::Device::start(&opts.cmd, OBS, ACT, params, opts.timeout)?;
        eprintln!("learning on the device `{}`", opts.cmd);
        t.attach_device(dev, &settings)?;
    }
    let (mut metrics_rows, wall0, mut last_checkpoint) = match &req.resume {
        Some(v) => (
            v.meta.metrics.clone(),
            v.meta.wall_s,
            Some(v.meta.env_steps),
        ),
        None => (Vec::new(), 0.0, None),
    };
    std::fs::create_dir_all(&out).map_err(io_err(&out))?;
    let cfg_path = out.join("config.toml");
    let text = settings.config_toml(&row.sizes);
    metrics::write_atomic(&cfg_path, text.as_bytes()).map_err(io_err(&cfg_path))?;

    let started = Instant::now();
    let wall = |started: &Instant| wall0 + started.elapsed().as_secs_f64();
    let pb = if req.progress {
        ProgressBar::with_draw_target(Some(settings.steps), ProgressDrawTarget::stderr())
    } else {
        ProgressBar::hidden()
    };
    pb.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} steps  {msg}  ETA {eta}",
        )
        .expect("template")
        .progress_chars("=> "),
    );
    pb.set_position(t.env_steps());
    let mut last_eval = metrics_rows
        .last()
        .map(|r: &MetricsRow| (r.eval_return_mean, r.eval_return_std))
        .unwrap_or((f64::NAN, f64::NAN));
    let (mut mark_t, mut mark_steps, mut mark_updates) =
        (wall(&started), t.env_steps(), t.agent.learner.updates);

    let evaluate_now = |t: &mut Trainer<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>,
                        metrics_rows: &mut Vec<MetricsRow>,
                        mark: (f64, u64, u64)|
     -> Result<(f64, f64), TrainError> {
        let returns = t.evaluate(
            &settings.task,
            settings.seed,
            settings.schedule.eval_episodes,
        )?;
        let (mean, std) = mean_std(&returns);
        let now = wall(&started);
        let dt = (now - mark.0).max(1e-9);
        let stats = t
            .stats
            .take_means()
            .into_iter()
            .map(|v| v.is_finite().then_some(v))
            .collect();
        metrics_rows.push(MetricsRow {
            env_steps: t.env_steps(),
            updates: t.agent.learner.updates,
            episodes: t.episodes,
            wall_s: now,
            eval_return_mean: mean,
            eval_return_std: std,
            env_steps_per_s: (t.env_steps() - mark.1) as f64 / dt,
            updates_per_s: (t.agent.learner.updates - mark.2) as f64 / dt,
            stats,
        });
        // `--render-every N`: a picture of the policy just evaluated; only reads it, and a
        // failure is a warning (like curve.png).
        if let Some(strips) = &req.render {
            let policy = |o: &[f32; OBS], a: &mut [f32; ACT]| t.agent.learner.mean_action(o, a);
            let (i, task) = (metrics_rows.len() - 1, &settings.task);
            if let Err(e) =
                strips.after_evaluation(i, t.env_steps(), task, settings.seed, &out, policy)
            {
                log(&pb, &format!("warning: evaluation sheet not written: {e}"));
            }
        }
        Ok((mean, std))
    };

    let write_outputs = |rows: &[MetricsRow], pb: &ProgressBar| -> Result<(), TrainError> {
        metrics::write_all(&out, rows).map_err(io_err(&out))?;
        if let Err(e) = crate::plot::write_curve(
            &out.join("curve.png"),
            &format!("MPO {} (seed {})", settings.task, settings.seed),
            rows,
        ) {
            log(pb, &format!("warning: curve.png not written: {e}"));
        }
        Ok(())
    };

    let save = |t: &Trainer<OBS, ACT, TRI, AH1, AH2, QH1, QH2, BC, C, L, M, N, CAP>,
                rows: &[MetricsRow],
                wall_s: f64|
     -> Result<(), TrainError> {
        let meta = t.meta(&settings, row, rows, wall_s);
        checkpoint::save(&out, &t.agent.learner, &t.agent.replay, &meta)?;
        Ok(())
    };

    if metrics_rows.is_empty() {
        // The untrained policy: the curve's first point and the baseline of every later one.
        last_eval = evaluate_now(
            &mut t,
            &mut metrics_rows,
            (mark_t, mark_steps, mark_updates),
        )?;
        write_outputs(&metrics_rows, &pb)?;
        log(
            &pb,
            &format!(
                "step {:>8}  eval {:7.1} +- {:5.1}  (untrained)",
                0, last_eval.0, last_eval.1
            ),
        );
    }

    let mut interrupted = false;
    const CHUNK: u64 = 100;
    while t.env_steps() < settings.steps {
        let to_eval =
            settings.schedule.eval_interval - t.env_steps() % settings.schedule.eval_interval;
        let n = CHUNK.min(to_eval).min(settings.steps - t.env_steps());
        if let Err(e) = t.collect(n) {
            let dir = out.join(checkpoint::SUBDIR);
            pb.abandon();
            return Err(match e {
                StepError::Sim(s) => TrainError::Sim(s),
                StepError::Link(l) => TrainError::Link(l),
                StepError::Device(d) => TrainError::Device(d),
                StepError::Update(what) => TrainError::NonFinite {
                    update: t.agent.learner.updates,
                    env_steps: t.env_steps(),
                    what,
                    last_checkpoint,
                    dir,
                },
            });
        }
        if let Some(link) = t.link.as_mut() {
            for e in link.take_events() {
                log(&pb, &e);
            }
        }
        pb.set_position(t.env_steps());
        let now = wall(&started);
        if now - mark_t > 0.0 {
            pb.set_message(format!(
                "{:.0} steps/s  {:.0} upd/s  eval {:.1}",
                (t.env_steps() - mark_steps) as f64 / (now - mark_t),
                (t.agent.learner.updates - mark_updates) as f64 / (now - mark_t),
                last_eval.0
            ));
        }
        let at_eval = t
            .env_steps()
            .is_multiple_of(settings.schedule.eval_interval)
            || t.env_steps() == settings.steps;
        if at_eval {
            last_eval = evaluate_now(
                &mut t,
                &mut metrics_rows,
                (mark_t, mark_steps, mark_updates),
            )?;
            let r = metrics_rows.last().expect("row");
            log(
                &pb,
                &format!(
                    "step {:>8}  eval {:7.1} +- {:5.1}  updates {:>7}  {:.0} steps/s  {:.1} upd/s  wall {:.0} s",
                    r.env_steps,
                    r.eval_return_mean,
                    r.eval_return_std,
                    r.updates,
                    r.env_steps_per_s,
                    r.updates_per_s,
                    r.wall_s
                ),
            );
            (mark_t, mark_steps, mark_updates) =
                (wall(&started), t.env_steps(), t.agent.learner.updates);
            write_outputs(&metrics_rows, &pb)?;
            save(&t, &metrics_rows, wall(&started))?;
            last_checkpoint = Some(t.env_steps());
        }
        if req.interrupt.load(Ordering::SeqCst) && t.at_episode_boundary() {
            if !at_eval {
                save(&t, &metrics_rows, wall(&started))?;
            }
            log(
                &pb,
                &format!(
                    "interrupted: checkpoint written at environment step {}",
                    t.env_steps()
                ),
            );
            interrupted = true;
            break;
        }
    }
    pb.finish_and_clear();
    let controller = t.link.take().map(|mut l| {
        for e in l.drain_events() {
            log(&pb, &e);
        }
        l.finish()
    });
    if let Some(c) = &controller
        && c.misses > 0
    {
        log(
            &pb,
            &format!(
                "controller: {} of {} requests missed (safe action applied); the run differs from an in-process one",
                c.misses, c.requests
            ),
        );
    }
    Ok(Summary {
        task: settings.task.clone(),
        seed: settings.seed,
        env_steps: t.env_steps(),
        updates: t.agent.learner.updates,
        eval_return_mean: last_eval.0,
        eval_return_std: last_eval.1,
        wall_s: wall(&started),
        params_sha256: checkpoint::params_sha256(
            &t.agent.learner.live.actor,
            &t.agent.learner.live.critic,
        ),
        out: out.display().to_string(),
        interrupted,
        controller,
        device: t.device.as_ref().map(|d| d.report.clone()),
    })
}
