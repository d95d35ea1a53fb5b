//! The host side of the link: sends observations, waits for actions with a deadline, pushes
//! policy parameters.
//!
//! The plant never blocks past its deadline: when the controller is slow, dead, or answers
//! with something malformed, [`Plant::request_action`] returns a [`Miss`], the caller applies
//! the safe (zero) action and the plant keeps running. A restarted controller is picked up
//! without any action from the caller: iceoryx2 connects new ports on the next send/receive,
//! and the parameter history hands the new controller the newest policy.

use core::time::Duration;

use iceoryx2::port::update_connections::UpdateConnections;
use mpo_core::params::Params;

use crate::messages::{
    ACT_SAMPLED, ActMsg, CHECKSUM_SEED, CHUNK, MAX_ACT, MAX_BLOCKS, MAX_OBS, ObsMsg, ParamChunk,
    Reject, Rejections, checksum,
};
use crate::service::{
    LinkError, PlantPorts, RunId, WaitMode, err, monotonic_ns, remaining, wait_for_event,
};

/// Reply flag set by the controller when it rejected the request (the action is zero and must
/// not be used).
pub const ACT_REJECTED: u32 = 2;

/// Why no action arrived in time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Miss {
    /// The deadline passed (controller slow, dead or not started yet).
    Timeout,
    /// The controller answered that it rejected the request (for example a NaN observation).
    Rejected,
    /// The request itself was invalid here (wrong length, non-finite): never sent.
    Invalid(Reject),
    /// iceoryx2 failed to send (for example shared memory exhausted).
    Send,
}

/// One action received in time.
#[derive(Debug, Clone, Copy)]
pub struct Action {
    /// The action; entries past the policy's action size are zero.
    pub action: [f32; MAX_ACT],
    /// `ln pi(a | s)` for a sampled action.
    pub log_prob: Option<f32>,
    /// Parameter generation the controller used.
    pub generation: u64,
    /// Request sequence number.
    pub seq: u64,
    /// Plant send, controller receive, controller send, plant receive (`CLOCK_MONOTONIC` ns).
    pub t: [u64; 4],
}

/// Counters of the plant side.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlantStats {
    /// Requests sent.
    pub requests: u64,
    /// Valid replies received in time.
    pub replies: u64,
    /// Requests that ended in a miss (safe action applied by the caller).
    pub misses: u64,
    /// Of which: deadline passed.
    pub timeouts: u64,
    /// Of which: rejected by the controller.
    pub rejected_by_controller: u64,
    /// Malformed or unexpected replies dropped here (never acted on).
    pub rejections: Rejections,
    /// Parameter generations pushed.
    pub pushes: u64,
    /// Replies computed with parameters older than the newest pushed (the controller read the
    /// request before it had taken the push): never acted on; the request is sent again.
    pub stale_policy: u64,
}

/// Sizes and timing of one plant.
#[derive(Debug, Clone, Copy)]
pub struct PlantConfig {
    /// Policy input size.
    pub obs_len: usize,
    /// Policy output size.
    pub act_len: usize,
    /// How to wait for the reply.
    pub wait: WaitMode,
    /// Deadline per request for [`Plant::act`] and [`Plant::act_sampled`].
    pub deadline: Duration,
    /// In event mode, how long after sending to spin on the reply before sleeping
    /// (`Duration::ZERO`: sleep at once). A reply that comes within it spares the plant its own
    /// wake-up, which on a VM whose idle vCPUs halt is a large part of the round trip (event
    /// p50 33.4 us without, 21.1 us with 60 us here: `cargo bench -p mpo-link --bench latency`,
    /// docs/controller.md); the price is at most this
    /// much CPU time per request. Busy-poll spins anyway.
    pub spin: Duration,
}

/// The plant's endpoint.
pub struct Plant {
    ports: Option<PlantPorts>,
    cfg: PlantConfig,
    run: RunId,
    seq: u64,
    generation: u64,
    stats: PlantStats,
    /// The request being built (reused: no allocation per message).
    req: ObsMsg,
    /// One parameter block being built (16 KiB: kept on the heap).
    chunk: Box<ParamChunk>,
}

impl Drop for Plant {
    fn drop(&mut self) {
        // Clear what killed controllers left registered, release the ports so the run's files
        // go, then the counter segment if the controller is gone too.
        if let Some(p) = &self.ports {
            p.cleanup_dead();
        }
        self.ports = None;
        self.run.remove_if_last();
    }
}

impl Plant {
    fn ports(&self) -> &PlantPorts {
        self.ports.as_ref().expect("ports live until drop")
    }

