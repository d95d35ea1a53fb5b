//! Observation normalisation: the fit equals the statistics written out in f64, the identity
//! passes every finite input bit for bit, outside parameters cannot make it panic, and the
//! agent refits on schedule, normalises the learner's batches with the policy's own
//! normaliser and acts on normalised states.

#![allow(clippy::needless_range_loop)]

use mpo_core::actor::Actor;
use mpo_core::agent::{Agent, AgentSchedule};
use mpo_core::config::MpoConfig;
use mpo_core::obs_norm::{CLIP, InputNorm, STD_FLOOR};
use mpo_core::parallel::Serial;
use mpo_core::params::Params;
use mpo_core::replay::Transition;
use mpo_core::rng::Rng;

const OBS: usize = 4;
const ACT: usize = 2;
const TRI: usize = 3;
const H: usize = 16;
const BC: usize = 8;
const C: usize = 2;
const CAP: usize = 512;

type A = Agent<OBS, ACT, TRI, H, H, H, H, BC, C, 1, 4, 4, CAP>;

/// Observations with very different scales and offsets per input; input 3 is constant.
fn observation(rng: &mut Rng) -> [f32; OBS] {
    [
        rng.uniform_range(-1.0, 1.0),
        30.0 * rng.uniform_range(-1.0, 1.0) + 12.0,
        0.01 * rng.uniform_range(-1.0, 1.0) - 3.0,
        0.7,
    ]
}

#[test]
fn fit_equals_the_statistics_written_out_and_clips_outliers() {
    let mut rng = Rng::seed_from_u64(3);
    let rows: Vec<[f32; OBS]> = (0..1000).map(|_| observation(&mut rng)).collect();
    let mut n = InputNorm::<OBS>::zeroed_identity();
    n.fit(&rows);
    for j in 0..OBS {
        // Written out: the mean, then the population variance from the differences.
        let xs: Vec<f64> = rows.iter().map(|r| r[j] as f64).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        let std = var.sqrt().max(STD_FLOOR);
        assert!(
            (n.shift[j] as f64 - mean).abs() <= 1e-6 * (1.0 + mean.abs()),
            "shift[{j}] {} vs mean {mean}",
            n.shift[j]
        );
        assert!(
            (n.scale[j] as f64 * std - 1.0).abs() < 1e-6,
            "scale[{j}] {} vs 1/std {}",
            n.scale[j],
            1.0 / std
        );
        assert_eq!(n.limit[j], CLIP);
    }
    // Normalised rows: mean 0 and standard deviation 1 per input (the constant input: 0).
    let z: Vec<[f32; OBS]> = rows.iter().map(|r| n.apply(r)).collect();
    for j in 0..3 {
        let m = z.iter().map(|r| r[j] as f64).sum::<f64>() / z.len() as f64;
        let v = z.iter().map(|r| (r[j] as f64 - m).powi(2)).sum::<f64>() / z.len() as f64;
        assert!(
            m.abs() < 1e-4 && (v - 1.0).abs() < 1e-3,
            "input {j}: {m} {v}"
        );
    }
    assert!(z.iter().all(|r| r[3] == 0.0), "a constant input is centred");
    // An outlier is clipped to the bound, on both sides.
    let far = n.apply(&[1e6, -1e6, 0.0, 0.7]);
    assert_eq!((far[0], far[1]), (CLIP, -CLIP));
    // No rows: unchanged.
    let before = n.clone();
    n.fit(&[]);
    assert_eq!(before.shift, n.shift);
}

trait Identity {
    fn zeroed_identity() -> Self;
}

impl Identity for InputNorm<OBS> {
    fn zeroed_identity() -> Self {
        let mut n: Self = bytemuck::Zeroable::zeroed();
        n.init();
        n
    }
}

#[test]
fn the_identity_passes_every_finite_input_bit_for_bit_and_keeps_nan() {
    let n = InputNorm::<OBS>::zeroed_identity();
    assert!(n.is_identity());
    let mut rng = Rng::seed_from_u64(9);
    let specials = [
        0.0f32,
        -0.0,
        f32::MAX,
        f32::MIN,
        f32::MIN_POSITIVE,
        1e-45,
        -1e-45,
    ];
    for t in 0..100_000 {
        let x: [f32; OBS] = core::array::from_fn(|j| {
            if t < specials.len() {
                specials[(t + j) % specials.len()]
            } else {
                // Random bit patterns: every exponent, subnormals included.
                let v = f32::from_bits(rng.next_u64() as u32);
                if v.is_finite() { v } else { 1.5 }
            }
        });
        let y = n.apply(&x);
        for j in 0..OBS {
            assert_eq!(y[j].to_bits(), x[j].to_bits(), "{:e}", x[j]);
        }
    }
    assert!(n.apply(&[f32::NAN, 0.0, 0.0, 0.0])[0].is_nan());
}

