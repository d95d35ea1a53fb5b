//! A plant in another process: the learner asks, an external program (a Gymnasium environment
//! in Python, a robot's own software) steps the plant and answers.
//!
//! # Protocol (version 1)
//!
//! Four iceoryx2 services per run, named after the run id like the controller link's
//! (`mpo/<run>/plant/...`, every file under the run's own prefix `iox2_mpo_<run>_`):
//!
//! | service                      | pattern       | payload | user header      | writer  |
//! |------------------------------|---------------|---------|------------------|---------|
//! | `mpo/<run>/plant/request`    | publish-subscribe | `[f64]` | [`PlantRequest`] | learner |
//! | `mpo/<run>/plant/reply`      | publish-subscribe | `[f64]` | [`PlantReply`]   | plant   |
//! | `mpo/<run>/plant/to-plant`   | event         |         |                  | learner |
//! | `mpo/<run>/plant/to-learner` | event         |         |                  | plant   |
//!
//! Every request is answered by exactly one reply with the same `seq`, except [`KIND_CLOSE`]
//! and [`KIND_BYE`], which have none. After each send the sender notifies the other side's
//! event, so both can sleep between messages. The payload is a slice of `f64`, as long as the
//! message needs (the publishers are sized from the task's sizes):
//!
//! | kind           | request payload                 | reply payload                         |
//! |----------------|---------------------------------|---------------------------------------|
//! | [`KIND_HELLO`] | the task's action bounds: `act` lows, then `act` highs | the plant's bounds (same layout; infinite or NaN where it has none) |
//! | [`KIND_RESET`] | empty                           | the first observation (`obs` values)  |
//! | [`KIND_STEP`]  | the action, in the plant's units | the next observation                 |
//! | [`KIND_CLOSE`] | empty; no reply                 |                                       |
//! | [`KIND_BYE`]   | empty; no reply                 |                                       |
//!
//! A run: HELLO (resent every 200 ms until answered: the plant may start after the learner);
//! then per environment instance `env` (one per seed: the training environment, and a fresh
//! one per evaluation episode) RESET with [`RESET_FRESH`] and the seed first, later RESETs
//! without it (the environment's own random stream continues, as dm_control's does), STEPs
//! until a reply has `last`, CLOSE when the instance is dropped; BYE at the end of the run.
//!
//! The action is sent in the plant's units: the learner maps the policy's `[-1, 1]` onto the
//! task file's `action_low`/`action_high` (linearly, per dimension) before it sends, so a
//! robot-side program receives what its actuators take.
//!
//! # Failures
//!
//! Every request has a deadline ([`ExternalOptions::timeout`]); a spawned plant program whose
//! process exits is noticed within [`SLICE`] of waiting. Either is an error naming the plant,
//! the request and the cause, never a hang. A reply with [`STATUS_ERROR`] carries the plant's
//! own error text.

use core::time::Duration;
use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::service::{RunId, monotonic_ns, remaining, wait_for_event};

/// The protocol version a plant must answer HELLO with.
pub const PROTOCOL_VERSION: u32 = 1;

/// Request: handshake (sizes, bounds, task name).
pub const KIND_HELLO: u32 = 1;
/// Request: start an episode of instance `env`.
pub const KIND_RESET: u32 = 2;
/// Request: one control step of instance `env`.
pub const KIND_STEP: u32 = 3;
/// Request: instance `env` is no longer used (no reply).
pub const KIND_CLOSE: u32 = 4;
/// Request: the run is over (no reply).
pub const KIND_BYE: u32 = 5;

/// The name of a request kind, for messages.
pub fn kind_name(kind: u32) -> &'static str {
    match kind {
        KIND_HELLO => "HELLO",
        KIND_RESET => "RESET",
        KIND_STEP => "STEP",
        KIND_CLOSE => "CLOSE",
        KIND_BYE => "BYE",
        _ => "an unknown request",
    }
}

