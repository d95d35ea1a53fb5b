//! MPO learns small problems with known optima, deterministically, in seconds: a 1-D and a
//! 4-D continuous bandit and a linear-quadratic point mass (compared with the LQR policy).
//!
//! The loop is the product's in miniature: act with the sampled online policy, store in the
//! ring-buffer replay, sample uniform batches, update, evaluate the mean action.

#![allow(clippy::needless_range_loop)]

use mpo_core::config::MpoConfig;
use mpo_core::learner::Learner;
use mpo_core::params::fingerprint;
use mpo_core::replay::{BatchMode, Replay, Transition};
use mpo_core::rng::Rng;

/// An episodic problem.
trait Problem<const OBS: usize, const ACT: usize> {
    fn reset(&mut self, rng: &mut Rng) -> [f32; OBS];
    /// Next observation, reward, terminal.
    fn step(&mut self, a: &[f32; ACT]) -> ([f32; OBS], f32, bool);
    /// Steps before the time limit truncates an episode.
    const HORIZON: usize;
}

const CAP: usize = 1 << 15;

/// The learner of these tests: 32-32 networks, 4 chunks of 16 rows, 20 E-step samples, 10
/// next-action samples.
type Small<const OBS: usize, const ACT: usize, const TRI: usize> =
    Learner<OBS, ACT, TRI, 32, 32, 32, 32, 16, 4, 1, 20, 10>;

/// Trains for `env_steps` environment steps (one update per step after `warmup`) and returns
/// the learner.
fn train<P, const OBS: usize, const ACT: usize, const TRI: usize>(
    p: &mut P,
    cfg: MpoConfig,
    seed: u64,
    env_steps: usize,
    warmup: usize,
) -> Box<Small<OBS, ACT, TRI>>
where
    P: Problem<OBS, ACT>,
{
    let mut l: Box<Small<OBS, ACT, TRI>> = bytemuck::zeroed_box();
    l.init(cfg, seed).unwrap();
    let mut replay: Box<Replay<CAP, OBS, ACT>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(seed ^ 0x5eed);
    let mut obs = p.reset(&mut rng);
    replay.begin_episode();
    let mut t = 0;
    for step in 0..env_steps {
        let mut a = [0f32; ACT];
        let logp = l.sample_action(&obs, &mut rng, &mut a);
        let (next, r, terminal) = p.step(&a);
        t += 1;
        replay.push(&Transition {
            obs,
            action: a,
            reward: r,
            next_obs: next,
            discount: if terminal { 0.0 } else { 1.0 },
            behaviour_log_prob: logp,
        });
        obs = next;
        if terminal || t == P::HORIZON {
            obs = p.reset(&mut rng);
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
        }
    }
    l
}

/// Mean undiscounted return of the mean action over `episodes` from evaluation seeds.
fn evaluate<P, const OBS: usize, const ACT: usize>(
    p: &mut P,
    policy: &dyn Fn(&[f32; OBS]) -> [f32; ACT],
    episodes: usize,
) -> f64
where
    P: Problem<OBS, ACT>,
{
    let mut rng = Rng::seed_from_u64(1_000_003);
    let mut total = 0f64;
    for _ in 0..episodes {
        let mut obs = p.reset(&mut rng);
        for _ in 0..P::HORIZON {
            let (next, r, terminal) = p.step(&policy(&obs));
            total += r as f64;
            obs = next;
            if terminal {
                break;
            }
        }
    }
    total / episodes as f64
}

/// One-step bandit: reward `1 - |a - a*|^2`, best return 1.
struct Bandit<const ACT: usize> {
    best: [f32; ACT],
}

impl<const ACT: usize> Problem<1, ACT> for Bandit<ACT> {
    const HORIZON: usize = 1;
    fn reset(&mut self, _: &mut Rng) -> [f32; 1] {
        [1.0]
    }
    fn step(&mut self, a: &[f32; ACT]) -> ([f32; 1], f32, bool) {
        let d2: f32 = a
            .iter()
            .zip(&self.best)
            .map(|(x, y)| (x - y) * (x - y))
            .sum();
        ([1.0], 1.0 - d2, true)
    }
}

