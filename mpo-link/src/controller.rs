//! The controller: mpo-core inference behind iceoryx2 and nothing else.
//!
//! One loop, single-threaded: wait (`ppoll` on the listener, or spin), apply any complete parameter generation,
//! answer the newest observation, repeat. Parameters are assembled into a second policy and
//! swapped in by exchanging two boxes between requests, so no request ever sees a half-written
//! policy. Everything is allocated before the loop starts.

use core::sync::atomic::{AtomicBool, Ordering};
use core::time::Duration;

use mpo_core::actor::Actor;
use mpo_core::network::PolicyNet;
use mpo_core::params::Params;
use mpo_core::rng::Rng;

use crate::messages::{
    ACT_SAMPLED, ActMsg, CHECKSUM_SEED, CHUNK, MAX_BLOCKS, OBS_SAMPLE, ObsMsg, ParamChunk, Reject,
    Rejections, checksum,
};
use crate::plant::ACT_REJECTED;
use crate::service::{ControllerPorts, LinkError, RunId, WaitMode, monotonic_ns, wait_for_event};

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

/// Installs SIGINT and SIGTERM handlers that only set a flag the loop polls.
///
/// iceoryx2's own handling is disabled on our node (with it enabled, iceoryx2 consumes the
/// signal and reports it only through the return value of its waits). No `SA_RESTART`, so a
/// blocking wait returns early on a signal.
pub fn install_stop_handler() {
    // SAFETY: the handler only stores to an atomic (async-signal-safe); `sa` is fully
    // initialised before use.
    unsafe {
        let mut sa: libc::sigaction = core::mem::zeroed();
        sa.sa_sigaction = on_signal as *const () as usize;
        libc::sigemptyset(&mut sa.sa_mask);
        sa.sa_flags = 0;
        libc::sigaction(libc::SIGINT, &sa, core::ptr::null_mut());
        libc::sigaction(libc::SIGTERM, &sa, core::ptr::null_mut());
    }
}

/// True once SIGINT or SIGTERM arrived (or [`request_stop`] was called).
pub fn stop_requested() -> bool {
    STOP.load(Ordering::Relaxed)
}

/// Asks the loop to stop (in-process uses: benchmarks, tests).
pub fn request_stop() {
    STOP.store(true, Ordering::Relaxed);
}

/// Controller counters, printed on exit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ControllerStats {
    /// Actions sent.
    pub answered: u64,
    /// Observations dropped because a newer one was already waiting.
    pub superseded: u64,
    /// Rejected observations and parameter blocks.
    pub rejections: Rejections,
    /// Parameter generations swapped in.
    pub swaps: u64,
}

impl core::fmt::Display for ControllerStats {
    /// The `stats ...` line both controller binaries print on exit.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let r = &self.rejections;
        write!(
            f,
            "stats answered={} superseded={} swaps={} rejected_length={} rejected_non_finite={} \
             rejected_sequence={} rejected_corrupt={}",
            self.answered,
            self.superseded,
            self.swaps,
            r.length,
            r.non_finite,
            r.sequence,
            r.corrupt
        )
    }
}

/// Assembles parameter blocks into a staging policy and verifies the whole vector.
pub struct Assembler<P: Params> {
    staging: Box<P>,
    generation: u64,
    received: u64,
    count: u32,
    total_checksum: u64,
}

impl<P: Params> Assembler<P> {
    /// An assembler writing into `staging` (its contents are overwritten block by block).
    pub fn new(staging: Box<P>) -> Self {
        const { assert!(MAX_BLOCKS <= 64) };
        Self {
            staging,
            generation: 0,
            received: 0,
            count: 0,
            total_checksum: 0,
        }
    }

    /// The generation being assembled (after [`Self::add`] returned true: the one completed).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Exchanges the staging policy, complete after [`Self::add`] returned true, with `active`.
    pub fn swap_into(&mut self, active: &mut Box<P>) {
        core::mem::swap(active, &mut self.staging);
    }