/// RESET flag: a fresh environment instance; reset it with `seed` (Gymnasium's
/// `env.reset(seed=seed)`). Without it the instance continues its own random stream
/// (`env.reset()`).
pub const RESET_FRESH: u32 = 1;

/// Reply status: done.
pub const STATUS_OK: u32 = 0;
/// Reply status: the plant failed to do it; `message` says why.
pub const STATUS_ERROR: u32 = 1;

/// The longest the learner sleeps in one wait before it looks whether a spawned plant process
/// is still alive.
pub const SLICE: Duration = Duration::from_millis(50);

/// Bytes of the task name in HELLO.
pub const TASK_NAME_LEN: usize = 64;
/// Bytes of a reply's text.
pub const MESSAGE_LEN: usize = 256;

/// The header of every request (learner to plant).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("mpo_link::PlantRequest/v1")]
#[repr(C)]
pub struct PlantRequest {
    /// Strictly increasing per run; the reply echoes it.
    pub seq: u64,
    /// The environment instance (RESET, STEP, CLOSE).
    pub env: u64,
    /// RESET with [`RESET_FRESH`]: the seed.
    pub seed: u64,
    /// `KIND_*`.
    pub kind: u32,
    /// `RESET_*` flags.
    pub flags: u32,
    /// HELLO: the task's observation size.
    pub obs_len: u32,
    /// HELLO: the task's action size.
    pub act_len: u32,
    /// HELLO: the task's episode length in control steps.
    pub episode_steps: u32,
    /// HELLO: [`PROTOCOL_VERSION`].
    pub version: u32,
    /// HELLO: the task's name, UTF-8, NUL-padded.
    pub task: [u8; TASK_NAME_LEN],
}

/// The header of every reply (plant to learner).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("mpo_link::PlantReply/v1")]
#[repr(C)]
pub struct PlantReply {
    /// The request's `seq`.
    pub seq: u64,
    /// The request's `env`.
    pub env: u64,
    /// STEP: the reward of the step.
    pub reward: f64,
    /// STEP: 0 when the episode ended in a terminal state, else 1 (Gymnasium:
    /// `0.0 if terminated else 1.0`).
    pub discount: f64,
    /// The request's kind.
    pub kind: u32,
    /// `STATUS_*`.
    pub status: u32,
    /// STEP: 1 on the episode's last step (Gymnasium: `terminated or truncated`).
    pub last: u32,
    /// HELLO: the plant's observation size.
    pub obs_len: u32,
    /// HELLO: the plant's action size.
    pub act_len: u32,
    /// HELLO: the plant's episode length (0: it does not say).
    pub episode_steps: u32,
    /// HELLO: the protocol version the plant speaks.
    pub version: u32,
    /// Zero.
    pub reserved: u32,
    /// HELLO: what the plant is (e.g. `gymnasium Pendulum-v1`); errors: why. UTF-8,
    /// NUL-padded.
    pub message: [u8; MESSAGE_LEN],
}

// Plain integers and floats: the zero value is valid, and there is no padding (checked below),
// so the Python side's ctypes structures of the same fields have the same bytes.
unsafe impl bytemuck::Zeroable for PlantRequest {}
unsafe impl bytemuck::Zeroable for PlantReply {}
const _: () = {
    assert!(size_of::<PlantRequest>() == 3 * 8 + 6 * 4 + TASK_NAME_LEN);
    assert!(size_of::<PlantReply>() == 4 * 8 + 8 * 4 + MESSAGE_LEN);
};

