//! Command-line flags (clap derive); validation and resolution happen in [`crate::commands`].

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use crate::link::LinkArgs;

/// MPO (Maximum a Posteriori Policy Optimisation) on the DeepMind Control Suite.
#[derive(Debug, Parser)]
#[command(name = "mpo", version, about, long_about = None)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
// One value per process, parsed once: the size of the largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Train a policy: collect with the sampled policy, learn, evaluate, checkpoint.
    ///
    /// Writes into the run directory: config.toml (the resolved configuration), metrics.csv and
    /// metrics.jsonl (one row per evaluation), curve.png and checkpoint/. Prints a one-line JSON
    /// summary on stdout. Exit status: 0 done, 1 error, 2 usage, 130 interrupted by Ctrl-C
    /// (after finishing the current episode and writing a checkpoint; a second Ctrl-C exits at
    /// once, keeping the last checkpoint).
    Train(TrainArgs),
    /// Evaluate a checkpoint's mean-action policy; prints mean and std of the return as JSON.
    Eval(EvalArgs),
    /// Watch a checkpoint's policy: a video and/or a contact sheet of its evaluation episodes.
    ///
    /// Runs the mean action on the same evaluation environments and seeds as `mpo eval` (the
    /// returns printed and drawn on the frames are `mpo eval`'s) and renders offscreen with
    /// MuJoCo's renderer through EGL (without a GPU: Mesa's software renderer, Debian packages
    /// libegl1 libegl-mesa0 libgl1-mesa-dri libgles2). Video formats by --out's extension: .gif
    /// (built in, at most 50 frames per second) and .mp4 (needs the ffmpeg program). Prints a
    /// JSON summary.
    Render(RenderArgs),
    /// Write a checkpoint's policy as Rust source (constant arrays in read-only memory) for
    /// the inference-only firmware: OUT/policy.rs. Build the firmware with
    /// `MPO_FIRMWARE_WEIGHTS=OUT/policy.rs cargo build --release --manifest-path
    /// freestanding/firmware/Cargo.toml --target x86_64-unknown-linux-gnu` (docs/firmware.md).
    Export(ExportArgs),
    /// List the built-in tasks with their observation and action sizes and rows (and, with
    /// --task-file, a task file's).
    Tasks(TasksArgs),
    /// Draw the learning curves of several runs (e.g. seeds) into one PNG.
    Plot(PlotArgs),
    /// Run a checkpoint's policy on its task, paced at a control rate (default 1 kHz wall
    /// clock) or in lockstep, in-process or through a controller process over iceoryx2.
    ///
    /// Counts deadline misses (the safe action, zero, is applied and the plant keeps running)
    /// and reports the round-trip latency and the loop's wake-up lateness. Episode i runs on
    /// the evaluation seed of `mpo eval`, so in lockstep the returns equal `mpo eval`'s. Each
    /// episode's environment is built between episodes, outside the paced loop. Prints a
    /// table on stderr and a JSON summary on stdout; Ctrl-C or SIGTERM stops it cleanly (both
    /// processes, exit status 130).
    Run(RunArgs),
    /// Serve a policy over iceoryx2: the controller process (inference only, as on the robot).
    ///
    /// `mpo train/run --controller ipc` start one themselves; start it by hand to attach to
    /// (`--attach RUN_ID`). It answers with its initial policy until the host pushes
    /// parameters. Prints `ready` once listening and a `stats ...` line on exit (SIGINT or
    /// SIGTERM).
    Controller(ControllerArgs),
    /// A plant of a fleet (docs/fleet.md): joins the run, steps its own environment with the
    /// policy it last received and sends its transitions.
    ///
    /// `mpo train --plants N` starts its plants itself. On another host, start each plant of
    /// `mpo train --plants-remote N` by hand: `mpo plant-worker --fleet-connect ENDPOINT --run
    /// RUN_ID --index I` with the learner's task flags (it prints the command).
    PlantWorker(PlantWorkerArgs),
}

impl Command {
    /// The plant flags of the commands that step an environment (`train`, `eval`, `run`).
    pub fn plant_args(&self) -> Option<&crate::plant::PlantArgs> {
        match self {
            Self::Train(a) => Some(&a.plant),
            Self::Eval(a) => Some(&a.plant),
            Self::Run(a) => Some(&a.plant),
            _ => None,
        }
    }
}

