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
use crate::kernels::{
    G2pResult, displacement_gradient_stencil, g2p_stencil, g2p_stencil_particle_gs4,
};
use crate::math::Mat3;
use crate::scatter::{BlockPlan, GatherScratch};
use crate::step::schedule::StepContext;

/// Velocity, acceleration and position update of every particle: gathered block by block
/// ([`crate::scatter::BlockPlan::gather_into`]), then written in query order.
#[allow(clippy::type_complexity)]
pub fn grid_to_particle(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    grid: Res<MpmGrid>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<G2pResult>>,
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
    {
        let layout = grid.layout;
        let inputs: Vec<_> = q
            .iter()
            .map(|(st, x, v, a, _, _)| (st, x.0, v.0, a.0))
            .collect();
        let (plan, out) = scratch.order(&shared, &layout, inputs.iter().map(|it| it.0.base));
        plan.gather_into(&grid, &grid.nodes, out, |i, local, hood| {
            let (st, x, v, a) = inputs[i];
            kernel(local, hood, &st.stencil(&layout), x, v, a, &c)
        });
    }
    for ((_, mut x, mut v, mut a, solid, phase), r) in q.iter_mut().zip(scratch.out.iter()) {
        // Change ticks are not needed on these per-step quantities (8 B written per component).
        // GridVelocity: a particle with F moves with the grid displacement in proportion to its
        // solid fraction (1 without phase change), so a melt moves as a liquid.
        x.bypass_change_detection().0 = if solid && solids_with_grid {
            match phase {
                Some(s) => r.position + s.0.clamp(0.0, 1.0) * (r.grid_position - r.position),
                None => r.grid_position,
            }
        } else {
            r.position
        };
        v.bypass_change_detection().0 = r.velocity;
        a.bypass_change_detection().0 = r.acceleration;
    }
}

/// Deformation-gradient update (D7) for particles that carry F. Runs before
/// [`grid_to_particle`] (it needs no particle velocity, only the grid).
pub fn update_deformation_gradients(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<Mat3>>,
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
    {
        let layout = grid.layout;
        let inputs: Vec<_> = q.iter().map(|(st, ft, _)| (st, ft.0)).collect();
        let (plan, out) = scratch.order(&shared, &layout, inputs.iter().map(|it| it.0.base));
        plan.gather_into(&grid, &grid.nodes, out, |i, local, hood| {
            let (st, ft) = inputs[i];
            displacement_gradient_stencil(local, hood, &st.stencil(&layout), &c) * ft
        });
    }
    for ((_, _, mut f), gf) in q.iter_mut().zip(scratch.out.iter()) {
        f.0 += *gf;
    }
}
