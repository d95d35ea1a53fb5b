//! Cortex-M4F figures, measured under QEMU: the firmware and the device trainer built for
//! thumbv7em-none-eabihf and run on the `mps2-an386` board.
//!
//! - Flash and RAM from the ELFs' sections (`arm-none-eabi-size -A`): flash = vector table +
//!   `.text` + `.rodata` + `.data`'s image; RAM = `.data` + `.bss` + peak stack.
//! - Peak stack: the reset handler paints the free stack; after the run the painted region is
//!   read back through QEMU's QMP socket (`pmemsave`) and the lowest overwritten word found.
//! - Executed instructions per inference, per environment step and per learner update:
//!   the project's QEMU plugin (`scripts/qemu-count`) counts every instruction and reports the
//!   count at the binaries' marks (`mpo_rt::mark_begin` / `mark_end` around the policy, `act`
//!   and `observe`).
//! - Cycles on an STM32F4 at 168 MHz: the executed instructions, by mnemonic (the plugin's
//!   per-address histogram of the measured spans, mapped through `arm-none-eabi-objdump`),
//!   times the Cortex-M4 cycle counts each takes (a low and a high figure: see [`cycles`]).
//!
//! The trainer is measured a second time on a Cortex-M7 (`mps2-an500`, code generated for its
//! double-precision FPU), to show what the f64 arithmetic costs the M4F. Then the issue's
//! targets, met or missed by how much. Run: `cargo bench --bench cortex_m`
//! (after `scripts/setup-cortex-m`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_frames::DELIMITER;
use mpo_integration::cortex_m::{self, Board, MPS2_AN386, MPS2_AN500, Qmp};
use mpo_integration::firmware::export_and_build_cortex_m;

#[path = "common/trainer_frames.rs"]
mod trainer_frames;
use trainer_frames::trainer_input;

const HZ: f64 = 168e6;
/// The targets (issue 34).
const FIRMWARE_FLASH: u64 = 32 * 1024;
const FIRMWARE_RAM: u64 = 4 * 1024;
const INFERENCE_INSTRUCTIONS: u64 = 15_000;
const TRAINER_RAM: u64 = 256 * 1024;
const UPDATE_INSTRUCTIONS: u64 = 2_500_000;

