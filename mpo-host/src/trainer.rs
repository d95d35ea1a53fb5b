//! A run's act-and-learn state for one instantiation's sizes: the agent (learner, replay,
//! random streams), the training environment, and the controller or device it may act
//! through. It implements [`Training`], the interface the sizes-free training loop
//! (`crate::train`) drives.
//!
//! Random streams (all xoshiro256++, all in the checkpoint): the learner's own (network
//! initialisation, then every update's samples), the collector's (warm-up actions and
//! exploration noise) and the replay sampler's (batch indices). The last two are split from
//! one root seeded from the run's seed, so acting and learning never share draws and the
//! ratio of updates to steps can change without changing what the collector does.
//!
//! Nothing in [`Trainer::collect`] (the act-and-learn loop) allocates: buffers are sized once.

use std::path::Path;

use mpo_core::agent::{AgentError, AgentOf};
use mpo_core::learner::UpdateError;
use mpo_core::network::{PolicyNet, PolicyTrain, ValueNet};
use mpo_core::replay::Transition;
use sim_bridge::{Environment, TaskDef};

use crate::checkpoint::{self, CheckpointError, Counters, Meta, Verified};
use crate::device::{Device, DeviceReport};
use crate::eval::evaluate_with;
use crate::fleet::learner::Fleet;
use crate::link::Link;
use crate::metrics::{self, StatsAccumulator};
use crate::policy::Policy;
use crate::pool::PoolParallel;
use crate::settings::Settings;
use crate::sizes::Sizes;
use crate::time_split::{Laps, TimeSplit};
use crate::training::{StepError, TrainError};
use crate::training::{Training, TrainingInit};
use crate::{dormant, weight_growth};

pub use crate::collection::agent_schedule;
use crate::collection::{STREAM_SALT, env_step};

/// [`Trainer`] with the two-layer MLPs (actor widths `AH1`, `AH2`, critic widths `QH1`, `QH2`).
pub type MlpTrainer<
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
> = Trainer<
    OBS,
    ACT,
    TRI,
    mpo_core::actor::Actor<OBS, ACT, TRI, AH1, AH2>,
    mpo_core::critic::Critic<OBS, ACT, QH1, QH2>,
    BC,
    C,
    L,
    M,
    N,
    CAP,
>;

