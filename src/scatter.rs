//! Deterministic parallel particle-to-grid scatter by slab colouring.
//!
//! Particles are binned by their stencil base along one axis into slabs `S ≥ 2` nodes wide.
//! A particle of slab k writes nodes `[kS, (k+1)S + 1]` along that axis, so slabs k and k+2
//! never share a node (because `S > 1`). The scatter runs in two phases — even slabs in
//! parallel, then odd slabs in parallel, an odd slab starting as soon as its two even
//! neighbours are done — and every slab processes its particles in query order. Each node
//! therefore receives its contributions in one fixed order (its even slab's particles, then
//! its odd slab's), independent of the number of threads: the grid is bit-identical for 1 or N
//! threads. No atomic adds on the grid, no per-thread grid copies.
//!
//! The slab axis is the one with the largest particle extent and the width gives at most
//! [`MAX_SLABS`] slabs, both chosen from the particle positions only (never from the thread
//! count).
use bevy_ecs::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};

use bevy_tasks::ComputeTaskPool;
use glam::IVec3;

use crate::components::ParticleStencil;
use crate::grid::{BLOCK, BLOCK_NODES, GridLayout, MpmGrid, NodeBox, local_offset};
use crate::math::Vec3;

/// Upper bound on the number of slabs (more slabs = better balance, more task overhead).
pub const MAX_SLABS: i32 = 24;

/// Below this many particles the scatter runs on the calling thread (same result).
pub const SERIAL_BELOW: usize = 4096;

/// A binning of particles into slabs, rebuilt by every scatter (buffers reused).
#[derive(Resource, Default, Debug, Clone)]
pub struct ScatterPlan {
    axis: usize,
    /// `order[offsets[s]..offsets[s+1]]` are the particle indices of slab s, ascending.
    offsets: Vec<u32>,
    order: Vec<u32>,
    keys: Vec<u32>,
    bases: Vec<IVec3>,
    /// The binned positions, in binning order (to check that a later scatter of the same step
    /// sees the same particles in the same order before reusing the plan).
    positions: Vec<Vec3>,
    /// Nodes touched by the binned particles' stencils.
    pub touched: NodeBox,
    /// Per odd slab, the even slabs it still waits for during [`ScatterPlan::run`].
    pending: Pending,
}

impl ScatterPlan {
    /// Bins `positions` (predicted positions x̃, in query order).
    pub fn build(&mut self, layout: &GridLayout, positions: impl Iterator<Item = Vec3>) {
        let (lo_b, hi_b) = layout.base_bounds();
        self.positions.clear();
        self.bases.clear();
        for x in positions {
            self.positions.push(x);
            self.bases.push(layout.base_of(x).clamp(lo_b, hi_b));
        }
        self.bin();
    }

    /// Bins particles by their stencil bases (in query order; clamped into the node box, as
    /// [`crate::kernels::Stencil::locate`] gives them): the same plan as [`ScatterPlan::build`]
    /// of the positions they were located from. [`ScatterPlan::matches`] then sees no
    /// positions.
    pub fn build_from_bases(&mut self, layout: &GridLayout, bases: impl Iterator<Item = IVec3>) {
        let (lo_b, hi_b) = layout.base_bounds();
        self.positions.clear();
        self.bases.clear();
        self.bases.extend(bases.map(|b| b.clamp(lo_b, hi_b)));
        self.bin();
    }

    /// Bins `self.bases` into slabs.
    fn bin(&mut self) {
        self.offsets.clear();
        self.order.clear();
        self.keys.clear();
        let mut bmin = IVec3::MAX;
        let mut bmax = IVec3::MIN;
        for &b in &self.bases {
            bmin = bmin.min(b);
            bmax = bmax.max(b);
        }
        let n = self.bases.len();
        if n == 0 {
            self.touched = NodeBox::EMPTY;
            self.offsets.push(0);
            return;
        }
        self.touched = NodeBox {
            min: bmin,
            max: bmax + IVec3::splat(2),
        };
        let extent = bmax - bmin + IVec3::ONE;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        self.axis = axis;
        let width = ((extent[axis] + MAX_SLABS - 1) / MAX_SLABS).max(2);
        let slabs = ((extent[axis] + width - 1) / width) as usize;
        self.pending.reserve(slabs / 2);
        let origin = bmin[axis];
        let mut counts = vec![0u32; slabs + 1];
        self.keys.extend(self.bases.iter().map(|b| {
            let s = ((b[axis] - origin) / width) as u32;
            counts[s as usize + 1] += 1;
            s
        }));
        for s in 0..slabs {
            counts[s + 1] += counts[s];
        }
        self.offsets.extend_from_slice(&counts);
        self.order.resize(n, 0);
        let mut cursor = counts;
        for (i, &s) in self.keys.iter().enumerate() {
            let c = &mut cursor[s as usize];
            self.order[*c as usize] = i as u32;
            *c += 1;
        }
    }

