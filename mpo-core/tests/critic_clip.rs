//! `clip_critic_actions` (Acme's `ClipToSpec` before the critic): the critic is only ever given
//! actions inside the actuators' range `[-1, 1]`, on both of its input paths: the replayed
//! actions of its loss, and the target policy's samples whose values make the TD target and
//! the E-step's weights. Each test also runs with the option off, to show it can fail.

#![allow(clippy::needless_range_loop)]

use mpo_core::batch::BatchChunk;
use mpo_core::config::MpoConfig;
use mpo_core::learner::Learner;
use mpo_core::params::fingerprint;
use mpo_core::rng::Rng;

const OBS: usize = 1;
const ACT: usize = 1;
const TRI: usize = 1;
const H: usize = 32;
const BC: usize = 16;
const C: usize = 4;
const M: usize = 20;
const N: usize = 20;

type L = Learner<OBS, ACT, TRI, H, H, H, H, BC, C, 1, M, N>;

/// One-step transitions from the constant state `[1]`, actions spread over `[-3, 3]` (two
/// thirds outside the box), rewards from the action as the plant clips it.
fn fill(batch: &mut [BatchChunk<BC, 1, OBS, ACT>; C], rng: &mut Rng) {
    for ch in batch.iter_mut() {
        for i in 0..BC {
            let a = 6.0 * rng.uniform() - 3.0;
            ch.obs[0][i] = [1.0];
            ch.action[0][i] = [a];
            ch.reward[0][i] = 1.0 - (a.clamp(-1.0, 1.0) - 0.5).powi(2);
            ch.next_obs[0][i] = [1.0];
            ch.bootstrap[0][i] = 0.99;
            ch.behaviour_log_prob[0][i] = 0.0;
        }
    }
}

fn learner(cfg: MpoConfig) -> Box<L> {
    let mut l: Box<L> = bytemuck::zeroed_box();
    l.init(cfg, 7).unwrap();
    l
}

/// The loss path: with the option on, replayed actions beyond the box train the critic
/// exactly as the same actions clipped beforehand do (TD(0), where a batch's actions reach
/// nothing but the critic), to the bit over ten updates; with it off they do not.
#[test]
fn replayed_actions_reach_the_critic_clipped() {
    let run = |clip: bool, preclip: bool| {
        let cfg = MpoConfig {
            clip_critic_actions: clip,
            ..MpoConfig::REPORT
        };
        let mut l = learner(cfg);
        let mut rng = Rng::seed_from_u64(3);
        for _ in 0..10 {
            fill(&mut l.batch, &mut rng);
            if preclip {
                for ch in l.batch.iter_mut() {
                    for a in ch.action[0].iter_mut() {
                        a[0] = a[0].clamp(-1.0, 1.0);
                    }
                }
            }
            l.update().unwrap();
        }
        fingerprint(&l.live.critic)
    };
    assert_eq!(run(true, false), run(true, true));
    assert_ne!(run(false, false), run(false, true));
}

/// The sample path: a wide policy (standard deviation 3) puts most E-step samples outside the
/// box. With the option on, every sample's value (the update's `q_min`, `q_max`) lies within
/// the range of the target critic over `[-1, 1]` at that state, found on a grid of 4001
/// points written out here; with it off the critic's extrapolation reaches beyond that range.
/// Both with the report's separate E-step samples and with Acme's shared samples.
#[test]
fn sampled_actions_reach_the_critic_clipped() {
    for shared in [false, true] {
        let outside = |clip: bool| {
            let cfg = MpoConfig {
                clip_critic_actions: clip,
                shared_samples: shared,
                init_std: 3.0,
                ..MpoConfig::REPORT
            };
            let mut l = learner(cfg);
            fill(&mut l.batch, &mut Rng::seed_from_u64(5));
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for k in 0..=4000 {
                let a = -1.0 + k as f32 / 2000.0;
                let q = l.target_critic.q_one(&[1.0], &[a], false);
                lo = lo.min(q);
                hi = hi.max(q);
            }
            let s = l.update().unwrap();
            // How far the sampled values leave the in-box range, relative to its width (the
            // grid's own error is below 1e-3 of it for a critic this smooth).
            let width = (hi - lo).max(1e-6);
            ((lo - s.q_min).max(s.q_max - hi) / width, s.action_excess)
        };
        let (with, excess) = outside(true);
        let (without, _) = outside(false);
        assert!(excess > 1.0, "the samples should leave the box: {excess}");
        assert!(
            with <= 1e-3,
            "shared {shared}: a clipped sample valued {with} widths outside the box's range"
        );
        assert!(
            without > 0.05,
            "shared {shared}: unclipped samples should reach beyond the box's range: {without}"
        );
    }
}
