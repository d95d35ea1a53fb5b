//! A fleet: `mpo train --plants N` collects with N plant processes, one learner (this
//! process). Each plant steps its own copy of the task's environment with the policy it last
//! received and sends its transitions in blocks of `--sync-every K` steps over the fleet
//! transport (`mpo_link::fleet`, iceoryx2 between the processes of a host); the learner inserts
//! them into its replay, runs the updates the row's schedule calls for per inserted transition
//! (the rate limit: updates per insert never depend on the plants' speed) and sends the
//! policy's parameters back. docs/fleet.md is the user's guide.
//!
//! This module is the learner's sizes-free side: starting and admitting the plants
//! ([`learner::Fleet::open`], [`learner::Fleet::spawn`], [`learner::Fleet::admit`]), the schedules' rounds, faults and the
//! counters. What depends on the sizes is elsewhere: the trainer decodes blocks into
//! transitions (`crate::trainer`), and a plant process runs [`worker::run`] for its row.
//!
//! Seeds: plant 0 steps the environment seeded with the run's seed and draws from the
//! collector stream of the in-process run ([`collector_of`], [`env_seed_of`]); plant `i > 0`
//! from streams derived from the seed and `i`. So a one-plant fleet is the in-process run.

pub mod learner;
pub mod worker;

use std::time::Duration;

use mpo_core::rng::Rng;
use mpo_link::fleet::frames::{Identity, put_text, text_of};
use serde::{Deserialize, Serialize};

/// How plants and learner take turns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FleetSchedule {
    /// Rounds: every plant takes K steps with the policy version of the round, the learner
    /// inserts the blocks in plant order, learns, and starts the next round. The same seed
    /// gives the same bits whatever the processes' timing.
    Deterministic,
    /// Plants never wait: each sends a block every K steps and acts with the newest
    /// parameters it has; the learner inserts blocks as they arrive.
    Free,
}

impl FleetSchedule {
    /// The flag's value (`deterministic`, `free`).
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "deterministic" => Some(Self::Deterministic),
            "free" => Some(Self::Free),
            _ => None,
        }
    }

    /// The WELCOME frame's `mode`.
    pub fn code(self) -> u32 {
        match self {
            Self::Deterministic => 0,
            Self::Free => 1,
        }
    }
}

/// `--plants`, `--sync-every`, `--schedule`, `--plant-timeout`.
#[derive(Clone, Debug)]
pub struct FleetOptions {
    /// Plant processes to start.
    pub plants: usize,
    /// Steps per block (K): a plant sends its transitions and looks for new parameters
    /// every K steps.
    pub sync_every: u32,
    /// The schedule.
    pub schedule: FleetSchedule,
    /// A plant silent this long while the learner waits for it is dropped (and, when the
    /// learner started it, killed).
    pub timeout: Duration,
    /// Free schedule: a block acted with a policy more than this many versions older than
    /// the learner's newest is dropped (counted), not inserted.
    pub max_lag: u64,
    /// Each plant's steps per second of wall clock (a robot's control rate); `None`: as fast
    /// as it steps.
    pub rate: Option<f64>,
    /// Times the learner restarts each plant process it started, when it dies or hangs
    /// (`--plant-restarts`).
    pub restarts: u32,
    /// The run id plants join with (`--fleet-run`, or a resumed run's); `None`: a fresh one.
    pub run: Option<mpo_link::RunId>,
    /// Plants on other hosts over zenoh (`--plants-remote`): the learner listens and waits
    /// for them instead of starting plant processes. `None`: plant processes of this host over
    /// iceoryx2.
    pub remote: Option<RemoteOptions>,
}

/// `--plants-remote N --fleet-listen ...`: where the learner listens.
#[derive(Clone, Debug)]
pub struct RemoteOptions {
    /// The endpoints to listen on and the certificates.
    pub listen: mpo_link::fleet::Remote,
}

/// Why a build without the `zenoh` feature cannot reach other hosts.
pub const NO_ZENOH: &str = "this mpo was built without the `zenoh` feature (plants on other \
     hosts): build it with `cargo build --release -p mpo-host --features zenoh`";

/// The learner's end of the link to plants on other hosts.
#[cfg(feature = "zenoh")]
pub fn remote_learner(
    run: &mpo_link::RunId,
    remote: &mpo_link::fleet::Remote,
    plants: usize,
) -> Result<Box<dyn mpo_link::fleet::LearnerPort>, mpo_link::LinkError> {
    Ok(Box::new(mpo_link::fleet::zenoh::ZenohLearner::open(
        run, remote, plants,
    )?))
}