    /// Whether `positions` are exactly (bit for bit, same order) the ones binned last, so the
    /// plan can be reused without rebuilding.
    pub fn matches(&self, positions: impl ExactSizeIterator<Item = Vec3>) -> bool {
        positions.len() == self.positions.len()
            && positions
                .zip(&self.positions)
                .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits))
    }

    /// Number of slabs.
    pub fn slabs(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Runs `f(particle index)` for every binned particle in the deterministic two-phase order.
    ///
    /// `f` may write to the grid nodes of the particle's stencil through a shared raw pointer:
    /// no two concurrently running slabs share a node (module docs).
    pub fn run(&self, f: impl Fn(usize) + Sync) {
        let slabs = self.slabs();
        let parallel = self.order.len() >= SERIAL_BELOW && slabs > 1;
        let slab = |s: usize| {
            for &i in &self.order[self.offsets[s] as usize..self.offsets[s + 1] as usize] {
                f(i as usize);
            }
        };
        match ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && parallel) {
            // Even slab 2i, odd slab 2j + 1; odd slab 2j + 1 waits for slabs 2j and 2j + 2.
            Some(pool) => run_linked_phases(
                pool,
                slabs.div_ceil(2),
                |j| 1 + u32::from(2 * j + 2 < slabs),
                |i| i.saturating_sub(1)..i.min((slabs / 2).saturating_sub(1)) + 1,
                &self.pending.lock()[..slabs / 2],
                |colour, i| slab(2 * i + colour),
            ),
            None => (0..slabs)
                .step_by(2)
                .chain((1..slabs).step_by(2))
                .for_each(slab),
        }
    }
}

/// Runs the two phases of a scatter on `pool`: every even task (`run(0, i)`, `i < evens`), and
/// every odd task (`run(1, j)`, `j < pending.len()`) as soon as the `waits(j)` even tasks whose
/// ranges `releases(i)` hold `j` have finished, rather than after the whole even phase. `pending`
/// is the counters' storage. Each odd task still runs after every even task it shares nodes
/// with, so each node is summed in the order of the two phases run one after the other.
fn run_linked_phases(
    pool: &bevy_tasks::TaskPool,
    evens: usize,
    waits: impl Fn(usize) -> u32,
    releases: impl Fn(usize) -> std::ops::Range<usize> + Sync,
    pending: &[AtomicU32],
    run: impl Fn(usize, usize) + Sync,
) {
    for (j, p) in pending.iter().enumerate() {
        p.store(waits(j), Ordering::Relaxed);
    }
    let (run, releases) = (&run, &releases);
    pool.scope(|s| {
        for (j, p) in pending.iter().enumerate() {
            if p.load(Ordering::Relaxed) == 0 {
                s.spawn(async move { run(1, j) });
            }
        }
        for i in 0..evens {
            s.spawn(async move {
                run(0, i);
                for j in releases(i) {
                    // The last even task to finish starts the odd one; the AcqRel decrements
                    // order every even task's writes before it.
                    if pending[j].fetch_sub(1, Ordering::AcqRel) == 1 {
                        s.spawn(async move { run(1, j) });
                    }
                }
            });
        }
    });
}

/// A raw pointer that may be shared with scatter tasks. See [`ScatterPlan::run`] for why the
/// writes through it do not race.
#[derive(Clone, Copy, Debug)]
pub struct SharedMut<T>(pub *mut T);
// SAFETY: used only by ScatterPlan::run callbacks, whose writes are disjoint per phase.
unsafe impl<T> Send for SharedMut<T> {}
// SAFETY: as above.
unsafe impl<T> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    /// The pointer to the first element of `slice`.
    pub fn slice(slice: &mut [T]) -> Self {
        Self(slice.as_mut_ptr())
    }

    /// The pointer to the first element of a shared `slice`: nothing may be written through
    /// it.
    pub fn read(slice: &[T]) -> Self {
        Self(slice.as_ptr().cast_mut())
    }

    /// The pointer (a method, so closures capture the whole `Sync` wrapper).
    #[inline(always)]
    pub fn get(self) -> *mut T {
        self.0
    }
}

/// Nodes along each axis of a particle block's neighbourhood: the [`BLOCK`] nodes of the block
/// its particles' stencil bases lie in plus the 2 beyond that their stencils reach.
pub const HOOD: i32 = BLOCK + 2;
/// Nodes of a neighbourhood.
pub const HOOD_NODES: usize = (HOOD * HOOD * HOOD) as usize;

/// Particles per task of the parallel block loops (blocks are grouped until a task has this many).
const PARTICLES_PER_TASK: usize = 2048;

