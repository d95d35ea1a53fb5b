//! Hand-written backward passes against central finite differences, for every parameter of
//! both networks, at sizes that exercise every tile and remainder path of the kernels.

#![allow(clippy::needless_range_loop)]

use bytemuck::Zeroable;
use mpo_core::actor::{Actor, ActorGradInputs, ActorTape, ActorTransposed};
use mpo_core::critic::{Critic, CriticTape, CriticTransposed};
use mpo_core::linear::Linear;
use mpo_core::params::Params;
use mpo_core::rng::Rng;

const OBS: usize = 5;
const ACT: usize = 2;
const TRI: usize = 3;
const H1: usize = 20; // one 16-wide tile plus a remainder
const H2: usize = 17;
const B: usize = 6; // one 4-sample tile plus a remainder

/// Relative error with a floor: gradients smaller than 1e-2 are compared absolutely (the f32
/// rounding noise of a central difference with h = 1e-3 on objectives of size ~1 is ~1e-4).
fn rel_err(a: f64, b: f64) -> f64 {
    (a - b).abs() / (1e-2 + a.abs().max(b.abs()))
}

/// Fingerprint of which ReLU units are active: a central difference across a kink measures
/// no derivative, so such parameters are skipped (and counted).
fn relu_mask(acts: &[f32]) -> u64 {
    acts.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, a| {
        (h ^ (*a > 0.0) as u64).wrapping_mul(0x100_0000_01b3)
    })
}

/// Checks `analytic` (flat, tensor order) against central differences of `f` (value and ReLU
/// mask) for every parameter of `p`; returns the worst relative error. At most 2% of the
/// parameters may be skipped for straddling a ReLU kink.
fn check_all<P: Params>(
    p: &mut P,
    analytic: &P,
    f: &mut dyn FnMut(&P) -> (f64, u64),
    bound: f64,
) -> f64 {
    let h = 1e-3f32;
    let mut worst = 0f64;
    let mut skipped = 0;
    let mask0 = f(p).1;
    for k in 0..P::TENSORS {
        for i in 0..p.tensor(k).len() {
            let x0 = p.tensor(k)[i];
            p.tensor_mut(k)[i] = x0 + h;
            let (fp, mp) = f(p);
            p.tensor_mut(k)[i] = x0 - h;
            let (fm, mm) = f(p);
            p.tensor_mut(k)[i] = x0;
            if mp != mask0 || mm != mask0 {
                skipped += 1;
                continue;
            }
            let fd = (fp - fm) / (2.0 * h as f64);
            let an = analytic.tensor(k)[i] as f64;
            let e = rel_err(an, fd);
            assert!(
                e < bound,
                "tensor {k} index {i}: analytic {an} finite difference {fd}"
            );
            worst = worst.max(e);
        }
    }
    assert!(
        skipped * 50 <= p.len(),
        "{skipped} of {} parameters straddle a ReLU kink",
        p.len()
    );
    worst
}

#[test]
fn linear_layer_weight_bias_and_input_gradients() {
    const I: usize = 9;
    const O: usize = 21;
    let mut rng = Rng::seed_from_u64(1);
    let mut l = Linear::<I, O>::zeroed();
    l.init_uniform(&mut rng);
    let mut x = [[0f32; I]; B];
    let mut c = [[0f32; O]; B];
    rng.fill_normal(x.as_flattened_mut());
    rng.fill_normal(c.as_flattened_mut());
    // f = sum_n c[n] . y[n]; its gradient with respect to y is c.
    let f = |l: &Linear<I, O>, x: &[[f32; I]; B]| -> f64 {
        let mut y = [[0f32; O]; B];
        l.forward(x, &mut y);
        y.as_flattened()
            .iter()
            .zip(c.as_flattened())
            .map(|(a, b)| *a as f64 * *b as f64)
            .sum()
    };
    let mut g = Linear::<I, O>::zeroed();
    let mut dx = [[0f32; I]; B];
    let mut wt = [[0f32; I]; O];
    l.backward(&x, &c, &mut g);
    l.input_grad(&c, &mut dx, &mut wt);
    let worst = check_all(&mut l.clone(), &g, &mut |p| (f(p, &x), 0), 1e-2);
    // Input gradient.
    let h = 1e-3f32;
    for n in 0..B {
        for i in 0..I {
            let (mut xp, mut xm) = (x, x);
            xp[n][i] += h;
            xm[n][i] -= h;
            let fd = (f(&l, &xp) - f(&l, &xm)) / (2.0 * h as f64);
            assert!(
                rel_err(dx[n][i] as f64, fd) < 1e-2,
                "dx[{n}][{i}]: {} vs {fd}",
                dx[n][i]
            );
        }
    }
    eprintln!("linear: worst relative error {worst:.2e}");
}

