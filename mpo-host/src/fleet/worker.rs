//! A plant of a fleet (`mpo plant-worker`, started by `mpo train --plants N`): it joins the
//! run, steps its own environment with the newest policy it has, and sends its transitions
//! to the learner in blocks of K steps. A user's robot program could speak the same frames
//! (`mpo_link::fleet::frames`); this one is compiled for a row's policy type.
//!
//! It acts exactly as the in-process trainer does (the same [`Explorer`] code and draws, the
//! same policy sample and log-density, the same step and reward through
//! `crate::collection::env_step`), which is why plant 0 of a one-plant deterministic fleet with
//! K = 1 produces the in-process run's transitions bit for bit.
//!
//! The step path (act, step, encode the record) allocates nothing: the block's buffers are
//! sized at the start and the policy is assembled into a staging copy allocated once.

use std::time::{Duration, Instant};

use mpo_core::explore::{Explorer, NoiseKind};
use mpo_core::network::PolicyNet;
use mpo_core::params::Params;
use mpo_link::RunId;
use mpo_link::controller::Assembler;
use mpo_link::fleet::PlantPort;
use mpo_link::fleet::frames::{
    self, ANNOUNCE, AT_BOUNDARY, BLOCK, BYE, BlockHead, DROPPED, FIRST, GO, Go, HELLO, Header,
    Hello, LAST, PARAMS, REFUSE, STOP, Text, WELCOME, Welcome,
};
use mpo_link::fleet::ipc::IpcPlant;
use mpo_link::messages::ParamChunk;
use sim_bridge::{Environment, TaskDef};

use crate::sizes::Sizes;

/// What a plant process is started with.
pub struct WorkerInit<'a> {
    /// The run to join.
    pub run: &'a RunId,
    /// Its index in the fleet.
    pub index: usize,
    /// The task it steps.
    pub task: &'a TaskDef,
    /// The row's network variant.
    pub net: &'a str,
    /// The row's sizes.
    pub sizes: Sizes,
    /// Steps per block expected (sizes the first shared-memory segment).
    pub block_hint: usize,
    /// Started by the learner (it exits when its parent does).
    pub spawned: bool,
    /// Steps per second of wall clock (`None`: unpaced).
    pub rate: Option<f64>,
    /// A learner on another host, over zenoh (`--fleet-connect`); `None`: this host's, over
    /// iceoryx2.
    pub remote: Option<&'a mpo_link::fleet::Remote>,
}

/// How long a plant started by hand waits for the learner's answer to its HELLO, or for a
/// round.
const PATIENCE: Duration = Duration::from_secs(120);

/// How often a plant repeats its HELLO until the learner answers.
const HELLO_AGAIN: Duration = Duration::from_millis(500);

/// What the learner says between blocks.
struct Inbox<P: Params> {
    asm: Assembler<P>,
    policy: Box<P>,
    /// The policy version in `policy` (0: none yet).
    version: u64,
    /// The newest GO.
    go: Option<Go>,
    /// When the newest GO arrived, and the plant's steps then.
    go_steps: u64,
    welcome: Option<Result<Welcome, String>>,
    stop: Option<String>,
    /// Why this plant is to join again: the learner dropped it, or another incarnation of
    /// the run's learner (a resumed one) speaks.
    rejoin: Option<String>,
    /// The incarnation of the learner that welcomed this plant (0: none yet).
    learner: u64,
    heard: Instant,
    /// The newest version's latency: from the learner's send of its last block to this
    /// plant having it assembled and in use (ns, `CLOCK_MONOTONIC` of both processes).
    latency_ns: u64,
}

impl<P: Params> Inbox<P> {
    /// Nothing heard yet: no policy, no round, no learner.
    fn new() -> Self
    where
        P: bytemuck::Zeroable,
    {
        Self {
            asm: Assembler::new(bytemuck::zeroed_box()),
            policy: bytemuck::zeroed_box(),
            version: 0,
            go: None,
            go_steps: 0,
            welcome: None,
            stop: None,
            rejoin: None,
            learner: 0,
            heard: Instant::now(),
            latency_ns: 0,
        }
    }

