//! S11 (first half): internal grid forces f̃ᵢ = −Σₚ Ṽₚ σ̃ₚ ∇w̃ᵢₚ with Ṽₚ = mₚ/ρ̃ₚ
//! (ALGORITHM §2.9, eq. 35); periodic and mirror folds (§2.5, §2.11 choice D18).
//!
//! Reads `PredictedPosition`, `Mass`, `PredictedDensity`, `CauchyStress`; writes
//! `MpmGrid::nodes[..].force`.
use bevy_ecs::prelude::*;

use crate::components::{
    CauchyStress, Mass, Particle, ParticleStencil, PredictedDensity, PredictedPosition,
};
use crate::config::MpmConfig;
use crate::grid::{Fold, MpmGrid};
use crate::kernels::force_stencil;
use crate::scatter::{ScatterPlan, SharedMut};
use crate::step::p2g::{mirror_faces, periodic_counts};

/// Scatters the stress divergence to the grid.
pub fn grid_forces(
    config: Res<MpmConfig>,
    mut grid: ResMut<MpmGrid>,
    mut plan: ResMut<ScatterPlan>,
    q: Query<
        (
            &PredictedPosition,
            &ParticleStencil,
            &Mass,
            &PredictedDensity,
            &CauchyStress,
        ),
        With<Particle>,
    >,
) {
    let grid = &mut *grid;
    let items: Vec<_> = q.iter().collect();
    // The P2G plan of this step binned the same predicted positions; reuse it unless the
    // particle set or order changed in between (checked bit for bit).
    if !plan.matches(items.iter().map(|it| it.0.0)) {
        plan.build(&grid.layout, items.iter().map(|it| it.0.0));
    }
    let layout = grid.layout;
    let nodes = SharedMut(grid.nodes.as_mut_ptr());
    plan.run(|i| {
        let (_, st, m, rho, sigma) = items[i];
        let volume = m.0 / rho.value;
        // SAFETY: see ScatterPlan::run; same argument as in particle_to_grid.
        unsafe { force_stencil(&layout, nodes.get(), &st.0, volume * sigma.0) };
    });
    let periodic = config.walls.periodic_axes();
    if periodic.iter().any(|p| *p) {
        let counts = periodic_counts(&config, grid);
        grid.fold_periodic(periodic, counts, Fold::Force);
    }
    let faces = mirror_faces(&config, &grid.layout);
    grid.fold_mirror(&faces, Fold::Force);
}
