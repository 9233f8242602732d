//! The phase-change systems (ALGORITHM §4.1–4.3): the phase state of a material's particles
//! ([`init_phase_state`], [`attach_phase_change`]), the stress blend with the temperature factor
//! ([`blend_phase_stress`], S6, S9, S10) and the shape-memory reset of choice D12
//! ([`reset_shape_memory`], S15).
use bevy_ecs::prelude::*;
use glam::DMat3;

use super::model::PhaseChangeTable;
use super::temperature_viscosity::TemperatureViscosityTable;
use crate::components::{
    CauchyStress, DeformationGradient, Particle, PredictedDeformationGradient, PredictedDensity,
    StabilityData, VelocityGradient,
};
use crate::failure::{FailureCollector, FailureReport};
use crate::material::{MaterialId, Materials};
use crate::math::{Mat3, Real, Vec3};
use crate::thermal::components::{PhaseIndex, PredictedTemperature, Temperature};

/// Gives `particles` of `material` the phase state (F = I, F̃ = I, I_s = 0) if the material
/// has a phase change; only what is missing is inserted.
pub fn init_phase_state(world: &mut World, material: MaterialId, particles: &[Entity]) {
    let Some(params) = world
        .get_resource::<PhaseChangeTable>()
        .and_then(|t| t.0.get(material).cloned())
    else {
        return;
    };
    // The phase index of a particle that already has a temperature follows from it (a solid
    // body starts solid in the frame-0 metrics); otherwise fluid until the first step sets it.
    let phases: Vec<(Entity, Real)> = particles
        .iter()
        .map(|&e| {
            let t = world.get::<Temperature>(e).map(|t| t.value);
            (e, t.map_or(0.0, |t| params.solid_fraction(t)))
        })
        .collect();
    world.insert_batch_if_new(phases.into_iter().map(|(e, phase)| {
        (
            e,
            (
                DeformationGradient::default(),
                PredictedDeformationGradient::default(),
                PhaseIndex(phase),
            ),
        )
    }));
}

/// Gives every particle of `material` that has no phase state yet the phase state
/// ([`init_phase_state`]); returns how many particles the material has. The particles also
/// need a temperature ([`Temperature`], from the thermal plugin or set directly) to take part.
pub fn attach_phase_change(world: &mut World, material: MaterialId) -> usize {
    attach_missing_phase_state(world, material);
    world
        .query_filtered::<&MaterialId, With<Particle>>()
        .iter(world)
        .filter(|m| **m == material)
        .count()
}

/// [`attach_phase_change`] without the count: visits only the particles of `material` that
/// have no phase index, so calling it after every spawned chunk costs only the new ones.
pub(crate) fn attach_missing_phase_state(world: &mut World, material: MaterialId) {
    let targets: Vec<Entity> = world
        .query_filtered::<(Entity, &MaterialId), (With<Particle>, Without<PhaseIndex>)>()
        .iter(world)
        .filter(|(_, m)| **m == material)
        .map(|(e, _)| e)
        .collect();
    init_phase_state(world, material, &targets);
}