impl Default for PlantRequest {
    fn default() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

impl Default for PlantReply {
    fn default() -> Self {
        bytemuck::Zeroable::zeroed()
    }
}

/// Text from a NUL-padded byte field.
pub fn text_of(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(&bytes[..end]).into_owned()
}

/// Writes `s` into a NUL-padded byte field (cut at a character boundary if too long).
pub fn set_text(field: &mut [u8], s: &str) {
    let mut n = s.len().min(field.len());
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    field[..n].copy_from_slice(&s.as_bytes()[..n]);
    field[n..].fill(0);
}

/// Why the external plant could not do what was asked: one line, naming the plant.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlantError(pub String);

impl core::fmt::Display for PlantError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for PlantError {}

/// What the learner expects of the plant (from the task file).
#[derive(Debug, Clone)]
pub struct Expected {
    /// The task's name (sent in HELLO; shown by the plant).
    pub task: String,
    /// Observation size.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// Episode length in control steps.
    pub episode_steps: usize,
    /// Per action dimension, `[low, high]` in the plant's units.
    pub bounds: Vec<(f64, f64)>,
}

/// What the plant said about itself in its HELLO reply.
#[derive(Debug, Clone, PartialEq)]
pub struct PlantInfo {
    /// Its description (e.g. `gymnasium Pendulum-v1`).
    pub name: String,
    /// Observation size.
    pub obs: usize,
    /// Action size.
    pub act: usize,
    /// Episode length (0: not said).
    pub episode_steps: usize,
    /// Per action dimension, `[low, high]` as the plant knows them (infinite or NaN: none).
    pub bounds: Vec<(f64, f64)>,
}

/// Deadlines.
#[derive(Debug, Clone, Copy)]
pub struct ExternalOptions {
    /// How long the plant may take to answer HELLO (its program starting included).
    pub connect_timeout: Duration,
    /// How long the plant may take to answer one RESET or STEP.
    pub timeout: Duration,
}

impl Default for ExternalOptions {
    fn default() -> Self {
        Self {
            connect_timeout: Duration::from_secs(60),
            timeout: Duration::from_secs(10),
        }
    }
}

/// The outcome of one STEP.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantStep {
    /// The reward.
    pub reward: f64,
    /// 0 at a terminal state, else 1.
    pub discount: f64,
    /// The episode's last step.
    pub last: bool,
}

/// The program that serves the plant, when the learner started it.
#[derive(Debug, Clone)]
pub struct PlantCommand {
    /// The program and its arguments. A relative program path with a `/` is relative to
    /// `dir`; a bare name is looked up in `PATH`.
    pub argv: Vec<String>,
    /// Its working directory (the task file's folder).
    pub dir: PathBuf,
}

type Svc = ipc_threadsafe::Service;

/// The learner's ports.
struct Ports {
    request: Publisher<Svc, [f64], PlantRequest>,
    reply: Subscriber<Svc, [f64], PlantReply>,
    notify: Notifier<Svc>,
    listen: Listener<Svc>,
    node: Node<Svc>,
}

/// The publish-subscribe service `leaf` of the run: `[f64]` payloads with the header `H`,
/// settings identical on both sides (the Python plant opens it with the same ones).
fn slice_service<H: core::fmt::Debug + ZeroCopySend>(
    node: &Node<Svc>,
    run: &RunId,
    leaf: &str,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, [f64], H>,
    PlantError,
> {
    node.service_builder(&service_name(run, leaf)?)
        .publish_subscribe::<[f64]>()
        .user_header::<H>()
        .enable_safe_overflow(true)
        .subscriber_max_buffer_size(8)
        .history_size(0)
        .max_publishers(4)
        .max_subscribers(4)
        .open_or_create()
        .map_err(|e| {
            PlantError(format!(
                "the {leaf} service of run {}: {e:?} (a plant of another protocol version?)",
                run.as_str()
            ))
        })
}

/// `what: <iceoryx2's error>` (its errors are reported, never matched on).
fn fail<E: core::fmt::Debug>(what: &str) -> impl FnOnce(E) -> PlantError + '_ {
    move |e| PlantError(format!("{what}: {e:?}"))
}

