//! S2–S3: particle-to-grid transfer at the predicted positions (ALGORITHM §2.5, eq. 31):
//! m̃ᵢ = Σ mₚw̃ᵢₚ, vᵢ = Σ mₚw̃ᵢₚvₚ / m̃ᵢ, aᵢ = Σ mₚw̃ᵢₚaₚ / m̃ᵢ (mass-normalised, active where
//! m̃ᵢ > m_ε). Free-slip faces on a node plane are mirrors (§2.11, choice D18): the nodes
//! beyond them are folded onto their images and become reflected copies.
//!
//! Reads `PredictedPosition`, `Mass`, `Velocity`, `Acceleration`; writes `MpmGrid` (mass,
//! velocity, acceleration; clears the rest of the touched box).
use bevy_ecs::prelude::*;

use crate::components::{
    Acceleration, Mass, Particle, ParticleStencil, PredictedPosition, Velocity,
};
use crate::config::{BoundaryCondition, MpmConfig};
use crate::grid::{Fold, GhostCopy, GridLayout, MirrorFace, MpmGrid};
use crate::kernels::p2g_stencil;
use crate::scatter::{ScatterPlan, SharedMut};
use crate::step::grid_update::for_each_active_row;

/// Clears the grid, scatters mass, momentum and m·a, and normalises.
pub fn particle_to_grid(
    config: Res<MpmConfig>,
    mut grid: ResMut<MpmGrid>,
    mut plan: ResMut<ScatterPlan>,
    q: Query<
        (
            &PredictedPosition,
            &ParticleStencil,
            &Mass,
            &Velocity,
            &Acceleration,
        ),
        With<Particle>,
    >,
) {
    let grid = &mut *grid;
    grid.clear_active();
    let items: Vec<_> = q.iter().collect();
    plan.build(&grid.layout, items.iter().map(|it| it.0.0));
    grid.active = plan.touched;
    // m_ε: 1e-10 of the smallest particle mass (§2.5).
    let mut m_min = f32::INFINITY;
    for it in &items {
        m_min = m_min.min(it.2.0);
    }
    grid.mass_epsilon = if m_min.is_finite() {
        1e-10 * m_min
    } else {
        0.0
    };
    let layout = grid.layout;
    let nodes = SharedMut(grid.nodes.as_mut_ptr());
    plan.run(|i| {
        let (_, st, m, v, a) = items[i];
        // SAFETY: ScatterPlan::run never runs two particles whose stencils share a node
        // concurrently; the pointer covers `layout.node_count()` nodes and stencils are clamped.
        unsafe { p2g_stencil(&layout, nodes.get(), &st.0, m.0, v.0, a.0) };
    });
    let periodic = config.walls.periodic_axes();
    let counts = periodic_counts(&config, grid);
    grid.widen_periodic(periodic);
    grid.fold_periodic(periodic, counts, Fold::Transfer);
    let faces = mirror_faces(&config, &grid.layout);
    grid.widen_mirror(&faces);
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
    copy_ghosts(&config, grid, GhostCopy::Transfer);
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