    fn frame(&mut self, f: &[u8], tag: u64, index: usize, incarnation: u64, steps: u64) {
        let Ok((h, body)) = frames::parse(f, tag) else {
            return;
        };
        if h.plant != u32::MAX && h.plant as usize != index {
            return;
        }
        self.heard = Instant::now();
        if self.learner != 0
            && h.incarnation != self.learner
            && matches!(h.kind, GO | PARAMS | ANNOUNCE)
        {
            // The learner this plant worked for is gone; its resumed self waits for plants.
            self.rejoin = Some("another incarnation of the run's learner speaks".into());
            return;
        }
        match h.kind {
            PARAMS => {
                if let Ok(chunk) = frames::read::<ParamChunk>(body)
                    && let Ok(true) = self.asm.add(&chunk, self.version)
                {
                    self.asm.swap_into(&mut self.policy);
                    self.version = self.asm.generation();
                    self.latency_ns = mpo_link::service::monotonic_ns().saturating_sub(h.t_send_ns);
                }
            }
            GO => {
                if let Ok(go) = frames::read::<Go>(body) {
                    self.go = Some(go);
                    self.go_steps = steps;
                }
            }
            WELCOME => {
                if let Ok(w) = frames::read::<Welcome>(body)
                    && w.plant_incarnation == incarnation
                {
                    self.welcome = Some(Ok(w));
                    self.learner = h.incarnation;
                }
            }
            REFUSE => {
                if let Ok(t) = frames::read::<Text>(body)
                    && t.plant_incarnation == incarnation
                {
                    self.welcome = Some(Err(frames::text_of(&t.message)));
                }
            }
            STOP => self.stop = Some("the learner stopped the run".into()),
            DROPPED => {
                if let Ok(t) = frames::read::<Text>(body)
                    && (t.plant_incarnation == incarnation || t.plant_incarnation == 0)
                {
                    let why = frames::text_of(&t.message);
                    self.rejoin = Some(format!("the learner dropped this plant: {why}"));
                }
            }
            _ => {}
        }
    }
}

/// A plant's environment, its exploration state and the block being filled: the step path
/// (public for the allocation test, `mpo-host/tests/no_alloc.rs`).
pub struct Stepper<const OBS: usize, const ACT: usize> {
    env: Box<dyn Environment>,
    explore: Box<Explorer<ACT>>,
    obs64: [f64; OBS],
    next64: [f64; OBS],
    act64: [f64; ACT],
    in_episode: bool,
    /// Resets of the environment so far (those replayed at the start included).
    resets: u64,
    std_floor: f32,
    action_penalty: f32,
    /// The block's records (little-endian words).
    records: Vec<u8>,
    count: u32,
    /// Pacing: the period and the time of the next step.
    period: Option<Duration>,
    next_at: Instant,
}

impl<const OBS: usize, const ACT: usize> Stepper<OBS, ACT> {
    /// A plant of `task` as `w` configures it (environment seed and the resets to replay,
    /// collector stream, noise, std floor, action penalty, K), unpaced at `rate` `None`.
    pub fn new(task: &TaskDef, w: &Welcome, rate: Option<f64>) -> Result<Self, String> {
        let k = w.block.max(1) as usize;
        let mut env = crate::plant::make(task, w.env_seed).map_err(|e| e.to_string())?;
        // The environment's random state advances once per reset: replaying the resets of
        // the plant's previous processes continues its stream (no initial state repeats).
        let mut obs64 = [0.0; OBS];
        for _ in 0..w.episodes {
            env.reset(&mut obs64);
        }
        let mut explore: Box<Explorer<ACT>> = bytemuck::zeroed_box();
        explore.init(
            w.collector,
            NoiseKind {
                corr: w.noise_corr,
                pink: w.noise_pink != 0,
            },
        );
        Ok(Self {
            env,
            explore,
            obs64,
            next64: [0.0; OBS],
            act64: [0.0; ACT],
            in_episode: false,
            resets: w.episodes,
            std_floor: w.std_floor,
            action_penalty: w.action_penalty,
            records: Vec::with_capacity(4 * k * frames::record_words(OBS, ACT)),
            count: 0,
            period: rate.map(|r| Duration::from_secs_f64(1.0 / r)),
            next_at: Instant::now(),
        })
    }

    /// Records in the block being filled.
    pub fn count(&self) -> u32 {
        self.count
    }

    /// Empties the block (after it was sent).
    pub fn clear_block(&mut self) {
        self.records.clear();
        self.count = 0;
    }

