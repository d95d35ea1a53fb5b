//! The learner's end of a fleet, whatever the sizes: plant processes, admission, the frames
//! sent down (parameters, rounds, stop), the blocks received up, and faults. The trainer
//! (`crate::trainer`) drives it: it sends the policy when it changed, asks for a round (or
//! what arrived), and inserts the blocks [`Fleet::take_inbox`] hands it.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use mpo_core::params::Params;
use mpo_link::LinkError;
use mpo_link::RunId;
use mpo_link::fleet::LearnerPort;
use mpo_link::fleet::frames::{
    self, ANNOUNCE, AT_BOUNDARY, BLOCK, BYE, BlockHead, DROPPED, GO, Go, HELLO, Header, Hello,
    Identity, PARAMS, REFUSE, STOP, Text, WELCOME, Welcome,
};
use mpo_link::fleet::ipc::IpcLearner;
use mpo_link::messages::{CHECKSUM_SEED, CHUNK, MAX_BLOCKS, ParamChunk, checksum};

use super::{FleetError, FleetOptions, FleetReport, FleetSchedule, mismatch};
use crate::checkpoint::{FleetRecord, PlantRecord};

/// One plant of the fleet, as the learner sees it.
pub struct Member {
    /// Its index (its place in a round's order).
    pub index: usize,
    /// Its process, when this learner started it.
    child: Option<Child>,
    /// Its process id (from its HELLO).
    pid: u32,
    /// Its incarnation (from its HELLO); 0 until it joined.
    incarnation: u64,
    /// Taking part (joined, not dropped).
    pub live: bool,
    /// The replay's id of its current episode.
    pub episode: u64,
    /// Between episodes after its last block.
    pub at_boundary: bool,
    /// Its block counter: the next block expected (free: gaps are lost blocks).
    next_block: u64,
    /// The newest policy version it reported acting with (its latency is counted once).
    seen_version: u64,
    /// When the learner last heard from it.
    heard: Instant,
    /// Its collector stream after its last block (a (re)joining process starts from it).
    collector: [u8; 32],
    /// Resets of its environment up to its last block (a (re)joining process replays them).
    resets: u64,
    /// Times it joined.
    joins: u64,
    /// The WELCOME it was sent last (a repeated HELLO is answered with it again).
    welcome: Welcome,
    /// In the current round (it was live at the round's GO).
    in_round: bool,
    /// Times this learner restarted its process.
    restarts: u32,
    /// Restarted and not joined yet: since when.
    restarting: Option<Instant>,
}

/// The learner's end of a fleet.
pub struct Fleet {
    port: Box<dyn LearnerPort>,
    run: RunId,
    tag: u64,
    incarnation: u64,
    opts: FleetOptions,
    identity: Identity,
    welcome: Welcome,
    seed: u32,
    /// The plants, by index.
    pub members: Vec<Member>,
    version: u64,
    /// Environment steps at the last parameter send.
    sent_at: u64,
    round: u64,
    down: Vec<u8>,
    chunk: Box<ParamChunk>,
    /// Received blocks not yet inserted: (member, frame).
    inbox: Vec<(usize, Vec<u8>)>,
    spare: Vec<Vec<u8>>,
    report: FleetReport,
    lag_sum: u64,
    /// Parameter latencies reported (one per plant and version): count, sum, largest (ns).
    latency: (u64, u64, u64),
    events: Vec<String>,
    /// The first refusal while the fleet is starting (it fails the start).
    refused: Option<FleetError>,
    /// The task flags plant processes are started with (for restarts).
    task_args: Vec<String>,
    /// A plant joined a started run: send the policy again (it has none).
    resend: bool,
}