/// Checks the actor's backward pass against central differences; with `bound`, the mean of
/// action 0 is squashed (`bound tanh(raw / bound)`, curved at this scale) and action 1 left
/// unbounded, and the gradient at the squashed mean goes through `squash_backward` first, as
/// in the learner.
fn check_actor_gradients(bound: Option<f32>) {
    type Net = Actor<OBS, ACT, TRI, H1, H2>;
    let mut rng = Rng::seed_from_u64(2);
    let mut net = Net::zeroed();
    net.init(&mut rng, 0.7, 1e-3);
    // Undo the head down-scaling so every parameter has a sizeable effect.
    net.mean.init_uniform(&mut rng);
    net.chol.init_uniform(&mut rng);
    if let Some(b) = bound {
        net.squash.bound[0] = b;
    }
    let squash = net.squash.clone();
    let mut obs = [[0f32; OBS]; B];
    rng.fill_normal(obs.as_flattened_mut());
    let mut cm = [[0f32; ACT]; B];
    let mut cc = [[0f32; TRI]; B];
    rng.fill_normal(cm.as_flattened_mut());
    rng.fill_normal(cc.as_flattened_mut());
    let mut tape: Box<ActorTape<B, H1, H2>> = bytemuck::zeroed_box();
    // The bound is a constant of the objective (it is not trained): differences in it must
    // find nothing, as its analytic gradient is zero.
    let f = |net: &Net, tape: &mut ActorTape<B, H1, H2>| -> (f64, u64) {
        let mut net = net.clone();
        net.squash = squash.clone();
        let mut m = [[0f32; ACT]; B];
        let mut c = [[0f32; TRI]; B];
        net.forward(&obs, tape, &mut m, &mut c);
        let a: f64 = m
            .as_flattened()
            .iter()
            .zip(cm.as_flattened())
            .map(|(x, y)| *x as f64 * *y as f64)
            .sum();
        let b: f64 = c
            .as_flattened()
            .iter()
            .zip(cc.as_flattened())
            .map(|(x, y)| *x as f64 * *y as f64)
            .sum();
        (
            a + b,
            relu_mask(tape.h1.as_flattened()) ^ relu_mask(tape.h2.as_flattened()).rotate_left(1),
        )
    };
    f(&net, &mut tape);
    let mut m = [[0f32; ACT]; B];
    let mut c = [[0f32; TRI]; B];
    net.forward(&obs, &mut tape, &mut m, &mut c);
    if let Some(b) = bound {
        // The squashed dimension is inside its bound and in tanh's curved part somewhere.
        assert!(m.iter().all(|r| r[0].abs() < b));
        assert!(m.iter().any(|r| r[0].abs() > 0.3 * b), "{m:?}");
    }
    let mut d = cm;
    net.squash_backward(&m, &mut d);
    let mut grad = Net::zeroed();
    let mut t: Box<ActorTransposed<ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    net.backward(&obs, &mut tape, &d, &cc, &mut t, &mut grad);
    let mut tape2: Box<ActorTape<B, H1, H2>> = bytemuck::zeroed_box();
    let worst = check_all(&mut net.clone(), &grad, &mut |p| f(p, &mut tape2), 1e-2);
    eprintln!(
        "actor (bound {bound:?}): {} parameters, worst relative error {worst:.2e}",
        net.len()
    );
}

#[test]
fn actor_gradients_for_every_parameter() {
    check_actor_gradients(None);
}

#[test]
fn squashed_mean_actor_gradients_for_every_parameter() {
    check_actor_gradients(Some(0.5));
}

/// A critic with random weights; with `layer_norm`, a gain and bias away from the identity so
/// that their gradients and their effect on the others are exercised.
fn random_critic(seed: u64, layer_norm: bool) -> Critic<OBS, ACT, H1, H2> {
    let mut rng = Rng::seed_from_u64(seed);
    let mut net = Critic::<OBS, ACT, H1, H2>::zeroed();
    net.init(&mut rng);
    if layer_norm {
        for o in 0..H1 {
            net.ln1.g[o] = 1.0 + 0.3 * rng.normal();
            net.ln1.b[o] = 0.2 * rng.normal();
        }
    }
    net
}