/// Particles ordered by the grid block of their stencil base (a *particle block*), the unit of
/// the block-sparse transfers (ALGORITHM §11).
///
/// A particle block `B` reaches the nodes `lo + 4B … lo + 4B + 5` on every axis — its
/// neighbourhood of [`HOOD`]³ nodes, inside grid blocks `B` and `B + 1`. The transfers work on
/// one neighbourhood at a time through a dense copy (the kernels of [`crate::kernels`] address
/// it with [`GridLayout::sub_box`]): the scatter accumulates a block's particles into a zeroed
/// copy and adds it onto the grid; the gather copies the grid into it once per block.
///
/// **Determinism.** The scatter has 2 phases, one per parity of the blocks' x coordinate
/// (*colour*); a task takes whole x-slabs of blocks of one colour and runs their blocks one
/// after another in key order. Two slabs of one colour differ by at least 2 in x, so their
/// neighbourhoods share no node and the tasks of a phase run in parallel. A task of the odd
/// phase waits only for the even tasks whose slabs lie next to its own (the slabs whose
/// neighbourhoods share nodes with it), not for the whole even phase, so no thread idles at a
/// barrier between the phases. A node therefore still receives the sums of its particle blocks
/// in a fixed order (its even slab's, then its odd slab's; key order within a slab, each block
/// summed in particle order): the grid is bit-identical for any number of threads. (Eight
/// colours over the three block parities would split the work finer but cost eight pool
/// barriers per scatter instead of two — measured slower than one thread on small scenes on a
/// 2-core VM.)
#[derive(Resource, Default, Debug, Clone)]
pub struct BlockPlan {
    /// Block key of every particle (in the order given to [`BlockPlan::build`]).
    keys: Vec<u32>,
    /// Distinct particle blocks, ascending key.
    blocks: Vec<u32>,
    /// `order[starts[b]..starts[b + 1]]` are the particles of `blocks[b]`, ascending.
    starts: Vec<u32>,
    order: Vec<u32>,
    /// Per colour (x-slab parity), the indices into `blocks` of that colour, ascending.
    colour_blocks: [Vec<u32>; 2],
    /// Per colour, task ranges `[first, end)` of `colour_blocks[colour]` (whole slabs).
    colour_tasks: [Vec<(u32, u32)>; 2],
    /// Task ranges over all blocks (the gathers, which need no colouring).
    tasks: Vec<(u32, u32)>,
    counts: Vec<u32>,
    /// Per even task, the range of odd tasks that wait for it (their slabs lie next to its).
    releases: Vec<(u32, u32)>,
    /// Per odd task, the number of even tasks it waits for.
    waits: Vec<u32>,
    /// Per odd task, the even tasks it still waits for during a scatter.
    pending: Pending,
}

/// The linked phases' counters (scratch kept with a plan, so a scatter allocates nothing). A
/// scatter holds the lock while it runs, so two scatters of one plan from different threads
/// take turns instead of sharing counters.
#[derive(Default, Debug)]
struct Pending(Mutex<Vec<AtomicU32>>);

impl Clone for Pending {
    fn clone(&self) -> Self {
        let n = self.lock().len();
        Self(Mutex::new((0..n).map(|_| AtomicU32::new(0)).collect()))
    }
}

impl Pending {
    /// Room for `n` counters.
    fn reserve(&mut self, n: usize) {
        let v = self.0.get_mut().unwrap_or_else(PoisonError::into_inner);
        if v.len() < n {
            v.resize_with(n, || AtomicU32::new(0));
        }
    }

    /// The counters, for one scatter (they are reset by it, so a poisoned lock is harmless).
    fn lock(&self) -> MutexGuard<'_, Vec<AtomicU32>> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl BlockPlan {
    /// Orders particles by the block of their stencil bases `bases` (clamped into the node box,
    /// as [`crate::kernels::Stencil::new`] makes them). Returns whether the order changed from
    /// the last build (if not, nothing is rebuilt).
    pub fn build(
        &mut self,
        layout: &GridLayout,
        bases: impl ExactSizeIterator<Item = IVec3>,
    ) -> bool {
        let n = bases.len();
        let key_of = |b: IVec3| Self::key_of(layout, b);
        let mut same = n == self.keys.len() && !self.blocks.is_empty();
        if same {
            for (b, k) in bases.zip(self.keys.iter_mut()) {
                let key = key_of(b);
                if key != *k {
                    same = false;
                    *k = key;
                }
            }
            if same {
                return false;
            }
        } else {
            self.keys.clear();
            self.keys.extend(bases.map(key_of));
        }
        self.sort(layout);
        true
    }

    /// Block key of a stencil base.
    #[inline(always)]
    fn key_of(layout: &GridLayout, base: IVec3) -> u32 {
        let k = layout.block_of_node(base);
        ((k.x * layout.blocks.y + k.y) * layout.blocks.z + k.z) as u32
    }

    /// Whether this plan orders exactly `bases` (the same block keys in the same order), so a
    /// system whose particles have these bases may use it instead of building its own.
    pub fn orders(&self, layout: &GridLayout, bases: impl ExactSizeIterator<Item = IVec3>) -> bool {
        bases.len() == self.keys.len()
            && !self.blocks.is_empty()
            && bases
                .zip(&self.keys)
                .all(|(b, &k)| Self::key_of(layout, b) == k)
    }

