//! `mpo run`: a checkpoint's policy driving its task, as a robot would be driven.
//!
//! Two timing modes. Paced: one control step per period of the wall clock (default 1 kHz),
//! each woken by an absolute-time sleep so lateness does not accumulate; a request the
//! controller does not answer within its deadline gets the safe action (zero) and the plant
//! steps on. Lockstep: as fast as possible with a generous deadline, which makes the run
//! deterministic (episode i uses the environment seed of `mpo eval`'s episode i, so the
//! returns are `mpo eval`'s bit for bit).
//!
//! What is measured is what a control engineer asks first: how many deadlines were missed,
//! how long a round trip observation -> action took (p50 to max), and how late the loop woke.
//! Latencies go into fixed-size histograms allocated before the loop, so the loop itself
//! allocates nothing while the controller answers.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use mpo_link::service::monotonic_ns;
use serde::{Deserialize, Serialize};
use sim_bridge::{SimError, TaskDef};

use crate::eval::{eval_env_seed, mean_std};
use crate::link::{
    ControllerKind, ControllerTarget, Link, LinkOptions, LinkReport, LinkSetupError,
};
use crate::policy::Policy;
use crate::progress::Progress;

/// How the loop is timed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pacing {
    /// As fast as possible; deterministic.
    Lockstep,
    /// One step per period of the wall clock at this rate (Hz).
    Paced(f64),
}

/// When the run ends (or earlier on an interrupt).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Limit {
    /// After this many environment steps.
    Steps(u64),
    /// After this much wall-clock time (seconds).
    Seconds(f64),
}

/// What `mpo run` was asked to do.
pub struct RunRequest<'a> {
    /// Task of the checkpoint.
    pub task: TaskDef,
    /// What a controller process serves (names the policy's sizes).
    pub target: ControllerTarget,
    /// Environment steps the checkpoint was trained for (reported).
    pub checkpoint_env_steps: u64,
    /// Evaluation seed: episode i runs on `eval_env_seed(seed, i)`.
    pub seed: u32,
    /// Timing mode.
    pub pacing: Pacing,
    /// Stop condition.
    pub limit: Limit,
    /// Through a controller process, or in-process when `None`.
    pub link: Option<LinkOptions>,
    /// `SCHED_FIFO` priority of this loop.
    pub realtime: Option<i32>,
    /// Show a progress line.
    pub progress: bool,
    /// Set on SIGINT/SIGTERM: stop after the current step.
    pub interrupt: &'a AtomicBool,
}

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The controller could not be started or reached.
    #[error(transparent)]
    LinkSetup(#[from] LinkSetupError),
    /// Pushing the policy to the controller failed.
    #[error("controller link: {0}")]
    Link(#[from] mpo_link::LinkError),
    /// The simulator failed.
    #[error("simulator: {0}")]
    Sim(#[from] SimError),
    /// Real-time scheduling was asked for and refused.
    #[error("--realtime: {0}")]
    Realtime(String),
}

/// Distribution of one latency in microseconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Quantiles {
    /// Samples recorded.
    pub samples: u64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p999: f64,
    /// Largest sample.
    pub max: f64,
}

impl Quantiles {
    fn of(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        let us = |ns: u64| ns as f64 / 1e3;
        Self {
            samples: h.len(),
            mean: h.mean() / 1e3,
            p50: us(h.value_at_quantile(0.5)),
            p99: us(h.value_at_quantile(0.99)),
            p999: us(h.value_at_quantile(0.999)),
            max: us(h.max()),
        }
    }
}

/// What `mpo run` prints (JSON on stdout; a table on stderr).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Task.
    pub task: String,
    /// Environment steps of the checkpoint.
    pub checkpoint_env_steps: u64,
    /// Evaluation seed.
    pub seed: u32,
    /// Where the policy ran.
    pub controller: ControllerKind,
    /// `lockstep` or `paced`.
    pub mode: String,
    /// Control rate when paced.
    pub rate_hz: Option<f64>,
    /// Environment steps taken.
    pub steps: u64,
    /// Returns of the completed episodes (equal to `mpo eval`'s in lockstep without misses).
    pub returns: Vec<f64>,
    /// Mean of `returns` (0 when none completed).
    pub return_mean: f64,
    /// Population standard deviation of `returns`.
    pub return_std: f64,
    /// Return so far of the episode the run stopped in (absent when it stopped between
    /// episodes).
    pub partial_return: Option<f64>,
    /// Wall-clock seconds of stepping (environment construction between episodes excluded).
    pub wall_s: f64,
    /// Requests that got the safe action (zero) instead of the policy's.
    pub misses: u64,
    /// Request deadline in microseconds (through a controller process).
    pub deadline_us: Option<f64>,
    /// Observation sent -> action received (through a controller process), or the policy's
    /// inference time (in-process), in microseconds.
    pub latency_us: Quantiles,
    /// Work of one control step (observation to action to simulator step done), in
    /// microseconds: what has to fit in a period.
    pub cycle_us: Quantiles,
    /// Paced: how late each period's wake-up was, in microseconds (the loop's jitter).
    pub lateness_us: Option<Quantiles>,
    /// Paced: steps that ended after their period (the next step started late).
    pub overruns: u64,
    /// The 1-, 5- and 15-minute load averages when the run started (/proc/loadavg).
    pub load_average: Option<[f64; 3]>,
    /// Stopped early by SIGINT/SIGTERM.
    pub interrupted: bool,
    /// Counters of the controller link (through a controller process).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<LinkReport>,
}

