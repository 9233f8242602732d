//! The pressure projection of [`PressureSolve::Projection`](crate::config::PressureSolve)
//! (ALGORITHM §5.4): velocities stay on the nodes, one pressure per cell, the liquid's volume is
//! kept by a solve on the grid instead of by the Tait equation's sound waves.
//!
//! # The system
//!
//! A cell c (nodes c + {0,1}³) holds a liquid when a particle lies in it; other cells are air
//! (p = 0, the free surface) or solid. With trilinear (Q1) velocities in a cell, the divergence
//! integrated over it is
//!
//! (D v)_c = ∫_c ∇·v dV = (Δx²/4) Σₖ sₖ·v_{c+k},  sₖ = 2k − 1 ∈ {−1, 1}³,
//!
//! and the virtual work of a cell pressure gives the nodal force fᵢ = (Dᵀp)ᵢ (the weak form of
//! −∇p with p = 0 in the air: the free surface is traction-free). After the grid update has
//! produced v* (gravity, viscous and model stresses, collisions), the step ends with
//!
//! mᵢ vᵢ = mᵢ v*ᵢ + Δt Pᵢ (Dᵀp)ᵢ,   (D v)_c = r_c,
//!
//! where Pᵢ projects onto the components a wall or collider leaves free (the classification of
//! the implicit viscous solve: all components at a sticky wall, the normal one at a slip wall
//! the node presses into, always on a mirror face). Eliminating v:
//!
//! Δt D P M⁻¹ P Dᵀ p = r − D v*,
//!
//! symmetric positive semi-definite on the liquid cells, solved by Jacobi-preconditioned CG
//! ([`crate::krylov`]) from the last step's pressures. The right-hand side's r_c relaxes the
//! volume drift the particle transfer leaves (particles move with the B-spline interpolant of
//! a field that is divergence-free in the Q1 sense only, so they bunch up a little):
//! r_c = Δx³ max(0, ln φ_c) / max(τ, Δt), with φ_c = Σₖ m_{c+k} / (8ρ₀Δx³) the cell's fill
//! (its corners' transferred masses, ρ₀ the mean rest density of its particles; 1 in a liquid
//! at rest) and τ = `volume_relaxation`: an overfull cell expands, a partly filled one (the
//! surface, a splash) is left alone. (A count of the particles in the cell was tried first: its
//! jitter of ±1 particle in 8 made half the cells "overfull", and the one-sided correction
//! inflated a settling pool to 1.7× its volume.) The particles keep ρₚ = ρ₀ (an incompressible
//! liquid's particle volume does not change; the first-order density update is skipped).
//!
//! # Why cells and Q1, not nodes
//!
//! A collocated projection (a pressure per node, the node Laplacian) does not hold a pool at
//! rest: next to a wall its Laplacian and the product of its one-sided divergence and the
//! adjoint gradient differ, so gravity is not balanced there. With D and Dᵀ exact adjoints the
//! discrete hydrostatic pressure balances gravity to the solver tolerance
//! (`tests/it/pressure.rs`). The checkerboard pressure modes of this element pair lie in the
//! null space of Dᵀ: they do not reach the velocities.
//!
//! # What it changes elsewhere
//!
//! The constitutive stage leaves the Tait pressure out of the stress and reports no sound
//! speed, so Δt is limited by advection (and explicit viscosities, relaxation) only. Rigid
//! bodies still exchange momentum through their coupling projection after this stage, but the
//! cell pressure does not act on them (a body's interior cells are air): a floating body needs
//! [`PressureSolve::Tait`](crate::config::PressureSolve::Tait).
//!
//! # Determinism
//!
//! Cells and nodes are numbered in grid storage order, block by block, from per-block bit
//! masks. The cell volumes are summed in one serial pass in query order. The system is built
//! and the velocities are updated block by block on the task pool (fixed ranges of blocks; each
//! element is computed on its own), and the operator's two passes compute each node and each
//! cell as one sum in a fixed order (split over the pool for large systems); the inner
//! products are serial in storage order, so results are bit-identical for any thread count.
//!
//! # On ranks
//!
//! Each cell is the unknown of one rank; the ranks sharing a block column exchange that
//! column's first cell layer, their corner nodes there, and per operator application the node
//! sums of the pressures around the shared nodes (`halo` module; ALGORITHM §12). Inner
//! products are summed over the ranks in rank order.
use std::ops::Range;

use bevy_ecs::prelude::*;
use bevy_tasks::ComputeTaskPool;
use glam::{DMat3, DVec3, IVec3};

