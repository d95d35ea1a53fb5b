//! Whole learner updates with the residual networks and the categorical critic: the bits
//! depend on neither the chunking of the batch nor the threads (as for the MLPs,
//! `tests/mstep.rs`; also with the categorical head's logit floor dropping atoms), the learner learns a contextual bandit, and a periodic reset draws
//! exactly the networks a fresh initialisation from the learner's stream would, keeping the
//! observation normalisation; with `weight_norm` every hidden layer's incoming weight vectors
//! stay on the unit sphere through updates and the heads stay free.

#![allow(clippy::needless_range_loop)]

use bytemuck::Zeroable;
use mpo_core::adam::AdamState;
use mpo_core::config::MpoConfig;
use mpo_core::learner::LearnerOf;
use mpo_core::network::{PolicyNet, ValueNet};
use mpo_core::parallel::{Parallel, Serial};
use mpo_core::params::Params;
use mpo_core::residual::{ResidualActor, ResidualCritic};
use mpo_core::rng::Rng;

const OBS: usize = 3;
const ACT: usize = 2;
const TRI: usize = 3;
const SEQ: usize = 4;
const M: usize = 10;
const N: usize = 10;
const K: usize = 21;

type Pi = ResidualActor<OBS, ACT, TRI, 16, 32, 2>;
type Q = ResidualCritic<OBS, ACT, 16, 32, 2, K>;
type L<const BC: usize, const C: usize> = LearnerOf<OBS, ACT, TRI, Pi, Q, BC, C, SEQ, M, N>;

/// The bandit's best action at state `s`.
fn best(s: &[f32; OBS]) -> [f32; ACT] {
    [0.5 * s[0] - 0.2, 0.3 * s[1] + 0.1 * s[2]]
}

/// Position 0 of every row: a contextual bandit, reward `-|a - f(s)|^2`, terminal (also as a
/// sequence: the later positions continue with the same state, for Retrace).
fn fill_bandit<const BC: usize, const C: usize>(l: &mut L<BC, C>, rng: &mut Rng) {
    for n in 0..BC * C {
        let (c, i) = (n / BC, n % BC);
        let ch = &mut l.batch[c];
        for k in 0..SEQ {
            rng.fill_normal(&mut ch.obs[k][i]);
            rng.fill_normal(&mut ch.action[k][i]);
            let s = ch.obs[k][i];
            let (f, a) = (best(&s), ch.action[k][i]);
            ch.reward[k][i] = 2.0 - ((a[0] - f[0]).powi(2) + (a[1] - f[1]).powi(2));
            ch.next_obs[k][i] = s;
            ch.bootstrap[k][i] = if k + 1 < SEQ { 0.5 } else { 0.0 };
            ch.behaviour_log_prob[k][i] = -1.0;
        }
    }
}

/// Runs items on `threads` scoped threads in a rotated order.
struct Threads(usize);

impl Parallel for Threads {
    fn for_each<T: Send>(&self, items: &mut [T], f: &(dyn Fn(usize, &mut T) + Sync)) {
        let mut buckets: Vec<Vec<(usize, &mut T)>> = (0..self.0).map(|_| vec![]).collect();
        for (k, it) in items.iter_mut().enumerate().rev() {
            buckets[k % self.0].push((k, it));
        }
        std::thread::scope(|s| {
            for b in buckets {
                s.spawn(move || {
                    for (k, it) in b {
                        f(k, it);
                    }
                });
            }
        });
    }
    fn threads(&self) -> usize {
        self.0
    }
}

fn chunked_run<const BC: usize, const C: usize, P: Parallel>(
    cfg: MpoConfig,
    par: &P,
    updates: usize,
) -> (Box<L<BC, C>>, String) {
    let mut l: Box<L<BC, C>> = bytemuck::zeroed_box();
    l.init(cfg, 9).unwrap();
    let mut rng = Rng::seed_from_u64(10);
    let mut log = String::new();
    for _ in 0..updates {
        fill_bandit(&mut l, &mut rng);
        log += &format!("{:?}\n", l.update_with(par).unwrap());
    }
    (l, log)
}

fn configs() -> [MpoConfig; 3] {
    let base = MpoConfig {
        value_min: -5.0,
        value_max: 5.0,
        actor_clip: 40.0,
        mstep_iters: 2,
        ..MpoConfig::REPORT
    };
    [
        MpoConfig {
            shared_samples: true,
            action_penalization: true,
            per_dim_kl: true,
            ..base
        },
        MpoConfig {
            sequence_len: 3,
            target_tau: 0.05,
            value_sigma: 0.0,
            weight_norm: true,
            ..base
        },
        // A floor low enough that the head drops atoms in every update (40, the default, is
        // never reached by these short runs).
        MpoConfig {
            logit_floor: 0.3,
            ..base
        },
    ]
}