/// The load averages from /proc/loadavg.
pub fn load_average() -> Option<[f64; 3]> {
    let s = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = s.split_whitespace().map(|x| x.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

fn histogram() -> Histogram<u64> {
    // 1 ns to 100 s at 3 significant digits: ~200 KiB, allocated once.
    Histogram::new_with_bounds(1, 100_000_000_000, 3).expect("valid histogram bounds")
}

/// Sleeps to the start of each period and measures how late it woke; counts steps that ran
/// past their period.
struct Pacer {
    period_ns: u64,
    next: u64,
    overruns: u64,
    lateness: Histogram<u64>,
}

impl Pacer {
    fn new(pacing: Pacing) -> Self {
        Self {
            period_ns: match pacing {
                Pacing::Lockstep => 0,
                Pacing::Paced(hz) => (1e9 / hz).round().max(1.0) as u64,
            },
            next: 0,
            overruns: 0,
            lateness: histogram(),
        }
    }

    /// The start of an episode's schedule (now).
    fn restart(&mut self) {
        self.next = monotonic_ns();
    }

    /// Waits for the current period to start (paced) and records the wake-up's lateness.
    fn wait(&mut self) {
        if self.period_ns > 0 {
            mpo_link::realtime::sleep_until(self.next);
            let woke = monotonic_ns();
            self.lateness
                .saturating_record(woke.saturating_sub(self.next).max(1));
        }
    }

    /// After a step: the next period, and an overrun if this step ended after it started.
    fn after_step(&mut self) {
        if self.period_ns == 0 {
            return;
        }
        self.next += self.period_ns;
        let now = monotonic_ns();
        if now > self.next {
            self.overruns += 1;
            // More than a whole period behind: start a fresh schedule rather than catching up
            // with a burst of steps.
            if now - self.next > self.period_ns {
                self.next = now;
            }
        }
    }
}

/// The policy, in this process or through the controller, with its latency recorded.
struct Actuator<'a> {
    policy: &'a dyn Policy,
    link: Option<Link>,
    latency: Histogram<u64>,
    misses_in_process: u64,
}

impl Actuator<'_> {
    /// The action for `obs` (the safe action, zero, when the policy's is not finite or the
    /// controller missed its deadline).
    fn act(&mut self, episode: u32, step: u32, obs: &[f32], act: &mut [f32]) {
        match self.link.as_mut() {
            Some(l) => {
                l.set_episode_step(episode as u64, step);
                if let Some(a) = l.act(obs, act) {
                    self.latency.saturating_record((a.t[3] - a.t[0]).max(1));
                }
            }
            None => {
                let t0 = monotonic_ns();
                self.policy.mean_action(obs, act);
                self.latency.saturating_record((monotonic_ns() - t0).max(1));
                if !act.iter().all(|a| a.is_finite()) {
                    // The link rejects non-finite actions; in-process does the same.
                    act.fill(0.0);
                    self.misses_in_process += 1;
                }
            }
        }
    }
}

