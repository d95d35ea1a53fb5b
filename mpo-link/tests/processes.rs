//! The link between real processes: the `mpo-controller` binary on one side, a `Plant` in the
//! test process on the other.

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_link::messages::{CHUNK, ObsMsg, ParamChunk};
use mpo_link::{Miss, Plant, PlantConfig, RunId, WaitMode};

type Hopper = Actor<15, 4, 10, 64, 64>;

/// A controller process; killed on drop if still running.
struct Controller {
    child: Child,
    out: BufReader<ChildStdout>,
}

impl Controller {
    fn spawn(run: &RunId, profile: &str, wait: &str, seed: u64) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_mpo-controller"))
            .args(["--run", run.as_str(), "--profile", profile, "--wait", wait])
            .args(["--seed", &seed.to_string()])
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn mpo-controller");
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        out.read_line(&mut line).unwrap();
        assert_eq!(line.trim(), "ready", "controller did not come up");
        Self { child, out }
    }

    fn signal(&self, sig: i32) {
        // SAFETY: plain kill(2) on our own child.
        assert_eq!(unsafe { libc::kill(self.child.id() as i32, sig) }, 0);
    }

    /// Waits for the exit (at most 5 s) and returns the exit success and the `stats` line.
    fn wait_exit(mut self) -> (bool, String) {
        let t0 = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                let mut rest = String::new();
                let _ = std::io::Read::read_to_string(&mut self.out, &mut rest);
                return (status.success(), rest);
            }
            assert!(
                t0.elapsed() < Duration::from_secs(5),
                "controller did not exit"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

impl Drop for Controller {
    /// SIGTERM (so the run's files go), SIGKILL after 2 s.
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // SAFETY: plain kill(2) on our own child.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            let t0 = Instant::now();
            while let Ok(None) = self.child.try_wait() {
                if t0.elapsed() > Duration::from_secs(2) {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(2));
            }
        }
    }
}

fn plant(run: &RunId, obs: usize, act: usize, wait: WaitMode) -> Plant {
    Plant::open(
        run,
        PlantConfig {
            obs_len: obs,
            act_len: act,
            wait,
            // Generous: the test binaries are debug builds on a shared machine.
            deadline: Duration::from_millis(500),
            spin: Duration::ZERO,
        },
    )
    .unwrap()
}

fn policy<const H: usize>(seed: u64) -> Box<Actor<15, 4, 10, H, H>> {
    let mut p: Box<Actor<15, 4, 10, H, H>> = bytemuck::zeroed_box();
    p.init(&mut Rng::seed_from_u64(seed), 1.0, 1e-4);
    p
}

fn random_obs(rng: &mut Rng) -> [f32; 15] {
    let mut o = [0f32; 15];
    for x in &mut o {
        *x = rng.uniform_range(-3.0, 3.0);
    }
    o
}

fn stat(line: &str, key: &str) -> u64 {
    line.split_whitespace()
        .find_map(|kv| kv.strip_prefix(&format!("{key}=")))
        .unwrap_or_else(|| panic!("{key} missing in {line:?}"))
        .parse()
        .unwrap()
}

/// Mean actions, sampled actions and log-probabilities through the controller equal the
/// in-process ones bit for bit: with the controller's own initial policy, and after a push.
fn round_trip<const H: usize>(profile: &str, wait: WaitMode) {
    let run = RunId::new();
    let ctl = Controller::spawn(&run, profile, wait.name(), 3);
    let mut plant = plant(&run, 15, 4, wait);
    let mut rng = Rng::seed_from_u64(11);
    let mut check = |plant: &mut Plant, p: &Actor<15, 4, 10, H, H>, generation: u64| {
        for _ in 0..200 {
            let o = random_obs(&mut rng);
            let mut want = [0f32; 4];
            p.mean_action(&o, &mut want);
            let mut got = [9f32; 4];
            let a = plant.act(&o, &mut got).expect("reply in time");
            assert_eq!(a.generation, generation);
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits));
            // Sampled, with the noise drawn here exactly as `Gaussian::sample` draws it.
            let mut z = [0f32; 4];
            rng.fill_normal(&mut z);
            let d = p.distribution(&o, 1e-4);
            let mut want = [0f32; 4];
            d.transform(&z, &mut want);
            let a = plant.act_sampled(&o, &z, 1e-4, &mut got).expect("reply");
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits));
            assert_eq!(a.log_prob.unwrap().to_bits(), d.log_prob(&want).to_bits());
        }
    };
    check(&mut plant, &policy::<H>(3), 0);
    let pushed = policy::<H>(99);
    assert_eq!(plant.push_params(&*pushed).unwrap(), 1);
    check(&mut plant, &pushed, 1);
    let s = plant.stats();
    assert_eq!((s.requests, s.replies, s.misses), (800, 800, 0));
    assert_eq!(s.rejections.total(), 0);
    drop(ctl);
}

