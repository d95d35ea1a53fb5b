//! The core really is `no_std` and allocator-free, and bit-deterministic across builds.
//!
//! Builds `freestanding/core-check` (a `#![no_std] #![no_main]` static binary with its own
//! `_start`, no libc, no allocator) in release mode for the baseline x86-64 CPU, runs it, and
//! compares its fingerprints with the same computation done here (std, dev profile, the
//! workspace's x86-64-v3 target, where `mul_add` is the FMA instruction; the freestanding
//! build's baseline CPU computes it with `libm::fmaf`): same seed, same bits, for the kernels
//! and for whole learner updates. Then proves the harness has teeth:
//! the same binary with a feature that uses `alloc`, or one that links `std`, fails to build.

#![allow(clippy::needless_range_loop)]

use std::path::PathBuf;
use std::process::Command;

use mpo_core::selfcheck::{SelfCheck, forward_checksum};

fn target_dir() -> PathBuf {
    mpo_integration::workspace_root().join("target/freestanding")
}

fn build(features: &str) -> std::process::Output {
    mpo_integration::build_freestanding("core-check", features, &[], &target_dir())
}

fn parse_hex(line: &str) -> u64 {
    u64::from_str_radix(line.split_whitespace().last().unwrap(), 16).unwrap()
}

#[test]
fn freestanding_binary_links_runs_and_matches_host_bits() {
    let out = build("");
    assert!(
        out.status.success(),
        "freestanding build failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let bin = target_dir().join("x86_64-unknown-linux-gnu/release/core-check");
    let run = Command::new(&bin)
        .output()
        .expect("failed to run core-check");
    assert!(
        run.status.success(),
        "core-check exited with {:?}",
        run.status
    );
    let stdout = String::from_utf8(run.stdout).unwrap();
    let mut lines = stdout.lines();
    let self_line = lines.next().expect("no selfcheck line");
    let learner_line = lines.next().expect("no learner line");
    let fwd_line = lines.next().expect("no forward line");
    assert!(self_line.starts_with("selfcheck 42 200 "), "{self_line}");
    assert!(learner_line.starts_with("learner 42 6 "), "{learner_line}");
    assert!(fwd_line.starts_with("forward 42 "), "{fwd_line}");

    let mut check: Box<SelfCheck> = bytemuck::zeroed_box();
    let host = check.run(42, 200);
    assert_eq!(
        parse_hex(self_line),
        host,
        "training fingerprint differs between builds"
    );
    // Whole learner updates: E-step (temperature solve, weights), M-step, TD and Retrace
    // targets, action penalization, shared samples, Polyak targets.
    assert_eq!(
        parse_hex(learner_line),
        check.learner(42, 6),
        "learner fingerprint differs between builds"
    );
    assert_eq!(
        parse_hex(fwd_line),
        forward_checksum(42),
        "forward fingerprint differs"
    );

    // The binary is static and has no interpreter: no libc was linked.
    let file = std::fs::read(&bin).unwrap();
    assert!(
        !file.windows(b"ld-linux".len()).any(|w| w == b"ld-linux"),
        "dynamic loader referenced"
    );
}

#[test]
fn freestanding_build_fails_when_alloc_or_std_enter() {
    mpo_integration::assert_builds_fail(
        &[
            ("use-alloc", "no global memory allocator"),
            ("use-std", "duplicate lang item"),
        ],
        build,
    );
}

#[test]
fn selfcheck_is_reproducible_within_a_build_and_sensitive_to_the_seed() {
    let mut a: Box<SelfCheck> = bytemuck::zeroed_box();
    let mut b: Box<SelfCheck> = bytemuck::zeroed_box();
    assert_eq!(a.run(7, 50), b.run(7, 50));
    assert_ne!(a.run(7, 50), b.run(8, 50));
    assert_eq!(a.learner(7, 3), b.learner(7, 3));
    assert_ne!(a.learner(7, 3), b.learner(8, 3));
}