/// Starts the controller process the request asks for and hands it the policy.
fn start_link(policy: &dyn Policy, req: &RunRequest<'_>) -> Result<Option<Link>, RunError> {
    let Some(opts) = &req.link else {
        return Ok(None);
    };
    let mut link = Link::start(&req.target, policy.obs_dim(), policy.act_dim(), opts)?;
    eprintln!(
        "acting through controller process {} (run id {}, {} wait{}, deadline {} us)",
        link.controller_pid()
            .map(|p| format!("pid {p}"))
            .unwrap_or_else(|| "attached".into()),
        link.run_id(),
        opts.wait.name(),
        if opts.spin.is_zero() {
            String::new()
        } else {
            format!(" after a {} us spin", opts.spin.as_micros())
        },
        opts.deadline.as_micros()
    );
    policy.push(&mut link)?;
    Ok(Some(link))
}

/// What the episodes came to.
#[derive(Default)]
struct Outcome {
    returns: Vec<f64>,
    steps: u64,
    stepping: Duration,
    partial_return: Option<f64>,
    interrupted: bool,
    cycle: Option<Histogram<u64>>,
}

/// Runs `policy` (the checkpoint's online policy) on the task as `req` says. Most of its length
/// is the summary's field list.
pub fn run(policy: &dyn Policy, req: RunRequest<'_>) -> Result<RunSummary, RunError> {
    let deadline = req.link.as_ref().map(|o| o.deadline);
    let link = start_link(policy, &req)?;
    if let Some(p) = req.realtime {
        mpo_link::realtime::enter(p).map_err(RunError::Realtime)?;
    }
    mpo_link::realtime::tight_timer_slack();
    let load_average = load_average();
    let mut actuator = Actuator {
        policy,
        link,
        latency: histogram(),
        misses_in_process: 0,
    };
    let mut pacer = Pacer::new(req.pacing);
    let len = match req.limit {
        Limit::Steps(n) => n,
        Limit::Seconds(s) => (s * 10.0).ceil() as u64,
    };
    let progress = Progress::new(req.progress, len, "{elapsed_precise} [{bar:30}] {msg}");
    let o = episodes(&req, &mut actuator, &mut pacer, &progress)?;
    progress.finish();
    let report = actuator.link.take().map(|mut l| {
        for e in l.drain_events() {
            eprintln!("{e}");
        }
        l.finish()
    });
    let (return_mean, return_std) = match o.returns.is_empty() {
        true => (0.0, 0.0),
        false => mean_std(&o.returns),
    };
    Ok(RunSummary {
        task: req.task.name().into(),
        checkpoint_env_steps: req.checkpoint_env_steps,
        seed: req.seed,
        controller: match report.is_some() {
            true => ControllerKind::Ipc,
            false => ControllerKind::InProcess,
        },
        mode: match req.pacing {
            Pacing::Lockstep => "lockstep".into(),
            Pacing::Paced(_) => "paced".into(),
        },
        rate_hz: match req.pacing {
            Pacing::Lockstep => None,
            Pacing::Paced(hz) => Some(hz),
        },
        steps: o.steps,
        returns: o.returns,
        return_mean,
        return_std,
        partial_return: o.partial_return,
        wall_s: o.stepping.as_secs_f64(),
        misses: report
            .as_ref()
            .map_or(actuator.misses_in_process, |r| r.misses),
        deadline_us: deadline.map(|d| d.as_secs_f64() * 1e6),
        latency_us: Quantiles::of(&actuator.latency),
        cycle_us: Quantiles::of(o.cycle.as_ref().expect("recorded")),
        lateness_us: (pacer.period_ns > 0).then(|| Quantiles::of(&pacer.lateness)),
        overruns: pacer.overruns,
        load_average,
        interrupted: o.interrupted,
        link: report,
    })
}

