//! The categorical critic's target projection on small cases written out by hand: two-hot
//! (the two atoms around the target, weighted so their mean is the target) and HL-Gauss (the
//! mass of a Gaussian on each atom's bin, renormalised), with targets inside, on and outside
//! the support; and the head's expectation and cross-entropy gradient.

use mpo_core::config::MpoConfig;
use mpo_core::value_head::{Support, loss, project, softmax, values};

fn close(a: &[f32], b: &[f64], tol: f64) {
    assert_eq!(a.len(), b.len());
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(
            (*x as f64 - y).abs() <= tol,
            "atom {k}: {x} vs {y} ({a:?} vs {b:?})"
        );
    }
}

/// Atoms -1, -0.5, 0, 0.5, 1.
const FIVE: Support = Support {
    min: -1.0,
    max: 1.0,
    sigma: 0.0,
    floor: 40.0,
};

#[test]
fn two_hot_splits_the_mass_between_the_neighbouring_atoms() {
    let mut t = [0f32; 5];
    // 0.2 lies 0.4 of the way from atom 2 (0) to atom 3 (0.5).
    project(&FIVE, 0.2, &mut t);
    close(&t, &[0.0, 0.0, 0.6, 0.4, 0.0], 1e-6);
    // On an atom: all of it there.
    project(&FIVE, -0.5, &mut t);
    close(&t, &[0.0, 1.0, 0.0, 0.0, 0.0], 1e-6);
    // Half-way.
    project(&FIVE, 0.75, &mut t);
    close(&t, &[0.0, 0.0, 0.0, 0.5, 0.5], 1e-6);
    // The ends, and beyond them (clamped).
    project(&FIVE, 1.0, &mut t);
    close(&t, &[0.0, 0.0, 0.0, 0.0, 1.0], 1e-6);
    project(&FIVE, 7.0, &mut t);
    close(&t, &[0.0, 0.0, 0.0, 0.0, 1.0], 1e-6);
    project(&FIVE, -1.0, &mut t);
    close(&t, &[1.0, 0.0, 0.0, 0.0, 0.0], 1e-6);
    project(&FIVE, -3.0, &mut t);
    close(&t, &[1.0, 0.0, 0.0, 0.0, 0.0], 1e-6);
}

#[test]
fn hl_gauss_is_the_gaussian_mass_of_each_bin() {
    // Atoms 0, 1, 2 (bins [-0.5, 0.5], [0.5, 1.5], [1.5, 2.5]); sigma 0.75 spacings = 0.75.
    let s = Support {
        min: 0.0,
        max: 2.0,
        sigma: 0.75,
        floor: 40.0,
    };
    let mut t = [0f32; 3];
    // y = 1: the edges are -2, -2/3, 2/3, 2 standard deviations away. Phi(-2) = 0.0227501,
    // Phi(-2/3) = 0.2524925: masses 0.2297424, 0.4950149, 0.2297424 of 0.9544997.
    project(&s, 1.0, &mut t);
    close(&t, &[0.2406940, 0.5186119, 0.2406940], 2e-6);
    // y = 0: edges -2/3, 2/3, 2, 10/3 standard deviations. Phi(2/3) = 0.7475075,
    // Phi(2) = 0.9772499, Phi(10/3) = 0.9995709: masses 0.4950150, 0.2297424, 0.0223210 of
    // 0.7470784.
    project(&s, 0.0, &mut t);
    close(&t, &[0.6626010, 0.3075211, 0.0298778], 2e-6);
    // Beyond the support: clamped to its end first, so the same as y = 0.
    let mut u = [0f32; 3];
    project(&s, -5.0, &mut u);
    assert_eq!(t, u);
}

#[test]
fn the_value_is_the_expectation_and_the_gradient_is_p_minus_t() {
    let cfg = MpoConfig {
        value_min: -1.0,
        value_max: 1.0,
        value_sigma: 0.0,
        ..MpoConfig::REPORT
    };
    let s = Support::of(&cfg);
    assert_eq!(s, FIVE);
    let out = [[0.5f32, -1.0, 2.0, 0.0, 1.0]];
    // softmax written out: e^x / sum e^x.
    let e: Vec<f64> = out[0].iter().map(|&x| (x as f64).exp()).collect();
    let z: f64 = e.iter().sum();
    let p: Vec<f64> = e.iter().map(|v| v / z).collect();
    let mut probs = [[0f32; 5]];
    let mut q = [0f32];
    values(&s, &out, &mut probs, &mut q);
    close(&probs[0], &p, 1e-6);
    let want: f64 = p
        .iter()
        .zip([-1.0, -0.5, 0.0, 0.5, 1.0])
        .map(|(p, z)| p * z)
        .sum();
    assert!((q[0] as f64 - want).abs() < 1e-6, "{} vs {want}", q[0]);
    let mut scratch = [0f32; 5];
    let lse = softmax(&out[0], &mut scratch, 40.0);
    assert!((lse as f64 - z.ln()).abs() < 1e-6);
    // Target 0.2: t = (0, 0, 0.6, 0.4, 0); loss -sum t ln p, gradient (p - t) / B with B = 4.
    let (mut d, mut l) = ([[0f32; 5]], [0f32]);
    loss(&s, &out, &probs, &q, &[0.2], 0.25, &mut d, &mut l);
    let t = [0.0, 0.0, 0.6, 0.4, 0.0];
    let ce = -(0.6 * p[2].ln() + 0.4 * p[3].ln());
    assert!((l[0] as f64 - ce).abs() < 1e-5, "{} vs {ce}", l[0]);
    let g: Vec<f64> = (0..5).map(|k| (p[k] - t[k]) * 0.25).collect();
    close(&d[0], &g, 1e-6);
    // A scalar head: 0.5 (q - y)^2, gradient (q - y) / B.
    let out1 = [[3.0f32]];
    let (mut p1, mut q1) = ([[0f32; 1]], [0f32]);
    values(&s, &out1, &mut p1, &mut q1);
    assert_eq!(q1[0], 3.0);
    let (mut d1, mut l1) = ([[0f32; 1]], [0f32]);
    loss(&s, &out1, &p1, &q1, &[1.0], 0.5, &mut d1, &mut l1);
    assert_eq!((l1[0], d1[0][0]), (2.0, 1.0));
}