use super::ImplicitSolveStats;
use super::viscous::classify;
use crate::components::{Mass, Particle, Position};
use crate::config::MpmConfig;
use crate::distributed::{RankReduction, Ranks};
use crate::failure::{FailureCollector, FailureReport};
use crate::grid::{BLOCK_NODES, GhostCopy, MpmGrid, local_coords};
use crate::krylov::{
    CgInfo, CgParams, CgScratch, JacobiPreconditioner, LinearOperator, Reduction, ResidualNorm,
    conjugate_gradient_reduced,
};
use crate::material::{MaterialId, Materials};
use crate::math::{Vec3, fast_floor};
use crate::parallel::{for_each_item, split_lens};
use crate::step::grid_update::collide_node;
use crate::step::p2g::{copy_ghosts, mirror_faces};
use crate::step::schedule::{ActiveColliders, StepContext};

mod halo;
use halo::PressureHalo;

/// Statistics of the pressure solves of a run (a Resource; as [`ImplicitSolveStats`]).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct PressureSolveStats(pub ImplicitSolveStats);

/// Run condition: the pressure is projected ([`crate::config::PressureSolve::Projection`]) and
/// the step is not the start-up rate evaluation.
pub fn pressure_projection_step(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    config.integrator.pressure.projection().is_some() && !ctx.rate_evaluation
}

/// The corner offsets of a cell, k = (kx, ky, kz) ∈ {0,1}³ in x-major order.
const CORNERS: [IVec3; 8] = [
    IVec3::new(0, 0, 0),
    IVec3::new(0, 0, 1),
    IVec3::new(0, 1, 0),
    IVec3::new(0, 1, 1),
    IVec3::new(1, 0, 0),
    IVec3::new(1, 0, 1),
    IVec3::new(1, 1, 0),
    IVec3::new(1, 1, 1),
];

/// The 26 neighbour offsets of a node, x-major.
const NEIGHBOURS: [IVec3; 26] = {
    let mut out = [IVec3::ZERO; 26];
    let mut k = 0;
    let mut j = 0;
    while k < 27 {
        if k != 13 {
            out[j] = IVec3::new(k / 9 - 1, (k / 3) % 3 - 1, k % 3 - 1);
            j += 1;
        }
        k += 1;
    }
    out
};

/// A node of the projection: a corner of a liquid cell.
#[derive(Clone, Copy, Debug, Default)]
struct ProjectionNode {
    /// The liquid cell it is corner k of, for k = 0..8 (u32::MAX: none).
    cells: [u32; 8],
    /// Δt/mᵢ (0 for a node without mass: it does not move).
    scale: f64,
    /// Whether a wall or collider constrains it (its Pᵢ is then in the operator's
    /// `constraint`).
    constrained: bool,
}

/// The operator Δt D P M⁻¹ P Dᵀ on the liquid cells, applied as two gathers: node velocities
/// from the pressures of the (at most 8) cells around each node, then cell divergences from
/// their 8 corners. Each output element is one fixed-order sum, so the result does not depend
/// on how the passes are split over threads.
struct ProjectionOperator<'a> {
    cells: &'a [[u32; 8]],
    nodes: &'a [ProjectionNode],
    /// Per node: Pᵢ where it is constrained (unused elsewhere).
    constraint: &'a [DMat3],
    /// Nodal velocity work vector.
    work: &'a mut Vec<DVec3>,
    /// Δx²/4: sₖ = (Δx²/4)(2k − 1).
    c: f64,
    /// On ranks: the exchanges with the neighbours, the node numbering, and the node layers
    /// of the shared columns whose sums the gradient completes (a mask of the local layers
    /// 0..4 along the axis).
    halo: Option<(&'a PressureHalo<'a>, &'a Numbering, u8)>,
}

/// Below this many elements a pass of the operator runs in the calling thread: a task scope
/// then costs more than it saves. Measured on the 2-core VM of BENCHMARKS.md (h) with
/// `game_keepup --projection`, 2 threads: at 2,744 cells the solve took 0.87–1.02 ms with
/// serial passes against 1.23–1.37 ms split over the pool; about even at 8,000 cells; at
/// 20,000 cells 11.0–13.4 ms split against 16.7–17.4 ms serial. The thread-count test of
/// `tests/it/pressure.rs` (about 12,800 cells) runs both passes on the pool.
const PARALLEL_MIN: usize = 8192;

