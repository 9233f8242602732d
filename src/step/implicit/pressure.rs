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
//! Cells and nodes are listed in grid storage order. The operator's two passes compute each
//! node and each cell as one sum in a fixed order (split over the task pool for large
//! systems); every other pass and every inner product is serial in storage order, so results
//! are bit-identical for any thread count.
use bevy_ecs::prelude::*;
use bevy_tasks::ComputeTaskPool;
use glam::{DMat3, DVec3, IVec3};

use super::ImplicitSolveStats;
use super::viscous::classify;
use crate::components::{Mass, Particle, Position};
use crate::config::MpmConfig;
use crate::failure::{FailureCollector, FailureReport};
use crate::grid::{BLOCK_NODES, GhostCopy, MpmGrid, local_coords};
use crate::krylov::{
    CgInfo, CgParams, CgScratch, JacobiPreconditioner, LinearOperator, conjugate_gradient,
};
use crate::material::{MaterialId, Materials};
use crate::math::Vec3;
use crate::step::grid_update::collide_node;
use crate::step::p2g::{copy_ghosts, mirror_faces};
use crate::step::schedule::{ActiveColliders, StepContext};

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

/// No projector: the node moves freely (Pᵢ = I).
const FREE: u32 = u32::MAX;

/// The operator Δt D P M⁻¹ P Dᵀ on the liquid cells, applied as two gathers: node velocities
/// from the pressures of the (at most 8) cells around each node, then cell divergences from
/// their 8 corners. Nodes are compact indices into `scale` (Δt/mᵢ, 0 for a node without mass:
/// it does not move) and `projector` (an index into `constrained`, the nodes a wall or collider
/// constrains with their Pᵢ, or [`FREE`]). Each output element is one fixed-order sum, so the
/// result does not depend on how the passes are split over threads.
struct ProjectionOperator<'a> {
    cells: &'a [[u32; 8]],
    /// Per compact node: the cell it is corner k of, for k = 0..8 (u32::MAX: none).
    node_cells: &'a [[u32; 8]],
    scale: &'a [f64],
    projector: &'a [u32],
    constrained: &'a [(u32, DMat3)],
    /// Nodal velocity work vector.
    work: &'a mut Vec<DVec3>,
    /// Δx²/4: sₖ = (Δx²/4)(2k − 1).
    c: f64,
}

/// Below this many elements a pass runs in the calling thread (a task scope costs more). At
/// 2,048 the quasi-2D dam break of `tests/it/pressure.rs` (about 3,200 cells and 4,300 nodes)
/// runs both passes on the pool, which its thread-count test checks.
const PARALLEL_MIN: usize = 2048;

/// `f(offset, chunk)` over consecutive chunks of `out`, on the `ComputeTaskPool` when it has
/// more than one thread and `out` is long enough; `f` must compute each element on its own.
fn for_each_chunk<T: Send>(out: &mut [T], f: impl Fn(usize, &mut [T]) + Sync) {
    match ComputeTaskPool::try_get().filter(|p| p.thread_num() > 1 && out.len() >= PARALLEL_MIN) {
        Some(pool) => {
            let len = out.len().div_ceil(pool.thread_num());
            pool.scope(|scope| {
                for (t, chunk) in out.chunks_mut(len).enumerate() {
                    let f = &f;
                    scope.spawn(async move { f(t * len, chunk) });
                }
            });
        }
        None => f(0, out),
    }
}

