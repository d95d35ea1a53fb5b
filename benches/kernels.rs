//! Kernel benchmarks: single-state actor forward, and batch forward + backward of actor and
//! critic, at the hopper size and at a microcontroller profile, beside this core's measured
//! peak for 8-wide fused multiply-add (the kernels' instruction).
//!
//! Run: `cargo bench --bench kernels` (release profile, the workspace's x86-64-v3 target).
//! Prints a Markdown table; figures are medians of 9 timed repetitions, in the calling
//! thread's CPU time (`MPO_BENCH_WALL=1`: wall clock), and the peaks are the best of 9.

#![allow(clippy::needless_range_loop)]

use std::hint::black_box;
use std::time::Instant;

use mpo_core::actor::{Actor, ActorTape, ActorTransposed};
use mpo_core::critic::{Critic, CriticTape, CriticTransposed};
use mpo_core::rng::Rng;

const B: usize = 256;

/// One Zen 4 core: two 256-bit fused multiply-adds per cycle (32 f32 FLOP/cycle) at about
/// 3.65 GHz (the clock measured on this kind of machine in November; some instances report
/// and run at lower clocks, which the measured peak shows).
const NOMINAL_PEAK: f64 = 117.0;

/// Median seconds per call of `f`, over 9 repetitions of `iters` calls.
fn time<F: FnMut()>(iters: usize, f: F) -> f64 {
    repetitions(iters, f)[4]
}

