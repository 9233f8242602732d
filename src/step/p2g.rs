//! S2–S3: particle-to-grid transfer at the predicted positions (ALGORITHM §2.5, eq. 31):
//! m̃ᵢ = Σ mₚw̃ᵢₚ, vᵢ = Σ mₚw̃ᵢₚvₚ / m̃ᵢ, aᵢ = Σ mₚw̃ᵢₚaₚ / m̃ᵢ (mass-normalised, active where
//! m̃ᵢ > m_ε). Free-slip faces on a node plane are mirrors (§2.11, choice D18): the nodes
//! beyond them are folded onto their images and become reflected copies.
//!
//! The grid is block-sparse (§11): this system allocates the blocks the stencils reach and
//! scatters through [`BlockPlan`] (particles ordered by block, colour phases, deterministic).
//!
//! Reads `ParticleStencil`, `Mass`, `Velocity`, `Acceleration`; writes `MpmGrid` (the
//! allocated blocks; mass, velocity, acceleration, the rest zero), [`BlockPlan`]. Symplectic
//! Euler steps leave aᵢ at zero: nothing of theirs reads it.
use bevy_ecs::prelude::*;

use crate::components::{Acceleration, Mass, Particle, ParticleStencil, Velocity};
use crate::config::{BoundaryCondition, MpmConfig, Scheme};
use crate::distributed::{HaloFields, Ranks};
use crate::grid::{
    Fold, GhostCopy, GridLayout, GridNode, MirrorFace, MpmGrid, NodeBox, image_closure,
};
use crate::kernels::{p2g_stencil, p2g_stencil_momentum};
use crate::scatter::{BlockPlan, QueryRows, SharedMut};
use crate::step::grid_update::{for_each_active_row, for_each_active_row_indexed, on_domain_face};
use crate::step::schedule::StepContext;
use glam::IVec3;

/// One table's columns of [`particle_to_grid`].
#[derive(Clone, Copy)]
pub struct P2gColumns {
    m: SharedMut<Mass>,
    v: SharedMut<Velocity>,
    a: SharedMut<Acceleration>,
}

/// Allocates the blocks the particle stencils reach (and their periodic and mirror images),
/// scatters mass, momentum and m·a block by block, folds the ghosts and normalises.
#[allow(clippy::too_many_arguments)]
pub fn particle_to_grid(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    mut grid: ResMut<MpmGrid>,
    mut plan: ResMut<BlockPlan>,
    ranks: Option<Res<Ranks>>,
    mut keys: Local<Vec<u32>>,
    mut rows: Local<QueryRows<P2gColumns>>,
    q: Query<(&ParticleStencil, &Mass, &Velocity, &Acceleration), With<Particle>>,
) {
    let grid = &mut *grid;
    let layout = grid.layout;
    // m_ε: 1e-10 of the smallest particle mass (§2.5); the stencils' reach (mirror layers).
    let mut m_min = f32::INFINITY;
    let mut reach = NodeBox::EMPTY;
    rows.clear();
    for (st, m, v, a) in q
        .contiguous_iter()
        .expect("particle components are table components")
    {
        for (st, m) in st.iter().zip(m) {
            m_min = m_min.min(m.0);
            reach.min = reach.min.min(st.base);
            reach.max = reach.max.max(st.base + IVec3::splat(2));
        }
        // Read only: the pointers are never written through.
        let cols = P2gColumns {
            m: SharedMut::read(m),
            v: SharedMut::read(v),
            a: SharedMut::read(a),
        };
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { rows.push(st, cols) };
    }
    if let Some(ranks) = &ranks {
        // Every rank needs the same threshold and the same reach (the folds of a shared
        // column's ghosts must run on both ranks or neither).
        let lows = ranks.max(&[
            -(m_min as f64),
            -(reach.min.x as f64),
            -(reach.min.y as f64),
            -(reach.min.z as f64),
            reach.max.x as f64,
            reach.max.y as f64,
            reach.max.z as f64,
        ]);
        m_min = -lows[0] as f32;
        reach.min = IVec3::new(-lows[1] as i32, -lows[2] as i32, -lows[3] as i32);
        reach.max = IVec3::new(lows[4] as i32, lows[5] as i32, lows[6] as i32);
    }
    plan.build(&layout, rows.bases());
    let periodic = config.walls.periodic_axes();
    let counts = periodic_counts(&config, grid);
    let faces = mirror_faces(&config, &grid.layout);
    keys.clear();
    plan.reached_blocks(&grid.layout, &mut keys);
    image_closure(&grid.layout, &mut keys, periodic, counts, &faces);
    grid.allocate(&keys);
    grid.reach = reach;
    grid.mass_epsilon = if m_min.is_finite() {
        1e-10 * m_min
    } else {
        0.0
    };
    let mut nodes = std::mem::take(&mut grid.nodes);
    // Symplectic Euler's grid update and G2P do not read the transferred aᵢ (it stays 0).
    let with_a = config.integrator.scheme != Scheme::SymplecticEuler || ctx.rate_evaluation;
    plan.scatter(
        grid,
        &mut nodes,
        |n: &mut GridNode, h: &GridNode| {
            n.mass += h.mass;
            n.velocity += h.velocity;
            if with_a {
                n.acceleration += h.acceleration;
            }
        },
        |i, local, hood| {
            let (st, t, row) = rows.get(i);
            let st = st.stencil(&layout);
            let hood = hood.as_mut_ptr();
            // SAFETY: the columns hold the table's rows (`QueryRows::get` checks the row), read
            // only. `hood` is the dense neighbourhood `local` of the particle's block, which
            // holds its whole stencil; the closure has it to itself.
            unsafe {
                let (m, v) = ((*t.m.get().add(row)).0, (*t.v.get().add(row)).0);
                if with_a {
                    p2g_stencil(local, hood, &st, m, v, (*t.a.get().add(row)).0);
                } else {
                    p2g_stencil_momentum(local, hood, &st, m, v);
                }
            }
        },
    );
    rows.clear();
    grid.nodes = nodes;
    if let Some(ranks) = &ranks {
        ranks.sum_halo(grid, HaloFields::Transfer);
    }
    grid.fold_periodic(periodic, counts, Fold::Transfer);
    grid.fold_mirror(&faces, Fold::Transfer);
    let eps = grid.mass_epsilon;
    for_each_active_row(grid, |row| {
        for n in row {
            if n.mass > eps {
                let inv = 1.0 / n.mass;
                n.velocity *= inv;
                n.acceleration *= inv;
            } else {
                *n = Default::default();
            }
        }
    });
    hold_sticky_faces(&config, ctx.sticky_share, grid);
    copy_ghosts(&config, grid, GhostCopy::Transfer);
}

