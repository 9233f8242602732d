//! Ordered parallel loops over task indices on Bevy's `ComputeTaskPool`: the tasks are fixed by
//! the work, never by the thread count, so what they compute does not depend on it.
use bevy_tasks::ComputeTaskPool;

/// `f(item)` for every item, each item a task on the `ComputeTaskPool` when `parallel` holds and
/// the pool has more than one thread, else in this thread in order. Each task takes its item by
/// value (e.g. a range and disjoint `&mut` pieces of output buffers, [`split_lens`]); nothing is
/// allocated.
pub(crate) fn for_each_item<I: Send>(
    parallel: bool,
    items: impl Iterator<Item = I>,
    f: impl Fn(I) + Sync,
) {
    match ComputeTaskPool::try_get().filter(|p| parallel && p.thread_num() > 1) {
        Some(pool) => {
            pool.scope(|scope| {
                let f = &f;
                for item in items {
                    scope.spawn(async move { f(item) });
                }
            });
        }
        None => items.for_each(f),
    }
}

#[cfg(feature = "surface")]
/// `f(0), f(1), …, f(tasks − 1)` in that order, run on the `ComputeTaskPool` when it exists
/// with more than one thread and there is more than one task, else in this thread. The result
/// does not depend on the pool: each task's output is returned in task order.
pub(crate) fn map<T: Send + 'static>(tasks: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
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

#[cfg(feature = "surface")]
/// `f(0, items[0]), f(1, items[1]), …` like [`map`], each task taking its item by value
/// (e.g. a disjoint `&mut` slice of an output buffer).
pub(crate) fn map_items<I: Send, T: Send + 'static>(
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

/// `buffer` cut into consecutive mutable pieces of `lens[t]` elements (lazily: nothing is
/// allocated). Panics if the lengths add up to more than the buffer.
pub(crate) fn split_lens<T>(
    mut buffer: &mut [T],
    lens: impl IntoIterator<Item = usize>,
) -> impl Iterator<Item = &mut [T]> {
    lens.into_iter().map(move |len| {
        let (head, tail) = std::mem::take(&mut buffer).split_at_mut(len);
        buffer = tail;
        head
    })
}

#[cfg(feature = "surface")]
/// Splits `0..n` into about `pieces` contiguous ranges (at least one element each, none
/// empty unless `n = 0`), independent of the thread count when `pieces` is.
pub(crate) fn ranges(n: usize, pieces: usize) -> Vec<std::ops::Range<usize>> {
    let pieces = pieces.clamp(1, n.max(1));
    (0..pieces)
        .map(|p| n * p / pieces..n * (p + 1) / pieces)
        .collect()
}

#[cfg(feature = "surface")]
/// A raw pointer shared with tasks that write disjoint elements through it (each use states
/// why the writes are disjoint).
#[derive(Clone, Copy)]
pub(crate) struct SharedMut<T>(pub *mut T);
#[cfg(feature = "surface")]
// SAFETY: only used by tasks whose concurrent writes are disjoint (each use states why).
unsafe impl<T> Send for SharedMut<T> {}
#[cfg(feature = "surface")]
// SAFETY: as above.
unsafe impl<T> Sync for SharedMut<T> {}

#[cfg(feature = "surface")]
impl<T> SharedMut<T> {
    /// The pointer (a method, so closures capture the whole `Sync` wrapper).
    #[inline(always)]
    pub(crate) fn get(self) -> *mut T {
        self.0
    }
}