fn check_critic_gradients(layer_norm: bool) {
    type Net = Critic<OBS, ACT, H1, H2>;
    let mut rng = Rng::seed_from_u64(3);
    let net = random_critic(5, layer_norm);
    let mut obs = [[0f32; OBS]; B];
    let mut act = [[0f32; ACT]; B];
    let mut cq = [[0f32; 1]; B];
    rng.fill_normal(obs.as_flattened_mut());
    rng.fill_normal(act.as_flattened_mut());
    rng.fill_normal(cq.as_flattened_mut());
    let mut tape: Box<CriticTape<B, H1, H2>> = bytemuck::zeroed_box();
    let f = |net: &Net, tape: &mut CriticTape<B, H1, H2>| -> (f64, u64) {
        let mut q = [[0f32; 1]; B];
        net.forward(&obs, &act, tape, &mut q, layer_norm);
        let v = (0..B).map(|n| q[n][0] as f64 * cq[n][0] as f64).sum();
        // tanh has no kink: only ReLU layers count in the mask.
        let m1 = if layer_norm {
            0
        } else {
            relu_mask(tape.h1.as_flattened())
        };
        (v, m1 ^ relu_mask(tape.h2.as_flattened()).rotate_left(1))
    };
    f(&net, &mut tape);
    let mut grad = Net::zeroed();
    let mut t: Box<CriticTransposed<H1, H2>> = bytemuck::zeroed_box();
    net.backward(&obs, &act, &mut tape, &cq, &mut t, &mut grad, layer_norm);
    let mut tape2: Box<CriticTape<B, H1, H2>> = bytemuck::zeroed_box();
    let worst = check_all(&mut net.clone(), &grad, &mut |p| f(p, &mut tape2), 1e-2);
    eprintln!(
        "critic (layer norm {layer_norm}): {} parameters, worst relative error {worst:.2e}",
        net.len()
    );
    let ln_grad = grad
        .ln1
        .g
        .iter()
        .chain(&grad.ln1.b)
        .map(|g| g.abs())
        .sum::<f32>();
    if layer_norm {
        assert!(
            ln_grad > 1e-3,
            "the layer norm's gain and bias get gradients"
        );
    } else {
        assert_eq!(ln_grad, 0.0, "an unused layer norm gets no gradient");
    }
    // The split first layer is one layer on the concatenation: q_one agrees with the batch.
    let mut q = [[0f32; 1]; B];
    net.forward(&obs, &act, &mut tape, &mut q, layer_norm);
    for n in 0..B {
        assert_eq!(
            net.q_one(&obs[n], &act[n], layer_norm).to_bits(),
            q[n][0].to_bits()
        );
    }
}

#[test]
fn critic_gradients_for_every_parameter() {
    check_critic_gradients(false);
}

#[test]
fn layer_normalised_critic_gradients_for_every_parameter() {
    check_critic_gradients(true);
}

/// `Q(s, a)` of the layer-normalised critic written out in f64 from the definition (one layer
/// on the concatenation `[s, a]`, LayerNorm with eps 1e-5, tanh, ReLU, linear), sharing no code
/// with the network.
fn naive_layer_norm_q(net: &Critic<OBS, ACT, H1, H2>, s: &[f32; OBS], a: &[f32; ACT]) -> f64 {
    let x: Vec<f64> = s.iter().chain(a.iter()).map(|&v| v as f64).collect();
    let pre: Vec<f64> = (0..H1)
        .map(|o| {
            let w = |i: usize| {
                if i < OBS {
                    net.l1s.w[i][o]
                } else {
                    net.l1a.w[i - OBS][o]
                }
            };
            net.l1s.b[o] as f64 + (0..OBS + ACT).map(|i| x[i] * w(i) as f64).sum::<f64>()
        })
        .collect();
    let mean = pre.iter().sum::<f64>() / H1 as f64;
    let var = pre.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / H1 as f64;
    let h1: Vec<f64> = (0..H1)
        .map(|o| {
            let xh = (pre[o] - mean) / (var + 1e-5).sqrt();
            (net.ln1.g[o] as f64 * xh + net.ln1.b[o] as f64).tanh()
        })
        .collect();
    let h2: Vec<f64> = (0..H2)
        .map(|o| {
            let v =
                net.l2.b[o] as f64 + (0..H1).map(|i| h1[i] * net.l2.w[i][o] as f64).sum::<f64>();
            v.max(0.0)
        })
        .collect();
    net.out.b[0] as f64 + (0..H2).map(|i| h2[i] * net.out.w[i][0] as f64).sum::<f64>()
}

