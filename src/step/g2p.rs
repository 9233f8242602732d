//! S13–S14: grid-to-particle transfer with the PIC/FLIP blend, positions and F
//! (ALGORITHM §2.12–2.13, eqs. 42–45; choices D6, D7).
//!
//! FLIP ([`FlipUpdate::GridIncrement`]): v_F = vₚ + Σ w̃ (vᵢⁿ⁺¹ − vᵢⁿ),
//! a_F = aₚ + Σ w̃ (aᵢⁿ⁺¹ − aᵢⁿ); [`FlipUpdate::ParticleGs4`] (the default) applies GS4 to the
//! particle velocity with the decaying correction of §2.12 on top. PIC: Σ w̃ vᵢⁿ⁺¹, Σ w̃ aᵢⁿ⁺¹;
//! blend with α_F. Positions xₚⁿ⁺¹ = xₚ + Δt/2 (vₚ + v_F) (eq. 45 via identity 1.1).
//! F: Fⁿ⁺¹ = Fⁿ + G̃ F̃ with G̃ = Δt/2 Σ (vᵢⁿ + vᵢⁿ⁺¹) ⊗ ∇w̃ (D7).
//!
//! [`FlipUpdate`] chooses the FLIP form ([`g2p_stencil`], or [`g2p_stencil_particle_gs4`] by
//! default).
//!
//! Reads `MpmGrid`, `ParticleStencil`, `PredictedDeformationGradient`,
//! `StepContext`, `MpmConfig`; writes `Position`, `Velocity`, `Acceleration`,
//! `DeformationGradient`.
use bevy_ecs::prelude::*;

use crate::components::{
    Acceleration, DeformationGradient, Particle, ParticleStencil, PhaseIndex, Position,
    PredictedDeformationGradient, Velocity,
};
use crate::config::{FlipUpdate, MpmConfig, SolidMotion};
use crate::grid::MpmGrid;
use crate::kernels::{displacement_gradient_stencil, g2p_stencil, g2p_stencil_particle_gs4};
use crate::scatter::{BlockPlan, GatherScratch, SharedMut};
use crate::step::schedule::StepContext;

/// One table's columns of [`grid_to_particle`].
#[derive(Clone, Copy)]
pub struct G2pColumns {
    x: SharedMut<Position>,
    v: SharedMut<Velocity>,
    a: SharedMut<Acceleration>,
    /// The table's particles carry F.
    solid: bool,
    phase: Option<SharedMut<PhaseIndex>>,
}

/// Velocity, acceleration and position update of every particle: gathered block by block
/// ([`GatherScratch::gather`]), each particle's result written into its own components.
#[allow(clippy::type_complexity)]
pub fn grid_to_particle(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    grid: Res<MpmGrid>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<G2pColumns>>,
    mut q: Query<
        (
            &ParticleStencil,
            &mut Position,
            &mut Velocity,
            &mut Acceleration,
            Has<DeformationGradient>,
            Option<&PhaseIndex>,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    let solids_with_grid = config.integrator.solid_motion == SolidMotion::GridVelocity;
    let kernel = match config.integrator.flip_update {
        FlipUpdate::GridIncrement => g2p_stencil,
        FlipUpdate::ParticleGs4 => g2p_stencil_particle_gs4,
    };
    let layout = grid.layout;
    // Change ticks are not needed on these per-step quantities (8 B written per component).
    scratch.clear();
    for (st, mut x, mut v, mut a, solid, phase) in q
        .contiguous_iter_mut()
        .expect("particle components are table components")
    {
        let cols = G2pColumns {
            x: SharedMut::slice(x.bypass_change_detection()),
            v: SharedMut::slice(v.bypass_change_detection()),
            a: SharedMut::slice(a.bypass_change_detection()),
            solid,
            phase: phase.map(SharedMut::read),
        };
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { scratch.push(st, cols) };
    }
    scratch.gather(&shared, &grid, &grid.nodes, |st, t, row, local, hood| {
        // SAFETY: `gather` visits each row of each table once; the columns hold the table's
        // rows (pushed above from this query's slices, which nothing else borrows meanwhile).
        let (x, v, a) = unsafe {
            (
                &mut *t.x.get().add(row),
                &mut *t.v.get().add(row),
                &mut *t.a.get().add(row),
            )
        };
        let r = kernel(local, hood, &st.stencil(&layout), x.0, v.0, a.0, &c);
        // GridVelocity: a particle with F moves with the grid displacement in proportion to its
        // solid fraction (1 without phase change), so a melt moves as a liquid.
        x.0 = if t.solid && solids_with_grid {
            match t.phase {
                // SAFETY: as above (read only).
                Some(p) => {
                    let s = unsafe { (*p.get().add(row)).0 };
                    r.position + s.clamp(0.0, 1.0) * (r.grid_position - r.position)
                }
                None => r.grid_position,
            }
        } else {
            r.position
        };
        v.0 = r.velocity;
        a.0 = r.acceleration;
    });
}

/// One table's columns of [`update_deformation_gradients`].
#[derive(Clone, Copy)]
pub struct FColumns {
    ft: SharedMut<PredictedDeformationGradient>,
    f: SharedMut<DeformationGradient>,
}

/// Deformation-gradient update (D7) for particles that carry F. Runs before
/// [`grid_to_particle`] (it needs no particle velocity, only the grid).
pub fn update_deformation_gradients(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<FColumns>>,
    mut q: Query<
        (
            &ParticleStencil,
            &PredictedDeformationGradient,
            &mut DeformationGradient,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    let layout = grid.layout;
    scratch.clear();
    for (st, ft, mut f) in q
        .contiguous_iter_mut()
        .expect("particle components are table components")
    {
        let cols = FColumns {
            ft: SharedMut::read(ft),
            f: SharedMut::slice(f.bypass_change_detection()),
        };
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { scratch.push(st, cols) };
    }
    scratch.gather(&shared, &grid, &grid.nodes, |st, t, row, local, hood| {
        // SAFETY: `gather` visits each row of each table once; F̃ is only read.
        let (ft, f) = unsafe { (&*t.ft.get().add(row), &mut *t.f.get().add(row)) };
        f.0 += displacement_gradient_stencil(local, hood, &st.stencil(&layout), &c) * ft.0;
    });
}
