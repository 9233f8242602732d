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
//! [`DeformationGradient`](crate::components::DeformationGradient) (advanced by the core, §2.13) and a [`PhaseIndex`].
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
//! [`MpmSystems::Constitutive`](crate::step::schedule::MpmSystems::Constitutive) after
//! [`ConstitutiveSystems::Models`] (S6, S9, S10 of §2.3) and [`reset_shape_memory`] to
//! [`CommitSystems::Models`] (S15). Both touch only particles with a [`Temperature`](crate::thermal::Temperature) or a
//! [`PredictedTemperature`](crate::thermal::PredictedTemperature) whose material has an entry; other particles pay nothing.
//!
//! # Files
//!
//! | file | content | ALGORITHM |
//! |---|---|---|
//! | `model` | [`PhaseChange`]: solid fraction I_s, neo-Hookean solid stress; [`PhaseChangeTable`] | §4.1–4.2 |
//! | `temperature_viscosity` | [`TemperatureLaw`], Cross-WLF, [`TemperatureViscosity`] and its factor φ; [`TemperatureViscosityTable`] | §4.3 |
//! | `systems` | the phase state of particles and the systems [`blend_phase_stress`], [`reset_shape_memory`] | §4.1–4.3 |
//! | `spec` | scene entries [`PhaseChangeSpec`], [`TemperatureViscositySpec`] and [`validate_phase_entries`] | |
//!
//! This file holds [`PhaseChangePlugin`]; the files depend one way (`spec` and `systems` on
//! `model` and `temperature_viscosity`, never the reverse).
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::common_conditions::any_with_component;

use super::components::PhaseIndex;
use crate::material::MaterialId;
use crate::spawn::ParticleInitializers;
use crate::step::schedule::{CommitSystems, ConstitutiveSystems, MpmStep, init_step_schedule};

mod model;
mod spec;
mod systems;
mod temperature_viscosity;

pub use crate::material::MaterialTable;
pub use model::{PhaseChange, PhaseChangeTable};
pub use spec::{PhaseChangeSpec, TemperatureViscositySpec, validate_phase_entries};
pub(crate) use systems::attach_missing_phase_state;
pub use systems::{attach_phase_change, blend_phase_stress, init_phase_state, reset_shape_memory};
pub use temperature_viscosity::{
    TemperatureLaw, TemperatureViscosity, TemperatureViscosityTable, cross_wlf_viscosity,
    cross_wlf_zero_shear,
};

/// Registers phase change and temperature-dependent viscosity: the two tables (entries merged
/// into existing ones), [`blend_phase_stress`] after the rheology models, [`reset_shape_memory`]
/// in the model commits, and the [`ParticleInitializers`]
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
        crate::distributed::travel::<PhaseIndex>(world);
        crate::distributed::travel::<crate::components::DeformationGradient>(world);
        crate::distributed::travel::<crate::components::PredictedDeformationGradient>(world);
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