#[test]
fn parameters_from_outside_cannot_make_it_panic() {
    let mut n = InputNorm::<OBS>::zeroed_identity();
    n.limit = [-1.0, f32::NAN, 0.0, f32::INFINITY];
    n.scale = [f32::NAN, 1.0, -2.0, 0.0];
    let y = n.apply(&[1.0, 2.0, 3.0, 4.0]);
    assert_eq!(y[2], 0.0);
    assert_eq!(y[3], 0.0);
}

/// Runs an agent with normalisation every `every` steps from a warm-up of `warmup` steps,
/// checking after each step that the policy's normaliser is the identity before the warm-up
/// ends and equals a fit to the replay's observations as of the last refit after it.
#[test]
fn the_agent_refits_on_schedule_and_normalises_batches_and_actions() {
    let (warmup, every) = (64u64, 50u64);
    let cfg = MpoConfig {
        obs_norm_interval: every as u32,
        mstep_iters: 1,
        ..MpoConfig::REPORT
    };
    let schedule = AgentSchedule {
        warmup_steps: warmup,
        update_interval: 4,
        updates_per_interval: 1,
        n_step: 1,
        noise_corr: 0.0,
        noise_pink: false,
    };
    let mut agent: Box<A> = bytemuck::zeroed_box();
    agent.init(cfg, 1, 2, schedule).unwrap();
    let mut rng = Rng::seed_from_u64(5);
    let mut obs = observation(&mut rng);
    let mut last_fit: Option<InputNorm<OBS>> = None;
    let mut batches_checked = 0;
    for step in 1..=300u64 {
        let mut action = [0f32; ACT];
        agent.act(&obs, &mut action);
        let next = observation(&mut rng);
        let t = Transition {
            obs,
            action,
            reward: rng.uniform_range(0.0, 1.0),
            next_obs: next,
            discount: 1.0,
            behaviour_log_prob: 0.0,
        };
        agent.observe(&t, &Serial, &mut |_| {}).unwrap();
        let stored: Vec<[f32; OBS]> = (0..agent.replay.len())
            .map(|k| agent.replay.get(k).obs)
            .collect();
        if step >= warmup && (step - warmup) % every == 0 {
            let mut want = InputNorm::<OBS>::zeroed_identity();
            want.fit(&stored);
            last_fit = Some(want);
        }
        let input = &agent.learner.live.actor.input;
        match &last_fit {
            None => assert!(
                input.is_identity(),
                "step {step}: fit before the warm-up ended"
            ),
            Some(want) => {
                assert_eq!(input.shift, want.shift, "step {step}");
                assert_eq!(input.scale, want.scale, "step {step}");
                assert_eq!(agent.learner.target_actor.input.shift, want.shift);
            }
        }
        // The batch the last update learned from: every state and next state is a stored
        // observation passed through the policy's normaliser (the next state of the last
        // transition is not stored as a state, hence the two lists).
        if step >= warmup && step % schedule.update_interval == 0 {
            let n = agent.learner.live.actor.input.clone();
            let states: Vec<[u32; OBS]> = stored
                .iter()
                .map(|o| n.apply(o).map(f32::to_bits))
                .collect();
            let nexts: Vec<[u32; OBS]> = (0..agent.replay.len())
                .map(|k| n.apply(&agent.replay.get(k).next_obs).map(f32::to_bits))
                .collect();
            for b in &agent.learner.batch {
                for r in 0..BC {
                    assert!(
                        states.contains(&b.obs[0][r].map(f32::to_bits)),
                        "step {step}"
                    );
                    assert!(
                        nexts.contains(&b.next_obs[0][r].map(f32::to_bits)),
                        "step {step}"
                    );
                    assert!(b.obs[0][r].iter().all(|v| v.abs() <= CLIP));
                }
            }
            batches_checked += 1;
        }
        obs = next;
    }
    assert!(batches_checked > 50);
    // Acting: the policy's mean action is the trunk's on the normalised state, i.e. that of
    // the same network with an identity normaliser fed the normalised state.
    let actor = &agent.learner.live.actor;
    let mut plain: Box<Actor<OBS, ACT, TRI, H, H>> = bytemuck::zeroed_box();
    plain.copy_from(actor);
    plain.input.init();
    for _ in 0..20 {
        let o = observation(&mut rng);
        let (mut a, mut b) = ([0f32; ACT], [0f32; ACT]);
        agent.learner.mean_action(&o, &mut a);
        plain.mean_action(&actor.input.apply(&o), &mut b);
        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
        let mut raw = [0f32; ACT];
        plain.mean_action(&o, &mut raw);
        assert_ne!(a, raw, "the fit normaliser changes the action");
    }
}
