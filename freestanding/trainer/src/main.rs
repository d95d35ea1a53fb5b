//! The device trainer: frames in and out over the byte stream (stdin and stdout on Linux, the
//! UART on the Cortex-M4F board: `mpo-rt`), the learner in `.bss`.
//!
//! State machine (docs/device.md): `HELLO` -> `INFO`; `START` (configuration, schedule,
//! seed) initialises the agent; `BEGIN` opens an episode and answers with the first action;
//! each `STEP` stores the transition, runs the scheduled updates and answers with the next
//! action (or `ACK` after an episode's last step); `EVAL` answers with the mean action and
//! changes nothing; `PARAMS` streams the counters and the parameters. A request with the
//! sequence number of the one before is a repeat (its reply was lost): it gets the last reply
//! again and changes nothing. A frame the device cannot use gets `ERROR` and changes nothing.
//! End of input ends the program (exit 0; a UART has none); a read or write error exits 2.
//! The measurement marks (`mpo_rt::mark_begin`/`mark_end`) bracket `act` and `observe`, so the
//! instruction counter under QEMU (benches/cortex_m.rs) sees each step and each update.
#![no_std]
#![no_main]

#[cfg(feature = "use-alloc")]
extern crate alloc;
#[cfg(feature = "use-std")]
extern crate std;

use mpo_core::agent::{Agent, AgentSchedule};
use mpo_core::config::{CONFIG_WORDS, MpoConfig};
use mpo_core::parallel::Serial;
use mpo_core::params::Params;
use mpo_core::replay::Transition;
use mpo_frames::{
    COUNTERS_LEN, Counters, Event, Fault, Receiver, START_LEN, encode, encoded_max, f32_at,
    get_f32s, kind, put_f32s, u32_at, u64_at, write_frame,
};

// The frame layout's count of configuration words is the core's.
const _: () = assert!(mpo_frames::CONFIG_FIELDS == CONFIG_WORDS);

/// The `mcu` row of the host's task table (mpo-host/src/tasks.rs): cartpole-balance.
const OBS: usize = 5;
const ACT: usize = 1;
type McuAgent = Agent<OBS, ACT, 1, 32, 32, 32, 32, 32, 1, 1, 8, 8, 1_000>;

/// Mixed into the run's seed for the collector and sampler streams (the host's `STREAM_SALT`).
const STREAM_SALT: u64 = 0x6d70_6f2d_686f_7374;

static AGENT: mpo_rt::ZeroedStatic<McuAgent> = mpo_rt::ZeroedStatic::new();

/// The learner's parameter count (actor, then critic).
fn param_count(a: &McuAgent) -> usize {
    a.learner.live.actor.len() + a.learner.live.critic.len()
}

/// Largest reply kept for repeats (`PARAMS` is regenerated instead).
const REPLY_CAP: usize = encoded_max(COUNTERS_LEN + 1);
/// The receive buffer: the largest frame the host sends is `START`.
const RX_CAP: usize = encoded_max(START_LEN);

#[derive(Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Before `START`.
    Idle,
    /// Between episodes.
    Ready,
    /// Waiting for the outcome of `action` taken in `obs`.
    Acting,
}

struct Device {
    agent: &'static mut McuAgent,
    phase: Phase,
    obs: [f32; OBS],
    action: [f32; ACT],
    log_prob: f32,
    counters: Counters,
    reply: [u8; REPLY_CAP],
    reply_len: usize,
    /// The last reply was `PARAMS` (regenerated for a repeat).
    reply_params: bool,
    /// Sequence number of the request being answered, and of the last one answered.
    seq: u8,
    last_seq: Option<u8>,
}

mpo_rt::entry!(main);

fn main() -> i32 {
    #[cfg(feature = "use-alloc")]
    core::hint::black_box(alloc::boxed::Box::new(1u8));
    let Some(agent) = AGENT.take() else { return 2 };
    let params = param_count(agent);
    let mut d = Device {
        agent,
        phase: Phase::Idle,
        obs: [0.0; OBS],
        action: [0.0; ACT],
        log_prob: 0.0,
        counters: Counters::default(),
        reply: [0; REPLY_CAP],
        reply_len: 0,
        reply_params: false,
        seq: 0,
        last_seq: None,
    };
    let mut rx = Receiver::<RX_CAP>::new(OBS, ACT, params);
    let mut inbuf = [0u8; 256];
    loop {
        let n = mpo_rt::read(0, &mut inbuf);
        if n == 0 {
            return 0;
        }
        if n < 0 {
            return 2;
        }
        for &b in &inbuf[..n as usize] {
            let ok = match rx.push(b) {
                Event::Pending => true,
                Event::Frame(_, seq) if d.last_seq == Some(seq) => d.repeat(),
                Event::Frame(k, seq) => {
                    d.seq = seq;
                    d.last_seq = Some(seq);
                    d.handle(k, rx.payload())
                }
                Event::Rejected(f) => {
                    // Damaged: the sequence number cannot be trusted; the host repeats its
                    // request, which is then new (not answered yet). This `ERROR` is not a
                    // reply to a request, so it is not kept for repeats.
                    d.counters.rejected = rx.rejected;
                    d.transport_error(f)
                }
            };
            if !ok {
                return 2;
            }
        }
    }
}

