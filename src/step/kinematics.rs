//! S4: particle kinematics at t_{n+W₁} (ALGORITHM §2.3 S4): L̃ₚ = Σᵢ ṽᵢ ⊗ ∇w̃ᵢₚ with
//! ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ, and for particles with a deformation gradient
//! F̃ₚ = (I + Ĝₚ) Fₚ, Ĝₚ = Σᵢ (W₁Λ₁Δt vᵢ + W₂Λ₂Δt² aᵢ) ⊗ ∇w̃ᵢₚ (eq. 32, choice D16).
//!
//! Reads `MpmGrid`, `ParticleStencil`, `DeformationGradient`; writes `VelocityGradient`,
//! `PredictedDeformationGradient`.
use bevy_ecs::prelude::*;

use crate::components::{
    DeformationGradient, Particle, ParticleStencil, PredictedDeformationGradient, VelocityGradient,
};
use crate::grid::MpmGrid;
use crate::kernels::kinematics_stencil;
use crate::math::Mat3;
use crate::step::schedule::StepContext;

/// Velocity gradient of every particle.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn velocity_gradients(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    mut q: Query<
        (&ParticleStencil, &mut VelocityGradient),
        (With<Particle>, Without<DeformationGradient>),
    >,
) {
    let c = ctx.coefficients;
    q.par_iter_mut().for_each(|(xt, mut l)| {
        l.bypass_change_detection().0 =
            kinematics_stencil(&grid.layout, &grid.nodes, &xt.0, &c, false).0;
    });
}

/// Velocity gradient and predicted deformation gradient of particles that carry F.
pub fn velocity_and_deformation_gradients(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    mut q: Query<
        (
            &ParticleStencil,
            &DeformationGradient,
            &mut VelocityGradient,
            &mut PredictedDeformationGradient,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    q.par_iter_mut().for_each(|(xt, f, mut l, mut ft)| {
        let (lt, g) = kinematics_stencil(&grid.layout, &grid.nodes, &xt.0, &c, true);
        l.bypass_change_detection().0 = lt;
        ft.bypass_change_detection().0 = (Mat3::IDENTITY + g) * f.0;
    });
}
