//! Round-trip latency observation -> action, including inference at hopper size (15/4,
//! 256-256), for iceoryx2 event mode (without and with the plant spinning 60 us before it
//! sleeps), iceoryx2 busy-poll and a Unix-domain-socket baseline with
//! the same payload, in one run; then a paced 1 kHz run in event mode counting deadline misses
//! and wake-up jitter. Prints Markdown.
//!
//! ```text
//! cargo bench -p mpo-link --bench latency -- [--round-trips N] [--paced-seconds S]
//! ```
//!
//! Every server is a separate process (the `mpo-controller` binary, or this binary re-executed
//! with `--uds-server PATH`) running the same policy.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_link::messages::{ActMsg, ObsMsg};
use mpo_link::service::monotonic_ns;
use mpo_link::{Plant, PlantConfig, RunId, WaitMode};

type Policy = Actor<15, 4, 10, 256, 256>;
const PROFILE: &str = "hopper-256";
const SEED: u64 = 0;
/// The plant's spin before sleeping in the event-mode row that has one (`PlantConfig::spin`).
const SPIN: Duration = Duration::from_micros(60);

fn policy() -> Box<Policy> {
    let mut p: Box<Policy> = bytemuck::zeroed_box();
    p.init(&mut Rng::seed_from_u64(SEED), 1.0, 1e-4);
    p
}

fn observations() -> Vec<[f32; 15]> {
    let mut rng = Rng::seed_from_u64(1);
    (0..1024)
        .map(|_| core::array::from_fn(|_| rng.uniform_range(-2.0, 2.0)))
        .collect()
}

/// The baseline server: blocking reads of whole `ObsMsg`s, inference, blocking writes of whole
/// `ActMsg`s.
fn uds_server(path: &str) {
    let listener = UnixListener::bind(path).expect("bind");
    println!("ready");
    std::io::stdout().flush().unwrap();
    let (mut s, _) = listener.accept().expect("accept");
    let p = policy();
    let mut req: ObsMsg = bytemuck::Zeroable::zeroed();
    let mut rep: ActMsg = bytemuck::Zeroable::zeroed();
    while s.read_exact(bytemuck::bytes_of_mut(&mut req)).is_ok() {
        rep.t_recv_ns = monotonic_ns();
        rep.seq = req.seq;
        rep.len = 4;
        let obs: &[f32; 15] = req.obs[..15].try_into().unwrap();
        let a: &mut [f32; 4] = (&mut rep.action[..4]).try_into().unwrap();
        p.mean_action(obs, a);
        rep.t_send_ns = monotonic_ns();
        if s.write_all(bytemuck::bytes_of(&rep)).is_err() {
            break;
        }
    }
}