    fn sort(&mut self, layout: &GridLayout) {
        let n = self.keys.len();
        self.blocks.clear();
        self.starts.clear();
        self.order.clear();
        for c in &mut self.colour_tasks {
            c.clear();
        }
        for c in &mut self.colour_blocks {
            c.clear();
        }
        self.tasks.clear();
        let (Some(&kmin), Some(&kmax)) = (self.keys.iter().min(), self.keys.iter().max()) else {
            self.starts.push(0);
            return;
        };
        // Counting sort over the occupied key range (stable: ascending particle index).
        let range = (kmax - kmin) as usize + 1;
        self.counts.clear();
        self.counts.resize(range, 0);
        for &k in &self.keys {
            self.counts[(k - kmin) as usize] += 1;
        }
        // Exclusive prefix sums: counts[r] = first position of key kmin + r.
        let mut acc = 0u32;
        for (r, c) in self.counts.iter_mut().enumerate() {
            let count = *c;
            if count > 0 {
                self.blocks.push(kmin + r as u32);
                self.starts.push(acc);
            }
            *c = acc;
            acc += count;
        }
        self.starts.push(n as u32);
        self.order.resize(n, 0);
        for (i, &k) in self.keys.iter().enumerate() {
            let c = &mut self.counts[(k - kmin) as usize];
            self.order[*c as usize] = i as u32;
            *c += 1;
        }
        // Task ranges: consecutive blocks (whole x-slabs of one colour, for the scatter) until
        // a task holds PARTICLES_PER_TASK particles. They depend on the particles only, never
        // on the thread count.
        let per_slab = (layout.blocks.y * layout.blocks.z) as u32;
        // Per colour: (first list index of the open task, its particles, its last slab).
        let mut open = [(0u32, 0usize, u32::MAX); 2];
        let mut all = (0u32, 0usize);
        for (bi, &key) in self.blocks.iter().enumerate() {
            let slab = key / per_slab;
            let colour = (slab & 1) as usize;
            let count = (self.starts[bi + 1] - self.starts[bi]) as usize;
            let list = &mut self.colour_blocks[colour];
            let task = &mut open[colour];
            if slab != task.2 && task.1 >= PARTICLES_PER_TASK {
                self.colour_tasks[colour].push((task.0, list.len() as u32));
                *task = (list.len() as u32, 0, slab);
            }
            task.1 += count;
            task.2 = slab;
            list.push(bi as u32);
            all.1 += count;
            if all.1 >= PARTICLES_PER_TASK {
                self.tasks.push((all.0, bi as u32 + 1));
                all = (bi as u32 + 1, 0);
            }
        }
        for (c, list) in self.colour_blocks.iter().enumerate() {
            if (open[c].0 as usize) < list.len() {
                self.colour_tasks[c].push((open[c].0, list.len() as u32));
            }
        }
        if (all.0 as usize) < self.blocks.len() {
            self.tasks.push((all.0, self.blocks.len() as u32));
        }
        self.link_phases(per_slab);
    }

    /// Which odd tasks wait for which even ones: an odd task and an even task whose slabs are
    /// next to each other (or interleave) reach common nodes. Tasks of a colour hold
    /// consecutive slabs in ascending order, so each even task releases a contiguous range of
    /// odd tasks.
    fn link_phases(&mut self, per_slab: u32) {
        // The first and last x-slab of task `t` of colour `c`.
        let slabs = |c: usize, t: usize| {
            let (first, end) = self.colour_tasks[c][t];
            let slab = |i: u32| self.blocks[self.colour_blocks[c][i as usize] as usize] / per_slab;
            (slab(first), slab(end - 1))
        };
        let odds = self.colour_tasks[1].len();
        self.releases.clear();
        self.waits.clear();
        self.waits.resize(odds, 0);
        let mut j0 = 0;
        for i in 0..self.colour_tasks[0].len() {
            let (lo, hi) = slabs(0, i);
            while j0 < odds && slabs(1, j0).1 + 1 < lo {
                j0 += 1;
            }
            let mut j1 = j0;
            while j1 < odds && slabs(1, j1).0 <= hi + 1 {
                self.waits[j1] += 1;
                j1 += 1;
            }
            self.releases.push((j0 as u32, j1 as u32));
        }
        self.pending.reserve(odds);
    }