/// The act-and-learn state of a run with the row's types.
pub struct Trainer<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI> + Policy,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
> {
    /// The learner, its replay, the acting and sampling streams and the schedule: the part a
    /// device trainer runs too (`mpo_core::agent`).
    pub agent: Box<AgentOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N, CAP>>,
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
    pub device: Option<Device>,
    /// With a device: the action it chose for the current state, and its log-density.
    device_action: [f32; ACT],
    /// Seconds spent learning, stepping the environment and acting in this process.
    pub times: TimeSplit,
    /// The plant processes, when collecting with a fleet (`--plants N`): the trainer then
    /// steps no environment of its own.
    pub fleet: Option<Fleet>,
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI> + Policy,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
> Trainer<OBS, ACT, TRI, P, Q, BC, C, L, M, N, CAP>
{
    /// A fresh run of the settings' task (networks initialised from the seed, empty replay),
    /// or the state of `resume`. `threads` runs the learner's work (any count gives the same
    /// bits).
    pub fn new(
        settings: &Settings,
        resume: Option<&Verified>,
        threads: usize,
    ) -> Result<Self, TrainError> {
        let task = match &settings.task_file {
            Some(p) => TaskDef::from_file(p)?,
            None => TaskDef::builtin(&settings.task)?,
        };
        Self::with_task(TrainingInit {
            settings,
            task: &task,
            resume,
            threads,
        })
    }

    /// A trainer for the run `init` describes, behind the sizes-free interface (the
    /// instance's `trainer`).
    pub fn boxed(init: TrainingInit<'_>) -> Result<Box<dyn Training>, TrainError> {
        Ok(Box::new(Self::with_task(init)?))
    }

    /// [`Trainer::new`] for a task already loaded.
    // Long for its list of parts (environments, agent, random streams, buffers, resume),
    // each built once in the order the checkpoint restores them.
    pub fn with_task(init: TrainingInit<'_>) -> Result<Self, TrainError> {
        let TrainingInit {
            settings,
            task,
            resume,
            threads,
        } = init;
        let spec = task.spec();
        if spec.obs_dim != OBS || spec.act_dim != ACT {
            return Err(TrainError::Internal(format!(
                "the learner has OBS {OBS} ACT {ACT}, the task {} has {} {}",
                task.name(),
                spec.obs_dim,
                spec.act_dim
            )));
        }
        let mut agent: Box<AgentOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N, CAP>> =
            bytemuck::zeroed_box();
        agent
            .init(
                settings.mpo.to_config(),
                settings.seed as u64,
                settings.seed as u64 ^ STREAM_SALT,
                agent_schedule(settings),
            )
            .map_err(|e| crate::settings::SettingsError::Invalid(format!("mpo: {e}")))?;
        let mut env: Box<dyn Environment> = crate::plant::make(task, settings.seed)?;
        let (mut episodes, mut stats) = (0, StatsAccumulator::default());
        let mut obs64 = [0f64; OBS];
        if let Some(v) = resume {
            (episodes, stats) = Self::restore(&mut agent, v)?;
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
            times: TimeSplit::default(),
            fleet: None,
        })
    }

    /// The agent's state from a checkpoint: networks, optimiser, replay, the three random
    /// streams and the counters. Returns the episodes completed and the pending statistics.
    fn restore(
        agent: &mut AgentOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N, CAP>,
        v: &Verified,
    ) -> Result<(u64, StatsAccumulator), TrainError> {
        v.restore(&mut agent.learner, &mut agent.replay)?;
        let m = &v.meta;
        let bad = |what: &str| CheckpointError::Corrupt {
            path: v.dir.join("meta.json"),
            message: format!("bad {what}"),
        };
        agent.explore.collector =
            checkpoint::unhex32(&m.collector_rng).ok_or_else(|| bad("collector_rng"))?;
        agent.sampler = checkpoint::unhex32(&m.sampler_rng).ok_or_else(|| bad("sampler_rng"))?;
        agent.env_steps = m.env_steps;
        Ok((m.episodes, m.stats.clone()))
    }

    /// Environment steps taken.
    pub fn env_steps(&self) -> u64 {
        self.agent.env_steps
    }

    /// The checkpoint metadata of the present state: counters, random streams, replay
    /// counters, statistics and parameter hash, over the run-level fields of `base`.
    pub fn meta(&self, base: Meta) -> Meta {
        let c = self.agent.replay.counters();
        let l = &self.agent.learner;
        Meta {
            env_steps: self.env_steps(),
            episodes: self.episodes,
            updates: l.updates,
            learner_rng: checkpoint::hex(&l.rng_state),
            collector_rng: checkpoint::hex(&self.agent.explore.collector),
            sampler_rng: checkpoint::hex(&self.agent.sampler),
            replay: Counters {
                head: c.head,
                len: c.len,
                inserted: c.inserted,
                current_episode: c.current_episode,
            },
            stats: self.stats.clone(),
            params_sha256: checkpoint::params_sha256(&l.live.actor, &l.live.critic),
            fleet: self.fleet.as_ref().map(Fleet::record),
            ..base
        }
    }

    /// True between episodes (where checkpoints may be taken); with a fleet, see
    /// [`Fleet::at_boundary`].
    pub fn at_episode_boundary(&self) -> bool {
        match &self.fleet {
            Some(f) => f.at_boundary(),
            None => !self.in_episode,
        }
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
    /// through the controller process (a missed request applies the safe action), or on the
    /// device.
    pub fn evaluate(
        &mut self,
        task: &TaskDef,
        seed: u32,
        episodes: u32,
    ) -> Result<Vec<f64>, TrainError> {
        self.sync_controller()?;
        if let Some(dev) = self.device.as_mut() {
            let mut err = None;
            let returns = evaluate_with(task, seed, episodes, &mut |o, a| {
                if err.is_none()
                    && let Err(e) = dev.eval(o, a)
                {
                    err = Some(e);
                }
            })?;
            if let Some(e) = err {
                return Err(e.into());
            }
            self.fetch_device_params()?;
            return Ok(returns);
        }
        Ok(match self.link.as_mut() {
            Some(link) => evaluate_with(task, seed, episodes, &mut |o, a| {
                link.act(o, a);
            })?,
            None => {
                let actor = &self.agent.learner.live.actor;
                evaluate_with(task, seed, episodes, &mut |o, a| {
                    Policy::mean_action(actor, o, a)
                })?
            }
        })
    }

    /// Takes `steps` environment steps, storing each transition and running the learner
    /// updates the schedule calls for. Allocates nothing (through a controller process:
    /// nothing while it answers).
    pub fn collect(&mut self, steps: u64) -> Result<(), StepError> {
        self.collect_until(steps, false).map(|_| ())
    }

    /// [`Trainer::collect`] that, with `stop_at_episode_end`, stops after the step that ends
    /// an episode; returns the steps taken.
    ///
    /// One step is observe, act, step the plant, store, learn: kept in one loop over buffers
    /// owned by the trainer, so nothing between them allocates.
    pub fn collect_until(
        &mut self,
        steps: u64,
        stop_at_episode_end: bool,
    ) -> Result<u64, StepError> {
        if self.device.is_some() {
            return self.collect_on_device(steps, stop_at_episode_end);
        }
        if self.fleet.is_some() {
            return self.collect_from_fleet(steps, stop_at_episode_end);
        }
        let mut obs = [0f32; OBS];
        let mut act = [0f32; ACT];
        let mut laps = Laps::start();
        for taken in 1..=steps {
            if !self.in_episode {
                self.env.reset(&mut self.obs64);
                self.agent.begin_episode();
                self.in_episode = true;
                self.episode_step = 0;
                laps.lap(&mut self.times.env_s);
            }
            for (o, x) in obs.iter_mut().zip(&self.obs64) {
                *o = *x as f32;
            }
            let log_prob = if self.link.is_some() && !self.agent.in_warmup() {
                self.act_through_link(&obs, &mut act)?
            } else {
                self.agent.act(&obs, &mut act)
            };
            laps.lap(&mut self.times.act_s);
            let (t, last) = env_step(
                self.env.as_mut(),
                &obs,
                &act,
                log_prob,
                self.action_penalty,
                &mut self.act64,
                &mut self.next64,
            )
            .map_err(StepError::Sim)?;
            laps.lap(&mut self.times.env_s);
            core::mem::swap(&mut self.obs64, &mut self.next64);
            self.episode_step += 1;
            if last {
                self.in_episode = false;
                self.episodes += 1;
            }
            self.observe(None, &t).map_err(StepError::Update)?;
            laps.lap(&mut self.times.learn_s);
            if last && stop_at_episode_end {
                return Ok(taken);
            }
        }
        Ok(steps)
    }

    /// [`Trainer::collect`] with the agent on the device: the host steps the plant, sends each
    /// outcome and gets the next action.
    fn collect_on_device(
        &mut self,
        steps: u64,
        stop_at_episode_end: bool,
    ) -> Result<u64, StepError> {
        let mut obs = [0f32; OBS];
        let mut next = [0f32; OBS];
        // The device acts and learns in one exchange: its time is charged to learning.
        let mut laps = Laps::start();
        for taken in 1..=steps {
            let dev = self.device.as_mut().expect("checked");
            if !self.in_episode {
                self.env.reset(&mut self.obs64);
                laps.lap(&mut self.times.env_s);
                for (o, x) in obs.iter_mut().zip(&self.obs64) {
                    *o = *x as f32;
                }
                dev.begin(&obs, &mut self.device_action)
                    .map_err(StepError::Device)?;
                laps.lap(&mut self.times.learn_s);
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
            laps.lap(&mut self.times.env_s);
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
            laps.lap(&mut self.times.learn_s);
            core::mem::swap(&mut self.obs64, &mut self.next64);
            self.episode_step += 1;
            self.agent.env_steps += 1;
            if step.last {
                self.in_episode = false;
                self.episodes += 1;
                if stop_at_episode_end {
                    return Ok(taken);
                }
            }
        }
        Ok(steps)
    }

    /// [`Trainer::collect`] with a fleet: sends the policy when it changed, collects a round
    /// (deterministic) or what arrived (free), inserts the blocks; until `steps` were
    /// inserted or, with `stop_at_episode_end`, the fleet is between episodes.
    fn collect_from_fleet(
        &mut self,
        steps: u64,
        stop_at_episode_end: bool,
    ) -> Result<u64, StepError> {
        let mut fleet = self.fleet.take().expect("checked");
        let r = self.fleet_rounds(&mut fleet, steps, stop_at_episode_end);
        self.fleet = Some(fleet);
        r
    }

    fn fleet_rounds(
        &mut self,
        fleet: &mut Fleet,
        steps: u64,
        stop_at_episode_end: bool,
    ) -> Result<u64, StepError> {
        let start = self.agent.env_steps;
        // Waiting for the plants counts as the environment's time, sending the policy as
        // acting, inserting (and the updates it runs) as learning.
        let mut laps = Laps::start();
        loop {
            self.send_policy(fleet)?;
            laps.lap(&mut self.times.act_s);
            fleet
                .collect(self.agent.env_steps)
                .map_err(StepError::Fleet)?;
            laps.lap(&mut self.times.env_s);
            let inbox = fleet.take_inbox();
            let mut r = Ok(());
            for (i, frame) in &inbox {
                // Free: parameters go out between blocks, at the plants' rate.
                r = self.insert_block(fleet, *i, frame);
                laps.lap(&mut self.times.learn_s);
                if r.is_ok() && fleet.is_free() {
                    r = self.send_policy(fleet);
                    laps.lap(&mut self.times.act_s);
                }
                if r.is_err() {
                    break;
                }
            }
            fleet.recycle(inbox);
            r?;
            let taken = self.agent.env_steps - start;
            if taken >= steps || (stop_at_episode_end && taken > 0 && fleet.at_boundary()) {
                return Ok(taken);
            }
        }
    }

    /// Sends the policy to the fleet when [`Fleet::params_due`] says so.
    fn send_policy(&mut self, fleet: &mut Fleet) -> Result<(), StepError> {
        if fleet.params_due(self.params_dirty, self.agent.env_steps) {
            fleet
                .send_params(&self.agent.learner.live.actor, self.agent.env_steps)
                .map_err(StepError::Fleet)?;
            self.params_dirty = false;
        }
        Ok(())
    }

    /// Inserts the transitions of one block of plant `i` in order: a record that starts an
    /// episode opens a fresh replay episode for the plant, and each runs the updates the
    /// schedule calls for (the rate limit: updates per inserted transition).
    fn insert_block(&mut self, fleet: &mut Fleet, i: usize, frame: &[u8]) -> Result<(), StepError> {
        let Some((head, records)) = fleet.accept(i, frame, OBS, ACT) else {
            return Ok(());
        };
        let words = mpo_link::fleet::frames::record_words(OBS, ACT);
        for rec in records.chunks_exact(4 * words) {
            let (flags, t) = decode_record::<OBS, ACT>(rec);
            if flags & mpo_link::fleet::frames::FIRST != 0 {
                fleet.members[i].episode = self.agent.replay.new_episode_id();
            }
            self.observe(Some(fleet.members[i].episode), &t)
                .map_err(StepError::Update)?;
            if flags & mpo_link::fleet::frames::LAST != 0 {
                self.episodes += 1;
            }
        }
        if i == 0 {
            // Plant 0's stream is the in-process run's: the checkpoint keeps it.
            self.agent.explore.collector = head.collector;
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
        mut dev: Device,
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

    /// Stores a transition (in the replay's current episode, or in `episode` for a fleet's
    /// plant) and runs the learner updates the schedule calls for.
    fn observe(&mut self, episode: Option<u64>, t: &Transition<OBS, ACT>) -> Result<(), String> {
        let mut bad = None;
        let episode = episode.unwrap_or(self.agent.replay.counters().current_episode);
        let (stats, dirty) = (&mut self.stats, &mut self.params_dirty);
        self.agent
            .observe_in(episode, t, &self.pool, &mut |s| {
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
        // A refit observation normalisation changes the policy without an update.
        self.params_dirty |= self.agent.obs_norm_due();
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

/// One record of a fleet block (`mpo_link::fleet::frames::record_words` little-endian
/// words: flags, obs, action, reward, next obs, discount, log-probability): its flags and
/// transition.
fn decode_record<const OBS: usize, const ACT: usize>(rec: &[u8]) -> (u32, Transition<OBS, ACT>) {
    let mut w = rec.chunks_exact(4).map(|b| [b[0], b[1], b[2], b[3]]);
    let flags = u32::from_le_bytes(w.next().unwrap_or_default());
    let mut f = w.map(f32::from_le_bytes);
    let mut t = Transition {
        obs: [0.0; OBS],
        action: [0.0; ACT],
        reward: 0.0,
        next_obs: [0.0; OBS],
        discount: 0.0,
        behaviour_log_prob: 0.0,
    };
    let slots = t
        .obs
        .iter_mut()
        .chain(t.action.iter_mut())
        .chain([&mut t.reward]);
    let slots = slots.chain(t.next_obs.iter_mut()).chain([&mut t.discount]);
    for x in slots.chain([&mut t.behaviour_log_prob]) {
        *x = f.next().unwrap_or(0.0);
    }
    (flags, t)
}

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI> + Policy,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
> Training for Trainer<OBS, ACT, TRI, P, Q, BC, C, L, M, N, CAP>
{
    fn sizes(&self) -> Sizes {
        Sizes {
            obs: OBS,
            act: ACT,
            actor: P::HIDDEN,
            critic: Q::HIDDEN,
            batch: BC * C,
            chunks: C,
            seq: L,
            m: M,
            n: N,
            replay_capacity: CAP,
            actor_blocks: <P as PolicyNet<OBS, ACT, TRI>>::BLOCKS,
            critic_blocks: Q::BLOCKS,
            bins: Q::BINS,
        }
    }
    fn env_steps(&self) -> u64 {
        self.agent.env_steps
    }
    fn updates(&self) -> u64 {
        self.agent.learner.updates
    }
    fn episodes(&self) -> u64 {
        self.episodes
    }
    fn at_episode_boundary(&self) -> bool {
        Trainer::at_episode_boundary(self)
    }
    fn collect(&mut self, steps: u64, stop_at_episode_end: bool) -> Result<u64, StepError> {
        self.collect_until(steps, stop_at_episode_end)
    }
    fn evaluate(
        &mut self,
        task: &TaskDef,
        seed: u32,
        episodes: u32,
    ) -> Result<Vec<f64>, TrainError> {
        Trainer::evaluate(self, task, seed, episodes)
    }
    fn take_stat_means(&mut self) -> Vec<f64> {
        self.stats.take_means()
    }
    fn mean_action(&self, obs: &[f32], action: &mut [f32]) {
        Policy::mean_action(&self.agent.learner.live.actor, obs, action)
    }
    fn meta(&self, base: Meta) -> Meta {
        Trainer::meta(self, base)
    }
    fn save(&self, run_dir: &Path, meta: &Meta) -> Result<(), TrainError> {
        checkpoint::save(run_dir, &self.agent.learner, &self.agent.replay, meta)?;
        Ok(())
    }
    fn params_sha256(&self) -> String {
        let l = &self.agent.learner.live;
        checkpoint::params_sha256(&l.actor, &l.critic)
    }
    fn attach_link(&mut self, link: Link) {
        self.attach(link)
    }
    fn link_mut(&mut self) -> Option<&mut Link> {
        self.link.as_mut()
    }
    fn take_link(&mut self) -> Option<Link> {
        self.link.take()
    }
    fn param_count(&self) -> usize {
        let l = &self.agent.learner.live;
        l.actor.len() + l.critic.len()
    }
    fn weight_growth(&self) -> [f64; 2] {
        let (l, s) = (&self.agent.learner.live, self.sizes());
        [
            weight_growth::growth(&l.actor, &checkpoint::actor_layout(&s)),
            weight_growth::growth(&l.critic, &checkpoint::critic_layout(&s)),
        ]
    }
    fn dormant(&self) -> Option<[f64; 2]> {
        let (l, replay) = (&self.agent.learner, &self.agent.replay);
        dormant::measure(&l.live.actor, &l.live.critic, &l.cfg, replay)
    }
    fn attach_device(&mut self, dev: Device, settings: &Settings) -> Result<(), TrainError> {
        Trainer::attach_device(self, dev, settings)
    }
    fn time_split(&self) -> TimeSplit {
        self.times
    }
    fn device_report(&self) -> Option<DeviceReport> {
        self.device.as_ref().map(|d| d.report.clone())
    }
    fn policy_len(&self) -> usize {
        self.agent.learner.live.actor.len()
    }
    fn attach_fleet(&mut self, fleet: Fleet) {
        self.fleet = Some(fleet);
        self.params_dirty = true;
    }
    fn fleet_mut(&mut self) -> Option<&mut Fleet> {
        self.fleet.as_mut()
    }
    fn take_fleet(&mut self) -> Option<Fleet> {
        self.fleet.take()
    }
}
