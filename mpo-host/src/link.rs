//! The policy in a separate controller process, reached over iceoryx2 (`--controller ipc`).
//!
//! The host keeps the learner, the replay and the simulator; the controller process holds only
//! the policy network and answers observations with actions, as it would on the robot. The
//! host starts it as `mpo controller` (its own executable, so the controller always has the
//! same build and every task-table size), or attaches to one that is already running
//! (`--attach RUN_ID`, started by hand with `mpo controller --run RUN_ID --task ...`).
//!
//! The plant never stops for the controller: a request without an answer by its deadline
//! gets the safe action (zero), is counted and logged, and stepping goes on. A spawned
//! controller that exited is started again (at most once a second); an attached one is picked
//! up whenever it comes back, because iceoryx2 connects new ports on the next request and the
//! parameter history hands it the newest policy.

use std::io::{BufRead, BufReader, Read};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use mpo_core::params::Params;
use mpo_link::{Miss, Plant, PlantConfig, RunId, WaitMode};
use serde::{Deserialize, Serialize};

use crate::outage_log::OutageLog;

/// Where the policy runs while training or running a checkpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ControllerKind {
    /// In this process (no inter-process link).
    InProcess,
    /// In a controller process over iceoryx2 shared memory.
    Ipc,
}

/// Where the policy runs, and how the host reaches a controller process.
#[derive(Debug, clap::Args, Clone)]
pub struct LinkArgs {
    /// Where the policy runs: in this process, or in a controller process over iceoryx2 shared
    /// memory (started by mpo itself unless --attach is given).
    #[arg(long, value_enum, default_value_t = ControllerKind::InProcess)]
    pub controller: ControllerKind,
    /// With --controller ipc: use the controller already serving RUN_ID (`mpo controller
    /// --run RUN_ID --task ...`) instead of starting one; it is picked up whenever it
    /// (re)appears.
    #[arg(long, value_name = "RUN_ID")]
    pub attach: Option<String>,
    /// With --controller ipc: how both sides wait for each other: `event` (sleep until
    /// notified) or `busy-poll` (spin; lowest latency, burns a core: isolated cores only).
    #[arg(long, value_name = "MODE", default_value = "event", value_parser = ["event", "busy-poll"])]
    pub wait: String,
    /// With --controller ipc: deadline of one action request in microseconds; a later answer
    /// is a miss and the safe action (zero) is applied [default: 100000 in lockstep and
    /// training, half the period when paced].
    #[arg(long, value_name = "US")]
    pub deadline_us: Option<u64>,
    /// With --controller ipc and --wait event: spin this many microseconds on the answer
    /// before sleeping. An answer within it spares this process a wake-up (on a VM about a
    /// third of the round trip); costs at most that much CPU time per request.
    #[arg(long, value_name = "US", default_value_t = 0)]
    pub spin_us: u64,
    /// With --attach: seconds to wait for the controller to appear.
    #[arg(long, value_name = "S", default_value_t = 60.0)]
    pub connect_timeout: f64,
}

/// How to reach the controller process.
#[derive(Clone, Debug)]
pub struct LinkOptions {
    /// Attach to the controller serving this run id instead of starting one.
    pub attach: Option<String>,
    /// Event-driven waiting (default) or busy-polling, on both sides.
    pub wait: WaitMode,
    /// Deadline of each request; a later answer is a miss (safe action applied).
    pub deadline: Duration,
    /// With event waits: how long to spin on an answer before sleeping.
    pub spin: Duration,
    /// How long to wait for the controller to come up before the first request.
    pub connect_timeout: Duration,
    /// `SCHED_FIFO` priority for a spawned controller.
    pub realtime: Option<i32>,
}

/// Which policy a controller process serves: the run's task (built-in or a file) and network
/// variant, from which it finds the policy's sizes as the host does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ControllerTarget {
    /// The task's name.
    pub task: String,
    /// The network variant.
    pub net: String,
    /// The task file, for a task that is not built in.
    pub task_file: Option<PathBuf>,
}

impl ControllerTarget {
    /// The target of a run's settings.
    pub fn of(s: &crate::settings::Settings) -> Self {
        Self {
            task: s.task.clone(),
            net: s.net.clone(),
            task_file: s.task_file.clone(),
        }
    }

    /// The `mpo controller` flags that name it.
    pub fn args(&self) -> Vec<String> {
        let mut a = match &self.task_file {
            Some(f) => vec!["--task-file".into(), f.display().to_string()],
            None => vec!["--task".into(), self.task.clone()],
        };
        a.extend(["--net".into(), self.net.clone()]);
        a
    }
}

