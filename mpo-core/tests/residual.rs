//! The residual networks and their layer norm against references written out here in f64
//! (independently of the core's code): forward values, and the gradient of every parameter
//! against central differences of the f64 reference, through the chunked backward pass the
//! learner runs (two chunks, separate tapes). Also: a batch gives the bits of one state at a
//! time, and the scalar and categorical critics' losses (the categorical head's projection
//! and cross-entropy written out here too).

#![allow(clippy::needless_range_loop)]

use bytemuck::Zeroable;
use mpo_core::config::MpoConfig;
use mpo_core::layer_norm::{EPS, LayerNorm};
use mpo_core::linear::Linear;
use mpo_core::network::{PolicyGradInputs, PolicyTrain, ValueGradInputs, ValueNet};
use mpo_core::parallel::Serial;
use mpo_core::params::Params;
use mpo_core::residual::{
    ResidualActor, ResidualActorTransposed, ResidualCritic, ResidualCriticTape,
    ResidualCriticTransposed, Trunk, TrunkTape,
};
use mpo_core::rng::Rng;

const OBS: usize = 5;
const ACT: usize = 2;
const TRI: usize = 3;
const W: usize = 12; // one 8-lane chunk of the norms' sums and a remainder of 4
const F: usize = 20;
const D: usize = 2;
const BC: usize = 3;
const C: usize = 2;
const B: usize = BC * C;

type Actor = ResidualActor<OBS, ACT, TRI, W, F, D>;

/// `|a - b| / (floor + max(|a|, |b|))`.
fn rel_err(a: f64, b: f64, floor: f64) -> f64 {
    (a - b).abs() / (floor + a.abs().max(b.abs()))
}

// ---- The f64 references ----

/// Layer norm of `x` with gain `g` and bias `b` (population variance, `EPS` inside the root).
fn ln64(x: &[f64], g: &[f32], b: &[f32]) -> Vec<f64> {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    let r = 1.0 / (var + EPS as f64).sqrt();
    (0..x.len())
        .map(|i| (x[i] - mean) * r * g[i] as f64 + b[i] as f64)
        .collect()
}

/// `b + x W` for a layer of the core's (input-major weights).
fn lin64<const I: usize, const O: usize>(x: &[f64], l: &Linear<I, O>) -> Vec<f64> {
    (0..O)
        .map(|o| l.b[o] as f64 + (0..I).map(|i| x[i] * l.w[i][o] as f64).sum::<f64>())
        .collect()
}

/// The blocks and the final norm on the embedding `x`; ReLU signs folded into `mask`.
fn trunk64(mut x: Vec<f64>, t: &Trunk<W, F, D>, mask: &mut u64) -> Vec<f64> {
    for blk in &t.blocks {
        let y = ln64(&x, &blk.norm.g, &blk.norm.b);
        let h: Vec<f64> = lin64(&y, &blk.up)
            .into_iter()
            .map(|v| {
                *mask = (*mask ^ (v > 0.0) as u64).wrapping_mul(0x100_0000_01b3);
                v.max(0.0)
            })
            .collect();
        let d = lin64(&h, &blk.down);
        for i in 0..W {
            x[i] += d[i];
        }
    }
    ln64(&x, &t.norm.g, &t.norm.b)
}

/// The actor's raw heads (no squash, identity input normalisation) for one state.
fn actor64(a: &Actor, s: &[f32; OBS], mask: &mut u64) -> (Vec<f64>, Vec<f64>) {
    let x: Vec<f64> = s.iter().map(|&v| v as f64).collect();
    let z = trunk64(lin64(&x, &a.embed), &a.trunk, mask);
    (lin64(&z, &a.mean), lin64(&z, &a.chol))
}

/// The critic's outputs for one pair.
fn critic64<const K: usize>(
    q: &ResidualCritic<OBS, ACT, W, F, D, K>,
    s: &[f32; OBS],
    a: &[f32; ACT],
    mask: &mut u64,
) -> Vec<f64> {
    let mut x = vec![0f64; W];
    for o in 0..W {
        x[o] = q.embed_s.b[o] as f64
            + (0..OBS)
                .map(|i| s[i] as f64 * q.embed_s.w[i][o] as f64)
                .sum::<f64>()
            + (0..ACT)
                .map(|i| a[i] as f64 * q.embed_a.w[i][o] as f64)
                .sum::<f64>();
    }
    lin64(&trunk64(x, &q.trunk, mask), &q.out)
}