impl Device {
    /// Answers one verified frame; false on a write error.
    fn handle(&mut self, k: u8, p: &[u8]) -> bool {
        match k {
            kind::HELLO => {
                let mut b = [0u8; 14];
                b[0..2].copy_from_slice(&mpo_frames::VERSION.to_le_bytes());
                b[2..4].copy_from_slice(&(OBS as u16).to_le_bytes());
                b[4..6].copy_from_slice(&(ACT as u16).to_le_bytes());
                b[6..10].copy_from_slice(&(param_count(self.agent) as u32).to_le_bytes());
                b[10..14].copy_from_slice(&(self.agent.replay.capacity() as u32).to_le_bytes());
                self.send(kind::INFO, &b)
            }
            kind::START => self.start(p),
            kind::BEGIN if self.phase == Phase::Ready => {
                let Some(obs) = observation(p) else {
                    return self.error(Fault::Invalid);
                };
                self.agent.begin_episode();
                self.act(obs)
            }
            kind::STEP if self.phase == Phase::Acting => self.step(p),
            kind::EVAL if self.phase != Phase::Idle => {
                let Some(obs) = observation(p) else {
                    return self.error(Fault::Invalid);
                };
                let mut a = [0f32; ACT];
                self.agent.learner.mean_action(&obs, &mut a);
                self.send_action(&a, 0.0)
            }
            kind::PARAMS => self.send_params(),
            _ => self.error(Fault::OutOfOrder),
        }
    }

    /// A repeated request: the last reply again.
    fn repeat(&mut self) -> bool {
        self.counters.resent = self.counters.resent.wrapping_add(1);
        if self.reply_params {
            self.send_params()
        } else {
            mpo_rt::write_all(1, &self.reply[..self.reply_len])
        }
    }

    /// `START`: schedule, seed, configuration; a fresh agent.
    fn start(&mut self, p: &[u8]) -> bool {
        let schedule = AgentSchedule {
            warmup_steps: u64_at(p, 0),
            update_interval: u64_at(p, 8),
            updates_per_interval: u64_at(p, 16),
            n_step: u32_at(p, 24),
            // START carries no noise correlation: the host refuses one for a device.
            noise_corr: 0.0,
            noise_pink: false,
        };
        let seed = u32_at(p, 28) as u64;
        let mut w = [0u32; CONFIG_WORDS];
        for (i, x) in w.iter_mut().enumerate() {
            *x = u32_at(p, 32 + 4 * i);
        }
        let Ok(cfg) = MpoConfig::from_words(&w) else {
            return self.error(Fault::Invalid);
        };
        if self
            .agent
            .init(cfg, seed, seed ^ STREAM_SALT, schedule)
            .is_err()
        {
            return self.error(Fault::Invalid);
        }
        self.counters.env_steps = 0;
        self.counters.updates = 0;
        self.phase = Phase::Ready;
        self.ack()
    }

    /// `STEP`: store the transition, learn as scheduled, act on the next state.
    fn step(&mut self, p: &[u8]) -> bool {
        let (reward, discount, last) = (f32_at(p, 0), f32_at(p, 4), p[8]);
        let Some(next) = observation(&p[9..]) else {
            return self.error(Fault::Invalid);
        };
        if !(reward.is_finite() && discount.is_finite() && last <= 1) {
            return self.error(Fault::Invalid);
        }
        let t = Transition {
            obs: self.obs,
            action: self.action,
            reward,
            next_obs: next,
            discount,
            behaviour_log_prob: self.log_prob,
        };
        let mut updates = 0u64;
        mpo_rt::mark_begin();
        let observed = self.agent.observe(&t, &Serial, &mut |_| updates += 1);
        mpo_rt::mark_end();
        if observed.is_err() {
            // The learner undid the failing update; the host stops the run.
            return self.error(Fault::Invalid);
        }
        self.counters.env_steps = self.agent.env_steps;
        self.counters.updates += updates;
        if last == 1 {
            self.phase = Phase::Ready;
            self.ack()
        } else {
            self.act(next)
        }
    }

