//! The policy Gaussian against direct formulas, sample statistics and finite differences.

#![allow(clippy::needless_range_loop)]

use mpo_core::gaussian::{
    Gaussian, GaussianGrad, SampleStats, head_backward, kl_parts, kl_parts_grad, kl_per_dim,
    kl_per_dim_grad, softplus, softplus_inverse, tri_index, weighted_log_prob_cov,
    weighted_log_prob_mean,
};
use mpo_core::rng::Rng;
use nalgebra::{SMatrix, SVector};

const A: usize = 3;
const T: usize = 6;
const FLOOR: f32 = 1e-3;

fn random_head(rng: &mut Rng) -> ([f32; A], [f32; T]) {
    let mut m = [0f32; A];
    let mut c = [0f32; T];
    rng.fill_normal(&mut m);
    rng.fill_normal(&mut c);
    for x in &mut c {
        *x *= 0.5;
    }
    (m, c)
}

fn sigma_f64(g: &Gaussian<A>) -> SMatrix<f64, A, A> {
    let l = SMatrix::<f64, A, A>::from_fn(|r, c| g.l[r][c] as f64);
    l * l.transpose()
}

fn mu_f64(g: &Gaussian<A>) -> SVector<f64, A> {
    SVector::<f64, A>::from_fn(|r, _| g.mu[r] as f64)
}

/// KL(p || q) for Gaussians, straight from the textbook formula with explicit inverses.
fn kl_direct(p: &Gaussian<A>, q: &Gaussian<A>) -> f64 {
    let (sp, sq) = (sigma_f64(p), sigma_f64(q));
    let sq_inv = sq.try_inverse().unwrap();
    let d = mu_f64(q) - mu_f64(p);
    0.5 * ((sq_inv * sp).trace() + (d.transpose() * sq_inv * d)[0] - A as f64
        + (sq.determinant() / sp.determinant()).ln())
}

#[test]
fn log_prob_matches_direct_formula() {
    let mut rng = Rng::seed_from_u64(11);
    for _ in 0..50 {
        let (m, c) = random_head(&mut rng);
        let g = Gaussian::from_head(&m, &c, FLOOR);
        let mut a = [0f32; A];
        rng.fill_normal(&mut a);
        let s = sigma_f64(&g);
        let d = SVector::<f64, A>::from_fn(|r, _| a[r] as f64) - mu_f64(&g);
        let direct = -0.5 * (d.transpose() * s.try_inverse().unwrap() * d)[0]
            - 0.5 * s.determinant().ln()
            - 0.5 * A as f64 * (2.0 * std::f64::consts::PI).ln();
        let ours = g.log_prob(&a) as f64;
        assert!(
            (ours - direct).abs() < 1e-4 * (1.0 + direct.abs()),
            "{ours} vs {direct}"
        );
        // Entropy against the closed form 0.5 ln det(2 pi e Sigma).
        let h = 0.5
            * ((2.0 * std::f64::consts::PI * std::f64::consts::E).powi(A as i32) * s.determinant())
                .ln();
        assert!((g.entropy() as f64 - h).abs() < 1e-4, "entropy");
    }
}

/// Both branches of the softplus and its inverse (the inverse sets the policy's initial
/// standard deviation): against `ln(1 + e^x)` and `ln(e^y - 1)` in f64, and past the switch at
/// 20, where the f32 exponential would overflow to infinity without it.
#[test]
fn softplus_and_its_inverse_match_f64_on_both_branches() {
    for i in 0..=260 {
        let x = -10.0 + 0.5 * i as f32; // -10 ..= 120
        let want = (1.0 + (x as f64).exp()).ln();
        let got = softplus(x) as f64;
        assert!(
            (got - want).abs() <= 1e-6 * (1.0 + want),
            "softplus({x}) = {got}, want {want}"
        );
    }
    for i in 1..=240 {
        let y = 0.5 * i as f32; // 0.5 ..= 120
        let want = ((y as f64).exp_m1()).ln();
        let got = softplus_inverse(y) as f64;
        assert!(
            (got - want).abs() <= 1e-5 * (1.0 + want.abs()),
            "softplus_inverse({y}) = {got}, want {want}"
        );
        let back = softplus(softplus_inverse(y));
        assert!(
            (back - y).abs() <= 1e-5 * y,
            "softplus(softplus_inverse({y})) = {back}"
        );
    }
    // Small scales, as a policy initialised near its floor would ask.
    for y in [1e-3f32, 1e-2, 0.1] {
        let want = ((y as f64).exp_m1()).ln();
        assert!(
            (softplus_inverse(y) as f64 - want).abs() < 1e-4 * want.abs(),
            "softplus_inverse({y})"
        );
    }
}

