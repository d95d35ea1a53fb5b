//! The cost of one step through an external plant: the learner's request, Gymnasium's
//! Pendulum-v1 `step` in the Python plant server (`python/mpo_plant`, its own process) and the
//! reply, timed one by one over many episodes; and, for comparison, the Python server's
//! share (the same steps with the plant answering without Gymnasium: the fixture toy plant).
//! Prints Markdown.
//!
//! ```text
//! scripts/setup-python-plant && cargo bench -p mpo-link --bench external_plant -- [--steps N]
//! ```

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use mpo_link::external::{Expected, ExternalOptions, ExternalPlant, PlantCommand};
use mpo_link::service::monotonic_ns;

fn python(root: &Path) -> String {
    let out = Command::new(root.join("scripts/setup-python-plant"))
        .output()
        .expect("run scripts/setup-python-plant");
    assert!(out.status.success(), "scripts/setup-python-plant failed");
    String::from_utf8(out.stdout).unwrap().trim().to_string()
}

/// Per-step round trips in microseconds, sorted.
fn time_steps(cmd: &PlantCommand, steps: usize) -> Vec<f64> {
    let expected = Expected {
        task: "bench".into(),
        obs: 3,
        act: 1,
        episode_steps: 200,
        bounds: vec![(-2.0, 2.0)],
    };
    let opts = ExternalOptions {
        connect_timeout: Duration::from_secs(60),
        timeout: Duration::from_secs(10),
    };
    let mut p = ExternalPlant::start(cmd, expected, opts, "bench").expect("connect");
    let env = p.new_env();
    let mut obs = [0f64; 3];
    p.reset(env, 0, true, &mut obs).unwrap();
    let mut t = Vec::with_capacity(steps);
    for k in 0..steps {
        let action = [2.0 * (k as f64 * 0.01).sin()];
        let t0 = monotonic_ns();
        let s = p.step(env, &action, &mut obs).unwrap();
        t.push((monotonic_ns() - t0) as f64 / 1e3);
        if s.last {
            p.reset(env, 0, false, &mut obs).unwrap();
        }
    }
    t.sort_by(f64::total_cmp);
    t
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let steps = args
        .iter()
        .position(|a| a == "--steps")
        .and_then(|i| args.get(i + 1))
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000usize);
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let py = python(&root);
    let gym = PlantCommand {
        argv: vec![
            py.clone(),
            "-m".into(),
            "mpo_plant".into(),
            "--gym".into(),
            "Pendulum-v1".into(),
        ],
        dir: root.clone(),
    };
    let toy = PlantCommand {
        argv: vec![py, "faulty_plant.py".into()],
        dir: root.join("mpo-link/tests/fixtures"),
    };
    println!("| plant ({steps} steps) | p50 us | p90 us | p99 us | mean us |");
    println!("|---|---:|---:|---:|---:|");
    for (name, cmd) in [
        ("Gymnasium Pendulum-v1", &gym),
        ("toy plant (numpy only)", &toy),
    ] {
        let t = time_steps(cmd, steps);
        let q = |f: f64| t[((t.len() - 1) as f64 * f) as usize];
        let mean = t.iter().sum::<f64>() / t.len() as f64;
        println!(
            "| {name} | {:.1} | {:.1} | {:.1} | {mean:.1} |",
            q(0.5),
            q(0.9),
            q(0.99)
        );
    }
}
