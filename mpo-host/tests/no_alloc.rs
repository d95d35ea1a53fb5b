//! The act-and-learn loop allocates nothing: a counting allocator around
//! `Trainer::collect` over episode boundaries, warm-up, learner updates and observation
//! normalisation's refits; and a fleet plant's step path. The counter is global: the tests
//! of this binary take turns ([`serial`]).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

use mpo_host::commands::defaults;
use mpo_host::table;
use mpo_host::trainer::MlpTrainer as Trainer;

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

/// Holds the other tests of this binary off while one counts (a poisoned lock is fine: the
/// failing test has said why).
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// The tiny cartpole row's trainer type.
type Tiny = Trainer<5, 1, 1, 32, 32, 32, 32, 32, 2, 4, 10, 10, 50_000>;

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
        let before = ALLOCS.load(Ordering::SeqCst);
        // 2500 steps: three resets, 500 warm-up steps, then 500 updates (one per 4 steps).
        t.collect(2500).unwrap_or_else(|_| panic!("collect failed"));
        let after = ALLOCS.load(Ordering::SeqCst);
        assert!(
            t.agent.learner.updates >= 400,
            "updates {}",
            t.agent.learner.updates
        );
        assert_eq!(
            after - before,
            0,
            "allocations inside collect ({evaluation:?})"
        );
    }
}

/// A fleet plant's step path (act with its copy of the policy, step, encode the record into
/// the block) allocates nothing over warm-up, policy sampling and episode resets; sending
/// the block goes through iceoryx2 and is not counted here.
#[test]
fn a_fleet_plants_steps_allocate_nothing() {
    use mpo_core::actor::Actor;
    use mpo_core::rng::Rng;
    use mpo_host::fleet::worker::Stepper;
    let _one_at_a_time = serial();
    let task = sim_bridge::TaskDef::builtin("cartpole-balance").unwrap();
    let row = table::row("cartpole-balance", "tiny").unwrap();
    let settings = defaults(row);
    let mut w = mpo_host::fleet::welcome_of(&settings);
    w.block = 50;
    w.collector = mpo_host::fleet::collector_of(0, 1);
    let mut s = Stepper::<5, 1>::new(&task, &w, None).unwrap();
    let mut policy: Box<Actor<5, 1, 1, 32, 32>> = bytemuck::zeroed_box();
    policy.init(&mut Rng::seed_from_u64(3), 0.5, 1e-3);
    let before = ALLOCS.load(Ordering::SeqCst);
    // 2500 steps: three resets, 500 uniform steps, then the policy's samples.
    for j in 0..2500 {
        s.step::<1, _>(policy.as_ref(), j < 500).unwrap();
        if s.count() == 50 {
            s.clear_block();
        }
    }
    let after = ALLOCS.load(Ordering::SeqCst);
    assert_eq!(after - before, 0, "allocations on the plant's step path");
}
