//! M-step: the decoupled KL constraints hold on average, measured between the policy before
//! and after each update; a tiny covariance bound keeps the covariance (almost) still.

#![allow(clippy::needless_range_loop)]

use mpo_core::config::MpoConfig;
use mpo_core::gaussian::{Gaussian, kl_parts};
use mpo_core::learner::Learner;
use mpo_core::params::Params;
use mpo_core::rng::Rng;

const OBS: usize = 3;
const ACT: usize = 2;
const TRI: usize = 3;
const H: usize = 32;
const B: usize = 64;
const M: usize = 20;
const N: usize = 4;

type L = Learner<OBS, ACT, TRI, H, H, B, M, N>;

/// Fills the batch with a contextual bandit: reward `-|a - f(s)|^2`, terminal.
fn fill_batch(l: &mut L, rng: &mut Rng) {
    for n in 0..B {
        rng.fill_normal(&mut l.batch.obs[n]);
        rng.fill_normal(&mut l.batch.action[n]);
        let s = l.batch.obs[n];
        let f = [0.5 * s[0] - 0.2, 0.3 * s[1] + 0.1 * s[2]];
        let a = l.batch.action[n];
        l.batch.reward[n] = -((a[0] - f[0]).powi(2) + (a[1] - f[1]).powi(2));
        l.batch.next_obs[n] = s;
        l.batch.bootstrap[n] = 0.0;
    }
}

/// Mean KL parts (decoupled, as constrained) between `before` and `after` over the batch.
fn measured_kl(l: &L, before: &mpo_core::actor::Actor<OBS, ACT, TRI, H, H>) -> (f64, f64) {
    let (mut km, mut kc) = (0f64, 0f64);
    let floor = l.cfg.std_floor;
    for n in 0..B {
        let p0: Gaussian<ACT> = before.distribution(&l.batch.obs[n], floor);
        let p1 = l.live.actor.distribution(&l.batch.obs[n], floor);
        km += kl_parts(&p0, &Gaussian { mu: p1.mu, l: p0.l }).mean as f64;
        kc += kl_parts(&p0, &Gaussian { mu: p0.mu, l: p1.l }).cov as f64;
    }
    (km / B as f64, kc / B as f64)
}

/// Runs 100 updates and returns the average over updates of the KL parts measured after each
/// update between the target policy (MPO's "old" policy, which the constraints are relative
/// to; with `target_period >= 100` it stays fixed for the whole run) and the online policy.
fn run(cfg: MpoConfig) -> (f64, f64, Box<L>) {
    let mut l: Box<L> = bytemuck::zeroed_box();
    l.init(cfg, 5).unwrap();
    let mut rng = Rng::seed_from_u64(6);
    let mut before: Box<mpo_core::actor::Actor<OBS, ACT, TRI, H, H>> = bytemuck::zeroed_box();
    let (mut km, mut kc) = (0f64, 0f64);
    for _ in 0..100 {
        fill_batch(&mut l, &mut rng);
        before.copy_from(&l.target_actor);
        l.update().unwrap();
        let (a, b) = measured_kl(&l, &before);
        km += a;
        kc += b;
    }
    (km / 100.0, kc / 100.0, l)
}

fn aggressive() -> MpoConfig {
    // The report's settings with the target copied every update (so "old" is the policy
    // before the update) and a bigger actor step, so the bounds bind.
    MpoConfig {
        actor_lr: 1e-3,
        target_period: 1000,
        eps_mean: 1e-2,
        eps_cov: 1e-4,
        ..MpoConfig::REPORT
    }
}

