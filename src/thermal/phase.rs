//! Melting and solidification (ALGORITHM §4.1–4.2, choices D11, D12) and temperature-dependent
//! viscosity (§4.3, choice D13; \[Li\]'s μ₀e^{−dT}).
//!
//! # Phase index and stress blend (§4.1, eq. 15 of \[Su21\], erratum E23)
//!
//! I_s = 1 if T̂_p < T_m (solid), else 0, from the predicted temperature T̂_p; with a ramp
//! ΔT_m > 0 (not in the paper) I_s = clamp((T_m + ΔT_m − T̂_p)/(2ΔT_m), 0, 1). The pressure is
//! common to both phases and the deviatoric parts are blended:
//!
//! ```text
//! σ̃ = −p̃ I + (1 − I_s) φ(T̂, γ̇) σ̃_fluid,dev + I_s σ̃ˢ_dev
//! ```
//! where σ̃_fluid,dev is everything the core and the rheology models wrote besides −p̃I (the
//! local viscous stress 2F_vμD̃ and every model's extra stress, §2.9, §6.1) and φ is the
//! temperature factor below (1 without one). The polymer stress σᴺᴸ keeps evolving while
//! solid (paper-literal, §4.1).
//!
//! # Neo-Hookean solid (§4.2, D11)
//!
//! σ̃ˢ_dev = (G_s/J̃) dev(det(F̃)^{−2/3} F̃F̃ᵀ), J̃ = ρ₀/ρ̃: the math of
//! [`NeoHookean::stress`](crate::rheology::NeoHookean::stress) with no extra bulk modulus (the
//! Tait pressure carries the volume). Particles of a phase-change material carry a
//! [`DeformationGradient`] (advanced by the core, §2.13) and a [`PhaseIndex`].
//!
//! # Shape memory (D12)
//!
//! While a particle is fluid (I_s = 0 in the step just taken) its shape memory is reset after
//! the step: F ← (det F)^{1/3} I. The solid's reference configuration is then the one at
//! solidification, so a blob that melts and solidifies again has no memory of its pre-melt
//! shape.
//!
//! # Temperature factor (§4.3)
//!
//! A material may scale its fluid deviatoric stress — whatever rheology produced it — by a
//! factor φ that reads the predicted temperature ([`TemperatureLaw`]):
//!
//! - `Exponential`: φ = e^{−d(T − T_ref)}, \[Li\]'s μ₀e^{−dT} for T_ref = 0 (the material's or
//!   model's viscosity is μ₀);
//! - `CrossWlf` (§4.3, D13): the Cross-WLF viscosity
//!   μ(T, γ̇) = μ₀(T)/(1 + (μ₀(T)γ̇/τ*)^{1−n}), μ₀(T) = D₁ exp(−A₁(T − D₂)/(A₂ + T − D₂)) with
//!   T clamped to ≥ D₂ (so μ₀ ≤ D₁), replacing the material's viscosity: φ = μ/μ_material.
//!
//! Both are capped by `max_viscosity` (μ ≤ μ_max, D13). For a purely viscous law (Newtonian,
//! \[Li\]'s generalized-Newtonian laws) scaling the stress is exactly scaling μ. For a model with
//! memory it scales the returned stress; for Oldroyd-B with a constant φ this equals scaling
//! η_p (the model is linear in its forcing 2G₀D), when φ varies in time it is the current
//! factor applied to the whole history (a deviation). Under
//! [`Scheme::implicit_viscosity`](crate::config::Scheme) the local viscous part is applied by
//! the grid solve and is not scaled. The stability data are scaled with the stress: the
//! viscous limit by (1 − I_s)φ, the model part of the wave speed likewise, plus the solid's
//! 4/3 G_eff/ρ̃ (§4.2, §7.2).
//!
//! # Where it runs
//!
//! [`PhaseChangePlugin`] adds [`blend_phase_stress`] to
//! [`MpmSystems::Constitutive`] after
//! [`ConstitutiveSystems::Models`] (S6, S9, S10 of §2.3) and [`reset_shape_memory`] to
//! [`CommitSystems::Models`] (S15). Both touch only particles with a [`Temperature`] or a
//! [`PredictedTemperature`] whose material has an entry; other particles pay nothing.
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::common_conditions::any_with_component;
use glam::DMat3;
use serde::{Deserialize, Serialize};

