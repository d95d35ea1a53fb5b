//! The act-store-learn loop of training: what a trainer does between the plant's steps, as a
//! `no_std` state machine the host and a device share.
//!
//! [`AgentOf::act`] picks the action for a state (uniform during the warm-up, then a sample of the
//! online policy, both from the collector's random stream) and [`AgentOf::observe`] stores the
//! transition and runs the learner updates the schedule calls for (batches from the replay's
//! sampler stream). The host's trainer and the freestanding device trainer drive the same code,
//! which is why a run on the device has the bits of the same run in-process.
//!
//! Random streams are kept as raw states (`[u8; 32]`) so the whole agent is plain data that can
//! be created zeroed in place (a static on a device).

use bytemuck::Zeroable;

use crate::actor::Actor;
use crate::config::{ConfigError, MpoConfig};
use crate::critic::Critic;
use crate::explore::{Explorer, NoiseKind};
use crate::learner::{LearnerOf, UpdateError, UpdateStats};
use crate::network::{PolicyTrain, ValueNet};
use crate::parallel::Parallel;
use crate::replay::{BatchMode, Replay, SampleError, Transition};
use crate::rng::Rng;

/// When to act randomly and when to learn, in environment steps, and how the exploration
/// noise runs in time.
#[derive(Clone, Copy, Debug, PartialEq, Zeroable)]
pub struct AgentSchedule {
    /// Steps with uniformly random actions in [-1, 1] before the policy acts and learning
    /// starts.
    pub warmup_steps: u64,
    /// Environment steps between learning phases.
    pub update_interval: u64,
    /// Learner updates per learning phase.
    pub updates_per_interval: u64,
    /// Steps of an n-step transition (1 = single transitions; ignored with Retrace, whose
    /// sequence length is the learner's `sequence_len`).
    pub n_step: u32,
    /// Correlation `beta` in `[0, 1)` of the exploration noise between consecutive steps of
    /// an episode: the standard-normal draws `z` of `action = mu + L z` follow
    /// `z_t = beta z_(t-1) + sqrt(1 - beta^2) xi_t` (an AR(1) process, each `z_t` still
    /// standard normal), restarted with `z_1 = xi_1` at every episode. 0 = independent draws
    /// (the default). White noise of std 0.5 cannot pump a pendulum's energy: its torque
    /// changes sign every few steps; correlated noise pushes one way for about
    /// `1 / (1 - beta)` steps at the same marginal spread (the colored-noise argument of
    /// Eberhard et al. 2023). The stored log-density is the marginal one, not the conditional
    /// one, so Retrace (which uses it) refuses correlated noise.
    pub noise_corr: f32,
    /// Pink (1/f) exploration noise instead: each `z_t` is the sum of [`PINK_OCTAVES`]
    /// standard-normal rows over `sqrt(PINK_OCTAVES)`, row `k` redrawn every `2^k` steps of
    /// the episode (Voss's generator), so each `z_t` is still standard normal and its power
    /// falls as `1/f` from one step out to `2^PINK_OCTAVES` steps: pushes of every duration
    /// up to an episode, where AR(1) noise has one time scale. Eberhard et al. 2023 found it
    /// the best single default across tasks and agents (MPO among them). Exclusive with
    /// `noise_corr > 0`; like it, refused with Retrace.
    pub noise_pink: bool,
}

pub use crate::explore::PINK_OCTAVES;

impl AgentSchedule {
    /// The exploration noise this schedule asks for.
    pub fn noise_kind(&self) -> NoiseKind {
        NoiseKind {
            corr: self.noise_corr,
            pink: self.noise_pink,
        }
    }
}

/// Why a step of learning failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum AgentError {
    /// The replay could not provide a batch.
    Sample(SampleError),
    /// A learner update was rejected (and undone).
    Update(UpdateError),
}

impl core::fmt::Display for AgentError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Sample(e) => write!(f, "replay: {e}"),
            Self::Update(e) => write!(f, "{e}"),
        }
    }
}

