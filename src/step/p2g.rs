//! S2–S3: particle-to-grid transfer at the predicted positions (ALGORITHM §2.5, eq. 31):
//! m̃ᵢ = Σ mₚw̃ᵢₚ, vᵢ = Σ mₚw̃ᵢₚvₚ / m̃ᵢ, aᵢ = Σ mₚw̃ᵢₚaₚ / m̃ᵢ (mass-normalised, active where
//! m̃ᵢ > m_ε).
//!
//! Reads `PredictedPosition`, `Mass`, `Velocity`, `Acceleration`; writes `MpmGrid` (mass,
//! velocity, acceleration; clears the rest of the touched box).
use bevy_ecs::prelude::*;

use crate::components::{
    Acceleration, Mass, Particle, ParticleStencil, PredictedPosition, Velocity,
};
use crate::config::MpmConfig;
use crate::grid::{Fold, MpmGrid};
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
    copy_ghosts(&config, grid);
}

/// Number of distinct nodes along each periodic axis (domain length / Δx).
pub fn periodic_counts(config: &MpmConfig, grid: &MpmGrid) -> [i32; 3] {
    let len = config.domain_max - config.domain_min;
    [0, 1, 2].map(|a| grid.periodic_count(len[a]))
}

/// After normalisation: ghosts take their images' values (so gathers see a periodic field).
pub fn copy_ghosts(config: &MpmConfig, grid: &mut MpmGrid) {
    let periodic = config.walls.periodic_axes();
    if periodic.iter().any(|p| *p) {
        let counts = periodic_counts(config, grid);
        grid.copy_periodic(periodic, counts);
    }
}