/// Steps episodes until the limit or an interrupt: episode `i` on a fresh environment of
/// evaluation seed `i`, each built outside the paced loop (loading a model takes
/// milliseconds). The paced loop is kept in one piece so that everything between two wake-ups
/// can be read at once.
fn episodes(
    req: &RunRequest<'_>,
    actuator: &mut Actuator<'_>,
    pacer: &mut Pacer,
    progress: &Progress,
) -> Result<Outcome, RunError> {
    let spec = req.task.spec();
    let (mut obs64, mut obs) = (vec![0f64; spec.obs_dim], vec![0f32; spec.obs_dim]);
    let (mut act, mut act64) = (vec![0f32; spec.act_dim], vec![0f64; spec.act_dim]);
    let mut cycle = histogram();
    let mut o = Outcome::default();
    let budget = match req.limit {
        Limit::Seconds(s) => Some(Duration::from_secs_f64(s)),
        Limit::Steps(_) => None,
    };
    let done = |steps: u64, stepping: Duration| match (req.limit, budget) {
        (Limit::Steps(n), _) => steps >= n,
        (Limit::Seconds(_), b) => stepping >= b.expect("seconds limit"),
    };
    'episodes: for episode in 0u32.. {
        let mut env = crate::plant::make(&req.task, eval_env_seed(req.seed, episode))?;
        env.reset(&mut obs64);
        let (mut ret, mut episode_step) = (0.0, 0u32);
        let started = Instant::now();
        pacer.restart();
        loop {
            if req.interrupt.load(Ordering::Relaxed) {
                (o.interrupted, o.partial_return) = (true, Some(ret));
                o.stepping += started.elapsed();
                break 'episodes;
            }
            pacer.wait();
            let work0 = monotonic_ns();
            for (x, y) in obs.iter_mut().zip(&obs64) {
                *x = *y as f32;
            }
            actuator.act(episode, episode_step, &obs, &mut act);
            for (x, a) in act64.iter_mut().zip(&act) {
                *x = a.clamp(-1.0, 1.0) as f64;
            }
            let step = env.try_step(&act64, &mut obs64)?;
            cycle.saturating_record((monotonic_ns() - work0).max(1));
            ret += step.reward;
            o.steps += 1;
            episode_step += 1;
            pacer.after_step();
            if o.steps & 255 == 0 {
                show(
                    req,
                    actuator,
                    progress,
                    o.steps,
                    o.stepping + started.elapsed(),
                    o.returns.len(),
                );
            }
            if done(o.steps, o.stepping + started.elapsed()) {
                o.stepping += started.elapsed();
                match step.last {
                    true => o.returns.push(ret),
                    false => o.partial_return = Some(ret),
                }
                break 'episodes;
            }
            if step.last {
                o.returns.push(ret);
                break;
            }
        }
        o.stepping += started.elapsed();
    }
    o.cycle = Some(cycle);
    Ok(o)
}