/// `f(offset, chunk)` over consecutive chunks of `out`, on the `ComputeTaskPool` when it has
/// more than one thread and `out` is long enough; `f` must compute each element on its own.
fn for_each_chunk<T: Send>(out: &mut [T], f: impl Fn(usize, &mut [T]) + Sync) {
    let threads = ComputeTaskPool::try_get().map_or(1, |p| p.thread_num());
    let (len, parallel) = (
        out.len().div_ceil(threads).max(1),
        out.len() >= PARALLEL_MIN,
    );
    let items = out.chunks_mut(len).enumerate();
    for_each_item(parallel, items, |(t, chunk)| f(t * len, chunk));
}

impl ProjectionOperator<'_> {
    /// work = Δt P M⁻¹ P Dᵀ p: the velocity change of the pressures p. On ranks the sums
    /// Σ ±p over the cells around a node are completed with the neighbours' first
    /// ([`PressureHalo::sum_nodes`]).
    fn gradient(&mut self, p: &[f64]) {
        self.work.resize(self.nodes.len(), DVec3::ZERO);
        let (c, nodes, constraint) = (self.c, self.nodes, self.constraint);
        // Node n's velocity change from its sum g = Σ ±p.
        let finish = move |n: usize, g: DVec3| {
            let node = &nodes[n];
            let g = g * (c * node.scale);
            if node.constrained {
                constraint[n] * g
            } else {
                g
            }
        };
        let halo = self.halo;
        for_each_chunk(self.work, |first, out| {
            for (j, w) in out.iter_mut().enumerate() {
                let n = first + j;
                // Corner k = (kx, ky, kz) of CORNERS gets ±p of its cell per axis.
                let mut g = DVec3::ZERO;
                for (k, &cell) in nodes[n].cells.iter().enumerate() {
                    if cell != u32::MAX {
                        let q = p[cell as usize];
                        g.x += if k & 4 != 0 { q } else { -q };
                        g.y += if k & 2 != 0 { q } else { -q };
                        g.z += if k & 1 != 0 { q } else { -q };
                    }
                }
                *w = if halo.is_some() { g } else { finish(n, g) };
            }
        });
        if let Some((halo, corners, layers)) = halo {
            halo.sum_nodes(corners, self.work, layers);
            for_each_chunk(self.work, |first, out| {
                for (j, w) in out.iter_mut().enumerate() {
                    *w = finish(first + j, *w);
                }
            });
        }
    }

    /// y = D work.
    fn divergence(&self, y: &mut [f64]) {
        let (c, cells, work) = (self.c, self.cells, &**self.work);
        for_each_chunk(y, |first, out| {
            for (j, y) in out.iter_mut().enumerate() {
                let mut d = DVec3::ZERO;
                for (k, &n) in cells[first + j].iter().enumerate() {
                    let w = work[n as usize];
                    d.x += if k & 4 != 0 { w.x } else { -w.x };
                    d.y += if k & 2 != 0 { w.y } else { -w.y };
                    d.z += if k & 1 != 0 { w.z } else { -w.z };
                }
                *y = c * (d.x + d.y + d.z);
            }
        });
    }
}

impl LinearOperator for ProjectionOperator<'_> {
    fn dim(&self) -> usize {
        self.cells.len()
    }

    fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        self.gradient(x);
        self.divergence(y);
    }
}

const _: () = assert!(BLOCK_NODES == 64, "a slot's nodes are the bits of a u64");

/// Grid slots per task of the block loops that build the system and apply its solution (fixed,
/// so the tasks do not depend on the thread count; the loops compute each element on its own
/// anyway).
const SLOTS_PER_TASK: usize = 16;

/// The tasks of the block loops over `slots` grid slots: consecutive ranges of
/// [`SLOTS_PER_TASK`] slots.
fn slot_ranges(slots: usize) -> impl Iterator<Item = Range<usize>> + Clone {
    (0..slots.div_ceil(SLOTS_PER_TASK))
        .map(move |t| t * SLOTS_PER_TASK..((t + 1) * SLOTS_PER_TASK).min(slots))
}

/// A set of grid nodes (or of cells, named by their lower corner node) numbered in storage
/// order: bit o of `mask[s]` marks node o of slot s, and `start[s]` is the number of the first
/// marked node of slot s (`start[slots]` is their count). The numbers come from the masks, so
/// a block loop can name another block's nodes before that block's task has run.
#[derive(Debug, Default)]
struct Numbering {
    mask: Vec<u64>,
    start: Vec<u32>,
}

impl Numbering {
    /// Clears the marks of `slots` slots.
    fn reset(&mut self, slots: usize) {
        self.mask.clear();
        self.mask.resize(slots, 0);
    }

    /// Numbers the marked nodes; returns their count.
    fn number(&mut self) -> usize {
        self.start.clear();
        let mut n = 0u32;
        for &m in &self.mask {
            self.start.push(n);
            n += m.count_ones();
        }
        self.start.push(n);
        n as usize
    }