/// Why the link could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum LinkSetupError {
    /// iceoryx2 refused (for example shared memory exhausted, a bad run id).
    #[error("controller link: {0}")]
    Link(#[from] mpo_link::LinkError),
    /// The controller process could not be started or did not come up.
    #[error("controller process: {0}")]
    Spawn(String),
}

/// Counters of one link, reported in the run's summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LinkReport {
    /// The run id (service names `mpo/<id>/...`, file prefix `iox2_mpo_<id>_`).
    pub run_id: String,
    /// `spawned` or `attached`.
    pub origin: String,
    /// `event` or `busy-poll`.
    pub wait: String,
    /// Request deadline in microseconds.
    pub deadline_us: f64,
    /// Event waits: spin before sleeping, microseconds.
    pub spin_us: f64,
    /// Action requests sent.
    pub requests: u64,
    /// Valid answers in time.
    pub replies: u64,
    /// Requests that got the safe action instead (all causes).
    pub misses: u64,
    /// Of which: no answer by the deadline.
    pub timeouts: u64,
    /// Of which: the controller rejected the request.
    pub rejected_by_controller: u64,
    /// Malformed or stale answers dropped (never acted on).
    pub dropped_replies: u64,
    /// Parameter generations pushed.
    pub pushes: u64,
    /// Times a spawned controller was found dead and started again.
    pub restarts: u64,
    /// The controller's own counters (its `stats` line), when it was spawned and exited
    /// cleanly.
    pub controller_stats: Option<String>,
    /// Files of the run left under /dev/shm and /tmp/iceoryx2 after shutdown (0 when clean).
    pub leftover_files: usize,
}

/// A spawned controller process and how to start it again.
struct Spawned {
    exe: PathBuf,
    args: Vec<String>,
    child: Child,
    stdout: Option<BufReader<ChildStdout>>,
    started: Instant,
}

