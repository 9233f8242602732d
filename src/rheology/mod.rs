//! Rheology models: extra stress and history state on particles (ALGORITHM §6.1).
//!
//! A rheology model is a pure constitutive function plus a per-particle history state. It plugs
//! into the step at two points:
//!
//! | when | set | what the model does |
//! |---|---|---|
//! | S7–S9 | [`ConstitutiveSystems::Models`](crate::step::schedule::ConstitutiveSystems::Models) | [`Rheology::evaluate`]: returns the extra Cauchy stress at t_{n+W₁} and its stability data; may store the step's increment in its state |
//! | S15 | [`CommitSystems::Models`](crate::step::schedule::CommitSystems::Models) | [`Rheology::commit`]: advances the history state to t_{n+1} |
//!
//! [`RheologyPlugin<M>`] registers both systems for a model type `M`; the model's parameters
//! live per material in [`RheologyTable<M>`] (keyed by [`MaterialId`]); a particle takes part
//! only if it carries the model's state component [`Rheology::State`], attached with
//! [`attach_model`] (exclusive access) or [`RheologyCommandsExt::attach_model`] (from a system).
//! Particles without the state pay nothing: the systems query `&mut M::State` and do not run at
//! all while no entity has it.
//!
//! # Stress and viscosity convention
//!
//! The core ([`crate::step::constitutive`]) already writes the **local** (Newtonian, solvent)
//! part σ̃ᴸ = 2 F_v μ D̃ of the material (`FluidMaterial::viscosity` μ, `local_fraction` F_v)
//! together with the pressure −p̃ I. A model returns only what comes **on top** of that, e.g. the
//! non-local (polymer) stress σ̃ᴺᴸ of the \[Su21\] split μ = F_v μ + (1 − F_v) μ. It must not
//! repeat the local part. The total is (ALGORITHM §2.9, §6.1)
//! σ̃ = −p̃ I + 2 F_v μ D̃ + Σ_models σ̃_extra.
//!
//! A model returns its liquid-phase stress unscaled: the phase blend
//! σ̃ = −p̃I + (1 − I_s)φσ̃_fluid,dev + I_s σ̃ˢ_dev of §4.1 is applied after the models, in
//! [`ConstitutiveSystems::Blend`](crate::step::schedule::ConstitutiveSystems::Blend), by the
//! phase-change plugin (`thermal::phase::blend_phase_stress`), not by each model.
//!
//! # Stability data
//!
//! The evaluate system adds the model's moduli to the particle's [`StabilityData`](crate::components::StabilityData) so that the
//! adaptive step (§2.15) accounts for them: c² += (4/3 G_el + K_el)/ρ̃;
//! ν = max(ν, μ_tan/ρ̃); k_relax = max(k_relax, relaxation rate).
//!
//! # Precision
//!
//! The core stores particle state in `f32`. The context hands models the step's GS4 weights in
//! `f64` ([`FirstOrderCoefficients`], built from [`Gs4Params`], not from the `f32`
//! [`StepCoefficients`](crate::kernels::StepCoefficients)), so a model that keeps its history
//! in `f64` integrates to `f64` accuracy.
//!
//! # Writing a model
//!
//! 1. A parameter struct `M: Clone + Send + Sync + 'static` and a state component
//!    (`#[derive(Component, Clone)]` with a `Default` that means "at rest"; note that glam's
//!    `Mat3::default()` is the identity, so write `Default` by hand for matrix states).
//! 2. `impl Rheology for M`: `evaluate` reads the context and the state at t_n, returns the
//!    stress at t_{n+W₁} and stores what `commit` needs; `commit` advances the state. For a
//!    GS4-1 history pair (y, ẏ), use [`FirstOrderCoefficients`] as in [`su2021_unified`].
//!    `evaluate` must not advance the history: a failed step has to leave the state at t_n.
//! 3. `validate` lists every ill-posed parameter ([`InvalidParameter`]).
//! 4. A file per model, named after its source (`author2021_model.rs`), and tests that drive
//!    evaluate/commit in a loop without an App (`tests/it/rheology.rs`).
//! 5. A model that reads the deformation gradient sets [`Rheology::NEEDS_DEFORMATION_GRADIENT`]
//!    ([`neo_hookean`]); one that needs its own strain history keeps it in its state
//!    ([`li2024_elastoplastic`] integrates its own F).
//!
//! A complete model written outside the crate with the public API only (the Giesekus fluid) is
//! `examples/custom_rheology.rs`.
//!
//! # Models
//!
//! | file | model |
//! |---|---|
//! | [`li2024_elastoplastic`] | von Mises elasto-plastic solid of \[Li\] with elastic / plastic limits and fracture (ALGORITHM §6.3) |
//! | [`li2024_generalized_newtonian`] | generalized-Newtonian viscosities of \[Li\] (ALGORITHM §6.2) |
//! | [`neo_hookean`] | neo-Hookean solid from the core's deformation gradient (ALGORITHM §4.2) |
//! | [`su2021_unified`] | XPP / Oldroyd-B / UCM polymer stress of \[Su21\] (ALGORITHM §2.8) |