impl core::error::Error for AgentError {}

/// A learner with the policy `P` and the critic `Q`, its replay, the two random streams of
/// acting and sampling, and the schedule.
#[derive(Zeroable)]
#[zeroable(bound = "")]
pub struct AgentOf<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
> {
    /// The learner.
    pub learner: LearnerOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N>,
    /// Experience.
    pub replay: Replay<CAP, OBS, ACT>,
    /// The collector's stream (warm-up actions and exploration noise) and the noise's state.
    pub explore: Explorer<ACT>,
    /// State of the sampler's stream (batch indices).
    pub sampler: [u8; 32],
    /// Environment steps observed.
    pub env_steps: u64,
    /// The schedule.
    pub schedule: AgentSchedule,
}

/// The agent with the two-layer MLPs (actor widths `AH1`, `AH2`, critic widths `QH1`, `QH2`).
pub type Agent<
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
> = AgentOf<
    OBS,
    ACT,
    TRI,
    Actor<OBS, ACT, TRI, AH1, AH2>,
    Critic<OBS, ACT, QH1, QH2>,
    BC,
    C,
    L,
    M,
    N,
    CAP,
>;

impl<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    P: PolicyTrain<OBS, ACT, TRI>,
    Q: ValueNet<OBS, ACT>,
    const BC: usize,
    const C: usize,
    const L: usize,
    const M: usize,
    const N: usize,
    const CAP: usize,