    /// Writes one block into `staging` at its flat offset; returns true when generation
    /// `chunk.generation` is complete and its whole-vector checksum matched. `applied` is the
    /// generation in use (its blocks and older ones are ignored).
    pub fn add(&mut self, chunk: &ParamChunk, applied: u64) -> Result<bool, Reject> {
        let total = self.staging.len();
        let payload = chunk.validate(total)?;
        if chunk.generation <= applied {
            // Already active (a history replay after a restart of the plant's view): ignore.
            return Ok(false);
        }
        if chunk.generation != self.generation {
            // A newer generation starts (or an older one's leftover arrives first from the
            // history): restart assembly for it.
            if chunk.generation < self.generation {
                return Ok(false);
            }
            self.generation = chunk.generation;
            self.received = 0;
            self.count = chunk.count;
            self.total_checksum = chunk.total_checksum;
        } else if chunk.total_checksum != self.total_checksum {
            return Err(Reject::Corrupt);
        }
        // Scatter into the tensors.
        let mut flat = chunk.index as usize * CHUNK;
        let mut done = 0;
        let mut k = 0;
        let mut base = 0;
        while done < payload.len() {
            let t = self.staging.tensor_mut(k);
            if flat >= base + t.len() {
                base += t.len();
                k += 1;
                continue;
            }
            let off = flat - base;
            let take = (t.len() - off).min(payload.len() - done);
            t[off..off + take].copy_from_slice(&payload[done..done + take]);
            done += take;
            flat += take;
        }
        self.received |= 1 << chunk.index;
        if self.received.count_ones() < self.count {
            return Ok(false);
        }
        let mut h = CHECKSUM_SEED;
        for k in 0..P::TENSORS {
            h = checksum(h, self.staging.tensor(k));
        }
        if h != self.total_checksum {
            self.received = 0;
            return Err(Reject::Corrupt);
        }
        Ok(true)
    }
}

/// Options of one controller.
#[derive(Debug, Clone)]
pub struct ControllerOptions {
    /// The run to serve.
    pub run: RunId,
    /// Event-driven or busy-poll waiting.
    pub wait: WaitMode,
    /// Seed of the initial policy (generation 0) before any push.
    pub seed: u64,
    /// Standard deviation of the initial policy.
    pub init_std: f32,
}

/// Serves `run` with an `Actor<OBS, ACT, TRI, H1, H2>` until SIGINT/SIGTERM (or
/// [`request_stop`]). Returns the counters; every iceoryx2 resource of this side is released
/// when it returns.
pub fn serve<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
>(
    opts: &ControllerOptions,
    ready: impl FnOnce(),
) -> Result<ControllerStats, LinkError> {
    serve_policy::<OBS, ACT, TRI, Actor<OBS, ACT, TRI, H1, H2>>(opts, ready)
}

/// [`serve`] with a policy network of any form (`mpo_core::network::PolicyNet`: the two-layer
/// actor or the residual one).
// The controller's whole loop (wait, read, act, reply, take new parameters) in one place, so
// that the hot path between two requests can be read at once and checked for allocations.
pub fn serve_policy<const OBS: usize, const ACT: usize, const TRI: usize, P>(
    opts: &ControllerOptions,
    ready: impl FnOnce(),
) -> Result<ControllerStats, LinkError>
where
    P: PolicyNet<OBS, ACT, TRI>,
{
    let ports = ControllerPorts::open(&opts.run)?;
    let mut policy: Box<P> = bytemuck::zeroed_box();
    policy.init(&mut Rng::seed_from_u64(opts.seed), opts.init_std, 1e-4);
    let mut asm = Assembler::<P>::new(bytemuck::zeroed_box());
    let mut applied = 0u64;
    let mut stats = ControllerStats::default();
    let mut reply: ActMsg = bytemuck::Zeroable::zeroed();
    let mut latest: ObsMsg = bytemuck::Zeroable::zeroed();

    ready();

    // Bounded waits: the stop flag is checked at least this often even if a signal arrived
    // just before the wait started.
    let tick = Duration::from_millis(50);
    while !stop_requested() {
        if opts.wait == WaitMode::Event {
            wait_for_event(&ports.listen, tick);
        }
        // Parameters first: a push made before a request applies to that request.
        while let Ok(Some(sample)) = ports.params.receive() {
            match asm.add(&sample, applied) {
                Ok(true) => {
                    asm.swap_into(&mut policy);
                    applied = asm.generation();
                    stats.swaps += 1;
                }
                Ok(false) => {}
                Err(e) => stats.rejections.count(e),
            }
        }
        // Only the newest observation is answered; older ones are stale by now.
        let mut have = false;
        while let Ok(Some(sample)) = ports.obs.receive() {
            if have {
                stats.superseded += 1;
            }
            latest = *sample;
            have = true;
        }
        if !have {
            if opts.wait == WaitMode::BusyPoll {
                core::hint::spin_loop();
            }
            continue;
        }
        reply.t_recv_ns = monotonic_ns();
        respond_with(&*policy, &latest, applied, &mut stats, &mut reply);
        reply.t_send_ns = monotonic_ns();
        if ports.act.send_copy(reply).is_ok() {
            stats.answered += 1;
        }
        if opts.wait == WaitMode::Event {
            let _ = ports.notify.notify();
        }
    }
    drop(ports);
    opts.run.remove_if_last();
    Ok(stats)
}