use std::fmt;

use bevy_ecs::component::Mutable;
use bevy_ecs::prelude::*;
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::gs4::Gs4Params;
use crate::material::{FluidMaterial, MaterialId, MaterialTable};
use crate::math::{Mat3, Real};

pub mod li2024_elastoplastic;
pub mod li2024_generalized_newtonian;
pub mod metrics;
pub mod neo_hookean;
pub mod plugin;
pub mod registry;
pub mod su2021_unified;
pub mod tensor;

pub use plugin::{
    AttachError, ModelSet, RheologyCommandsExt, RheologyPlugin, attach_model, commit_model,
    evaluate_model, init_rheology_state,
};
pub use registry::{ModelEntry, ModelRegistry, ModelSpec};

pub use li2024_elastoplastic::{ElastoPlasticState, Li2024ElastoPlastic};
pub use li2024_generalized_newtonian::{GeneralizedNewtonian, LiModel, LiViscosity, ShearMeasure};
pub use neo_hookean::{NeoHookean, NeoHookeanSolid};
pub use su2021_unified::{PolymerStress, Su2021Unified};

/// The GS4-1 weights of one step in `f64` (ALGORITHM §1.2): what a first-order particle field
/// (y, ẏ) needs for ŷ = y + W₁Λ₄Δt ẏ, Δẏ = (g(ŷ) − ẏ)/(W₁Λ₆ + η W₂Λ₅Δt K),
/// ỹ = ŷ + W₂Λ₅Δt Δẏ, yⁿ⁺¹ = y + λ₄Δt ẏ + λ₅Δt Δẏ, ẏⁿ⁺¹ = ẏ + Δẏ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirstOrderCoefficients {
    /// Δt \[s\] (0 in the start-up rate evaluation).
    pub dt: f64,
    /// W₁Λ₄: predictor weight.
    pub w1l4: f64,
    /// W₁Λ₆: weight of the rate increment in the balance (the "effective mass").
    pub w1l6: f64,
    /// W₂Λ₅: weight of Δt Δẏ in the algorithmic value ỹ.
    pub w2l5: f64,
    /// λ₄: weight of Δt ẏ in yⁿ⁺¹.
    pub l4: f64,
    /// λ₅: weight of Δt Δẏ in yⁿ⁺¹.
    pub l5: f64,
    /// The mechanics run a first-order scheme ([`Scheme::SymplecticEuler`],
    /// [`Scheme::BackwardEulerViscous`]): the grid forces want the stress at tₙ, and a model
    /// may take a first-order step of its own instead of the GS4-1 pair above (as
    /// [`Su2021Unified`] does: its convected update, ALGORITHM §2.8, choice D22). False for
    /// the GS4 schemes and in the start-up rate evaluation.
    ///
    /// [`Scheme::SymplecticEuler`]: crate::config::Scheme::SymplecticEuler
    /// [`Scheme::BackwardEulerViscous`]: crate::config::Scheme::BackwardEulerViscous
    pub first_order_mechanics: bool,
}

impl FirstOrderCoefficients {
    /// The weights of a step of size `dt` \[s\] with the GS4 parameters `p`.
    pub fn step(p: &Gs4Params, dt: f64) -> Self {
        Self {
            dt,
            w1l4: p.w1l4,
            w1l6: p.w1l6,
            w2l5: p.w2l5,
            l4: p.l4,
            l5: p.l5,
            first_order_mechanics: false,
        }
    }

    /// The same weights, for mechanics run by a first-order scheme (`true`) or by GS4
    /// (`false`, the default); see [`first_order_mechanics`](Self::first_order_mechanics).
    pub fn with_first_order_mechanics(mut self, first_order: bool) -> Self {
        self.first_order_mechanics = first_order;
        self
    }

    /// The start-up rate evaluation of §2.14: Δt = 0 and W₁Λ₆ = 1, so that evaluate + commit
    /// leave the value unchanged and set the rate to g(y⁰) (ẏ⁰ = g(y⁰), any stored ẏ is
    /// replaced).
    pub fn rate_evaluation() -> Self {
        Self {
            dt: 0.0,
            w1l4: 0.0,
            w1l6: 1.0,
            w2l5: 0.0,
            l4: 0.0,
            l5: 0.0,
            first_order_mechanics: false,
        }
    }
}

