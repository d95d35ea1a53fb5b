//! E-step: the temperature solver against brute-force minimisation of the dual, the KL
//! constraint, and invariance of the weights to the scale and offset of Q.

#![allow(clippy::needless_range_loop)]

use mpo_core::estep::{solve_temperature, weights};
use mpo_core::rng::Rng;

const B: usize = 64;
const M: usize = 20;
const EPS: f32 = 0.1;

fn random_q(rng: &mut Rng, scale: f32) -> Vec<[f32; M]> {
    (0..B)
        .map(|_| {
            let offset = rng.normal() * 3.0;
            let spread = 0.2 + rng.uniform() * 2.0;
            let mut row = [0f32; M];
            for x in &mut row {
                // On a 1/8 grid so that adding 1e6 is exact in f32 (ulp of 1e6 is 1/16):
                // the shift test then measures the algorithm, not input rounding.
                *x = (((offset + spread * rng.normal()) * scale) * 8.0).round() / 8.0;
            }
            row
        })
        .collect()
}

/// The sample-based dual written out as the paper states it,
/// `g(eta) = eta eps + eta mean_i log mean_j exp(Q_ij / eta)`, in f64 with a plain
/// log-sum-exp around each state's largest value: no code shared with the solver.
fn naive_dual(q: &[[f32; M]], eta: f64) -> f64 {
    let mut total = 0.0;
    for row in q {
        let vals: Vec<f64> = row.iter().map(|&v| v as f64 / eta).collect();
        let mx = vals.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let mean_exp = vals.iter().map(|v| (v - mx).exp()).sum::<f64>() / M as f64;
        total += mx + mean_exp.ln();
    }
    eta * EPS as f64 + eta * total / q.len() as f64
}

/// Golden-section search of the naive dual over ln(eta), after a coarse grid scan: no
/// derivatives, no shared code with the solver.
fn brute_force_eta(q: &[[f32; M]]) -> f64 {
    let g = |u: f64| naive_dual(q, u.exp());
    let mut best = (f64::INFINITY, 0.0);
    let mut u = -18.0;
    while u <= 28.0 {
        let v = g(u);
        if v < best.0 {
            best = (v, u);
        }
        u += 0.01;
    }
    let (mut a, mut b) = (best.1 - 0.02, best.1 + 0.02);
    let r = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..200 {
        let c = b - r * (b - a);
        let d = a + r * (b - a);
        if g(c) < g(d) {
            b = d;
        } else {
            a = c;
        }
    }
    (0.5 * (a + b)).exp()
}

#[test]
fn eta_matches_brute_force_minimisation_and_kl_meets_the_bound() {
    let mut rng = Rng::seed_from_u64(21);
    let mut worst_eta = 0f64;
    let mut worst_kl = 0f64;
    for trial in 0..20 {
        let scale = 1.0 + 10.0 * rng.uniform();
        let q = random_q(&mut rng, scale);
        let s = solve_temperature(&q, EPS, 1.0, 1e-9, 100);
        assert!(s.converged, "trial {trial}: {s:?}");
        // The solver's dual value at its solution is the naive formula's.
        let g = naive_dual(&q, s.eta as f64);
        assert!(
            (s.dual - g).abs() < 1e-6 * g.abs().max(1.0),
            "dual {} vs {g}",
            s.dual
        );
        let brute = brute_force_eta(&q);
        let rel = (s.eta as f64 - brute).abs() / brute;
        assert!(
            rel < 1e-5,
            "trial {trial}: eta {} brute force {brute} (rel {rel:.2e})",
            s.eta
        );
        // The constraint binds (log M = 3.0 > eps): KL(weights || sampling) = eps within 1%.
        let mut w = vec![[0f32; M]; B];
        let kl = weights(&q, s.eta, &mut w);
        let kl_rel = (kl - EPS as f64).abs() / EPS as f64;
        assert!(kl_rel < 0.01, "trial {trial}: KL {kl}");
        for row in &w {
            let sum: f32 = row.iter().sum();
            assert!((sum - 1.0).abs() < 1e-5);
        }
        worst_eta = worst_eta.max(rel);
        worst_kl = worst_kl.max(kl_rel);
    }
    eprintln!("worst eta relative error {worst_eta:.2e}, worst KL relative error {worst_kl:.2e}");
}

#[test]
fn weights_are_invariant_to_scaling_and_shifting_q() {
    let mut rng = Rng::seed_from_u64(22);
    for _ in 0..10 {
        let q = random_q(&mut rng, 1.0);
        let base = solve_temperature(&q, EPS, 1.0, 1e-9, 100);
        let mut w0 = vec![[0f32; M]; B];
        weights(&q, base.eta, &mut w0);
        for (label, f) in [
            (
                "scaled by 1e6",
                Box::new(|x: f32| x * 1e6) as Box<dyn Fn(f32) -> f32>,
            ),
            ("shifted by 1e6", Box::new(|x: f32| x + 1e6)),
        ] {
            let q2: Vec<[f32; M]> = q.iter().map(|r| r.map(&f)).collect();
            // Warm start from the unscaled temperature: the solver must travel far.
            let s = solve_temperature(&q2, EPS, base.eta, 1e-9, 100);
            assert!(s.converged && s.eta.is_finite(), "{label}: {s:?}");
            let mut w = vec![[0f32; M]; B];
            weights(&q2, s.eta, &mut w);
            for (a, b) in w.iter().flatten().zip(w0.iter().flatten()) {
                assert!(a.is_finite());
                assert!((a - b).abs() < 1e-6, "{label}: weight {a} vs {b}");
            }
        }
    }
}