    /// Opens the plant side of `run` (the controller may start before or after).
    pub fn open(run: &RunId, cfg: PlantConfig) -> Result<Self, LinkError> {
        if cfg.obs_len == 0 || cfg.obs_len > MAX_OBS || cfg.act_len == 0 || cfg.act_len > MAX_ACT {
            return Err(LinkError(format!(
                "sizes {}/{} outside 1..={MAX_OBS} / 1..={MAX_ACT}",
                cfg.obs_len, cfg.act_len
            )));
        }
        Ok(Self {
            ports: Some(PlantPorts::open(run)?),
            cfg,
            run: run.clone(),
            seq: 0,
            generation: 0,
            stats: PlantStats::default(),
            req: bytemuck::Zeroable::zeroed(),
            chunk: bytemuck::zeroed_box(),
        })
    }

    /// The run this plant belongs to (pass it to the controller: `--run <id>`).
    pub fn run_id(&self) -> &RunId {
        &self.run
    }

    /// Counters so far.
    pub fn stats(&self) -> PlantStats {
        self.stats
    }

    /// The newest parameter generation pushed (0 before the first push).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// True when a live controller is attached to the observation service (dead ones are
    /// cleaned up first). For waiting until a freshly spawned controller is ready.
    pub fn controller_connected(&self) -> bool {
        self.ports().cleanup_dead();
        self.ports().services.obs_subscribers() > 0
    }

    /// Mean action for `obs`, within the configured deadline. On a miss `out` is set to zero
    /// (the safe action) and the miss is returned; the caller keeps stepping.
    pub fn act(&mut self, obs: &[f32], out: &mut [f32]) -> Result<Action, Miss> {
        let r = self.request_action(obs, None, 0.0, self.cfg.deadline);
        Self::write_out(&r, out, self.cfg.act_len);
        r
    }

    /// A sampled action `mu + L z` for the standard-normal `noise` (drawn by the caller in the
    /// same order `Gaussian::sample` draws it) and its log-probability, within the deadline.
    /// On a miss `out` is zero.
    pub fn act_sampled(
        &mut self,
        obs: &[f32],
        noise: &[f32],
        std_floor: f32,
        out: &mut [f32],
    ) -> Result<Action, Miss> {
        let r = self.request_action(obs, Some(noise), std_floor, self.cfg.deadline);
        Self::write_out(&r, out, self.cfg.act_len);
        r
    }

    fn write_out(r: &Result<Action, Miss>, out: &mut [f32], n: usize) {
        let n = n.min(out.len());
        match r {
            Ok(a) => out[..n].copy_from_slice(&a.action[..n]),
            Err(_) => out[..n].fill(0.0),
        }
    }

    /// One request: sends `obs` (and `noise` for a sampled action) and waits until `deadline`
    /// from now for the reply with the same sequence number. Replies to older requests
    /// (a controller that answered late) and malformed replies are counted and dropped.
    pub fn request_action(
        &mut self,
        obs: &[f32],
        noise: Option<&[f32]>,
        std_floor: f32,
        deadline: Duration,
    ) -> Result<Action, Miss> {
        let deadline_ns = monotonic_ns() + deadline.as_nanos() as u64;
        let r = self.fill_request(obs, noise, std_floor);
        if let Err(e) = r {
            self.stats.rejections.count(e);
            return self.miss(Miss::Invalid(e));
        }
        self.send_and_wait(deadline_ns)
    }

    /// Sends `msg` as is, without the local checks (tests of the controller's validation use
    /// it to deliver malformed requests), and waits for the reply like `request_action`.
    pub fn request_raw(&mut self, msg: ObsMsg, deadline: Duration) -> Result<Action, Miss> {
        let deadline_ns = monotonic_ns() + deadline.as_nanos() as u64;
        let (episode, step) = (self.req.episode, self.req.step);
        self.req = msg;
        let r = self.send_and_wait(deadline_ns);
        (self.req.episode, self.req.step) = (episode, step);
        r
    }

    /// Sends the request (a new sequence number); `false` if it could not be sent.
    fn send_request(&mut self) -> bool {
        // iceoryx2 hands a new subscriber the parameter history when the publisher notices it,
        // which happens only inside a publisher call: look before every request, so a restarted
        // controller has the newest policy before it sees the observation (a cheap check of a
        // change counter when nothing changed).
        let _ = UpdateConnections::update_connections(&self.ports().params);
        self.seq += 1;
        self.req.seq = self.seq;
        self.req.t_send_ns = monotonic_ns();
        if self.ports().obs.send_copy(self.req).is_err() {
            return false;
        }
        if self.cfg.wait == WaitMode::Event {
            // Nobody listening (controller dead) is not an error here: the deadline reports it.
            let _ = self.ports().notify.notify();
        }
        true
    }