fn bandit_cfg() -> MpoConfig {
    MpoConfig {
        actor_lr: 1e-3,
        critic_lr: 1e-3,
        target_period: 25,
        actor_clip: 40.0,
        ..MpoConfig::REPORT
    }
}

#[test]
fn one_dimensional_bandit() {
    let mut p = Bandit::<1> { best: [0.6] };
    let l = train::<_, 1, 1, 1>(&mut p, bandit_cfg(), 1, 1200, 200);
    let ret = evaluate(
        &mut p,
        &|o| {
            let mut a = [0f32; 1];
            l.mean_action(o, &mut a);
            a
        },
        1,
    );
    eprintln!("1-D bandit: return {ret:.4} (optimum 1.0)");
    assert!(ret >= 0.95, "return {ret}");
}

#[test]
fn four_dimensional_bandit_deterministically() {
    let run = || {
        let mut p = Bandit::<4> {
            best: [0.5, -0.3, 0.2, -0.6],
        };
        let l = train::<_, 1, 4, 10>(&mut p, bandit_cfg(), 2, 1500, 200);
        let ret = evaluate(
            &mut p,
            &|o| {
                let mut a = [0f32; 4];
                l.mean_action(o, &mut a);
                a
            },
            1,
        );
        (ret, fingerprint(&l.live.actor), fingerprint(&l.live.critic))
    };
    let (ret, fa, fc) = run();
    eprintln!("4-D bandit: return {ret:.4} (optimum 1.0; untrained about 0.26)");
    assert!(ret >= 0.95, "return {ret}");
    assert_eq!(run(), (ret, fa, fc), "a second run differs");
}

/// Point mass on a plane, driven by its velocity: `p' = p + dt a`, reward
/// `-(|p|^2 + 0.1 |a|^2)`, 40-step episodes from uniform initial positions (a time limit, not a
/// terminal). Linear dynamics, quadratic cost: the optimum is linear state feedback from the
/// discounted Riccati equation.
struct PointMass {
    p: [f32; 2],
}

const DT: f32 = 0.2;
const R_A: f64 = 0.1;

impl Problem<2, 2> for PointMass {
    const HORIZON: usize = 40;
    fn reset(&mut self, rng: &mut Rng) -> [f32; 2] {
        self.p = [rng.uniform_range(-1.0, 1.0), rng.uniform_range(-1.0, 1.0)];
        self.p
    }
    fn step(&mut self, a: &[f32; 2]) -> ([f32; 2], f32, bool) {
        let [x, y] = self.p;
        let r = -(x * x + y * y + R_A as f32 * (a[0] * a[0] + a[1] * a[1]));
        self.p = [x + DT * a[0], y + DT * a[1]];
        (self.p, r, false)
    }
}

/// Discounted LQR gain for one axis (`a = -k p`): iterate the scalar Riccati equation
/// `P = 1 + gamma P - gamma^2 P^2 dt^2 / (R + gamma P dt^2)` to convergence.
fn lqr_gain(gamma: f64) -> f64 {
    let dt = DT as f64;
    let mut p = 1.0;
    for _ in 0..100_000 {
        p = 1.0 + gamma * p - (gamma * p * dt).powi(2) / (R_A + gamma * p * dt * dt);
    }
    gamma * p * dt / (R_A + gamma * p * dt * dt)
}

#[test]
fn linear_quadratic_point_mass_reaches_lqr_performance() {
    let cfg = MpoConfig {
        actor_lr: 1e-3,
        critic_lr: 1e-3,
        target_period: 100,
        actor_clip: 40.0,
        gamma: 0.95,
        ..MpoConfig::REPORT
    };
    let k = lqr_gain(cfg.gamma as f64);
    let mut p = PointMass { p: [0.0; 2] };
    let lqr = evaluate(&mut p, &|s| s.map(|x| (-k * x as f64) as f32), 50);
    let zero = evaluate(&mut p, &|_| [0.0; 2], 50);
    let l = train::<_, 2, 2, 3>(&mut p, cfg, 3, 10_000, 500);
    let mpo = evaluate(
        &mut p,
        &|o| {
            let mut a = [0f32; 2];
            l.mean_action(o, &mut a);
            a
        },
        50,
    );
    eprintln!("point mass: MPO {mpo:.4}, LQR {lqr:.4}, zero action {zero:.4} (k = {k:.4})");
    assert!(mpo >= 1.05 * lqr, "MPO return {mpo} vs LQR {lqr}");
}