/// `transform` is `mu + L z` and `std_devs` the square roots of `diag(L L^T)`, written out in f64.
#[test]
fn transform_and_std_devs_are_the_factor_written_out() {
    let mut rng = Rng::seed_from_u64(23);
    for _ in 0..50 {
        let (m, c) = random_head(&mut rng);
        let g = Gaussian::from_head(&m, &c, FLOOR);
        let mut z = [0f32; A];
        rng.fill_normal(&mut z);
        let mut a = [0f32; A];
        g.transform(&z, &mut a);
        let s = sigma_f64(&g);
        let sd = g.std_devs();
        for j in 0..A {
            let mut want = g.mu[j] as f64;
            for k in 0..=j {
                want += g.l[j][k] as f64 * z[k] as f64;
            }
            assert!(
                (a[j] as f64 - want).abs() < 1e-5 * (1.0 + want.abs()),
                "a[{j}]"
            );
            let sd_want = s[(j, j)].sqrt();
            assert!(
                (sd[j] as f64 - sd_want).abs() < 1e-5 * sd_want,
                "std[{j}] {} vs {sd_want}",
                sd[j]
            );
        }
    }
}

#[test]
fn samples_have_the_right_mean_and_covariance() {
    let mut rng = Rng::seed_from_u64(12);
    let (m, c) = random_head(&mut rng);
    let g = Gaussian::from_head(&m, &c, FLOOR);
    let n = 400_000;
    let mut sum = SVector::<f64, A>::zeros();
    let mut sum2 = SMatrix::<f64, A, A>::zeros();
    let mut a = [0f32; A];
    for _ in 0..n {
        g.sample(&mut rng, &mut a);
        let v = SVector::<f64, A>::from_fn(|r, _| a[r] as f64);
        sum += v;
        sum2 += v * v.transpose();
    }
    let mean = sum / n as f64;
    let cov = sum2 / n as f64 - mean * mean.transpose();
    let s = sigma_f64(&g);
    for r in 0..A {
        let sd = s[(r, r)].sqrt();
        // Standard error of the mean is sd / sqrt(n) ~ sd * 1.6e-3: allow 5 of them.
        assert!(
            (mean[r] - g.mu[r] as f64).abs() < 5.0 * sd / (n as f64).sqrt(),
            "mean {r}"
        );
        for k in 0..A {
            let scale = (s[(r, r)] * s[(k, k)]).sqrt();
            assert!(
                (cov[(r, k)] - s[(r, k)]).abs() < 0.01 * scale,
                "cov {r},{k}: {} vs {}",
                cov[(r, k)],
                s[(r, k)]
            );
        }
    }
}

#[test]
fn kl_parts_sum_to_the_full_kl_and_vanish_at_equality() {
    let mut rng = Rng::seed_from_u64(13);
    for _ in 0..50 {
        let (m1, c1) = random_head(&mut rng);
        let (m2, c2) = random_head(&mut rng);
        let p = Gaussian::from_head(&m1, &c1, FLOOR);
        let q = Gaussian::from_head(&m2, &c2, FLOOR);
        let parts = kl_parts(&p, &q);
        let direct = kl_direct(&p, &q);
        assert!(parts.mean >= 0.0 && parts.cov >= 0.0);
        assert!(
            (parts.total() as f64 - direct).abs() < 1e-4 * (1.0 + direct),
            "{parts:?} vs {direct}"
        );
        // The mean part alone is the KL to the distribution with the old covariance... when
        // the covariances agree: KL(p || N(mu_q, Sigma_p)) has no covariance part.
        let q_mean_only = Gaussian { mu: q.mu, l: p.l };
        let mo = kl_parts(&p, &q_mean_only);
        assert!(
            mo.cov.abs() < 1e-6,
            "cov part with equal covariances: {}",
            mo.cov
        );
        assert!(
            (mo.mean as f64 - kl_direct(&p, &q_mean_only)).abs() < 1e-4 * (1.0 + mo.mean as f64)
        );
        let same = kl_parts(&p, &p);
        assert_eq!(same.mean, 0.0);
        assert!(same.cov.abs() < 1e-6, "KL(p||p) cov part {}", same.cov);
    }
}

const PD_MEAN: [f32; A] = [0.3, 1.7, 0.9];
const PD_COV: [f32; A] = [2.0, 0.5, 1.1];

/// The scalar function of the raw head outputs whose gradient is checked.
fn objective(which: usize, old: &Gaussian<A>, a: &[f32; A], m: &[f32; A], c: &[f32; T]) -> f64 {
    let g = Gaussian::from_head(m, c, FLOOR);
    match which {
        0 => g.log_prob(a) as f64,
        1 => kl_parts(old, &g).mean as f64,
        2 => kl_parts(old, &g).cov as f64,
        _ => {
            // A weighted sum of the per-dimension parts (the per-dimension constraints).
            let p = kl_per_dim(old, &g);
            (0..A)
                .map(|j| PD_MEAN[j] as f64 * p.mean[j] as f64 + PD_COV[j] as f64 * p.cov[j] as f64)
                .sum()
        }
    }
}