/// Sorted seconds per call of `f` for 9 repetitions of `iters` calls (after a warm-up): the
/// CPU time the calling thread got (`CLOCK_THREAD_CPUTIME_ID`), or with `MPO_BENCH_WALL=1`
/// the wall clock. On a shared machine (load 6-10 from other work) the wall clock of a
/// single-threaded kernel is mostly the time it waited for a CPU; the thread's CPU time is not
/// (a busy sibling hardware thread or cache still slows it).
fn repetitions<F: FnMut()>(iters: usize, mut f: F) -> Vec<f64> {
    for _ in 0..iters.div_ceil(4) {
        f();
    }
    let wall = std::env::var_os("MPO_BENCH_WALL").is_some();
    let now = || {
        if wall {
            WALL0.with(|t| t.elapsed().as_secs_f64())
        } else {
            thread_cpu_secs()
        }
    };
    let mut v: Vec<f64> = (0..9)
        .map(|_| {
            let t = now();
            for _ in 0..iters {
                f();
            }
            (now() - t) / iters as f64
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v
}

thread_local! {
    static WALL0: Instant = Instant::now();
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

/// Achievable f32 throughput of this core for fused multiply-add: 12 independent 8-wide
/// chains of `x = fma(x, m, c)` (enough to cover the FMA latency on two pipes); the best of 9
/// repetitions, since a peak is a best case (a busy sibling hardware thread or a preemption
/// only lowers it).
fn measure_peak() -> f64 {
    use mpo_core::linear::mul_add;
    // 12 chains: with the two constants, 14 of the 16 AVX2 registers (16 would spill).
    const CH: usize = 12;
    const L: usize = 8;
    let mut acc = [[1.0f32; L]; CH];
    let (m, c) = (black_box(0.999_999f32), black_box(1e-7f32));
    let n = 2_000_000usize;
    let secs = repetitions(1, || {
        for _ in 0..n / 100 {
            for _ in 0..100 {
                for a in acc.iter_mut() {
                    for x in a.iter_mut() {
                        *x = mul_add(*x, m, c);
                    }
                }
            }
        }
        black_box(&mut acc);
    })[0];
    (n * CH * L * 2) as f64 / secs / 1e9
}

/// The same peak measured with 16-wide (512-bit) fused multiply-adds, on a CPU that has
/// AVX-512 (`None` elsewhere): the ceiling of `mpo_core::linear::wide`'s kernels, as the 8-wide peak
/// is of the others (docs/core.md, "512-bit kernels on an AVX-512 CPU").
fn measure_peak_512() -> Option<f64> {
    if !std::arch::is_x86_feature_detected!("avx512f") {
        return None;
    }
    // SAFETY: the CPU has AVX-512F (checked above), the only feature the function enables.
    #[allow(unsafe_code)]
    let secs = repetitions(1, || unsafe { fma_chains_512(black_box(2_000_000)) })[0];
    Some((2_000_000usize * 16 * 16 * 2) as f64 / secs / 1e9)
}

/// 16 independent 16-wide chains of `x = fma(x, m, c)`, `n` times each.
#[target_feature(enable = "avx512f")]
fn fma_chains_512(n: usize) {
    use std::arch::x86_64::{_mm512_fmadd_ps, _mm512_set1_ps};
    let mut acc = [_mm512_set1_ps(1.0); 16];
    let (m, c) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(1e-7));
    for _ in 0..n {
        for a in acc.iter_mut() {
            *a = _mm512_fmadd_ps(*a, m, c);
        }
    }
    black_box(&mut acc);
}

struct Row {
    name: String,
    secs: f64,
    flops: f64,
}

fn actor_rows<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
>(
    label: &str,
    rows: &mut Vec<Row>,
    single: bool,
    batch: bool,
) {
    let mut rng = Rng::seed_from_u64(1);
    let mut actor: Box<Actor<OBS, ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    actor.init(&mut rng, 0.5, 1e-4);
    let mut grad: Box<Actor<OBS, ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    let mut tape: Box<ActorTape<B, H1, H2>> = bytemuck::zeroed_box();
    let mut t: Box<ActorTransposed<ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    let mut obs: Box<[[f32; OBS]; B]> = bytemuck::zeroed_box();
    rng.fill_normal(obs.as_flattened_mut());
    let mut mean: Box<[[f32; ACT]; B]> = bytemuck::zeroed_box();
    let mut chol: Box<[[f32; TRI]; B]> = bytemuck::zeroed_box();
    let mut dm: Box<[[f32; ACT]; B]> = bytemuck::zeroed_box();
    let mut dc: Box<[[f32; TRI]; B]> = bytemuck::zeroed_box();
    rng.fill_normal(dm.as_flattened_mut());
    rng.fill_normal(dc.as_flattened_mut());

    let macs = (OBS * H1 + H1 * H2 + H2 * (ACT + TRI)) as f64;
    let mut o = [0f32; OBS];
    rng.fill_normal(&mut o);
    let (mut m1, mut c1) = ([0f32; ACT], [0f32; TRI]);
    if single {
        let secs = time(20_000, || {
            actor.forward_one(black_box(&o), &mut m1, &mut c1);
            black_box(&m1);
        });
        rows.push(Row {
            name: format!("{label}: actor forward, 1 state"),
            secs,
            flops: 2.0 * macs,
        });
    }
    if !batch {
        return;
    }

    let secs = time(20, || {
        actor.forward(&obs, &mut tape, &mut mean, &mut chol);
        actor.backward(&obs, &mut tape, &dm, &dc, &mut t, &mut grad);
        black_box(&grad.l1.w[0][0]);
    });
    // forward 2 macs, weight gradients 2 macs, input gradients 2 macs except the first layer.
    let bwd_in = (H1 * H2 + H2 * (ACT + TRI)) as f64;
    let flops = B as f64 * 2.0 * (2.0 * macs + bwd_in);
    rows.push(Row {
        name: format!("{label}: actor forward+backward, batch {B}"),
        secs,
        flops,
    });
}

fn critic_rows<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize>(
    label: &str,
    rows: &mut Vec<Row>,
) {
    let mut rng = Rng::seed_from_u64(2);
    let mut critic: Box<Critic<OBS, ACT, H1, H2>> = bytemuck::zeroed_box();
    critic.init(&mut rng);
    let mut grad: Box<Critic<OBS, ACT, H1, H2>> = bytemuck::zeroed_box();
    let mut tape: Box<CriticTape<B, H1, H2>> = bytemuck::zeroed_box();
    let mut t: Box<CriticTransposed<H1, H2>> = bytemuck::zeroed_box();
    let mut obs: Box<[[f32; OBS]; B]> = bytemuck::zeroed_box();
    let mut act: Box<[[f32; ACT]; B]> = bytemuck::zeroed_box();
    rng.fill_normal(obs.as_flattened_mut());
    rng.fill_normal(act.as_flattened_mut());
    let mut q = [[0f32; 1]; B];
    let mut dq = [[0f32; 1]; B];
    rng.fill_normal(dq.as_flattened_mut());
    let macs = ((OBS + ACT) * H1 + H1 * H2 + H2) as f64;
    let secs = time(20, || {
        critic.forward(&obs, &act, &mut tape, &mut q, false);
        critic.backward(&obs, &act, &mut tape, &dq, &mut t, &mut grad, false);
        black_box(&grad.l2.w[0][0]);
    });
    let flops = B as f64 * 2.0 * (2.0 * macs + (H1 * H2 + H2) as f64);
    rows.push(Row {
        name: format!("{label}: critic forward+backward, batch {B}"),
        secs,
        flops,
    });
}

/// The learner's hottest path: the target critic on one chunk of 64 rows given the state
/// part (action block, ReLU, second layer, ReLU, output), as for every E-step and
/// next-action sample.
fn critic_eval_rows<const OBS: usize, const ACT: usize, const H1: usize, const H2: usize>(
    label: &str,
    rows: &mut Vec<Row>,
) {
    const R: usize = 64;
    let mut rng = Rng::seed_from_u64(4);
    let mut critic: Box<Critic<OBS, ACT, H1, H2>> = bytemuck::zeroed_box();
    critic.init(&mut rng);
    let mut tape: Box<CriticTape<R, H1, H2>> = bytemuck::zeroed_box();
    let mut obs: Box<[[f32; OBS]; R]> = bytemuck::zeroed_box();
    let mut act: Box<[[f32; ACT]; R]> = bytemuck::zeroed_box();
    let mut pre1: Box<[[f32; H1]; R]> = bytemuck::zeroed_box();
    rng.fill_normal(obs.as_flattened_mut());
    rng.fill_normal(act.as_flattened_mut());
    critic.state_part(&*obs, &mut *pre1);
    let mut q = [[0f32; 1]; R];
    let secs = time(200, || {
        critic.forward_from_state_part(&pre1, &act, &mut tape, &mut q, false);
        black_box(&q);
    });
    rows.push(Row {
        name: format!("{label}: critic evaluation from the state part, {R} rows"),
        secs,
        flops: R as f64 * 2.0 * (ACT * H1 + H1 * H2 + H2) as f64,
    });
}

/// The three kernels of one 256 x 256 layer on a batch of 256, separately.
fn layer_rows(rows: &mut Vec<Row>) {
    use mpo_core::linear::{Linear, weight_grad};
    const N: usize = 256;
    let mut rng = Rng::seed_from_u64(3);
    let mut l: Box<Linear<N, N>> = bytemuck::zeroed_box();
    l.init_uniform(&mut rng);
    let mut g: Box<Linear<N, N>> = bytemuck::zeroed_box();
    let mut x: Box<[[f32; N]; B]> = bytemuck::zeroed_box();
    let mut y: Box<[[f32; N]; B]> = bytemuck::zeroed_box();
    let mut dx: Box<[[f32; N]; B]> = bytemuck::zeroed_box();
    rng.fill_normal(x.as_flattened_mut());
    let flops = 2.0 * (B * N * N) as f64;
    let secs = time(50, || {
        l.forward(&*x, &mut *y);
        black_box(&y[0][0]);
    });
    rows.push(Row {
        name: format!("layer 256x256, batch {B}: forward"),
        secs,
        flops,
    });
    let secs = time(50, || {
        weight_grad(&*x, &*y, &mut g.w);
        black_box(&g.w[0][0]);
    });
    rows.push(Row {
        name: format!("layer 256x256, batch {B}: weight gradient"),
        secs,
        flops,
    });
    // The learner's shape: one chunk of 64 rows with the ReLU fused in.
    let secs = time(200, || {
        l.forward_relu(&x[..64], &mut y[..64]);
        black_box(&y[0][0]);
    });
    rows.push(Row {
        name: "layer 256x256, 64 rows: forward with ReLU".into(),
        secs,
        flops: flops / 4.0,
    });
    let mut wt: Box<[[f32; N]; N]> = bytemuck::zeroed_box();
    let secs = time(50, || {
        l.backward(&*x, &*y, &mut g);
        l.input_grad(&*y, &mut *dx, &mut wt);
        black_box(&dx[0][0]);
    });
    rows.push(Row {
        name: format!("layer 256x256, batch {B}: full backward (transposed input gradient)"),
        secs,
        flops: 2.0 * flops,
    });
}

fn cpuinfo(key: &str) -> Option<String> {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()?
        .lines()
        .find(|l| l.starts_with(key))
        .and_then(|l| l.split(':').nth(1))
        .map(|v| v.trim().to_string())
}

/// The clock /proc/cpuinfo reports (a VM's nominal clock).
fn cpu_mhz() -> f64 {
    cpuinfo("cpu MHz")
        .and_then(|v| v.parse().ok())
        .unwrap_or(f64::NAN)
}

/// Model name, family and model (the name alone says only "AMD EPYC" on these VMs; family
/// 25 model 1 is Zen 3, model 17 Zen 4).
fn cpu_name() -> String {
    format!(
        "{} (family {}, model {})",
        cpuinfo("model name").unwrap_or_default(),
        cpuinfo("cpu family").unwrap_or_default(),
        cpuinfo("model\t").unwrap_or_default()
    )
}

/// The 1-minute load average (other work on the machine skews every figure).
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().next().unwrap_or("?").to_string())
        .unwrap_or_else(|_| "?".into())
}

