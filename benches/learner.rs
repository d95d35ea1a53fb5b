//! Learner updates per second on one thread: batch 256, hidden 256-256, at cartpole
//! (observation 5, action 1) and hopper (15, 4) dimensions, for the configuration
//! "20 E-step samples, 20 next-action samples, 1 M-step iteration" and the report's
//! "20 E-step samples, 64 next-action samples, 5 M-step iterations".
//!
//! Run: `cargo bench --bench learner`. Prints a Markdown table (median of 5 timed runs of
//! `ITERS` updates each, after warm-up updates) with FLOPs per update (network arithmetic:
//! see `Learner::flops_per_update`) and the achieved GFLOP/s.

#![allow(clippy::needless_range_loop)]

use std::hint::black_box;
use std::time::Instant;

use mpo_core::config::MpoConfig;
use mpo_core::learner::Learner;
use mpo_core::rng::Rng;

const B: usize = 256;
const H: usize = 256;

fn bench<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize>(
    label: &str,
    mstep_iters: u32,
) {
    let mut l: Box<Learner<OBS, ACT, TRI, H, H, B, M, N>> = bytemuck::zeroed_box();
    let cfg = MpoConfig {
        mstep_iters,
        ..MpoConfig::REPORT
    };
    l.init(cfg, 0).unwrap();
    let mut rng = Rng::seed_from_u64(1);
    let mut refill = |l: &mut Learner<OBS, ACT, TRI, H, H, B, M, N>| {
        rng.fill_normal(l.batch.obs.as_flattened_mut());
        rng.fill_normal(l.batch.action.as_flattened_mut());
        rng.fill_normal(l.batch.next_obs.as_flattened_mut());
        rng.fill_normal(&mut l.batch.reward);
        l.batch.bootstrap = [0.99; B];
    };
    for _ in 0..3 {
        refill(&mut l);
        l.update().unwrap();
    }
    const ITERS: usize = 8;
    let mut times: Vec<f64> = (0..5)
        .map(|_| {
            let mut t = 0.0;
            for _ in 0..ITERS {
                refill(&mut l);
                let start = Instant::now();
                black_box(l.update().unwrap());
                t += start.elapsed().as_secs_f64();
            }
            t / ITERS as f64
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let secs = times[2];
    let flops =
        Learner::<OBS, ACT, TRI, H, H, B, M, N>::flops_per_update(mstep_iters as usize) as f64;
    println!(
        "| {label} | {M} | {N} | {mstep_iters} | {:.1} | {:.2} | {:.2} | {:.1} |",
        1.0 / secs,
        secs * 1e3,
        flops / 1e9,
        flops / secs / 1e9
    );
}

fn main() {
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "load average (1, 5, 15 min) at start: {}\n",
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "| dimensions | E-step samples M | next-action samples N | M-step iterations | updates/s | ms/update | GFLOP/update | GFLOP/s |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    bench::<5, 1, 1, 20, 20>("cartpole 5/1", 1);
    bench::<15, 4, 10, 20, 20>("hopper 15/4", 1);
    bench::<5, 1, 1, 20, 64>("cartpole 5/1 (report)", 5);
    bench::<15, 4, 10, 20, 64>("hopper 15/4 (report)", 5);
}