/// A server process and its stdout (kept open so its exit message has a reader).
struct Server(Child, #[allow(dead_code)] std::process::ChildStdout);

impl Server {
    fn wait_ready(mut child: Child) -> Self {
        let mut out = child.stdout.take().unwrap();
        let mut buf = [0u8; 6];
        out.read_exact(&mut buf).unwrap();
        assert_eq!(&buf, b"ready\n");
        Self(child, out)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        // SIGTERM first so the controller removes its resources; SIGKILL if it does not go.
        unsafe { libc::kill(self.0.id() as i32, libc::SIGTERM) };
        for _ in 0..200 {
            if self.0.try_wait().ok().flatten().is_some() {
                return;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

struct Row {
    name: String,
    lat: Vec<u64>,
    server: Vec<u64>,
    misses: u64,
}

fn pct(sorted: &[u64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i] as f64 / 1000.0
}

fn iceoryx(wait: WaitMode, spin: Duration, n: usize, obs: &[[f32; 15]]) -> Row {
    let run = RunId::new();
    let ctl = Command::new(env!("CARGO_BIN_EXE_mpo-controller"))
        .args([
            "--run",
            run.as_str(),
            "--profile",
            PROFILE,
            "--wait",
            wait.name(),
        ])
        .args(["--seed", &SEED.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn mpo-controller");
    let _ctl = Server::wait_ready(ctl);
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: 15,
            act_len: 4,
            wait,
            deadline: Duration::from_millis(100),
            spin,
        },
    )
    .unwrap();
    let mut out = [0f32; 4];
    for o in obs.iter().cycle().take(2000) {
        let _ = plant.act(o, &mut out);
    }
    let (mut lat, mut server) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut misses = 0;
    for o in obs.iter().cycle().take(n) {
        match plant.act(o, &mut out) {
            Ok(a) => {
                lat.push(a.t[3] - a.t[0]);
                server.push(a.t[2] - a.t[1]);
            }
            Err(_) => misses += 1,
        }
    }
    Row {
        name: if spin.is_zero() {
            format!("iceoryx2 {}", wait.name())
        } else {
            format!(
                "iceoryx2 {}, plant spins {} us first",
                wait.name(),
                spin.as_micros()
            )
        },
        lat,
        server,
        misses,
    }
}

fn uds(n: usize, obs: &[[f32; 15]]) -> Row {
    let path = format!("/tmp/mpo-latency-{}.sock", RunId::new().as_str());
    let child = Command::new(std::env::current_exe().unwrap())
        .args(["--uds-server", &path])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let _srv = Server::wait_ready(child);
    let mut s = UnixStream::connect(&path).unwrap();
    let _ = std::fs::remove_file(&path);
    let mut req: ObsMsg = bytemuck::Zeroable::zeroed();
    let mut rep: ActMsg = bytemuck::Zeroable::zeroed();
    req.len = 15;
    let (mut lat, mut server) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for (i, o) in obs.iter().cycle().take(n + 2000).enumerate() {
        req.seq = i as u64 + 1;
        req.obs[..15].copy_from_slice(o);
        req.t_send_ns = monotonic_ns();
        s.write_all(bytemuck::bytes_of(&req)).unwrap();
        s.read_exact(bytemuck::bytes_of_mut(&mut rep)).unwrap();
        let t = monotonic_ns();
        assert_eq!(rep.seq, req.seq);
        if i >= 2000 {
            lat.push(t - req.t_send_ns);
            server.push(rep.t_send_ns - rep.t_recv_ns);
        }
    }
    Row {
        name: "Unix socket (blocking)".into(),
        lat,
        server,
        misses: 0,
    }
}

/// Paced at 1 kHz: each period's request must be answered before the next period starts.
/// With `rt`, both sides run under `SCHED_FIFO` at that priority.
fn paced(seconds: u64, obs: &[[f32; 15]], rt: Option<i32>) {
    let run = RunId::new();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mpo-controller"));
    cmd.args([
        "--run",
        run.as_str(),
        "--profile",
        PROFILE,
        "--wait",
        "event",
    ]);
    if let Some(p) = rt {
        if let Err(e) = mpo_link::realtime::enter(p) {
            println!("\n(SCHED_FIFO not available here: {e}; real-time run skipped)");
            return;
        }
        cmd.args(["--realtime", &p.to_string()]);
    }
    mpo_link::realtime::tight_timer_slack();
    let ctl = cmd.stdout(Stdio::piped()).spawn().unwrap();
    let _ctl = Server::wait_ready(ctl);
    let period = 1_000_000u64;
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: 15,
            act_len: 4,
            wait: WaitMode::Event,
            deadline: Duration::from_nanos(period),
            spin: Duration::ZERO,
        },
    )
    .unwrap();
    let mut out = [0f32; 4];
    for o in obs.iter().take(500) {
        let _ = plant.act(o, &mut out);
    }
    let n = (seconds * 1000) as usize;
    let (mut late, mut lat) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut misses = 0u64;
    let start = monotonic_ns() + period;
    for (k, o) in obs.iter().cycle().take(n).enumerate() {
        let due = start + k as u64 * period;
        mpo_link::realtime::sleep_until(due);
        let woke = monotonic_ns();
        late.push(woke.saturating_sub(due));
        // The reply must arrive before the next period begins.
        let left = (due + period).saturating_sub(woke);
        match plant.request_action(o, None, 0.0, Duration::from_nanos(left)) {
            Ok(a) => lat.push(a.t[3] - a.t[0]),
            Err(_) => misses += 1,
        }
    }
    late.sort_unstable();
    lat.sort_unstable();
    let s = plant.stats();
    println!(
        "\n### Paced at 1 kHz, iceoryx2 event mode, {}, {seconds} s ({n} periods)\n\n\
         | deadline misses | wake-up lateness p50 / p99 / p99.9 / max (us) | round trip p50 / p99 / p99.9 / max (us) | stale replies dropped |\n\
         |---:|---|---|---:|\n\
         | {misses} ({:.3}%) | {:.1} / {:.1} / {:.1} / {:.1} | {:.1} / {:.1} / {:.1} / {:.1} | {} |",
        match rt {
            Some(p) => format!("SCHED_FIFO priority {p} on both sides"),
            None => "default scheduler".to_string(),
        },
        100.0 * misses as f64 / n as f64,
        pct(&late, 0.5),
        pct(&late, 0.99),
        pct(&late, 0.999),
        pct(&late, 1.0),
        pct(&lat, 0.5),
        pct(&lat, 0.99),
        pct(&lat, 0.999),
        pct(&lat, 1.0),
        s.rejections.sequence,
    );
}

fn main() {
    let mut args = std::env::args().skip(1);
    let (mut n, mut seconds) = (100_000usize, 60u64);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--uds-server" => return uds_server(&args.next().expect("path")),
            "--round-trips" => n = args.next().and_then(|v| v.parse().ok()).expect("N"),
            "--paced-seconds" => seconds = args.next().and_then(|v| v.parse().ok()).expect("S"),
            _ => {} // `cargo bench` passes `--bench`.
        }
    }
    let obs = observations();
    // Inference alone, in this process, for reference.
    let p = policy();
    let mut a = [0f32; 4];
    let mut inf: Vec<u64> = (0..20_000)
        .map(|i| {
            let t = monotonic_ns();
            p.mean_action(std::hint::black_box(&obs[i % obs.len()]), &mut a);
            std::hint::black_box(&a);
            monotonic_ns() - t
        })
        .collect();
    inf.sort_unstable();
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("## Round trip observation -> action, hopper 15/4, 256-256 ({n} round trips each)\n");
    println!("load average at start: {}", load.trim());
    println!(
        "inference alone (in process, 20k calls): p50 {:.2} us, p99 {:.2} us\n",
        pct(&inf, 0.5),
        pct(&inf, 0.99)
    );
    println!(
        "| transport | p50 (us) | p99 (us) | p99.9 (us) | max (us) | server-side p50 (us) | misses |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for row in [
        iceoryx(WaitMode::Event, Duration::ZERO, n, &obs),
        iceoryx(WaitMode::Event, SPIN, n, &obs),
        iceoryx(WaitMode::BusyPoll, Duration::ZERO, n, &obs),
        uds(n, &obs),
    ] {
        let (mut l, mut s) = (row.lat, row.server);
        l.sort_unstable();
        s.sort_unstable();
        println!(
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
            row.name,
            pct(&l, 0.5),
            pct(&l, 0.99),
            pct(&l, 0.999),
            pct(&l, 1.0),
            pct(&s, 0.5),
            row.misses
        );
    }
    if seconds > 0 {
        paced(seconds, &obs, None);
        // Last: it switches this process to SCHED_FIFO.
        paced(seconds, &obs, Some(50));
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!("\nload average at end: {}", load.trim());
}