#[test]
fn residual_updates_have_the_same_bits_for_any_chunking_and_thread_count() {
    for cfg in configs() {
        let (a, la) = chunked_run::<16, 4, _>(cfg, &Serial, 12);
        let (b, lb) = chunked_run::<64, 1, _>(cfg, &Serial, 12);
        let (c, lc) = chunked_run::<8, 8, _>(cfg, &Threads(3), 12);
        for (name, l2, log) in [("64x1", &b.live, &lb), ("8x8, 3 threads", &c.live, &lc)] {
            assert!(
                a.live.actor.bits_eq(&l2.actor) && a.live.critic.bits_eq(&l2.critic),
                "{name}: parameters differ"
            );
            assert_eq!(a.live.duals, l2.duals, "{name}");
            assert_eq!(&la, log, "{name}: statistics differ");
        }
        assert!(a.target_critic.bits_eq(&c.target_critic));
        assert_eq!(a.rng_state, c.rng_state);
    }
    // The low floor did act: without it the same updates end elsewhere.
    let [.., low] = configs();
    let (with, _) = chunked_run::<16, 4, _>(low, &Serial, 12);
    let off = MpoConfig {
        logit_floor: 0.0,
        ..low
    };
    let (without, _) = chunked_run::<16, 4, _>(off, &Serial, 12);
    assert!(!with.live.critic.bits_eq(&without.live.critic));
}

#[test]
fn residual_learner_learns_the_bandit() {
    learns_the_bandit(false);
}

#[test]
fn residual_learner_with_weights_on_the_sphere_learns_the_bandit() {
    learns_the_bandit(true);
}

fn learns_the_bandit(weight_norm: bool) {
    // As the MLP learner's bandit (tests/learning.rs): faster steps and target copies every
    // 25 updates (the report's 100 would copy them three times in this test).
    let cfg = MpoConfig {
        eps_mean: 0.05,
        actor_lr: 1e-3,
        critic_lr: 1e-3,
        target_period: 25,
        weight_norm,
        ..configs()[0]
    };
    let mut l: Box<L<16, 4>> = bytemuck::zeroed_box();
    l.init(cfg, 3).unwrap();
    let mut rng = Rng::seed_from_u64(4);
    let error = |l: &L<16, 4>| {
        let mut r = Rng::seed_from_u64(99);
        let mut e = 0f64;
        for _ in 0..200 {
            let mut s = [0f32; OBS];
            r.fill_normal(&mut s);
            let (mut a, f) = ([0f32; ACT], best(&s));
            l.mean_action(&s, &mut a);
            e += ((a[0] - f[0]).powi(2) + (a[1] - f[1]).powi(2)) as f64 / 200.0;
        }
        e
    };
    let before = error(&l);
    let mut stats = None;
    for _ in 0..1000 {
        fill_bandit(&mut l, &mut rng);
        stats = Some(l.update().unwrap());
    }
    let after = error(&l);
    let s = stats.unwrap();
    assert!(
        after < 0.03 && after < before / 5.0,
        "mean squared error of the mean action: {before:.4} at the start, {after:.4} after 1000 updates"
    );
    // The categorical critic's expectations stay below the largest return the rows allow: a
    // reward of at most 2, continued with factor 0.5 gamma (the rows' `bootstrap`), sums to
    // at most 2 / (1 - 0.5 gamma), about 3.96; and the best actions are worth more than 0.
    let bound = 2.0 / (1.0 - 0.5 * cfg.gamma);
    assert!(s.q_max <= bound && s.q_mean > 0.0, "bound {bound}: {s:?}");
    eprintln!("bandit error {before:.4} -> {after:.4}; {s:?}");
}

#[test]
fn a_reset_draws_the_networks_of_a_fresh_start_from_the_learners_stream() {
    let cfg = MpoConfig {
        reset_interval: 3,
        ..configs()[0]
    };
    let mut l: Box<L<16, 4>> = bytemuck::zeroed_box();
    l.init(cfg, 5).unwrap();
    let mut rng = Rng::seed_from_u64(6);
    // A fitted observation normalisation: kept by the reset.
    fill_bandit(&mut l, &mut rng);
    let rows = l.batch[0].obs[0];
    l.fit_obs_norm(&rows);
    let input = l.live.actor.input.clone();
    for _ in 0..2 {
        fill_bandit(&mut l, &mut rng);
        l.update().unwrap();
    }
    assert_eq!(l.live.critic_opt.t, 2);
    let state = l.rng_state;
    fill_bandit(&mut l, &mut rng);
    l.update().unwrap();
    // What a fresh start from the stream's next state draws, after the update's own seed.
    let mut r = Rng::from_state(state);
    r.next_u64();
    let mut a = Pi::zeroed();
    PolicyNet::init(&mut a, &mut r, cfg.init_std, cfg.std_floor);
    a.input = input.clone();
    let mut q = Q::zeroed();
    ValueNet::init(&mut q, &mut r);
    assert!(l.live.actor.bits_eq(&a), "the actor is not a fresh draw");
    assert!(l.live.critic.bits_eq(&q), "the critic is not a fresh draw");
    assert!(l.target_actor.bits_eq(&a) && l.target_critic.bits_eq(&q));
    assert!(l.live.actor.input.bits_eq(&input));
    assert_eq!(l.live.actor_opt, AdamState::default());
    assert_eq!(l.live.critic_opt, AdamState::default());
    assert!(l.live.critic_m.global_norm() == 0.0 && l.live.actor_v.global_norm() == 0.0);
    assert_eq!(l.live.duals.eta, cfg.eta_init);
    assert_eq!(l.updates, 3);
    assert_eq!(l.rng_state, r.state());
    // The next update learns from there; without resets the same run keeps its networks.
    fill_bandit(&mut l, &mut rng);
    l.update().unwrap();
    assert!(!l.live.actor.bits_eq(&a));
    let (plain, _) = chunked_run::<16, 4, _>(
        MpoConfig {
            reset_interval: 0,
            ..cfg
        },
        &Serial,
        3,
    );
    let (reset, _) = chunked_run::<16, 4, _>(cfg, &Serial, 3);
    assert!(!plain.live.critic.bits_eq(&reset.live.critic));
    assert!(reset.live.critic.bits_eq(&reset.target_critic));
}