impl ProjectionOperator<'_> {
    /// work = Δt P M⁻¹ P Dᵀ p: the velocity change of the pressures p.
    fn gradient(&mut self, p: &[f64]) {
        self.work.resize(self.scale.len(), DVec3::ZERO);
        let (c, node_cells, scale) = (self.c, self.node_cells, self.scale);
        let (projector, constrained) = (self.projector, self.constrained);
        for_each_chunk(self.work, |first, out| {
            for (j, w) in out.iter_mut().enumerate() {
                let n = first + j;
                // Corner k = (kx, ky, kz) of CORNERS gets ±p of its cell per axis.
                let mut g = DVec3::ZERO;
                for (k, &cell) in node_cells[n].iter().enumerate() {
                    if cell != u32::MAX {
                        let q = p[cell as usize];
                        g.x += if k & 4 != 0 { q } else { -q };
                        g.y += if k & 2 != 0 { q } else { -q };
                        g.z += if k & 1 != 0 { q } else { -q };
                    }
                }
                g *= c * scale[n];
                *w = match projector[n] {
                    FREE => g,
                    i => constrained[i as usize].1 * g,
                };
            }
        });
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

/// Work storage of the projection, kept between steps (no allocation once the largest system
/// has been seen), and the last step's pressures for the warm start.
#[derive(Resource, Default)]
pub struct PressureScratch {
    /// Per grid node: Σ mₚ and Σ mₚ/ρ₀ₚ of the particles in the cell with this min-corner node.
    cell_volume: Vec<(f64, f64)>,
    /// Grid node → compact node (u32::MAX: none).
    node_map: Vec<u32>,
    cells: Vec<[u32; 8]>,
    /// Per compact node: the liquid cell it is corner k of (u32::MAX: none).
    node_cells: Vec<[u32; 8]>,
    /// Dense layout key of each liquid cell (for the warm start).
    keys: Vec<usize>,
    /// Per compact node: grid storage index, world position.
    nodes: Vec<(usize, Vec3)>,
    /// Per compact node: Δt/mᵢ (0 without mass).
    scale: Vec<f64>,
    /// Per compact node: index into `constrained`, or [`FREE`].
    projector: Vec<u32>,
    /// The constrained compact nodes and their Pᵢ.
    constrained: Vec<(u32, DMat3)>,
    rhs: Vec<f64>,
    pressure: Vec<f64>,
    residual: Vec<f64>,
    correction: Vec<f64>,
    /// The other nodes with mass: (storage index, position, extrapolated correction).
    outer: Vec<(usize, Vec3, DVec3)>,
    work: Vec<DVec3>,
    jacobi: JacobiPreconditioner,
    cg: CgScratch,
    /// The last solve's (dense cell key, pressure), sorted by key.
    previous: Vec<(usize, f64)>,
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
/// Reads the particles' positions, masses, densities and materials, `MpmGrid`, colliders;
/// writes `MpmGrid` (new velocity, new acceleration), [`PressureSolveStats`]; records a failure
/// if CG fails.
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
) {
    let Some(settings) = config.integrator.pressure.projection() else {
        return;
    };
    let dt = ctx.dt;
    if dt <= 0.0 {
        return;
    }
    let scratch = &mut *scratch;
    let grid = &mut *grid;
    let layout = grid.layout;
    let dx = layout.dx as f64;

    // Liquid cells: the cells holding particles, with their particles' rest volume.
    scratch.cell_volume.clear();
    scratch.cell_volume.resize(grid.nodes.len(), (0.0, 0.0));
    for (x, m, mat) in particles.iter() {
        let r = (x.0 - layout.origin) * layout.inv_dx;
        let c = IVec3::new(
            crate::math::fast_floor(r.x),
            crate::math::fast_floor(r.y),
            crate::math::fast_floor(r.z),
        );
        if let Some(i) = grid.index(c) {
            let v = &mut scratch.cell_volume[i];
            v.0 += m.0 as f64;
            v.1 += (m.0 / materials.get(*mat).density) as f64;
        }
    }
    scratch.node_map.clear();
    scratch.node_map.resize(grid.nodes.len(), u32::MAX);
    scratch.cells.clear();
    scratch.node_cells.clear();
    scratch.keys.clear();
    scratch.nodes.clear();
    scratch.scale.clear();
    scratch.projector.clear();
    scratch.constrained.clear();
    scratch.rhs.clear();
    let mirrors = mirror_faces(&config, &layout);
    let mut mirrored = [[false; 2]; 3];
    for f in &mirrors {
        mirrored[f.axis][f.upper as usize] = true;
    }
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let eps = grid.mass_epsilon;
    let s: [DVec3; 8] = CORNERS.map(|k| (2 * k - IVec3::ONE).as_dvec3() * (0.25 * dx * dx));
    let relax = 1.0 / settings.volume_relaxation.max(dt);
    let mut missing_corners = 0usize;
    // Block by block (storage order), corners found through the block's neighbour slots
    // instead of a table lookup each.
    for slot in 0..grid.block_count() {
        let first = slot * BLOCK_NODES;
        if scratch.cell_volume[first..first + BLOCK_NODES]
            .iter()
            .all(|v| v.1 <= 0.0)
        {
            continue;
        }
        let around = grid.neighbour_slots(slot);
        let origin = grid.slot_origin(slot);
        for o in 0..BLOCK_NODES {
            let (mass, rest) = scratch.cell_volume[first + o];
            if rest <= 0.0 {
                continue;
            }
            let l = local_coords(o);
            let mut corners = [0u32; 8];
            let mut div = 0.0;
            let mut corner_mass = 0.0;
            let mut complete = true;
            for (k, off) in CORNERS.iter().enumerate() {
                let Some(ni) = MpmGrid::neighbour_index(&around, l, *off) else {
                    complete = false;
                    break;
                };
                let node = &grid.nodes[ni];
                if scratch.node_map[ni] == u32::MAX {
                    let x = layout.node_position(origin + l + *off);
                    let v = Vec3::from(node.new_velocity).as_dvec3();
                    let n = scratch.nodes.len() as u32;
                    let free = classify(
                        x,
                        &config.walls,
                        mirrored,
                        dmin,
                        dmax,
                        &colliders.list,
                        v,
                        |w| w,
                    );
                    scratch.projector.push(match free {
                        Some((p, _)) => {
                            scratch.constrained.push((n, p));
                            scratch.constrained.len() as u32 - 1
                        }
                        None => FREE,
                    });
                    scratch.node_map[ni] = n;
                    scratch.nodes.push((ni, x));
                    scratch.node_cells.push([u32::MAX; 8]);
                    scratch.scale.push(if node.mass > eps {
                        dt / node.mass as f64
                    } else {
                        0.0
                    });
                }
                corners[k] = scratch.node_map[ni];
                corner_mass += node.mass as f64;
                div += s[k].dot(Vec3::from(node.new_velocity).as_dvec3());
            }
            if !complete {
                missing_corners += 1;
                continue;
            }
            // The cell's fill: the mean of its corners' B-spline masses over ρ₀Δx³ (1 in a
            // liquid at rest, whatever the particles' jitter), with ρ₀ that of its particles.
            // An overfull cell is asked to expand; a partly filled one (the surface, a
            // splash) is left alone.
            let fill = 0.125 * corner_mass * rest / (mass * dx.powi(3));
            let target = dx.powi(3) * fill.ln().max(0.0) * relax;
            let cell = scratch.cells.len() as u32;
            for (k, &n) in corners.iter().enumerate() {
                scratch.node_cells[n as usize][k] = cell;
            }
            scratch.cells.push(corners);
            scratch.keys.push(layout.index(origin + l));
            scratch.rhs.push(target - div);
        }
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
    let n = scratch.cells.len();
    stats.0.unknowns = n;
    if n == 0 {
        scratch.previous.clear();
        return;
    }

    // Warm start from the last step's pressures, Jacobi diagonal.
    scratch.pressure.clear();
    scratch.pressure.extend(scratch.keys.iter().map(|k| {
        scratch
            .previous
            .binary_search_by_key(k, |e| e.0)
            .map_or(0.0, |j| scratch.previous[j].1)
    }));
    scratch.jacobi.inverse_diagonal.clear();
    scratch
        .jacobi
        .inverse_diagonal
        .extend(scratch.cells.iter().map(|corners| {
            let d: f64 = corners
                .iter()
                .enumerate()
                .map(|(k, &nd)| {
                    let sk = match scratch.projector[nd as usize] {
                        FREE => s[k],
                        j => scratch.constrained[j as usize].1 * s[k],
                    };
                    s[k].dot(sk) * scratch.scale[nd as usize]
                })
                .sum::<f64>();
            if d > 0.0 { 1.0 / d } else { 0.0 }
        }));

    // Δt A p = b: CG on the correction from the warm start.
    let mut op = ProjectionOperator {
        cells: &scratch.cells,
        node_cells: &scratch.node_cells,
        scale: &scratch.scale,
        projector: &scratch.projector,
        constrained: &scratch.constrained,
        work: &mut scratch.work,
        c: 0.25 * dx * dx,
    };
    let b_norm = crate::krylov::dot(&scratch.rhs, &scratch.rhs).sqrt();
    let residual = &mut scratch.residual;
    residual.clear();
    residual.resize(n, 0.0);
    op.apply(&scratch.pressure, residual);
    for (r, b) in residual.iter_mut().zip(&scratch.rhs) {
        *r = b - *r;
    }
    let params = settings.solver;
    let tol = params.abs_tol.max(params.rel_tol * b_norm);
    let inner = CgParams {
        rel_tol: 0.0,
        abs_tol: tol,
        max_iters: params.max_iters,
    };
    let correction = &mut scratch.correction;
    correction.clear();
    correction.resize(n, 0.0);
    let result = if crate::krylov::dot(residual, residual).sqrt() <= tol {
        Ok(CgInfo::default())
    } else {
        conjugate_gradient(
            &mut op,
            &mut scratch.jacobi,
            residual,
            correction,
            &inner,
            &mut scratch.cg,
        )
    };
    if correction.iter().all(|c| c.is_finite()) {
        for (p, c) in scratch.pressure.iter_mut().zip(correction.iter()) {
            *p += c;
        }
    }
    let (info, error) = CgInfo::of_result(result, b_norm);
    if let Some(e) = error {
        failures.record(FailureReport::global(
            "pressure solve",
            info.rel_residual,
            format!(
                "the pressure projection ({n} liquid cells) failed after {} conjugate-gradient \
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
    // into a wall it was leaving).
    op.gradient(&scratch.pressure);
    let work = &*op.work;
    let (node_map, scale) = (&scratch.node_map, &scratch.scale);
    // The correction of grid node j, if it is a projected node with mass.
    let correction_of = |j: usize| -> Option<DVec3> {
        let c = node_map[j];
        (c != u32::MAX && scale[c as usize] > 0.0).then(|| work[c as usize])
    };
    scratch.outer.clear();
    for slot in 0..grid.block_count() {
        let first = slot * BLOCK_NODES;
        let outer = |i: usize| grid.nodes[i].mass > eps && node_map[i] == u32::MAX;
        if !(first..first + BLOCK_NODES).any(outer) {
            continue;
        }
        let around = grid.neighbour_slots(slot);
        let origin = grid.slot_origin(slot);
        for o in 0..BLOCK_NODES {
            let i = first + o;
            if !outer(i) {
                continue;
            }
            let l = local_coords(o);
            let (mut sum, mut count) = (DVec3::ZERO, 0u32);
            for d in NEIGHBOURS {
                if let Some(dv) = MpmGrid::neighbour_index(&around, l, d).and_then(correction_of) {
                    sum += dv;
                    count += 1;
                }
            }
            if count > 0 {
                let x = layout.node_position(origin + l);
                scratch.outer.push((i, x, sum / count as f64));
            }
        }
    }
    let walls = config.walls;
    let updates = scratch
        .nodes
        .iter()
        .zip(work.iter())
        .zip(scale)
        .filter(|(_, f)| **f > 0.0)
        .map(|((&(idx, x), dv), _)| (idx, x, *dv))
        .chain(scratch.outer.iter().copied());
    for (idx, x, dv) in updates {
        let node = &mut grid.nodes[idx];
        let mut v = Vec3::from(node.new_velocity) + dv.as_vec3();
        let mut a = Vec3::from(node.new_acceleration) + (dv / dt).as_vec3();
        collide_node(x, 0.0, &walls, dmin, dmax, &colliders.list, &mut v, &mut a);
        node.new_velocity = v.into();
        node.new_acceleration = a.into();
    }
    copy_ghosts(&config, grid, GhostCopy::Update);

    scratch.previous.clear();
    scratch.previous.extend(
        scratch
            .keys
            .iter()
            .copied()
            .zip(scratch.pressure.iter().copied()),
    );
    scratch.previous.sort_unstable_by_key(|e| e.0);
}