    /// Number of particles ordered.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether no particle is ordered.
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// Number of particle blocks.
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }

    /// The grid blocks the transfers of these particles reach (each particle block and its
    /// neighbours above on every axis, inside the node box), appended to `out` (unsorted).
    pub fn reached_blocks(&self, layout: &GridLayout, out: &mut Vec<u32>) {
        for &key in &self.blocks {
            let b = layout.block_of_key(key);
            for d in 0..8 {
                let nb = b + IVec3::new(d >> 2, (d >> 1) & 1, d & 1);
                if let Some(k) = layout.key_of_block(nb) {
                    out.push(k);
                }
            }
        }
    }

    /// The particles of block `bi` (index into the particle blocks).
    #[inline]
    fn particles(&self, bi: usize) -> &[u32] {
        &self.order[self.starts[bi] as usize..self.starts[bi + 1] as usize]
    }

    /// Runs `f(particle, neighbourhood layout, neighbourhood)` for every particle, one zeroed
    /// dense neighbourhood per particle block, and adds each neighbourhood onto `nodes` (the
    /// storage of `grid`'s blocks, one `T` per node) with `add` — the deterministic colour
    /// order of the type docs.
    pub fn scatter<T: Copy + Default + Send + Sync>(
        &self,
        grid: &MpmGrid,
        nodes: &mut [T],
        add: impl Fn(&mut T, &T) + Sync,
        f: impl Fn(usize, &GridLayout, &mut [T]) + Sync,
    ) {
        assert_eq!(nodes.len(), grid.block_count() * BLOCK_NODES);
        let shared = SharedMut(nodes.as_mut_ptr());
        let run_task = |colour: usize, (first, end): (u32, u32)| {
            let mut hood = [T::default(); HOOD_NODES];
            for &bi in &self.colour_blocks[colour][first as usize..end as usize] {
                let bi = bi as usize;
                hood.fill(T::default());
                let local = self.hood_layout(&grid.layout, bi);
                for &i in self.particles(bi) {
                    f(i as usize, &local, &mut hood);
                }
                // SAFETY: blocks of one colour have disjoint neighbourhoods, and an odd task
                // starts only after the even tasks whose neighbourhoods meet its own have
                // finished (type docs), so no two tasks write one node concurrently;
                // `shared` covers every allocated node and `for_each_hood_node` yields
                // storage indices of allocated blocks only.
                for_each_hood_node(grid, &local, |h, idx| unsafe {
                    add(&mut *shared.get().add(idx), &hood[h])
                });
            }
        };
        let parallel = self.len() >= SERIAL_BELOW;
        let [even, odd] = &self.colour_tasks;
        match ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && parallel) {
            Some(pool) if even.len() + odd.len() > 1 => run_linked_phases(
                pool,
                even.len(),
                |j| self.waits[j],
                |i| self.releases[i].0 as usize..self.releases[i].1 as usize,
                &self.pending.lock()[..self.waits.len()],
                |colour, t| run_task(colour, self.colour_tasks[colour][t]),
            ),
            _ => {
                for (colour, tasks) in self.colour_tasks.iter().enumerate() {
                    tasks.iter().for_each(|&t| run_task(colour, t));
                }
            }
        }
    }

    /// Runs `f(particle, neighbourhood layout, neighbourhood)` for every particle, with a dense
    /// copy of its block's neighbourhood of `nodes` (zero where no block is allocated); blocks
    /// in parallel. `f` sees only its own particle's inputs, so the order does not matter.
    pub fn gather<T: Copy + Default + Send + Sync>(
        &self,
        grid: &MpmGrid,
        nodes: &[T],
        f: impl Fn(usize, &GridLayout, &[T]) + Sync,
    ) {
        assert_eq!(nodes.len(), grid.block_count() * BLOCK_NODES);
        let run_task = |(first, end): (u32, u32)| {
            let mut hood = [T::default(); HOOD_NODES];
            for bi in first as usize..end as usize {
                hood.fill(T::default());
                let local = self.hood_layout(&grid.layout, bi);
                for_each_hood_node(grid, &local, |h, idx| hood[h] = nodes[idx]);
                for &i in self.particles(bi) {
                    f(i as usize, &local, &hood);
                }
            }
        };
        let parallel = self.len() >= SERIAL_BELOW;
        match ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && parallel) {
            Some(pool) if self.tasks.len() > 1 => {
                pool.scope(|s| {
                    for &t in &self.tasks {
                        let run_task = &run_task;
                        s.spawn(async move { run_task(t) });
                    }
                });
            }
            _ => self.tasks.iter().for_each(|&t| run_task(t)),
        }
    }

    /// Gathers into `out[i]` (resized to the particle count) the value `f` computes for particle
    /// `i` from its block's neighbourhood ([`BlockPlan::gather`]).
    pub fn gather_into<T, R>(
        &self,
        grid: &MpmGrid,
        nodes: &[T],
        out: &mut Vec<R>,
        f: impl Fn(usize, &GridLayout, &[T]) -> R + Sync,
    ) where
        T: Copy + Default + Send + Sync,
        R: Copy + Default + Send + Sync,
    {
        out.clear();
        out.resize(self.len(), R::default());
        let shared = SharedMut(out.as_mut_ptr());
        self.gather(grid, nodes, |i, local, hood| {
            let r = f(i, local, hood);
            // SAFETY: every particle index appears once in the plan, so each slot is written
            // by one task; `out` holds `self.len()` entries.
            unsafe { *shared.get().add(i) = r };
        });
    }

    /// Layout of the neighbourhood of particle block `bi`.
    #[inline]
    fn hood_layout(&self, layout: &GridLayout, bi: usize) -> GridLayout {
        let b = layout.block_of_key(self.blocks[bi]);
        layout.sub_box(layout.lo + b * BLOCK, HOOD)
    }
}