    /// One step with `policy` (uniform while `warm`), its record appended to the block.
    pub fn step<const TRI: usize, P: PolicyNet<OBS, ACT, TRI>>(
        &mut self,
        policy: &P,
        warm: bool,
    ) -> Result<(), String> {
        if let Some(p) = self.period {
            // A robot's clock: an absolute schedule, so lateness does not accumulate.
            let now = Instant::now();
            if self.next_at > now {
                std::thread::sleep(self.next_at - now);
            }
            self.next_at = self.next_at.max(now.checked_sub(p).unwrap_or(now)) + p;
        }
        let mut flags = 0u32;
        if !self.in_episode {
            self.env.reset(&mut self.obs64);
            self.explore.begin_episode();
            self.in_episode = true;
            self.resets += 1;
            flags |= FIRST;
        }
        let mut obs = [0f32; OBS];
        for (o, x) in obs.iter_mut().zip(&self.obs64) {
            *o = *x as f32;
        }
        let mut act = [0f32; ACT];
        let log_prob = if warm {
            self.explore.uniform_action(&mut act)
        } else {
            let mut z = [0f32; ACT];
            self.explore.draw_noise(&mut z);
            let pi = policy.distribution(&obs, self.std_floor);
            pi.transform(&z, &mut act);
            pi.log_prob(&act)
        };
        let (t, last) = crate::collection::env_step(
            self.env.as_mut(),
            &obs,
            &act,
            log_prob,
            self.action_penalty,
            &mut self.act64,
            &mut self.next64,
        )
        .map_err(|e| e.to_string())?;
        core::mem::swap(&mut self.obs64, &mut self.next64);
        if last {
            self.in_episode = false;
            flags |= LAST;
        }
        let r = &mut self.records;
        r.extend_from_slice(&flags.to_le_bytes());
        let words = t
            .obs
            .iter()
            .chain(&t.action)
            .chain([&t.reward])
            .chain(&t.next_obs);
        for x in words.chain([&t.discount, &t.behaviour_log_prob]) {
            r.extend_from_slice(&x.to_le_bytes());
        }
        self.count += 1;
        Ok(())
    }
}

/// The plant's end of the transport and its frame buffer.
struct Wire {
    port: Box<dyn PlantPort>,
    tag: u64,
    index: usize,
    incarnation: u64,
    buf: Vec<u8>,
}

impl Wire {
    fn send<T: bytemuck::Pod>(
        &mut self,
        kind: u32,
        payload: &T,
        tail: &[u8],
    ) -> Result<(), String> {
        let head = Header {
            kind,
            plant: self.index as u32,
            run: self.tag,
            incarnation: self.incarnation,
            ..Default::default()
        };
        frames::write(&mut self.buf, head, payload, tail);
        self.port.send_up(&self.buf).map_err(|e| e.to_string())
    }

    fn drain<P: Params>(&mut self, inbox: &mut Inbox<P>, steps: u64) -> Result<(), String> {
        let (tag, index, inc) = (self.tag, self.index, self.incarnation);
        self.port
            .recv_down(&mut |f| inbox.frame(f, tag, index, inc, steps))
            .map_err(|e| e.to_string())?;
        Ok(())
    }
}

/// True when the learner that started this plant has exited (the plant was re-parented).
fn orphaned(spawned: bool, parent: i32) -> bool {
    // SAFETY: getppid has no preconditions.
    spawned && unsafe { libc::getppid() } != parent
}

/// True when the learner is gone: a plant the learner started was re-parented (its
/// learner exited); one started by hand heard nothing for [`PATIENCE`]. (A started plant
/// never times out while its learner lives: evaluations or a render may keep it busy.)
fn gone<P: Params>(inbox: &Inbox<P>, spawned: bool, parent: i32) -> bool {
    match spawned {
        true => orphaned(spawned, parent),
        false => inbox.heard.elapsed() > PATIENCE,
    }
}

/// How a plant's work for one learner ended.
enum Ended {
    /// The learner stopped the run (or, for a plant it started, dropped it).
    Stop,
    /// Join again, for this reason.
    Rejoin(String),
}

