//! S4: particle kinematics at t_{n+W₁} (ALGORITHM §2.3 S4): L̃ₚ = Σᵢ ṽᵢ ⊗ ∇w̃ᵢₚ with
//! ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ, and for particles with a deformation gradient
//! F̃ₚ = (I + Ĝₚ) Fₚ, Ĝₚ = Σᵢ (W₁Λ₁Δt vᵢ + W₂Λ₂Δt² aᵢ) ⊗ ∇w̃ᵢₚ (eq. 32, choice D16).
//!
//! Reads `MpmGrid`, `ParticleStencil`, `DeformationGradient`; writes `VelocityGradient`,
//! `PredictedDeformationGradient`.
//!
//! With [`VelocityGradientSource::Carried`] (first-order schemes) the gather is skipped: Lₚ is
//! the one the last G2P wrote, and F̃ₚ = Fₚ (the first-order predictor).
use bevy_ecs::prelude::*;

use crate::components::{
    DeformationGradient, Particle, ParticleStencil, PredictedDeformationGradient, VelocityGradient,
};
use crate::config::{MpmConfig, VelocityGradientSource};
use crate::grid::MpmGrid;
use crate::kernels::kinematics_stencil;
use crate::math::Mat3;
use crate::scatter::{BlockPlan, GatherScratch, SharedMut};
use crate::step::schedule::StepContext;

/// Run condition: this step gathers Lₚ from the grid (always, except in first-order steps with
/// [`VelocityGradientSource::Carried`]; the start-up rate evaluation always gathers).
pub fn gathered_velocity_gradient(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    let ig = &config.integrator;
    ig.velocity_gradient == VelocityGradientSource::Gather
        || ig.scheme.is_gs4()
        || ctx.rate_evaluation
}

/// F̃ₚ = Fₚ for the particles that carry F, when Lₚ is carried from the last G2P (the
/// first-order coefficients' predictor, without the gather).
pub fn carry_deformation_gradients(
    mut q: Query<(&DeformationGradient, &mut PredictedDeformationGradient), With<Particle>>,
) {
    for (f, mut ft) in &mut q {
        ft.bypass_change_detection().0 = f.0;
    }
}

/// Velocity gradient of every particle (gathered block by block, written into its own
/// component).
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn velocity_gradients(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<SharedMut<VelocityGradient>>>,
    mut q: Query<
        (&ParticleStencil, &mut VelocityGradient),
        (With<Particle>, Without<DeformationGradient>),
    >,
) {
    let c = ctx.coefficients;
    let layout = grid.layout;
    scratch.clear();
    for (st, mut l) in q
        .contiguous_iter_mut()
        .expect("particle components are table components")
    {
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { scratch.push(st, SharedMut::slice(l.bypass_change_detection())) };
    }
    scratch.gather(&shared, &grid, &grid.nodes, |st, l, row, local, hood| {
        let lt = kinematics_stencil(local, hood, &st.stencil(&layout), &c, false).0;
        // SAFETY: `gather` visits each row of each table once.
        unsafe { (*l.get().add(row)).0 = lt };
    });
}

/// One table's columns of [`velocity_and_deformation_gradients`].
#[derive(Clone, Copy)]
pub struct KinematicsColumns {
    f: SharedMut<DeformationGradient>,
    l: SharedMut<VelocityGradient>,
    ft: SharedMut<PredictedDeformationGradient>,
}

/// Velocity gradient and predicted deformation gradient of particles that carry F.
pub fn velocity_and_deformation_gradients(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<KinematicsColumns>>,
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
    let layout = grid.layout;
    scratch.clear();
    for (st, f, mut l, mut ft) in q
        .contiguous_iter_mut()
        .expect("particle components are table components")
    {
        let cols = KinematicsColumns {
            f: SharedMut::read(f),
            l: SharedMut::slice(l.bypass_change_detection()),
            ft: SharedMut::slice(ft.bypass_change_detection()),
        };
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { scratch.push(st, cols) };
    }
    scratch.gather(&shared, &grid, &grid.nodes, |st, t, row, local, hood| {
        let (lt, g) = kinematics_stencil(local, hood, &st.stencil(&layout), &c, true);
        // SAFETY: `gather` visits each row of each table once; F is only read.
        unsafe {
            let f = (*t.f.get().add(row)).0;
            (*t.l.get().add(row)).0 = lt;
            (*t.ft.get().add(row)).0 = (Mat3::IDENTITY + g) * f;
        }
    });
}
