//! Ordered parallel map over task indices on Bevy's `ComputeTaskPool`.
use bevy_tasks::ComputeTaskPool;

/// `f(0), f(1), …, f(tasks − 1)` in that order, run on the `ComputeTaskPool` when it exists
/// with more than one thread and there is more than one task, else in this thread. The result
/// does not depend on the pool: each task's output is returned in task order.
pub(super) fn map<T: Send + 'static>(tasks: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    match ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && tasks > 1) {
        Some(pool) => pool.scope(|scope| {
            for t in 0..tasks {
                let f = &f;
                scope.spawn(async move { f(t) });
            }
        }),
        None => (0..tasks).map(f).collect(),
    }
}

/// `f(0, items[0]), f(1, items[1]), …` like [`map`], each task taking its item by value
/// (e.g. a disjoint `&mut` slice of an output buffer).
pub(super) fn map_items<I: Send, T: Send + 'static>(
    items: Vec<I>,
    f: impl Fn(usize, I) -> T + Sync,
) -> Vec<T> {
    match ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && items.len() > 1) {
        Some(pool) => pool.scope(|scope| {
            for (t, item) in items.into_iter().enumerate() {
                let f = &f;
                scope.spawn(async move { f(t, item) });
            }
        }),
        None => items
            .into_iter()
            .enumerate()
            .map(|(t, i)| f(t, i))
            .collect(),
    }
}

/// `buffer` cut into consecutive mutable pieces of `lens[t]` elements.
pub(super) fn split_lens<T>(
    mut buffer: &mut [T],
    lens: impl IntoIterator<Item = usize>,
) -> Vec<&mut [T]> {
    let mut out = Vec::new();
    for len in lens {
        let (head, tail) = buffer.split_at_mut(len);
        out.push(head);
        buffer = tail;
    }
    out
}

/// Splits `0..n` into about `pieces` contiguous ranges (at least one element each, none
/// empty unless `n = 0`), independent of the thread count when `pieces` is.
pub(super) fn ranges(n: usize, pieces: usize) -> Vec<std::ops::Range<usize>> {
    let pieces = pieces.clamp(1, n.max(1));
    (0..pieces)
        .map(|p| n * p / pieces..n * (p + 1) / pieces)
        .collect()
}

/// A raw pointer shared with tasks that write disjoint elements through it (each use states
/// why the writes are disjoint).
#[derive(Clone, Copy)]
pub(super) struct SharedMut<T>(pub *mut T);
// SAFETY: only used by the two-phase slab fill of `field`, whose concurrent writes are
// disjoint (see there).
unsafe impl<T> Send for SharedMut<T> {}
// SAFETY: as above.
unsafe impl<T> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    /// The pointer (a method, so closures capture the whole `Sync` wrapper).
    #[inline(always)]
    pub(super) fn get(self) -> *mut T {
        self.0
    }
}
