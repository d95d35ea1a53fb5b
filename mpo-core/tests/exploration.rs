//! Correlated exploration noise (`AgentSchedule::noise_corr`): independent draws when it is 0
//! (the bits of `Learner::sample_action`), an AR(1) process with standard-normal marginals and
//! lag-one correlation `beta` otherwise, restarted at every episode, and refused where it would
//! be wrong (out of range, or with Retrace).

use mpo_core::agent::{Agent, AgentSchedule};
use mpo_core::config::MpoConfig;
use mpo_core::rng::Rng;

const OBS: usize = 3;
const ACT: usize = 2;
const TRI: usize = 3;
const H: usize = 8;
const CAP: usize = 64;

type A = Agent<OBS, ACT, TRI, H, H, H, H, 4, 1, 4, 4, 4, CAP>;

fn agent(noise_corr: f32, cfg: MpoConfig) -> Result<Box<A>, mpo_core::config::ConfigError> {
    let mut a: Box<A> = bytemuck::zeroed_box();
    let schedule = AgentSchedule {
        warmup_steps: 0,
        update_interval: 1,
        updates_per_interval: 1,
        n_step: 1,
        noise_corr,
    };
    a.init(cfg, 7, 11, schedule)?;
    Ok(a)
}

/// With `noise_corr = 0` the agent's action is the learner's `sample_action` on the collector's
/// stream, bit for bit, step after step (the refactoring into `draw_noise` changed no run).
#[test]
fn independent_noise_is_sample_action_bit_for_bit() {
    let mut a = agent(0.0, MpoConfig::REPORT).unwrap();
    let mut rng = Rng::from_state(a.collector);
    let mut obs_rng = Rng::seed_from_u64(3);
    a.begin_episode();
    for _ in 0..200 {
        let obs = [0.0; OBS].map(|_: f32| obs_rng.uniform_range(-2.0, 2.0));
        let (mut got, mut want) = ([0f32; ACT], [0f32; ACT]);
        let lp = a.act(&obs, &mut got);
        let lp_want = a.learner.sample_action(&obs, &mut rng, &mut want);
        assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits));
        assert_eq!(lp.to_bits(), lp_want.to_bits());
    }
}

/// With `beta = 0.9`, over 400 episodes of 500 steps: every draw's mean is 0 and variance 1
/// (each `z_t` standard normal), consecutive draws correlate at `beta` within an episode, and
/// an episode's first draw is the collector's fresh normal draw (so it is independent of the
/// previous episode: the correlation across boundaries is about 0, not `beta`).
#[test]
fn correlated_noise_is_standard_normal_with_lag_one_correlation_beta() {
    let beta = 0.9f32;
    let mut a = agent(beta, MpoConfig::REPORT).unwrap();
    let (mut n, mut sum, mut sq, mut lag, mut lag_n) = (0f64, 0f64, 0f64, 0f64, 0f64);
    let (mut across, mut across_n) = (0f64, 0f64);
    let mut last_of_previous: Option<[f32; ACT]> = None;
    for _ in 0..400 {
        a.begin_episode();
        let mut fresh = [0f32; ACT];
        Rng::from_state(a.collector).fill_normal(&mut fresh);
        let mut prev = [0f32; ACT];
        for t in 0..500 {
            let mut z = [0f32; ACT];
            a.draw_noise(&mut z);
            if t == 0 {
                assert_eq!(z, fresh, "an episode's first draw is not the fresh draw");
                if let Some(p) = last_of_previous {
                    for k in 0..ACT {
                        across += (p[k] * z[k]) as f64;
                        across_n += 1.0;
                    }
                }
            } else {
                for k in 0..ACT {
                    lag += (prev[k] * z[k]) as f64;
                    lag_n += 1.0;
                }
            }
            for &x in &z {
                n += 1.0;
                sum += x as f64;
                sq += (x as f64) * (x as f64);
            }
            prev = z;
        }
        last_of_previous = Some(prev);
    }
    let mean = sum / n;
    let var = sq / n - mean * mean;
    let rho = lag / lag_n / var;
    let rho_across = across / across_n / var;
    // 400k draws with an effective sample size of about n (1 - b) / (1 + b) = 21k: the
    // mean's standard error is about 0.007, the variance's about 0.01.
    assert!(mean.abs() < 0.04, "mean {mean}");
    assert!((var - 1.0).abs() < 0.06, "variance {var}");
    assert!(
        (rho - beta as f64).abs() < 0.01,
        "lag-one correlation {rho}"
    );
    // 798 products of independent pairs: standard error about 0.035.
    assert!(
        rho_across.abs() < 0.15,
        "correlation across episodes {rho_across}"
    );
}

/// Out-of-range correlations and correlated noise with Retrace (which weighs each replayed
/// action by a behaviour density the marginal one is not) are refused at `init`.
#[test]
fn out_of_range_or_retrace_correlation_is_refused() {
    for bad in [1.0, 1.5, -0.1, f32::NAN] {
        let e = agent(bad, MpoConfig::REPORT).err().expect("accepted");
        assert_eq!(e.field, "noise_corr");
    }
    let retrace = MpoConfig {
        sequence_len: 4,
        ..MpoConfig::REPORT
    };
    assert_eq!(
        agent(0.5, retrace).err().expect("accepted").field,
        "noise_corr"
    );
    assert!(agent(0.0, retrace).is_ok());
    assert!(agent(0.99, MpoConfig::REPORT).is_ok());
}