impl Fleet {
    /// Opens the learner's side of the run id `opts.run` (a fresh one when `None`) for
    /// plants of `identity`; `welcome` is the template of every plant's WELCOME (its
    /// per-plant fields are filled at admission). `resumed`: the fleet's record in the
    /// checkpoint resumed from, so each plant continues its streams where its last inserted
    /// block left them (plants beyond the record start afresh).
    pub fn open(
        mut opts: FleetOptions,
        identity: Identity,
        welcome: Welcome,
        seed: u32,
        resumed: Option<&FleetRecord>,
    ) -> Result<Self, FleetError> {
        if let Some(r) = opts.rate {
            // A paced plant needs K periods for a block: that is not silence.
            opts.timeout += Duration::from_secs_f64(opts.sync_every as f64 / r);
        }
        let run = opts.run.clone().unwrap_or_default();
        let port: Box<dyn LearnerPort> = match &opts.remote {
            None => Box::new(IpcLearner::open(&run)?),
            Some(r) => super::remote_learner(&run, &r.listen, opts.plants)?,
        };
        let report = FleetReport {
            plants: opts.plants,
            schedule: match opts.schedule {
                FleetSchedule::Deterministic => "deterministic".into(),
                FleetSchedule::Free => "free".into(),
            },
            sync_every: opts.sync_every,
            ..Default::default()
        };
        let record = |i: usize| -> Result<([u8; 32], u64), FleetError> {
            match resumed.and_then(|r| r.plants.get(i)) {
                Some(p) => crate::checkpoint::unhex32(&p.collector)
                    .map(|c| (c, p.resets))
                    .ok_or_else(|| {
                        LinkError(format!("the checkpoint's plant {i}: bad collector")).into()
                    }),
                None => Ok((super::collector_of(seed, i), 0)),
            }
        };
        let members = (0..opts.plants)
            .map(|index| {
                let (collector, resets) = record(index)?;
                Ok(Member {
                    index,
                    child: None,
                    pid: 0,
                    incarnation: 0,
                    live: false,
                    episode: 0,
                    at_boundary: true,
                    next_block: 0,
                    seen_version: 0,
                    heard: Instant::now(),
                    collector,
                    resets,
                    joins: 0,
                    welcome: bytemuck::Zeroable::zeroed(),
                    in_round: false,
                    restarts: 0,
                    restarting: None,
                })
            })
            .collect::<Result<_, FleetError>>()?;
        Ok(Self {
            port,
            tag: frames::run_tag(run.as_str()),
            run,
            incarnation: random_u64(),
            opts,
            identity,
            welcome,
            seed,
            members,
            version: 0,
            sent_at: 0,
            round: 0,
            down: Vec::with_capacity(frames::MAX_DOWN),
            chunk: bytemuck::zeroed_box(),
            inbox: Vec::new(),
            spare: Vec::new(),
            report,
            lag_sum: 0,
            latency: (0, 0, 0),
            events: Vec::new(),
            refused: None,
            task_args: Vec::new(),
            resend: false,
        })
    }

    /// The run id plants join with (`mpo plant-worker --run`).
    pub fn run_id(&self) -> &str {
        self.run.as_str()
    }