    fn act(&mut self, obs: [f32; OBS]) -> bool {
        self.obs = obs;
        mpo_rt::mark_begin();
        self.log_prob = self.agent.act(&obs, &mut self.action);
        mpo_rt::mark_end();
        self.phase = Phase::Acting;
        let a = self.action;
        self.send_action(&a, self.log_prob)
    }

    fn send_action(&mut self, a: &[f32; ACT], log_prob: f32) -> bool {
        let mut b = [0u8; 4 * ACT + 4];
        put_f32s(a, &mut b[..4 * ACT]);
        b[4 * ACT..].copy_from_slice(&mpo_frames::f32_bytes(log_prob));
        self.send(kind::ACTION, &b)
    }

    fn ack(&mut self) -> bool {
        let mut b = [0u8; COUNTERS_LEN];
        self.counters.encode(&mut b);
        self.send(kind::ACK, &b)
    }

    fn error_payload(&self, f: Fault) -> [u8; 1 + COUNTERS_LEN] {
        let mut b = [0u8; 1 + COUNTERS_LEN];
        b[0] = f as u8;
        let mut c = [0u8; COUNTERS_LEN];
        self.counters.encode(&mut c);
        b[1..].copy_from_slice(&c);
        b
    }

    /// `ERROR` as the reply to a verified request (kept for repeats).
    fn error(&mut self, f: Fault) -> bool {
        let b = self.error_payload(f);
        self.send(kind::ERROR, &b)
    }

    /// `ERROR` for a damaged frame: numbered as the next request would be, not kept.
    fn transport_error(&mut self, f: Fault) -> bool {
        let b = self.error_payload(f);
        let seq = self.last_seq.map_or(0, |s| s.wrapping_add(1));
        let mut out = [0u8; REPLY_CAP];
        let n = encode(kind::ERROR, seq, &b, &mut out);
        mpo_rt::write_all(1, &out[..n])
    }

    /// Encodes, keeps (for `RESEND`) and writes a small reply.
    fn send(&mut self, k: u8, payload: &[u8]) -> bool {
        self.reply_len = encode(k, self.seq, payload, &mut self.reply);
        self.reply_params = false;
        mpo_rt::write_all(1, &self.reply[..self.reply_len])
    }

    /// `PARAMS`: counters, then every parameter of the online actor and critic, streamed
    /// through a small buffer.
    fn send_params(&mut self) -> bool {
        self.reply_params = true;
        let live = &self.agent.learner.live;
        let len = COUNTERS_LEN + 4 * (live.actor.len() + live.critic.len());
        let mut c = [0u8; COUNTERS_LEN];
        self.counters.encode(&mut c);
        let mut out = Buffered {
            buf: [0; 512],
            n: 0,
        };
        let r = write_frame(
            kind::PARAMS_REPLY,
            self.seq,
            len,
            &mut |b: &[u8]| out.write(b),
            &mut |w| {
                w(&c)?;
                let mut result = Ok(());
                let mut put = |x: f32| {
                    if result.is_ok() {
                        result = w(&mpo_frames::f32_bytes(x));
                    }
                };
                live.actor.for_each(&mut put);
                live.critic.for_each(&mut put);
                result
            },
        );
        r.is_ok() && out.flush().is_ok()
    }
}

/// An observation from a payload, if every value is finite.
fn observation(p: &[u8]) -> Option<[f32; OBS]> {
    let mut o = [0f32; OBS];
    get_f32s(&p[..4 * OBS], &mut o);
    o.iter().all(|x| x.is_finite()).then_some(o)
}

/// Gathers small writes into whole-buffer system calls.
struct Buffered {
    buf: [u8; 512],
    n: usize,
}

impl Buffered {
    fn write(&mut self, mut b: &[u8]) -> Result<(), ()> {
        while !b.is_empty() {
            let k = b.len().min(self.buf.len() - self.n);
            self.buf[self.n..self.n + k].copy_from_slice(&b[..k]);
            self.n += k;
            b = &b[k..];
            if self.n == self.buf.len() {
                self.flush()?;
            }
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), ()> {
        let ok = mpo_rt::write_all(1, &self.buf[..self.n]);
        self.n = 0;
        if ok { Ok(()) } else { Err(()) }
    }
}