> AgentOf<OBS, ACT, TRI, P, Q, BC, C, L, M, N, CAP>
{
    /// A fresh agent: the learner initialised from `seed`, an empty replay, and the collector
    /// and sampler streams split from one root seeded with `stream_seed` (in that order).
    pub fn init(
        &mut self,
        cfg: MpoConfig,
        seed: u64,
        stream_seed: u64,
        schedule: AgentSchedule,
    ) -> Result<(), ConfigError> {
        if schedule.update_interval == 0 {
            return Err(ConfigError {
                field: "update_interval",
                requirement: "at least 1",
            });
        }
        if !(schedule.noise_corr >= 0.0 && schedule.noise_corr < 1.0) {
            return Err(ConfigError {
                field: "noise_corr",
                requirement: "in [0, 1)",
            });
        }
        if schedule.noise_corr > 0.0 && cfg.sequence_len > 1 {
            return Err(ConfigError {
                field: "noise_corr",
                requirement: "0 with Retrace (it needs each action's behaviour density)",
            });
        }
        if schedule.noise_pink && (schedule.noise_corr > 0.0 || cfg.sequence_len > 1) {
            return Err(ConfigError {
                field: "noise_pink",
                requirement: "off with noise_corr > 0 or with Retrace",
            });
        }
        self.learner.init(cfg, seed)?;
        self.replay.clear();
        let mut root = Rng::seed_from_u64(stream_seed);
        let collector = root.split().state();
        self.explore.init(collector, schedule.noise_kind());
        self.sampler = root.split().state();
        self.env_steps = 0;
        self.schedule = schedule;
        Ok(())
    }

    /// True while the warm-up's random actions are taken.
    pub fn in_warmup(&self) -> bool {
        self.env_steps < self.schedule.warmup_steps
    }

    /// The action for state `obs` and its log-density under the behaviour policy: uniform in
    /// [-1, 1] during the warm-up, else a sample of the online policy (`mu + L z` with `z`
    /// from [`AgentOf::draw_noise`]; for correlated noise the density is the marginal one).
    pub fn act(&mut self, obs: &[f32; OBS], action: &mut [f32; ACT]) -> f32 {
        if self.in_warmup() {
            return self.explore.uniform_action(action);
        }
        let mut z = [0f32; ACT];
        self.draw_noise(&mut z);
        self.learner.sample_action_from(obs, &z, action)
    }

    /// The standard-normal draws [`AgentOf::act`] turns into a sample of the policy after the
    /// warm-up (`action = mu + L z`): independent draws from the collector's stream, with
    /// `noise_corr > 0` their AR(1) combination with the episode's previous draw, or with
    /// `noise_pink` the pink generator's next value. Also for a policy evaluated elsewhere (a
    /// controller process) with the same bits.
    pub fn draw_noise(&mut self, z: &mut [f32; ACT]) {
        self.explore.draw_noise(z);
    }

    /// Marks the start of an episode (later transitions never join a sequence with earlier
    /// ones).
    pub fn begin_episode(&mut self) {
        self.replay.begin_episode();
        self.explore.begin_episode();
    }

    /// How the replay's batches are drawn for this configuration.
    pub fn batch_mode(&self) -> BatchMode {
        let cfg = &self.learner.cfg;
        if cfg.sequence_len > 1 {
            BatchMode::Sequences {
                len: cfg.sequence_len,
                gamma: cfg.gamma,
            }
        } else {
            BatchMode::OneStep {
                n: self.schedule.n_step.max(1),
                gamma: cfg.gamma,
            }
        }
    }

    /// Stores a transition, counts the step, and runs the updates the schedule calls for,
    /// on `par`, handing each update's statistics to `on_update`.
    pub fn observe<Par: Parallel>(
        &mut self,
        t: &Transition<OBS, ACT>,
        par: &Par,
        on_update: &mut dyn FnMut(&UpdateStats),
    ) -> Result<(), AgentError> {
        let episode = self.replay.counters().current_episode;
        self.observe_in(episode, t, par, on_update)
    }

    /// [`AgentOf::observe`] for a transition of episode `episode` (an id from
    /// [`Replay::new_episode_id`]): a fleet's learner inserts the episodes of several plants
    /// in turn. With the replay's current episode it is [`AgentOf::observe`], bit for bit.
    pub fn observe_in<Par: Parallel>(
        &mut self,
        episode: u64,
        t: &Transition<OBS, ACT>,
        par: &Par,
        on_update: &mut dyn FnMut(&UpdateStats),
    ) -> Result<(), AgentError> {
        self.replay.push_to(episode, t);
        self.env_steps += 1;
        if self.obs_norm_due() {
            let rows = &self.replay.raw().obs[..self.replay.len()];
            self.learner.fit_obs_norm(rows);
        }
        let s = self.schedule;
        if self.env_steps >= s.warmup_steps && self.env_steps.is_multiple_of(s.update_interval) {
            for _ in 0..s.updates_per_interval {
                let stats = self.update(par)?;
                on_update(&stats);
            }
        }
        Ok(())
    }

    /// True when the observation normalisation is refit after this step: every
    /// `obs_norm_interval` steps from the end of the warm-up (so before the first update).
    /// After [`AgentOf::observe`]: true when that step refit it (the policy changed without an
    /// update).
    pub fn obs_norm_due(&self) -> bool {
        let every = self.learner.cfg.obs_norm_interval as u64;
        let warm = self.schedule.warmup_steps;
        every > 0 && self.env_steps >= warm && (self.env_steps - warm).is_multiple_of(every)
    }

    /// One learner update on a batch drawn as the configuration's policy evaluation needs.
    pub fn update<Par: Parallel>(&mut self, par: &Par) -> Result<UpdateStats, AgentError> {
        self.fill_batch()?;
        self.learner.update_with(par).map_err(AgentError::Update)
    }

    /// Draws the learner's next batch from the replay (n-step transitions or sequences),
    /// normalised when observation normalisation is on.
    pub fn fill_batch(&mut self) -> Result<(), AgentError> {
        let mode = self.batch_mode();
        let mut rng = Rng::from_state(self.sampler);
        let r = self
            .replay
            .fill_batch(&mut rng, &mut self.learner.batch, mode);
        self.sampler = rng.state();
        r.map_err(AgentError::Sample)?;
        if self.learner.cfg.obs_norm_interval > 0 {
            self.learner.normalize_batch();
        }
        Ok(())
    }
}
