//! A step through an external plant allocates nothing of ours on the learner's side: the
//! request is written into a loaned sample, the reply copied into a buffer sized at connect.
//! A counting allocator over this thread's allocations (the threads that relay the plant
//! program's output are not the step path), Gymnasium's Pendulum-v1 in its Python process.
//!
//! What remains is iceoryx2's: in 0.10 every published sample allocates one 48-byte `Rc`
//! (`Publisher::loan_slice_uninit` -> `ChunkMutSharedState::new`), so a step (one request
//! sent) counts exactly one. The test asserts exactly that count: one more allocation of ours
//! per step, or a change in iceoryx2, makes it fail.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use mpo_link::external::{Expected, ExternalOptions, ExternalPlant, PlantCommand};

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);
thread_local! {
    static COUNTED: Cell<bool> = const { Cell::new(false) };
}

fn count() {
    if COUNTED.try_with(|c| c.get()).unwrap_or(false) {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
    }
}

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn a_step_allocates_only_iceoryx2s_sample_state() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = Command::new(root.join("scripts/setup-python-plant"))
        .output()
        .expect("run scripts/setup-python-plant");
    assert!(
        out.status.success(),
        "scripts/setup-python-plant failed; run it by hand (it needs PyPI): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let python = String::from_utf8(out.stdout).unwrap().trim().to_string();
    let cmd = PlantCommand {
        argv: vec![
            python,
            "-m".into(),
            "mpo_plant".into(),
            "--gym".into(),
            "Pendulum-v1".into(),
        ],
        dir: root,
    };
    let expected = Expected {
        task: "pendulum-v1".into(),
        obs: 3,
        act: 1,
        episode_steps: 200,
        bounds: vec![(-2.0, 2.0)],
    };
    let opts = ExternalOptions {
        connect_timeout: Duration::from_secs(60),
        timeout: Duration::from_secs(10),
    };
    let mut p = ExternalPlant::start(&cmd, expected, opts, "test").expect("connect");
    let env = p.new_env();
    let mut obs = [0f64; 3];
    p.reset(env, 3, true, &mut obs).unwrap();
    // Warm up (first sends may set up connections), then count 150 steps within one episode.
    for _ in 0..20 {
        p.step(env, &[0.3], &mut obs).unwrap();
    }
    COUNTED.with(|c| c.set(true));
    let before = ALLOCS.load(Ordering::SeqCst);
    let steps = 150;
    for k in 0..steps {
        let s = p.step(env, &[(k as f64 * 0.05).sin()], &mut obs).unwrap();
        assert!(!s.last);
    }
    let allocs = ALLOCS.load(Ordering::SeqCst) - before;
    COUNTED.with(|c| c.set(false));
    assert_eq!(
        allocs, steps,
        "{allocs} allocations in {steps} steps: one per step is iceoryx2's, more are ours"
    );
}