/// The learner's end of the link to plants on other hosts (not in this build).
#[cfg(not(feature = "zenoh"))]
pub fn remote_learner(
    _run: &mpo_link::RunId,
    _remote: &mpo_link::fleet::Remote,
    _plants: usize,
) -> Result<Box<dyn mpo_link::fleet::LearnerPort>, mpo_link::LinkError> {
    Err(mpo_link::LinkError(NO_ZENOH.into()))
}

/// A plant's end of the link to a learner on another host.
#[cfg(feature = "zenoh")]
pub fn remote_plant(
    run: &mpo_link::RunId,
    remote: &mpo_link::fleet::Remote,
) -> Result<Box<dyn mpo_link::fleet::PlantPort>, mpo_link::LinkError> {
    Ok(Box::new(mpo_link::fleet::zenoh::ZenohPlant::open(
        run, remote,
    )?))
}

/// A plant's end of the link to a learner on another host (not in this build).
#[cfg(not(feature = "zenoh"))]
pub fn remote_plant(
    _run: &mpo_link::RunId,
    _remote: &mpo_link::fleet::Remote,
) -> Result<Box<dyn mpo_link::fleet::PlantPort>, mpo_link::LinkError> {
    Err(mpo_link::LinkError(NO_ZENOH.into()))
}

/// Checks a zenoh link's endpoints and certificates (as far as this build can).
#[cfg(feature = "zenoh")]
pub fn check_remote(remote: &mpo_link::fleet::Remote) -> Result<(), mpo_link::LinkError> {
    mpo_link::fleet::zenoh::check(remote)
}

/// Checks a zenoh link's endpoints and certificates (not in this build).
#[cfg(not(feature = "zenoh"))]
pub fn check_remote(_remote: &mpo_link::fleet::Remote) -> Result<(), mpo_link::LinkError> {
    Err(mpo_link::LinkError(NO_ZENOH.into()))
}

/// Default steps per block: 50 divides the Control Suite's 1000-step episodes, so every
/// plant's episodes end at round ends.
pub const DEFAULT_SYNC_EVERY: u32 = 50;

/// Default `--plant-timeout` (generous: the machines this runs on are shared).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(30);

/// Default `--plant-restarts`.
pub const DEFAULT_RESTARTS: u32 = 3;

/// Default `max_lag` of the free schedule, in policy versions.
pub const DEFAULT_MAX_LAG: u64 = 100;

/// Mixed into the run's seed with the plant's index for plant `i > 0`'s streams.
const PLANT_SALT: u64 = 0x9e37_79b9_7f4a_7c15;

/// The environment seed of plant `i` (plant 0: the run's seed, as in-process).
pub fn env_seed_of(seed: u32, i: usize) -> u32 {
    seed ^ (i as u32).wrapping_mul(0x9e37_79b9)
}

/// The initial collector stream of plant `i`: plant 0's is the in-process run's (the first
/// split of the root seeded with `seed ^ STREAM_SALT`), plant `i`'s the first split of a root
/// seeded with that value mixed with `i`.
pub fn collector_of(seed: u32, i: usize) -> [u8; 32] {
    let base = seed as u64 ^ crate::collection::STREAM_SALT;
    let root = base ^ (i as u64).wrapping_mul(PLANT_SALT);
    Rng::seed_from_u64(root).split().state()
}

/// What a plant runs, for the learner to compare with its own: the task (name and hash), the
/// network variant, the row's sizes and the policy's parameter count.
pub fn identity(
    task: &sim_bridge::TaskDef,
    net: &str,
    z: &crate::sizes::Sizes,
    policy_len: usize,
) -> Identity {
    let mut id: Identity = bytemuck::Zeroable::zeroed();
    put_text(&mut id.task, task.name());
    put_text(&mut id.task_sha256, task.sha256());
    put_text(&mut id.net, net);
    let s = [
        z.obs,
        z.act,
        z.actor[0],
        z.actor[1],
        z.critic[0],
        z.critic[1],
        z.batch,
        z.chunks,
        z.seq,
        z.m,
        z.n,
    ];
    for (o, v) in id.sizes.iter_mut().zip(s) {
        *o = v as u32;
    }
    id.policy_len = policy_len as u32;
    id.replay = z.replay_capacity as u64;
    id
}

