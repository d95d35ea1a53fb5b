//! Learner updates per second: batch 256 (4 chunks of 64), hidden 256-256 for both networks,
//! at cartpole (observation 5, action 1), hopper (15, 4) and walker (24, 6) dimensions, for
//! "20 E-step samples, 20 next-action samples, 1 M-step iteration", the report's "20 E-step
//! samples, 64 next-action samples, 5 M-step iterations", Acme's shared samples (the E- and
//! M-steps reuse the TD target's 20 samples), and Retrace over 5 transitions.
//!
//! Run: `cargo bench --bench learner`. Every configuration is timed on one thread and on two,
//! alternating the two in each of 7 rounds of `ITERS` updates (so both see the same machine
//! state), and the medians are printed as a Markdown table with the network arithmetic per
//! update (`Learner::flops_per_update`) and the achieved GFLOP/s. Both thread counts give the
//! same parameters bit for bit (checked here after the runs).

#![allow(clippy::needless_range_loop)]

use std::hint::black_box;
use std::time::Instant;

use mpo_core::config::MpoConfig;
use mpo_core::learner::Learner;
use mpo_core::parallel::Parallel;
use mpo_core::params::fingerprint;
use mpo_core::rng::Rng;
use mpo_host::pool::PoolParallel;

const H: usize = 256;
const BC: usize = 64;
const C: usize = 4;
const SEQ: usize = 5;
const ITERS: usize = 6;

type L<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize> =
    Learner<OBS, ACT, TRI, H, H, H, H, BC, C, SEQ, M, N>;

fn refill<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize>(
    l: &mut L<OBS, ACT, TRI, M, N>,
    rng: &mut Rng,
) {
    for b in l.batch.iter_mut() {
        rng.fill_normal(b.obs.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.action.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.next_obs.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.reward.as_flattened_mut());
        b.bootstrap = [[0.99; BC]; SEQ];
        for x in b.behaviour_log_prob.as_flattened_mut() {
            *x = -1.0 - rng.uniform();
        }
    }
}

/// Seconds per update of `ITERS` updates on `par`.
fn round<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize>(
    l: &mut L<OBS, ACT, TRI, M, N>,
    rng: &mut Rng,
    par: &impl Parallel,
) -> f64 {
    let mut t = 0.0;
    for _ in 0..ITERS {
        refill(l, rng);
        let start = Instant::now();
        black_box(l.update_with(par).unwrap());
        t += start.elapsed().as_secs_f64();
    }
    t / ITERS as f64
}

fn bench<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize>(
    label: &str,
    cfg: MpoConfig,
    one: &PoolParallel,
    two: &PoolParallel,
) {
    let mut a: Box<L<OBS, ACT, TRI, M, N>> = bytemuck::zeroed_box();
    let mut b: Box<L<OBS, ACT, TRI, M, N>> = bytemuck::zeroed_box();
    a.init(cfg, 0).unwrap();
    b.init(cfg, 0).unwrap();
    let (mut ra, mut rb) = (Rng::seed_from_u64(1), Rng::seed_from_u64(1));
    for _ in 0..2 {
        refill(&mut a, &mut ra);
        a.update_with(one).unwrap();
        refill(&mut b, &mut rb);
        b.update_with(two).unwrap();
    }
    let (mut t1, mut t2) = (vec![], vec![]);
    for _ in 0..7 {
        t1.push(round(&mut a, &mut ra, one));
        t2.push(round(&mut b, &mut rb, two));
    }
    assert_eq!(
        (fingerprint(&a.live.actor), fingerprint(&a.live.critic)),
        (fingerprint(&b.live.actor), fingerprint(&b.live.critic)),
        "{label}: one and two threads differ"
    );
    t1.sort_by(f64::total_cmp);
    t2.sort_by(f64::total_cmp);
    let (s1, s2) = (t1[3], t2[3]);
    let flops = a.flops_per_update() as f64;
    println!(
        "| {label} | {M} | {N} | {} | {:.1} | {:.1} | {:.2}x | {:.2} | {:.2} | {:.1} | {:.1} |",
        cfg.mstep_iters,
        1.0 / s1,
        1.0 / s2,
        s1 / s2,
        s1 * 1e3,
        flops / 1e9,
        flops / s1 / 1e9,
        flops / s2 / 1e9,
    );
}