/// What a model sees of one particle at t_{n+W₁} (ALGORITHM §6.1 input). Plain data: no ECS
/// types, so models can be tested and reused without an `App`.
///
/// In [`Rheology::commit`] the same context is passed with one difference:
/// `deformation_gradient` is F^{n+1} (after `GridToParticle`) instead of F̃.
#[derive(Clone, Copy, Debug)]
pub struct RheologyContext<'a> {
    /// Velocity gradient L̃ \[1/s\], L_ab = ∂v_a/∂x_b (glam is column-major: column b holds
    /// ∂v/∂x_b, so `l.y_axis.x` = ∂v_x/∂y).
    pub velocity_gradient: Mat3,
    /// Strain rate D̃ = ½(L̃ + L̃ᵀ) \[1/s\].
    pub strain_rate: Mat3,
    /// Shear rate γ̇ = √(2 D̃:D̃) \[1/s\] (choice D14; \[Li\]'s tables use γ̇/√2).
    pub shear_rate: Real,
    /// F̃ (evaluate) or Fⁿ⁺¹ (commit); `None` unless the particle carries a
    /// [`DeformationGradient`](crate::components::DeformationGradient).
    pub deformation_gradient: Option<Mat3>,
    /// Algorithmic density ρ̃ \[kg/m³\].
    pub density: Real,
    /// Volume ratio J̃ = ρ₀/ρ̃ (choice D11).
    pub volume_ratio: Real,
    /// The particle's material (μ, F_v, ρ₀, c₀).
    pub material: &'a FluidMaterial,
    /// GS4-1 weights of this step.
    pub coefficients: FirstOrderCoefficients,
    /// True during the start-up rate evaluation (Δt = 0, §2.14).
    pub rate_evaluation: bool,
}

impl<'a> RheologyContext<'a> {
    /// A context for velocity gradient `l`, density `density` (ρ̃) and `material`; derives D̃,
    /// γ̇ and J̃; no deformation gradient. (Inlined: a model that does not read D̃, γ̇ or J̃
    /// and is itself inlined into the per-particle loop does not pay for them.)
    #[inline]
    pub fn new(
        l: Mat3,
        density: Real,
        material: &'a FluidMaterial,
        coefficients: FirstOrderCoefficients,
        rate_evaluation: bool,
    ) -> Self {
        let d = 0.5 * (l + l.transpose());
        let dd = d.x_axis.dot(d.x_axis) + d.y_axis.dot(d.y_axis) + d.z_axis.dot(d.z_axis);
        Self {
            velocity_gradient: l,
            strain_rate: d,
            shear_rate: (2.0 * dd).sqrt(),
            deformation_gradient: None,
            density,
            volume_ratio: material.density / density,
            material,
            coefficients,
            rate_evaluation,
        }
    }

    /// The same context with a deformation gradient.
    pub fn with_deformation_gradient(mut self, f: Mat3) -> Self {
        self.deformation_gradient = Some(f);
        self
    }
}

/// What a model returns for one particle (ALGORITHM §6.1 output). `Default` is "nothing":
/// zero stress and zero moduli.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RheologyOutput {
    /// Extra Cauchy stress σ̃_extra at t_{n+W₁} \[Pa\], added to [`CauchyStress`](crate::components::CauchyStress). Symmetric.
    pub stress: Mat3,
    /// Tangent viscosity μ_tan = d|τ|/dγ̇ of any **explicit** viscous part \[Pa·s\] (viscous Δt
    /// limit); 0 if the model has none.
    pub tangent_viscosity: Real,
    /// Instantaneous shear modulus G_el \[Pa\] (wave Δt limit).
    pub shear_modulus: Real,
    /// Extra bulk modulus K_el \[Pa\]; 0 when the Tait equation carries the volume response.
    pub bulk_modulus: Real,
    /// Stiffest explicitly integrated pointwise relaxation rate \[1/s\] (Δt ≤ z_crit/rate);
    /// 0 if none or treated implicitly.
    pub relaxation_rate: Real,
}

impl Default for RheologyOutput {
    fn default() -> Self {
        // By hand: glam's `Mat3::default()` is the identity.
        Self {
            stress: Mat3::ZERO,
            tangent_viscosity: 0.0,
            shear_modulus: 0.0,
            bulk_modulus: 0.0,
            relaxation_rate: 0.0,
        }
    }
}

impl RheologyOutput {
    /// True if every number is finite.
    pub fn is_finite(&self) -> bool {
        self.stress.is_finite()
            && self.tangent_viscosity.is_finite()
            && self.shear_modulus.is_finite()
            && self.bulk_modulus.is_finite()
            && self.relaxation_rate.is_finite()
    }
}

