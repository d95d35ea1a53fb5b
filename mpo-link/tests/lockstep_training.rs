//! Lockstep training through the controller process equals in-process training bit for bit.
//!
//! The product's loop in miniature (as in `mpo-core/tests/learning.rs`), at cartpole sizes
//! with 64-64 networks on a 1-D point mass: act with the sampled policy, store, update, and
//! (on the IPC path) push the new policy to the controller after every update. The in-process
//! path samples with `Learner::sample_action`; the IPC path draws the same noise with the same
//! RNG and lets the controller compute the action and log-probability. Same seed, same bits:
//! every action, every log-probability, and the final fingerprints of actor and critic.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use mpo_core::config::MpoConfig;
use mpo_core::learner::Learner;
use mpo_core::params::fingerprint;
use mpo_core::replay::{BatchMode, Replay, Transition};
use mpo_core::rng::Rng;
use mpo_link::{Plant, PlantConfig, RunId, WaitMode};

type L = Learner<5, 1, 1, 64, 64, 64, 64, 16, 2, 1, 20, 10>;

/// 1-D point mass, velocity control: observation `[x, 0, 0, 0, 0]`, reward `-x^2 - 0.1 a^2`.
struct PointMass {
    x: f32,
}

impl PointMass {
    fn reset(&mut self, rng: &mut Rng) -> [f32; 5] {
        self.x = rng.uniform_range(-1.0, 1.0);
        [self.x, 0.0, 0.0, 0.0, 0.0]
    }
    fn step(&mut self, a: f32) -> ([f32; 5], f32) {
        let r = -self.x * self.x - 0.1 * a * a;
        self.x = (self.x + 0.1 * a.clamp(-1.0, 1.0)).clamp(-2.0, 2.0);
        ([self.x, 0.0, 0.0, 0.0, 0.0], r)
    }
}

/// Acting: in process, or through a plant.
enum Acting<'a> {
    InProcess,
    Ipc(&'a mut Plant),
}

/// Trains for `steps` environment steps (updates after `warmup`), returns the learner and a
/// hash of every action and log-probability taken.
fn train(mut acting: Acting, steps: usize, warmup: usize) -> (Box<L>, u64) {
    let cfg = MpoConfig {
        target_period: 25,
        ..MpoConfig::REPORT
    };
    let mut l: Box<L> = bytemuck::zeroed_box();
    l.init(cfg, 9).unwrap();
    let mut replay: Box<Replay<4096, 5, 1>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(0x5eed);
    let mut env = PointMass { x: 0.0 };
    let mut obs = env.reset(&mut rng);
    replay.begin_episode();
    if let Acting::Ipc(plant) = &mut acting {
        plant.push_params(&l.live.actor).unwrap();
    }
    let mut trace = 0xcbf2_9ce4_8422_2325u64;
    let mut t = 0;
    for step in 0..steps {
        let mut a = [0f32; 1];
        let logp = match &mut acting {
            Acting::InProcess => l.sample_action(&obs, &mut rng, &mut a),
            Acting::Ipc(plant) => {
                let mut z = [0f32; 1];
                rng.fill_normal(&mut z);
                let r = plant
                    .act_sampled(&obs, &z, cfg.std_floor, &mut a)
                    .expect("lockstep: every request answered");
                assert_eq!(r.generation, plant.generation(), "stale policy used");
                r.log_prob.unwrap()
            }
        };
        for v in [a[0], logp] {
            trace = (trace ^ v.to_bits() as u64).wrapping_mul(0x0000_0100_0000_01b3);
        }
        let (next, r) = env.step(a[0]);
        t += 1;
        replay.push(&Transition {
            obs,
            action: a,
            reward: r,
            next_obs: next,
            discount: 1.0,
            behaviour_log_prob: logp,
        });
        obs = next;
        if t == 20 {
            obs = env.reset(&mut rng);
            replay.begin_episode();
            t = 0;
        }
        if step >= warmup {
            let mode = BatchMode::OneStep {
                n: 1,
                gamma: cfg.gamma,
            };
            replay.fill_batch(&mut rng, &mut l.batch, mode).unwrap();
            l.update().unwrap();
            if let Acting::Ipc(plant) = &mut acting {
                plant.push_params(&l.live.actor).unwrap();
            }
        }
    }
    (l, trace)
}

/// Stops the controller if the test fails half-way (it would otherwise outlive the test and
/// hold the test's stderr open): SIGTERM so it removes its files, SIGKILL after 2 s.
struct Guard(std::process::Child);

impl Drop for Guard {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            // SAFETY: plain kill(2) on our own child.
            unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
            let t0 = std::time::Instant::now();
            while let Ok(None) = self.0.try_wait() {
                if t0.elapsed() > Duration::from_secs(2) {
                    let _ = self.0.kill();
                    let _ = self.0.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(2));
            }
        }
    }
}

#[test]
fn lockstep_training_through_the_controller_equals_in_process_training() {
    let (steps, warmup) = (160, 40);
    let (local, local_trace) = train(Acting::InProcess, steps, warmup);

    let run = RunId::new();
    let mut ctl = Guard(
        Command::new(env!("CARGO_BIN_EXE_mpo-controller"))
            .args([
                "--run",
                run.as_str(),
                "--profile",
                "cartpole-64",
                "--seed",
                "1",
            ])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut out = BufReader::new(ctl.0.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    assert_eq!(line.trim(), "ready");
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: 5,
            act_len: 1,
            wait: WaitMode::Event,
            deadline: Duration::from_secs(2),
            spin: Duration::ZERO,
        },
    )
    .unwrap();
    let (ipc, ipc_trace) = train(Acting::Ipc(&mut plant), steps, warmup);

    // Training happened (the policy moved) ...
    let mut fresh: Box<L> = bytemuck::zeroed_box();
    fresh.init(local.cfg, 9).unwrap();
    assert_ne!(
        fingerprint(&local.live.actor),
        fingerprint(&fresh.live.actor)
    );
    // ... and both paths took the same actions and ended with the same bits.
    assert_eq!(ipc_trace, local_trace);
    assert_eq!(fingerprint(&ipc.live.actor), fingerprint(&local.live.actor));
    assert_eq!(
        fingerprint(&ipc.live.critic),
        fingerprint(&local.live.critic)
    );

    let s = plant.stats();
    assert_eq!((s.replies, s.misses), (steps as u64, 0));
    assert_eq!(s.pushes, (steps - warmup + 1) as u64);

    // SAFETY: plain kill(2) on our own child.
    unsafe { libc::kill(ctl.0.id() as i32, libc::SIGTERM) };
    assert!(ctl.0.wait().unwrap().success());
    drop(plant);
    assert!(run.files().is_empty(), "{:?}", run.files());
}