#[test]
fn kl_constraints_hold_on_average_and_the_check_can_fail() {
    let cfg = aggressive();
    let (km, kc, _) = run(cfg);
    eprintln!(
        "constrained: KL_mu {km:.3e} (bound {:.1e}), KL_Sigma {kc:.3e} (bound {:.1e})",
        cfg.eps_mean, cfg.eps_cov
    );
    assert!(
        km <= 1.5 * cfg.eps_mean as f64,
        "KL_mu {km} vs bound {}",
        cfg.eps_mean
    );
    assert!(
        kc <= 1.5 * cfg.eps_cov as f64,
        "KL_Sigma {kc} vs bound {}",
        cfg.eps_cov
    );

    // Negative control: the same run with bounds 1000x looser moves far past the tight bounds,
    // so the assertions above measure the constraint, not a step size too small to matter.
    let loose = MpoConfig {
        eps_mean: 10.0,
        eps_cov: 1.0,
        alpha_mean_init: 1e-3,
        alpha_cov_init: 1e-3,
        ..cfg
    };
    let (km2, kc2, _) = run(loose);
    eprintln!("loose: KL_mu {km2:.3e}, KL_Sigma {kc2:.3e}");
    assert!(
        km2 > 1.5 * cfg.eps_mean as f64 || kc2 > 1.5 * cfg.eps_cov as f64,
        "loose run stayed inside the tight bounds"
    );
}

#[test]
fn tiny_covariance_bound_keeps_the_covariance_still() {
    let tiny = MpoConfig {
        eps_cov: 1e-9,
        ..aggressive()
    };
    let (_, kc_tiny, _) = run(tiny);
    // Control: a loose bound with a small initial multiplier lets the covariance move.
    let (_, kc_free, _) = run(MpoConfig {
        eps_cov: 1e-1,
        alpha_cov_init: 1e-3,
        ..aggressive()
    });
    eprintln!("KL_Sigma(target || online): eps 1e-9 -> {kc_tiny:.3e}; eps 1e-1 -> {kc_free:.3e}");
    assert!(kc_tiny < 1e-6, "covariance moved: {kc_tiny}");
    assert!(
        kc_free > 100.0 * kc_tiny.max(1e-12),
        "the looser bound did not let it move: {kc_free}"
    );
}

#[test]
fn updates_are_bit_identical_across_runs_and_report_finite_stats() {
    let cfg = MpoConfig {
        target_period: 10,
        ..MpoConfig::REPORT
    };
    let mk = || {
        let mut l: Box<L> = bytemuck::zeroed_box();
        l.init(cfg, 9).unwrap();
        let mut rng = Rng::seed_from_u64(10);
        let mut last = None;
        for _ in 0..30 {
            fill_batch(&mut l, &mut rng);
            last = Some(l.update().unwrap());
        }
        (l, last.unwrap())
    };
    let (a, sa) = mk();
    let (b, sb) = mk();
    assert!(a.live.actor.bits_eq(&b.live.actor) && a.live.critic.bits_eq(&b.live.critic));
    assert!(a.target_actor.bits_eq(&b.target_actor));
    assert_eq!(a.rng_state, b.rng_state);
    assert_eq!(format!("{sa:?}"), format!("{sb:?}"));
    for v in [
        sa.critic_loss,
        sa.eta,
        sa.estep_kl,
        sa.alpha_mean,
        sa.alpha_cov,
        sa.kl_mean,
        sa.kl_cov,
        sa.q_mean,
        sa.std_mean,
    ] {
        assert!(v.is_finite(), "{sa:?}");
    }
    // The E-step meets its bound.
    assert!(
        (sa.estep_kl - 0.1).abs() < 0.01 * 0.1,
        "E-step KL {}",
        sa.estep_kl
    );
}

