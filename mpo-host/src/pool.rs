//! A fixed pool of worker threads that runs the learner's independent work items
//! ([`mpo_core::parallel::Parallel`]) with no allocation per call.
//!
//! `for_each` publishes the job (a borrowed closure and the item list) under a new generation
//! number, wakes the workers, works on items itself, and returns once every item is done.
//! Items are claimed one at a time by a compare-and-swap on one word holding the generation
//! and the next item index, so a worker that wakes late can never claim an item of a later
//! job, and the job it dereferences is alive until all of its items have finished. Which
//! thread runs which item varies from run to run; the learner's results do not (the items
//! share nothing mutable and every reduction happens after the call, in a fixed order).
//!
//! Workers spin for a short while after each job (the learner issues several jobs per update
//! in quick succession) and then sleep on a condition variable. A panic in an item is caught
//! on the worker and re-raised on the calling thread after the job. Dropping the pool stops
//! and joins the workers.
//!
//! A job costs no system call and no lock while the workers spin: the job's pointer travels
//! in two atomic words published before the claim word, and the caller signals the condition
//! variable only when a worker has said it is going to sleep (a count both sides read and
//! write with sequentially consistent order, so either the caller sees the sleeper or the
//! sleeper sees the new job). An update issues dozens of jobs (every Newton iteration of the
//! E-step's two temperature solves is one), so a lock per item and a `futex` wake per job
//! were a measurable share of a two-thread update (docs/core.md, "Where the time goes").

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mpo_core::parallel::Parallel;

/// How long an idle worker spins before it sleeps.
const SPIN: Duration = Duration::from_micros(200);

/// Most items of one job: the count and the next index share the claim word's low 32 bits.
const MAX_ITEMS: usize = 0xffff;

/// Worker stack size: the learner's per-item work keeps small arrays on the stack.
const STACK: usize = 8 << 20;

/// The type-erased job: calls item `k`.
type Job<'a> = dyn Fn(usize) + Sync + 'a;

struct Shared {
    /// `generation << 32 | item count << 16 | next item index`.
    claim: AtomicU64,
    /// Items of the current job not yet finished.
    pending: AtomicUsize,
    /// The current job's pointer (a `*const Job` as its two words), valid for a thread that
    /// has claimed an item of the current generation (see the module doc).
    job: [AtomicUsize; 2],
    /// Workers that are about to sleep or sleeping on `wake`.
    sleepers: AtomicUsize,
    /// A worker's item panicked during the current job.
    panicked: AtomicBool,
    /// Sleepers wait here for a new generation or shutdown.
    wake: Condvar,
    sleep_lock: Mutex<()>,
    shutdown: AtomicBool,
    /// Workers that have started (`new` waits for all, so nothing of a thread's start-up
    /// happens later, during a job).
    started: AtomicUsize,
}

/// The two words of a `*const Job` (a pointer to an unsized closure: data and vtable).
type JobWords = [usize; 2];

/// A pool of `threads - 1` workers plus the calling thread.
pub struct Pool {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
    generation: u64,
}