/// Central differences of `f` (f64 value, ReLU mask) for every parameter of `p` against
/// `analytic`; returns the worst relative error. At most 3% of the parameters may be skipped
/// for straddling a ReLU kink.
fn check_all<P: Params>(
    p: &mut P,
    analytic: &P,
    f: &mut dyn FnMut(&P) -> (f64, u64),
    bound: f64,
) -> f64 {
    let h = 1e-3f32;
    let (mut worst, mut skipped) = (0f64, 0);
    let mask0 = f(p).1;
    for k in 0..P::TENSORS {
        for i in 0..p.tensor(k).len() {
            let x0 = p.tensor(k)[i];
            let (xp, xm) = (x0 + h, x0 - h);
            if xp == xm {
                // Too large to perturb (the identity normalisation's clip bound, f32::MAX):
                // outside what gradients train.
                assert_eq!(analytic.tensor(k)[i], 0.0, "tensor {k} index {i}");
                continue;
            }
            p.tensor_mut(k)[i] = xp;
            let (fp, mp) = f(p);
            p.tensor_mut(k)[i] = xm;
            let (fm, mm) = f(p);
            p.tensor_mut(k)[i] = x0;
            if mp != mask0 || mm != mask0 {
                skipped += 1;
                continue;
            }
            let fd = (fp - fm) / (xp as f64 - xm as f64);
            let an = analytic.tensor(k)[i] as f64;
            let e = rel_err(an, fd, 1e-3);
            assert!(
                e < bound,
                "tensor {k} index {i}: analytic {an}, finite difference {fd}"
            );
            worst = worst.max(e);
        }
    }
    assert!(
        skipped * 33 <= p.len(),
        "{skipped} of {} parameters straddle a ReLU kink",
        p.len()
    );
    worst
}

/// Random gains and biases, so the norms' affine parts carry gradient of their own.
fn perturb_norm<const N: usize>(ln: &mut LayerNorm<N>, rng: &mut Rng) {
    for o in 0..N {
        ln.g[o] = 1.0 + 0.3 * rng.normal();
        ln.b[o] = 0.2 * rng.normal();
    }
}

fn perturb_trunk(t: &mut Trunk<W, F, D>, rng: &mut Rng) {
    for b in t.blocks.iter_mut() {
        perturb_norm(&mut b.norm, rng);
    }
    perturb_norm(&mut t.norm, rng);
}

// ---- Layer norm ----

#[test]
fn layer_norm_forward_and_backward_match_the_f64_reference() {
    const N: usize = 13;
    let mut rng = Rng::seed_from_u64(1);
    let mut ln = LayerNorm::<N>::zeroed();
    perturb_norm(&mut ln, &mut rng);
    let mut x = [[0f32; N]; 3];
    rng.fill_normal(x.as_flattened_mut());
    for v in x[2].iter_mut() {
        *v = 10.0 + 0.5 * *v; // an offset twenty times the spread
    }
    let mut c = [[0f32; N]; 3];
    rng.fill_normal(c.as_flattened_mut());
    let (mut xhat, mut rstd, mut y) = ([[0f32; N]; 3], [0f32; 3], [[0f32; N]; 3]);
    ln.forward_rows(&x, &mut xhat, &mut rstd, &mut y);
    let mut dx = [[0.5f32; N]; 3];
    ln.backward_rows(&xhat, &rstd, &c, &mut dx);
    for n in 0..3 {
        let x64: Vec<f64> = x[n].iter().map(|&v| v as f64).collect();
        let r = ln64(&x64, &ln.g, &ln.b);
        for o in 0..N {
            assert!(
                rel_err(y[n][o] as f64, r[o], 1e-3) < 1e-4,
                "row {n} unit {o}: {} vs {}",
                y[n][o],
                r[o]
            );
        }
        // d/dx_i of sum_o c_o y_o, by central differences of the reference; backward adds to
        // what `dx` held (0.5).
        for i in 0..N {
            let h = 1e-4 * (1.0 + x64[i].abs());
            let f = |d: f64| {
                let mut xs = x64.clone();
                xs[i] += d;
                let r = ln64(&xs, &ln.g, &ln.b);
                (0..N).map(|o| c[n][o] as f64 * r[o]).sum::<f64>()
            };
            let fd = (f(h) - f(-h)) / (2.0 * h);
            let an = dx[n][i] as f64 - 0.5;
            assert!(
                rel_err(an, fd, 1e-3) < 2e-3,
                "row {n} input {i}: analytic {an}, finite difference {fd}"
            );
        }
    }
}