#[test]
fn round_trip_is_bit_exact_event_mode() {
    round_trip::<64>("hopper-64", WaitMode::Event);
}

#[test]
fn round_trip_is_bit_exact_busy_poll() {
    round_trip::<64>("hopper-64", WaitMode::BusyPoll);
}

#[test]
fn round_trip_is_bit_exact_hopper_256() {
    // 73,486 parameters: 18 blocks per push.
    assert_eq!(
        mpo_core::params::Params::len(&*policy::<256>(0)).div_ceil(CHUNK),
        18
    );
    round_trip::<256>("hopper-256", WaitMode::Event);
}

#[test]
fn killed_controller_gives_safe_actions_then_a_new_one_takes_over() {
    let run = RunId::new();
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: 15,
            act_len: 4,
            wait: WaitMode::Event,
            deadline: Duration::from_millis(20),
            spin: Duration::ZERO,
        },
    )
    .unwrap();
    let mut ctl = Controller::spawn(&run, "hopper-64", "event", 1);
    let p: Box<Hopper> = policy::<64>(5);
    plant.push_params(&*p).unwrap();
    let mut rng = Rng::seed_from_u64(2);
    let mut out = [0f32; 4];
    let mut want = [0f32; 4];
    for _ in 0..50 {
        let o = random_obs(&mut rng);
        // The first replies may take longer than 20 ms on a loaded machine: retry those.
        let mut tries = 0;
        while plant.act(&o, &mut out).is_err() {
            tries += 1;
            assert!(tries < 50, "controller never answered");
        }
        p.mean_action(&o, &mut want);
        assert_eq!(out, want);
    }
    // Kill -9: no chance to clean up.
    ctl.child.kill().unwrap();
    ctl.child.wait().unwrap();
    let misses_before = plant.stats().misses;
    for _ in 0..20 {
        let o = random_obs(&mut rng);
        out = [7.0; 4];
        assert_eq!(plant.act(&o, &mut out).unwrap_err(), Miss::Timeout);
        assert_eq!(out, [0.0; 4], "a miss must leave the safe (zero) action");
    }
    assert_eq!(plant.stats().misses - misses_before, 20);
    assert_eq!(plant.stats().timeouts, plant.stats().misses);
    // A new controller with a different initial policy: it must pick up the pushed parameters
    // from the service's history and answer with them.
    let ctl2 = Controller::spawn(&run, "hopper-64", "event", 77);
    let mut resumed = 0;
    for _ in 0..200 {
        let o = random_obs(&mut rng);
        if let Ok(a) = plant.act(&o, &mut out) {
            assert_eq!(a.generation, 1);
            p.mean_action(&o, &mut want);
            assert_eq!(out, want);
            resumed += 1;
        }
    }
    assert!(
        resumed >= 190,
        "only {resumed} of 200 answered after the restart"
    );
    // Even the killed controller's resources are reclaimed once the run ends.
    drop(ctl2);
    drop(plant);
    assert!(run.files().is_empty(), "left behind: {:?}", run.files());
}