impl Pool {
    /// A pool that runs items on `threads` threads in all (the caller and `threads - 1`
    /// workers); `threads` is at least 1.
    pub fn new(threads: usize) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            claim: AtomicU64::new(0),
            pending: AtomicUsize::new(0),
            job: [AtomicUsize::new(0), AtomicUsize::new(0)],
            sleepers: AtomicUsize::new(0),
            panicked: AtomicBool::new(false),
            wake: Condvar::new(),
            sleep_lock: Mutex::new(()),
            shutdown: AtomicBool::new(false),
            started: AtomicUsize::new(0),
        });
        let mut workers = Vec::new();
        for i in 1..threads.max(1) {
            let s = Arc::clone(&shared);
            workers.push(
                std::thread::Builder::new()
                    .name(format!("mpo-learner-{i}"))
                    .stack_size(STACK)
                    .spawn(move || worker(&s))?,
            );
        }
        while shared.started.load(Ordering::Acquire) < workers.len() {
            std::thread::yield_now();
        }
        Ok(Self {
            shared,
            workers,
            generation: 0,
        })
    }

    /// The number of available CPUs (at least 1).
    pub fn available() -> usize {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    }

    /// Calls `job(k)` for every `k < items`, on the workers and the calling thread; returns
    /// when all calls have returned, re-raising a panic of any of them.
    pub fn run(&mut self, items: usize, job: &Job<'_>) {
        if items == 0 {
            return;
        }
        assert!(items <= MAX_ITEMS, "at most {MAX_ITEMS} items per job");
        if self.workers.is_empty() || items == 1 {
            for k in 0..items {
                job(k);
            }
            return;
        }
        let s = &*self.shared;
        self.generation = (self.generation + 1) & 0xffff_ffff;
        let generation = self.generation;
        // SAFETY: the pointer is only dereferenced by a thread that has claimed an item of
        // this generation (see `claim`), and this function does not return before every
        // claimed item has finished (`pending` reaches 0), so the borrow outlives every use.
        // A fat pointer is two words (data, vtable), which is what `JobWords` holds.
        let words: JobWords = unsafe { std::mem::transmute(job as *const Job<'_>) };
        // Published before the claim word (release): a thread that claims an item of this
        // generation (acquire) reads these words.
        s.job[0].store(words[0], Ordering::Relaxed);
        s.job[1].store(words[1], Ordering::Relaxed);
        s.pending.store(items, Ordering::Relaxed);
        s.panicked.store(false, Ordering::Relaxed);
        // The item count travels in the claim word itself: a worker still claiming for the
        // previous job can then never compare its index against this job's count (it once
        // read a separately stored count, claimed a non-existent item of the old generation
        // and ran it on this job, and the job could return while that item still ran).
        s.claim.store(
            (generation << 32) | ((items as u64) << 16),
            Ordering::SeqCst,
        );
        // A worker going to sleep counts itself, then reads the claim word (both SeqCst);
        // this side wrote the claim word, then reads the count: one of the two sees the
        // other, so a sleeper is either woken here or never sleeps.
        if s.sleepers.load(Ordering::SeqCst) > 0 {
            let _g = s.sleep_lock.lock().expect("pool lock");
            s.wake.notify_all();
        }
        work(s, generation);
        while s.pending.load(Ordering::Acquire) != 0 {
            std::hint::spin_loop();
        }
        if s.panicked.load(Ordering::Relaxed) {
            panic!("a learner work item panicked on a pool thread");
        }
    }
}

/// Claims and runs items of `generation` until none are left.
fn work(s: &Shared, generation: u64) {
    while let Some(k) = claim(s, generation) {
        let words: JobWords = [
            s.job[0].load(Ordering::Relaxed),
            s.job[1].load(Ordering::Relaxed),
        ];
        // SAFETY: item `k` of this generation is claimed and not finished, so the caller of
        // `Pool::run` is still waiting, the job is alive and its words (published before the
        // claim word, which the claim read with acquire order) are this job's (module doc).
        let f: &Job<'_> = unsafe { &*std::mem::transmute::<JobWords, *const Job<'_>>(words) };
        if catch_unwind(AssertUnwindSafe(|| f(k))).is_err() {
            s.panicked.store(true, Ordering::Relaxed);
        }
        s.pending.fetch_sub(1, Ordering::AcqRel);
    }
}

/// The next unclaimed item of `generation`, if any.
fn claim(s: &Shared, generation: u64) -> Option<usize> {
    let mut cur = s.claim.load(Ordering::Acquire);
    loop {
        let (g, n, k) = (
            cur >> 32,
            ((cur >> 16) & 0xffff) as usize,
            (cur & 0xffff) as usize,
        );
        if g != generation || k >= n {
            return None;
        }
        match s
            .claim
            .compare_exchange_weak(cur, cur + 1, Ordering::AcqRel, Ordering::Acquire)
        {
            Ok(_) => return Some(k),
            Err(now) => cur = now,
        }
    }
}