use super::components::{PhaseIndex, PredictedTemperature, Temperature};
use crate::components::{
    CauchyStress, DeformationGradient, Particle, PredictedDeformationGradient, PredictedDensity,
    StabilityData, VelocityGradient,
};
use crate::failure::{FailureCollector, FailureReport};
use crate::material::{MaterialId, Materials};
use crate::math::{Mat3, Real, Vec3};
use crate::rheology::NeoHookean;
use crate::spawn::ParticleInitializers;
use crate::step::schedule::{CommitSystems, ConstitutiveSystems, MpmStep, init_step_schedule};
use crate::validation::InvalidParameter;

/// Melting and solidification of one material (§4.1–4.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseChange {
    /// Melting temperature T_m (scene temperature unit; \[Su21\] uses T_m = 0.1 normalised).
    pub melting_temperature: Real,
    /// Half width ΔT_m ≥ 0 of the smooth ramp of I_s (0: the paper's step). Default 0.
    #[serde(default)]
    pub ramp: Real,
    /// Shear modulus G_s of the neo-Hookean solid \[Pa\] > 0.
    pub shear_modulus: f64,
    /// Choice D12: reset the shape memory F ← J^{1/3}I while fluid. Default true.
    #[serde(default = "default_true")]
    pub reset_shape_memory: bool,
}

fn default_true() -> bool {
    true
}

impl PhaseChange {
    /// A step change at `melting_temperature` to a neo-Hookean solid of shear modulus
    /// `shear_modulus` \[Pa\], with the D12 reset.
    pub fn new(melting_temperature: Real, shear_modulus: f64) -> Self {
        Self {
            melting_temperature,
            ramp: 0.0,
            shear_modulus,
            reset_shape_memory: true,
        }
    }

    /// With a smooth ramp of half width ΔT_m.
    pub fn with_ramp(mut self, ramp: Real) -> Self {
        self.ramp = ramp;
        self
    }

    /// The solid fraction I_s ∈ \[0, 1\] at temperature `t` (§4.1). NaN gives 0 (fluid).
    pub fn solid_fraction(&self, t: Real) -> Real {
        let tm = self.melting_temperature;
        if self.ramp > 0.0 {
            let s = (tm + self.ramp - t) / (2.0 * self.ramp);
            if s.is_nan() { 0.0 } else { s.clamp(0.0, 1.0) }
        } else if t < tm {
            1.0
        } else {
            0.0
        }
    }

    /// Deviatoric solid stress σ̃ˢ_dev \[Pa\] at F̃ = `f` and J̃ = `volume_ratio`, and the
    /// effective shear modulus of the stability estimate \[Pa\] (§4.2, D11). `None` if
    /// det F̃ ≤ 0.
    pub fn solid_stress(&self, f: DMat3, volume_ratio: f64) -> Option<(DMat3, f64)> {
        NeoHookean::new(self.shear_modulus).stress(f, volume_ratio)
    }

