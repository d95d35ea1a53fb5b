//! After construction, acting and a full forward + backward + Adam step allocate nothing.
//!
//! The counting allocator counts per thread; every measured closure runs the real routines at
//! the hopper size (observation 15, action 4, hidden 256-256, batch 256).

#![allow(clippy::needless_range_loop)]

use mpo_core::actor::{Actor, ActorTape, ActorTransposed};
use mpo_core::adam::{AdamConfig, AdamState, adam_step};
use mpo_core::critic::{Critic, CriticTape, CriticTransposed};
use mpo_core::gaussian::{Gaussian, GaussianGrad, head_backward};
use mpo_core::params::clip_global_norm;
use mpo_core::rng::Rng;
use mpo_integration::{CountingAlloc, count_allocations};

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

const OBS: usize = 15;
const ACT: usize = 4;
const TRI: usize = 10;
const H: usize = 256;
const B: usize = 256;

type A = Actor<OBS, ACT, TRI, H, H>;
type C = Critic<OBS, ACT, H, H>;

/// Everything one step touches, built once (the only allocation).
struct Bench {
    actor: Box<A>,
    actor_grad: Box<A>,
    actor_m: Box<A>,
    actor_v: Box<A>,
    critic: Box<C>,
    critic_grad: Box<C>,
    critic_m: Box<C>,
    critic_v: Box<C>,
    atape: Box<ActorTape<B, H, H>>,
    ctape: Box<CriticTape<B, H, H>>,
    at: Box<ActorTransposed<ACT, TRI, H, H>>,
    ct: Box<CriticTransposed<H, H>>,
    obs: Box<[[f32; OBS]; B]>,
    act: Box<[[f32; ACT]; B]>,
    mean: Box<[[f32; ACT]; B]>,
    chol: Box<[[f32; TRI]; B]>,
    d_mean: Box<[[f32; ACT]; B]>,
    d_chol: Box<[[f32; TRI]; B]>,
}

#[test]
fn acting_and_training_steps_do_not_allocate() {
    let mut s = Bench {
        actor: bytemuck::zeroed_box(),
        actor_grad: bytemuck::zeroed_box(),
        actor_m: bytemuck::zeroed_box(),
        actor_v: bytemuck::zeroed_box(),
        critic: bytemuck::zeroed_box(),
        critic_grad: bytemuck::zeroed_box(),
        critic_m: bytemuck::zeroed_box(),
        critic_v: bytemuck::zeroed_box(),
        atape: bytemuck::zeroed_box(),
        ctape: bytemuck::zeroed_box(),
        at: bytemuck::zeroed_box(),
        ct: bytemuck::zeroed_box(),
        obs: bytemuck::zeroed_box(),
        act: bytemuck::zeroed_box(),
        mean: bytemuck::zeroed_box(),
        chol: bytemuck::zeroed_box(),
        d_mean: bytemuck::zeroed_box(),
        d_chol: bytemuck::zeroed_box(),
    };
    let mut rng = Rng::seed_from_u64(0);
    s.actor.init(&mut rng, 0.5, 1e-4);
    s.critic.init(&mut rng);
    let cfg = AdamConfig::with_lr(3e-4);
    let (mut sa, mut sc) = (AdamState::default(), AdamState::default());

    // Acting: one state forward + sample.
    let ((), n) = count_allocations(|| {
        let mut o = [0f32; OBS];
        rng.fill_normal(&mut o);
        let pi = s.actor.distribution(&o, 1e-4);
        let mut a = [0f32; ACT];
        pi.sample(&mut rng, &mut a);
        std::hint::black_box(pi.log_prob(&a));
    });
    assert_eq!(n, 0, "acting allocated {n} times");

    // A full training step for both networks.
    let ((), n) = count_allocations(|| {
        rng.fill_normal(s.obs.as_flattened_mut());
        s.actor
            .forward(&s.obs, &mut s.atape, &mut s.mean, &mut s.chol);
        for i in 0..B {
            let pi = Gaussian::from_head(&s.mean[i], &s.chol[i], 1e-4);
            pi.sample(&mut rng, &mut s.act[i]);
            let mut g = GaussianGrad::ZERO;
            pi.log_prob_grad(&s.act[i], -1.0 / B as f32, &mut g);
            head_backward(&s.chol[i], &g, &mut s.d_mean[i], &mut s.d_chol[i]);
        }
        s.actor.backward(
            &s.obs,
            &mut s.atape,
            &s.d_mean,
            &s.d_chol,
            &mut s.at,
            &mut s.actor_grad,
        );
        clip_global_norm(&mut *s.actor_grad, 40.0);
        adam_step(
            &cfg,
            &mut sa,
            &mut *s.actor,
            &s.actor_grad,
            &mut *s.actor_m,
            &mut *s.actor_v,
        );

        let mut q = [[0f32; 1]; B];
        s.critic.forward(&s.obs, &s.act, &mut s.ctape, &mut q, true);
        let mut dq = [[0f32; 1]; B];
        for i in 0..B {
            dq[i][0] = q[i][0] / B as f32;
        }
        s.critic.backward(
            &s.obs,
            &s.act,
            &mut s.ctape,
            &dq,
            &mut s.ct,
            &mut s.critic_grad,
            true,
        );
        adam_step(
            &cfg,
            &mut sc,
            &mut *s.critic,
            &s.critic_grad,
            &mut *s.critic_m,
            &mut *s.critic_v,
        );
    });
    assert_eq!(n, 0, "a training step allocated {n} times");

    // A full learner update (policy evaluation, E-step, M-step) at hopper size, after the
    // first update has run (nothing is allocated lazily either).
    let mut learner: Box<Hopper> = bytemuck::zeroed_box();
    learner
        .init(mpo_core::config::MpoConfig::REPORT, 3)
        .unwrap();
    for round in 0..2 {
        fill(&mut learner, &mut rng);
        let (r, n) = count_allocations(|| learner.update());
        r.unwrap();
        assert_eq!(n, 0, "learner update {round} allocated {n} times");
    }

    // The counter works: a Vec does allocate.
    let (_, n) = count_allocations(|| std::hint::black_box(vec![1u8; 16]));
    assert_eq!(n, 1);
}

/// The hopper-size learner of these tests: 2 chunks of 32 rows, sequences up to 3.
type Hopper = mpo_core::learner::Learner<OBS, ACT, TRI, H, H, H, H, 32, 2, 3, 20, 20>;

fn fill(l: &mut Hopper, rng: &mut Rng) {
    for b in l.batch.iter_mut() {
        rng.fill_normal(b.obs.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.action.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.next_obs.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.reward.as_flattened_mut());
        b.bootstrap = [[0.99; 32]; 3];
        b.behaviour_log_prob = [[-2.0; 32]; 3];
    }
}
