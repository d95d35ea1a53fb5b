//! `mpo train --device CMD`: the learner on a device, the plant here, framed records between
//! them over the device's standard input and output (a pipe here; a serial line in the field).
//!
//! The device (`freestanding/trainer`) holds the whole agent: learner, replay, the acting and
//! sampling streams, the schedule. The host steps MuJoCo, sends each outcome and receives the
//! next action; it evaluates through the device (`EVAL`, the mean action) and fetches the
//! parameters at every evaluation for the checkpoint and the run's `params_sha256`. Frames and
//! their recovery are `mpo-frames` (docs/device.md): every request is sent again, same sequence
//! number, until a verified reply with that number comes back, so damaged, truncated or lost
//! frames on either side are counted and recovered from, never acted on twice.

use std::io::{Read, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver as Rx, RecvTimeoutError, SyncSender, sync_channel};
use std::time::Duration;

use mpo_core::agent::AgentSchedule;
use mpo_core::config::MpoConfig;
use mpo_frames::{
    COUNTERS_LEN, Counters, Event, Fault, Receiver, START_LEN, encode, encoded_max, f32_at,
    get_f32s, kind, put_f32s, u32_at,
};
use serde::{Deserialize, Serialize};

// The frame layout's count of configuration words is the core's (the frames crate does not
// depend on the core).
const _: () = assert!(mpo_frames::CONFIG_FIELDS == mpo_core::config::CONFIG_WORDS);

/// Largest payload the host accepts (the parameters of the largest learner a device holds).
const MAX_PAYLOAD: usize = 60_000;
/// The host's receive buffer (one encoded frame).
const RX_CAP: usize = encoded_max(MAX_PAYLOAD);
/// Attempts per request before the device counts as not answering.
const ATTEMPTS: u32 = 50;

/// Why the device run failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DeviceError {
    /// The program could not be started.
    #[error("cannot start the device program `{cmd}`")]
    Spawn {
        /// The command.
        cmd: String,
        /// Why.
        source: std::io::Error,
    },
    /// The device's output ended (it exited or was killed).
    #[error("the device stopped ({status}) after {requests} requests")]
    Died {
        /// How it ended.
        status: String,
        /// Requests answered before.
        requests: u64,
    },
    /// No verified answer after every attempt.
    #[error(
        "the device did not answer a {what} request after {ATTEMPTS} attempts ({timeout_s} s each)"
    )]
    NoAnswer {
        /// The request.
        what: &'static str,
        /// Seconds per attempt.
        timeout_s: f64,
    },
    /// The device refused a request as invalid (not a transport fault).
    #[error("the device refused a {what} request: {fault:?}")]
    Refused {
        /// The request.
        what: &'static str,
        /// Its code.
        fault: Fault,
    },
    /// The device holds a learner of other sizes than this run's row.
    #[error("the device reports {got}; this run needs {want}")]
    Mismatch {
        /// What the device reports.
        got: String,
        /// What the run needs.
        want: String,
    },
    /// Writing to the device failed.
    #[error("writing to the device")]
    Io(#[from] std::io::Error),
}

/// What the link counted, for the run's summary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DeviceReport {
    /// Requests sent (each counted once, whatever its attempts).
    pub requests: u64,
    /// Requests sent again (after a damaged, rejected or missing reply).
    pub retries: u64,
    /// Frames from the device the host rejected (checksum, length, kind).
    pub rejected_by_host: u64,
    /// Frames from the host the device rejected (its counter).
    pub rejected_by_device: u64,
    /// Repeated requests the device answered again (its counter).
    pub repeats_answered: u64,
    /// Replies with a stale sequence number, ignored.
    pub stale: u64,
}

/// What one attempt at a request got back.
enum Reply {
    Frame(u8, u8, Vec<u8>),
    Rejected,
}

/// A running device program and the protocol's state.
pub struct Device {
    child: Child,
    stdin: ChildStdin,
    replies: Rx<Reply>,
    seq: u8,
    timeout: Duration,
    /// Counters for the summary.
    pub report: DeviceReport,
    obs: usize,
    act: usize,
    params: usize,
    /// A hook for the tests (`MPO_TEST_DAMAGE_EVERY=n`): every `n`-th frame the host sends is
    /// damaged, a flipped byte and a truncation in turn.
    damage_every: Option<u64>,
}

