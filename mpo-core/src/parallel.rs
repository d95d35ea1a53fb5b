//! How the learner hands out independent pieces of an update: the [`Parallel`] trait.
//!
//! An update is a fixed sequence of phases. Within a phase the work is a list of items that
//! share nothing mutable (the batch chunks of a forward and backward pass, the parameter
//! blocks of a weight gradient), each item's result depends only on its own inputs, and every
//! reduction across items happens afterwards in a fixed order. So whoever runs the items, in
//! whatever order and on however many threads, the bits are the same. The core stays `no_std`
//! and runs items itself with [`Serial`]; a host supplies a thread pool.

/// Runs `f` on every item of a list, possibly on several threads.
pub trait Parallel: Sync {
    /// Calls `f(k, &mut items[k])` once for every `k` and returns when all calls have
    /// returned. Calls may run concurrently and in any order.
    fn for_each<T: Send>(&self, items: &mut [T], f: &(dyn Fn(usize, &mut T) + Sync));

    /// How many threads run items (for display and for sizing work; never for results).
    fn threads(&self) -> usize;
}

/// Runs every item on the calling thread, in order.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

impl Parallel for Serial {
    fn for_each<T: Send>(&self, items: &mut [T], f: &(dyn Fn(usize, &mut T) + Sync)) {
        for (k, item) in items.iter_mut().enumerate() {
            f(k, item);
        }
    }

    fn threads(&self) -> usize {
        1
    }
}
