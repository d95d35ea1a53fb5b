//! Learner updates per second: batch 256 (4 chunks of 64), hidden 256-256 for both networks,
//! at cartpole (observation 5, action 1), hopper (15, 4) and walker (24, 6) dimensions, for
//! "20 E-step samples, 20 next-action samples, 1 M-step iteration", the report's "20 E-step
//! samples, 64 next-action samples, 5 M-step iterations", Acme's shared samples (the E- and
//! M-steps reuse the TD target's 20 samples), and Retrace over 5 transitions.
//!
//! The suite rows as `mpo train` runs them: a built-in row's sizes and configuration (shared
//! samples, 5-step returns, action penalization's second temperature solve, 5 M-step
//! iterations), its updates/s out (`row TASK` runs one: `cargo bench --bench learner -- row
//! walker-walk`).
//!
//! Run: `cargo bench --bench learner`. Every configuration is timed on one thread and on two,
//! alternating the two in each of 7 rounds of `ITERS` updates (so both see the same machine
//! state), and the medians are printed as a Markdown table with the network arithmetic per
//! update (`Learner::flops_per_update`) and the achieved GFLOP/s. One thread is also timed by
//! the CPU time the calling thread got (with one thread it runs every item), which a loaded
//! machine disturbs far less than the wall clock. Both thread counts give the
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
/// The built-in 256-256 rows' sequence capacity.
const ROW_SEQ: usize = 8;
const ITERS: usize = 6;

type Ls<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const S: usize,
    const M: usize,
    const N: usize,
> = Learner<OBS, ACT, TRI, H, H, H, H, BC, C, S, M, N>;
type L<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize> =
    Ls<OBS, ACT, TRI, SEQ, M, N>;

fn refill<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const S: usize,
    const M: usize,
    const N: usize,
>(
    l: &mut Ls<OBS, ACT, TRI, S, M, N>,
    rng: &mut Rng,
) {
    for b in l.batch.iter_mut() {
        rng.fill_normal(b.obs.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.action.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.next_obs.as_flattened_mut().as_flattened_mut());
        rng.fill_normal(b.reward.as_flattened_mut());
        b.bootstrap = [[0.99; BC]; S];
        for x in b.behaviour_log_prob.as_flattened_mut() {
            *x = -1.0 - rng.uniform();
        }
    }
}

/// Seconds per update of `ITERS` updates on `par`: (wall clock, CPU time of the calling
/// thread). With one thread every item runs on the calling thread, so its CPU time is the
/// update's, whatever else the machine runs (docs/core.md says why both are printed).
fn round<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const S: usize,
    const M: usize,
    const N: usize,
>(
    l: &mut Ls<OBS, ACT, TRI, S, M, N>,
    rng: &mut Rng,
    par: &impl Parallel,
) -> (f64, f64) {
    let (mut t, mut cpu) = (0.0, 0.0);
    for _ in 0..ITERS {
        refill(l, rng);
        let (start, c0) = (Instant::now(), thread_cpu_secs());
        black_box(l.update_with(par).unwrap());
        cpu += thread_cpu_secs() - c0;
        t += start.elapsed().as_secs_f64();
    }
    (t / ITERS as f64, cpu / ITERS as f64)
}