/// The norms of the columns of the stacked input-major matrices, in f64.
fn column_norms<const O: usize>(parts: &[&[[f32; O]]]) -> Vec<f64> {
    (0..O)
        .map(|o| {
            let sq: f64 = parts
                .iter()
                .flat_map(|p| p.iter())
                .map(|row| (row[o] as f64).powi(2))
                .sum();
            sq.sqrt()
        })
        .collect()
}

/// Every hidden layer's columns of `a` and `q` at unit norm (to f32 rounding); `what` names
/// the moment for the message.
fn assert_on_the_sphere(a: &Pi, q: &Q, what: &str) {
    let mut hidden = vec![
        ("actor embed", column_norms(&[&a.embed.w[..]])),
        (
            "critic embed (s, a)",
            column_norms(&[&q.embed_s.w[..], &q.embed_a.w[..]]),
        ),
    ];
    for (net, trunk) in [("actor", &a.trunk), ("critic", &q.trunk)] {
        for b in &trunk.blocks {
            hidden.push((net, column_norms(&[&b.up.w[..]])));
            hidden.push((net, column_norms(&[&b.down.w[..]])));
        }
    }
    for (name, norms) in hidden {
        for (o, n) in norms.iter().enumerate() {
            assert!(
                (n - 1.0).abs() < 1e-6,
                "{what}: {name} layer column {o} has norm {n}"
            );
        }
    }
}

#[test]
fn weight_norm_holds_the_hidden_layers_on_the_unit_sphere_and_leaves_the_heads_free() {
    let cfg = MpoConfig {
        weight_norm: true,
        ..configs()[0]
    };
    let mut l: Box<L<16, 4>> = bytemuck::zeroed_box();
    l.init(cfg, 11).unwrap();
    assert_on_the_sphere(&l.live.actor, &l.live.critic, "after init");
    assert!(l.target_critic.bits_eq(&l.live.critic));
    let mut rng = Rng::seed_from_u64(12);
    let start = l.live.actor.clone();
    for u in 0..5 {
        fill_bandit(&mut l, &mut rng);
        l.update().unwrap();
        assert_on_the_sphere(&l.live.actor, &l.live.critic, &format!("after update {u}"));
    }
    // The weights moved (on the sphere), and the heads are not projected: their columns keep
    // the initialisation's scale (about 1/sqrt(3) for a uniform fan-in draw), not 1.
    assert!(!l.live.actor.bits_eq(&start));
    for norms in [
        column_norms(&[&l.live.actor.mean.w[..]]),
        column_norms(&[&l.live.critic.out.w[..]]),
    ] {
        assert!(
            norms.iter().all(|n| (n - 1.0).abs() > 0.05),
            "a head was projected: {norms:?}"
        );
    }
    // A periodic reset lands on the sphere too.
    let mut r: Box<L<16, 4>> = bytemuck::zeroed_box();
    r.init(
        MpoConfig {
            reset_interval: 2,
            ..cfg
        },
        11,
    )
    .unwrap();
    for _ in 0..2 {
        fill_bandit(&mut r, &mut rng);
        r.update().unwrap();
    }
    assert_eq!(r.live.critic_opt.t, 0, "the reset did not happen");
    assert_on_the_sphere(&r.live.actor, &r.live.critic, "after a reset");
}

#[test]
fn weight_norm_is_refused_for_networks_without_the_projection() {
    use mpo_core::learner::Learner;
    type Mlp = Learner<OBS, ACT, TRI, 16, 16, 16, 16, 16, 4, SEQ, M, N>;
    let mut l: Box<Mlp> = bytemuck::zeroed_box();
    let cfg = MpoConfig {
        weight_norm: true,
        ..MpoConfig::REPORT
    };
    let e = l.init(cfg, 1).unwrap_err();
    assert_eq!(e.field, "weight_norm");
    assert!(l.init(MpoConfig::REPORT, 1).is_ok());
}