    /// Whether node `idx` (grid storage index) is marked.
    #[inline(always)]
    fn contains(&self, idx: usize) -> bool {
        self.mask[idx / BLOCK_NODES] >> (idx % BLOCK_NODES) & 1 != 0
    }

    /// The number of node `idx` (grid storage index), if it is marked.
    #[inline(always)]
    fn of(&self, idx: usize) -> Option<u32> {
        let (s, o) = (idx / BLOCK_NODES, idx % BLOCK_NODES);
        let m = self.mask[s];
        (m >> o & 1 != 0).then(|| self.start[s] + (m & ((1u64 << o) - 1)).count_ones())
    }

    /// How many marked nodes the slots `r` hold.
    fn span(&self, r: Range<usize>) -> usize {
        (self.start[r.end] - self.start[r.start]) as usize
    }
}

/// Masks over the 64 nodes of a block: bit o is local node o ([`local_coords`]: x-major, z
/// fastest).
mod bits {
    use glam::IVec3;

    /// The nodes with local z = 0, y = 0; z = 3, y = 3, x = 3.
    const Z0: u64 = 0x1111_1111_1111_1111;
    const Y0: u64 = 0x000F_000F_000F_000F;
    const Z3: u64 = 0x8888_8888_8888_8888;
    const Y3: u64 = 0xF000_F000_F000_F000;
    const X3: u64 = 0xFFFF_0000_0000_0000;

    /// Index of the block at offset `d` ∈ {−1, 0, 1}³ in
    /// [`MpmGrid::neighbour_slots`](crate::grid::MpmGrid::neighbour_slots).
    fn at(d: IVec3) -> usize {
        ((d.x + 1) * 9 + (d.y + 1) * 3 + (d.z + 1)) as usize
    }

    /// The cells (by lower corner) of a block with a corner in a block that is not allocated;
    /// `around` are its neighbour slots. A cell at local l has its corners in the block at
    /// offset d ∈ {0,1}³ only if l = 3 on every axis where d = 1.
    pub(super) fn incomplete(around: &[Option<usize>; 27]) -> u64 {
        let on = |d: i32, face: u64| if d == 1 { face } else { u64::MAX };
        (1..8)
            .map(|k| IVec3::new(k >> 2, (k >> 1) & 1, k & 1))
            .filter(|&d| around[at(d)].is_none())
            .fold(0, |out, d| out | (on(d.x, X3) & on(d.y, Y3) & on(d.z, Z3)))
    }

    /// The nodes of a block that are a corner of a cell marked in `masks` (per slot): the
    /// marks of this block and the 7 below it, dilated by one node up each axis (one axis
    /// after the other; a shift carries the top layer of the block below into the bottom one).
    pub(super) fn corners(around: &[Option<usize>; 27], masks: &[u64]) -> u64 {
        let m = |x: i32, y: i32, z: i32| around[at(IVec3::new(-x, -y, -z))].map_or(0, |s| masks[s]);
        let up_z = |x, y| {
            let (here, below) = (m(x, y, 0), m(x, y, 1));
            here | ((here << 1) & !Z0) | ((below >> 3) & Z0)
        };
        let up_y = |x| {
            let (here, below) = (up_z(x, 0), up_z(x, 1));
            here | ((here << 4) & !Y0) | ((below >> 12) & Y0)
        };
        let (here, below) = (up_y(0), up_y(1));
        here | (here << 16) | (below >> 48)
    }
}

/// Work storage of the projection, kept between steps (no allocation once the largest system
/// has been seen), and the last step's pressures for the warm start.
#[derive(Resource, Default)]
pub struct PressureScratch {
    /// Per grid node: Σ mₚ and Σ mₚ/ρ₀ₚ of the particles in the cell with this lower corner.
    cell_volume: Vec<(f64, f64)>,
    /// Per grid slot: its 27 neighbour slots ([`MpmGrid::neighbour_slots`]) and first node.
    slots: Vec<([Option<usize>; 27], IVec3)>,
    /// The liquid cells (the unknowns), by lower corner.
    liquid: Numbering,
    /// The projection's nodes: the liquid cells' corners.
    corners: Numbering,
    /// Per liquid cell: its corners' node numbers, k in [`CORNERS`] order.
    cells: Vec<[u32; 8]>,
    /// Dense layout key of each liquid cell (for the warm start).
    keys: Vec<usize>,
    nodes: Vec<ProjectionNode>,
    /// Per node: its Pᵢ where constrained.
    constraint: Vec<DMat3>,
    rhs: Vec<f64>,
    pressure: Vec<f64>,
    residual: Vec<f64>,
    correction: Vec<f64>,
    work: Vec<DVec3>,
    jacobi: JacobiPreconditioner,
    cg: CgScratch,
    /// The last solve's (dense cell key, pressure), sorted by key.
    previous: Vec<(usize, f64)>,
    /// On ranks: the partition of the last solve (halo module's hand-over).
    last_partition: Option<crate::distributed::Partition>,
}