/// `cargo bench --bench learner -- profile N`: `N` updates at walker size on one thread, and
/// nothing else (for `perf record` or `valgrind --tool=callgrind`).
/// `profile N` runs N updates of the first walker configuration; `profile N suite` runs the
/// suite rows' learner settings instead (shared samples, action penalization at 0.1, eps_mean
/// 0.01, actor clip 40, the report's 5 M-step iterations unless a count follows: `suite 1`).
fn profile(updates: usize, suite: Option<u32>) {
    let cfg = match suite {
        None => MpoConfig {
            mstep_iters: 1,
            ..MpoConfig::REPORT
        },
        Some(iters) => MpoConfig {
            mstep_iters: iters,
            shared_samples: true,
            action_penalization: true,
            eps_penalty: 0.1,
            eps_mean: 0.01,
            actor_clip: 40.0,
            ..MpoConfig::REPORT
        },
    };
    let mut l: Box<L<24, 6, 21, 20, 20>> = bytemuck::zeroed_box();
    l.init(cfg, 0).unwrap();
    let mut rng = Rng::seed_from_u64(1);
    for _ in 0..updates {
        refill(&mut l, &mut rng);
        black_box(l.update().unwrap());
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "profile") {
        let n = args.get(i + 1).and_then(|v| v.parse().ok()).unwrap_or(3);
        let suite = (args.get(i + 2).map(String::as_str) == Some("suite"))
            .then(|| args.get(i + 3).and_then(|v| v.parse().ok()).unwrap_or(5));
        return profile(n, suite);
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let mhz = std::fs::read_to_string("/proc/cpuinfo")
        .unwrap_or_default()
        .lines()
        .find(|l| l.starts_with("cpu MHz"))
        .and_then(|l| l.split(':').nth(1))
        .map(|v| v.trim().to_string())
        .unwrap_or_default();
    println!(
        "load average (1, 5, 15 min) at start: {}; cpu MHz (as reported): {mhz}\n",
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    let one = PoolParallel::new(1).unwrap();
    let two = PoolParallel::new(2).unwrap();
    println!(
        "| dimensions, configuration | M | N | M-step iterations | updates/s, 1 thread | updates/s, 2 threads | speed-up | ms/update (1 thread) | GFLOP/update | GFLOP/s (1) | GFLOP/s (2) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let base = MpoConfig {
        mstep_iters: 1,
        ..MpoConfig::REPORT
    };
    let report = MpoConfig::REPORT;
    let shared = MpoConfig {
        shared_samples: true,
        ..base
    };
    let retrace = MpoConfig {
        sequence_len: SEQ as u32,
        ..base
    };
    bench::<5, 1, 1, 20, 20>("cartpole 5/1", base, &one, &two);
    bench::<15, 4, 10, 20, 20>("hopper 15/4", base, &one, &two);
    bench::<24, 6, 21, 20, 20>("walker 24/6", base, &one, &two);
    bench::<5, 1, 1, 20, 64>("cartpole 5/1, report", report, &one, &two);
    bench::<15, 4, 10, 20, 64>("hopper 15/4, report", report, &one, &two);
    bench::<5, 1, 1, 20, 20>("cartpole 5/1, shared samples", shared, &one, &two);
    bench::<24, 6, 21, 20, 20>("walker 24/6, shared samples", shared, &one, &two);
    bench::<24, 6, 21, 20, 20>("walker 24/6, Retrace 5", retrace, &one, &two);
    if mpo_core::linear::wide::enabled() {
        // The same configurations with the 512-bit kernels (forward and weight gradient)
        // turned off: the same bits, the 8-wide speed.
        mpo_core::linear::wide::set_enabled(false);
        bench::<5, 1, 1, 20, 20>("cartpole 5/1, 8-wide kernels", base, &one, &two);
        bench::<24, 6, 21, 20, 20>(
            "walker 24/6, shared samples, 8-wide kernels",
            shared,
            &one,
            &two,
        );
        mpo_core::linear::wide::set_enabled(true);
    }
}