/// The transferred state vᵢⁿ, aᵢⁿ of the nodes on or beyond a `Sticky` domain face is scaled by
/// β = [`StepContext::sticky_share`] (§2.11, choice D20; [`crate::config::StickyReset`]); the
/// grid update then imposes the wall's vᵢⁿ⁺¹ = aᵢⁿ⁺¹ = 0, so the FLIP increment of such a node
/// takes β of the particles' transferred velocity there.
pub fn hold_sticky_faces(config: &MpmConfig, share: f32, grid: &mut MpmGrid) {
    let walls = config.walls;
    let faces = [0, 1, 2].map(|axis| [false, true].map(|upper| (axis, upper)));
    let sticky = |&(axis, upper): &(usize, bool)| {
        matches!(walls.face(axis, upper), BoundaryCondition::Sticky)
    };
    if share >= 1.0 || !faces.iter().flatten().any(sticky) {
        return;
    }
    let (lo, hi) = (config.domain_min, config.domain_max);
    let layout = grid.layout;
    for_each_active_row_indexed(grid, |first, row| {
        for (k, n) in row.iter_mut().enumerate() {
            let x = layout.node_position(first + IVec3::new(0, 0, k as i32));
            let held = faces
                .iter()
                .flatten()
                .any(|f| sticky(f) && on_domain_face(x, f.0, f.1, lo, hi));
            if held {
                n.velocity *= share;
                n.acceleration *= share;
            }
        }
    });
}

/// Number of distinct nodes along each periodic axis (domain length / Δx).
pub fn periodic_counts(config: &MpmConfig, grid: &MpmGrid) -> [i32; 3] {
    let len = config.domain_max - config.domain_min;
    [0, 1, 2].map(|a| grid.periodic_count(len[a]))
}

/// The free-slip domain faces that lie on a node plane, in the order x min, x max, y min, …
/// (§2.11, choice D18). The min faces always do (nodes start at the domain's lower corner); a
/// max face does when the domain length is a whole number of cells. A `Slip` face between
/// node planes keeps the plain velocity projection of §2.11.
pub fn mirror_faces(config: &MpmConfig, layout: &GridLayout) -> Vec<MirrorFace> {
    let len = config.domain_max - config.domain_min;
    let mut faces = Vec::new();
    for axis in 0..3 {
        for upper in [false, true] {
            if !matches!(config.walls.face(axis, upper), BoundaryCondition::Slip) {
                continue;
            }
            let node = if upper {
                let cells = len[axis] * layout.inv_dx;
                if (cells - cells.round()).abs() > 1e-3 {
                    continue;
                }
                cells.round() as i32
            } else {
                0
            };
            faces.push(MirrorFace { axis, node, upper });
        }
    }
    faces
}

/// After normalisation ([`GhostCopy::Transfer`]) and after the grid update
/// ([`GhostCopy::Update`]): mirror ghosts take their images' reflected values of those fields,
/// periodic ghosts their images' nodes (so gathers see a mirrored and periodic field; mirrors
/// first, the reverse of the folds).
pub fn copy_ghosts(config: &MpmConfig, grid: &mut MpmGrid, what: GhostCopy) {
    let faces = mirror_faces(config, &grid.layout);
    grid.copy_mirror(&faces, what);
    let periodic = config.walls.periodic_axes();
    if periodic.iter().any(|p| *p) {
        let counts = periodic_counts(config, grid);
        grid.copy_periodic(periodic, counts);
    }
}
