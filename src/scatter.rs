//! Deterministic parallel particle-to-grid scatter by slab colouring.
//!
//! Particles are binned by their stencil base along one axis into slabs `S ≥ 2` nodes wide.
//! A particle of slab k writes nodes `[kS, (k+1)S + 1]` along that axis, so slabs k and k+2
//! never share a node (because `S > 1`). The scatter runs in two phases — even slabs in
//! parallel, then odd slabs in parallel — and every slab processes its particles in query
//! order. Each node therefore receives its contributions in one fixed order (its even slab's
//! particles, then its odd slab's), independent of the number of threads: the grid is
//! bit-identical for 1 or N threads. No atomics, no per-thread grid copies.
//!
//! The slab axis is the one with the largest particle extent and the width gives at most
//! [`MAX_SLABS`] slabs, both chosen from the particle positions only (never from the thread
//! count).
use bevy_ecs::prelude::*;
use bevy_tasks::ComputeTaskPool;
use glam::IVec3;

use crate::grid::{GridLayout, NodeBox};
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
}

impl ScatterPlan {
    /// Bins `positions` (predicted positions x̃, in query order).
    pub fn build(&mut self, layout: &GridLayout, positions: impl Iterator<Item = Vec3>) {
        let (lo_b, hi_b) = layout.base_bounds();
        self.positions.clear();
        self.offsets.clear();
        self.order.clear();
        self.keys.clear();
        self.bases.clear();
        let mut bmin = IVec3::MAX;
        let mut bmax = IVec3::MIN;
        for x in positions {
            let b = layout.base_of(x).clamp(lo_b, hi_b);
            bmin = bmin.min(b);
            bmax = bmax.max(b);
            self.positions.push(x);
            self.bases.push(b);
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
    /// within a phase no two concurrently running slabs share a node (module docs).
    pub fn run(&self, f: impl Fn(usize) + Sync) {
        let slabs = self.slabs();
        let parallel = self.order.len() >= SERIAL_BELOW && slabs > 1;
        let pool = ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && parallel);
        for phase in 0..2 {
            match pool {
                Some(pool) => {
                    pool.scope(|scope| {
                        for s in (phase..slabs).step_by(2) {
                            let f = &f;
                            let idx =
                                &self.order[self.offsets[s] as usize..self.offsets[s + 1] as usize];
                            scope.spawn(async move {
                                for &i in idx {
                                    f(i as usize);
                                }
                            });
                        }
                    });
                }
                None => {
                    for s in (phase..slabs).step_by(2) {
                        for &i in
                            &self.order[self.offsets[s] as usize..self.offsets[s + 1] as usize]
                        {
                            f(i as usize);
                        }
                    }
                }
            }
        }
    }
}

/// A raw pointer that may be shared with scatter tasks. See [`ScatterPlan::run`] for why the
/// writes through it do not race.
#[derive(Clone, Copy)]
pub struct SharedMut<T>(pub *mut T);
// SAFETY: used only by ScatterPlan::run callbacks, whose writes are disjoint per phase.
unsafe impl<T> Send for SharedMut<T> {}
// SAFETY: as above.
unsafe impl<T> Sync for SharedMut<T> {}

impl<T> SharedMut<T> {
    /// The pointer (a method, so closures capture the whole `Sync` wrapper).
    #[inline(always)]
    pub fn get(self) -> *mut T {
        self.0
    }
}