/// `mpo run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Run directory or checkpoint directory.
    #[arg(long, value_name = "DIR")]
    pub checkpoint: PathBuf,
    /// Controller placement and link.
    #[command(flatten)]
    pub link: LinkArgs,
    /// Control rate in Hz, paced by the wall clock.
    #[arg(
        long,
        value_name = "HZ",
        default_value_t = 1000.0,
        conflicts_with = "lockstep"
    )]
    pub rate: f64,
    /// Step as fast as possible instead of pacing: deterministic, the returns equal
    /// `mpo eval`'s.
    #[arg(long)]
    pub lockstep: bool,
    /// Wall-clock duration in seconds.
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    pub seconds: f64,
    /// Stop after this many environment steps instead of --seconds.
    #[arg(long, value_name = "N")]
    pub steps: Option<u64>,
    /// Evaluation seed (episode i uses environment seed (2^31 + 1000 S + i) mod 2^32)
    /// [default: the run's seed].
    #[arg(long, value_name = "S")]
    pub seed: Option<u32>,
    /// SCHED_FIFO priority (1-99) for the paced loop and a spawned controller; needs root or
    /// CAP_SYS_NICE and CAP_IPC_LOCK.
    #[arg(long, value_name = "PRIO")]
    pub realtime: Option<i32>,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// An external plant's program.
    #[command(flatten)]
    pub plant: crate::plant::PlantArgs,
}

/// `mpo controller`.
#[derive(Debug, Args)]
pub struct ControllerArgs {
    /// Run id to serve: letters, digits and '-' (a host attaches with `--attach RUN_ID`).
    #[arg(long, value_name = "RUN_ID")]
    pub run: String,
    /// Built-in task whose policy size to serve.
    #[arg(long, default_value = crate::table::DEFAULT_TASK, conflicts_with = "task_file")]
    pub task: String,
    /// A task file instead of a built-in task.
    #[arg(long, value_name = "FILE.toml")]
    pub task_file: Option<PathBuf>,
    /// Network variant of the task's row.
    #[arg(long, default_value = crate::table::DEFAULT_NET)]
    pub net: String,
    /// `event` or `busy-poll` (must match the host's --wait).
    #[arg(long, value_name = "MODE", default_value = "event", value_parser = ["event", "busy-poll"])]
    pub wait: String,
    /// SCHED_FIFO priority (1-99); not with busy-poll.
    #[arg(long, value_name = "PRIO")]
    pub realtime: Option<i32>,
}

/// `mpo plant-worker`.
#[derive(Debug, Args)]
pub struct PlantWorkerArgs {
    /// The run to join (the learner's fleet run id).
    #[arg(long, value_name = "RUN_ID")]
    pub run: String,
    /// This plant's index in the fleet (0-based; its seeds derive from it).
    #[arg(long, value_name = "I")]
    pub index: usize,
    /// Built-in task.
    #[arg(long, default_value = crate::table::DEFAULT_TASK, conflicts_with = "task_file")]
    pub task: String,
    /// A task file instead of a built-in task.
    #[arg(long, value_name = "FILE.toml")]
    pub task_file: Option<PathBuf>,
    /// Network variant of the task's row.
    #[arg(long, default_value = crate::table::DEFAULT_NET)]
    pub net: String,
    /// Steps per block expected (sizes the first shared-memory segment).
    #[arg(long, value_name = "K", default_value_t = 50)]
    pub block_hint: usize,
    /// Steps per second of wall clock, as a robot at its control rate [default: as fast as
    /// the environment steps].
    #[arg(long, value_name = "HZ")]
    pub rate: Option<f64>,
    /// A learner on another host (`mpo train --plants-remote`): its zenoh endpoint,
    /// `tcp/ADDR:PORT`, or `tls/ADDR:PORT` with --fleet-ca/--fleet-cert/--fleet-key. Repeat
    /// for several. Without it, the plant joins a learner of this host over iceoryx2. Needs a
    /// build with the `zenoh` feature.
    #[arg(long, value_name = "ENDPOINT")]
    pub fleet_connect: Vec<String>,
    /// With --fleet-connect: seconds to keep trying to reach the learner (its endpoint may
    /// not listen yet) before giving up; a refused TLS handshake is retried until then too.
    #[arg(
        long,
        value_name = "S",
        default_value_t = 60.0,
        requires = "fleet_connect"
    )]
    pub fleet_connect_timeout: f64,
    /// With --fleet-connect: the link's certificates.
    #[command(flatten)]
    pub fleet_tls: FleetTlsArgs,
    /// Started by the learner (`mpo train --plants`): exit with it rather than wait for its
    /// resumed self.
    #[arg(long, hide = true)]
    pub spawned: bool,
}