/// CPU time of the calling thread, in seconds.
fn thread_cpu_secs() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant the kernel knows.
    #[allow(unsafe_code)]
    let r = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(r, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

fn bench<const OBS: usize, const ACT: usize, const TRI: usize, const M: usize, const N: usize>(
    label: &str,
    cfg: MpoConfig,
    one: &PoolParallel,
    two: &PoolParallel,
) {
    bench_seq::<OBS, ACT, TRI, SEQ, M, N>(label, cfg, one, two);
}

/// A built-in row's learner as `mpo train` runs it: the row's configuration
/// (`Row::mpo`, through the same `to_config` as training) on the row's sizes, which must be
/// these types' (checked).
fn bench_row<const OBS: usize, const ACT: usize, const TRI: usize>(
    task: &str,
    net: &str,
    one: &PoolParallel,
    two: &PoolParallel,
) {
    let row = mpo_host::table::row(task, net).expect("a built-in row");
    let want = mpo_host::sizes::Sizes {
        obs: OBS,
        act: ACT,
        actor: [H, H],
        critic: [H, H],
        batch: BC * C,
        chunks: C,
        seq: ROW_SEQ,
        m: 20,
        n: 20,
        replay_capacity: row.sizes.replay_capacity,
        actor_blocks: 0,
        critic_blocks: 0,
        bins: 1,
    };
    assert_eq!(
        row.sizes, want,
        "{task} `{net}`: the bench's types are not the row's sizes"
    );
    let cfg = row.mpo.to_config();
    let label = format!("{task} `{net}` row (as trained)");
    bench_seq::<OBS, ACT, TRI, ROW_SEQ, 20, 20>(&label, cfg, one, two);
}

fn bench_seq<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const S: usize,
    const M: usize,
    const N: usize,
>(
    label: &str,
    cfg: MpoConfig,
    one: &PoolParallel,
    two: &PoolParallel,
) {
    let mut a: Box<Ls<OBS, ACT, TRI, S, M, N>> = bytemuck::zeroed_box();
    let mut b: Box<Ls<OBS, ACT, TRI, S, M, N>> = bytemuck::zeroed_box();
    a.init(cfg, 0).unwrap();
    b.init(cfg, 0).unwrap();
    let (mut ra, mut rb) = (Rng::seed_from_u64(1), Rng::seed_from_u64(1));
    for _ in 0..2 {
        refill(&mut a, &mut ra);
        a.update_with(one).unwrap();
        refill(&mut b, &mut rb);
        b.update_with(two).unwrap();
    }
    let (mut t1, mut t2, mut c1) = (vec![], vec![], vec![]);
    for _ in 0..7 {
        let (w, c) = round(&mut a, &mut ra, one);
        t1.push(w);
        c1.push(c);
        t2.push(round(&mut b, &mut rb, two).0);
    }
    assert_eq!(
        (fingerprint(&a.live.actor), fingerprint(&a.live.critic)),
        (fingerprint(&b.live.actor), fingerprint(&b.live.critic)),
        "{label}: one and two threads differ"
    );
    t1.sort_by(f64::total_cmp);
    t2.sort_by(f64::total_cmp);
    c1.sort_by(f64::total_cmp);
    let (s1, s2, sc) = (t1[3], t2[3], c1[3]);
    let flops = a.flops_per_update() as f64;
    println!(
        "| {label} | {M} | {N} | {} | {:.1} | {:.1} | {:.1} | {:.2}x | {:.2} | {:.2} | {:.1} | {:.1} |",
        cfg.mstep_iters,
        1.0 / s1,
        1.0 / sc,
        1.0 / s2,
        s1 / s2,
        s1 * 1e3,
        flops / 1e9,
        flops / sc / 1e9,
        flops / s2 / 1e9,
    );
}

/// `cargo bench --bench learner -- profile N`: `N` updates at walker size on one thread, and
/// nothing else (for `perf record` or `valgrind --tool=callgrind`).
/// `profile N` runs N updates of the first walker configuration; `profile N suite` runs the
/// suite rows' learner settings instead (shared samples, action penalization at 0.1, eps_mean
/// 0.01, actor clip 40, the report's 5 M-step iterations unless a count follows: `suite 1`);
/// `profile N row` runs walker-walk's row exactly as `mpo train` does (its configuration and
/// sizes). A trailing `threads T` runs them on a pool of `T` threads.
fn profile(updates: usize, mode: &[String], threads: usize) {
    let pool = PoolParallel::new(threads).unwrap();
    if mode.first().map(String::as_str) == Some("row") {
        let row = mpo_host::table::row("walker-walk", mpo_host::table::DEFAULT_NET).unwrap();
        let mut l: Box<Ls<24, 6, 21, ROW_SEQ, 20, 20>> = bytemuck::zeroed_box();
        l.init(row.mpo.to_config(), 0).unwrap();
        let mut rng = Rng::seed_from_u64(1);
        for _ in 0..updates {
            refill(&mut l, &mut rng);
            black_box(l.update_with(&pool).unwrap());
        }
        return;
    }
    let suite = (mode.first().map(String::as_str) == Some("suite"))
        .then(|| mode.get(1).and_then(|v| v.parse().ok()).unwrap_or(5));
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
        black_box(l.update_with(&pool).unwrap());
    }
}

/// The suite rows' benches (`row TASK` runs the one named).
fn bench_rows(only: Option<&str>, one: &PoolParallel, two: &PoolParallel) {
    let on = |t: &str| only.is_none_or(|o| o == t);
    if on("walker-walk") {
        bench_row::<24, 6, 21>("walker-walk", "default", one, two);
    }
    if on("hopper-hop") {
        // hopper-hop's 256-256 MLP row (its default is the residual `simba` row since 2026-12-05).
        bench_row::<15, 4, 10>("hopper-hop", "mlp", one, two);
    }
    if on("cheetah-run") {
        bench_row::<17, 6, 21>("cheetah-run", "default", one, two);
    }
    if on("cartpole-swingup") {
        bench_row::<5, 1, 1>("cartpole-swingup", "default", one, two);
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let threads = args
        .iter()
        .position(|a| a == "threads")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(1);
    if let Some(i) = args.iter().position(|a| a == "profile") {
        let n = args.get(i + 1).and_then(|v| v.parse().ok()).unwrap_or(3);
        let end = args
            .iter()
            .position(|a| a == "threads")
            .unwrap_or(args.len());
        return profile(n, &args[(i + 2).min(end)..end], threads);
    }
    let only_row = args
        .iter()
        .position(|a| a == "row")
        .and_then(|i| args.get(i + 1).cloned());
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
        "| dimensions, configuration | M | N | M-step iterations | updates/s, 1 thread | 1 thread by its CPU time | updates/s, 2 threads | speed-up (wall) | ms/update (1 thread) | GFLOP/update | GFLOP/s (1, CPU time) | GFLOP/s (2) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    if only_row.is_some() {
        return bench_rows(only_row.as_deref(), &one, &two);
    }
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
    bench_rows(None, &one, &two);
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
