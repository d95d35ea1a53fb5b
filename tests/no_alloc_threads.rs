//! The learner's update on the host's thread pool allocates nothing on any thread.
//!
//! A binary of its own with a single test: the counting allocator's all-threads count would
//! otherwise see other tests' allocations.

use mpo_core::rng::Rng;
use mpo_integration::CountingAlloc;

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

const OBS: usize = 15;
const ACT: usize = 4;
const TRI: usize = 10;
const H: usize = 256;

/// The hopper-size learner: 2 chunks of 32 rows, sequences up to 3.
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

/// Every path of an update (Retrace, action penalization, shared samples, Polyak targets,
/// observation normalisation) on
/// the host's thread pool allocates nothing on any thread once the pool exists. The only test
/// in this binary that spreads work over threads, so the all-threads count sees nothing else.
#[test]
fn threaded_updates_allocate_nothing_on_any_thread() {
    use mpo_core::config::MpoConfig;
    use mpo_integration::count_allocations_all_threads;
    let pool = mpo_host::pool::PoolParallel::new(2).unwrap();
    let mut rng = Rng::seed_from_u64(4);
    let mut learner: Box<Hopper> = bytemuck::zeroed_box();
    for cfg in [
        MpoConfig {
            sequence_len: 3,
            action_penalization: true,
            target_tau: 0.005,
            critic_layer_norm: true,
            tanh_mean: true,
            clip_critic_actions: true,
            ..MpoConfig::REPORT
        },
        MpoConfig {
            shared_samples: true,
            per_dim_kl: true,
            obs_norm_interval: 1,
            ..MpoConfig::REPORT
        },
    ] {
        learner.init(cfg, 5).unwrap();
        for round in 0..3 {
            fill(&mut learner, &mut rng);
            let (r, n) = count_allocations_all_threads(|| {
                if cfg.obs_norm_interval > 0 {
                    // What the agent does: refit the normaliser, normalise the batch.
                    let rows = learner.batch[0].obs[0];
                    learner.fit_obs_norm(&rows);
                    learner.normalize_batch();
                }
                learner.update_with(&pool)
            });
            r.unwrap();
            assert_eq!(n, 0, "threaded update {round} allocated {n} times");
        }
    }
}
