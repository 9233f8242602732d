//! S5–S10: density, Tait pressure and the Newtonian (local) stress (ALGORITHM §2.6–2.7, §2.9).
//!
//! Density by GS4-1, pointwise implicit in ρ (§2.6, erratum E2 corrected):
//! θ = tr L̃, Δρ̇ = −(ρ̇ + (ρ + W₁Λ₄Δt ρ̇) θ) / (W₁Λ₆ + W₂Λ₅Δt θ),
//! ρ̃ = ρ + W₁Λ₄Δt ρ̇ + W₂Λ₅Δt Δρ̇. Then p̃ = Tait(ρ̃) and σ̃ = −p̃ I + 2 F_v μ D̃.
//!
//! This system runs first in [`ConstitutiveSystems::Base`](crate::schedule::ConstitutiveSystems);
//! rheology models run in `ConstitutiveSystems::Models` after it and **add** their stress to
//! `CauchyStress` and raise `StabilityData`.
//!
//! Reads `Density`, `VelocityGradient`, `MaterialId`, `Materials`; writes `PredictedDensity`,
//! `CauchyStress`, `StabilityData`; records a failure when the density guard trips.
use bevy_ecs::prelude::*;

use crate::components::{
    CauchyStress, Density, Particle, PredictedDensity, StabilityData, VelocityGradient,
};
use crate::failure::{FailureCollector, FailureReport};
use crate::material::{MaterialId, Materials};
use crate::math::Mat3;
use crate::schedule::StepContext;

/// Density update, pressure and Newtonian stress of every particle.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn newtonian_stress(
    ctx: Res<StepContext>,
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
            let p = m.pressure(rho_t);
            let d = 0.5 * (l.0 + l.0.transpose());
            let mu_l = m.local_fraction * m.viscosity;
            sigma.bypass_change_detection().0 =
                Mat3::from_diagonal(crate::math::Vec3::splat(-p)) + (2.0 * mu_l) * d;
            let stab = stab.bypass_change_detection();
            stab.wave_speed_sq = m.sound_speed_sq(rho_t.max(0.0));
            stab.kinematic_viscosity = mu_l / rho_t;
            stab.relaxation_rate = 0.0;
        });
}