/// The categorical value head of 101 atoms on a batch of 256 rows: the softmax and expectation
/// (`values`), the cross-entropy's gradient (`loss`) and the 128 -> 101 output layer's backward
/// on that gradient, at two shapes of logits. "near": every logit within 13 of the largest
/// (values inside the support). "far": logits falling 1.5 per atom away from atom 85, so the
/// atoms below about 27 lie more than 87 under the largest, as when a critic's values climb
/// toward the support's top and Adam keeps pushing the far atoms' logits down; without a floor
/// their probabilities and gradients are subnormal numbers, which x86 cores handle in microcode.
fn value_rows(rows: &mut Vec<Row>) {
    use mpo_core::linear::Linear;
    use mpo_core::value_head::{Support, loss, values};
    const K: usize = 101;
    const H: usize = 128;
    let mut support = Support {
        min: 0.0,
        max: 100.0,
        sigma: 0.0,
        floor: 0.0,
    };
    let mut rng = Rng::seed_from_u64(5);
    let mut l: Box<Linear<H, K>> = bytemuck::zeroed_box();
    l.init_uniform(&mut rng);
    let mut g: Box<Linear<H, K>> = bytemuck::zeroed_box();
    let mut wt: Box<[[f32; H]; K]> = bytemuck::zeroed_box();
    let mut x: Box<[[f32; H]; B]> = bytemuck::zeroed_box();
    let mut dx: Box<[[f32; H]; B]> = bytemuck::zeroed_box();
    rng.fill_normal(x.as_flattened_mut());
    let mut out: Box<[[f32; K]; B]> = bytemuck::zeroed_box();
    let mut probs: Box<[[f32; K]; B]> = bytemuck::zeroed_box();
    let mut d_out: Box<[[f32; K]; B]> = bytemuck::zeroed_box();
    let (mut q, mut y, mut ce) = ([0f32; B], [0f32; B], [0f32; B]);
    // "far" with the floor off (every atom kept) and on (`MpoConfig::logit_floor`'s 40).
    for (name, slope, floor) in [
        ("near logits", 0.13f32, 40.0),
        ("far logits, floor off", 1.5, 0.0),
        ("far logits, floor 40", 1.5, 40.0),
    ] {
        support.floor = floor;
        for (n, row) in out.iter_mut().enumerate() {
            let peak = 80.0 + (n % 10) as f32;
            for (k, o) in row.iter_mut().enumerate() {
                *o = -slope * (k as f32 - peak).abs() + 0.01 * (n % 7) as f32;
            }
            y[n] = peak - 0.5;
        }
        let secs = time(200, || {
            values(&support, &*out, &mut *probs, &mut q);
            loss(
                &support,
                &*out,
                &*probs,
                &q,
                &y,
                1.0 / B as f32,
                &mut *d_out,
                &mut ce,
            );
            black_box(&d_out[0][0]);
        });
        rows.push(Row {
            name: format!("value head {K} atoms, batch {B}, {name}: values + loss"),
            secs,
            flops: (B * K * 8) as f64,
        });
        let secs = time(200, || {
            l.backward(&*x, &*d_out, &mut g);
            l.input_grad(&*d_out, &mut *dx, &mut wt);
            black_box(&dx[0][0]);
        });
        rows.push(Row {
            name: format!("output layer {H}x{K}, batch {B}, {name}: backward of the gradient"),
            secs,
            flops: 4.0 * (B * H * K) as f64,
        });
    }
}

