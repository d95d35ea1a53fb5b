//! MPO learns small problems with known optima, deterministically, in seconds: a 1-D and a
//! 4-D continuous bandit and a linear-quadratic point mass (compared with the LQR policy).
//!
//! The loop is the product's in miniature: act with the sampled online policy, store in the
//! ring-buffer replay, sample uniform batches, update, evaluate the mean action.

use mpo_core::config::MpoConfig;
use mpo_core::learner::Learner;
use mpo_core::params::fingerprint;
use mpo_core::replay::{Replay, Transition};
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

/// Trains for `env_steps` environment steps (one update per step after `warmup`) and returns
/// the learner.
#[allow(clippy::type_complexity)]
fn train<P, const OBS: usize, const ACT: usize, const TRI: usize, const B: usize>(
    p: &mut P,
    cfg: MpoConfig,
    seed: u64,
    env_steps: usize,
    warmup: usize,
) -> Box<Learner<OBS, ACT, TRI, 32, 32, B, 20, 10>>
where
    P: Problem<OBS, ACT>,
{
    let mut l: Box<Learner<OBS, ACT, TRI, 32, 32, B, 20, 10>> = bytemuck::zeroed_box();
    l.init(cfg, seed).unwrap();
    let mut replay: Box<Replay<CAP, OBS, ACT>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(seed ^ 0x5eed);
    let mut obs = p.reset(&mut rng);
    replay.begin_episode();
    let mut t = 0;
    let mut idx = [0usize; B];
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
            replay.sample_indices(&mut rng, &mut idx).unwrap();
            let b = &mut l.batch;
            let mut disc = [0f32; B];
            replay.gather(&idx, &mut b.obs, &mut b.action, &mut b.reward, &mut b.next_obs, &mut disc);
            for n in 0..B {
                b.bootstrap[n] = cfg.gamma * disc[n];
            }
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
        let d2: f32 = a.iter().zip(&self.best).map(|(x, y)| (x - y) * (x - y)).sum();
        ([1.0], 1.0 - d2, true)
    }
}

fn bandit_cfg() -> MpoConfig {
    MpoConfig { actor_lr: 1e-3, critic_lr: 1e-3, target_period: 25, actor_clip: 40.0, ..MpoConfig::REPORT }
}

#[test]
fn one_dimensional_bandit() {
    let mut p = Bandit::<1> { best: [0.6] };
    let l = train::<_, 1, 1, 1, 64>(&mut p, bandit_cfg(), 1, 1200, 200);
    let ret = evaluate(&mut p, &|o| {
        let mut a = [0f32; 1];
        l.mean_action(o, &mut a);
        a
    }, 1);
    eprintln!("1-D bandit: return {ret:.4} (optimum 1.0)");
    assert!(ret >= 0.95, "return {ret}");
}

#[test]
fn four_dimensional_bandit_deterministically() {
    let run = || {
        let mut p = Bandit::<4> { best: [0.5, -0.3, 0.2, -0.6] };
        let l = train::<_, 1, 4, 10, 64>(&mut p, bandit_cfg(), 2, 1500, 200);
        let ret = evaluate(&mut p, &|o| {
            let mut a = [0f32; 4];
            l.mean_action(o, &mut a);
            a
        }, 1);
        (ret, fingerprint(&l.live.actor), fingerprint(&l.live.critic))
    };
    let (ret, fa, fc) = run();
    eprintln!("4-D bandit: return {ret:.4} (optimum 1.0; untrained about 0.26)");
    assert!(ret >= 0.95, "return {ret}");
    assert_eq!(run(), (ret, fa, fc), "a second run differs");
}

/// Point mass on a line: `x' = x + dt v`, `v' = v + dt a`, reward `-(x^2 + 0.1 v^2 + 0.1 a^2)`,
/// 40-step episodes from uniform initial states (time limit, not terminal).
struct PointMass {
    s: [f32; 2],
}

const DT: f32 = 0.2;
const R_X: f64 = 1.0;
const R_V: f64 = 0.1;
const R_A: f64 = 0.1;