/// The certificates of a fleet's mutual-TLS link over zenoh (`tls/` endpoints): PEM files,
/// all three or none.
#[derive(Debug, Args)]
pub struct FleetTlsArgs {
    /// The CA certificate that signed both the learner's and the plants' certificates (the
    /// only authority trusted: a peer without a certificate of it is refused).
    #[arg(long, value_name = "CA.pem", requires_all = ["fleet_cert", "fleet_key"])]
    pub fleet_ca: Option<PathBuf>,
    /// This side's certificate (the learner's must name the address plants connect to, as
    /// a subjectAltName IP or DNS entry).
    #[arg(long, value_name = "CERT.pem", requires_all = ["fleet_ca", "fleet_key"])]
    pub fleet_cert: Option<PathBuf>,
    /// This side's private key.
    #[arg(long, value_name = "KEY.pem", requires_all = ["fleet_ca", "fleet_cert"])]
    pub fleet_key: Option<PathBuf>,
}

impl FleetTlsArgs {
    /// The files, when given.
    pub fn files(&self) -> Option<mpo_link::fleet::TlsFiles> {
        match (&self.fleet_ca, &self.fleet_cert, &self.fleet_key) {
            (Some(ca), Some(cert), Some(key)) => Some(mpo_link::fleet::TlsFiles {
                ca: ca.clone(),
                cert: cert.clone(),
                key: key.clone(),
            }),
            _ => None,
        }
    }
}

/// `mpo tasks`.
#[derive(Debug, Args)]
pub struct TasksArgs {
    /// Also list (and check) these task files: their sizes, rows, and whether this build has
    /// a learner of each row's sizes.
    #[arg(long, value_name = "FILE.toml")]
    pub task_file: Vec<PathBuf>,
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
    /// Chart title [default: "MPO <the first run's task>"; with --by-task, "MPO"].
    #[arg(long)]
    pub title: Option<String>,
    /// Run directories (each with metrics.jsonl, or metrics.csv); each becomes one curve,
    /// labelled with the directory's name.
    #[arg(required = true, value_name = "RUN_DIR")]
    pub runs: Vec<PathBuf>,
    /// One panel per task (read from each run's config.toml), in the order the tasks first
    /// appear, each with its runs as curves: e.g. every task's seeds in one image.
    #[arg(long)]
    pub by_task: bool,
    /// With --by-task: a dashed line at RETURN in TASK's panel, e.g. `--target walker-walk=900`.
    /// Repeat for several tasks.
    #[arg(long, value_name = "TASK=RETURN", requires = "by_task")]
    pub target: Vec<String>,
    /// With --by-task: TASK's panel spans STEPS environment steps (its budget) even where its
    /// runs stop earlier, so a run's length reads against the budget, e.g.
    /// `--budget walker-run=1000000`. Repeat for several tasks.
    #[arg(long, value_name = "TASK=STEPS", requires = "by_task")]
    pub budget: Vec<String>,
    /// Draw the mean over the runs (over each panel's runs with --by-task) as the bold curve,
    /// its band +-1 standard deviation over the runs (population, not over episodes), the runs
    /// as thin lines behind it; only the evaluation steps every run has are averaged. Prints
    /// the mean at the last such step, with each run's return there.
    #[arg(long)]
    pub mean: bool,
    /// The metrics column to draw instead of the evaluation return: any column of
    /// `metrics.csv`, e.g. `critic_weight_growth`, `q_mean`, `std_mean`, `critic_loss`
    /// (docs/training.md lists them). Its axis fits the data; evaluations where the column is
    /// empty (before learning starts, or rows written before the column existed) are left
    /// out [default: eval_return_mean, with its +-1 std band over the evaluation episodes].
    #[arg(long, value_name = "COLUMN")]
    pub metric: Option<String>,
}