fn service_name(run: &RunId, leaf: &str) -> Result<ServiceName, PlantError> {
    ServiceName::new(&format!("mpo/{}/plant/{leaf}", run.as_str()))
        .map_err(|e| PlantError(format!("service name: {e:?}")))
}

impl Ports {
    fn open(run: &RunId, max_request_len: usize) -> Result<Self, PlantError> {
        iceoryx2::prelude::set_log_level_from_env_or(LogLevel::Error);
        let cfg = run.config().map_err(|x| PlantError(x.0))?;
        let node = NodeBuilder::new()
            .config(&cfg)
            .name(&NodeName::new("mpo-learner").map_err(fail("node name"))?)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Svc>()
            .map_err(fail("node"))?;
        let request = slice_service::<PlantRequest>(&node, run, "request")?
            .publisher_builder()
            .initial_max_slice_len(max_request_len.max(1))
            .create()
            .map_err(fail("request publisher"))?;
        let reply = slice_service::<PlantReply>(&node, run, "reply")?
            .subscriber_builder()
            .create()
            .map_err(fail("reply subscriber"))?;
        let event = |leaf: &str| {
            node.service_builder(&service_name(run, leaf)?)
                .event()
                .max_notifiers(4)
                .max_listeners(4)
                .open_or_create()
                .map_err(|x| PlantError(format!("the {leaf} event service: {x:?}")))
        };
        let notify = event("to-plant")?
            .notifier_builder()
            .create()
            .map_err(fail("notifier"))?;
        let listen = event("to-learner")?
            .listener_builder()
            .create()
            .map_err(fail("listener"))?;
        Ok(Self {
            request,
            reply,
            notify,
            listen,
            node,
        })
    }
}

/// The spawned plant program: its process and the last lines it wrote.
struct Spawned {
    child: Child,
    /// Its process group (its own: a Ctrl-C at the terminal reaches the learner, which ends
    /// the run cleanly, not the plant).
    pgid: i32,
    tail: Arc<Mutex<VecDeque<String>>>,
    readers: Vec<std::thread::JoinHandle<()>>,
}

/// Lines of the plant's output kept for error messages.
const TAIL_LINES: usize = 6;