// ---- The policy ----

#[test]
fn residual_actor_forward_matches_the_reference_and_one_state_gives_the_batch_bits() {
    let mut rng = Rng::seed_from_u64(2);
    let mut a = Actor::zeroed();
    a.init(&mut rng, 0.7, 1e-3);
    perturb_trunk(&mut a.trunk, &mut rng);
    let mut obs = [[0f32; OBS]; B];
    rng.fill_normal(obs.as_flattened_mut());
    let mut tape: Box<TrunkTape<B, W, F, D>> = bytemuck::zeroed_box();
    let (mut mean, mut chol) = ([[0f32; ACT]; B], [[0f32; TRI]; B]);
    PolicyTrain::forward(&a, &obs, &mut tape, &mut mean, &mut chol);
    for n in 0..B {
        let (m64, c64) = actor64(&a, &obs[n], &mut 0);
        for k in 0..ACT {
            assert!(rel_err(mean[n][k] as f64, m64[k], 1e-3) < 1e-4);
        }
        for k in 0..TRI {
            assert!(rel_err(chol[n][k] as f64, c64[k], 1e-3) < 1e-4);
        }
        let (mut m1, mut c1) = ([0f32; ACT], [0f32; TRI]);
        a.forward_one(&obs[n], &mut m1, &mut c1);
        assert_eq!(m1.map(f32::to_bits), mean[n].map(f32::to_bits), "row {n}");
        assert_eq!(c1.map(f32::to_bits), chol[n].map(f32::to_bits), "row {n}");
        let mut act = [0f32; ACT];
        a.mean_action(&obs[n], &mut act);
        assert_eq!(act.map(f32::to_bits), mean[n].map(f32::to_bits), "row {n}");
    }
}

#[test]
fn residual_actor_gradients_match_finite_differences() {
    let mut rng = Rng::seed_from_u64(3);
    let mut a = Actor::zeroed();
    a.init(&mut rng, 0.7, 1e-3);
    a.mean.init_uniform(&mut rng);
    a.chol.init_uniform(&mut rng);
    perturb_trunk(&mut a.trunk, &mut rng);
    let mut obs = [[0f32; OBS]; B];
    rng.fill_normal(obs.as_flattened_mut());
    let (mut cm, mut cc) = ([[0f32; ACT]; B], [[0f32; TRI]; B]);
    rng.fill_normal(cm.as_flattened_mut());
    rng.fill_normal(cc.as_flattened_mut());
    // Two chunks with their own tapes, as the learner holds a batch.
    let mut t = ResidualActorTransposed::<ACT, TRI, W, F, D>::zeroed();
    PolicyTrain::transpose_into(&a, &mut t);
    let mut tapes: Vec<Box<TrunkTape<BC, W, F, D>>> =
        (0..C).map(|_| bytemuck::zeroed_box()).collect();
    let chunk = |c: usize| -> &[[f32; OBS]; BC] { obs[c * BC..][..BC].try_into().unwrap() };
    let dm = |c: usize| -> &[[f32; ACT]; BC] { cm[c * BC..][..BC].try_into().unwrap() };
    let dc = |c: usize| -> &[[f32; TRI]; BC] { cc[c * BC..][..BC].try_into().unwrap() };
    for (c, tape) in tapes.iter_mut().enumerate() {
        let (mut m, mut ch) = ([[0f32; ACT]; BC], [[0f32; TRI]; BC]);
        PolicyTrain::forward(&a, chunk(c), tape, &mut m, &mut ch);
        a.backprop(tape, dm(c), dc(c), &t);
    }
    let mut grad = Actor::zeroed();
    let obs_c: Vec<&[[f32; OBS]]> = (0..C).map(|c| &chunk(c)[..]).collect();
    let tape_refs: Vec<&TrunkTape<BC, W, F, D>> = tapes.iter().map(|t| &**t).collect();
    let dm_c: Vec<&[[f32; ACT]]> = (0..C).map(|c| &dm(c)[..]).collect();
    let dc_c: Vec<&[[f32; TRI]]> = (0..C).map(|c| &dc(c)[..]).collect();
    let sq = Actor::weight_grads(
        &mut grad,
        &Serial,
        &PolicyGradInputs {
            obs: &obs_c,
            tapes: &tape_refs,
            d_mean: &dm_c,
            d_chol: &dc_c,
        },
    );
    let norm = grad.global_norm() as f64;
    assert!(
        rel_err(sq.sqrt(), norm, 0.0) < 1e-5,
        "{} vs {norm}",
        sq.sqrt()
    );
    let worst = check_all(
        &mut a.clone(),
        &grad,
        &mut |p: &Actor| {
            let mut mask = 0xcbf2_9ce4_8422_2325u64;
            let mut f = 0f64;
            for n in 0..B {
                let (m, ch) = actor64(p, &obs[n], &mut mask);
                f += (0..ACT).map(|k| cm[n][k] as f64 * m[k]).sum::<f64>();
                f += (0..TRI).map(|k| cc[n][k] as f64 * ch[k]).sum::<f64>();
            }
            (f, mask)
        },
        5e-3,
    );
    eprintln!("residual actor: worst relative error {worst:.2e}");
}