pub use crate::validation::{InvalidParameter, ParameterWarning};

/// A rheology model: parameters (`self`, one value per material) and a pure constitutive
/// update. Implementors must not touch ECS types; [`RheologyPlugin`] does the gathering and
/// scattering.
///
/// The parameters are (de)serialisable so that a scene file can name the model as
/// `model: NAME((field: value, ...))` once its [`RheologyPlugin`] (or
/// [`ModelRegistry::register`]) has registered it.
pub trait Rheology:
    Clone + Send + Sync + PartialEq + fmt::Debug + Serialize + DeserializeOwned + 'static
{
    /// The model's name in scene files and messages (unique among registered models).
    const NAME: &'static str;

    /// Per-particle state: the history (e.g. polymer stress and its rate) and any per-step
    /// value that [`commit`](Rheology::commit) needs (e.g. the rate increment).
    type State: Component<Mutability = Mutable> + Clone + Default;

    /// Whether the model reads the deformation gradient ([`RheologyContext::deformation_gradient`]).
    /// If true, [`attach_model`] also gives the particles a [`DeformationGradient`](crate::components::DeformationGradient) (F = I) and
    /// a [`PredictedDeformationGradient`](crate::components::PredictedDeformationGradient) unless they carry them already, so that the core
    /// advances F (§2.4, §2.13); a particle with the state but without F stops the run with a
    /// failure report. Default false.
    const NEEDS_DEFORMATION_GRADIENT: bool = false;

    /// Evaluates the model at t_{n+W₁}: returns the extra stress and the stability data, and
    /// may write the step's increment into `state`. Must not advance the history (a failed
    /// step must leave the state at t_n).
    fn evaluate(&self, ctx: &RheologyContext, state: &mut Self::State) -> RheologyOutput;

    /// Advances the history to t_{n+1} (S15), after the grid update and G2P.
    fn commit(&self, ctx: &RheologyContext, state: &mut Self::State);

    /// Makes [`Rheology::State`] travel with particles that migrate between ranks in a
    /// distributed run: the crate's models call
    /// [`travel::<Self::State>(world)`](crate::distributed::travel) (the state then implements
    /// [`Travels`](crate::distributed::Travels)). Default: nothing, and a distributed run
    /// refuses particles carrying the state, naming it.
    fn travel(world: &mut bevy_ecs::world::World) {
        let _ = world;
    }

    /// The state a particle starts with when the model is attached. Default: `State::default()`.
    fn initial_state(&self) -> Self::State {
        Self::State::default()
    }

    /// Checks the parameters for use with `material`. Default: always valid.
    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        let _ = material;
        Ok(())
    }

    /// Parameters that are accepted but questionable (outside the model's physical range,
    /// inconsistent with each other, likely to blow up): reported at load, never rejected.
    /// Default: none.
    fn warnings(&self, material: &FluidMaterial) -> Vec<ParameterWarning> {
        let _ = material;
        Vec::new()
    }
}

/// The parameters of model `M` per material: `MaterialId(i)` → `M`. Materials without an
/// entry do not use the model.
#[derive(Resource, Clone)]
pub struct RheologyTable<M: Rheology> {
    entries: MaterialTable<M>,
}

impl<M: Rheology> Default for RheologyTable<M> {
    fn default() -> Self {
        Self {
            entries: MaterialTable::default(),
        }
    }
}

impl<M: Rheology> RheologyTable<M> {
    /// Sets the model of `material`; returns the previous one. Takes effect from the next
    /// step (parameters may be changed at run time through `ResMut<RheologyTable<M>>`).
    pub fn insert(&mut self, material: MaterialId, model: M) -> Option<M> {
        self.entries.insert(material, model)
    }

    /// Removes the model of `material`. Particles that still carry the state then stop the
    /// run with a failure report at their next step (remove their state too).
    pub fn remove(&mut self, material: MaterialId) -> Option<M> {
        self.entries.remove(material)
    }

    /// The model of `material`, if any.
    #[inline]
    pub fn get(&self, material: MaterialId) -> Option<&M> {
        self.entries.get(material)
    }

    /// The model of `material`, mutably.
    pub fn get_mut(&mut self, material: MaterialId) -> Option<&mut M> {
        self.entries.get_mut(material)
    }

    /// All (material, model) pairs.
    pub fn iter(&self) -> impl Iterator<Item = (MaterialId, &M)> {
        self.entries.iter()
    }

    /// The initial state for a new particle of `material` (add it to the spawn bundle), or
    /// `None` if the material does not use the model.
    pub fn initial_state(&self, material: MaterialId) -> Option<M::State> {
        self.get(material).map(M::initial_state)
    }
}
