//! Correlated exploration noise (`AgentSchedule::noise_corr`): independent draws when it is 0
//! (the bits of `Learner::sample_action`), an AR(1) process with standard-normal marginals and
//! lag-one correlation `beta` otherwise, restarted at every episode, and refused where it would
//! be wrong (out of range, or with Retrace). Pink noise (`AgentSchedule::noise_pink`): standard
//! normal draws whose correlation at every lag is that of Voss's generator, computed here by
//! counting the rows two steps share.

use mpo_core::agent::{Agent, AgentSchedule, PINK_OCTAVES};
use mpo_core::config::MpoConfig;
use mpo_core::rng::Rng;

const OBS: usize = 3;
const ACT: usize = 2;
const TRI: usize = 3;
const H: usize = 8;
const CAP: usize = 64;

type A = Agent<OBS, ACT, TRI, H, H, H, H, 4, 1, 4, 4, 4, CAP>;

fn agent(noise_corr: f32, cfg: MpoConfig) -> Result<Box<A>, mpo_core::config::ConfigError> {
    agent_with(noise_corr, false, cfg)
}

fn agent_with(
    noise_corr: f32,
    noise_pink: bool,
    cfg: MpoConfig,
) -> Result<Box<A>, mpo_core::config::ConfigError> {
    let mut a: Box<A> = bytemuck::zeroed_box();
    let schedule = AgentSchedule {
        warmup_steps: 0,
        update_interval: 1,
        updates_per_interval: 1,
        n_step: 1,
        noise_corr,
        noise_pink,
    };
    a.init(cfg, 7, 11, schedule)?;
    Ok(a)
}

/// With `noise_corr = 0` the agent's action is the learner's `sample_action` on the collector's
/// stream, bit for bit, step after step (the refactoring into `draw_noise` changed no run).
#[test]
fn independent_noise_is_sample_action_bit_for_bit() {
    let mut a = agent(0.0, MpoConfig::REPORT).unwrap();
    let mut rng = Rng::from_state(a.explore.collector);
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
        Rng::from_state(a.explore.collector).fill_normal(&mut fresh);
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

/// The correlation of pink draws `lag` steps apart, averaged over the pairs `(t, t + lag)` of
/// an episode of `len` steps: the fraction of the rows both steps share (row `k` is one value
/// over each block of `2^k` steps), counted pair by pair.
fn voss_correlation(lag: usize, len: usize) -> f64 {
    let mut shared = 0usize;
    for t in 0..len - lag {
        shared += (0..PINK_OCTAVES)
            .filter(|&k| t >> k == (t + lag) >> k)
            .count();
    }
    shared as f64 / ((len - lag) * PINK_OCTAVES) as f64
}

/// Pink noise over 600 episodes of 1024 steps: each draw standard normal (mean 0, variance 1),
/// the correlation at lags 1 to 512 that of Voss's generator (0.80 at lag 1, 0.23 at 64, 0.07
/// at 256: the long pushes white noise lacks and AR(1) noise has at one time scale), an episode's first draw the scaled sum
/// of ten fresh rows and its second one that with only row 0 redrawn.
#[test]
fn pink_noise_is_standard_normal_with_the_correlation_of_voss_generator() {
    const LEN: usize = 1024;
    const LAGS: [usize; 6] = [1, 2, 8, 64, 256, 512];
    let mut a = agent_with(0.0, true, MpoConfig::REPORT).unwrap();
    let scale = 1.0 / (PINK_OCTAVES as f32).sqrt();
    let (mut n, mut sum, mut sq) = (0f64, 0f64, 0f64);
    let mut lag_sum = [0f64; LAGS.len()];
    let mut lag_n = [0f64; LAGS.len()];
    let mut episode = vec![[0f32; ACT]; LEN];
    for _ in 0..600 {
        a.begin_episode();
        let mut rng = Rng::from_state(a.explore.collector);
        let mut rows = [[0f32; ACT]; PINK_OCTAVES];
        for row in rows.iter_mut() {
            rng.fill_normal(row);
        }
        let first =
            core::array::from_fn::<f32, ACT, _>(|i| rows.iter().map(|r| r[i]).sum::<f32>() * scale);
        rng.fill_normal(&mut rows[0]);
        let second =
            core::array::from_fn::<f32, ACT, _>(|i| rows.iter().map(|r| r[i]).sum::<f32>() * scale);
        for z in episode.iter_mut() {
            a.draw_noise(z);
        }
        assert_eq!(
            episode[0], first,
            "an episode's first draw is not ten fresh rows"
        );
        assert_eq!(
            episode[1], second,
            "the second draw redraws more than row 0"
        );
        for z in &episode {
            for &x in z {
                n += 1.0;
                sum += x as f64;
                sq += (x as f64) * (x as f64);
            }
        }
        for (j, &lag) in LAGS.iter().enumerate() {
            for (now, later) in episode.iter().zip(&episode[lag..]) {
                for (x, y) in now.iter().zip(later) {
                    lag_sum[j] += (x * y) as f64;
                    lag_n[j] += 1.0;
                }
            }
        }
    }
    let mean = sum / n;
    let var = sq / n - mean * mean;
    // An episode's mean has variance about 0.1 (the slow rows hold for most of it): over 1200
    // episode-dimensions the mean's standard error is about 0.01.
    assert!(mean.abs() < 0.04, "mean {mean}");
    assert!((var - 1.0).abs() < 0.05, "variance {var}");
    for (j, &lag) in LAGS.iter().enumerate() {
        let got = lag_sum[j] / lag_n[j] / var;
        let want = voss_correlation(lag, LEN);
        assert!(
            (got - want).abs() < 0.03,
            "lag {lag}: correlation {got}, Voss's generator {want}"
        );
    }
}

/// Pink noise is refused with correlated (AR(1)) noise and with Retrace.
#[test]
fn pink_noise_with_ar1_noise_or_retrace_is_refused() {
    let retrace = MpoConfig {
        sequence_len: 4,
        ..MpoConfig::REPORT
    };
    for (corr, cfg) in [(0.5, MpoConfig::REPORT), (0.0, retrace)] {
        let e = agent_with(corr, true, cfg).err().expect("accepted");
        assert_eq!(e.field, "noise_pink", "noise_corr {corr}");
    }
    assert!(agent_with(0.0, true, MpoConfig::REPORT).is_ok());
}