/// `init` leaves the layer norm at the identity affine map, and the layer norm's epsilon is
/// the definition's: checked where it matters, on first-layer pre-activations whose variance
/// (about 1e-7) is far below it.
#[test]
fn layer_norm_initialises_to_the_identity_and_uses_its_epsilon() {
    let mut net = random_critic(9, false);
    assert!(net.ln1.g.iter().all(|&g| g == 1.0), "gain 1 after init");
    assert!(net.ln1.b.iter().all(|&b| b == 0.0), "bias 0 after init");
    for v in net
        .l1s
        .w
        .as_flattened_mut()
        .iter_mut()
        .chain(&mut net.l1s.b)
    {
        *v *= 1e-3;
    }
    for v in net.l1a.w.as_flattened_mut() {
        *v *= 1e-3;
    }
    assert_matches_the_definition(&net, 10, 1.0);
}

/// `visit_mut` (what Adam, clipping and Polyak averaging walk) visits exactly the tensors of
/// `tensor`, in order, including the layer norm's.
#[test]
fn critic_visit_mut_covers_every_tensor_in_order() {
    let mut net = random_critic(11, true);
    let want: Vec<(usize, usize)> = (0..<Critic<OBS, ACT, H1, H2> as Params>::TENSORS)
        .map(|k| {
            let t = net.tensor(k);
            (t.as_ptr() as usize, t.len())
        })
        .collect();
    let mut got = Vec::new();
    net.visit_mut(&mut |t| got.push((t.as_ptr() as usize, t.len())));
    assert_eq!(got, want);
}

#[test]
fn layer_normalised_critic_matches_the_definition() {
    // Large observations: the layer norm makes the first layer blind to their scale.
    assert_matches_the_definition(&random_critic(7, true), 8, 30.0);
}

/// The layer-normalised forward pass on random states (scaled by `obs_scale`) and actions
/// equals [`naive_layer_norm_q`] within 1e-4 relative, and `tanh` bounds the first layer.
fn assert_matches_the_definition(net: &Critic<OBS, ACT, H1, H2>, seed: u64, obs_scale: f32) {
    let mut rng = Rng::seed_from_u64(seed);
    let mut obs = [[0f32; OBS]; B];
    let mut act = [[0f32; ACT]; B];
    rng.fill_normal(obs.as_flattened_mut());
    rng.fill_normal(act.as_flattened_mut());
    for v in obs.as_flattened_mut() {
        *v *= obs_scale;
    }
    let mut tape: Box<CriticTape<B, H1, H2>> = bytemuck::zeroed_box();
    let mut q = [[0f32; 1]; B];
    net.forward(&obs, &act, &mut tape, &mut q, true);
    for n in 0..B {
        let want = naive_layer_norm_q(net, &obs[n], &act[n]);
        let err = (q[n][0] as f64 - want).abs() / (1e-3 + want.abs());
        assert!(
            err < 1e-4,
            "row {n}: {} vs {want} (rel. {err:.1e})",
            q[n][0]
        );
        for v in &tape.h1[n] {
            assert!(v.abs() <= 1.0, "tanh bounds the first layer");
        }
    }
}

#[test]
fn actor_single_state_forward_equals_batch_bits() {
    type Net = Actor<OBS, ACT, TRI, H1, H2>;
    let mut rng = Rng::seed_from_u64(4);
    let mut net = Net::zeroed();
    net.init(&mut rng, 0.5, 1e-3);
    // One mean squashed (the other not), tightly enough to curve: both paths squash alike.
    net.squash.bound[1] = 0.01;
    let mut obs = [[0f32; OBS]; B];
    rng.fill_normal(obs.as_flattened_mut());
    let mut tape: Box<ActorTape<B, H1, H2>> = bytemuck::zeroed_box();
    let mut m = [[0f32; ACT]; B];
    let mut c = [[0f32; TRI]; B];
    net.forward(&obs, &mut tape, &mut m, &mut c);
    for n in 0..B {
        let mut m1 = [0f32; ACT];
        let mut c1 = [0f32; TRI];
        net.forward_one(&obs[n], &mut m1, &mut c1);
        assert_eq!(m1.map(f32::to_bits), m[n].map(f32::to_bits));
        assert_eq!(c1.map(f32::to_bits), c[n].map(f32::to_bits));
    }
}