// ---- The critic ----

/// The critic's outputs, loss and every parameter's gradient against the reference, for `K`
/// outputs (1: `0.5 (Q - y)^2`; more: cross-entropy to the projection written in
/// `project64`).
fn check_critic<const K: usize>(cfg: MpoConfig) {
    type Tape<const K: usize> = ResidualCriticTape<BC, W, F, D, K>;
    let mut rng = Rng::seed_from_u64(4);
    let mut q = ResidualCritic::<OBS, ACT, W, F, D, K>::zeroed();
    ValueNet::init(&mut q, &mut rng);
    perturb_trunk(&mut q.trunk, &mut rng);
    let mut obs = [[0f32; OBS]; B];
    let mut act = [[0f32; ACT]; B];
    rng.fill_normal(obs.as_flattened_mut());
    rng.fill_normal(act.as_flattened_mut());
    let y: [f32; B] = core::array::from_fn(|n| [-2.0, 0.3, 1.7, 3.05, 12.0, -0.8][n]);
    let mut t = ResidualCriticTransposed::<W, F, D, K>::zeroed();
    q.transpose_into(&mut t);
    let mut tapes: Vec<Box<Tape<K>>> = (0..C).map(|_| bytemuck::zeroed_box()).collect();
    let inv_b = 1.0 / B as f32;
    let mut loss = [0f32; B];
    for (c, tape) in tapes.iter_mut().enumerate() {
        let s: &[[f32; OBS]; BC] = obs[c * BC..][..BC].try_into().unwrap();
        let a: &[[f32; ACT]; BC] = act[c * BC..][..BC].try_into().unwrap();
        let yc: &[f32; BC] = y[c * BC..][..BC].try_into().unwrap();
        let mut v = [0f32; BC];
        q.values(s, a, tape, &mut v, &cfg);
        // The state-part path gives the same bits.
        let mut part = [[0f32; W]; BC];
        q.state_part(s, &mut part);
        let mut other: Box<Tape<K>> = bytemuck::zeroed_box();
        let mut v2 = [0f32; BC];
        q.values_from_state_part(&part, a, &mut other, &mut v2, &cfg);
        assert_eq!(v.map(f32::to_bits), v2.map(f32::to_bits));
        for n in 0..BC {
            let out = critic64(&q, &s[n], &a[n], &mut 0);
            let want = value64::<K>(&out, &cfg);
            assert!(
                rel_err(v[n] as f64, want, 1e-2) < 1e-4,
                "value {} vs {want}",
                v[n]
            );
        }
        let mut l = [0f32; BC];
        q.loss(tape, &v, yc, inv_b, &cfg, &mut l);
        loss[c * BC..][..BC].copy_from_slice(&l);
        q.backprop(tape, &t, &cfg);
    }
    let loss_fn = |p: &ResidualCritic<OBS, ACT, W, F, D, K>, mask: &mut u64| -> Vec<f64> {
        (0..B)
            .map(|n| loss64::<K>(&critic64(p, &obs[n], &act[n], mask), y[n], &cfg))
            .collect()
    };
    let ref_loss = loss_fn(&q, &mut 0);
    for n in 0..B {
        assert!(
            rel_err(loss[n] as f64, ref_loss[n], 1e-3) < 1e-4,
            "row {n}: loss {} vs {}",
            loss[n],
            ref_loss[n]
        );
    }
    let mut grad = ResidualCritic::<OBS, ACT, W, F, D, K>::zeroed();
    let obs_c: Vec<&[[f32; OBS]]> = (0..C).map(|c| &obs[c * BC..][..BC]).collect();
    let act_c: Vec<&[[f32; ACT]]> = (0..C).map(|c| &act[c * BC..][..BC]).collect();
    let tape_refs: Vec<&Tape<K>> = tapes.iter().map(|t| &**t).collect();
    let inputs = ValueGradInputs {
        obs: &obs_c,
        act: &act_c,
        tapes: &tape_refs,
    };
    ResidualCritic::weight_grads(&mut grad, &Serial, &inputs, &cfg);
    let worst = check_all(
        &mut q.clone(),
        &grad,
        &mut |p| {
            let mut mask = 0xcbf2_9ce4_8422_2325u64;
            let l: f64 = loss_fn(p, &mut mask).iter().sum::<f64>() / B as f64;
            (l, mask)
        },
        5e-3,
    );
    eprintln!("residual critic, {K} outputs: worst relative error {worst:.2e}");
}

