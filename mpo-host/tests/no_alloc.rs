//! The act-and-learn loop allocates nothing: a counting allocator around
//! `Trainer::collect` over episode boundaries, warm-up, learner updates and observation
//! normalisation's refits, with the MLPs and with the residual networks (weights on the sphere,
//! periodic resets) (a fleet plant's step path: `no_alloc_plant.rs`). The counter is
//! global: this binary holds this one test (`counting`'s header says why).

mod common;
mod counting;

use std::sync::atomic::Ordering;

use common::{Tiny, TinySimba};
use counting::{ALLOCS, serial};
use mpo_host::commands::defaults;
use mpo_host::table;

/// Allocations (counted globally) while `f` runs.
fn allocations_in(f: impl FnOnce()) -> u64 {
    let before = ALLOCS.load(Ordering::SeqCst);
    f();
    ALLOCS.load(Ordering::SeqCst) - before
}

#[test]
fn collect_and_learn_allocate_nothing() {
    use mpo_host::settings::PolicyEvaluation;
    let _one_at_a_time = serial();
    let row = table::row("cartpole-balance", "tiny").unwrap();
    // Every policy evaluation, on two learner threads (the pool's workers count too: the
    // counter is global, and no other test of this binary runs meanwhile).
    for (evaluation, n) in [
        (PolicyEvaluation::Td, 1),
        (PolicyEvaluation::NStep, 3),
        (PolicyEvaluation::Retrace, 4),
    ] {
        let mut settings = defaults(row);
        settings.mpo.policy_evaluation = evaluation;
        settings.mpo.n_step = n;
        // Observation normalisation on for n-step: its refits (the whole replay, every 300
        // steps) run inside `collect` too.
        settings.mpo.obs_norm_interval = if n == 3 { 300 } else { 0 };
        // The squashed mean on Retrace (its target-policy passes squash too).
        settings.mpo.tanh_mean = n == 4;
        // The clip before the critic on TD and Retrace (its copies are fixed scratch).
        settings.mpo.clip_critic_actions = n != 3;
        let mut t = Tiny::new(&settings, None, 2).unwrap();
        // 2500 steps: three resets, 500 warm-up steps, then 500 updates (one per 4 steps).
        let allocs = allocations_in(|| {
            t.collect(2500).unwrap_or_else(|_| panic!("collect failed"));
        });
        assert!(
            t.agent.learner.updates >= 400,
            "updates {}",
            t.agent.learner.updates
        );
        assert_eq!(allocs, 0, "allocations inside collect ({evaluation:?})");
    }
    // The residual networks and the categorical critic, with the weights held on the sphere
    // and a periodic reset (a fresh draw of both networks, in place) every 150 updates.
    let row = table::row("cartpole-balance", "tiny-simba").unwrap();
    let mut settings = defaults(row);
    settings.mpo.weight_norm = true;
    settings.mpo.reset_interval = 150;
    let mut t = TinySimba::new(&settings, None, 2).unwrap();
    let allocs = allocations_in(|| {
        t.collect(2500).unwrap_or_else(|_| panic!("collect failed"));
    });
    assert!(
        t.agent.learner.updates >= 300,
        "updates {}",
        t.agent.learner.updates
    );
    assert_eq!(allocs, 0, "allocations inside collect (tiny-simba)");
}