/// Answers the request `request` with `policy` (parameter generation `applied`) into `reply`:
/// the mean action, or with `OBS_SAMPLE` the sample `mu + L z` for the request's noise and its
/// log-probability. A request that fails validation, or a policy output that is not finite,
/// gets the zero action and `ACT_REJECTED`, counted in `stats`. Everything but the two
/// timestamps, which are the caller's. (Pure, so the fuzz target `link_messages` reaches it.)
pub fn respond<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
>(
    policy: &Actor<OBS, ACT, TRI, H1, H2>,
    request: &ObsMsg,
    applied: u64,
    stats: &mut ControllerStats,
    reply: &mut ActMsg,
) {
    respond_with::<OBS, ACT, TRI, _>(policy, request, applied, stats, reply);
}

/// [`respond`] with a policy network of any form.
pub fn respond_with<const OBS: usize, const ACT: usize, const TRI: usize, P>(
    policy: &P,
    request: &ObsMsg,
    applied: u64,
    stats: &mut ControllerStats,
    reply: &mut ActMsg,
) where
    P: PolicyNet<OBS, ACT, TRI>,
{
    reply.seq = request.seq;
    reply.generation = applied;
    reply.len = ACT as u32;
    reply.log_prob = 0.0;
    reply.action = [0.0; crate::messages::MAX_ACT];
    match request.validate(OBS) {
        Err(e) => {
            stats.rejections.count(e);
            reply.flags = ACT_REJECTED;
        }
        Ok(o) => {
            let obs: &[f32; OBS] = o.try_into().expect("validated length");
            let a: &mut [f32; ACT] = (&mut reply.action[..ACT]).try_into().expect("ACT");
            if request.flags & OBS_SAMPLE != 0 {
                let d = policy.distribution(obs, request.std_floor);
                let z: &[f32; ACT] = request.noise[..ACT].try_into().expect("ACT");
                d.transform(z, a);
                reply.log_prob = d.log_prob(a);
                reply.flags = ACT_SAMPLED;
            } else {
                policy.mean_action(obs, a);
                reply.flags = 0;
            }
            if !a.iter().all(|x| x.is_finite()) || !reply.log_prob.is_finite() {
                // A policy that produces NaN must not drive the plant.
                stats.rejections.count(Reject::NonFinite);
                reply.action = [0.0; crate::messages::MAX_ACT];
                reply.flags = ACT_REJECTED;
            }
        }
    }
    reply.rejected = stats.rejections.total().min(u32::MAX as u64) as u32;
}

/// Calls `$f::<OBS, ACT, TRI, H1, H2>($args)` for the policy profile named `$name`, or
/// evaluates `$unknown` for an unknown name. The one table of sizes the controller supports.
#[macro_export]
macro_rules! with_profile {
    ($name:expr, $f:ident ( $($args:expr),* ), $unknown:expr) => {
        match $name {
            "cartpole-256" => $f::<5, 1, 1, 256, 256>($($args),*),
            "cartpole-64" => $f::<5, 1, 1, 64, 64>($($args),*),
            "hopper-256" => $f::<15, 4, 10, 256, 256>($($args),*),
            "hopper-64" => $f::<15, 4, 10, 64, 64>($($args),*),
            _ => $unknown,
        }
    };
}

/// Names accepted by [`with_profile!`] (task, hidden width).
pub const PROFILES: [&str; 4] = ["cartpole-256", "cartpole-64", "hopper-256", "hopper-64"];