/// The atoms of `K` bins over the configuration's support.
fn atoms64<const K: usize>(cfg: &MpoConfig) -> Vec<f64> {
    let (lo, hi) = (cfg.value_min as f64, cfg.value_max as f64);
    (0..K)
        .map(|k| lo + (hi - lo) * k as f64 / (K - 1) as f64)
        .collect()
}

/// The value of outputs `out`: itself, or the softmax's expectation over the atoms.
fn value64<const K: usize>(out: &[f64], cfg: &MpoConfig) -> f64 {
    if K == 1 {
        return out[0];
    }
    let p = softmax64(out);
    p.iter().zip(atoms64::<K>(cfg)).map(|(p, z)| p * z).sum()
}

fn softmax64(x: &[f64]) -> Vec<f64> {
    let m = x.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = x.iter().map(|v| (v - m).exp()).collect();
    let s: f64 = e.iter().sum();
    e.iter().map(|v| v / s).collect()
}

/// The target distribution for `y`, written out: two-hot (`sigma` 0) or the Gaussian mass of
/// each atom's bin, renormalised.
fn project64<const K: usize>(y: f64, cfg: &MpoConfig) -> Vec<f64> {
    let z = atoms64::<K>(cfg);
    let dz = z[1] - z[0];
    let y = y.clamp(z[0], z[K - 1]);
    let mut t = vec![0f64; K];
    if cfg.value_sigma > 0.0 {
        let sigma = cfg.value_sigma as f64 * dz;
        let cdf = |v: f64| 0.5 * (1.0 + libm::erf((v - y) / (sigma * 2f64.sqrt())));
        let total = cdf(z[K - 1] + dz / 2.0) - cdf(z[0] - dz / 2.0);
        for k in 0..K {
            t[k] = (cdf(z[k] + dz / 2.0) - cdf(z[k] - dz / 2.0)) / total;
        }
        return t;
    }
    for k in 0..K - 1 {
        if y >= z[k] && y <= z[k + 1] {
            let frac = (y - z[k]) / dz;
            t[k] = 1.0 - frac;
            t[k + 1] = frac;
            break;
        }
    }
    t
}

fn loss64<const K: usize>(out: &[f64], y: f32, cfg: &MpoConfig) -> f64 {
    if K == 1 {
        return 0.5 * (out[0] - y as f64).powi(2);
    }
    let p = softmax64(out);
    let t = project64::<K>(y as f64, cfg);
    -(0..K).map(|k| t[k] * p[k].ln()).sum::<f64>()
}

#[test]
fn residual_scalar_critic_matches_the_reference_and_finite_differences() {
    check_critic::<1>(MpoConfig::REPORT);
}

