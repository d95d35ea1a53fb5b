//! The interface between the training loop, compiled once, and a trainer of some sizes
//! ([`crate::trainer::Trainer`], compiled once per instantiation). Everything that depends on
//! the sizes is behind it: acting, storing, learning, evaluating the policy, writing the
//! checkpoint's tensors.

use std::path::{Path, PathBuf};

use sim_bridge::{SimError, TaskDef};

use crate::checkpoint::{CheckpointError, Meta, Verified};
use crate::device::{Device, DeviceReport};
use crate::link::{Link, LinkSetupError};
use crate::settings::Settings;
use crate::sizes::Sizes;

/// What a trainer is made from.
pub struct TrainingInit<'a> {
    /// The run's resolved settings.
    pub settings: &'a Settings,
    /// The task (its sizes are the instance's).
    pub task: &'a TaskDef,
    /// The checkpoint to continue from.
    pub resume: Option<&'a Verified>,
    /// Threads of the learner (results do not depend on it).
    pub threads: usize,
}

/// A run's act-and-learn state, whatever its sizes.
pub trait Training {
    /// The instance's sizes.
    fn sizes(&self) -> Sizes;
    /// Environment steps taken.
    fn env_steps(&self) -> u64;
    /// Learner updates made.
    fn updates(&self) -> u64;
    /// Training episodes completed.
    fn episodes(&self) -> u64;
    /// True between episodes (where checkpoints and evaluations may be taken).
    fn at_episode_boundary(&self) -> bool;
    /// Takes up to `steps` environment steps, storing each transition and running the learner
    /// updates the schedule calls for; with `stop_at_episode_end`, stops after the step that
    /// ends an episode. Returns the steps taken. Allocates nothing.
    fn collect(&mut self, steps: u64, stop_at_episode_end: bool) -> Result<u64, StepError>;
    /// Returns of the evaluation episodes of the current policy's mean action (in-process,
    /// through the controller, or on the device).
    fn evaluate(
        &mut self,
        task: &TaskDef,
        seed: u32,
        episodes: u32,
    ) -> Result<Vec<f64>, TrainError>;
    /// The learner statistics' means since the last call (NaN where none were recorded).
    fn take_stat_means(&mut self) -> Vec<f64>;
    /// The online policy's mean action for one observation.
    fn mean_action(&self, obs: &[f32], action: &mut [f32]);
    /// The checkpoint metadata of the present state, with the run-level fields of `base`
    /// (settings, task file, metrics, wall clock) kept.
    fn meta(&self, base: Meta) -> Meta;
    /// Writes the checkpoint of the present state (its metadata from [`Training::meta`]).
    fn save(&self, run_dir: &Path, meta: &Meta) -> Result<(), TrainError>;
    /// sha256 of the online actor and critic.
    fn params_sha256(&self) -> String;
    /// Acts through a controller process from now on.
    fn attach_link(&mut self, link: Link);
    /// The controller link, when acting through one.
    fn link_mut(&mut self) -> Option<&mut Link>;
    /// Takes the controller link (at the end of the run).
    fn take_link(&mut self) -> Option<Link>;
    /// Scalar parameters of actor and critic (what a device sends back).
    fn param_count(&self) -> usize;
    /// How far the online actor's and critic's hidden weights have grown since initialisation
    /// ([`crate::weight_growth`]): `[actor, critic]`, about 1 for fresh networks.
    fn weight_growth(&self) -> [f64; 2];
    /// The online actor's and critic's dormant ReLU units in percent ([`crate::dormant`]):
    /// `[actor, critic]`, `None` while the replay buffer is empty.
    fn dormant(&self) -> Option<[f64; 2]>;
    /// Learns on a device program from now on (a fresh run).
    fn attach_device(&mut self, dev: Device, settings: &Settings) -> Result<(), TrainError>;
    /// The device link's counters, when learning on one.
    fn device_report(&self) -> Option<DeviceReport>;
    /// Seconds this process spent learning, stepping the environment and acting (the other
    /// parts of [`crate::time_split::TimeSplit`] are the training loop's).
    fn time_split(&self) -> crate::time_split::TimeSplit;
    /// Scalar parameters of the policy (what a fleet's plants receive).
    fn policy_len(&self) -> usize;
    /// Collects with a fleet of plant processes from now on (`--plants N`).
    fn attach_fleet(&mut self, fleet: crate::fleet::learner::Fleet);
    /// The fleet, when collecting with one.
    fn fleet_mut(&mut self) -> Option<&mut crate::fleet::learner::Fleet>;
    /// Takes the fleet (at the end of the run).
    fn take_fleet(&mut self) -> Option<crate::fleet::learner::Fleet>;
}

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
    /// The simulator (missing MuJoCo, a physics error) or an external plant. (Transparent: the
    /// simulator's messages say what failed, and a prefix here printed them twice, once as
    /// this error and once as its source.)
    #[error(transparent)]
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
    /// The fleet of plant processes failed (`--plants`).
    #[error(transparent)]
    Fleet(#[from] crate::fleet::FleetError),
    /// Sizes of the row and the simulator disagree (a bug).
    #[error("internal: {0}")]
    Internal(String),
}

/// Why one step of [`Training::collect`] failed.
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
    /// The fleet failed (every plant dropped, the transport).
    Fleet(crate::fleet::FleetError),
}
