//! Test support shared by the cross-crate tests in `tests/` and the benchmarks in `benches/`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

/// Allocations on every thread (for code that runs on worker threads).
static ALL_THREADS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    // const-initialised and without Drop, so touching it never allocates or registers a
    // destructor (which would itself count).
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

/// A global allocator that counts heap allocations per thread (parallel tests do not disturb
/// each other's counts) and over all threads. Install it in a test binary with
/// `#[global_allocator] static A: CountingAlloc = CountingAlloc;`.
pub struct CountingAlloc;

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        ALL_THREADS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        ALL_THREADS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        ALL_THREADS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Runs `f` and returns its result with the number of heap allocations it made on this
/// thread (meaningful only in a binary whose global allocator is [`CountingAlloc`]).
pub fn count_allocations<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCATIONS.with(Cell::get);
    let r = f();
    (r, ALLOCATIONS.with(Cell::get) - before)
}

/// Runs `f` and returns its result with the number of heap allocations made on every thread
/// meanwhile (for work spread over a thread pool; meaningful only in a test binary where
/// nothing else runs at the same time).
pub fn count_allocations_all_threads<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALL_THREADS.load(Ordering::SeqCst);
    let r = f();
    (r, ALL_THREADS.load(Ordering::SeqCst) - before)
}

/// The workspace root (for tests that build or run other parts of the repository).
pub fn workspace_root() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `cargo build --release` of a freestanding crate under `freestanding/` for the baseline
/// x86-64 CPU (`RUSTFLAGS` replaces the workspace's config flags: no target-cpu, no rpath),
/// with extra `features` and environment, into `target_dir`.
pub fn build_freestanding(
    krate: &str,
    features: &str,
    env: &[(&str, &std::ffi::OsStr)],
    target_dir: &std::path::Path,
) -> std::process::Output {
    let mut cmd =
        std::process::Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cmd.current_dir(workspace_root().join("freestanding").join(krate))
        .args([
            "build",
            "--release",
            "--target",
            "x86_64-unknown-linux-gnu",
            "--target-dir",
        ])
        .arg(target_dir)
        .env("RUSTFLAGS", "-C target-cpu=x86-64")
        .env_remove("CARGO_ENCODED_RUSTFLAGS");
    for (k, v) in env {
        cmd.env(k, v);
    }
    if !features.is_empty() {
        cmd.args(["--features", features]);
    }
    cmd.output().expect("failed to spawn cargo")
}

/// Asserts that a build with each `(feature, expected error text)` fails, for that reason:
/// the negative controls that show a "does not link with std/alloc" check has teeth.
pub fn assert_builds_fail(cases: &[(&str, &str)], build: impl Fn(&str) -> std::process::Output) {
    for (feature, expect) in cases {
        let out = build(feature);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success(),
            "build with {feature} succeeded; the check has no teeth"
        );
        assert!(
            err.contains(expect),
            "build with {feature} failed for another reason:\n{err}"
        );
    }
}

/// Building and running the inference-only firmware (`freestanding/firmware`).
pub mod firmware {
    use std::path::{Path, PathBuf};
    use std::process::Output;

    use mpo_core::actor::Actor;

    /// Writes `actor` as the firmware's policy source (`mpo_core::export`) to `path`.
    pub fn export<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const H1: usize,
        const H2: usize,
    >(
        actor: &Actor<OBS, ACT, TRI, H1, H2>,
        origin: &str,
        path: &Path,
    ) {
        let mut src = String::new();
        mpo_core::export::write_actor_source(actor, origin, &mut src).unwrap();
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, src).unwrap();
    }

    /// Builds the firmware with the policy source `policy` and extra `features`.
    pub fn build(policy: &Path, features: &str, target_dir: &Path) -> Output {
        super::build_freestanding(
            "firmware",
            features,
            &[("MPO_FIRMWARE_WEIGHTS", policy.as_os_str())],
            target_dir,
        )
    }

    /// Exports `actor` and builds the firmware under `target/firmware/NAME/`; returns the
    /// binary's path (panics with cargo's output if the build fails).
    pub fn export_and_build<
        const OBS: usize,
        const ACT: usize,
        const TRI: usize,
        const H1: usize,
        const H2: usize,
    >(
        actor: &Actor<OBS, ACT, TRI, H1, H2>,
        name: &str,
    ) -> PathBuf {
        let dir = super::workspace_root().join("target/firmware").join(name);
        let src = dir.join("policy.rs");
        export(actor, name, &src);
        let out = build(&src, "", &dir.join("build"));
        assert!(
            out.status.success(),
            "firmware build failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        dir.join("build/x86_64-unknown-linux-gnu/release/mpo-firmware")
    }
}