impl Problem<2, 1> for PointMass {
    const HORIZON: usize = 40;
    fn reset(&mut self, rng: &mut Rng) -> [f32; 2] {
        self.s = [rng.uniform_range(-1.0, 1.0), rng.uniform_range(-1.0, 1.0)];
        self.s
    }
    fn step(&mut self, a: &[f32; 1]) -> ([f32; 2], f32, bool) {
        let [x, v] = self.s;
        let r = -(R_X as f32 * x * x + R_V as f32 * v * v + R_A as f32 * a[0] * a[0]);
        self.s = [x + DT * v, v + DT * a[0]];
        (self.s, r, false)
    }
}

/// Discounted LQR gain `a = -K s` by iterating the Riccati equation to convergence.
fn lqr_gain(gamma: f64) -> [f64; 2] {
    let dt = DT as f64;
    let (a, b) = ([[1.0, dt], [0.0, 1.0]], [0.0, dt]);
    let mut p = [[R_X, 0.0], [0.0, R_V]];
    let mut k = [0.0; 2];
    for _ in 0..10_000 {
        // K = gamma (R + gamma B'PB)^-1 B'PA ; P = Q + gamma A'PA - gamma A'PB K
        let pb = [p[0][0] * b[0] + p[0][1] * b[1], p[1][0] * b[0] + p[1][1] * b[1]];
        let bpb = b[0] * pb[0] + b[1] * pb[1];
        let bpa = [pb[0] * a[0][0] + pb[1] * a[1][0], pb[0] * a[0][1] + pb[1] * a[1][1]];
        let denom = R_A + gamma * bpb;
        k = [gamma * bpa[0] / denom, gamma * bpa[1] / denom];
        let mut ap = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                let mut apa = 0.0;
                for m in 0..2 {
                    for n in 0..2 {
                        apa += a[m][i] * p[m][n] * a[n][j];
                    }
                }
                let q = if i == j { if i == 0 { R_X } else { R_V } } else { 0.0 };
                ap[i][j] = q + gamma * apa - gamma * bpa[i] * k[j];
            }
        }
        p = ap;
    }
    k
}

#[test]
fn linear_quadratic_point_mass_reaches_lqr_performance() {
    let cfg = MpoConfig {
        actor_lr: 1e-3,
        critic_lr: 1e-3,
        target_period: 50,
        actor_clip: 40.0,
        gamma: 0.95,
        ..MpoConfig::REPORT
    };
    let k = lqr_gain(cfg.gamma as f64);
    let mut p = PointMass { s: [0.0; 2] };
    let lqr = evaluate(&mut p, &|s| [(-(k[0] * s[0] as f64 + k[1] * s[1] as f64)) as f32], 50);
    let zero = evaluate(&mut p, &|_| [0.0], 50);
    let steps: usize = std::env::var("LQ_STEPS").map(|s| s.parse().unwrap()).unwrap_or(6000);
    let tp: u32 = std::env::var("LQ_TP").map(|s| s.parse().unwrap()).unwrap_or(50);
    let lr: f32 = std::env::var("LQ_LR").map(|s| s.parse().unwrap()).unwrap_or(1e-3);
    let ecov: f32 = std::env::var("LQ_ECOV").map(|s| s.parse().unwrap()).unwrap_or(1e-4);
    let istd: f32 = std::env::var("LQ_STD").map(|s| s.parse().unwrap()).unwrap_or(0.5);
    let cfg = MpoConfig { target_period: tp, actor_lr: lr, critic_lr: lr, eps_cov: ecov, init_std: istd, ..cfg };
    let l = train::<_, 2, 1, 1, 64>(&mut p, cfg, 3, steps, 500);
    let mpo = evaluate(&mut p, &|o| {
        let mut a = [0f32; 1];
        l.mean_action(o, &mut a);
        a
    }, 50);
    for s in [[0.5f32, 0.0], [0.0, 0.5], [-0.5, 0.5], [0.1, -0.1], [1.0, 1.0]] {
        let mut a = [0f32; 1];
        l.mean_action(&s, &mut a);
        eprintln!("DBG s {s:?} mpo {:.4} lqr {:.4} std {:?}", a[0], -(k[0] * s[0] as f64 + k[1] * s[1] as f64), l.live.actor.distribution(&s, 1e-4).std_devs());
    }
    eprintln!("point mass: MPO {mpo:.4}, LQR {lqr:.4}, zero action {zero:.4} (K = {k:?})");
    assert!(mpo >= 1.05 * lqr, "MPO return {mpo} vs LQR {lqr}");
}