/// The progress line and the controller's events, every 256 steps.
fn show(
    req: &RunRequest<'_>,
    actuator: &mut Actuator<'_>,
    progress: &Progress,
    steps: u64,
    elapsed: Duration,
    episodes: usize,
) {
    if let Some(l) = actuator.link.as_mut() {
        for e in l.take_events() {
            progress.log(&e);
        }
    }
    if !progress.is_hidden() {
        progress.set_position(match req.limit {
            Limit::Steps(_) => steps,
            Limit::Seconds(_) => (elapsed.as_secs_f64() * 10.0) as u64,
        });
        let misses = actuator.link.as_ref().map_or(0, |l| l.report().misses);
        progress.set_message(format!(
            "{steps} steps, {episodes} episodes, {misses} misses"
        ));
    }
}

/// The human-readable table of a run (printed on stderr). One `push_str` per line of the
/// table, in the order printed: longer than a screen, but read top to bottom like its output.
// One `push_str` per line of the printed table, in the order printed: long, but read top to
// bottom as the output it makes (splitting it would scatter the layout).
pub fn table(s: &RunSummary) -> String {
    let mut t = String::new();
    let mode = match s.rate_hz {
        Some(hz) => format!("paced at {hz} Hz"),
        None => "lockstep".into(),
    };
    let ctl = match (&s.link, s.controller) {
        (Some(l), _) => format!("controller process ({} wait, {})", l.wait, l.origin),
        (None, _) => "in-process".into(),
    };
    t.push_str(&format!(
        "mpo run: {} ({} env steps checkpoint), {ctl}, {mode}{}\n",
        s.task,
        s.checkpoint_env_steps,
        if s.interrupted { ", interrupted" } else { "" }
    ));
    t.push_str(&format!(
        "  {:<22} {} in {:.2} s ({:.0} steps/s)\n",
        "steps",
        s.steps,
        s.wall_s,
        s.steps as f64 / s.wall_s.max(1e-9)
    ));
    let partial = s
        .partial_return
        .map(|r| format!(", unfinished episode {r:.1} so far"))
        .unwrap_or_default();
    t.push_str(&format!(
        "  {:<22} {} complete{}{partial}\n",
        "episodes",
        s.returns.len(),
        if s.returns.is_empty() {
            String::new()
        } else {
            format!(", return {:.2} +- {:.2}", s.return_mean, s.return_std)
        }
    ));
    let deadline = s
        .deadline_us
        .map(|d| format!(" (deadline {d:.0} us)"))
        .unwrap_or_default();
    t.push_str(&format!(
        "  {:<22} {} of {} ({:.3} %){deadline}\n",
        "missed (safe action)",
        s.misses,
        s.steps,
        100.0 * s.misses as f64 / (s.steps.max(1)) as f64
    ));
    let row = |name: &str, q: &Quantiles| {
        format!(
            "  {name:<22} p50 {:>8.1}  p99 {:>8.1}  p99.9 {:>8.1}  max {:>9.1}  (us, {} samples)\n",
            q.p50, q.p99, q.p999, q.max, q.samples
        )
    };
    let lat_name = if s.link.is_some() {
        "round trip"
    } else {
        "inference"
    };
    t.push_str(&row(lat_name, &s.latency_us));
    t.push_str(&row("control step", &s.cycle_us));
    if let Some(q) = &s.lateness_us {
        t.push_str(&row("wake-up lateness", q));
        t.push_str(&format!(
            "  {:<22} {}\n",
            "overruns (late step)", s.overruns
        ));
    }
    if let Some(l) = &s.link {
        t.push_str(&format!(
            "  {:<22} {} requests, {} replies, {} timeouts, {} rejected by it, {} replies dropped, {} restarts, {} files left\n",
            "link",
            l.requests,
            l.replies,
            l.timeouts,
            l.rejected_by_controller,
            l.dropped_replies,
            l.restarts,
            l.leftover_files
        ));
        if let Some(c) = &l.controller_stats {
            t.push_str(&format!("  {:<22} {c}\n", "controller"));
        }
    }
    if let Some([a, b, c]) = s.load_average {
        t.push_str(&format!("  {:<22} {a:.2} {b:.2} {c:.2}\n", "load average"));
    }
    t
}