fn scratch() -> PathBuf {
    let d = mpo_integration::workspace_root().join("target/cortex-m/bench");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// What one QEMU session measured.
struct Measured {
    spans: Vec<u64>,
    histogram: Vec<(u64, u64)>,
    stack: u64,
}

/// Runs `elf` with the counter (and its histogram) and QMP, sends `input`, waits for `done`,
/// reads the stack's paint and stops QEMU cleanly.
fn measure(
    board: &Board,
    elf: &Path,
    name: &str,
    input: Vec<u8>,
    done: impl Fn(&[u8]) -> bool + Send + 'static,
) -> Measured {
    let log = scratch().join(format!("{name}.log"));
    let socket = scratch().join(format!("{name}.qmp"));
    let _ = std::fs::remove_file(&log);
    let _ = std::fs::remove_file(&socket);
    let cmd = cortex_m::command_with(board, elf, Some(&log), true, Some(&socket));
    let mut stack = 0;
    cortex_m::session(&cmd, input, done, Duration::from_secs(1800), || {
        let mut q = Qmp::connect(&socket);
        stack = cortex_m::peak_stack(&mut q, elf);
        q.quit();
        true
    });
    Measured {
        spans: cortex_m::spans(&log),
        histogram: cortex_m::histogram(&log),
        stack,
    }
}

/// The Cortex-M4's cycles for one execution of an instruction, low and high (Arm's Cortex-M4
/// Technical Reference Manual, instruction timings of the processor and of the FPU): a load
/// or store 2 (1 when it pipelines with the one before), a load or store multiple 1 + N, a
/// fused multiply-add 3, a division or square root 14 (FP) or 2-12 (integer), a branch 1 (not
/// taken) to 4 (taken: 1 + a pipeline refill of 1-3), everything else 1. Flash wait states are
/// left out here (see `estimate`).
fn cycles(mnemonic: &str, operands: &str) -> (f64, f64) {
    let base = mnemonic.split('.').next().unwrap_or(mnemonic);
    let regs = register_count(operands) as f64;
    let conditions = [
        "eq", "ne", "cs", "hs", "cc", "lo", "mi", "pl", "vs", "vc", "hi", "ls", "ge", "lt", "gt",
        "le",
    ];
    let is_branch = matches!(base, "b" | "bl" | "bx" | "blx" | "cbz" | "cbnz")
        || (base.len() == 3 && base.starts_with('b') && conditions.contains(&&base[1..]));
    match base {
        "vfma" | "vfms" | "vfnma" | "vfnms" | "vmla" | "vmls" | "vnmla" | "vnmls" => (3.0, 3.0),
        "vdiv" | "vsqrt" => (14.0, 14.0),
        "vldr" | "vstr" | "ldr" | "ldrb" | "ldrh" | "ldrsb" | "ldrsh" | "str" | "strb" | "strh"
        | "ldrex" | "strex" => (1.0, 2.0),
        "ldrd" | "strd" => (2.0, 3.0),
        "vldmia" | "vldmdb" | "vstmia" | "vstmdb" | "vpush" | "vpop" | "ldm" | "ldmia"
        | "ldmdb" | "stm" | "stmia" | "stmdb" | "push" => (1.0 + regs, 1.0 + regs),
        "pop" if operands.contains("pc") => (1.0 + regs + 1.0, 1.0 + regs + 3.0),
        "pop" => (1.0 + regs, 1.0 + regs),
        "sdiv" | "udiv" => (2.0, 12.0),
        "tbb" | "tbh" => (2.0, 4.0),
        _ if is_branch => (1.0, 4.0),
        _ => (1.0, 1.0),
    }
}

/// Registers in a list operand (`{r4, r5, lr}`, `{s16-s31}`, `{d8-d9}`: words moved).
fn register_count(operands: &str) -> usize {
    let Some(list) = operands
        .split_once('{')
        .and_then(|(_, r)| r.split_once('}'))
        .map(|(l, _)| l)
    else {
        return 1;
    };
    list.split(',')
        .map(|r| {
            let r = r.trim();
            let words = if r.starts_with('d') { 2 } else { 1 };
            match r.split_once('-') {
                Some((a, b)) => {
                    let n = |x: &str| x.trim()[1..].parse::<usize>().unwrap_or(0);
                    (n(b) - n(a) + 1) * words
                }
                None => words,
            }
        })
        .sum()
}

/// Address -> (mnemonic, operands) of every instruction in `elf`.
fn disassembly(elf: &Path) -> HashMap<u64, (String, String)> {
    let out = std::process::Command::new("arm-none-eabi-objdump")
        .args(["-d", "--no-show-raw-insn"])
        .arg(elf)
        .output()
        .expect("arm-none-eabi-objdump");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let (at, rest) = l.trim_start().split_once(":\t")?;
            let at = u64::from_str_radix(at, 16).ok()?;
            let mut it = rest.splitn(2, '\t');
            let m = it.next()?.trim().to_string();
            Some((at, (m, it.next().unwrap_or("").trim().to_string())))
        })
        .collect()
}