impl Device {
    /// Starts `cmd` (a program and its arguments, split at whitespace: no shell quoting; a
    /// pipeline goes in a script), asks for its sizes and checks them against `obs`, `act`
    /// and `params`.
    pub fn start(
        cmd: &str,
        obs: usize,
        act: usize,
        params: usize,
        timeout: Duration,
    ) -> Result<Self, DeviceError> {
        let mut words = cmd.split_whitespace();
        let program = words.next().unwrap_or_default();
        let mut child = Command::new(program)
            .args(words)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|source| DeviceError::Spawn {
                cmd: cmd.to_string(),
                source,
            })?;
        let stdin = child.stdin.take().expect("piped");
        let stdout = child.stdout.take().expect("piped");
        let (tx, replies) = sync_channel(16);
        let damage_replies = test_hook("MPO_TEST_DAMAGE_REPLIES_EVERY");
        std::thread::Builder::new()
            .name("mpo-device-reader".into())
            .spawn(move || read_frames(stdout, obs, act, params, damage_replies, tx))
            .map_err(|source| DeviceError::Spawn {
                cmd: cmd.to_string(),
                source,
            })?;
        let damage_every = test_hook("MPO_TEST_DAMAGE_EVERY");
        let mut d = Self {
            child,
            stdin,
            replies,
            seq: 0,
            timeout,
            report: DeviceReport::default(),
            obs,
            act,
            params,
            damage_every,
        };
        let info = d.request("HELLO", kind::HELLO, &[], kind::INFO)?;
        let (o, a, p) = (
            u16::from_le_bytes([info[2], info[3]]) as usize,
            u16::from_le_bytes([info[4], info[5]]) as usize,
            u32_at(&info, 6) as usize,
        );
        if (o, a, p) != (obs, act, params) {
            return Err(DeviceError::Mismatch {
                got: format!("{o} observations, {a} actions, {p} parameters"),
                want: format!("{obs} observations, {act} actions, {params} parameters"),
            });
        }
        Ok(d)
    }

    /// Starts a fresh run on the device with this configuration, schedule and seed.
    pub fn configure(
        &mut self,
        cfg: &MpoConfig,
        schedule: &AgentSchedule,
        seed: u32,
    ) -> Result<(), DeviceError> {
        let mut b = vec![0u8; START_LEN];
        b[0..8].copy_from_slice(&schedule.warmup_steps.to_le_bytes());
        b[8..16].copy_from_slice(&schedule.update_interval.to_le_bytes());
        b[16..24].copy_from_slice(&schedule.updates_per_interval.to_le_bytes());
        b[24..28].copy_from_slice(&schedule.n_step.to_le_bytes());
        b[28..32].copy_from_slice(&seed.to_le_bytes());
        for (i, w) in cfg.to_words().iter().enumerate() {
            b[32 + 4 * i..36 + 4 * i].copy_from_slice(&w.to_le_bytes());
        }
        self.request("START", kind::START, &b, kind::ACK)?;
        Ok(())
    }

    /// The first action of an episode, for its first observation (and its log-density).
    pub fn begin(&mut self, obs: &[f32], action: &mut [f32]) -> Result<f32, DeviceError> {
        let mut b = vec![0u8; 4 * self.obs];
        put_f32s(obs, &mut b);
        let r = self.request("BEGIN", kind::BEGIN, &b, kind::ACTION)?;
        Ok(self.action(&r, action))
    }

    /// The outcome of the last action; the next action, unless `last` ends the episode.
    pub fn step(
        &mut self,
        reward: f32,
        discount: f32,
        last: bool,
        next_obs: &[f32],
        action: &mut [f32],
    ) -> Result<Option<f32>, DeviceError> {
        let mut b = vec![0u8; 9 + 4 * self.obs];
        b[0..4].copy_from_slice(&mpo_frames::f32_bytes(reward));
        b[4..8].copy_from_slice(&mpo_frames::f32_bytes(discount));
        b[8] = last as u8;
        put_f32s(next_obs, &mut b[9..]);
        if last {
            self.request("STEP", kind::STEP, &b, kind::ACK)?;
            Ok(None)
        } else {
            let r = self.request("STEP", kind::STEP, &b, kind::ACTION)?;
            Ok(Some(self.action(&r, action)))
        }
    }

    /// The mean action for `obs` (evaluation; changes nothing on the device).
    pub fn eval(&mut self, obs: &[f32], action: &mut [f32]) -> Result<(), DeviceError> {
        let mut b = vec![0u8; 4 * self.obs];
        put_f32s(obs, &mut b);
        let r = self.request("EVAL", kind::EVAL, &b, kind::ACTION)?;
        self.action(&r, action);
        Ok(())
    }

    /// The device's counters and its parameters (actor, then critic) into `out`.
    pub fn params(&mut self, out: &mut [f32]) -> Result<Counters, DeviceError> {
        let r = self.request("PARAMS", kind::PARAMS, &[], kind::PARAMS_REPLY)?;
        let c = Counters::decode(&r);
        get_f32s(&r[COUNTERS_LEN..], out);
        self.absorb(&c);
        Ok(c)
    }

    fn action(&self, r: &[u8], action: &mut [f32]) -> f32 {
        get_f32s(&r[..4 * self.act], action);
        f32_at(r, 4 * self.act)
    }

    fn absorb(&mut self, c: &Counters) {
        self.report.rejected_by_device = c.rejected as u64;
        self.report.repeats_answered = c.resent as u64;
    }

    /// Sends a request until a verified reply of kind `want` with its sequence number comes
    /// back; returns the reply's payload.
    // One retry loop: send, wait, verify, resend on a timeout or a damaged reply, give up
    // after the limit; its states share the counters of the report, so it stays in one piece.
    fn request(
        &mut self,
        what: &'static str,
        k: u8,
        payload: &[u8],
        want: u8,
    ) -> Result<Vec<u8>, DeviceError> {
        self.seq = self.seq.wrapping_add(1);
        self.report.requests += 1;
        let mut frame = vec![0u8; encoded_max(payload.len())];
        let n = encode(k, self.seq, payload, &mut frame);
        frame.truncate(n);
        for attempt in 0..ATTEMPTS {
            if attempt > 0 {
                self.report.retries += 1;
            }
            self.send(&frame)?;
            loop {
                match self.replies.recv_timeout(self.timeout) {
                    Ok(Reply::Rejected) => {
                        self.report.rejected_by_host += 1;
                        break; // ask again
                    }
                    Ok(Reply::Frame(_, rs, _)) if rs != self.seq => {
                        // A late copy of an earlier reply, or a damaged frame's `ERROR`.
                        self.report.stale += 1;
                    }
                    Ok(Reply::Frame(kind::ERROR, _, p)) => {
                        let fault = Fault::from_code(p[0]).unwrap_or(Fault::Invalid);
                        self.absorb(&Counters::decode(&p[1..]));
                        match fault {
                            Fault::Invalid | Fault::OutOfOrder => {
                                return Err(DeviceError::Refused { what, fault });
                            }
                            _ => break, // our frame arrived damaged: send it again
                        }
                    }
                    Ok(Reply::Frame(rk, _, p)) if rk == want => {
                        if rk == kind::ACK {
                            self.absorb(&Counters::decode(&p));
                        }
                        return Ok(p);
                    }
                    Ok(Reply::Frame(..)) => {
                        self.report.stale += 1;
                    }
                    Err(RecvTimeoutError::Timeout) => break,
                    Err(RecvTimeoutError::Disconnected) => {
                        let status = match self.child.wait() {
                            Ok(s) => s.to_string(),
                            Err(e) => format!("status unknown: {e}"),
                        };
                        return Err(DeviceError::Died {
                            status,
                            requests: self.report.requests - 1,
                        });
                    }
                }
            }
        }
        Err(DeviceError::NoAnswer {
            what,
            timeout_s: self.timeout.as_secs_f64(),
        })
    }

    /// Writes a frame (damaged on purpose when the test hook asks for it: a flipped byte, or
    /// only the first half of the frame, in turn).
    fn send(&mut self, frame: &[u8]) -> Result<(), DeviceError> {
        let sent = self.report.requests + self.report.retries;
        match self.damage_every {
            Some(n) if sent.is_multiple_of(n) && (sent / n).is_multiple_of(2) => {
                let mut bad = frame.to_vec();
                let i = (sent as usize * 7) % (bad.len() - 1); // never the delimiter
                bad[i] = match bad[i] ^ 0x10 {
                    0 => 0x55,
                    b => b,
                };
                self.stdin.write_all(&bad)?;
            }
            Some(n) if sent.is_multiple_of(n) => self.stdin.write_all(&frame[..frame.len() / 2])?,
            _ => self.stdin.write_all(frame)?,
        }
        Ok(self.stdin.flush()?)
    }

    /// The parameter count the device holds.
    pub fn param_count(&self) -> usize {
        self.params
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A positive count from a test hook's environment variable.
fn test_hook(var: &str) -> Option<u64> {
    std::env::var(var)
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n| n > 0)
}