/// `mpo train`.
#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("fleet").args(["plants", "plants_remote"])))]
pub struct TrainArgs {
    /// Built-in task (`mpo tasks` lists them) [default: cartpole-balance].
    #[arg(long, conflicts_with = "task_file")]
    pub task: Option<String>,
    /// Train on a task file instead: a TOML file beside your MJCF model that says what the
    /// task observes, how it is rewarded, when it ends and how it starts (docs/task-files.md).
    /// Its sizes choose the learner; a build without a learner of those sizes says so (exit
    /// status 3) and `./mpo` rebuilds with them.
    #[arg(long, value_name = "FILE.toml")]
    pub task_file: Option<PathBuf>,
    /// Network variant of the task's row [default: default; a task file's rows are its
    /// `[rows.NAME]` tables].
    #[arg(long)]
    pub net: Option<String>,
    /// Seed of the networks, the exploration noise and the training environment [default: 0].
    #[arg(long)]
    pub seed: Option<u32>,
    /// Total environment steps, a multiple of the episode length when every episode has it
    /// [default: the row's].
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
    /// Only --steps may differ from the checkpoint's configuration. A fleet's run resumes
    /// with its fleet flags given again (--plants ...); see docs/fleet.md for when it is
    /// bit-identical.
    #[arg(long, value_name = "DIR")]
    pub resume: Option<PathBuf>,
    /// No progress bar (it is also hidden when stderr is not a terminal).
    #[arg(long)]
    pub no_progress: bool,
    /// Print the resolved configuration (the config.toml this command would write: the task
    /// table row's defaults under --config, --set and the flags, or the resumed run's) and exit
    /// without training.
    #[arg(long)]
    pub print_config: bool,
    /// Threads of the learner [default: every available CPU]. The results are bit-identical
    /// for any number: only the speed changes.
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Learn on a device instead of in this process: CMD (a program and its arguments) is the
    /// device trainer (freestanding/trainer, built for the `mcu` row), talking framed records
    /// on its stdin/stdout. Same results as the run in-process (docs/device.md). Checkpoints of
    /// a device run hold the parameters fetched at each evaluation, not the device's replay
    /// or optimiser state: they evaluate and export, they do not resume.
    #[arg(long, value_name = "CMD")]
    pub device: Option<String>,
    /// With --device: seconds to wait for each reply before sending the request again.
    #[arg(long, value_name = "S", default_value_t = 10.0, requires = "device")]
    pub device_timeout: f64,
    /// Controller placement: `--controller ipc` acts through a controller process in
    /// lockstep, with the same results as in-process training.
    #[command(flatten)]
    pub link: LinkArgs,
    /// Every N evaluations (the untrained policy's first), a contact sheet of evaluation
    /// episode 0 in <run>/renders/step-<env steps>.png (as `mpo render --strip`; needs
    /// offscreen rendering, see `mpo render --help`). Off by default.
    #[arg(long, value_name = "N")]
    pub render_every: Option<u32>,
    /// An external plant's program.
    #[command(flatten)]
    pub plant: crate::plant::PlantArgs,
    /// Collect with N plant processes (each stepping its own copy of the task's environment
    /// with the policy it last received) instead of in this process; the learner stays here
    /// and keeps the row's updates per inserted transition (docs/fleet.md). With --resume,
    /// the plants continue their streams from the checkpoint.
    #[arg(long, value_name = "N", conflicts_with = "device")]
    pub plants: Option<usize>,
    /// Collect with N plants on other hosts, over zenoh, instead of starting plant processes:
    /// the learner listens on --fleet-listen and waits (up to --plant-timeout) for N plants to
    /// join, each started on its host as `mpo plant-worker --fleet-connect ENDPOINT --run
    /// RUN_ID --index I` with this run's task flags (the learner prints the command). Needs a
    /// build with the `zenoh` feature (docs/fleet.md).
    #[arg(
        long,
        value_name = "N",
        conflicts_with = "device",
        requires = "fleet_listen"
    )]
    pub plants_remote: Option<usize>,
    /// With --plants-remote: a zenoh endpoint to listen on, `tcp/ADDR:PORT`, or
    /// `tls/ADDR:PORT` with --fleet-ca/--fleet-cert/--fleet-key (mutual TLS: only plants with
    /// a certificate of that CA get in). Repeat for several.
    #[arg(long, value_name = "ENDPOINT", requires = "plants_remote")]
    pub fleet_listen: Vec<String>,
    /// With --plants-remote: the run id the plants join with (letters, digits, '-') [default:
    /// with --resume the resumed run's (its plants join the resumed learner by themselves),
    /// otherwise a fresh one, printed].
    #[arg(long, value_name = "RUN_ID", requires = "plants_remote")]
    pub fleet_run: Option<String>,
    /// With --plants-remote: the link's certificates.
    #[command(flatten)]
    pub fleet_tls: FleetTlsArgs,
    /// With --plants: steps per block; a plant sends its transitions and receives the newest
    /// parameters every K steps [default: 50].
    #[arg(long, value_name = "K", requires = "fleet")]
    pub sync_every: Option<u32>,
    /// With --plants: `deterministic` (rounds in a fixed order: the same seed gives the same
    /// bits; one plant with --sync-every 1 is the in-process run) or `free` (plants never
    /// wait; faster, not reproducible).
    #[arg(long, value_name = "S", default_value = "deterministic", value_parser = ["deterministic", "free"], requires = "fleet")]
    pub schedule: String,
    /// With --plants: seconds a plant may stay silent (not joining, not delivering its block)
    /// before it is dropped and training goes on without it.
    #[arg(long, value_name = "S", default_value_t = 30.0, requires = "fleet")]
    pub plant_timeout: f64,
    /// With --plants: each plant steps at most HZ steps per second of wall clock, as a robot
    /// at its control rate (simulated plants otherwise step as fast as they can, which with
    /// the free schedule takes the learner's CPU) [default: unpaced].
    #[arg(long, value_name = "HZ", requires = "fleet")]
    pub plant_rate: Option<f64>,
    /// With --plants: times the learner starts a plant process again after it died or hung
    /// (each plant; the new process continues the plant's streams and joins the next round).
    #[arg(long, value_name = "N", default_value_t = crate::fleet::DEFAULT_RESTARTS, requires = "fleet")]
    pub plant_restarts: u32,
}