/// Cycles (low, high) of the measured spans, and the share of instructions by class.
struct Mix {
    instructions: u64,
    low: f64,
    high: f64,
    classes: Vec<(&'static str, u64)>,
}

fn mix(elf: &Path, histogram: &[(u64, u64)]) -> Mix {
    let dis = disassembly(elf);
    let (mut low, mut high, mut instructions) = (0.0, 0.0, 0);
    let mut classes: HashMap<&'static str, u64> = HashMap::new();
    for &(at, n) in histogram {
        let (m, ops) = dis
            .get(&at)
            .unwrap_or_else(|| panic!("no instruction at {at:#x} in {}", elf.display()));
        let (lo, hi) = cycles(m, ops);
        low += lo * n as f64;
        high += hi * n as f64;
        instructions += n;
        let class = if m.starts_with("vfma") {
            "fused multiply-add"
        } else if m.starts_with("vldr") || m.starts_with("vstr") {
            "FP load/store"
        } else if m.starts_with('v') {
            "other FP"
        } else if m.starts_with("ldr") || m.starts_with("str") {
            "load/store"
        } else if lo == 1.0 && hi == 4.0 {
            "branch"
        } else {
            "other"
        };
        *classes.entry(class).or_default() += n;
    }
    let mut classes: Vec<_> = classes.into_iter().collect();
    classes.sort_by_key(|&(_, n)| std::cmp::Reverse(n));
    Mix {
        instructions,
        low,
        high,
        classes,
    }
}

fn median(v: &mut [u64]) -> u64 {
    v.sort_unstable();
    v[v.len() / 2]
}

fn kib(b: u64) -> String {
    format!("{:.1}", b as f64 / 1024.0)
}

/// Flash and RAM (bytes) of an ELF with the measured peak stack.
fn footprint(elf: &Path, stack: u64) -> (u64, u64, String) {
    let s = cortex_m::sections(elf);
    let get = |k: &str| s.get(k).copied().unwrap_or(0);
    let flash = get(".vector_table") + get(".text") + get(".rodata") + get(".data");
    let ram = get(".data") + get(".bss") + stack;
    let detail = format!(
        ".text {} B, .rodata {} B, .data {} B, .bss {} B, peak stack {stack} B",
        get(".text"),
        get(".rodata"),
        get(".data"),
        get(".bss")
    );
    (flash, ram, detail)
}

fn verdict(got: u64, target: u64) -> String {
    if got <= target {
        format!(
            "met ({:.0}% of the target)",
            100.0 * got as f64 / target as f64
        )
    } else {
        format!("MISSED by {:.2}x", got as f64 / target as f64)
    }
}

/// The firmware for a 64-64 policy: 1000 inferences. Returns the median instructions per
/// inference, flash and RAM.
fn firmware<const OBS: usize, const ACT: usize, const TRI: usize>(name: &str) -> (u64, u64, u64) {
    let mut actor: Box<Actor<OBS, ACT, TRI, 64, 64>> = bytemuck::zeroed_box();
    let mut rng = Rng::seed_from_u64(1);
    actor.init(&mut rng, 0.5, 1e-4);
    actor.mean.init_uniform(&mut rng);
    let elf = export_and_build_cortex_m(&*actor, &format!("bench-{name}"));
    const RECORDS: usize = 1000;
    let mut rng = Rng::seed_from_u64(2);
    let input: Vec<u8> = (0..RECORDS * OBS)
        .flat_map(|_| rng.normal().to_le_bytes())
        .collect();
    let m = measure(&MPS2_AN386, &elf, name, input, |got| {
        got.len() >= RECORDS * ACT * 4
    });
    assert_eq!(m.spans.len(), RECORDS, "one span per inference");
    let mut spans = m.spans.clone();
    let (lo, med, hi) = (
        *spans.iter().min().unwrap(),
        median(&mut spans),
        *spans.iter().max().unwrap(),
    );
    let (flash, ram, detail) = footprint(&elf, m.stack);
    let mx = mix(&elf, &m.histogram);
    let per = |c: f64| c / RECORDS as f64;
    // Weights are read from flash once per inference: with the flash accelerator's prefetch
    // missing every 16-byte line, 5 wait states each (the high figure).
    let weights = 4.0 * mpo_core::params::Params::len(&*actor) as f64;
    let (c_lo, c_hi) = (per(mx.low), per(mx.high) + weights / 16.0 * 5.0);
    println!(
        "### firmware, {name} policy ({} parameters)",
        mpo_core::params::Params::len(&*actor)
    );
    println!(
        "- flash {} KiB, RAM {} KiB ({detail})",
        kib(flash),
        kib(ram)
    );
    println!(
        "- instructions per inference: median {med}, min {lo}, max {hi} ({RECORDS} inferences)"
    );
    println!(
        "- cycles per inference on a Cortex-M4F: {:.0}-{:.0} ({:.2}-{:.2} per instruction), \
         {:.0}-{:.0} us at 168 MHz",
        c_lo,
        c_hi,
        c_lo / per(mx.instructions as f64),
        c_hi / per(mx.instructions as f64),
        c_lo / HZ * 1e6,
        c_hi / HZ * 1e6
    );
    print_classes(&mx);
    (med, flash, ram)
}

fn print_classes(mx: &Mix) {
    let parts: Vec<String> = mx
        .classes
        .iter()
        .map(|(c, n)| format!("{c} {:.1}%", 100.0 * *n as f64 / mx.instructions as f64))
        .collect();
    println!("- instruction mix: {}", parts.join(", "));
}

/// The device trainer on `board` (built into `target/DIR`): `WARMUP` steps without updates,
/// then `UPDATES` steps with one update each. Returns the median instructions per update and
/// the RAM.
fn trainer(board: &Board, dir: &str, title: &str, cycle_model: bool) -> (u64, u64) {
    const WARMUP: u64 = 300;
    const UPDATES: u64 = 40;
    let target = mpo_integration::workspace_root().join("target").join(dir);
    let out = cortex_m::build_for(board, "trainer", "", &[], &target);
    assert!(
        out.status.success(),
        "trainer build failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let elf = cortex_m::elf(&target, "mpo-trainer");
    let replies = 3 + WARMUP + UPDATES; // INFO, ACK, the first ACTION, one ACTION per step
    let m = measure(
        board,
        &elf,
        &format!("trainer-{}", board.machine),
        trainer_input(WARMUP, 1, WARMUP + UPDATES, false),
        move |got| got.iter().filter(|&&b| b == DELIMITER).count() as u64 >= replies,
    );
    // Spans alternate: act (BEGIN and every STEP), observe (every STEP).
    let acts: Vec<u64> = m.spans.iter().step_by(2).copied().collect();
    let observes: Vec<u64> = m.spans.iter().skip(1).step_by(2).copied().collect();
    assert_eq!(
        observes.len() as u64,
        WARMUP + UPDATES,
        "one observe span per step"
    );
    let mut quiet = observes[..WARMUP as usize - 1].to_vec();
    let mut busy = observes[WARMUP as usize..].to_vec();
    let mut act_after = acts[WARMUP as usize + 1..].to_vec();
    let store = median(&mut quiet);
    let (b_lo, b_hi) = (*busy.iter().min().unwrap(), *busy.iter().max().unwrap());
    let update = median(&mut busy) - store;
    let act = median(&mut act_after);
    let (flash, ram, detail) = footprint(&elf, m.stack);
    let mx = mix(&elf, &m.histogram);
    // The histogram covers every span; the updates dominate it (their instructions are
    // >99% of the spans'), so its cycles per instruction are the update's.
    let (cpi_lo, cpi_hi) = (
        mx.low / mx.instructions as f64,
        mx.high / mx.instructions as f64,
    );
    let (c_lo, c_hi) = (update as f64 * cpi_lo, update as f64 * cpi_hi);
    println!("### device trainer (`mcu` row), {title}");
    println!(
        "- flash {} KiB, RAM {} KiB ({detail})",
        kib(flash),
        kib(ram)
    );
    println!(
        "- instructions per learner update: median {update} (storing a transition without an \
         update: {store}; {UPDATES} updates on random observations: {} to {} with the store)",
        b_lo, b_hi
    );
    println!("- instructions per action after the warm-up (`act`: forward pass and a draw): {act}");
    if cycle_model {
        println!(
            "- cycles per update on a Cortex-M4F: {:.2e}-{:.2e} ({cpi_lo:.2}-{cpi_hi:.2} per \
             instruction), {:.0}-{:.0} ms at 168 MHz: {:.1}-{:.1} updates/s",
            c_lo,
            c_hi,
            c_lo / HZ * 1e3,
            c_hi / HZ * 1e3,
            HZ / c_hi,
            HZ / c_lo
        );
    }
    print_classes(&mx);
    let ranges = soft_double(&elf);
    let soft: u64 = m
        .histogram
        .iter()
        .filter(|&&(at, _)| ranges.iter().any(|&(a, b)| at >= a && at < b))
        .map(|&(_, n)| n)
        .sum();
    println!(
        "- in double-precision software routines (compiler_builtins' __adddf3 and the like, and \
         libm's f64 exp/log): {:.1}% of the instructions",
        100.0 * soft as f64 / mx.instructions as f64
    );
    (update, ram)
}

/// The address ranges of `elf`'s functions that do f64 arithmetic in software.
fn soft_double(elf: &Path) -> Vec<(u64, u64)> {
    {
        let out = std::process::Command::new("arm-none-eabi-nm")
            .args(["-S", "--defined-only"])
            .arg(elf)
            .output()
            .expect("arm-none-eabi-nm");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| {
                let f: Vec<&str> = l.split_whitespace().collect();
                let name = *f.get(3)?;
                let soft = [
                    "df3",
                    "aeabi_d",
                    "aeabi_f2d",
                    "aeabi_d2f",
                    "4libm4math3exp3exp",
                    "4libm4math3log3log",
                ]
                .iter()
                .any(|p| name.contains(p));
                let at = u64::from_str_radix(f[0], 16).ok()? & !1;
                let len = u64::from_str_radix(f[1], 16).ok()?;
                soft.then_some((at, at + len))
            })
            .collect()
    }
}

fn main() {
    cortex_m::require();
    println!("## Cortex-M4F (thumbv7em-none-eabihf on QEMU mps2-an386)\n");
    let (inference, fw_flash, fw_ram) = firmware::<5, 1, 1>("cartpole-64-64");
    println!();
    firmware::<15, 4, 10>("hopper-64-64");
    println!();
    let (update, trainer_ram) = trainer(
        &MPS2_AN386,
        "cortex-m",
        "Cortex-M4F (mps2-an386; single-precision FPU: f64 in software)",
        true,
    );
    println!();
    let (update_m7, _) = trainer(
        &MPS2_AN500,
        "cortex-m7",
        "Cortex-M7 (mps2-an500, code for cortex-m7: f64 in hardware; no cycle model here)",
        false,
    );
    println!("\n### targets");
    println!(
        "- cartpole 64-64 inference <= {INFERENCE_INSTRUCTIONS} instructions: {inference}, {}",
        verdict(inference, INFERENCE_INSTRUCTIONS)
    );
    println!(
        "- firmware flash <= 32 KiB: {} KiB, {}",
        kib(fw_flash),
        verdict(fw_flash, FIRMWARE_FLASH)
    );
    println!(
        "- firmware RAM <= 4 KiB: {} KiB, {}",
        kib(fw_ram),
        verdict(fw_ram, FIRMWARE_RAM)
    );
    println!(
        "- trainer RAM <= 256 KiB: {} KiB, {}",
        kib(trainer_ram),
        verdict(trainer_ram, TRAINER_RAM)
    );
    println!(
        "- one update <= {UPDATE_INSTRUCTIONS} instructions: {update} on the Cortex-M4F, {} \
         ({update_m7} on a Cortex-M7 with a double-precision FPU, {})",
        verdict(update, UPDATE_INSTRUCTIONS),
        verdict(update_m7, UPDATE_INSTRUCTIONS)
    );
}