/// The WELCOME every plant of a run of `settings` gets (its streams, seed, mode and block
/// are filled per plant at admission): the warm-up, the exploration noise, the policy's
/// standard-deviation floor and the action penalty, as the in-process trainer uses them.
pub fn welcome_of(settings: &crate::settings::Settings) -> mpo_link::fleet::frames::Welcome {
    let sched = crate::collection::agent_schedule(settings);
    let mut w: mpo_link::fleet::frames::Welcome = bytemuck::Zeroable::zeroed();
    w.warmup_steps = sched.warmup_steps;
    w.noise_corr = sched.noise_corr;
    w.noise_pink = sched.noise_pink as u32;
    w.std_floor = settings.mpo.to_config().std_floor;
    w.action_penalty = settings.schedule.action_penalty as f32;
    w
}

/// One line for an identity in a refusal (`cartpole-balance/tiny (obs 5, act 1, policy 1234
/// parameters)`).
pub fn describe(id: &Identity) -> String {
    format!(
        "{}/{} (obs {}, act {}, policy {} parameters)",
        text_of(&id.task),
        text_of(&id.net),
        id.sizes[0],
        id.sizes[1],
        id.policy_len
    )
}

/// Why a plant's identity is refused, or `None` when it runs what the learner trains.
pub fn mismatch(plant: &Identity, learner: &Identity) -> Option<String> {
    if plant == learner {
        return None;
    }
    let what =
        if plant.task == learner.task && plant.net == learner.net && plant.sizes == learner.sizes {
            format!(
                "its task file differs (sha256 {} against the learner's {})",
                text_of(&plant.task_sha256),
                text_of(&learner.task_sha256)
            )
        } else {
            format!(
                "it runs {}, the learner trains {}",
                describe(plant),
                describe(learner)
            )
        };
    Some(what)
}

/// A fleet's counters, in the run's summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FleetReport {
    /// Plants started.
    pub plants: usize,
    /// `deterministic` or `free`.
    pub schedule: String,
    /// Steps per block.
    pub sync_every: u32,
    /// Rounds run (deterministic).
    pub rounds: u64,
    /// Blocks inserted.
    pub blocks: u64,
    /// Transitions inserted.
    pub transitions: u64,
    /// Policy versions sent.
    pub versions: u64,
    /// Plants dropped (died, hung, left); the run went on without them.
    pub dropped: u64,
    /// Plant processes the learner restarted after a drop.
    pub restarted: u64,
    /// Joins of a plant that had joined before (after a drop or a restart), or that worked
    /// for a previous incarnation of the learner (a resumed run).
    pub rejoined: u64,
    /// Plants refused (another task, sizes or protocol).
    pub refused: u64,
    /// Blocks dropped for acting with a policy more than `max_lag` versions old (free).
    pub stale_blocks: u64,
    /// Blocks a plant sent that never arrived (free: the learner's intake buffer overflowed).
    pub lost_blocks: u64,
    /// Blocks refused as malformed or non-finite.
    pub bad_blocks: u64,
    /// Mean policy-version lag of the inserted blocks (0 in the deterministic schedule).
    pub lag_mean: f64,
    /// Largest lag inserted.
    pub lag_max: u64,
    /// Mean latency of a parameter update (from the learner's send of a version's last block
    /// to the plant having assembled it), over plants and versions, microseconds.
    pub param_latency_us_mean: f64,
    /// Its largest value.
    pub param_latency_us_max: f64,
    /// Frames of other runs or protocols ignored.
    pub ignored_frames: u64,
}

/// Why the fleet failed.
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    /// The transport failed.
    #[error("fleet transport: {0}")]
    Link(#[from] mpo_link::LinkError),
    /// A plant process could not be started.
    #[error("starting plant {index}: {message}")]
    Spawn {
        /// The plant.
        index: usize,
        /// Why.
        message: String,
    },
    /// A plant was refused at joining.
    #[error("plant {index} refused: {message}")]
    Refused {
        /// The plant.
        index: usize,
        /// Why.
        message: String,
    },
    /// Plants did not join in time.
    #[error("{missing} of {plants} plants did not join within {seconds:.0} s")]
    JoinTimeout {
        /// Plants that did not join.
        missing: usize,
        /// Plants expected.
        plants: usize,
        /// The wait.
        seconds: f64,
    },
    /// Every plant was dropped.
    #[error("every plant was dropped ({0}); nothing left to collect with")]
    NoPlants(String),
}