/// The reader thread: bytes from the device into verified frames (or rejections). With
/// `damage` (a test hook), every `n`-th frame from the device has its fourth byte flipped or
/// dropped, in turn, before the receiver sees it.
fn read_frames(
    mut out: impl Read,
    obs: usize,
    act: usize,
    params: usize,
    damage: Option<u64>,
    tx: SyncSender<Reply>,
) {
    let mut rx = Box::new(Receiver::<RX_CAP>::new(obs, act, params));
    let mut buf = [0u8; 4096];
    let (mut frame_no, mut pos) = (1u64, 0usize);
    loop {
        let n = match out.read(&mut buf) {
            Ok(0) | Err(_) => return, // the sender hangs up: the device is gone
            Ok(n) => n,
        };
        for &b in &buf[..n] {
            let mut b = b;
            if let Some(k) = damage
                && frame_no.is_multiple_of(k)
                && pos == 3
                && b != mpo_frames::DELIMITER
            {
                if (frame_no / k) % 2 == 0 {
                    b = match b ^ 0x10 {
                        0 => 0x55,
                        x => x,
                    };
                } else {
                    pos += 1;
                    continue;
                }
            }
            pos += 1;
            if b == mpo_frames::DELIMITER {
                frame_no += 1;
                pos = 0;
            }
            let reply = match rx.push(b) {
                Event::Pending => continue,
                Event::Frame(k, s) => Reply::Frame(k, s, rx.payload().to_vec()),
                Event::Rejected(_) => Reply::Rejected,
            };
            if tx.send(reply).is_err() {
                return;
            }
        }
    }
}