/// Runs plant `init.index` of the run with the policy type `P` until the learner stops it;
/// returns the steps taken. A refusal or a failed environment is an error (after a BYE).
///
/// A plant started by hand joins again when the learner drops it or when another
/// incarnation of the run's learner (one resumed from its checkpoint) announces itself; the
/// learner's WELCOME then continues its streams where its last inserted block left them. A
/// plant the learner started exits instead (the learner restarts it).
pub fn run<const OBS: usize, const ACT: usize, const TRI: usize, P>(
    init: &WorkerInit<'_>,
) -> Result<u64, String>
where
    P: PolicyNet<OBS, ACT, TRI> + Params,
{
    // SAFETY: getppid has no preconditions.
    let parent = unsafe { libc::getppid() };
    let port: Box<dyn PlantPort> = match init.remote {
        None => Box::new(
            IpcPlant::open(init.run, OBS, ACT, init.block_hint.max(1))
                .map_err(|e| e.to_string())?,
        ),
        Some(r) => super::remote_plant(init.run, r).map_err(|e| e.to_string())?,
    };
    let mut wire = Wire {
        port,
        tag: frames::run_tag(init.run.as_str()),
        index: init.index,
        incarnation: 0,
        buf: Vec::new(),
    };
    let mut steps = 0u64;
    let mut learner = 0u64;
    loop {
        let mut inbox = Inbox::<P>::new();
        // A fresh incarnation per join: blocks of the previous one still in flight are
        // told apart and ignored.
        wire.incarnation = super::learner::random_u64();
        let w = join(init, &mut wire, &mut inbox, learner, parent)?;
        learner = inbox.learner;
        let k = w.block.max(1) as usize;
        let mut s = Stepper::<OBS, ACT>::new(init.task, &w, init.rate)?;
        wire.buf = Vec::with_capacity(frames::block_len(OBS, ACT, k));
        let r = match w.mode {
            0 => {
                rounds::<OBS, ACT, TRI, P>(&mut wire, &mut inbox, &mut s, &w, init.spawned, parent)
            }
            _ => free::<OBS, ACT, TRI, P>(&mut wire, &mut inbox, &mut s, &w, init.spawned, parent),
        };
        match r {
            Ok((n, Ended::Stop)) => return Ok(steps + n),
            Ok((n, Ended::Rejoin(_))) if init.spawned => return Ok(steps + n),
            Ok((n, Ended::Rejoin(why))) => {
                steps += n;
                eprintln!("plant {}: {why}; joining again", init.index);
            }
            Err(why) => {
                let mut t: Text = bytemuck::Zeroable::zeroed();
                frames::put_text(&mut t.message, &why);
                let _ = wire.send(BYE, &t, &[]);
                return Err(why);
            }
        }
    }
}

/// Says HELLO (again every [`HELLO_AGAIN`]) until the learner answers; `learner`: the
/// incarnation this plant worked for before (0: none).
fn join<P: Params>(
    init: &WorkerInit<'_>,
    wire: &mut Wire,
    inbox: &mut Inbox<P>,
    learner: u64,
    parent: i32,
) -> Result<Welcome, String> {
    let hello = Hello {
        id: super::identity(init.task, init.net, &init.sizes, inbox.policy.len()),
        learner,
        pid: std::process::id(),
        spawned: init.spawned as u32,
    };
    wire.send(HELLO, &hello, &[])?;
    let mut said = Instant::now();
    loop {
        wire.drain(inbox, 0)?;
        match inbox.welcome.take() {
            Some(Ok(w)) => return Ok(w),
            Some(Err(why)) => return Err(format!("the learner refused this plant: {why}")),
            None => {}
        }
        if inbox.stop.is_some() {
            return Err("the learner stopped the run before this plant joined".into());
        }
        if gone(inbox, init.spawned, parent) {
            return Err(format!("no learner of run {} answered", init.run.as_str()));
        }
        if said.elapsed() >= HELLO_AGAIN {
            // Over zenoh a frame sent before the other side's subscription reached this one
            // goes nowhere: say it again (the learner answers a repeated HELLO again).
            wire.send(HELLO, &hello, &[])?;
            said = Instant::now();
        }
        wire.port.wait(Duration::from_millis(50));
    }
}