/// A bandit whose plant clips the action (as every Control Suite actuator does) and whose
/// best clipped action is the bound: reward `1 - (clip(a) - 1)^2`. Everything at or beyond the
/// bound earns the same, so the critic is flat there and nothing but the penalty objective
/// keeps the policy's mean inside.
struct ClippedBandit;

impl Problem<1, 1> for ClippedBandit {
    const HORIZON: usize = 1;
    fn reset(&mut self, _: &mut Rng) -> [f32; 1] {
        [1.0]
    }
    fn step(&mut self, a: &[f32; 1]) -> ([f32; 1], f32, bool) {
        let d = a[0].clamp(-1.0, 1.0) - 1.0;
        ([1.0], 1.0 - d * d, true)
    }
}

/// The penalty objective holds the mean action at the actuators' bound on a bandit whose
/// plant clips the action (so the critic is flat beyond the bound and extrapolates there),
/// where without it the mean drifts out. `eps_penalty` is 0.1, the E-step's own bound: a
/// smaller penalty budget loses to the task objective here (the sweep over `eps_penalty` with
/// this test's settings is in docs/core.md, "Proofs").
#[test]
fn action_penalization_keeps_the_mean_inside_the_bounds() {
    let mean_after = |penalize: bool| {
        let cfg = MpoConfig {
            action_penalization: penalize,
            eps_penalty: 0.1,
            ..bandit_cfg()
        };
        let l = train::<_, 1, 1, 1>(&mut ClippedBandit, cfg, 4, 3000, 200);
        let mut a = [0f32; 1];
        l.mean_action(&[1.0], &mut a);
        a[0]
    };
    let (with, without) = (mean_after(true), mean_after(false));
    eprintln!(
        "clipped bandit: mean action {with:.3} with action penalization, {without:.3} without"
    );
    assert!((0.8..=1.1).contains(&with), "penalized mean {with}");
    assert!(
        without > 1.3,
        "without the penalty the mean should drift outwards: {without}"
    );
}

/// tonic's squashed mean (`tanh_mean`): on the clipped bandit without action penalization,
/// where the plain mean drifts out to about 1.47, the squashed mean stays inside (-1, 1) by
/// construction and still goes to the bound, the best clipped action; and on the 4-D bandit
/// with one optimum near the bound (-0.9, where `tanh` is steep to invert) it learns the
/// optimum as the unbounded mean does.
#[test]
fn squashed_mean_stays_inside_the_bounds_and_learns_the_optimum() {
    let cfg = MpoConfig {
        tanh_mean: true,
        ..bandit_cfg()
    };
    let l = train::<_, 1, 1, 1>(&mut ClippedBandit, cfg, 4, 3000, 200);
    let mut a = [0f32; 1];
    l.mean_action(&[1.0], &mut a);
    eprintln!("clipped bandit, squashed mean: mean action {:.4}", a[0]);
    assert!((0.9..1.0).contains(&a[0]), "squashed mean {}", a[0]);

    let mut p = Bandit::<4> {
        best: [0.5, -0.3, 0.2, -0.9],
    };
    let l = train::<_, 1, 4, 10>(&mut p, cfg, 2, 1500, 200);
    let mut a = [0f32; 4];
    l.mean_action(&[1.0], &mut a);
    let ret = evaluate(&mut p, &|_| a, 1);
    eprintln!("4-D bandit, squashed mean: {a:?}, return {ret:.4}");
    assert!(ret >= 0.95, "return {ret}");
    assert!(a.iter().all(|x| x.abs() < 1.0));
}
