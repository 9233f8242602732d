//! S11 (first half): internal grid forces f̃ᵢ = −Σₚ Ṽₚ σ̃ₚ ∇w̃ᵢₚ with Ṽₚ = mₚ/ρ̃ₚ
//! (ALGORITHM §2.9, eq. 35); periodic and mirror folds (§2.5, §2.11 choice D18).
//!
//! Reads `ParticleStencil`, `Mass`, `PredictedDensity`, `CauchyStress`; writes
//! `MpmGrid::nodes[..].force`.
use bevy_ecs::prelude::*;

use crate::components::{CauchyStress, Mass, Particle, ParticleStencil, PredictedDensity};
use crate::config::MpmConfig;
use crate::distributed::{HaloFields, Ranks};
use crate::grid::{Fold, GridNode, MpmGrid};
use crate::kernels::force_stencil;
use crate::scatter::{BlockPlan, QueryRows, SharedMut};
use crate::step::p2g::{mirror_faces, periodic_counts};

/// One table's columns of [`grid_forces`] (read only).
#[derive(Clone, Copy)]
pub struct ForceColumns {
    m: SharedMut<Mass>,
    rho: SharedMut<PredictedDensity>,
    sigma: SharedMut<CauchyStress>,
}

/// Scatters the stress divergence to the grid.
pub fn grid_forces(
    config: Res<MpmConfig>,
    mut grid: ResMut<MpmGrid>,
    mut plan: ResMut<BlockPlan>,
    ranks: Option<Res<Ranks>>,
    mut rows: Local<QueryRows<ForceColumns>>,
    q: Query<(&ParticleStencil, &Mass, &PredictedDensity, &CauchyStress), With<Particle>>,
) {
    let grid = &mut *grid;
    rows.clear();
    for (st, m, rho, sigma) in q
        .contiguous_iter()
        .expect("particle components are table components")
    {
        let cols = ForceColumns {
            m: SharedMut::read(m),
            rho: SharedMut::read(rho),
            sigma: SharedMut::read(sigma),
        };
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { rows.push(st, cols) };
    }
    // The P2G plan of this step ordered the same stencils (the particles do not move in
    // between); it is rebuilt only if the particle set changed.
    let layout = grid.layout;
    if plan.build(&layout, rows.bases()) && cfg!(debug_assertions) {
        let mut keys = Vec::new();
        plan.reached_blocks(&grid.layout, &mut keys);
        debug_assert!(
            keys.iter()
                .all(|&k| grid.slot_of_block(grid.layout.block_of_key(k)).is_some()),
            "a particle reached a block the P2G of this step did not allocate"
        );
    }
    let mut nodes = std::mem::take(&mut grid.nodes);
    plan.scatter(
        grid,
        &mut nodes,
        |n: &mut GridNode, h: &GridNode| n.force += h.force,
        |i, local, hood| {
            let (st, t, row) = rows.get(i);
            let st = st.stencil(&layout);
            // SAFETY: as in particle_to_grid (the columns are read only at a checked row; the
            // neighbourhood holds the whole stencil).
            unsafe {
                let volume = (*t.m.get().add(row)).0 / (*t.rho.get().add(row)).value;
                let sigma = (*t.sigma.get().add(row)).0;
                force_stencil(local, hood.as_mut_ptr(), &st, volume * sigma);
            }
        },
    );
    rows.clear();
    grid.nodes = nodes;
    if let Some(ranks) = ranks {
        ranks.sum_halo(grid, HaloFields::Force);
    }
    let periodic = config.walls.periodic_axes();
    if periodic.iter().any(|p| *p) {
        let counts = periodic_counts(&config, grid);
        grid.fold_periodic(periodic, counts, Fold::Force);
    }
    let faces = mirror_faces(&config, &grid.layout);
    grid.fold_mirror(&faces, Fold::Force);
}
