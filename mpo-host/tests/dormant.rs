//! The dormant-unit measurement (`mpo_host::dormant`, the `metrics.csv` columns
//! `actor_dormant` and `critic_dormant`) on real trainers: units killed by hand are counted,
//! in the MLPs and in the residual networks, and measuring takes nothing from the run's bits.

mod common;

use common::{Tiny, TinySimba};
use mpo_host::commands::defaults;
use mpo_host::table;
use mpo_host::training::Training;

/// A unit that never fires whatever its input: no incoming weight, a negative bias.
fn kill(w: &mut [[f32; 32]], b: &mut [f32; 32], unit: usize) {
    for row in w.iter_mut() {
        row[unit] = 0.0;
    }
    b[unit] = -1.0;
}

#[test]
fn units_killed_in_the_mlps_are_counted_and_measuring_changes_no_bits() {
    let settings = defaults(table::row("cartpole-balance", "tiny").unwrap());
    let mut t = Tiny::new(&settings, None, 1).unwrap();
    assert_eq!(
        t.dormant(),
        None,
        "an empty buffer has nothing to measure on"
    );
    t.collect(1200).unwrap_or_else(|_| panic!("collect failed"));
    let [actor0, critic0] = t.dormant().unwrap();
    // Twice the same figure, and the parameters, buffer and streams untouched: a second
    // trainer that never measured ends on the same bits.
    assert_eq!(t.dormant(), Some([actor0, critic0]));
    let mut quiet = Tiny::new(&settings, None, 1).unwrap();
    quiet
        .collect(1200)
        .unwrap_or_else(|_| panic!("collect failed"));
    t.collect(300).unwrap_or_else(|_| panic!("collect failed"));
    quiet
        .collect(300)
        .unwrap_or_else(|_| panic!("collect failed"));
    assert_eq!(t.params_sha256(), quiet.params_sha256());

    // 24 of the actor's first layer (37.5% of its 64 ReLU units in two layers of 32) and 24 of
    // the critic's second: more than were dormant, so the figure must rise to at least that.
    let l = &mut t.agent.learner.live;
    for unit in 0..24 {
        kill(&mut l.actor.l1.w, &mut l.actor.l1.b, unit);
        kill(&mut l.critic.l2.w, &mut l.critic.l2.b, unit + 8);
    }
    let killed = 100.0 * 24.0 / 64.0;
    assert!(actor0 < killed && critic0 < killed, "{actor0} {critic0}");
    let [actor1, critic1] = t.dormant().unwrap();
    assert!(actor1 >= killed, "actor {actor0} -> {actor1}");
    assert!(critic1 >= killed, "critic {critic0} -> {critic1}");
}

#[test]
fn units_killed_in_the_residual_blocks_are_counted() {
    let settings = defaults(table::row("cartpole-balance", "tiny-simba").unwrap());
    let mut t = TinySimba::new(&settings, None, 1).unwrap();
    t.collect(1200).unwrap_or_else(|_| panic!("collect failed"));
    let [actor0, critic0] = t.dormant().unwrap();
    let l = &mut t.agent.learner.live;
    // The blocks' inner width is 64 (one policy block, two critic blocks): kill 48 of the
    // policy's 64 (75%) and 48 of the critic's first block's (37.5% of 128), more than were
    // dormant.
    for unit in 0..48 {
        let up = &mut l.actor.trunk.blocks[0].up;
        for row in up.w.iter_mut() {
            row[unit] = 0.0;
        }
        up.b[unit] = -1.0;
        let up = &mut l.critic.trunk.blocks[0].up;
        for row in up.w.iter_mut() {
            row[unit + 16] = 0.0;
        }
        up.b[unit + 16] = -1.0;
    }
    let (actor_killed, critic_killed) = (75.0, 37.5);
    assert!(
        actor0 < actor_killed && critic0 < critic_killed,
        "{actor0} {critic0}"
    );
    let [actor1, critic1] = t.dormant().unwrap();
    assert!(actor1 >= actor_killed, "actor {actor0} -> {actor1}");
    assert!(critic1 >= critic_killed, "critic {critic0} -> {critic1}");
}