#[test]
fn solver_is_deterministic_and_cheap_from_a_warm_start() {
    let mut rng = Rng::seed_from_u64(23);
    let q = random_q(&mut rng, 5.0);
    let a = solve_temperature(&q, EPS, 1.0, 1e-6, 100);
    let b = solve_temperature(&q, EPS, 1.0, 1e-6, 100);
    assert_eq!(a.eta.to_bits(), b.eta.to_bits());
    let warm = solve_temperature(&q, EPS, a.eta * 1.1, 1e-6, 100);
    assert!(
        warm.iterations <= 5,
        "warm start took {} iterations",
        warm.iterations
    );
}

/// The problems of the tests above at several scales, for the solver's paths.
fn problems() -> Vec<Vec<[f32; M]>> {
    let mut rng = Rng::seed_from_u64(24);
    [0.01f32, 1.0, 30.0, 1e4]
        .iter()
        .map(|&scale| random_q(&mut rng, scale))
        .collect()
}

/// Cold starts anywhere in the temperature range converge in Newton's time: Newton steps
/// (limited to a factor e^4 until the root is bracketed) converge quadratically, while
/// bisection over the bracket `[ln 1e-8, ln 1e12]` (46 wide) would need about 35 halvings to
/// reach `|h| <= 1e-9 eps`. At the solution the KL meets the bound and the reported KL and dual
/// are those of the returned temperature.
#[test]
fn cold_starts_converge_in_newton_time_to_the_bound() {
    let mut worst = 0;
    for q in problems() {
        let want = brute_force_eta(&q);
        for start in [1e-7f32, 1e-3, 1.0, 1e3, 1e7, 1e11] {
            let s = solve_temperature(&q, EPS, start, 1e-9, 100);
            assert!(s.converged, "start {start}: {s:?}");
            assert!(
                ((s.eta as f64 - want) / want).abs() < 1e-5,
                "start {start}: {s:?} vs {want}"
            );
            assert!(
                (s.kl - EPS as f64).abs() <= 1e-9 * EPS as f64 + 1e-12,
                "{s:?}"
            );
            let mut w = vec![[0f32; M]; B];
            let kl = weights(&q, s.eta, &mut w);
            assert!((kl - s.kl).abs() < 1e-4, "reported KL {} vs {kl}", s.kl);
            assert!((s.dual - naive_dual(&q, s.eta as f64)).abs() < 1e-6 * s.dual.abs().max(1.0));
            // Distance to the root in ln eta, in limited steps of 4, plus Newton's few.
            let far = ((start as f64).ln() - want.ln()).abs();
            let bound = (far / 4.0).ceil() as u32 + 8;
            assert!(
                s.iterations <= bound,
                "start {start}: {} > {bound} iterations",
                s.iterations
            );
            worst = worst.max(s.iterations);
        }
    }
    eprintln!("most iterations from a cold start: {worst}");
}

/// A bound the KL cannot reach (above `ln M`, the KL of weights on one sample) or a batch
/// whose values are all equal (KL 0 at every temperature): the solver walks down to the
/// smallest temperature in steps of e^4, evaluates it, reports no convergence, and stops.
#[test]
fn unreachable_bounds_end_at_the_smallest_temperature() {
    let q = &problems()[1];
    let flat = vec![[2.5f32; M]; B];
    for (label, q, eps) in [("eps > ln M", q, 3.5f32), ("equal values", &flat, EPS)] {
        for start in [1e-8f32, 1e-5, 1.0, 1e6] {
            let s = solve_temperature(q, eps, start, 1e-9, 100);
            assert!(!s.converged, "{label}, start {start}: {s:?}");
            assert_eq!(
                s.eta,
                mpo_core::estep::ETA_MIN as f32,
                "{label}, start {start}"
            );
            assert!(s.kl < eps as f64, "{label}: {s:?}");
            let steps = ((start as f64).ln() - mpo_core::estep::ETA_MIN.ln()) / 4.0;
            assert!(
                s.iterations <= steps.ceil() as u32 + 2,
                "{label}, start {start}: {s:?}"
            );
        }
    }
}

/// Values so spread that even the largest temperature leaves the weights on one sample
/// (KL above the bound everywhere): the solver walks up to the largest temperature and stops
/// there, unconverged.
#[test]
fn a_bound_beyond_the_largest_temperature_ends_there() {
    let mut rng = Rng::seed_from_u64(25);
    let q: Vec<[f32; M]> = (0..B)
        .map(|_| core::array::from_fn(|_| 1e16 * rng.normal()))
        .collect();
    for start in [1.0f32, 1e9, 1e12] {
        let s = solve_temperature(&q, EPS, start, 1e-9, 100);
        assert!(!s.converged, "start {start}: {s:?}");
        assert_eq!(s.eta, mpo_core::estep::ETA_MAX as f32, "start {start}");
        assert!(s.kl > EPS as f64, "{s:?}");
        let steps = (mpo_core::estep::ETA_MAX.ln() - (start as f64).ln()) / 4.0;
        assert!(
            s.iterations <= steps.ceil() as u32 + 2,
            "start {start}: {s:?}"
        );
    }
}