/// `mpo render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Run directory or checkpoint directory.
    #[arg(long, value_name = "DIR")]
    pub checkpoint: PathBuf,
    /// Episodes, each on a fresh evaluation environment (as `mpo eval`).
    #[arg(long, value_name = "K", default_value_t = 1)]
    pub episodes: u32,
    /// Evaluation seed; episode i uses environment seed (2^31 + 1000 S + i) mod 2^32
    /// [default: the run's seed].
    #[arg(long, value_name = "S")]
    pub seed: Option<u32>,
    /// Control steps pictured per episode [default: the whole episode]. The episode still
    /// runs to its end, so the returns printed are whole-episode returns.
    #[arg(long, value_name = "T")]
    pub steps: Option<u32>,
    /// Image width in pixels.
    #[arg(long, value_name = "W", default_value_t = 320)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, value_name = "H", default_value_t = 240)]
    pub height: u32,
    /// Camera: one of the model's (an unknown name lists them) or `free` (MuJoCo's free
    /// camera) [default: the model's first: cartpole `fixed`, walker and cheetah `side`, hopper
    /// `cam0`, acrobot and pendulum `fixed`].
    #[arg(long, value_name = "NAME")]
    pub camera: Option<String>,
    /// Frames per second; a frame every round(control rate / F) control steps, played in real
    /// time [default: the control rate, at most 50 for .gif].
    #[arg(long, value_name = "F")]
    pub fps: Option<f64>,
    /// The video: FILE.gif (built in) or FILE.mp4 (needs the ffmpeg program, Debian package
    /// `ffmpeg`). Each frame shows the step and the running return.
    #[arg(long, value_name = "FILE", required_unless_present = "strip")]
    pub out: Option<PathBuf>,
    /// A contact sheet: --strip-frames frames at regular intervals in one PNG, each labelled
    /// with its step and running return.
    #[arg(long, value_name = "FILE.png")]
    pub strip: Option<PathBuf>,
    /// Frames on the contact sheet.
    #[arg(long, value_name = "N", default_value_t = 8)]
    pub strip_frames: u32,
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
    /// An external plant's program.
    #[command(flatten)]
    pub plant: crate::plant::PlantArgs,
}
