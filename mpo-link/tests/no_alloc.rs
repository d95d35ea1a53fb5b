//! Once both sides are open, a request and its answer allocate nothing of ours on either side:
//! the controller's loop (event waits, validation, inference, reply) and the plant's `act` /
//! `act_sampled`. A process-wide counting allocator, the controller in a thread of this test
//! process, hopper 256-256.
//!
//! What remains is iceoryx2's: in 0.10 every published sample allocates one 48-byte `Rc`
//! (`Publisher::loan_uninit` -> `ChunkMutSharedState::new`), so a round trip (one send each
//! way) counts exactly two. The test asserts exactly that count: one more allocation of ours per
//! message, or a change in iceoryx2, makes it fail. (With the controller waiting in a `WaitSet`,
//! as it did before, it counted four: the WaitSet allocates on every wait.)

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use mpo_core::actor::Actor;
use mpo_core::rng::Rng;
use mpo_link::controller::{ControllerOptions, request_stop, serve};
use mpo_link::{Plant, PlantConfig, RunId, WaitMode};

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        ALLOCS.fetch_add(1, Ordering::SeqCst);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

const OBS: usize = 15;
const ACT: usize = 4;
type Policy = Actor<OBS, ACT, 10, 256, 256>;

#[test]
fn requests_and_answers_allocate_nothing_on_either_side() {
    let run = RunId::new();
    let opts = ControllerOptions {
        run: run.clone(),
        wait: WaitMode::Event,
        seed: 3,
        init_std: 1.0,
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let controller = std::thread::spawn(move || {
        serve::<OBS, ACT, 10, 256, 256>(&opts, || tx.send(()).unwrap()).expect("controller")
    });
    rx.recv_timeout(Duration::from_secs(10))
        .expect("controller ready");
    let mut plant = Plant::open(
        &run,
        PlantConfig {
            obs_len: OBS,
            act_len: ACT,
            wait: WaitMode::Event,
            deadline: Duration::from_secs(2),
            spin: Duration::ZERO,
        },
    )
    .expect("plant");
    let mut policy: Box<Policy> = bytemuck::zeroed_box();
    policy.init(&mut Rng::seed_from_u64(9), 1.0, 1e-4);
    plant.push_params(&*policy).expect("push");

    let mut rng = Rng::seed_from_u64(1);
    let mut obs = [0f32; OBS];
    let mut z = [0f32; ACT];
    let mut a = [0f32; ACT];
    let mut step = |plant: &mut Plant| {
        for o in obs.iter_mut() {
            *o = rng.uniform_range(-1.0, 1.0);
        }
        rng.fill_normal(&mut z);
        plant.act(&obs, &mut a).expect("mean action");
        plant
            .act_sampled(&obs, &z, 1e-4, &mut a)
            .expect("sampled action");
    };
    // Warm-up: connections, the parameter swap, first-use buffers.
    for _ in 0..50 {
        step(&mut plant);
    }
    let before = ALLOCS.load(Ordering::SeqCst);
    for _ in 0..500 {
        step(&mut plant);
    }
    let during = ALLOCS.load(Ordering::SeqCst) - before;
    let stats = plant.stats();

    request_stop();
    let served = controller.join().expect("controller thread");
    drop(plant);
    run.remove_if_last();

    assert_eq!(stats.misses, 0, "{stats:?}");
    assert_eq!(stats.replies, 1100);
    assert_eq!(served.answered, 1100);
    assert_eq!(served.swaps, 1, "the pushed policy was used");
    // 1,000 round trips: 1,000 sends by the plant, 1,000 by the controller.
    assert_eq!(
        during, 2000,
        "allocations during 1,000 round trips: iceoryx2's one per send expected, nothing else"
    );
}
