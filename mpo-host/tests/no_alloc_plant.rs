//! A fleet plant's step path (act with its copy of the policy, step, encode the record into
//! the block) allocates nothing over warm-up, policy sampling and episode resets; sending the
//! block goes through iceoryx2 and is not counted here. In a binary of its own: the counter is
//! process-wide (`counting`'s header says why).

mod counting;

use std::sync::atomic::Ordering;

use counting::{ALLOCS, serial};
use mpo_host::commands::defaults;
use mpo_host::table;

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
