//! Command-line flags (clap derive); validation and resolution happen in [`crate::commands`].

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

/// MPO (Maximum a Posteriori Policy Optimisation) on the DeepMind Control Suite.
#[derive(Debug, Parser)]
#[command(name = "mpo", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Train a policy in-process: collect with the sampled policy, learn, evaluate, checkpoint.
    ///
    /// Writes into the run directory: config.toml (the resolved configuration), metrics.csv and
    /// metrics.jsonl (one row per evaluation), curve.png and checkpoint/. Prints a one-line JSON
    /// summary on stdout. Exit status: 0 done, 1 error, 2 usage, 130 interrupted by Ctrl-C
    /// (after finishing the current episode and writing a checkpoint; a second Ctrl-C exits at
    /// once, keeping the last checkpoint).
    Train(TrainArgs),
    /// Evaluate a checkpoint's mean-action policy; prints mean and std of the return as JSON.
    Eval(EvalArgs),
    /// Write a checkpoint's policy as Rust source (constant arrays in read-only memory) for
    /// the inference-only firmware: OUT/policy.rs. Build the firmware with
    /// `MPO_FIRMWARE_WEIGHTS=OUT/policy.rs cargo build --release --manifest-path
    /// freestanding/firmware/Cargo.toml --target x86_64-unknown-linux-gnu` (docs/firmware.md).
    Export(ExportArgs),
    /// List the Control Suite tasks with their observation and action sizes and table rows.
    Tasks,
    /// Draw the learning curves of several runs (e.g. seeds) into one PNG.
    Plot(PlotArgs),
}

/// `mpo export`.
#[derive(Debug, Args)]
pub struct ExportArgs {
    /// Run directory or checkpoint directory.
    #[arg(long, value_name = "DIR")]
    pub checkpoint: PathBuf,
    /// Output directory (created if missing); the source goes to OUT/policy.rs.
    #[arg(long, value_name = "OUT")]
    pub out: PathBuf,
}

/// `mpo plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Output PNG.
    #[arg(long, value_name = "FILE.png")]
    pub out: PathBuf,
    /// Chart title [default: the task of the first run].
    #[arg(long)]
    pub title: Option<String>,
    /// Run directories (each with metrics.jsonl); each becomes one labelled curve.
    #[arg(required = true, value_name = "RUN_DIR")]
    pub runs: Vec<PathBuf>,
}

/// `mpo train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Control Suite task [default: cartpole-balance].
    #[arg(long)]
    pub task: Option<String>,
    /// Network variant of the task table row [default: default].
    #[arg(long)]
    pub net: Option<String>,
    /// Seed of the networks, the exploration noise and the training environment [default: 0].
    #[arg(long)]
    pub seed: Option<u32>,
    /// Total environment steps, a multiple of the 1000-step episode [default: per task].
    #[arg(long)]
    pub steps: Option<u64>,
    /// Run directory [default: runs/<task>-seed<seed>; with --resume, the resumed directory].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// TOML file overriding any subset of the defaults (keys as in a run's config.toml).
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<PathBuf>,
    /// Override one setting, e.g. `--set mpo.actor_lr=1e-4 --set schedule.update_interval=4`
    /// (applied after --config, before the flags above).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Continue the run whose checkpoint is in DIR, bit-identically to an uninterrupted run.
    /// Only --steps may differ from the checkpoint's configuration.
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// No progress bar (it is also hidden when stderr is not a terminal).
    #[arg(long)]
    pub no_progress: bool,
}

/// `mpo eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run directory or checkpoint directory.
    #[arg(long, value_name = "DIR")]
    pub checkpoint: PathBuf,
    /// Episodes, each on a fresh environment.
    #[arg(long, default_value_t = 10)]
    pub episodes: u32,
    /// Evaluation seed; episode i uses environment seed (2^31 + 1000 S + i) mod 2^32
    /// [default: the run's seed, which repeats the run's own evaluations].
    #[arg(long, value_name = "S")]
    pub seed: Option<u32>,
}