#[test]
fn residual_categorical_critic_matches_the_reference_and_finite_differences() {
    let support = MpoConfig {
        value_min: -3.0,
        value_max: 5.0,
        ..MpoConfig::REPORT
    };
    // HL-Gauss and two-hot targets; 11 atoms (one 8-lane chunk and a remainder).
    check_critic::<11>(support);
    check_critic::<11>(MpoConfig {
        value_sigma: 0.0,
        ..support
    });
}

/// Logits far below their largest, as a critic's are once its values sit near the support's
/// top: the head's probabilities, values, losses and gradients hold no subnormal number (x86
/// cores take those through microcode; see `value_head::softmax`), the atoms beyond the
/// floor (`MpoConfig::logit_floor`, 40) get exactly 0, and values, losses and gradients still
/// match the f64 reference. With the floor off (0) the same logits do make subnormals: the
/// case tests what it is named after.
#[test]
fn categorical_head_on_far_logits_has_no_subnormal_and_matches_the_reference() {
    use mpo_core::value_head::{Support, loss, values};
    const K: usize = 101;
    let cfg = MpoConfig {
        value_min: 0.0,
        value_max: 100.0,
        value_sigma: 0.0,
        ..MpoConfig::REPORT
    };
    let support = Support::of(&cfg);
    // (slope of the logits per atom, the peak's atom, the target): spreads of 50 to 300.
    let shapes = [
        (0.5, 95.0, 94.3),
        (1.5, 99.0, 100.0),
        (3.0, 3.0, 2.5),
        (1.0, 50.0, 61.0),
    ];
    let mut out = [[0f32; K]; 4];
    let mut y = [0f32; 4];
    for (r, &(slope, peak, target)) in shapes.iter().enumerate() {
        for k in 0..K {
            out[r][k] = -slope * (k as f32 - peak).abs() + 0.25 * (k % 3) as f32;
        }
        y[r] = target;
    }
    let (mut probs, mut d_out) = ([[0f32; K]; 4], [[0f32; K]; 4]);
    let (mut q, mut ce) = ([0f32; 4], [0f32; 4]);
    // The batch-mean factor of the simba rows' critic batch (256 pairs of 8 actions).
    let inv_b = 1.0 / 2048.0;
    values(&support, &out, &mut probs, &mut q);
    loss(&support, &out, &probs, &q, &y, inv_b, &mut d_out, &mut ce);
    let tame = |x: f32| x == 0.0 || x.is_normal();
    for r in 0..4 {
        let o64: Vec<f64> = out[r].iter().map(|&v| v as f64).collect();
        let (p64, t64) = (softmax64(&o64), project64::<K>(y[r] as f64, &cfg));
        let top = out[r].iter().cloned().fold(f32::MIN, f32::max);
        for k in 0..K {
            let (p, g) = (probs[r][k], d_out[r][k]);
            assert!(
                tame(p) && tame(g),
                "row {r} atom {k}: p {p:e}, gradient {g:e}"
            );
            if out[r][k] - top < -cfg.logit_floor {
                assert_eq!(p, 0.0, "row {r} atom {k} lies beyond the floor");
            }
            let want = (p64[k] - t64[k]) * inv_b as f64;
            assert!(
                (g as f64 - want).abs() <= 1e-6 * inv_b as f64,
                "row {r} atom {k}"
            );
        }
        assert!(tame(q[r]) && tame(ce[r]));
        assert!(
            rel_err(q[r] as f64, value64::<K>(&o64, &cfg), 1.0) < 1e-5,
            "row {r}"
        );
        assert!(
            rel_err(ce[r] as f64, loss64::<K>(&o64, y[r], &cfg), 1.0) < 1e-5,
            "row {r}"
        );
    }
    let off = Support {
        floor: 0.0,
        ..support
    };
    values(&off, &out, &mut probs, &mut q);
    loss(&off, &out, &probs, &q, &y, inv_b, &mut d_out, &mut ce);
    let subnormal = (probs.iter().chain(&d_out))
        .flatten()
        .filter(|x| x.is_subnormal())
        .count();
    assert!(
        subnormal > 50,
        "only {subnormal} subnormals with the floor off"
    );
}