#[test]
fn gradients_match_central_differences() {
    let mut rng = Rng::seed_from_u64(14);
    let mut worst = 0f64;
    for trial in 0..30 {
        let (m, c) = random_head(&mut rng);
        let (mo, co) = random_head(&mut rng);
        let old = Gaussian::from_head(&mo, &co, FLOOR);
        let mut a = [0f32; A];
        rng.fill_normal(&mut a);
        let g = Gaussian::from_head(&m, &c, FLOOR);
        for which in 0..4 {
            let mut gg = GaussianGrad::ZERO;
            match which {
                0 => {
                    g.log_prob_grad(&a, 1.0, &mut gg);
                }
                1 => {
                    kl_parts_grad(&old, &g, 1.0, 0.0, &mut gg);
                }
                2 => {
                    kl_parts_grad(&old, &g, 0.0, 1.0, &mut gg);
                }
                _ => {
                    kl_per_dim_grad(&old, &g, &PD_MEAN, &PD_COV, &mut gg);
                }
            }
            let mut dm = [0f32; A];
            let mut dc = [0f32; T];
            head_backward(&c, &gg, &mut dm, &mut dc);
            // Central differences in f32 on the raw outputs, step 1e-2: truncation error
            // O(h^2) and rounding error O(eps_f32 |f| / h) ~ 1e-5 |f|.
            let h = 1e-2f32;
            let check = |analytic: f32, plus: f64, minus: f64, what: &str| -> f64 {
                let fd = (plus - minus) / (2.0 * h as f64);
                let err =
                    (analytic as f64 - fd).abs() / (1e-2 + fd.abs().max(analytic.abs() as f64));
                assert!(
                    err < 1e-2,
                    "trial {trial} obj {which} {what}: analytic {analytic} fd {fd}"
                );
                err
            };
            for j in 0..A {
                let (mut mp, mut mm) = (m, m);
                mp[j] += h;
                mm[j] -= h;
                let e = check(
                    dm[j],
                    objective(which, &old, &a, &mp, &c),
                    objective(which, &old, &a, &mm, &c),
                    "mean",
                );
                worst = worst.max(e);
            }
            for t in 0..T {
                let (mut cp, mut cm) = (c, c);
                cp[t] += h;
                cm[t] -= h;
                let e = check(
                    dc[t],
                    objective(which, &old, &a, &m, &cp),
                    objective(which, &old, &a, &m, &cm),
                    "chol",
                );
                worst = worst.max(e);
            }
        }
    }
    // The bound asserted per entry is 1e-2 relative (seen: about 2e-3); report the worst seen.
    eprintln!("worst relative error {worst:.2e}");
    let _ = tri_index(0, 0);
}

/// The M-step's closed forms over [`SampleStats`] equal the weighted sum of per-sample
/// log-densities and their gradients (`log_prob_grad`, one triangular solve per sample), for
/// the mean half (`N(mu, Sigma_old)`) and the covariance half (`N(mu_old, Sigma)`).
#[test]
fn sample_statistics_give_the_summed_likelihood_and_its_gradients() {
    let mut rng = Rng::seed_from_u64(21);
    let mut worst = 0f64;
    for _ in 0..50 {
        let (m0, c0) = random_head(&mut rng);
        let (m1, c1) = random_head(&mut rng);
        let old = Gaussian::from_head(&m0, &c0, FLOOR);
        let new = Gaussian::from_head(&m1, &c1, FLOOR);
        let mut st = SampleStats::ZERO;
        let (mut ref_m, mut ref_c) = (0f64, 0f64);
        let (mut gm_ref, mut gc_ref) = (GaussianGrad::<A>::ZERO, GaussianGrad::<A>::ZERO);
        let pi_mean = Gaussian {
            mu: new.mu,
            l: old.l,
        };
        let pi_cov = Gaussian {
            mu: old.mu,
            l: new.l,
        };
        for _ in 0..7 {
            let mut a = [0f32; A];
            old.sample(&mut rng, &mut a);
            let w = 0.05 + rng.uniform();
            st.add(w, &a, &old.mu);
            ref_m += w as f64 * pi_mean.log_prob_grad(&a, w, &mut gm_ref) as f64;
            ref_c += w as f64 * pi_cov.log_prob_grad(&a, w, &mut gc_ref) as f64;
        }
        let (mut gm, mut gc) = (GaussianGrad::<A>::ZERO, GaussianGrad::<A>::ZERO);
        let vm = weighted_log_prob_mean(&old, &new.mu, &st, 1.0, &mut gm) as f64;
        let vc = weighted_log_prob_cov(&new, &st, 1.0, &mut gc) as f64;
        let rel = |a: f64, b: f64| (a - b).abs() / (1.0 + a.abs().max(b.abs()));
        worst = worst.max(rel(vm, ref_m)).max(rel(vc, ref_c));
        assert!(rel(vm, ref_m) < 1e-4, "mean half {vm} vs {ref_m}");
        assert!(rel(vc, ref_c) < 1e-4, "covariance half {vc} vs {ref_c}");
        for j in 0..A {
            assert!(
                rel(gm.mu[j] as f64, gm_ref.mu[j] as f64) < 1e-4,
                "d/d mu {j}"
            );
            for k in 0..=j {
                let (x, y) = (gc.l[j][k] as f64, gc_ref.l[j][k] as f64);
                worst = worst.max(rel(x, y));
                assert!(rel(x, y) < 1e-4, "d/d L[{j}][{k}]: {x} vs {y}");
            }
        }
    }
    eprintln!("sample statistics vs per-sample sums: worst relative difference {worst:.2e}");
}