impl Spawned {
    fn start(exe: &PathBuf, args: &[String]) -> Result<Self, LinkSetupError> {
        let mut cmd = Command::new(exe);
        cmd.args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            // Its own process group: a Ctrl-C at the terminal reaches only the host, which then
            // shuts the controller down in order (after its last request).
            .process_group(0);
        // SAFETY: prctl is async-signal-safe; it only asks the kernel to SIGTERM the child when
        // this thread exits, so a host that is killed outright leaves no controller behind.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong);
                Ok(())
            });
        }
        let mut child = cmd
            .spawn()
            .map_err(|e| LinkSetupError::Spawn(format!("{}: {e}", exe.display())))?;
        let stdout = child.stdout.take().map(BufReader::new);
        Ok(Self {
            exe: exe.clone(),
            args: args.to_vec(),
            child,
            stdout,
            started: Instant::now(),
        })
    }

    /// Reads the `ready` line (blocks until the controller's ports are open or it exits).
    fn wait_ready(&mut self) -> Result<(), LinkSetupError> {
        let mut line = String::new();
        let out = self.stdout.as_mut().expect("stdout piped");
        let n = out.read_line(&mut line).unwrap_or(0);
        if n == 0 || line.trim() != "ready" {
            let status = self.child.wait().ok();
            return Err(LinkSetupError::Spawn(format!(
                "`{} {}` did not come up (exit {:?}); its error is above",
                self.exe.display(),
                self.args.join(" "),
                status.and_then(|s| s.code())
            )));
        }
        Ok(())
    }

    /// SIGTERM, then SIGKILL after 2 s. Returns the `stats` line if it printed one.
    fn stop(mut self) -> Option<String> {
        if let Ok(None) = self.child.try_wait() {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            let t0 = Instant::now();
            while let Ok(None) = self.child.try_wait() {
                if t0.elapsed() > Duration::from_secs(2) {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        let mut rest = String::new();
        if let Some(mut out) = self.stdout.take() {
            let _ = out.read_to_string(&mut rest);
        }
        rest.lines()
            .find(|l| l.starts_with("stats "))
            .map(|l| l.trim_start_matches("stats ").to_string())
    }
}

/// The host's end of the link to the controller process.
pub struct Link {
    plant: Option<Plant>,
    run: RunId,
    wait: WaitMode,
    deadline: Duration,
    spin: Duration,
    spawned: Option<Spawned>,
    restarts: u64,
    /// Misses, recoveries and restarts as log lines.
    log: OutageLog,
}

impl Link {
    /// Starts a controller process for `task`/`net` (or attaches to the one given in
    /// `opts.attach`) and waits until it listens.
    pub fn start(
        target: &ControllerTarget,
        obs_len: usize,
        act_len: usize,
        opts: &LinkOptions,
    ) -> Result<Self, LinkSetupError> {
        let run = match &opts.attach {
            Some(id) => RunId::parse(id)?,
            None => RunId::new(),
        };
        let plant = Plant::open(
            &run,
            PlantConfig {
                obs_len,
                act_len,
                wait: opts.wait,
                deadline: opts.deadline,
                spin: opts.spin,
            },
        )?;
        let spawned = match &opts.attach {
            Some(_) => None,
            None => {
                let exe = std::env::current_exe()
                    .map_err(|e| LinkSetupError::Spawn(format!("own executable: {e}")))?;
                let mut args: Vec<String> = vec!["controller".into(), "--run".into()];
                args.push(run.as_str().into());
                args.extend(target.args());
                args.extend(["--wait".into(), opts.wait.name().into()]);
                if let Some(p) = opts.realtime {
                    args.extend(["--realtime".to_string(), p.to_string()]);
                }
                let mut s = Spawned::start(&exe, &args)?;
                s.wait_ready()?;
                Some(s)
            }
        };
        let mut link = Self {
            plant: Some(plant),
            run,
            wait: opts.wait,
            deadline: opts.deadline,
            spin: opts.spin,
            spawned,
            restarts: 0,
            log: OutageLog::new(),
        };
        link.wait_connected(opts.connect_timeout, target)?;
        Ok(link)
    }

    fn plant(&mut self) -> &mut Plant {
        self.plant.as_mut().expect("plant lives until drop")
    }

    fn wait_connected(
        &mut self,
        timeout: Duration,
        target: &ControllerTarget,
    ) -> Result<(), LinkSetupError> {
        let t0 = Instant::now();
        let mut told = false;
        while !self.plant().controller_connected() {
            if !told && self.spawned.is_none() {
                eprintln!(
                    "waiting for the controller of run {}: start it with `mpo controller --run {} {}`",
                    self.run.as_str(),
                    self.run.as_str(),
                    target.args().join(" ")
                );
                told = true;
            }
            if t0.elapsed() > timeout {
                return Err(LinkSetupError::Spawn(format!(
                    "no controller attached to run {} within {:.0} s",
                    self.run.as_str(),
                    timeout.as_secs_f64()
                )));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(())
    }

    /// The run id (pass it to `mpo controller --run` to serve this host by hand).
    pub fn run_id(&self) -> &str {
        self.run.as_str()
    }

    /// The spawned controller's process id (None when attached).
    pub fn controller_pid(&self) -> Option<u32> {
        self.spawned.as_ref().map(|s| s.child.id())
    }

    /// Pushes the policy's parameters; every later request uses them.
    pub fn push<P: Params>(&mut self, policy: &P) -> Result<(), mpo_link::LinkError> {
        self.plant().push_params(policy).map(|_| ())
    }

    /// Labels the following requests with the episode and step (in the controller's view).
    pub fn set_episode_step(&mut self, episode: u64, step: u32) {
        self.plant().set_episode_step(episode, step);
    }

    /// The mean action for `obs`; `None` when the safe action (zero, written to `out`) was
    /// applied instead.
    pub fn act(&mut self, obs: &[f32], out: &mut [f32]) -> Option<mpo_link::Action> {
        let r = self.plant().act(obs, out);
        self.account(r)
    }

    /// A sampled action `mu + L z` for the caller's standard-normal draws `noise`, with its
    /// log-density; `None` on a miss (`out` is then the safe action, zero).
    pub fn act_sampled(
        &mut self,
        obs: &[f32],
        noise: &[f32],
        std_floor: f32,
        out: &mut [f32],
    ) -> Option<(mpo_link::Action, f32)> {
        let r = self.plant().act_sampled(obs, noise, std_floor, out);
        self.account(r)
            .map(|a| (a, a.log_prob.expect("sampled answers carry a log-density")))
    }

    fn account(&mut self, r: Result<mpo_link::Action, Miss>) -> Option<mpo_link::Action> {
        match r {
            Ok(a) => {
                self.log.answered();
                Some(a)
            }
            Err(m) => {
                let seq = self.plant().stats().requests;
                self.log.missed(seq, Instant::now(), || match m {
                    Miss::Timeout => "no answer by the deadline".to_string(),
                    Miss::Rejected => "the controller rejected it".to_string(),
                    Miss::Invalid(r) => format!("invalid request: {r:?}"),
                    Miss::Send => "send failed".to_string(),
                });
                self.restart_if_dead();
                None
            }
        }
    }

    /// A spawned controller that exited is started again, at most once a second.
    fn restart_if_dead(&mut self) {
        let Some(s) = self.spawned.as_mut() else {
            return;
        };
        let Ok(Some(status)) = s.child.try_wait() else {
            return;
        };
        if s.started.elapsed() < Duration::from_secs(1) {
            return;
        }
        match Spawned::start(&s.exe, &s.args) {
            Ok(new) => {
                self.restarts += 1;
                self.log.push(format!(
                    "controller: the process exited ({status}); started it again as pid {} (restart {})",
                    new.child.id(),
                    self.restarts
                ));
                // The recovery is logged even if the outage was too short to be.
                self.log.log_its_end();
                // The old one is gone: nothing to stop, its pipe is dropped.
                *s = new;
            }
            Err(e) => {
                s.started = Instant::now();
                self.log
                    .push(format!("controller: could not start it again: {e}"));
            }
        }
    }

    /// Log lines since the last call (misses, recoveries, restarts); short outages are
    /// summed up once a second (see [`OutageLog`]).
    pub fn take_events(&mut self) -> Vec<String> {
        self.log.take(Instant::now())
    }

    /// Every remaining log line (at the end of a run).
    pub fn drain_events(&mut self) -> Vec<String> {
        self.log.drain()
    }

    /// Counters so far.
    pub fn report(&self) -> LinkReport {
        let p = self.plant.as_ref().expect("plant").stats();
        LinkReport {
            run_id: self.run.as_str().to_string(),
            origin: if self.spawned.is_some() {
                "spawned"
            } else {
                "attached"
            }
            .into(),
            wait: self.wait.name().into(),
            deadline_us: self.deadline.as_secs_f64() * 1e6,
            spin_us: self.spin.as_secs_f64() * 1e6,
            requests: p.requests,
            replies: p.replies,
            misses: p.misses,
            timeouts: p.timeouts,
            rejected_by_controller: p.rejected_by_controller,
            dropped_replies: p.rejections.total() + p.stale_policy,
            pushes: p.pushes,
            restarts: self.restarts,
            controller_stats: None,
            leftover_files: 0,
        }
    }

    /// Stops a spawned controller (SIGTERM; an attached one keeps running), closes the link
    /// and reports, including the run's files still present afterwards.
    pub fn finish(mut self) -> LinkReport {
        let mut report = self.report();
        report.controller_stats = self.spawned.take().and_then(Spawned::stop);
        self.plant = None;
        self.run.remove_if_last();
        report.leftover_files = if report.origin == "spawned" {
            self.run.files().len()
        } else {
            0
        };
        report
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        if let Some(s) = self.spawned.take() {
            s.stop();
        }
        self.plant = None;
        self.run.remove_if_last();
    }
}

impl LinkOptions {
    /// The link settings of `--controller ipc`, `None` in-process. Flags that only apply to a
    /// controller process are refused without `--controller ipc` rather than ignored.
    pub fn from_args(
        a: &LinkArgs,
        default_deadline: Duration,
        realtime: Option<i32>,
    ) -> Result<Option<Self>, String> {
        if a.controller == ControllerKind::InProcess {
            let stray = [
                (a.attach.is_some(), "--attach"),
                (a.wait != "event", "--wait"),
                (a.deadline_us.is_some(), "--deadline-us"),
                (a.spin_us > 0, "--spin-us"),
            ];
            if let Some((_, flag)) = stray.iter().find(|(given, _)| *given) {
                return Err(format!("{flag} needs --controller ipc"));
            }
            return Ok(None);
        }
        if let Some(id) = &a.attach {
            RunId::parse(id).map_err(|e| format!("--attach: {e}"))?;
        }
        let deadline = match a.deadline_us {
            Some(0) => return Err("--deadline-us must be positive".into()),
            Some(us) => Duration::from_micros(us),
            None => default_deadline,
        };
        let wait = WaitMode::parse(&a.wait).ok_or(format!("--wait {}", a.wait))?;
        if a.spin_us > 0 && wait == WaitMode::BusyPoll {
            return Err("--spin-us applies to --wait event (busy-poll spins anyway)".into());
        }
        if !(a.connect_timeout.is_finite() && a.connect_timeout > 0.0) {
            return Err("--connect-timeout must be positive".into());
        }
        Ok(Some(Self {
            attach: a.attach.clone(),
            wait,
            deadline,
            spin: Duration::from_micros(a.spin_us),
            connect_timeout: Duration::from_secs_f64(a.connect_timeout),
            realtime,
        }))
    }
}