impl Spawned {
    fn start(cmd: &PlantCommand, run: &RunId, label: &str) -> Result<Self, PlantError> {
        use std::os::unix::process::CommandExt;
        let Some(program) = cmd.argv.first() else {
            return Err(PlantError(format!("{label}: the plant command is empty")));
        };
        // Absolute paths: the program starts in `dir`, and where a relative program path is
        // resolved after the change of directory is platform-specific.
        let dir = std::path::absolute(&cmd.dir).unwrap_or_else(|_| cmd.dir.clone());
        let program = if program.contains('/') && Path::new(program).is_relative() {
            dir.join(program)
        } else {
            PathBuf::from(program)
        };
        let mut child = Command::new(&program)
            .args(&cmd.argv[1..])
            .current_dir(&dir)
            .env("MPO_PLANT_RUN", run.as_str())
            .env("MPO_PLANT_PARENT", std::process::id().to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .process_group(0)
            .spawn()
            .map_err(|e| {
                PlantError(format!(
                    "{label}: cannot start the plant program `{}` in {}: {e}",
                    cmd.argv.join(" "),
                    cmd.dir.display()
                ))
            })?;
        let pgid = child.id() as i32;
        let tail = Arc::new(Mutex::new(VecDeque::new()));
        let mut readers = Vec::new();
        let out = child
            .stdout
            .take()
            .map(|s| Box::new(s) as Box<dyn Read + Send>);
        let err = child
            .stderr
            .take()
            .map(|s| Box::new(s) as Box<dyn Read + Send>);
        for stream in [out, err].into_iter().flatten() {
            let tail = tail.clone();
            readers.push(std::thread::spawn(move || relay(stream, &tail)));
        }
        Ok(Self {
            child,
            pgid,
            tail,
            readers,
        })
    }

    /// `Some(why)` once the process has exited.
    fn exited(&mut self) -> Option<String> {
        let status = self.child.try_wait().ok()??;
        // Its output ends with it: wait for the readers, so the last lines are complete.
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        let tail = self.tail.lock().map(|t| t.clone()).unwrap_or_default();
        let last = tail
            .back()
            .map(|l| format!("; its last output: `{l}`"))
            .unwrap_or_default();
        Some(format!("the plant program exited ({status}){last}"))
    }

    /// Waits up to `grace` for the exit, then kills its process group.
    fn stop(&mut self, grace: Duration) {
        let t0 = monotonic_ns();
        while self.child.try_wait().ok().flatten().is_none() {
            if monotonic_ns() - t0 > grace.as_nanos() as u64 {
                // SAFETY: kill(2) on the process group this learner created.
                unsafe { libc::kill(-self.pgid, libc::SIGKILL) };
                let _ = self.child.wait();
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
    }
}

/// Copies the plant's output to stderr, each line prefixed `plant| ` (stdout too: the
/// learner's stdout is its summary), keeping the last few lines for error messages.
fn relay(stream: Box<dyn Read + Send>, tail: &Mutex<VecDeque<String>>) {
    for line in BufReader::new(stream).lines() {
        let Ok(line) = line else { break };
        eprintln!("plant| {line}");
        if let Ok(mut t) = tail.lock() {
            if t.len() == TAIL_LINES {
                t.pop_front();
            }
            t.push_back(line);
        }
    }
}

/// The learner's end of an external plant: one connection, any number of environment
/// instances (see the module documentation for the protocol).
pub struct ExternalPlant {
    ports: Option<Ports>,
    run: RunId,
    spawned: Option<Spawned>,
    opts: ExternalOptions,
    expected: Expected,
    info: PlantInfo,
    label: String,
    seq: u64,
    next_env: u64,
    /// The last reply's header and payload (copied out of shared memory; sized once).
    header: PlantReply,
    payload: Vec<f64>,
}

impl core::fmt::Debug for ExternalPlant {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ExternalPlant")
            .field("run", &self.run)
            .field("info", &self.info)
            .finish()
    }
}

impl ExternalPlant {
    /// Starts `cmd` (with the run id in `MPO_PLANT_RUN`) and connects to it. `label` names the
    /// plant in every error (e.g. the task file).
    pub fn start(
        cmd: &PlantCommand,
        expected: Expected,
        opts: ExternalOptions,
        label: &str,
    ) -> Result<Self, PlantError> {
        let run = RunId::new();
        let spawned = Spawned::start(cmd, &run, label)?;
        Self::connect(run, Some(spawned), expected, opts, label)
    }

    /// Connects to a plant program started by someone else with run id `run`.
    pub fn attach(
        run: RunId,
        expected: Expected,
        opts: ExternalOptions,
        label: &str,
    ) -> Result<Self, PlantError> {
        Self::connect(run, None, expected, opts, label)
    }

    fn connect(
        run: RunId,
        spawned: Option<Spawned>,
        expected: Expected,
        opts: ExternalOptions,
        label: &str,
    ) -> Result<Self, PlantError> {
        let label = format!("{label} (external plant, run id {})", run.as_str());
        let ports = match Ports::open(&run, 2 * expected.act) {
            Ok(p) => p,
            Err(e) => {
                // No connection: a started program has nobody to serve.
                if let Some(mut s) = spawned {
                    s.stop(Duration::ZERO);
                }
                run.remove_if_last();
                return Err(PlantError(format!("{label}: {}", e.0)));
            }
        };
        let mut p = Self {
            ports: Some(ports),
            run,
            spawned,
            opts,
            info: PlantInfo {
                name: String::new(),
                obs: 0,
                act: 0,
                episode_steps: 0,
                bounds: Vec::new(),
            },
            label,
            seq: 0,
            next_env: 0,
            header: PlantReply::default(),
            payload: Vec::with_capacity(expected.obs.max(2 * expected.act)),
            expected,
        };
        p.hello()?;
        Ok(p)
    }

    /// What the plant said about itself.
    pub fn info(&self) -> &PlantInfo {
        &self.info
    }

    /// The run id (the services' names and the files' prefix).
    pub fn run_id(&self) -> &RunId {
        &self.run
    }

    /// The process id of the plant program, when this learner started it.
    pub fn pid(&self) -> Option<u32> {
        self.spawned.as_ref().map(|s| s.child.id())
    }

    /// A new environment instance id (its first RESET must be fresh).
    pub fn new_env(&mut self) -> u64 {
        self.next_env += 1;
        self.next_env
    }

    fn ports(&self) -> &Ports {
        self.ports.as_ref().expect("ports live until drop")
    }

    fn err(&self, what: impl core::fmt::Display) -> PlantError {
        PlantError(format!("{}: {what}", self.label))
    }

    fn hello(&mut self) -> Result<(), PlantError> {
        let e = self.expected.clone();
        let deadline = monotonic_ns() + self.opts.connect_timeout.as_nanos() as u64;
        let mut bounds = Vec::with_capacity(2 * e.act);
        bounds.extend(e.bounds.iter().map(|b| b.0));
        bounds.extend(e.bounds.iter().map(|b| b.1));
        loop {
            self.seq += 1;
            let seq = self.seq;
            self.send(KIND_HELLO, 0, 0, 0, &bounds, |h| {
                h.obs_len = e.obs as u32;
                h.act_len = e.act as u32;
                h.episode_steps = e.episode_steps.min(u32::MAX as usize) as u32;
                h.version = PROTOCOL_VERSION;
                set_text(&mut h.task, &e.task);
            })?;
            // Resent every 200 ms: the plant may subscribe after the first one went out.
            let resend = (monotonic_ns() + 200_000_000).min(deadline);
            match self.await_reply(seq, KIND_HELLO, resend) {
                Ok(()) => break,
                Err(Wait::Timeout) if monotonic_ns() < deadline => continue,
                Err(Wait::Timeout) => {
                    return Err(self.err(format!(
                        "no plant answered within {:.0} s ([external] connect_timeout){}",
                        self.opts.connect_timeout.as_secs_f64(),
                        match &self.spawned {
                            Some(_) => " although its program is running: does it serve this run id (MPO_PLANT_RUN)?",
                            None => ": is the plant program running with this run id?",
                        }
                    )));
                }
                Err(Wait::Failed(m)) => return Err(m),
            }
        }
        self.check_hello()
    }

    /// The plant's HELLO reply against the task file: sizes, episode length, bounds.
    fn check_hello(&mut self) -> Result<(), PlantError> {
        let h = self.header;
        let act = h.act_len as usize;
        let mut bounds = Vec::with_capacity(act);
        if self.payload.len() == 2 * act {
            for i in 0..act {
                bounds.push((self.payload[i], self.payload[act + i]));
            }
        }
        self.info = PlantInfo {
            name: text_of(&h.message),
            obs: h.obs_len as usize,
            act,
            episode_steps: h.episode_steps as usize,
            bounds,
        };
        let (i, e) = (&self.info, &self.expected);
        if h.version != PROTOCOL_VERSION {
            return Err(self.err(format!(
                "the plant `{}` speaks protocol version {}, this learner {PROTOCOL_VERSION}",
                i.name, h.version
            )));
        }
        if (i.obs, i.act) != (e.obs, e.act) {
            return Err(self.err(format!(
                "the plant `{}` has observation size {} and action size {}, the task file says obs = {}, act = {} ([external])",
                i.name, i.obs, i.act, e.obs, e.act
            )));
        }
        if i.episode_steps != 0 && i.episode_steps != e.episode_steps {
            return Err(self.err(format!(
                "the plant `{}` ends its episodes after {} steps, the task file says episode_steps = {}",
                i.name, i.episode_steps, e.episode_steps
            )));
        }
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * b.abs().max(1.0);
        for (k, (&(pl, ph), &(tl, th))) in i.bounds.iter().zip(&e.bounds).enumerate() {
            let known = pl.is_finite() && ph.is_finite();
            if known && !(close(pl, tl) && close(ph, th)) {
                return Err(self.err(format!(
                    "the plant `{}` takes action {k} in [{pl}, {ph}], the task file says [{tl}, {th}] ([external] action_low, action_high)",
                    i.name
                )));
            }
        }
        Ok(())
    }

    /// Starts an episode of instance `env` and writes the first observation into `obs`.
    /// `fresh`: the instance's first reset, seeded with `seed`.
    pub fn reset(
        &mut self,
        env: u64,
        seed: u64,
        fresh: bool,
        obs: &mut [f64],
    ) -> Result<(), PlantError> {
        let flags = if fresh { RESET_FRESH } else { 0 };
        self.request(KIND_RESET, env, seed, flags, &[])?;
        self.take_observation(obs, KIND_RESET)
    }

    /// One step of instance `env` with `action` (in the plant's units); writes the next
    /// observation into `obs`.
    pub fn step(
        &mut self,
        env: u64,
        action: &[f64],
        obs: &mut [f64],
    ) -> Result<PlantStep, PlantError> {
        if action.len() != self.expected.act {
            return Err(self.err(format!(
                "an action of {} values for a plant of {}",
                action.len(),
                self.expected.act
            )));
        }
        self.request(KIND_STEP, env, 0, 0, action)?;
        self.take_observation(obs, KIND_STEP)?;
        let h = &self.header;
        if !h.reward.is_finite() || !(h.discount == 0.0 || h.discount == 1.0) {
            return Err(self.err(format!(
                "the plant answered STEP with reward {} and discount {} (a finite reward and a discount of 0 or 1 are needed)",
                h.reward, h.discount
            )));
        }
        Ok(PlantStep {
            reward: h.reward,
            discount: h.discount,
            last: h.last != 0,
        })
    }

    /// Tells the plant that instance `env` is no longer used (no reply; never fails: a plant
    /// that is gone needs no telling).
    pub fn close(&mut self, env: u64) {
        self.seq += 1;
        let _ = self.send(KIND_CLOSE, env, 0, 0, &[], |_| {});
    }

    fn take_observation(&mut self, obs: &mut [f64], kind: u32) -> Result<(), PlantError> {
        let what = kind_name(kind);
        if self.payload.len() != obs.len() {
            return Err(self.err(format!(
                "the plant answered {what} with an observation of {} values, the task file says obs = {}",
                self.payload.len(),
                obs.len()
            )));
        }
        if let Some((i, v)) = self
            .payload
            .iter()
            .enumerate()
            .find(|(_, v)| !v.is_finite())
        {
            return Err(self.err(format!(
                "the plant answered {what} with observation element {i} = {v}"
            )));
        }
        obs.copy_from_slice(&self.payload);
        Ok(())
    }

    /// Sends one request and waits for its reply (into `self.header`, `self.payload`).
    fn request(
        &mut self,
        kind: u32,
        env: u64,
        seed: u64,
        flags: u32,
        payload: &[f64],
    ) -> Result<(), PlantError> {
        self.seq += 1;
        let seq = self.seq;
        self.send(kind, env, seed, flags, payload, |_| {})?;
        let deadline = monotonic_ns() + self.opts.timeout.as_nanos() as u64;
        let what = kind_name(kind);
        match self.await_reply(seq, kind, deadline) {
            Ok(()) => Ok(()),
            Err(Wait::Failed(e)) => Err(e),
            Err(Wait::Timeout) => Err(self.err(format!(
                "no answer to {what} within {:.1} s ([external] timeout){}",
                self.opts.timeout.as_secs_f64(),
                match &self.spawned {
                    Some(_) =>
                        "; its program is still running: it hangs, or needs a longer timeout",
                    None => ": the plant program died, hangs, or needs a longer timeout",
                }
            ))),
        }
    }

    fn send(
        &mut self,
        kind: u32,
        env: u64,
        seed: u64,
        flags: u32,
        payload: &[f64],
        fill: impl FnOnce(&mut PlantRequest),
    ) -> Result<(), PlantError> {
        let seq = self.seq;
        let ports = self.ports();
        let mut sample = ports
            .request
            .loan_slice_uninit(payload.len())
            .map_err(|e| self.err(format!("cannot loan a request: {e:?}")))?;
        let h = sample.user_header_mut();
        *h = PlantRequest::default();
        h.seq = seq;
        h.env = env;
        h.seed = seed;
        h.kind = kind;
        h.flags = flags;
        fill(h);
        let sample = sample.write_from_slice(payload);
        sample
            .send()
            .map_err(|e| self.err(format!("cannot send a request: {e:?}")))?;
        // Nobody listening (the plant not started yet, or dead) is not an error here: the
        // deadline reports it.
        let _ = ports.notify.notify();
        Ok(())
    }

    /// Waits until the reply to `seq` arrives (copied into `self.header` and `self.payload`),
    /// the plant reports an error, its process exits, or `deadline_ns` passes.
    fn await_reply(&mut self, seq: u64, kind: u32, deadline_ns: u64) -> Result<(), Wait> {
        let what = kind_name(kind);
        loop {
            loop {
                let sample = match self.ports().reply.receive() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        return Err(Wait::Failed(self.err(format!("cannot receive: {e:?}"))));
                    }
                };
                let h = *sample.user_header();
                if h.seq != seq {
                    // A late answer to an earlier HELLO: dropped.
                    continue;
                }
                let data = sample.payload();
                if data.len() > self.payload.capacity() {
                    return Err(Wait::Failed(self.err(format!(
                        "the plant answered {what} with {} values, more than the task file's sizes allow (obs = {}, act = {})",
                        data.len(),
                        self.expected.obs,
                        self.expected.act
                    ))));
                }
                self.payload.clear();
                self.payload.extend_from_slice(data);
                self.header = h;
                drop(sample);
                if h.status != STATUS_OK {
                    return Err(Wait::Failed(
                        self.err(format!("the plant failed {what}: {}", text_of(&h.message))),
                    ));
                }
                if h.kind != kind {
                    return Err(Wait::Failed(self.err(format!(
                        "the plant answered {what} with a reply of kind {}",
                        h.kind
                    ))));
                }
                return Ok(());
            }
            if let Some(why) = self.spawned.as_mut().and_then(Spawned::exited) {
                return Err(Wait::Failed(
                    self.err(format!("{why} (waiting for {what})")),
                ));
            }
            let left = remaining(deadline_ns);
            if left.is_zero() {
                return Err(Wait::Timeout);
            }
            wait_for_event(&self.ports().listen, left.min(SLICE));
        }
    }
}

enum Wait {
    Timeout,
    Failed(PlantError),
}

impl Drop for ExternalPlant {
    /// Says BYE, lets a spawned program exit (killing it after 5 s), releases the ports and
    /// removes the run's files once nobody else holds them.
    fn drop(&mut self) {
        if self.ports.is_some() {
            self.seq += 1;
            let _ = self.send(KIND_BYE, 0, 0, 0, &[], |_| {});
        }
        if let Some(s) = self.spawned.as_mut() {
            s.stop(Duration::from_secs(5));
        }
        if let Some(p) = &self.ports {
            let _ = p.node.try_cleanup_dead_nodes();
        }
        self.ports = None;
        self.run.remove_if_last();
    }
}