/// S6, S9, S10 (§4.1–4.3): phase index, temperature factor and the blend
/// σ̃ = −p̃I + (1 − I_s)φσ̃_fluid,dev + I_s σ̃ˢ_dev, with the stability data scaled alike.
///
/// Reads `Materials`, `PhaseChangeTable`, `TemperatureViscosityTable`, `MaterialId`,
/// `PredictedDensity`, `VelocityGradient`, `PredictedTemperature` (else `Temperature`),
/// `PredictedDeformationGradient`; writes `CauchyStress`, `StabilityData`, `PhaseIndex`.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn blend_phase_stress(
    materials: Res<Materials>,
    phases: Option<Res<PhaseChangeTable>>,
    viscosities: Option<Res<TemperatureViscosityTable>>,
    failures: Res<FailureCollector>,
    mut q: Query<
        (
            Entity,
            &MaterialId,
            &PredictedDensity,
            &VelocityGradient,
            Option<&PredictedTemperature>,
            Option<&Temperature>,
            Option<&PredictedDeformationGradient>,
            Option<&mut PhaseIndex>,
            &mut CauchyStress,
            &mut StabilityData,
        ),
        (
            With<Particle>,
            Or<(With<PredictedTemperature>, With<Temperature>)>,
        ),
    >,
) {
    let empty_p = PhaseChangeTable::default();
    let empty_v = TemperatureViscosityTable::default();
    let phases = phases.as_deref().unwrap_or(&empty_p);
    let viscosities = viscosities.as_deref().unwrap_or(&empty_v);
    if phases.0.is_empty() && viscosities.0.is_empty() {
        return;
    }
    q.par_iter_mut().for_each(
        |(e, mat, rho, l, t_hat, t, ft, phase_index, mut sigma, mut stab)| {
            let phase = phases.0.get(*mat);
            let law = viscosities.0.get(*mat);
            if phase.is_none() && law.is_none() {
                return;
            }
            let Some(temp) = t_hat.map(|p| p.0).or(t.map(|t| t.value)) else {
                return;
            };
            let m = materials.get(*mat);
            let rho_t = rho.value;
            let p = m.pressure(rho_t);
            let fluid_dev = sigma.0 + Mat3::from_diagonal(Vec3::splat(p));
            let d = 0.5 * (l.0 + l.0.transpose());
            let dd = d.x_axis.dot(d.x_axis) + d.y_axis.dot(d.y_axis) + d.z_axis.dot(d.z_axis);
            let shear_rate = (2.0 * dd as f64).sqrt();
            let phi = law.map_or(1.0, |v| {
                v.factor(temp as f64, shear_rate, m.viscosity as f64)
            });
            let i_s = phase.map_or(0.0, |ph| ph.solid_fraction(temp));
            if let Some(mut pi) = phase_index
                && pi.0 != i_s
            {
                pi.0 = i_s;
            }
            let c_tait_sq = m.sound_speed_sq(rho_t.max(0.0));
            let model_wave = (stab.wave_speed_sq - c_tait_sq).max(0.0);
            let fluid = (1.0 - i_s) as f64 * phi;
            let mut solid = Mat3::ZERO;
            let mut solid_wave = 0.0;
            if i_s > 0.0
                && let Some(ph) = phase
            {
                let f = ft.map_or(DMat3::IDENTITY, |f| f.0.as_dmat3());
                let j = (m.density / rho_t) as f64;
                match ph.solid_stress(f, j) {
                    Some((s, g_eff)) => {
                        solid = s.as_mat3();
                        solid_wave = 4.0 / 3.0 * g_eff / rho_t as f64;
                    }
                    None => {
                        failures.record(FailureReport::particle(
                            e,
                            "deformation gradient",
                            f.determinant(),
                            "det F̃ ≤ 0 in the solid phase (inverted material): reduce Δt or the solid's shear modulus",
                        ));
                        return;
                    }
                }
            }
            let new_sigma = Mat3::from_diagonal(Vec3::splat(-p))
                + fluid_dev * fluid as Real
                + solid * i_s;
            if !new_sigma.is_finite() {
                failures.record(FailureReport::particle(
                    e,
                    "phase stress",
                    phi,
                    "non-finite blended stress (temperature factor or solid stress)",
                ));
                return;
            }
            sigma.0 = new_sigma;
            let stab = stab.bypass_change_detection();
            stab.wave_speed_sq =
                c_tait_sq + (fluid * model_wave as f64 + i_s as f64 * solid_wave) as Real;
            stab.kinematic_viscosity = (fluid * stab.kinematic_viscosity as f64) as Real;
        },
    );
}

/// S15, choice D12: F ← (det F)^{1/3} I on every particle that was fully fluid (I_s = 0) in the
/// step just taken, if its material resets its shape memory. During the start-up rate
/// evaluation nothing is reset.
///
/// Reads `PhaseChangeTable`, `StepContext`, `MaterialId`, `PhaseIndex`; writes
/// `DeformationGradient`.
pub fn reset_shape_memory(
    ctx: Res<crate::step::schedule::StepContext>,
    phases: Option<Res<PhaseChangeTable>>,
    mut q: Query<(&MaterialId, &PhaseIndex, &mut DeformationGradient), With<Particle>>,
) {
    if ctx.rate_evaluation {
        return;
    }
    let Some(phases) = phases else { return };
    q.par_iter_mut().for_each(|(mat, i_s, mut f)| {
        let Some(ph) = phases.0.get(*mat) else { return };
        if !ph.reset_shape_memory || i_s.0 > 0.0 {
            return;
        }
        let det = f.0.determinant();
        let s = if det > 0.0 && det.is_finite() {
            det.cbrt()
        } else {
            1.0
        };
        let reset = Mat3::from_diagonal(Vec3::splat(s));
        if f.0 != reset {
            f.0 = reset;
        }
    });
}