    /// Checks the parameters (every violated constraint is listed).
    pub fn validate(&self) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        if !self.melting_temperature.is_finite() {
            e.push(InvalidParameter {
                field: "melting_temperature",
                constraint: "must be a finite number",
            });
        }
        if !(self.ramp.is_finite() && self.ramp >= 0.0) {
            e.push(InvalidParameter {
                field: "ramp",
                constraint: "must be a finite number ≥ 0 (temperature unit)",
            });
        }
        if !(self.shear_modulus.is_finite() && self.shear_modulus > 0.0) {
            e.push(InvalidParameter {
                field: "shear_modulus",
                constraint: "must be a finite number > 0 Pa (G_s of the solid)",
            });
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// A temperature dependence of the viscosity (§4.3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum TemperatureLaw {
    /// φ = e^{−d(T − T_ref)}: \[Li\]'s μ₀e^{−dT} with T_ref = 0 and μ₀ the material's (or
    /// model's) viscosity.
    Exponential {
        /// d \[1/temperature unit\] (\[Li\]'s ice cream: 0.1).
        coefficient: f64,
        /// T_ref (temperature unit) at which φ = 1. Default 0.
        #[serde(default)]
        reference_temperature: f64,
    },
    /// The Cross-WLF viscosity of §4.3 (D13 reading) replacing the material's viscosity μ
    /// (which must be > 0): φ = μ(T, γ̇)/μ. T in the unit of D₂ (°C for the \[Su21\] constants).
    CrossWlf {
        /// D₁ \[Pa·s\] > 0 (\[Su21\]: 3.32e9).
        d1: f64,
        /// A₁ ≥ 0 (\[Su21\]: 20.194).
        a1: f64,
        /// A₂ > 0 (temperature unit; 51.6, the universal WLF constant).
        a2: f64,
        /// D₂ = T* (temperature unit; 100).
        d2: f64,
        /// τ* \[Pa\] > 0. Default 5.66e3 (D13).
        #[serde(default = "default_tau_star")]
        tau_star: f64,
        /// Power-law index n ∈ \[0, 1\]. Default 0.25 (D13).
        #[serde(default = "default_power_index")]
        n: f64,
    },
}

fn default_tau_star() -> f64 {
    5.66e3
}
fn default_power_index() -> f64 {
    0.25
}

/// Cross-WLF zero-shear viscosity μ₀(T) = D₁ exp(−A₁(T_eff − D₂)/(A₂ + T_eff − D₂)) \[Pa·s\],
/// T_eff = max(T, D₂) (the D13 clamp: μ₀ ≤ D₁). NaN temperatures give D₁.
pub fn cross_wlf_zero_shear(d1: f64, a1: f64, a2: f64, d2: f64, t: f64) -> f64 {
    let t = if t.is_nan() { d2 } else { t.max(d2) };
    d1 * (-a1 * (t - d2) / (a2 + t - d2)).exp()
}

/// Cross-WLF viscosity μ(T, γ̇) = μ₀(T)/(1 + (μ₀(T)γ̇/τ*)^{1−n}) \[Pa·s\] (§4.3, D13).
#[expect(
    clippy::too_many_arguments,
    reason = "the six constants of §4.3 and (T, γ̇), in the order of the formula"
)]
pub fn cross_wlf_viscosity(
    d1: f64,
    a1: f64,
    a2: f64,
    d2: f64,
    tau_star: f64,
    n: f64,
    t: f64,
    shear_rate: f64,
) -> f64 {
    let mu0 = cross_wlf_zero_shear(d1, a1, a2, d2, t);
    let x = (mu0 * shear_rate.abs() / tau_star).max(0.0);
    mu0 / (1.0 + x.powf(1.0 - n))
}

/// A temperature-dependent viscosity of one material (§4.3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureViscosity {
    /// The law.
    pub law: TemperatureLaw,
    /// Cap μ_max \[Pa·s\] of the scaled viscosity φ·μ (D13). Default none.
    #[serde(default)]
    pub max_viscosity: Option<f64>,
}

impl TemperatureViscosity {
    /// \[Li\]'s μ₀e^{−dT} (the material's viscosity is μ₀).
    pub fn exponential(coefficient: f64) -> Self {
        Self {
            law: TemperatureLaw::Exponential {
                coefficient,
                reference_temperature: 0.0,
            },
            max_viscosity: None,
        }
    }

    /// The Cross-WLF law with the \[Su21\] constants read as in D13 (T in °C).
    pub fn cross_wlf_su2021() -> Self {
        Self {
            law: TemperatureLaw::CrossWlf {
                d1: 3.32e9,
                a1: 20.194,
                a2: 51.6,
                d2: 100.0,
                tau_star: 5.66e3,
                n: 0.25,
            },
            max_viscosity: None,
        }
    }

