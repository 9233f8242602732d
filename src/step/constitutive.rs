//! S5–S10: density, Tait pressure and the Newtonian (local) stress (ALGORITHM §2.6–2.7, §2.9).
//!
//! Density by GS4-1, pointwise implicit in ρ (§2.6, erratum E2 corrected):
//! θ = tr L̃, Δρ̇ = −(ρ̇ + (ρ + W₁Λ₄Δt ρ̇) θ) / (W₁Λ₆ + W₂Λ₅Δt θ),
//! ρ̃ = ρ + W₁Λ₄Δt ρ̇ + W₂Λ₅Δt Δρ̇. Then p̃ = Tait(ρ̃) and σ̃ = −p̃ I + 2 F_v μ D̃.
//!
//! This system runs first in [`ConstitutiveSystems::Base`](crate::step::schedule::ConstitutiveSystems);
//! rheology models run in `ConstitutiveSystems::Models` after it and **add** their stress to
//! `CauchyStress` and raise `StabilityData`.
//!
//! With implicit viscosity ([`Scheme::implicit_viscosity`](crate::config::Scheme)) the local
//! viscous stress is left out (the grid solve of [`crate::step::implicit`] applies it) and
//! `StabilityData::kinematic_viscosity` gets 0 for it, so the adaptive Δt drops the viscous
//! limit. The start-up rate evaluation (Δt = 0) keeps the stress, for a consistent a⁰.
//!
//! Reads `Density`, `VelocityGradient`, `MaterialId`, `Materials`, `MpmConfig`; writes
//! `PredictedDensity`, `CauchyStress`, `StabilityData`; records a failure when the density
//! guard trips.
use bevy_ecs::prelude::*;

use crate::components::{
    CauchyStress, Density, Particle, PredictedDensity, StabilityData, VelocityGradient,
};
use crate::config::MpmConfig;
use crate::failure::{FailureCollector, FailureReport};
use crate::material::{MaterialId, Materials};
use crate::math::Mat3;
use crate::step::schedule::StepContext;

/// Density update, pressure and Newtonian stress of every particle.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn newtonian_stress(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    materials: Res<Materials>,
    failures: Res<FailureCollector>,
    mut q: Query<
        (
            Entity,
            &Density,
            &MaterialId,
            &VelocityGradient,
            &mut PredictedDensity,
            &mut CauchyStress,
            &mut StabilityData,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    let dt = c.dt;
    let implicit = config.integrator.scheme.implicit_viscosity();
    // A projected pressure (§5.4) replaces the Tait pressure and its sound limit.
    let tait = config.integrator.pressure.projection().is_none();
    // Fraction of the local viscosity in the explicit stress and in the viscous Δt limit.
    let (stress_part, limit_part) = match (implicit, ctx.rate_evaluation) {
        (false, _) => (1.0, 1.0),
        (true, true) => (1.0, 0.0),
        (true, false) => (0.0, 0.0),
    };
    q.par_iter_mut()
        .for_each(|(e, rho, mat, l, mut rt, mut sigma, mut stab)| {
            let m = materials.get(*mat);
            let theta = l.0.x_axis.x + l.0.y_axis.y + l.0.z_axis.z;
            let denom = c.w1l6 + c.w2l5 * dt * theta;
            if denom.is_nan() || denom < 0.5 * c.w1l6 {
                failures.record(FailureReport::particle(
                    e,
                    "density",
                    theta as f64,
                    "strong compression: W₁Λ₆ + W₂Λ₅Δt·∇·v fell below ½W₁Λ₆ (ALGORITHM §2.6 guard)",
                ));
            }
            let rho_hat = rho.value + c.w1l4 * dt * rho.rate;
            let d_rate = -(rho.rate + rho_hat * theta) / denom;
            let rho_t = rho_hat + c.w2l5 * dt * d_rate;
            let rt = rt.bypass_change_detection();
            rt.value = rho_t;
            rt.rate_increment = d_rate;
            let p = if tait { m.pressure(rho_t) } else { 0.0 };
            let d = 0.5 * (l.0 + l.0.transpose());
            let mu_l = m.local_fraction * m.viscosity;
            sigma.bypass_change_detection().0 = Mat3::from_diagonal(crate::math::Vec3::splat(-p))
                + (2.0 * (stress_part * mu_l)) * d;
            let stab = stab.bypass_change_detection();
            stab.wave_speed_sq = if tait {
                m.sound_speed_sq(rho_t.max(0.0))
            } else {
                0.0
            };
            stab.kinematic_viscosity = (limit_part * mu_l) / rho_t;
            stab.relaxation_rate = 0.0;
        });
}
