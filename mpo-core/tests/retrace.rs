//! Retrace targets against a direct evaluation of the paper's sum (eq. 11), and n-step
//! transitions against their definition.

#![allow(clippy::needless_range_loop)]

use mpo_core::evaluation::{nstep, retrace};
use mpo_core::rng::Rng;

/// `Q_ret(t) = Q(t) + sum_{j>=t} gamma^{j-t} (prod_{k=t+1..j} c_k d_{k-1})
///   [r_j + gamma d_j V(j+1) - Q(j)]`, summed term by term in f64.
fn direct(q: &[f32], v: &[f32], r: &[f32], d: &[f32], c: &[f64], gamma: f64, t: usize) -> f64 {
    let mut total = q[t] as f64;
    for j in t..q.len() {
        let mut w = gamma.powi((j - t) as i32);
        for k in t + 1..=j {
            w *= c[k] * d[k - 1] as f64;
        }
        total += w * (r[j] as f64 + gamma * d[j] as f64 * v[j] as f64 - q[j] as f64);
    }
    total
}

#[test]
fn retrace_matches_the_direct_sum_on_random_chains() {
    let mut rng = Rng::seed_from_u64(31);
    for trial in 0..200 {
        let l = 1 + (trial % 8);
        let mut q = vec![0f32; l];
        let mut v = vec![0f32; l];
        let mut r = vec![0f32; l];
        let mut lr = vec![0f32; l];
        let d: Vec<f32> = (0..l)
            .map(|_| if rng.uniform() < 0.15 { 0.0 } else { 1.0 })
            .collect();
        rng.fill_normal(&mut q);
        rng.fill_normal(&mut v);
        rng.fill_normal(&mut r);
        rng.fill_normal(&mut lr);
        let c: Vec<f64> = lr.iter().map(|x| (*x as f64).min(0.0).exp()).collect();
        let mut out = vec![0f32; l];
        retrace(&q, &v, &r, &d, &lr, 0.95, &mut out);
        for t in 0..l {
            let want = direct(&q, &v, &r, &d, &c, 0.95, t);
            assert!(
                (out[t] as f64 - want).abs() < 1e-4 * (1.0 + want.abs()),
                "trial {trial} t {t}: {} vs {want}",
                out[t]
            );
        }
    }
}

#[test]
fn retrace_recovers_known_values_on_a_deterministic_chain() {
    // A 5-state chain with reward 1 per step and a terminal after the last: the true values
    // under any policy are Q_t = sum_{k<5-t} gamma^k. With exact Q and V, every Retrace target
    // equals the true value whatever the traces; with Q = 0 and V = 0 and on-policy traces
    // (c = 1) Retrace is the Monte Carlo return, which is the same number.
    let gamma = 0.9f32;
    let truth: Vec<f32> = (0..5)
        .map(|t| (0..5 - t).map(|k| gamma.powi(k)).sum())
        .collect();
    let r = [1f32; 5];
    let d = [1f32, 1.0, 1.0, 1.0, 0.0];
    let v_exact: Vec<f32> = (0..5)
        .map(|t| if t + 1 < 5 { truth[t + 1] } else { 0.0 })
        .collect();
    let mut out = [0f32; 5];
    retrace(
        &truth,
        &v_exact,
        &r,
        &d,
        &[-0.7, 0.3, -2.0, 0.0, -0.1],
        gamma,
        &mut out,
    );
    for t in 0..5 {
        assert!((out[t] - truth[t]).abs() < 1e-5, "exact values, t {t}");
    }
    retrace(&[0.0; 5], &[0.0; 5], &r, &d, &[0.0; 5], gamma, &mut out);
    for t in 0..5 {
        assert!(
            (out[t] - truth[t]).abs() < 1e-5,
            "Monte Carlo, t {t}: {} vs {}",
            out[t],
            truth[t]
        );
    }
    // Fully off-policy traces (c = 0) reduce Retrace to one-step TD targets.
    retrace(&[0.0; 5], &[2.0; 5], &r, &d, &[-100.0; 5], gamma, &mut out);
    for t in 0..5 {
        let td = 1.0 + gamma * d[t] * 2.0;
        assert!((out[t] - td).abs() < 1e-5, "TD, t {t}");
    }
}

#[test]
fn nstep_transition_equals_its_definition() {
    let gamma = 0.99f32;
    let rewards = [0.5f32, -1.0, 2.0, 0.25, 1.0];
    let (r, m) = nstep(&rewards, &[1.0; 5], gamma);
    let want: f32 = rewards
        .iter()
        .enumerate()
        .map(|(k, x)| gamma.powi(k as i32) * x)
        .sum();
    assert!((r - want).abs() < 1e-6);
    assert!((m - gamma.powi(5)).abs() < 1e-7);
}