    /// With a viscosity cap μ_max \[Pa·s\].
    pub fn with_max_viscosity(mut self, max_viscosity: f64) -> Self {
        self.max_viscosity = Some(max_viscosity);
        self
    }

    /// The factor φ ≥ 0 on the fluid deviatoric stress at temperature `t`, shear rate
    /// `shear_rate` \[1/s\], for a material of viscosity `viscosity` \[Pa·s\]. Always finite.
    pub fn factor(&self, t: f64, shear_rate: f64, viscosity: f64) -> f64 {
        let mut phi = match self.law {
            TemperatureLaw::Exponential {
                coefficient,
                reference_temperature,
            } => (-coefficient * (t - reference_temperature)).exp(),
            TemperatureLaw::CrossWlf {
                d1,
                a1,
                a2,
                d2,
                tau_star,
                n,
            } => {
                if viscosity > 0.0 {
                    cross_wlf_viscosity(d1, a1, a2, d2, tau_star, n, t, shear_rate) / viscosity
                } else {
                    1.0
                }
            }
        };
        if let Some(cap) = self.max_viscosity
            && viscosity > 0.0
        {
            phi = phi.min(cap / viscosity);
        }
        if phi.is_nan() {
            1.0
        } else {
            phi.clamp(0.0, f64::MAX)
        }
    }