#[test]
fn non_finite_input_is_reported_and_the_update_undone() {
    let mut l: Box<L> = bytemuck::zeroed_box();
    l.init(MpoConfig::REPORT, 1).unwrap();
    let mut rng = Rng::seed_from_u64(2);
    fill_batch(&mut l, &mut rng);
    l.update().unwrap();
    let mut actor: Box<mpo_core::actor::Actor<OBS, ACT, TRI, H, H>> = bytemuck::zeroed_box();
    let mut critic: Box<mpo_core::critic::Critic<OBS, ACT, H, H>> = bytemuck::zeroed_box();
    actor.copy_from(&l.live.actor);
    critic.copy_from(&l.live.critic);
    let duals = l.live.duals;
    let updates = l.updates;

    // NaN in the batch: rejected before anything runs.
    fill_batch(&mut l, &mut rng);
    l.batch.reward[3] = f32::NAN;
    assert_eq!(
        l.update(),
        Err(mpo_core::learner::UpdateError::NonFinite(
            mpo_core::learner::NonFinite::Batch
        ))
    );
    // A huge reward: finite input, non-finite loss; the critic step must be undone.
    fill_batch(&mut l, &mut rng);
    l.batch.reward[0] = f32::MAX;
    l.batch.reward[1] = f32::MAX;
    let e = l.update().unwrap_err();
    eprintln!("huge reward: {e}");
    assert!(
        l.live.actor.bits_eq(&actor) && l.live.critic.bits_eq(&critic),
        "parameters changed"
    );
    assert_eq!(l.live.duals, duals);
    assert_eq!(l.updates, updates);
    // Infinite parameters are caught after the step too.
    fill_batch(&mut l, &mut rng);
    l.live.actor.l1.b[0] = f32::INFINITY;
    assert!(l.update().is_err());
}

#[test]
fn retrace_update_with_one_step_sequences_equals_the_td_update() {
    use mpo_core::learner::SequenceBatch;
    let cfg = MpoConfig {
        target_period: 3,
        ..MpoConfig::REPORT
    };
    let mut a: Box<L> = bytemuck::zeroed_box();
    let mut b: Box<L> = bytemuck::zeroed_box();
    a.init(cfg, 4).unwrap();
    b.init(cfg, 4).unwrap();
    let mut rng = Rng::seed_from_u64(8);
    let mut seq: Box<SequenceBatch<B, 1, OBS, ACT>> = bytemuck::zeroed_box();
    for _ in 0..5 {
        fill_batch(&mut a, &mut rng);
        a.batch.bootstrap = [cfg.gamma; B];
        seq.obs[0] = a.batch.obs;
        seq.action[0] = a.batch.action;
        seq.reward[0] = a.batch.reward;
        seq.next_obs[0] = a.batch.next_obs;
        seq.discount[0] = [1.0; B];
        let sa = a.update().unwrap();
        let sb = b.update_retrace(&seq).unwrap();
        assert_eq!(format!("{sa:?}"), format!("{sb:?}"));
    }
    assert!(a.live.actor.bits_eq(&b.live.actor) && a.live.critic.bits_eq(&b.live.critic));
}

#[test]
fn retrace_update_on_longer_sequences_runs_and_stays_finite() {
    use mpo_core::learner::SequenceBatch;
    const LEN: usize = 4;
    let mut l: Box<L> = bytemuck::zeroed_box();
    l.init(MpoConfig::REPORT, 4).unwrap();
    let mut rng = Rng::seed_from_u64(9);
    let mut seq: Box<SequenceBatch<B, LEN, OBS, ACT>> = bytemuck::zeroed_box();
    for _ in 0..5 {
        // A random walk in state with the bandit reward; behaviour log-probabilities from the
        // current policy, so the traces are near 1.
        for n in 0..B {
            let mut s = [0f32; OBS];
            rng.fill_normal(&mut s);
            for k in 0..LEN {
                let mut a = [0f32; ACT];
                let logp = l.sample_action(&s, &mut rng, &mut a);
                let mut next = s;
                next[0] += 0.1 * a[0];
                seq.obs[k][n] = s;
                seq.action[k][n] = a;
                seq.reward[k][n] = -(a[0] - 0.5 * s[0]).powi(2);
                seq.next_obs[k][n] = next;
                seq.discount[k][n] = 1.0;
                seq.behaviour_log_prob[k][n] = logp;
                s = next;
            }
        }
        let st = l.update_retrace(&seq).unwrap();
        assert!(
            st.critic_loss.is_finite() && st.target_mean.is_finite(),
            "{st:?}"
        );
    }
    // A non-finite behaviour log-probability is rejected.
    seq.behaviour_log_prob[2][7] = f32::NAN;
    assert!(l.update_retrace(&seq).is_err());
}
