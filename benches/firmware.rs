//! Firmware size report: flash (.text + .rodata), RAM (.data + .bss + peak stack) and
//! instructions per inference of the inference-only firmware, for 64-64 policies of cartpole
//! and hopper size (the microcontroller profile) and, for contrast, hopper at 256-256; then the
//! same for the device trainer (`freestanding/trainer`), with instructions per environment
//! step and per learner update.
//!
//! Run: `cargo bench --bench firmware`. Needs binutils' `size` and valgrind (callgrind counts
//! instructions reproducibly; massif measures the peak stack). Targets for the 64-64 profile:
//! flash < 64 KiB, RAM < 16 KiB.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_integration::firmware::export_and_build;

#[path = "common/trainer_frames.rs"]
mod trainer_frames;
use trainer_frames::trainer_input;

/// Section sizes from `size -A`.
fn sections(bin: &Path) -> std::collections::HashMap<String, u64> {
    let out = Command::new("size")
        .arg("-A")
        .arg(bin)
        .output()
        .expect("binutils `size` not found");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            let (name, size) = (it.next()?, it.next()?.parse().ok()?);
            name.starts_with('.').then(|| (name.to_string(), size))
        })
        .collect()
}

fn run_valgrind(args: &[&str], bin: &Path, input: &[u8]) -> String {
    let mut child = Command::new("valgrind")
        .args(args)
        .arg(bin)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("valgrind not found");
    child.stdin.take().unwrap().write_all(input).unwrap();
    let out = child.wait_with_output().unwrap();
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Instructions executed for `input`, counted by callgrind.
fn instructions(bin: &Path, input: &[u8]) -> u64 {
    let f = std::env::temp_dir().join(format!("mpo-cg-{}", std::process::id()));
    let err = run_valgrind(
        &[
            "--tool=callgrind",
            &format!("--callgrind-out-file={}", f.display()),
        ],
        bin,
        input,
    );
    let _ = std::fs::remove_file(&f);
    err.lines()
        .find_map(|l| {
            l.split("Collected :")
                .nth(1)
                .map(|v| v.trim().parse().unwrap())
        })
        .expect("no callgrind total")
}

/// Peak stack bytes, measured by massif.
fn peak_stack(bin: &Path, input: &[u8]) -> u64 {
    let f = std::env::temp_dir().join(format!("mpo-ms-{}", std::process::id()));
    run_valgrind(
        &[
            "--tool=massif",
            "--stacks=yes",
            "--heap=no",
            &format!("--massif-out-file={}", f.display()),
        ],
        bin,
        input,
    );
    let text = std::fs::read_to_string(&f).expect("no massif output");
    let _ = std::fs::remove_file(&f);
    text.lines()
        .filter_map(|l| l.strip_prefix("mem_stacks_B="))
        .map(|v| v.parse().unwrap())
        .max()
        .unwrap()
}

fn report<
    const OBS: usize,
    const ACT: usize,
    const TRI: usize,
    const H1: usize,
    const H2: usize,
>(
    name: &str,
) {
    let mut actor: Box<Actor<OBS, ACT, TRI, H1, H2>> = bytemuck::zeroed_box();
    actor.init(&mut Rng::seed_from_u64(1), 0.5, 1e-4);
    let bin = export_and_build(&*actor, name);
    let s = sections(&bin);
    let get = |k: &str| s.get(k).copied().unwrap_or(0);
    let flash = get(".text") + get(".rodata");
    let mut rng = Rng::seed_from_u64(2);
    const RECORDS: u64 = 1000;
    let input: Vec<u8> = (0..RECORDS as usize * OBS)
        .flat_map(|_| rng.normal().to_le_bytes())
        .collect();
    let per = (instructions(&bin, &input) - instructions(&bin, &[])) / RECORDS;
    let stack = peak_stack(&bin, &input);
    let ram = get(".data") + get(".bss") + stack;
    println!(
        "| {name} | {} | {} | {} | {:.1} | {} | {} | {stack} | {:.2} | {per} |",
        actor_params(&*actor),
        get(".text"),
        get(".rodata"),
        flash as f64 / 1024.0,
        get(".data"),
        get(".bss"),
        ram as f64 / 1024.0,
    );
}

fn actor_params<P: mpo_core::params::Params>(p: &P) -> usize {
    p.len()
}

fn main() {
    println!(
        "| policy | parameters | .text B | .rodata B | flash KiB | .data B | .bss B | peak stack B | RAM KiB | instructions/inference |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    report::<5, 1, 1, 64, 64>("cartpole-64-64");
    report::<15, 4, 10, 64, 64>("hopper-64-64");
    report::<15, 4, 10, 256, 256>("hopper-256-256");
    trainer_report();
}

/// The device trainer (`freestanding/trainer`, the `mcu` row): flash, RAM, and instructions
/// per environment step and per update, built twice: for the baseline x86-64 CPU (no FMA
/// instruction, so every multiply-add is a call to `libm::fmaf`: what the bit-identity tests
/// run) and for x86-64-v3 (a hardware fused multiply-add, like a Cortex-M4F's VFMA.F32).
fn trainer_report() {
    println!(
        "\n| device trainer (mcu row), build | .text B | .rodata B | flash KiB | .data B | .bss B | peak stack B | RAM KiB | instructions/env step | instructions/update |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let mut per_update_v3 = 0;
    for (cpu, sub) in [("x86-64", "freestanding"), ("x86-64-v3", "freestanding-v3")] {
        let dir = mpo_integration::workspace_root().join("target").join(sub);
        let flags = std::ffi::OsString::from(format!("-C target-cpu={cpu}"));
        let out =
            mpo_integration::build_freestanding("trainer", "", &[("RUSTFLAGS", &flags)], &dir);
        assert!(
            out.status.success(),
            "trainer build failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let bin = dir.join("x86_64-unknown-linux-gnu/release/mpo-trainer");
        let s = sections(&bin);
        let get = |k: &str| s.get(k).copied().unwrap_or(0);
        // 200 steps without updates; then 200 more with an update every step.
        let (steps, updates) = (200u64, 200u64);
        let quiet = trainer_input(1_000_000, 1, steps, true);
        let busy = trainer_input(steps, 1, steps + updates, true);
        let base = instructions(&bin, &trainer_input(1_000_000, 1, 1, true));
        let i_quiet = instructions(&bin, &quiet);
        let i_busy = instructions(&bin, &busy);
        let per_step = (i_quiet - base) / (steps - 1);
        let per_update = (i_busy - i_quiet - updates * per_step) / updates;
        per_update_v3 = per_update;
        let stack = peak_stack(&bin, &busy);
        let flash = get(".text") + get(".rodata");
        let ram = get(".data") + get(".bss") + stack;
        let z = mpo_host::table::row("cartpole-balance", "mcu")
            .unwrap()
            .sizes;
        println!(
            "| cartpole-balance, actor {}-{}, critic {}-{}, batch {}, M = {}, N = {}, replay {}; {cpu} | {} | {} | {:.1} | {} | {} | {stack} | {:.1} | {per_step} | {per_update} |",
            z.actor[0],
            z.actor[1],
            z.critic[0],
            z.critic[1],
            z.batch,
            z.m,
            z.n,
            z.replay_capacity,
            get(".text"),
            get(".rodata"),
            flash as f64 / 1024.0,
            get(".data"),
            get(".bss"),
            ram as f64 / 1024.0,
        );
    }
    let macs = mcu_macs_per_update();
    println!(
        "\nnetwork multiply-adds per update: {macs} (forward, weight and input gradients; \
         see Learner::flops_per_update); {:.1} instructions per multiply-add on the x86-64-v3 \
         build (8-wide where the kernels vectorise)",
        per_update_v3 as f64 / macs as f64
    );
    println!(
        "for a Cortex-M4F, measured (instructions under QEMU, cycles from their mix): \
         cargo bench --bench cortex_m"
    );
}

/// Multiply-adds of one update of the mcu learner (half its network FLOPs).
fn mcu_macs_per_update() -> u64 {
    let row = mpo_host::table::row("cartpole-balance", "mcu").unwrap();
    let cfg = mpo_host::commands::defaults(row).mpo.to_config();
    let mut l: Box<mpo_core::learner::Learner<5, 1, 1, 32, 32, 32, 32, 32, 1, 1, 8, 8>> =
        bytemuck::zeroed_box();
    l.init(cfg, 0).unwrap();
    l.flops_per_update() / 2
}