    /// Checks the parameters for a material of viscosity `viscosity`.
    pub fn validate(&self, viscosity: f64) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        let mut bad = |field, constraint| e.push(InvalidParameter { field, constraint });
        match self.law {
            TemperatureLaw::Exponential {
                coefficient,
                reference_temperature,
            } => {
                if !coefficient.is_finite() {
                    bad("law.coefficient", "must be a finite number");
                }
                if !reference_temperature.is_finite() {
                    bad("law.reference_temperature", "must be a finite number");
                }
            }
            TemperatureLaw::CrossWlf {
                d1,
                a1,
                a2,
                d2,
                tau_star,
                n,
            } => {
                if !(d1.is_finite() && d1 > 0.0) {
                    bad("law.d1", "must be a finite number > 0 Pa·s");
                }
                if !(a1.is_finite() && a1 >= 0.0) {
                    bad("law.a1", "must be a finite number ≥ 0");
                }
                if !(a2.is_finite() && a2 > 0.0) {
                    bad("law.a2", "must be a finite number > 0");
                }
                if !d2.is_finite() {
                    bad("law.d2", "must be a finite number");
                }
                if !(tau_star.is_finite() && tau_star > 0.0) {
                    bad("law.tau_star", "must be a finite number > 0 Pa");
                }
                if !(n.is_finite() && (0.0..=1.0).contains(&n)) {
                    bad("law.n", "must lie in [0, 1]");
                }
                if viscosity.is_nan() || viscosity <= 0.0 {
                    bad(
                        "law",
                        "CrossWlf replaces the material's viscosity, which must then be > 0 Pa·s",
                    );
                }
            }
        }
        if let Some(cap) = self.max_viscosity
            && !(cap.is_finite() && cap > 0.0)
        {
            bad("max_viscosity", "must be a finite number > 0 Pa·s");
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

pub use crate::material::MaterialTable;

/// Phase change per material (may be changed at run time).
#[derive(Resource, Clone, Debug, Default)]
pub struct PhaseChangeTable(pub MaterialTable<PhaseChange>);

/// Temperature-dependent viscosity per material (may be changed at run time).
#[derive(Resource, Clone, Debug, Default)]
pub struct TemperatureViscosityTable(pub MaterialTable<TemperatureViscosity>);

/// Registers phase change and temperature-dependent viscosity: the two tables (entries merged
/// into existing ones), [`blend_phase_stress`] after the rheology models, [`reset_shape_memory`]
/// in the model commits, and the [`ParticleInitializers`](crate::emit::ParticleInitializers)
/// entry that gives emitted particles their phase state. Add it after
/// [`MpmPlugins`](crate::plugin::MpmPlugins); then give existing particles the phase state
/// with [`attach_phase_change`].
#[derive(Default)]
pub struct PhaseChangePlugin {
    /// Phase-change entries.
    pub phase_change: MaterialTable<PhaseChange>,
    /// Temperature-viscosity entries.
    pub temperature_viscosity: MaterialTable<TemperatureViscosity>,
}

impl PhaseChangePlugin {
    /// Adds a phase-change entry.
    pub fn with_phase_change(mut self, material: MaterialId, p: PhaseChange) -> Self {
        self.phase_change.insert(material, p);
        self
    }

    /// Adds a temperature-viscosity entry.
    pub fn with_temperature_viscosity(
        mut self,
        material: MaterialId,
        v: TemperatureViscosity,
    ) -> Self {
        self.temperature_viscosity.insert(material, v);
        self
    }
}

impl Plugin for PhaseChangePlugin {
    fn build(&self, app: &mut App) {
        init_step_schedule(app);
        let world = app.world_mut();
        world.init_resource::<PhaseChangeTable>();
        world.init_resource::<TemperatureViscosityTable>();
        for (id, p) in self.phase_change.iter() {
            world
                .resource_mut::<PhaseChangeTable>()
                .0
                .insert(id, p.clone());
        }
        for (id, v) in self.temperature_viscosity.iter() {
            world
                .resource_mut::<TemperatureViscosityTable>()
                .0
                .insert(id, v.clone());
        }
        world.init_resource::<ParticleInitializers>();
        world
            .resource_mut::<ParticleInitializers>()
            .add("phase_change", init_phase_state);
        app.add_systems(
            MpmStep,
            blend_phase_stress.in_set(ConstitutiveSystems::Blend),
        );
        app.add_systems(
            MpmStep,
            reset_shape_memory
                .in_set(CommitSystems::Reset)
                .run_if(any_with_component::<PhaseIndex>),
        );
    }
}

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

/// Gives every particle of `material` the phase state ([`init_phase_state`]); returns how
/// many particles the material has. The particles also need a temperature
/// ([`Temperature`], from the thermal plugin or set directly) to take part.
pub fn attach_phase_change(world: &mut World, material: MaterialId) -> usize {
    let targets: Vec<Entity> = world
        .query_filtered::<(Entity, &MaterialId), With<Particle>>()
        .iter(world)
        .filter(|(_, m)| **m == material)
        .map(|(e, _)| e)
        .collect();
    init_phase_state(world, material, &targets);
    targets.len()
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

/// Scene entry of a phase change (`phase_change: [ ... ]`): a material name and the
/// [`PhaseChange`] fields.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseChangeSpec {
    /// Name of a material.
    pub material: String,
    /// T_m.
    pub melting_temperature: Real,
    /// ΔT_m ≥ 0. Default 0.
    #[serde(default)]
    pub ramp: Real,
    /// G_s \[Pa\] > 0.
    pub shear_modulus: f64,
    /// D12 reset. Default true.
    #[serde(default = "default_true")]
    pub reset_shape_memory: bool,
}

impl PhaseChangeSpec {
    /// The simulation value.
    pub fn to_phase_change(&self) -> PhaseChange {
        PhaseChange {
            melting_temperature: self.melting_temperature,
            ramp: self.ramp,
            shear_modulus: self.shear_modulus,
            reset_shape_memory: self.reset_shape_memory,
        }
    }
}

/// Scene entry of a temperature-dependent viscosity (`temperature_viscosity: [ ... ]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureViscositySpec {
    /// Name of a material.
    pub material: String,
    /// The law.
    pub law: TemperatureLaw,
    /// μ_max \[Pa·s\]. Default none.
    #[serde(default)]
    pub max_viscosity: Option<f64>,
}

impl TemperatureViscositySpec {
    /// The simulation value.
    pub fn to_temperature_viscosity(&self) -> TemperatureViscosity {
        TemperatureViscosity {
            law: self.law.clone(),
            max_viscosity: self.max_viscosity,
        }
    }
}

/// Checks a scene's `phase_change` and `temperature_viscosity` sections (known material, one
/// entry per material, parameters, the melting temperature against the material's `thermal`
/// entry) given the scene's `materials` and `thermal` section. Returns every issue.
pub fn validate_phase_entries(
    phase_change: &[PhaseChangeSpec],
    temperature_viscosity: &[TemperatureViscositySpec],
    thermal: &super::scene::ThermalSpec,
    materials: &[crate::material::FluidMaterial],
) -> Vec<crate::validation::FieldIssue> {
    use crate::validation::FieldIssue;
    let mut issues = Vec::new();
    let find = |name: &str| materials.iter().find(|m| m.name == name);
    for (i, p) in phase_change.iter().enumerate() {
        if find(&p.material).is_none() {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].material"),
                format!("unknown material `{}`", p.material),
            ));
        }
        if let Some(k) = phase_change[..i]
            .iter()
            .position(|q| q.material == p.material)
        {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].material"),
                format!(
                    "material `{}` already has a phase change (phase_change[{k}])",
                    p.material
                ),
            ));
        }
        if let Some(t) = thermal
            .materials
            .iter()
            .find(|m| m.material == p.material)
            .and_then(|m| m.melting_temperature)
            && t != p.melting_temperature
        {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].melting_temperature"),
                format!(
                    "must equal the material's thermal melting_temperature {t} (got {})",
                    p.melting_temperature
                ),
            ));
        }
        for e in p.to_phase_change().validate().err().unwrap_or_default() {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].{}", e.field),
                format!("{} (got {})", e.constraint, phase_value(p, e.field)),
            ));
        }
    }
    for (i, v) in temperature_viscosity.iter().enumerate() {
        let Some(m) = find(&v.material) else {
            issues.push(FieldIssue::new(
                format!("temperature_viscosity[{i}].material"),
                format!("unknown material `{}`", v.material),
            ));
            continue;
        };
        if let Some(k) = temperature_viscosity[..i]
            .iter()
            .position(|q| q.material == v.material)
        {
            issues.push(FieldIssue::new(
                format!("temperature_viscosity[{i}].material"),
                format!(
                    "material `{}` already has a temperature law (temperature_viscosity[{k}])",
                    v.material
                ),
            ));
        }
        for e in v
            .to_temperature_viscosity()
            .validate(m.viscosity as f64)
            .err()
            .unwrap_or_default()
        {
            issues.push(FieldIssue::new(
                format!("temperature_viscosity[{i}].{}", e.field),
                e.constraint,
            ));
        }
    }
    issues
}