fn worker(s: &Shared) {
    s.started.fetch_add(1, Ordering::Release);
    let mut seen = 0u64;
    loop {
        // Spin for new work, then sleep until notified.
        let start = Instant::now();
        let generation = loop {
            if s.shutdown.load(Ordering::Acquire) {
                return;
            }
            let g = s.claim.load(Ordering::Acquire) >> 32;
            if g != seen {
                break g;
            }
            if start.elapsed() < SPIN {
                std::hint::spin_loop();
                continue;
            }
            let guard = s.sleep_lock.lock().expect("pool lock");
            s.sleepers.fetch_add(1, Ordering::SeqCst);
            let g = s.claim.load(Ordering::SeqCst) >> 32;
            if g == seen && !s.shutdown.load(Ordering::Acquire) {
                drop(
                    s.wake
                        .wait_timeout(guard, Duration::from_millis(100))
                        .expect("pool lock"),
                );
            }
            s.sleepers.fetch_sub(1, Ordering::SeqCst);
        };
        seen = generation;
        work(s, generation);
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.shared.shutdown.store(true, Ordering::Release);
        {
            let _g = self.shared.sleep_lock.lock().expect("pool lock");
            self.shared.wake.notify_all();
        }
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

/// A [`Pool`] as the learner's [`Parallel`] (the pool needs `&mut` to run a job; the
/// learner holds `&`, so the pool sits behind a mutex that only the learner's thread takes).
pub struct PoolParallel {
    pool: Mutex<Pool>,
    threads: usize,
}

impl PoolParallel {
    /// A pool of `threads` threads in all.
    pub fn new(threads: usize) -> std::io::Result<Self> {
        Ok(Self {
            pool: Mutex::new(Pool::new(threads)?),
            threads: threads.max(1),
        })
    }
}

/// The base pointer of an item list, shareable with the workers.
struct Items<T>(*mut T);

// SAFETY: each item is handed to exactly one call (item indices are claimed once), and `T:
// Send`, so moving access to an item to another thread is sound.
unsafe impl<T: Send> Sync for Items<T> {}

impl Parallel for PoolParallel {
    fn for_each<T: Send>(&self, items: &mut [T], f: &(dyn Fn(usize, &mut T) + Sync)) {
        let n = items.len();
        let base = Items(items.as_mut_ptr());
        let base = &base;
        let job = move |k: usize| {
            // SAFETY: `k < n` and every `k` is claimed by exactly one call, so this is the only
            // reference to item `k` while the call runs; `items` outlives `Pool::run`.
            let item = unsafe { &mut *base.0.add(k) };
            f(k, item);
        };
        self.pool
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .run(n, &job);
    }

    fn threads(&self) -> usize {
        self.threads
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Many jobs back to back whose item counts rise and fall: every item of every job runs
    /// exactly once. (The stale-claim race fixed with the count in the claim word did not
    /// show here in a run against the old code: its window is a few instructions wide.)
    #[test]
    fn back_to_back_jobs_of_changing_sizes_run_each_item_once() {
        use std::sync::atomic::AtomicU32;
        let mut pool = Pool::new(3).unwrap();
        let counts: Vec<AtomicU32> = (0..16).map(|_| AtomicU32::new(0)).collect();
        for round in 0..20_000usize {
            let n = [2, 9, 3, 16, 5][round % 5];
            pool.run(n, &|k| {
                counts[k].fetch_add(1, Ordering::Relaxed);
            });
            for (k, c) in counts.iter().enumerate() {
                let want = u32::from(k < n);
                assert_eq!(
                    c.swap(0, Ordering::Relaxed),
                    want,
                    "round {round}, item {k}"
                );
            }
        }
    }

    #[test]
    fn every_item_runs_once_for_any_thread_count() {
        for threads in 1..=4 {
            let par = PoolParallel::new(threads).unwrap();
            for round in 0..200 {
                let mut items: Vec<u64> = (0..(round % 13) as u64).collect();
                par.for_each(&mut items, &|k, x| {
                    assert_eq!(*x, k as u64);
                    *x = *x * 3 + 1;
                });
                for (k, x) in items.iter().enumerate() {
                    assert_eq!(*x, k as u64 * 3 + 1, "threads {threads} round {round}");
                }
            }
        }
    }

    #[test]
    fn a_panicking_item_is_re_raised_on_the_caller_and_the_pool_survives() {
        let par = PoolParallel::new(2).unwrap();
        let mut items = [0u32; 8];
        let r = catch_unwind(AssertUnwindSafe(|| {
            par.for_each(&mut items, &|k, _| {
                if k == 5 {
                    panic!("item 5");
                }
            })
        }));
        assert!(r.is_err());
        par.for_each(&mut items, &|k, x| *x = k as u32);
        assert_eq!(items, [0, 1, 2, 3, 4, 5, 6, 7]);
    }
}