impl PressureScratch {
    /// The cell pressures of the last solve \[Pa\], with the world position of each cell's
    /// centre (for output and tests).
    pub fn cell_pressures(&self, grid: &MpmGrid) -> Vec<(Vec3, f64)> {
        let l = &grid.layout;
        self.previous
            .iter()
            .map(|&(key, p)| {
                let c = l.node_of_index(key);
                (l.node_position(c) + Vec3::splat(0.5 * l.dx), p)
            })
            .collect()
    }
}

/// S11 (end): projects the updated grid velocities vᵢⁿ⁺¹ so that the liquid cells keep their
/// volume (module docs), and adds the pressure acceleration to aᵢⁿ⁺¹. Runs after the grid
/// update of the first-order schemes when [`pressure_projection_step`] holds.
///
/// The cell volumes are one serial pass over the particles; the liquid cells and their
/// corners are per-block bit masks (a few word operations per block); building the system and
/// updating the velocities run block by block on the task pool.
///
/// Reads the particles' positions, masses and materials, `MpmGrid`, colliders; writes `MpmGrid` (new velocity, new acceleration),
/// [`PressureSolveStats`]; records a failure if CG fails.
#[expect(
    clippy::too_many_arguments,
    reason = "a Bevy system: each parameter is a resource or query it reads"
)]
pub fn project_pressure(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    materials: Res<Materials>,
    colliders: Res<ActiveColliders>,
    failures: Res<FailureCollector>,
    mut grid: ResMut<MpmGrid>,
    mut scratch: ResMut<PressureScratch>,
    mut stats: ResMut<PressureSolveStats>,
    particles: Query<(&Position, &Mass, &MaterialId), With<Particle>>,
    ranks: Option<Res<Ranks>>,
) {
    let Some(settings) = config.integrator.pressure.projection() else {
        return;
    };
    let dt = ctx.dt;
    if dt <= 0.0 {
        return;
    }
    let PressureScratch {
        cell_volume,
        slots,
        liquid,
        corners,
        cells,
        keys,
        nodes,
        constraint,
        rhs,
        pressure,
        residual,
        correction,
        work,
        jacobi,
        cg,
        previous,
        last_partition,
    } = &mut *scratch;
    let grid = &mut *grid;
    let layout = grid.layout;
    let dx = layout.dx as f64;
    let ranks = ranks.as_deref().filter(|r| r.size() > 1);
    let reduce = RankReduction(ranks);
    let mut halo = ranks.map(|r| PressureHalo::new(r, grid));

    // Liquid cells: the cells holding particles, with their particles' rest volume (one
    // serial pass in query order: a parallel scatter would need the particles gathered into
    // block order first, which costs more than this pass on the machines measured).
    let slot_count = grid.block_count();
    let parallel = slot_count > SLOTS_PER_TASK;
    cell_volume.clear();
    cell_volume.resize(grid.nodes.len(), (0.0, 0.0));
    liquid.reset(slot_count);
    for (x, m, mat) in particles.iter() {
        let r = (x.0 - layout.origin) * layout.inv_dx;
        let c = IVec3::new(fast_floor(r.x), fast_floor(r.y), fast_floor(r.z));
        if let Some(i) = grid.index(c) {
            let v = &mut cell_volume[i];
            v.0 += m.0 as f64;
            v.1 += (m.0 / materials.get(*mat).density) as f64;
            liquid.mask[i / BLOCK_NODES] |= 1 << (i % BLOCK_NODES);
        }
    }
    // Per block: its neighbours; its liquid cells kept where all corners are allocated; the
    // cells' corners, the liquid cells dilated by one node up each axis.
    slots.clear();
    slots.extend((0..slot_count).map(|s| (grid.neighbour_slots(s), grid.slot_origin(s))));
    if let Some(h) = &halo {
        h.exchange_cells(&mut liquid.mask, cell_volume, slots, grid);
    }
    let mut missing_corners = 0;
    for (mask, (around, _)) in liquid.mask.iter_mut().zip(slots.iter()) {
        let incomplete = bits::incomplete(around);
        missing_corners += (*mask & incomplete).count_ones();
        *mask &= !incomplete;
    }
    corners.reset(slot_count);
    for (mask, (around, _)) in corners.mask.iter_mut().zip(slots.iter()) {
        *mask = bits::corners(around, &liquid.mask);
    }
    if let Some(h) = &mut halo {
        h.exchange_corners(&mut corners.mask, grid);
    }
    // P2G allocates every node of a particle's stencil, which holds the corners of its cell:
    // a cell without one would be a broken grid, not a solvable case.
    if missing_corners > 0 {
        failures.record(FailureReport::global(
            "pressure cells",
            missing_corners as f64,
            format!(
                "{missing_corners} liquid cells have a corner node the grid did not allocate, so \
                 the pressure projection cannot hold their volume (an internal error: please \
                 report it with the scene)"
            ),
        ));
    }
    let n = liquid.number();
    let node_count = corners.number();
    // On ranks every rank goes on while any has cells (the solve's collectives).
    let total = reduce.sum(n as f64) as usize;
    stats.0.unknowns = total;
    if total == 0 {
        previous.clear();
        return;
    }
    if let Some(h) = &halo {
        h.hand_over_pressures(previous, last_partition, &layout);
    }

    // The system, block by block: per node its cells, Δt/mᵢ and boundary projector; per cell
    // its corners, right-hand side, key and warm start (the last step's pressure).
    let mirrors = mirror_faces(&config, &layout);
    let mut mirrored = [[false; 2]; 3];
    for f in &mirrors {
        mirrored[f.axis][f.upper as usize] = true;
    }
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let eps = grid.mass_epsilon;
    let s: [DVec3; 8] = CORNERS.map(|k| (2 * k - IVec3::ONE).as_dvec3() * (0.25 * dx * dx));
    let relax = 1.0 / settings.volume_relaxation.max(dt);
    cells.resize(n, [0; 8]);
    keys.resize(n, 0);
    rhs.resize(n, 0.0);
    pressure.resize(n, 0.0);
    nodes.resize(node_count, ProjectionNode::default());
    constraint.resize(node_count, DMat3::IDENTITY);
    {
        let (grid, cell_volume, slots, liquid, corners) =
            (&*grid, &*cell_volume, &*slots, &*liquid, &*corners);
        let (walls, colliders, previous) = (&config.walls, &colliders.list, &*previous);
        let cell_lens = slot_ranges(slot_count).map(|r| liquid.span(r));
        let node_lens = slot_ranges(slot_count).map(|r| corners.span(r));
        let items = slot_ranges(slot_count)
            .zip(split_lens(cells, cell_lens.clone()))
            .zip(split_lens(keys, cell_lens.clone()))
            .zip(split_lens(rhs, cell_lens.clone()))
            .zip(split_lens(pressure, cell_lens))
            .zip(split_lens(nodes, node_lens.clone()))
            .zip(split_lens(constraint, node_lens));
        for_each_item(parallel, items, |item| {
            let ((((((range, cells), keys), rhs), pressure), nodes), constraint) = item;
            let (mut next_cell, mut next_node) = (0, 0);
            for slot in range {
                let (around, origin) = &slots[slot];
                let first = slot * BLOCK_NODES;
                // The marked nodes and cells of the block, in storage order.
                let mut todo = corners.mask[slot] | liquid.mask[slot];
                while todo != 0 {
                    let o = todo.trailing_zeros() as usize;
                    todo &= todo - 1;
                    let l = local_coords(o);
                    if corners.contains(first + o) {
                        let node = &grid.nodes[first + o];
                        let x = layout.node_position(*origin + l);
                        let v = Vec3::from(node.new_velocity).as_dvec3();
                        let free = classify(x, walls, mirrored, dmin, dmax, colliders, v, |w| w);
                        let out = &mut nodes[next_node];
                        out.scale = if node.mass > eps {
                            dt / node.mass as f64
                        } else {
                            0.0
                        };
                        out.constrained = free.is_some();
                        if let Some((p, _)) = free {
                            constraint[next_node] = p;
                        }
                        for (k, off) in CORNERS.iter().enumerate() {
                            out.cells[k] = MpmGrid::neighbour_index(around, l, -*off)
                                .and_then(|i| liquid.of(i))
                                .unwrap_or(u32::MAX);
                        }
                        next_node += 1;
                    }
                    if !liquid.contains(first + o) {
                        continue;
                    }
                    let (mass, rest) = cell_volume[first + o];
                    let mut div = 0.0;
                    let mut corner_mass = 0.0;
                    for (k, off) in CORNERS.iter().enumerate() {
                        // A liquid cell has all corners allocated, and they are marked.
                        let ni = MpmGrid::neighbour_index(around, l, *off).unwrap_or(first);
                        let node = &grid.nodes[ni];
                        cells[next_cell][k] = corners.of(ni).unwrap_or(u32::MAX);
                        corner_mass += node.mass as f64;
                        div += s[k].dot(Vec3::from(node.new_velocity).as_dvec3());
                    }
                    // The cell's fill: the mean of its corners' B-spline masses over ρ₀Δx³ (1
                    // in a liquid at rest, whatever the particles' jitter), with ρ₀ that of
                    // its particles. An overfull cell is asked to expand; a partly filled one
                    // (the surface, a splash) is left alone.
                    let fill = 0.125 * corner_mass * rest / (mass * dx.powi(3));
                    let target = dx.powi(3) * fill.ln().max(0.0) * relax;
                    let key = layout.index(*origin + l);
                    keys[next_cell] = key;
                    rhs[next_cell] = target - div;
                    pressure[next_cell] = previous
                        .binary_search_by_key(&key, |e| e.0)
                        .map_or(0.0, |j| previous[j].1);
                    next_cell += 1;
                }
            }
        });
    }

    // Jacobi diagonal.
    jacobi.inverse_diagonal.resize(n, 0.0);
    {
        let (cells, nodes, constraint) = (&*cells, &*nodes, &*constraint);
        for_each_chunk(&mut jacobi.inverse_diagonal, |first, out| {
            for (j, inv) in out.iter_mut().enumerate() {
                let d: f64 = cells[first + j]
                    .iter()
                    .enumerate()
                    .map(|(k, &nd)| {
                        let node = &nodes[nd as usize];
                        let sk = if node.constrained {
                            constraint[nd as usize] * s[k]
                        } else {
                            s[k]
                        };
                        s[k].dot(sk) * node.scale
                    })
                    .sum::<f64>();
                *inv = if d > 0.0 { 1.0 / d } else { 0.0 };
            }
        });
    }

    // Δt A p = b: CG on the correction from the warm start.
    let mut op = ProjectionOperator {
        cells,
        nodes,
        constraint,
        work,
        c: 0.25 * dx * dx,
        // In the solve the cells of two ranks meet on the shared columns' first two node
        // layers only (halo module docs).
        halo: halo.as_ref().map(|h| (h, &*corners, 0b0011)),
    };
    let b_norm = ResidualNorm::Euclidean.reduced(rhs, &reduce);
    residual.clear();
    residual.resize(n, 0.0);
    op.apply(pressure, residual);
    for (r, b) in residual.iter_mut().zip(rhs.iter()) {
        *r = b - *r;
    }
    let params = settings.solver;
    let tol = params.abs_tol.max(params.rel_tol * b_norm);
    let inner = CgParams {
        rel_tol: 0.0,
        abs_tol: tol,
        max_iters: params.max_iters,
    };
    correction.clear();
    correction.resize(n, 0.0);
    let result = if ResidualNorm::Euclidean.reduced(residual, &reduce) <= tol {
        Ok(CgInfo::default())
    } else {
        let norm = ResidualNorm::Euclidean;
        conjugate_gradient_reduced(
            &mut op, jacobi, residual, correction, &inner, norm, cg, &reduce,
        )
    };
    if correction.iter().all(|c| c.is_finite()) {
        for (p, c) in pressure.iter_mut().zip(correction.iter()) {
            *p += c;
        }
    }
    let (info, error) = CgInfo::of_result(result, b_norm);
    if let Some(e) = error {
        failures.record(FailureReport::global(
            "pressure solve",
            info.rel_residual,
            format!(
                "the pressure projection ({total} liquid cells) failed after {} conjugate-gradient \
                 iterations (relative residual {:.3e}): {e}. To fix: raise \
                 integrator.pressure.solver.max_iters (now {}) or rel_tol (now {:.1e}), or take \
                 smaller steps (time_step.safety, max_dt)",
                info.iterations, info.rel_residual, params.max_iters, params.rel_tol,
            ),
        ));
    }
    let st = &mut stats.0;
    st.solves += 1;
    st.iterations += info.iterations as u64;
    st.max_iterations = st.max_iterations.max(info.iterations);
    st.last = info;

    // vᵢ = v*ᵢ + Δt Pᵢ(Dᵀp)ᵢ/mᵢ on the liquid cells' nodes; the other nodes with mass (within
    // a particle's B-spline reach, at most one node from a liquid cell) get the mean correction
    // of their projected neighbours, so that G2P does not mix unprojected velocities into the
    // surface particles. Then the collision rule once more (a node the correction turned
    // into a wall it was leaving). Block by block: each node reads the corrections only.
    // On ranks, over the whole shared columns: a node there without a pressure of its own takes
    // its neighbours' corrections (halo module docs).
    op.halo = op.halo.map(|(h, c, _)| (h, c, 0b1111));
    op.gradient(pressure);
    let work = &*op.work;
    {
        let (slots, corners, nodes) = (&*slots, &*corners, &*nodes);
        let (walls, colliders) = (&config.walls, &colliders.list);
        // The correction of grid node i, if it is a projection node with mass.
        let correction_of = |i: usize| -> Option<DVec3> {
            let c = corners.of(i)? as usize;
            (nodes[c].scale > 0.0).then(|| work[c])
        };
        // On ranks, the means of the nodes around the shared columns, formed alike on both
        // ranks (halo module docs).
        let band = halo
            .as_ref()
            .map(|h| h.band_means(grid, corners, |c| (nodes[c].scale > 0.0).then(|| work[c])));
        let band = band.as_ref();
        let items =
            slot_ranges(slot_count).zip(grid.nodes.chunks_mut(SLOTS_PER_TASK * BLOCK_NODES));
        for_each_item(parallel, items, |(range, chunk)| {
            for (s, block) in range.zip(chunk.chunks_mut(BLOCK_NODES)) {
                let (around, origin) = &slots[s];
                for (o, node) in block.iter_mut().enumerate() {
                    if node.mass <= eps {
                        continue;
                    }
                    let l = local_coords(o);
                    let dv = match corners.of(s * BLOCK_NODES + o) {
                        Some(c) => work[c as usize],
                        None if band.is_some_and(|b| b.0[s] >> o & 1 != 0) => {
                            match band.and_then(|b| b.1.get(&(s * BLOCK_NODES + o))) {
                                Some(&mean) => mean,
                                None => continue,
                            }
                        }
                        None => {
                            let (mut sum, mut count) = (DVec3::ZERO, 0u32);
                            for d in NEIGHBOURS {
                                if let Some(dv) =
                                    MpmGrid::neighbour_index(around, l, d).and_then(correction_of)
                                {
                                    sum += dv;
                                    count += 1;
                                }
                            }
                            if count == 0 {
                                continue;
                            }
                            sum / count as f64
                        }
                    };
                    let x = layout.node_position(*origin + l);
                    let mut v = Vec3::from(node.new_velocity) + dv.as_vec3();
                    let mut a = Vec3::from(node.new_acceleration) + (dv / dt).as_vec3();
                    collide_node(x, 0.0, walls, dmin, dmax, colliders, &mut v, &mut a);
                    node.new_velocity = v.into();
                    node.new_acceleration = a.into();
                }
            }
        });
    }
    if let Some(h) = &halo {
        h.copy_edge_layers(grid);
    }
    copy_ghosts(&config, grid, GhostCopy::Update);

    previous.clear();
    previous.extend(keys.iter().copied().zip(pressure.iter().copied()));
    previous.sort_unstable_by_key(|e| e.0);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The word operations of [`bits`] against the node-by-node definitions, on random marks
    /// around a block whose neighbours are allocated at random.
    #[test]
    fn block_masks_match_the_node_by_node_definitions() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut random = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let block = |d: IVec3| ((d.x + 1) * 9 + (d.y + 1) * 3 + (d.z + 1)) as usize;
        for _ in 0..200 {
            // Slot k of `masks` is the block at offset k of `neighbour_slots`; sparse marks.
            let masks: Vec<u64> = (0..27).map(|_| random() & random() & random()).collect();
            let presence = random();
            let around: [Option<usize>; 27] =
                std::array::from_fn(|k| (k == 13 || presence >> k & 1 != 0).then_some(k));
            let marked = |c: IVec3| {
                let d = c.div_euclid(IVec3::splat(4));
                around[block(d)].is_some_and(|s| {
                    masks[s] >> crate::grid::local_offset(c.rem_euclid(IVec3::splat(4))) & 1 != 0
                })
            };
            let (mut corners, mut incomplete) = (0u64, 0u64);
            for o in 0..BLOCK_NODES {
                let l = local_coords(o);
                if CORNERS.iter().any(|&k| marked(l - k)) {
                    corners |= 1 << o;
                }
                if CORNERS
                    .iter()
                    .any(|&k| around[block((l + k) >> 2)].is_none())
                {
                    incomplete |= 1 << o;
                }
            }
            assert_eq!(bits::corners(&around, &masks), corners);
            assert_eq!(bits::incomplete(&around), incomplete);
        }
    }
}