/// A query's particles as the per-table column slices of `Query::contiguous_iter(_mut)`,
/// addressed by the query-order index the block plans use: `C` holds one table's column
/// pointers ([`SharedMut`]), so a transfer reads its inputs from, and writes its results into,
/// the table rows, with no per-particle buffer (issue 17's memory). Filled table by table with
/// [`QueryRows::push`] in query order; cleared after use.
#[derive(Debug)]
pub struct QueryRows<C> {
    /// First query index of each table pushed, then the total.
    starts: Vec<usize>,
    /// Each table's [`ParticleStencil`] column.
    stencils: Vec<SharedMut<ParticleStencil>>,
    /// Each table's other columns.
    cols: Vec<C>,
}

impl<C> Default for QueryRows<C> {
    fn default() -> Self {
        Self {
            starts: vec![0],
            stencils: Vec::new(),
            cols: Vec::new(),
        }
    }
}

impl<C: Copy + Send + Sync> QueryRows<C> {
    /// Appends the next table of the query (in query order): its stencils and its other
    /// columns `cols`.
    ///
    /// # Safety
    /// `stencils` and the pointers in `cols` must stay valid for `stencils.len()` rows, with
    /// no other access to them (no writes to `stencils`), until [`QueryRows::clear`]: this
    /// keeps pointers, not borrows.
    pub unsafe fn push(&mut self, stencils: &[ParticleStencil], cols: C) {
        if stencils.is_empty() {
            return;
        }
        self.starts.push(self.len() + stencils.len());
        self.stencils.push(SharedMut::read(stencils));
        self.cols.push(cols);
    }

    /// Forgets the tables.
    pub fn clear(&mut self) {
        self.starts.truncate(1);
        self.stencils.clear();
        self.cols.clear();
    }

    /// Number of particles pushed.
    pub fn len(&self) -> usize {
        self.starts.last().copied().unwrap_or(0)
    }

    /// Whether no particle was pushed.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The stencils of every particle, in query order.
    pub fn stencils(&self) -> impl ExactSizeIterator<Item = &ParticleStencil> + Clone {
        ExactLen {
            inner: self.stencils.iter().zip(self.starts.windows(2)).flat_map(
                // SAFETY: `push` received a slice of `end − start` stencils behind this pointer,
                // valid until `clear` (its contract); the stencil columns are only read.
                |(st, w)| unsafe { std::slice::from_raw_parts(st.get(), w[1] - w[0]) },
            ),
            remaining: self.len(),
        }
    }

    /// The stencil bases of every particle, in query order (for [`BlockPlan::build`]).
    pub fn bases(&self) -> impl ExactSizeIterator<Item = IVec3> + Clone {
        self.stencils().map(|st| st.base)
    }

    /// Particle `i` (query order): its stencil, its table's columns and its row there.
    #[inline(always)]
    pub fn get(&self, i: usize) -> (&ParticleStencil, C, usize) {
        let t = if self.cols.len() == 1 {
            0
        } else {
            self.starts.partition_point(|&s| s <= i) - 1
        };
        let row = i - self.starts[t];
        assert!(row < self.starts[t + 1] - self.starts[t]);
        // SAFETY: row < the table's length (asserted), whose stencils stay valid until `clear`
        // (the contract of `push`); the stencil column is only read.
        let st = unsafe { &*self.stencils[t].get().add(row) };
        (st, self.cols[t], row)
    }
}

/// The reusable memory of a gather system that writes its results straight into the particle
/// components: its block order and its query's table columns ([`QueryRows`]).
#[derive(Debug)]
pub struct GatherScratch<C> {
    /// The particles of the system's query ordered by block (when the step's shared plan does
    /// not order them, [`GatherScratch::gather`]).
    pub plan: BlockPlan,
    /// The query's tables, pushed before each gather.
    pub rows: QueryRows<C>,
}

impl<C> Default for GatherScratch<C> {
    fn default() -> Self {
        Self {
            plan: BlockPlan::default(),
            rows: QueryRows::default(),
        }
    }
}

impl<C: Copy + Send + Sync> GatherScratch<C> {
    /// Forgets the tables pushed (a gather does so too; call it before the first push, so a
    /// gather interrupted by a panic leaves nothing stale).
    pub fn clear(&mut self) {
        self.rows.clear();
    }

    /// Appends the next table of the query ([`QueryRows::push`]).
    ///
    /// # Safety
    /// As [`QueryRows::push`], until [`GatherScratch::gather`] or [`GatherScratch::clear`].
    pub unsafe fn push(&mut self, stencils: &[ParticleStencil], cols: C) {
        // SAFETY: the caller's contract is push's.
        unsafe { self.rows.push(stencils, cols) };
    }