    /// The transport's name (`iceoryx2`, `zenoh`).
    pub fn transport(&self) -> &'static str {
        self.port.name()
    }

    /// Starts plant `index` as `mpo plant-worker` (this program) with the task flags `task`
    /// (`--task T --net N` or `--task-file F --net N`).
    pub fn spawn(&mut self, index: usize, task: &[String]) -> Result<(), FleetError> {
        let spawn_err = |message: String| FleetError::Spawn { index, message };
        let exe = std::env::current_exe().map_err(|e| spawn_err(format!("own executable: {e}")))?;
        let child = Command::new(exe)
            .arg("plant-worker")
            .args(["--spawned", "--run", self.run.as_str()])
            .args(["--index", &index.to_string()])
            .args(["--block-hint", &self.opts.sync_every.to_string()])
            .args(
                self.opts
                    .rate
                    .iter()
                    .flat_map(|r| ["--rate".to_string(), r.to_string()]),
            )
            .args(task)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| spawn_err(e.to_string()))?;
        self.members[index].child = Some(child);
        self.task_args = task.to_vec();
        Ok(())
    }

    /// Waits until every plant joined (answering each HELLO with WELCOME or REFUSE). A
    /// refused plant, or one that exits before joining, fails the start.
    pub fn admit(&mut self, timeout: Duration) -> Result<(), FleetError> {
        let t0 = Instant::now();
        let mut announced: Option<Instant> = None;
        while self.members.iter().any(|m| !m.live) {
            if announced.is_none_or(|t| t.elapsed() >= Duration::from_millis(500)) {
                // Plants of this run that worked for a previous incarnation of the learner
                // (it died and this one resumed) hear it and join again.
                let t: Text = bytemuck::Zeroable::zeroed();
                self.send(ANNOUNCE, u32::MAX, &t)?;
                announced = Some(Instant::now());
            }
            self.pump()?;
            if let Some(e) = self.refused.take() {
                return Err(e);
            }
            for m in self.members.iter_mut().filter(|m| !m.live) {
                if let Some(c) = m.child.as_mut()
                    && let Ok(Some(status)) = c.try_wait()
                {
                    return Err(FleetError::Spawn {
                        index: m.index,
                        message: format!("it exited before joining ({status})"),
                    });
                }
            }
            if t0.elapsed() > timeout {
                return Err(FleetError::JoinTimeout {
                    missing: self.members.iter().filter(|m| !m.live).count(),
                    plants: self.members.len(),
                    seconds: timeout.as_secs_f64(),
                });
            }
            self.port.wait(Duration::from_millis(50));
        }
        Ok(())
    }

    fn header(&self, kind: u32, plant: u32) -> Header {
        Header {
            kind,
            plant,
            run: self.tag,
            incarnation: self.incarnation,
            ..Default::default()
        }
    }

    fn send<T: bytemuck::Pod>(
        &mut self,
        kind: u32,
        plant: u32,
        payload: &T,
    ) -> Result<(), LinkError> {
        let head = self.header(kind, plant);
        frames::write(&mut self.down, head, payload, &[]);
        self.port.send_down(&self.down)
    }

    /// True with the free schedule.
    pub fn is_free(&self) -> bool {
        self.opts.schedule == FleetSchedule::Free
    }

    /// The newest policy version sent (0: none yet).
    pub fn version(&self) -> u64 {
        self.version
    }

    /// True when the trainer should send its policy now: always first; then in the
    /// deterministic schedule whenever it changed (`dirty`), in the free one when it changed
    /// and K steps per plant were inserted since the last send (so parameters go out at the
    /// rate the plants take them, not once per block).
    pub fn params_due(&self, dirty: bool, env_steps: u64) -> bool {
        if self.version == 0 || self.resend {
            return true;
        }
        match self.opts.schedule {
            FleetSchedule::Deterministic => dirty,
            FleetSchedule::Free => dirty && env_steps - self.sent_at >= self.opts.sync_every as u64,
        }
    }

    /// Sends `policy` as the next version, in blocks of [`CHUNK`] scalars.
    pub fn send_params<P: Params>(&mut self, policy: &P, env_steps: u64) -> Result<(), FleetError> {
        let total = policy.len();
        let count = total.div_ceil(CHUNK);
        if count > MAX_BLOCKS {
            return Err(LinkError(format!(
                "{total} parameters need {count} blocks, more than {MAX_BLOCKS}"
            ))
            .into());
        }
        let mut sum = CHECKSUM_SEED;
        for k in 0..P::TENSORS {
            sum = checksum(sum, policy.tensor(k));
        }
        self.version += 1;
        for index in 0..count {
            self.chunk.set_block(policy, self.version, index, sum);
            let head = self.header(PARAMS, u32::MAX);
            frames::write(&mut self.down, head, &*self.chunk, &[]);
            self.port.send_down(&self.down)?;
        }
        self.sent_at = env_steps;
        self.resend = false;
        self.report.versions = self.version;
        if self.opts.schedule == FleetSchedule::Free {
            // The free schedule's plants read the learner's progress from it (the warm-up).
            let go = self.go(env_steps);
            self.send(GO, u32::MAX, &go)?;
        }
        Ok(())
    }

    /// Collects the next blocks into the inbox: one round (deterministic: GO, then every
    /// live plant's block of it, or its drop), or what arrived (free: waiting up to 50 ms when
    /// nothing has).
    pub fn collect(&mut self, env_steps: u64) -> Result<(), FleetError> {
        match self.opts.schedule {
            FleetSchedule::Deterministic => self.run_round(env_steps),
            FleetSchedule::Free => {
                self.pump()?;
                if self.inbox.is_empty() {
                    self.port.wait(Duration::from_millis(50));
                    self.pump()?;
                }
                self.check_health();
                self.require_plants()
            }
        }
    }

    /// A GO for the live plants at `env_steps`.
    fn go(&self, env_steps: u64) -> Go {
        let mut go: Go = bytemuck::Zeroable::zeroed();
        go.round = self.round;
        go.version = self.version;
        go.env_steps = env_steps;
        for m in self.members.iter().filter(|m| m.live) {
            go.members[m.index / 64] |= 1 << (m.index % 64);
        }
        go
    }

    /// One deterministic round: GO to the live plants, then their blocks.
    fn run_round(&mut self, env_steps: u64) -> Result<(), FleetError> {
        let go = self.go(env_steps);
        let now = Instant::now();
        for m in self.members.iter_mut() {
            m.heard = now;
            // A plant joining during the round takes part from the next one.
            m.in_round = m.live;
        }
        self.send(GO, u32::MAX, &go)?;
        loop {
            self.pump()?;
            self.check_health();
            self.require_plants()?;
            let waiting = self
                .members
                .iter()
                .any(|m| m.live && m.in_round && !self.inbox.iter().any(|(i, _)| *i == m.index));
            if !waiting {
                break;
            }
            self.port.wait(Duration::from_millis(20));
        }
        self.inbox.sort_by_key(|(i, _)| *i);
        self.round += 1;
        self.report.rounds = self.round;
        Ok(())
    }

    fn require_plants(&self) -> Result<(), FleetError> {
        match self
            .members
            .iter()
            .any(|m| m.live || m.restarting.is_some())
        {
            true => Ok(()),
            false => Err(FleetError::NoPlants(format!(
                "{} dropped; see the log above",
                self.report.dropped
            ))),
        }
    }

    /// Drops plants whose process exited or that were silent past the timeout, and gives up
    /// on restarted processes that exited or stayed silent before joining.
    fn check_health(&mut self) {
        let timeout = self.opts.timeout;
        let rounds = self.opts.schedule == FleetSchedule::Deterministic;
        let mut drop = Vec::new();
        let mut failed = Vec::new();
        for m in self.members.iter_mut() {
            let exited = m.child.as_mut().and_then(|c| c.try_wait().ok().flatten());
            // In rounds a plant owes only its block of the round: one that delivered it, or
            // that joined during the round, waits for the next GO and says nothing meanwhile.
            let owes = !rounds || (m.in_round && !self.inbox.iter().any(|(i, _)| *i == m.index));
            if m.live {
                if let Some(status) = exited {
                    drop.push((m.index, format!("its process exited ({status})")));
                } else if owes && m.heard.elapsed() > timeout {
                    drop.push((
                        m.index,
                        format!("silent for {:.0} s", timeout.as_secs_f64()),
                    ));
                }
            } else if let Some(since) = m.restarting {
                if let Some(status) = exited {
                    failed.push((m.index, format!("exited before joining ({status})")));
                } else if since.elapsed() > timeout {
                    failed.push((
                        m.index,
                        format!("did not join within {:.0} s", timeout.as_secs_f64()),
                    ));
                }
            }
        }
        for (i, why) in drop {
            self.drop_member(i, &why);
        }
        for (i, why) in failed {
            let m = &mut self.members[i];
            m.restarting = None;
            if let Some(mut c) = m.child.take() {
                let _ = c.kill();
                let _ = c.wait();
            }
            self.events
                .push(format!("fleet: plant {i}'s restarted process {why}"));
            self.restart(i);
        }
    }

    /// Drops plant `i` (tells it, kills a process this learner started, clears what it left
    /// registered), logs why, and restarts a process this learner started (up to
    /// `opts.restarts` times per plant).
    fn drop_member(&mut self, i: usize, why: &str) {
        let m = &mut self.members[i];
        m.live = false;
        let (pid, incarnation) = (m.pid, m.incarnation);
        let started = m.child.is_some();
        if let Some(mut c) = m.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        self.report.dropped += 1;
        let mut t: Text = bytemuck::Zeroable::zeroed();
        t.plant_incarnation = incarnation;
        frames::put_text(&mut t.message, why);
        let _ = self.send(DROPPED, i as u32, &t);
        self.port.cleanup_dead();
        self.inbox.retain(|(k, _)| *k != i);
        let left = self.members.iter().filter(|m| m.live).count();
        self.events.push(format!(
            "fleet: plant {i} (pid {pid}) dropped: {why}; {left} plant(s) go on"
        ));
        if started {
            self.restart(i);
        }
    }

    /// Starts plant `i`'s process again, when its restarts are not used up; it joins the
    /// round after it said HELLO, continuing its streams.
    fn restart(&mut self, i: usize) {
        let (done, limit) = (self.members[i].restarts, self.opts.restarts);
        if done >= limit {
            self.events.push(format!(
                "fleet: plant {i} is not restarted (it was restarted {done} time(s), --plant-restarts {limit})"
            ));
            return;
        }
        let args = self.task_args.clone();
        match self.spawn(i, &args) {
            Ok(()) => {
                let m = &mut self.members[i];
                m.restarts += 1;
                m.restarting = Some(Instant::now());
                self.report.restarted += 1;
                self.events.push(format!(
                    "fleet: plant {i} restarted (restart {} of {limit})",
                    done + 1
                ));
            }
            Err(e) => self.events.push(format!("fleet: {e}")),
        }
    }

    /// Drains the frames received: HELLOs are answered, BYEs drop their plant, blocks go to
    /// the inbox.
    fn pump(&mut self) -> Result<(), FleetError> {
        let mut frames_in = std::mem::take(&mut self.spare);
        let mut got: Vec<Vec<u8>> = Vec::new();
        self.port.recv_up(&mut |f| {
            let mut b = frames_in.pop().unwrap_or_default();
            b.clear();
            b.extend_from_slice(f);
            got.push(b);
        })?;
        self.spare = frames_in;
        for f in got {
            self.handle(f)?;
        }
        Ok(())
    }

    fn handle(&mut self, f: Vec<u8>) -> Result<(), FleetError> {
        let (h, body) = match frames::parse(&f, self.tag) {
            Ok(x) => x,
            Err(_) => {
                self.report.ignored_frames += 1;
                self.spare.push(f);
                return Ok(());
            }
        };
        let i = h.plant as usize;
        if i >= self.members.len() {
            self.report.ignored_frames += 1;
        } else {
            match h.kind {
                HELLO => self.hello(i, &h, body)?,
                BYE if self.members[i].live => {
                    let why = frames::read::<Text>(body)
                        .map(|t| frames::text_of(&t.message))
                        .unwrap_or_default();
                    self.drop_member(i, &format!("it left: {why}"));
                }
                BLOCK if self.members[i].live && h.incarnation == self.members[i].incarnation => {
                    self.members[i].heard = Instant::now();
                    self.inbox.push((i, f));
                    return Ok(());
                }
                _ => self.report.ignored_frames += 1,
            }
        }
        self.spare.push(f);
        Ok(())
    }

    /// Answers a HELLO: WELCOME with the plant's streams, or REFUSE with why. A plant may
    /// join at any time: late, again after a drop, as a new process of a live plant (the
    /// old one is dropped), or after this learner resumed the run its previous incarnation
    /// ran.
    fn hello(&mut self, i: usize, h: &Header, body: &[u8]) -> Result<(), FleetError> {
        let Ok(hello) = frames::read::<Hello>(body) else {
            self.report.ignored_frames += 1;
            return Ok(());
        };
        if let Some(why) = mismatch(&hello.id, &self.identity) {
            return self.refuse(i, h, &hello, why);
        }
        let m = &self.members[i];
        if m.live && m.incarnation == h.incarnation {
            // A repeated HELLO (the plant had not heard the WELCOME yet): answer it again.
            let w = m.welcome;
            self.send(WELCOME, i as u32, &w)?;
            return Ok(());
        }
        if m.live {
            self.drop_member(
                i,
                &format!("a new process of the plant (pid {}) joins", hello.pid),
            );
        }
        let w = self.welcome_of(i, h.incarnation);
        self.send(WELCOME, i as u32, &w)?;
        let started = self.version > 0;
        let m = &mut self.members[i];
        let again = m.joins > 0 || (hello.learner != 0 && hello.learner != self.incarnation);
        m.live = true;
        m.pid = hello.pid;
        m.incarnation = h.incarnation;
        m.heard = Instant::now();
        m.welcome = w;
        m.joins += 1;
        m.in_round = false;
        m.restarting = None;
        m.next_block = 0;
        m.seen_version = 0;
        m.at_boundary = true;
        // It has no policy yet: the next round (or block) sends it.
        self.resend |= started;
        let what = match again {
            true => {
                self.report.rejoined += 1;
                "rejoined"
            }
            false => "joined",
        };
        self.events.push(format!(
            "fleet: plant {i} {what} (pid {}, {} environment resets to replay)",
            hello.pid, w.episodes
        ));
        Ok(())
    }

    /// Refuses a HELLO (another task, sizes or task file); before the run started, the
    /// refusal fails the start.
    fn refuse(
        &mut self,
        i: usize,
        h: &Header,
        hello: &Hello,
        why: String,
    ) -> Result<(), FleetError> {
        let mut t: Text = bytemuck::Zeroable::zeroed();
        t.plant_incarnation = h.incarnation;
        frames::put_text(&mut t.message, &why);
        self.send(REFUSE, i as u32, &t)?;
        self.report.refused += 1;
        self.events.push(format!(
            "fleet: plant {i} (pid {}) refused: {why}",
            hello.pid
        ));
        if self.version == 0 && self.refused.is_none() {
            self.refused = Some(FleetError::Refused {
                index: i,
                message: why,
            });
        }
        Ok(())
    }

    /// The WELCOME of plant `i` (of incarnation `incarnation`): its streams where its last
    /// inserted block left them (its seeds' start when it has sent none).
    fn welcome_of(&self, i: usize, incarnation: u64) -> Welcome {
        let m = &self.members[i];
        let mut w = self.welcome;
        w.plant_incarnation = incarnation;
        w.collector = m.collector;
        w.episodes = m.resets;
        w.env_seed = super::env_seed_of(self.seed, i);
        w.mode = self.opts.schedule.code();
        w.block = self.opts.sync_every;
        w
    }

    /// What a checkpoint keeps of the fleet: the run id and each plant's streams.
    pub fn record(&self) -> FleetRecord {
        FleetRecord {
            run: self.run.as_str().to_string(),
            plants: self
                .members
                .iter()
                .map(|m| PlantRecord {
                    collector: crate::checkpoint::hex(&m.collector),
                    resets: m.resets,
                })
                .collect(),
        }
    }

    /// The blocks received and not yet inserted (deterministic: one per live plant, in plant
    /// order). Give the vector back with [`Fleet::recycle`].
    pub fn take_inbox(&mut self) -> Vec<(usize, Vec<u8>)> {
        std::mem::take(&mut self.inbox)
    }

    /// Takes back what [`Fleet::take_inbox`] gave (its buffers are reused).
    pub fn recycle(&mut self, mut inbox: Vec<(usize, Vec<u8>)>) {
        self.spare.extend(inbox.drain(..).map(|(_, b)| b));
        if self.inbox.is_empty() {
            self.inbox = inbox;
        }
    }

    /// Checks a block of member `i` and books it: returns its head and its records' bytes,
    /// or `None` when it is not to be inserted (malformed, non-finite, or too stale).
    pub fn accept<'f>(
        &mut self,
        i: usize,
        frame: &'f [u8],
        obs: usize,
        act: usize,
    ) -> Option<(BlockHead, &'f [u8])> {
        let (_, body) = frames::parse(frame, self.tag).ok()?;
        let head: BlockHead = match frames::read(body) {
            Ok(h) => h,
            Err(_) => {
                self.report.bad_blocks += 1;
                return None;
            }
        };
        let records = &body[size_of::<BlockHead>()..];
        let words = frames::record_words(obs, act);
        let finite = records
            .chunks_exact(4)
            .all(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]).is_finite());
        if head.obs as usize != obs
            || head.act as usize != act
            || records.len() != 4 * words * head.count as usize
            || !finite
        {
            self.report.bad_blocks += 1;
            return None;
        }
        let m = &mut self.members[i];
        // Where a process of this plant joining later continues its streams.
        m.collector = head.collector;
        m.resets = head.episodes;
        if head.round > m.next_block && self.opts.schedule == FleetSchedule::Free {
            self.report.lost_blocks += head.round - m.next_block;
        }
        m.next_block = head.round + 1;
        m.at_boundary = head.flags & AT_BOUNDARY != 0;
        if head.version > m.seen_version && head.param_latency_ns > 0 {
            m.seen_version = head.version;
            let l = &mut self.latency;
            *l = (
                l.0 + 1,
                l.1 + head.param_latency_ns,
                l.2.max(head.param_latency_ns),
            );
        }
        let lag = self.version.saturating_sub(head.version);
        if self.opts.schedule == FleetSchedule::Free && lag > self.opts.max_lag {
            self.report.stale_blocks += 1;
            return None;
        }
        self.report.blocks += 1;
        self.report.transitions += head.count as u64;
        self.lag_sum += lag;
        self.report.lag_max = self.report.lag_max.max(lag);
        Some((head, records))
    }

    /// True where an evaluation or checkpoint may be taken: with one plant in rounds, between
    /// its episodes (as in-process); with several, at any round's end (their episodes are not
    /// in step; the Control Suite's 1000-step episodes with K dividing 1000 end together
    /// anyway); free-running, always (the plants keep their episodes going meanwhile).
    pub fn at_boundary(&self) -> bool {
        match (self.opts.schedule, self.members.len()) {
            (FleetSchedule::Deterministic, 1) => self.members[0].at_boundary,
            _ => true,
        }
    }

    /// The log lines since the last call (joins, drops, refusals).
    pub fn take_events(&mut self) -> Vec<String> {
        std::mem::take(&mut self.events)
    }

    /// The counters so far.
    pub fn report(&self) -> FleetReport {
        let mut r = self.report.clone();
        r.lag_mean = match r.blocks {
            0 => 0.0,
            b => self.lag_sum as f64 / b as f64,
        };
        let (n, sum, max) = self.latency;
        if n > 0 {
            r.param_latency_us_mean = sum as f64 / n as f64 / 1e3;
            r.param_latency_us_max = max as f64 / 1e3;
        }
        r
    }

    /// Ends the run: STOP to every plant, then waits up to 5 s for the processes this learner
    /// started (killing what is left).
    pub fn finish(mut self) -> FleetReport {
        let t: Text = bytemuck::Zeroable::zeroed();
        let _ = self.send(STOP, u32::MAX, &t);
        let t0 = Instant::now();
        for m in self.members.iter_mut() {
            if let Some(mut c) = m.child.take() {
                while t0.elapsed() < Duration::from_secs(5) {
                    if let Ok(Some(_)) = c.try_wait() {
                        break;
                    }
                    std::thread::sleep(Duration::from_millis(10));
                }
                let _ = c.kill();
                let _ = c.wait();
            }
        }
        self.report()
    }
}

impl Drop for Fleet {
    fn drop(&mut self) {
        for m in self.members.iter_mut() {
            if let Some(mut c) = m.child.take() {
                let _ = c.kill();
                let _ = c.wait();
            }
        }
    }
}

/// 64 random bits from the kernel (the incarnation of this learner), the clock otherwise.
pub(crate) fn random_u64() -> u64 {
    let mut r = [0u8; 8];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut r))
        .map(|()| u64::from_le_bytes(r))
        .unwrap_or_else(|_| mpo_link::service::monotonic_ns())
}