/// Sends the filled block (`round`: the round, or the plant's block counter).
fn send_block<const OBS: usize, const ACT: usize>(
    wire: &mut Wire,
    s: &mut Stepper<OBS, ACT>,
    round: u64,
    (version, latency_ns): (u64, u64),
) -> Result<(), String> {
    let head = BlockHead {
        round,
        version,
        episodes: s.resets,
        collector: s.explore.collector,
        param_latency_ns: latency_ns,
        count: s.count,
        obs: OBS as u32,
        act: ACT as u32,
        flags: if s.in_episode { 0 } else { AT_BOUNDARY },
    };
    let r = wire.send(BLOCK, &head, &s.records);
    s.clear_block();
    r
}

/// Whether the plant's work for this learner is over: stopped, or to join again.
fn ended<P: Params>(inbox: &mut Inbox<P>) -> Option<Ended> {
    if inbox.stop.is_some() {
        return Some(Ended::Stop);
    }
    inbox.rejoin.take().map(Ended::Rejoin)
}

/// The deterministic schedule: wait for each round's GO and its policy version, take K
/// steps (global step `env_steps + rank K + j`, uniform actions below the warm-up), send them.
fn rounds<const OBS: usize, const ACT: usize, const TRI: usize, P>(
    wire: &mut Wire,
    inbox: &mut Inbox<P>,
    s: &mut Stepper<OBS, ACT>,
    w: &Welcome,
    spawned: bool,
    parent: i32,
) -> Result<(u64, Ended), String>
where
    P: PolicyNet<OBS, ACT, TRI> + Params,
{
    let (k, me) = (w.block as u64, wire.index);
    let mut steps = 0u64;
    let mut next_round = 0u64;
    loop {
        wire.drain(inbox, steps)?;
        if let Some(e) = ended(inbox) {
            return Ok((steps, e));
        }
        let ready = inbox
            .go
            .filter(|g| g.round >= next_round && g.version == inbox.version);
        let Some(go) = ready else {
            if gone(inbox, spawned, parent) {
                return Err("the learner went silent".into());
            }
            wire.port.wait(Duration::from_millis(50));
            continue;
        };
        next_round = go.round + 1;
        if go.members[me / 64] & (1 << (me % 64)) == 0 {
            continue;
        }
        let rank: u64 = (0..me)
            .filter(|i| go.members[i / 64] & (1 << (i % 64)) != 0)
            .count() as u64;
        let base = go.env_steps + rank * k;
        for j in 0..k {
            s.step::<TRI, P>(&inbox.policy, base + j < w.warmup_steps)?;
        }
        steps += k;
        send_block(wire, s, go.round, (inbox.version, inbox.latency_ns))?;
    }
}

/// The free schedule: never wait; K steps, send, take whatever parameters arrived, again.
/// The warm-up ends by the learner's step count at its newest GO plus this plant's steps
/// since, times the plants (an estimate: the plants' speeds differ).
fn free<const OBS: usize, const ACT: usize, const TRI: usize, P>(
    wire: &mut Wire,
    inbox: &mut Inbox<P>,
    s: &mut Stepper<OBS, ACT>,
    w: &Welcome,
    spawned: bool,
    parent: i32,
) -> Result<(u64, Ended), String>
where
    P: PolicyNet<OBS, ACT, TRI> + Params,
{
    let k = w.block as u64;
    let (mut steps, mut block) = (0u64, 0u64);
    while inbox.version == 0 || inbox.go.is_none() {
        wire.drain(inbox, steps)?;
        if let Some(e) = ended(inbox) {
            return Ok((steps, e));
        }
        if gone(inbox, spawned, parent) {
            return Err("the learner went silent".into());
        }
        wire.port.wait(Duration::from_millis(50));
    }
    loop {
        let go = inbox.go.expect("waited for");
        let plants = go
            .members
            .iter()
            .map(|m| m.count_ones() as u64)
            .sum::<u64>();
        for _ in 0..k {
            let learner_steps = go.env_steps + (steps - inbox.go_steps) * plants.max(1);
            s.step::<TRI, P>(&inbox.policy, learner_steps < w.warmup_steps)?;
            steps += 1;
        }
        send_block(wire, s, block, (inbox.version, inbox.latency_ns))?;
        block += 1;
        wire.drain(inbox, steps)?;
        if let Some(e) = ended(inbox) {
            return Ok((steps, e));
        }
        if orphaned(spawned, parent) {
            return Err("the learner exited".into());
        }
    }
}