    fn send_and_wait(&mut self, deadline_ns: u64) -> Result<Action, Miss> {
        self.stats.requests += 1;
        if !self.send_request() {
            return self.miss(Miss::Send);
        }
        let spin_until = self.req.t_send_ns + self.cfg.spin.as_nanos() as u64;
        loop {
            let mut stale = false;
            while let Ok(Some(sample)) = self.ports().act.receive() {
                let m: &ActMsg = &sample;
                match m.validate(self.seq, self.cfg.act_len) {
                    Ok(_) if m.flags & ACT_REJECTED != 0 => {
                        self.stats.rejected_by_controller += 1;
                        return self.miss(Miss::Rejected);
                    }
                    // A busy-polling controller may read the request between two looks at the
                    // parameter port, before the newest push has arrived: its answer is the old
                    // policy's. Never acted on as if fresh: asked again (the controller has the
                    // push by its next look), within the same deadline.
                    Ok(_) if m.generation < self.generation => {
                        self.stats.stale_policy += 1;
                        stale = true;
                        break;
                    }
                    Ok(a) => {
                        let mut action = [0f32; MAX_ACT];
                        action[..a.len()].copy_from_slice(a);
                        self.stats.replies += 1;
                        return Ok(Action {
                            action,
                            log_prob: (m.flags & ACT_SAMPLED != 0).then_some(m.log_prob),
                            generation: m.generation,
                            seq: m.seq,
                            t: [self.req.t_send_ns, m.t_recv_ns, m.t_send_ns, monotonic_ns()],
                        });
                    }
                    Err(e) => self.stats.rejections.count(e),
                }
            }
            if stale && !self.send_request() {
                return self.miss(Miss::Send);
            }
            let left = remaining(deadline_ns);
            if left.is_zero() {
                self.stats.timeouts += 1;
                return self.miss(Miss::Timeout);
            }
            match self.cfg.wait {
                WaitMode::Event if monotonic_ns() < spin_until => core::hint::spin_loop(),
                WaitMode::Event => wait_for_event(&self.ports().listen, left),
                WaitMode::BusyPoll => core::hint::spin_loop(),
            }
        }
    }

    fn miss(&mut self, m: Miss) -> Result<Action, Miss> {
        // A killed controller leaves its ports registered. They are not cleared here: the
        // scan of dead nodes takes hundreds of milliseconds, hundreds of control periods. A
        // restarted controller clears them before it opens its ports, and the plant clears
        // them when it closes (so the run's files go).
        self.stats.misses += 1;
        Err(m)
    }

    fn fill_request(
        &mut self,
        obs: &[f32],
        noise: Option<&[f32]>,
        std_floor: f32,
    ) -> Result<(), Reject> {
        let (n, a) = (self.cfg.obs_len, self.cfg.act_len);
        if obs.len() != n || noise.is_some_and(|z| z.len() != a) {
            return Err(Reject::Length);
        }
        if !obs.iter().all(|x| x.is_finite())
            || noise.is_some_and(|z| z.iter().any(|x| !x.is_finite()))
        {
            return Err(Reject::NonFinite);
        }
        self.req.set_observation(obs, noise, std_floor);
        Ok(())
    }

    /// Sets the episode and step written into the following requests (for the controller's
    /// logs).
    pub fn set_episode_step(&mut self, episode: u64, step: u32) {
        self.req.episode = episode;
        self.req.step = step;
    }

    /// Pushes a new parameter generation: every tensor of `policy` in `Params` order, split
    /// into blocks of [`CHUNK`] scalars, each with its own checksum and the checksum of the
    /// whole vector. The controller swaps to it between two requests once all blocks arrived
    /// and verified; requests sent after this call see it (iceoryx2 delivers in order and the
    /// controller drains parameters before answering).
    pub fn push_params<P: Params>(&mut self, policy: &P) -> Result<u64, LinkError> {
        let total = policy.len();
        let count = total.div_ceil(CHUNK);
        if count > MAX_BLOCKS {
            return Err(LinkError(format!(
                "{total} parameters need {count} blocks, more than {MAX_BLOCKS}"
            )));
        }
        let mut total_checksum = CHECKSUM_SEED;
        for k in 0..P::TENSORS {
            total_checksum = checksum(total_checksum, policy.tensor(k));
        }
        self.generation += 1;
        for index in 0..count {
            self.chunk
                .set_block(policy, self.generation, index, total_checksum);
            self.send_chunk()?;
        }
        let _ = self.ports().notify.notify();
        self.stats.pushes += 1;
        Ok(self.generation)
    }

    fn send_chunk(&mut self) -> Result<(), LinkError> {
        let sample = self
            .ports()
            .params
            .loan_uninit()
            .map_err(err("loan parameter block"))?;
        let sample = sample.write_payload(*self.chunk);
        sample.send().map_err(err("send parameter block"))?;
        Ok(())
    }

    /// Sends a raw parameter block as is (for tests of the controller's validation).
    pub fn send_raw_chunk(&mut self, chunk: &ParamChunk) -> Result<(), LinkError> {
        *self.chunk = *chunk;
        self.send_chunk()?;
        let _ = self.ports().notify.notify();
        Ok(())
    }
}