/// `max_iter` is the number of evaluations an unconverged solve makes, and the result is
/// always the last temperature evaluated: with one evaluation allowed, the start itself.
#[test]
fn max_iter_bounds_the_work() {
    let q = &problems()[2];
    for max_iter in 1..6 {
        let s = solve_temperature(q, EPS, 1e6, 1e-12, max_iter);
        assert_eq!(s.iterations, max_iter, "{s:?}");
        assert!(!s.converged, "{max_iter}: {s:?}");
        let g = naive_dual(q, s.eta as f64);
        assert!(
            (s.dual - g).abs() < 1e-6 * g.abs().max(1.0),
            "{max_iter}: {s:?}"
        );
    }
    let one = solve_temperature(q, EPS, 1e6, 1e-12, 1);
    assert_eq!((one.eta, one.iterations), (1e6, 1));
}

/// With a tolerance of 0 (never met exactly) the solver stops once the bracket around the
/// root is narrower than 1e-12 in `ln eta`, long before a generous `max_iter`, at the root.
#[test]
fn a_collapsed_bracket_stops_the_solver() {
    for q in problems() {
        let s = solve_temperature(&q, EPS, 1.0, 0.0, 1000);
        assert!(s.iterations < 100, "{s:?}");
        let want = brute_force_eta(&q);
        assert!(
            ((s.eta as f64 - want) / want).abs() < 1e-5,
            "{s:?} vs {want}"
        );
    }
}

/// The temperatures the solver evaluates, recorded through `solve_temperature_with`: before
/// the root is bracketed each move is at most 4 in `ln eta`, and once a point on each side
/// of the root has been evaluated every later point lies between the closest two (Newton
/// inside the bracket, else bisection): the safeguards, observed directly. A point's side is
/// the sign of `eps - KL` there (KL below the bound: above the root).
#[test]
fn evaluated_temperatures_stay_inside_the_bracket() {
    use mpo_core::estep::{DualSums, dual_row, solve_temperature_with};
    // The four problems of the other tests, then batches with a few outlying values, whose
    // KL curve bends sharply (Newton steps from below the root overshoot the bracket there).
    let mut rng = Rng::seed_from_u64(26);
    let mut all = problems();
    for k in 0..40 {
        let mut q = random_q(&mut rng, 1.0 + k as f32);
        for row in q.iter_mut().step_by(3) {
            row[k % M] += 50.0 * (1 + k % 4) as f32;
        }
        all.push(q);
    }
    for q in all {
        for start in [1e-7f32, 1e-2, 0.3, 3.0, 1e4, 1e11] {
            let mut seen: Vec<(f64, f64)> = Vec::new();
            let mut eval = |eta: f64| {
                let mut s = DualSums::default();
                for row in &q {
                    s.add(&dual_row(row, eta));
                }
                seen.push((eta.ln(), EPS as f64 - s.kl / s.rows as f64));
                s
            };
            let s = solve_temperature_with(EPS, start, 1e-9, 100, &mut eval);
            assert!(s.converged, "{s:?}");
            let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
            for w in seen.windows(2) {
                let ((u, h), (next, _)) = (w[0], w[1]);
                if h > 0.0 {
                    hi = hi.min(u);
                } else {
                    lo = lo.max(u);
                }
                if lo.is_finite() && hi.is_finite() {
                    assert!(
                        next > lo && next < hi,
                        "{next} outside ({lo}, {hi}): {seen:?}"
                    );
                } else {
                    assert!(
                        (next - u).abs() <= 4.0 + 1e-12,
                        "unbracketed step {u} -> {next}"
                    );
                }
            }
        }
    }
}

/// Samples whose weight underflows to exactly 0 in f64 (a value 1000 below the state's best at
/// temperature 1) contribute nothing to the KL: `0 ln 0` is taken as 0, not as NaN. With one
/// sample far above the rest, the weights are one-hot and the KL from uniform is `ln M`.
#[test]
fn underflowing_weights_are_zero_and_the_kl_stays_finite() {
    let mut q = vec![[0f32; M]; 4];
    for (i, row) in q.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = if j == i { 500.0 } else { -500.0 - j as f32 };
        }
    }
    let mut w = vec![[0f32; M]; 4];
    let kl = weights(&q, 1.0, &mut w);
    assert!((kl - (M as f64).ln()).abs() < 1e-12, "kl {kl}, want ln M");
    for (i, row) in w.iter().enumerate() {
        for (j, &x) in row.iter().enumerate() {
            assert_eq!(x, if j == i { 1.0 } else { 0.0 }, "w[{i}][{j}]");
        }
    }
}