    /// Runs `f(stencil, columns, row, neighbourhood layout, neighbourhood)` once for every
    /// particle pushed ([`BlockPlan::gather`]), blocks in parallel, then forgets the tables.
    /// The block order is the step's `shared` plan (built by P2G, resource [`BlockPlan`]) when
    /// it orders exactly these particles — the usual case, one counting sort per step for all
    /// transfers — and otherwise this system's own plan, rebuilt (a query over part of the
    /// particles).
    ///
    /// `f` may read and write row `row` of the columns of `columns` (each row is visited by
    /// one task, once) and nothing else of them.
    pub fn gather<T: Copy + Default + Send + Sync>(
        &mut self,
        shared: &BlockPlan,
        grid: &MpmGrid,
        nodes: &[T],
        f: impl Fn(&ParticleStencil, C, usize, &GridLayout, &[T]) + Sync,
    ) {
        let layout = &grid.layout;
        let rows = &self.rows;
        let plan = if shared.orders(layout, rows.bases()) {
            shared
        } else {
            self.plan.build(layout, rows.bases());
            &self.plan
        };
        plan.gather(grid, nodes, |i, local, hood| {
            let (st, cols, row) = rows.get(i);
            f(st, cols, row, local, hood);
        });
        self.rows.clear();
    }
}

/// An iterator of known length (the chained table slices of a query).
#[derive(Clone)]
struct ExactLen<I> {
    inner: I,
    remaining: usize,
}

impl<I: Iterator> Iterator for ExactLen<I> {
    type Item = I::Item;
    #[inline]
    fn next(&mut self) -> Option<I::Item> {
        let item = self.inner.next()?;
        self.remaining -= 1;
        Some(item)
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.remaining, Some(self.remaining))
    }
}

impl<I: Iterator> ExactSizeIterator for ExactLen<I> {}