/// The learner's path: the batch in two chunks with their own tapes, the hidden-layer
/// gradients per chunk, the weight gradients in small parameter blocks computed in reverse
/// order: bit for bit the gradient of one contiguous backward pass.
#[test]
fn chunked_blocked_actor_gradient_equals_contiguous_bits() {
    type Net = Actor<OBS, ACT, TRI, H1, H2>;
    const B1: usize = 4;
    const B2: usize = B - B1;
    let mut rng = Rng::seed_from_u64(7);
    let mut net = Net::zeroed();
    net.init(&mut rng, 0.7, 1e-3);
    net.mean.init_uniform(&mut rng);
    net.chol.init_uniform(&mut rng);
    let mut obs = [[0f32; OBS]; B];
    let mut cm = [[0f32; ACT]; B];
    let mut cc = [[0f32; TRI]; B];
    rng.fill_normal(obs.as_flattened_mut());
    rng.fill_normal(cm.as_flattened_mut());
    rng.fill_normal(cc.as_flattened_mut());
    let (mut m, mut c) = ([[0f32; ACT]; B], [[0f32; TRI]; B]);
    let mut tape: Box<ActorTape<B, H1, H2>> = bytemuck::zeroed_box();
    let mut t: Box<ActorTransposed<ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    net.forward(&obs, &mut tape, &mut m, &mut c);
    let mut whole = Net::zeroed();
    net.backward(&obs, &mut tape, &cm, &cc, &mut t, &mut whole);

    let o1: [[f32; OBS]; B1] = obs[..B1].try_into().unwrap();
    let o2: [[f32; OBS]; B2] = obs[B1..].try_into().unwrap();
    let (dm1, dm2): ([[f32; ACT]; B1], [[f32; ACT]; B2]) =
        (cm[..B1].try_into().unwrap(), cm[B1..].try_into().unwrap());
    let (dc1, dc2): ([[f32; TRI]; B1], [[f32; TRI]; B2]) =
        (cc[..B1].try_into().unwrap(), cc[B1..].try_into().unwrap());
    let mut t1: Box<ActorTape<B1, H1, H2>> = bytemuck::zeroed_box();
    let mut t2: Box<ActorTape<B2, H1, H2>> = bytemuck::zeroed_box();
    net.forward(&o1, &mut t1, &mut [[0.0; ACT]; B1], &mut [[0.0; TRI]; B1]);
    net.forward(&o2, &mut t2, &mut [[0.0; ACT]; B2], &mut [[0.0; TRI]; B2]);
    net.transpose_into(&mut t);
    net.backprop(&mut t1, &dm1, &dc1, &t);
    net.backprop(&mut t2, &dm2, &dc2, &t);
    let inputs = ActorGradInputs {
        obs: &[&o1[..], &o2[..]],
        h1: &[&t1.h1[..], &t2.h1[..]],
        h2: &[&t1.h2[..], &t2.h2[..]],
        d_h1: &[&t1.d_h1[..], &t2.d_h1[..]],
        d_h2: &[&t1.d_h2[..], &t2.d_h2[..]],
        d_mean: &[&dm1[..], &dm2[..]],
        d_chol: &[&dc1[..], &dc2[..]],
    };
    let mut blocked = Net::zeroed();
    let mut parts = blocked.grad_parts(5);
    assert!(parts.len() >= 6, "{} blocks", parts.len());
    let mut sq = 0f64;
    for p in parts.iter_mut().rev() {
        sq += p.compute(&inputs);
    }
    drop(parts);
    assert!(whole.bits_eq(&blocked), "chunked, blocked gradient differs");
    let norm = whole.global_norm() as f64;
    assert!(
        (sq.sqrt() - norm).abs() <= 1e-6 * norm,
        "{} vs {norm}",
        sq.sqrt()
    );
}