/// The residual critic's LayerNorm (width 128, as every built-in `simba` critic) on 256 rows,
/// forward and backward, beside the block's first linear layer (128 -> 256) on the same rows:
/// what normalising a row costs against what the block then does with it.
fn norm_rows(rows: &mut Vec<Row>) {
    use mpo_core::layer_norm::LayerNorm;
    use mpo_core::linear::Linear;
    const W: usize = 128;
    const F: usize = 256;
    let mut rng = Rng::seed_from_u64(7);
    let mut ln: Box<LayerNorm<W>> = bytemuck::zeroed_box();
    ln.init();
    rng.fill_normal(&mut ln.g);
    let mut l: Box<Linear<W, F>> = bytemuck::zeroed_box();
    l.init_uniform(&mut rng);
    let mut x: Box<[[f32; W]; B]> = bytemuck::zeroed_box();
    let mut xhat: Box<[[f32; W]; B]> = bytemuck::zeroed_box();
    let mut y: Box<[[f32; W]; B]> = bytemuck::zeroed_box();
    let mut dx: Box<[[f32; W]; B]> = bytemuck::zeroed_box();
    let mut h: Box<[[f32; F]; B]> = bytemuck::zeroed_box();
    let mut rstd = [0f32; B];
    rng.fill_normal(x.as_flattened_mut());
    let secs = time(400, || {
        ln.forward_rows(&*x, &mut *xhat, &mut rstd, &mut *y);
        black_box(&y[0][0]);
    });
    rows.push(Row {
        name: format!("layer norm {W}, batch {B}: forward"),
        secs,
        flops: (B * W * 7) as f64,
    });
    let secs = time(400, || {
        ln.backward_rows(&*xhat, &rstd, &*y, &mut *dx);
        black_box(&dx[0][0]);
    });
    rows.push(Row {
        name: format!("layer norm {W}, batch {B}: backward"),
        secs,
        flops: (B * W * 8) as f64,
    });
    let secs = time(100, || {
        l.forward_relu(&*y, &mut *h);
        black_box(&h[0][0]);
    });
    rows.push(Row {
        name: format!("layer {W}x{F}, batch {B}: forward with ReLU (beside it)"),
        secs,
        flops: 2.0 * (B * W * F) as f64,
    });
}