/// Calls `f(neighbourhood index, storage index)` for every node of the dense neighbourhood
/// `local` ([`GridLayout::sub_box`] of a particle block) whose grid block is allocated: one
/// table lookup per grid block (at most 8), then runs of consecutive nodes.
#[inline]
pub fn for_each_hood_node(grid: &MpmGrid, local: &GridLayout, mut f: impl FnMut(usize, usize)) {
    let layout = &grid.layout;
    let b0 = layout.block_of_node(local.lo);
    for d in 0..8 {
        let d = IVec3::new(d >> 2, (d >> 1) & 1, d & 1);
        let Some(slot) = grid.slot_of_block(b0 + d) else {
            continue;
        };
        let base = slot * BLOCK_NODES;
        // Along each axis: block part 0 covers hood 0..4 (local 0..4), part 1 hood 4..6
        // (local 0..2).
        let len = |p: i32| if p == 0 { BLOCK } else { HOOD - BLOCK };
        let (nx, ny, nz) = (len(d.x), len(d.y), len(d.z));
        let (hx, hy, hz) = (d.x * BLOCK, d.y * BLOCK, d.z * BLOCK);
        for x in 0..nx {
            for y in 0..ny {
                let h = (((hx + x) * HOOD + hy + y) * HOOD + hz) as usize;
                let g = base + local_offset(IVec3::new(x, y, 0));
                for z in 0..nz as usize {
                    f(h + z, g + z);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every pair of an even and an odd scatter task whose slabs lie next to each other is
    /// linked (the odd one waits for the even one), and no other pair: against a brute-force
    /// check, for tasks of one slab and tasks grouping several small slabs.
    #[test]
    fn block_plan_links_each_odd_task_to_its_neighbouring_even_tasks() {
        let layout = GridLayout::new(Vec3::ZERO, Vec3::new(16.0, 1.0, 1.0), 0.0625);
        // Per x-slab of blocks (0.25 m), a particle count: large ones make one-slab tasks,
        // runs of small ones are grouped into a task until it holds PARTICLES_PER_TASK.
        let counts = [
            3000, 3000, 3000, 10, 10, 10, 10, 2500, 2500, 40, 3000, 5, 5, 5, 5, 5, 5, 4000, 1, 3000,
        ];
        let mut bases = Vec::new();
        for (slab, &n) in counts.iter().enumerate() {
            for k in 0..n {
                bases.push(IVec3::new(4 * slab as i32 + 1, 1 + k % 2, 1));
            }
        }
        let mut plan = BlockPlan::default();
        plan.build(&layout, bases.into_iter());
        let per_slab = (layout.blocks.y * layout.blocks.z) as u32;
        let slabs_of = |c: usize, (first, end): (u32, u32)| -> Vec<u32> {
            (first..end)
                .map(|i| plan.blocks[plan.colour_blocks[c][i as usize] as usize] / per_slab)
                .collect()
        };
        let [even, odd] = &plan.colour_tasks;
        assert!(even.len() >= 3 && odd.len() >= 3, "tasks {even:?} {odd:?}");
        assert!(
            even.iter().chain(odd).any(|&(f, e)| e - f > 1),
            "some task groups several slabs"
        );
        let mut waits = vec![0; odd.len()];
        for (i, &te) in even.iter().enumerate() {
            let se = slabs_of(0, te);
            let linked: Vec<usize> = (0..odd.len())
                .filter(|&j| {
                    let so = slabs_of(1, odd[j]);
                    se.iter().any(|a| so.iter().any(|b| a.abs_diff(*b) == 1))
                })
                .collect();
            for &j in &linked {
                waits[j] += 1;
            }
            let (j0, j1) = plan.releases[i];
            assert_eq!(
                (j0 as usize..j1 as usize).collect::<Vec<_>>(),
                linked,
                "even task {i}, slabs {se:?}"
            );
        }
        assert_eq!(plan.waits, waits);
    }

    /// The linked phases run every task once, and each odd task only after every even task
    /// that releases it has finished, on a pool of four threads with tasks of uneven length.
    /// The slab arithmetic of `ScatterPlan::run` (odd slab 2j + 1 waits for 2j and 2j + 2).
    #[test]
    fn linked_phases_start_odd_tasks_after_their_even_neighbours() {
        use std::sync::Mutex;
        let pool = bevy_tasks::TaskPoolBuilder::new().num_threads(4).build();
        for slabs in [2usize, 3, 4, 7, 10] {
            let (evens, odds) = (slabs.div_ceil(2), slabs / 2);
            let waits = |j: usize| 1 + u32::from(2 * j + 2 < slabs);
            let releases = |i: usize| i.saturating_sub(1)..i.min(odds.saturating_sub(1)) + 1;
            let pending: Vec<AtomicU32> = (0..odds).map(|_| AtomicU32::new(0)).collect();
            // (slab, started, ended) in log order.
            let log = Mutex::new(Vec::new());
            let clock = AtomicU32::new(0);
            run_linked_phases(&pool, evens, waits, releases, &pending, |colour, i| {
                let slab = 2 * i + colour;
                let start = clock.fetch_add(1, Ordering::SeqCst);
                // Uneven work: the even slabs 0, 4, 8 are slow.
                let spin = if slab % 4 == 0 { 200_000 } else { 1_000 };
                std::hint::black_box((0..spin).sum::<u64>());
                let end = clock.fetch_add(1, Ordering::SeqCst);
                log.lock().unwrap().push((slab, start, end));
            });
            let log = log.into_inner().unwrap();
            let mut seen: Vec<usize> = log.iter().map(|e| e.0).collect();
            seen.sort_unstable();
            assert_eq!(seen, (0..slabs).collect::<Vec<_>>(), "{slabs} slabs");
            let at = |slab: usize| log.iter().find(|e| e.0 == slab).copied().unwrap();
            for odd in (1..slabs).step_by(2) {
                for even in [odd - 1, odd + 1].into_iter().filter(|&e| e < slabs) {
                    assert!(
                        at(even).2 < at(odd).1,
                        "{slabs} slabs: odd slab {odd} started before even slab {even} ended"
                    );
                }
            }
        }
    }

    /// A particle index of the query maps to its own table and row, across tables of different
    /// lengths (an empty one included), and the bases come out in query order.
    #[test]
    fn query_rows_map_indices_to_their_table_rows() {
        let table = |n: i32, t: i32| -> Vec<ParticleStencil> {
            (0..n)
                .map(|r| ParticleStencil {
                    base: IVec3::new(t, r, 0),
                    offset: Vec3::ZERO,
                })
                .collect()
        };
        let tables = [table(3, 0), table(0, 1), table(5, 2), table(1, 3)];
        let mut rows = QueryRows::<usize>::default();
        for (t, st) in tables.iter().enumerate() {
            // SAFETY: `tables` outlives `rows`' use below and is not written.
            unsafe { rows.push(st, t) };
        }
        assert_eq!(rows.len(), 9);
        let expected: Vec<(usize, usize)> = tables
            .iter()
            .enumerate()
            .flat_map(|(t, st)| (0..st.len()).map(move |r| (t, r)))
            .collect();
        for (i, &(t, r)) in expected.iter().enumerate() {
            let (st, cols, row) = rows.get(i);
            assert_eq!((cols, row), (t, r), "index {i}");
            assert_eq!(st.base, IVec3::new(t as i32, r as i32, 0));
        }
        let bases: Vec<IVec3> = rows.bases().collect();
        assert_eq!(bases.len(), rows.bases().len());
        assert_eq!(
            bases,
            expected
                .iter()
                .map(|&(t, r)| IVec3::new(t as i32, r as i32, 0))
                .collect::<Vec<_>>()
        );
        rows.clear();
        assert!(rows.is_empty());
    }
}