#[test]
fn bad_arguments_fail_loudly() {
    let exe = env!("CARGO_BIN_EXE_mpo-controller");
    for args in [
        &["--run", "x-1", "--profile", "walker-1024"][..],
        &["--run", "bad/name"],
        &["--profile", "hopper-64"],
        &["--run", "x-1", "--wait", "busy-poll", "--realtime", "50"],
        &["--run", "x-1", "--wait", "sometimes"],
    ] {
        let out = Command::new(exe).args(args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(!out.stderr.is_empty(), "{args:?}: no message");
    }
}

#[test]
fn two_concurrent_runs_do_not_interfere() {
    let (run_a, run_b) = (RunId::new(), RunId::new());
    assert_ne!(run_a, run_b);
    let _ca = Controller::spawn(&run_a, "hopper-64", "event", 1);
    let _cb = Controller::spawn(&run_b, "hopper-64", "busy-poll", 2);
    let mut pa = plant(&run_a, 15, 4, WaitMode::Event);
    let mut pb = plant(&run_b, 15, 4, WaitMode::BusyPoll);
    let (a, b) = (policy::<64>(1), policy::<64>(2));
    let mut rng = Rng::seed_from_u64(3);
    let (mut out, mut want) = ([0f32; 4], [0f32; 4]);
    for i in 0..300 {
        let o = random_obs(&mut rng);
        let (plant, p) = if i % 2 == 0 {
            (&mut pa, &a)
        } else {
            (&mut pb, &b)
        };
        plant.act(&o, &mut out).unwrap();
        p.mean_action(&o, &mut want);
        assert_eq!(out, want);
    }
    for p in [&pa, &pb] {
        let s = p.stats();
        assert_eq!((s.replies, s.misses, s.rejections.total()), (150, 0, 0));
    }
}

fn clean_shutdown_on(sig: i32) {
    let run = RunId::new();
    let ctl = Controller::spawn(&run, "cartpole-64", "event", 0);
    let mut plant = plant(&run, 5, 1, WaitMode::Event);
    let mut out = [0f32; 1];
    for i in 0..10 {
        plant.act(&[i as f32; 5], &mut out).unwrap();
    }
    assert!(
        !run.files().is_empty(),
        "the run should have files while it runs"
    );
    ctl.signal(sig);
    let (ok, rest) = ctl.wait_exit();
    assert!(ok, "controller exit status on signal {sig}: {rest}");
    assert_eq!(stat(&rest, "answered"), 10);
    // The plant notices: misses, no hang.
    assert_eq!(plant.act(&[0.0; 5], &mut out).unwrap_err(), Miss::Timeout);
    drop(plant);
    let left = run.files();
    assert!(left.is_empty(), "files of the run left behind: {left:?}");
}

#[test]
fn sigterm_shuts_down_cleanly_and_leaves_no_files() {
    clean_shutdown_on(libc::SIGTERM);
}

#[test]
fn sigint_shuts_down_cleanly_and_leaves_no_files() {
    clean_shutdown_on(libc::SIGINT);
}

#[test]
fn busy_poll_controller_also_stops_on_sigterm() {
    let run = RunId::new();
    let ctl = Controller::spawn(&run, "cartpole-64", "busy-poll", 0);
    ctl.signal(libc::SIGTERM);
    let (ok, _) = ctl.wait_exit();
    assert!(ok);
    assert!(run.files().is_empty(), "{:?}", run.files());
}

#[test]
fn malformed_requests_and_parameter_blocks_are_rejected_and_counted() {
    let run = RunId::new();
    let ctl = Controller::spawn(&run, "hopper-64", "event", 4);
    let mut plant = plant(&run, 15, 4, WaitMode::Event);
    let p0 = policy::<64>(4);
    let deadline = Duration::from_millis(500);
    let good = {
        let mut m: ObsMsg = bytemuck::Zeroable::zeroed();
        m.len = 15;
        m.obs[..15].copy_from_slice(&[0.5; 15]);
        m
    };
    // Local checks: never sent.
    let mut out = [0f32; 4];
    assert_eq!(
        plant.act(&[f32::NAN; 15], &mut out).unwrap_err(),
        Miss::Invalid(mpo_link::messages::Reject::NonFinite)
    );
    assert_eq!(
        plant.act(&[0.0; 14], &mut out).unwrap_err(),
        Miss::Invalid(mpo_link::messages::Reject::Length)
    );
    // The controller's checks: each malformed request gets a rejection, never an action.
    let mut bad_len = good;
    bad_len.len = 14;
    let mut nan_obs = good;
    nan_obs.obs[3] = f32::NAN;
    let mut inf_noise = good;
    inf_noise.flags = mpo_link::messages::OBS_SAMPLE;
    inf_noise.noise[0] = f32::INFINITY;
    for m in [bad_len, nan_obs, inf_noise] {
        assert_eq!(plant.request_raw(m, deadline).unwrap_err(), Miss::Rejected);
    }
    // Parameter blocks: a flipped bit (checksum), a wrong total length, a NaN with a matching
    // checksum. None may change the policy.
    let mut chunk: Box<ParamChunk> = bytemuck::zeroed_box();
    let total = mpo_core::params::Params::len(&*p0);
    chunk.generation = 5;
    chunk.total_len = total as u32;
    chunk.count = total.div_ceil(CHUNK) as u32;
    chunk.len = CHUNK.min(total) as u32;
    chunk.payload[0] = 1.0;
    let n = chunk.len as usize;
    chunk.checksum =
        mpo_link::messages::checksum(mpo_link::messages::CHECKSUM_SEED, &chunk.payload[..n]) ^ 1;
    plant.send_raw_chunk(&chunk).unwrap();
    chunk.total_len += 1;
    plant.send_raw_chunk(&chunk).unwrap();
    chunk.total_len -= 1;
    chunk.payload[1] = f32::NAN;
    chunk.checksum =
        mpo_link::messages::checksum(mpo_link::messages::CHECKSUM_SEED, &chunk.payload[..n]);
    plant.send_raw_chunk(&chunk).unwrap();
    let a = plant.request_raw(good, deadline).unwrap();
    let mut want = [0f32; 4];
    p0.mean_action(&[0.5; 15], &mut want);
    assert_eq!(a.generation, 0);
    assert_eq!(a.action[..4], want);
    assert_eq!(a.seq, plant.stats().requests);
    ctl.signal(libc::SIGTERM);
    let (ok, rest) = ctl.wait_exit();
    assert!(ok);
    assert_eq!(stat(&rest, "answered"), 4);
    assert_eq!(stat(&rest, "rejected_length"), 2);
    assert_eq!(stat(&rest, "rejected_non_finite"), 3);
    assert_eq!(stat(&rest, "rejected_corrupt"), 1);
    assert_eq!(stat(&rest, "swaps"), 0);
    assert_eq!(plant.stats().rejected_by_controller, 3);
}