fn phase_value(p: &PhaseChangeSpec, field: &str) -> String {
    match field {
        "melting_temperature" => p.melting_temperature.to_string(),
        "ramp" => p.ramp.to_string(),
        "shear_modulus" => p.shear_modulus.to_string(),
        _ => "?".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cross_wlf_samples() {
        let mu0 = |t| cross_wlf_zero_shear(3.32e9, 20.194, 51.6, 100.0, t);
        assert!((mu0(200.0) / 5.45e3 - 1.0).abs() < 5e-3, "{}", mu0(200.0));
        assert_eq!(mu0(100.0), 3.32e9);
        assert_eq!(mu0(20.0), 3.32e9); // clamped T_eff = D₂
    }

    #[test]
    fn ramp_and_step() {
        let p = PhaseChange::new(0.1, 1.0);
        assert_eq!(p.solid_fraction(0.099), 1.0);
        assert_eq!(p.solid_fraction(0.1), 0.0);
        let r = p.with_ramp(0.02);
        assert!((r.solid_fraction(0.1) - 0.5).abs() < 1e-6);
        assert_eq!(r.solid_fraction(0.07), 1.0);
        assert_eq!(r.solid_fraction(0.13), 0.0);
        assert_eq!(r.solid_fraction(f32::NAN), 0.0);
    }
}