fn main() {
    // `cargo bench --bench kernels -- NAME` runs only the groups whose name contains NAME
    // (layer, single, actor, critic, value, norm); `cargo bench` itself passes `--bench`, which is ignored.
    let filter = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .unwrap_or_default();
    let on = |g: &str| filter.is_empty() || g.contains(filter.as_str());
    let peak = measure_peak();
    let mut rows = Vec::new();
    let wide = mpo_core::linear::wide::detected();
    if on("layer") {
        if wide {
            // Both paths in one run: the 8-wide kernels first, then the default 512-bit one.
            mpo_core::linear::wide::set_enabled(false);
            let from = rows.len();
            layer_rows(&mut rows);
            for r in &mut rows[from..] {
                r.name.push_str(" (8-wide, AVX-512 off)");
            }
            mpo_core::linear::wide::set_enabled(true);
        }
        layer_rows(&mut rows);
    }
    let (single, batch) = (on("single"), on("actor"));
    if single || batch {
        actor_rows::<15, 4, 10, 256, 256>("hopper 15/4, 256-256", &mut rows, single, batch);
        actor_rows::<15, 4, 10, 64, 64>("mcu 15/4, 64-64", &mut rows, single, batch);
    }
    if on("critic") {
        critic_eval_rows::<24, 6, 256, 256>("walker 24/6, 256-256", &mut rows);
        critic_rows::<15, 4, 256, 256>("hopper 15/4, 256-256", &mut rows);
        critic_rows::<15, 4, 64, 64>("mcu 15/4, 64-64", &mut rows);
    }
    if on("value") {
        value_rows(&mut rows);
    }
    if on("norm") {
        norm_rows(&mut rows);
    }

    println!("measured single-core peak (8-wide fused multiply-add): {peak:.1} GFLOP/s");
    if let Some(p512) = measure_peak_512() {
        println!(
            "measured 16-wide (AVX-512) peak on this CPU: {p512:.1} GFLOP/s ({:.2}x the 8-wide peak)",
            p512 / peak
        );
    }
    println!(
        "nominal single-core peak (2 x 256-bit FMA per cycle at ~3.65 GHz): {NOMINAL_PEAK} GFLOP/s"
    );
    let mhz = cpu_mhz();
    println!(
        "this instance: {} at {mhz:.0} MHz as reported by /proc/cpuinfo, so 32 FLOP/cycle x clock = {:.1} GFLOP/s",
        cpu_name(),
        32.0 * mhz / 1e3
    );
    println!(
        "batch forward and weight-gradient kernels: {}",
        if mpo_core::linear::wide::enabled() {
            "512-bit (AVX-512F detected)"
        } else {
            "8-wide (no AVX-512)"
        }
    );
    println!("load average (1 min) at the end: {}\n", load_average());
    let clock_peak = 32.0 * mhz / 1e3;
    println!(
        "| kernel | time (median) | GFLOP/s | % of 117 GFLOP/s | % of 32 FLOP/cycle at the reported clock | % of measured peak |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    for r in &rows {
        let gf = r.flops / r.secs / 1e9;
        let t = if r.secs < 1e-3 {
            format!("{:.2} us", r.secs * 1e6)
        } else {
            format!("{:.3} ms", r.secs * 1e3)
        };
        println!(
            "| {} | {} | {:.1} | {:.0}% | {:.0}% | {:.0}% |",
            r.name,
            t,
            gf,
            100.0 * gf / NOMINAL_PEAK,
            100.0 * gf / clock_peak,
            100.0 * gf / peak
        );
    }
}
