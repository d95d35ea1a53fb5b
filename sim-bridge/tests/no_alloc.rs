//! After construction and the first reset, stepping and resetting allocate nothing (the trainer
//! calls them millions of times). A counting global allocator proves it for every built-in task and
//! the Gymnasium task files (tasks/gymnasium/).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

// SAFETY: forwards to the system allocator; the counter is a per-thread Cell without Drop.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn stepping_and_resetting_do_not_allocate() {
    let gymnasium = ["InvertedDoublePendulum-v5", "HalfCheetah-v5"].map(|n| {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("../tasks/gymnasium/{n}.toml"));
        sim_bridge::TaskDef::from_file(&path).unwrap()
    });
    let envs = sim_bridge::TASKS
        .iter()
        .map(|task| (task.to_string(), sim_bridge::make(task, 5).unwrap()))
        .chain(gymnasium.iter().map(|d| {
            let env: Box<dyn sim_bridge::Environment> = Box::new(d.make(5).unwrap());
            (d.name().to_string(), env)
        }));
    for (task, mut env) in envs {
        let spec = env.spec().clone();
        let mut obs = vec![0.0; spec.obs_dim];
        let action = vec![0.3; spec.act_dim];
        env.reset(&mut obs);
        let before = allocations();
        for episode in 0..2 {
            if episode > 0 {
                env.reset(&mut obs);
            }
            // Until the episode's end: the time limit, or a termination (the Gymnasium
            // pendulum falls).
            loop {
                let step = env.step(&action, &mut obs);
                assert!(step.reward.is_finite());
                if step.last {
                    break;
                }
            }
        }
        assert_eq!(
            allocations() - before,
            0,
            "{task}: allocations while stepping"
        );
    }
}
